//! Densification and pruning keep every per-Gaussian array, Adam moment and
//! statistic aligned: Gaussians are tagged through a feature channel, an extra
//! property and their Adam moments, and the tags are checked after clone / split /
//! prune, with and without a mask.

use transsplat_raster::Grads;
use transsplat_scene::{Extra, Gaussians};
use transsplat_train::{DensifyConfig, Group, LearningRates, Model, TrainConfig, Trainer, Update};

const N: usize = 12;
const EXTENT: f32 = 10.0;

/// Rows 0..3: large gradient, small (clone); 3..6: large gradient, large (split);
/// 6..8: transparent (prune); 8..12: ordinary.
fn trainer() -> Trainer {
    let mut g = Gaussians { sh_degree: 1, ..Default::default() };
    for i in 0..N {
        g.means.push([i as f32, 0.0, 5.0]);
        let s = if (3..6).contains(&i) { 0.5f32 } else { 0.05 }; // dense threshold 0.01 * 10 = 0.1
        g.log_scales.push([s.ln(), (s * 0.5).ln(), (s * 0.25).ln()]);
        g.rotations.push([1.0, 0.1 * i as f32, 0.0, 0.0]);
        g.opacity_logits.push(if (6..8).contains(&i) { -8.0 } else { 0.5 + 0.01 * i as f32 });
        for k in 0..12 {
            g.sh.push(i as f32 + 0.01 * k as f32);
        }
    }
    g.extra = Extra { names: vec!["label".into()], values: (0..N).map(|i| 10.0 * i as f32).collect() };
    let features: Vec<f32> = (0..N).flat_map(|i| [i as f32, -(i as f32)]).collect();
    let model = Model::with_features(g, features, 2).unwrap();
    let config = TrainConfig {
        lr: LearningRates { position_init: 1e-3, position_final: 1e-3, ..Default::default() },
        ..Default::default()
    };
    let mut t = Trainer::new(model, EXTENT, config).unwrap();
    // One Adam step with gradients tagging each row: m = 0.1 g after the first step.
    let mut grads = Grads::zeros(N, 1, 2);
    for i in 0..N {
        grads.means[i] = [i as f32 + 1.0; 3];
        grads.opacity_logits[i] = i as f32 + 1.0;
        grads.features[i * 2] = i as f32 + 1.0;
        grads.sh[i * 12] = i as f32 + 1.0;
        grads.sh[i * 12 + 5] = i as f32 + 1.0;
    }
    assert!(t
        .adam
        .step(&mut t.model, &grads, &t.config.lr.at(1, 100, EXTENT), Update::Dense(None))
        .is_none());
    // Densification statistics: rows 0..6 above the threshold 2e-4.
    for i in 0..N {
        t.stats.grad_accum[i] = if i < 6 { 3e-3 } else { 1e-4 };
        t.stats.denom[i] = 2;
        t.stats.max_radii[i] = 3.0;
    }
    t.step = 600;
    t
}

/// Checks that every array has the new length and that row j carries tag `want[j]`
/// (fresh rows: zero moments).
fn check_rows(t: &Trainer, want: &[usize], fresh_from: usize) {
    let n = want.len();
    assert_eq!(t.model.len(), n);
    t.model.validate().unwrap();
    for g in Group::ALL {
        let st = &t.adam.groups[g.index()];
        if !st.m.is_empty() {
            assert_eq!(st.m.len(), n * st.width, "{} moments", g.name());
            assert_eq!(st.v.len(), n * st.width, "{} moments", g.name());
        }
    }
    assert_eq!(t.stats.grad_accum.len(), n);
    assert_eq!(t.stats.denom.len(), n);
    assert_eq!(t.stats.max_radii.len(), n);
    let gs = &t.model.gaussians;
    for (j, &tag) in want.iter().enumerate() {
        let f = tag as f32;
        // Channel 0 took one Adam step of lr 2.5e-3 against a positive gradient.
        assert!((t.model.features_of(j)[0] - (f - 2.5e-3)).abs() < 1e-6, "row {j} features");
        assert_eq!(t.model.features_of(j)[1], -f, "row {j} features");
        assert_eq!(gs.extra.values[j], 10.0 * f, "row {j} label");
        assert!((gs.sh_of(j)[0] - (f - 2.5e-3)).abs() < 1e-6, "row {j} SH DC");
        assert!((gs.sh_of(j)[1] - (f + 0.01)).abs() < 1e-6, "row {j} SH");
        assert!((gs.rotations[j][1] - 0.1 * f).abs() < 1e-6, "row {j} rotation");
        let pos_m = &t.adam.groups[Group::Position.index()].m;
        let feat_m = &t.adam.groups[Group::Features.index()].m;
        let op_m = &t.adam.groups[Group::Opacity.index()].m;
        let dc_m = &t.adam.groups[Group::ShDc.index()].m;
        let rest_m = &t.adam.groups[Group::ShRest.index()].m;
        let tagm = 0.1 * (f + 1.0);
        if j < fresh_from {
            assert!((pos_m[j * 3] - tagm).abs() < 1e-5, "row {j} position moment {}", pos_m[j * 3]);
            assert!((feat_m[j * 2] - tagm).abs() < 1e-5, "row {j} feature moment");
            assert!((op_m[j] - tagm).abs() < 1e-5, "row {j} opacity moment");
            assert!((dc_m[j * 3] - tagm).abs() < 1e-5, "row {j} SH DC moment");
            assert!((rest_m[j * 9 + 2] - tagm).abs() < 1e-5, "row {j} SH rest moment");
            assert_eq!(feat_m[j * 2 + 1], 0.0);
        } else {
            for (m, w) in [(pos_m, 3), (feat_m, 2), (op_m, 1), (dc_m, 3), (rest_m, 9)] {
                assert!(m[j * w..(j + 1) * w].iter().all(|&v| v == 0.0), "fresh row {j} has moments");
            }
        }
        assert_eq!(t.stats.denom[j], 0, "statistics are cleared after densification");
    }
}

fn check_split_children(t: &Trainer, before: &Trainer, rows: std::ops::Range<usize>, parents: &[usize]) {
    let gs = &t.model.gaussians;
    for (j, &p) in rows.zip(parents) {
        let parent_scale = before.model.gaussians.log_scales[p];
        for (got, parent) in gs.log_scales[j].iter().zip(parent_scale) {
            assert!((got - (parent - 1.6f32.ln())).abs() < 1e-5, "split scale / 1.6");
        }
        let d: f32 =
            (0..3).map(|a| (gs.means[j][a] - before.model.gaussians.means[p][a]).powi(2)).sum::<f32>().sqrt();
        assert!(d > 0.0 && d < 6.0 * 0.5, "split sample {j} is {d} from its parent");
        assert_eq!(gs.opacity_logits[j], before.model.gaussians.opacity_logits[p]);
    }
}

#[test]
fn densify_without_mask_moves_the_right_rows() {
    let mut t = trainer();
    let before = t.clone();
    let (r, counts) = t.densify_and_prune(None);
    assert_eq!((counts.cloned, counts.split, counts.pruned()), (3, 3, 2));
    assert_eq!(
        counts.pruned_by,
        [2, 0, 0, 0],
        "rows 6 and 7 are transparent; no size rule before the first reset"
    );
    let want = [0, 1, 2, 8, 9, 10, 11, 0, 1, 2, 3, 3, 4, 4, 5, 5];
    check_rows(&t, &want, 7);
    assert_eq!(r.src.iter().map(|&s| s as usize).collect::<Vec<_>>(), want);
    // Clones are exact copies.
    for (j, p) in [(7, 0), (8, 1), (9, 2)] {
        assert_eq!(t.model.gaussians.means[j], before.model.gaussians.means[p]);
        assert_eq!(t.model.gaussians.log_scales[j], before.model.gaussians.log_scales[p]);
    }
    check_split_children(&t, &before, 10..16, &[3, 3, 4, 4, 5, 5]);
    // Outside arrays follow with the returned rearrangement.
    let mut outside: Vec<u32> = (0..N as u32).collect();
    r.apply(&mut outside, 1);
    assert_eq!(outside.iter().map(|&v| v as usize).collect::<Vec<_>>(), want);
}

#[test]
fn densify_with_mask_only_touches_allowed_rows() {
    let mut t = trainer();
    let before = t.clone();
    let mask: Vec<bool> = (0..N).map(|i| i % 2 == 0).collect();
    let (_, counts) = t.densify_and_prune(Some(&mask));
    assert_eq!((counts.cloned, counts.split, counts.pruned()), (2, 1, 1));
    let want = [0, 1, 2, 3, 5, 7, 8, 9, 10, 11, 0, 2, 4, 4];
    check_rows(&t, &want, 10);
    check_split_children(&t, &before, 12..14, &[4, 4]);
}

#[test]
fn prune_of_large_gaussians_after_the_first_reset() {
    let mut t = trainer();
    t.stats.grad_accum.fill(0.0);
    t.model.gaussians.log_scales[9] = [(2.0f32).ln(); 3]; // > 0.1 * extent = 1
    t.config.densify.max_screen_radius = Some(20.0); // the paper's rule (off by default)
    t.stats.max_radii[10] = 25.0; // > 20 px
    t.step = 2000; // before the first reset: only opacity
    let r = t.clone().prune(None);
    assert_eq!(r.len(), N - 2);
    t.step = 3100;
    let mut masked = t.clone();
    let r = t.prune(None);
    assert_eq!(r.src, vec![0, 1, 2, 3, 4, 5, 8, 11]);
    check_rows_plain(&t, &[0, 1, 2, 3, 4, 5, 8, 11]);
    let mask: Vec<bool> = (0..N).map(|i| i != 9 && i != 6).collect();
    let r = masked.prune(Some(&mask));
    assert_eq!(r.src, vec![0, 1, 2, 3, 4, 5, 6, 8, 9, 11]);
    check_rows_plain(&masked, &[0, 1, 2, 3, 4, 5, 6, 8, 9, 11]);
}

fn check_rows_plain(t: &Trainer, want: &[usize]) {
    t.model.validate().unwrap();
    assert_eq!(t.stats.max_radii.len(), want.len());
    for (j, &tag) in want.iter().enumerate() {
        assert_eq!(t.model.features_of(j)[1], -(tag as f32));
        assert_eq!(t.model.gaussians.extra.values[j], 10.0 * tag as f32);
        let m = &t.adam.groups[Group::Features.index()].m;
        assert!((m[j * 2] - 0.1 * (tag as f32 + 1.0)).abs() < 1e-5);
    }
}

#[test]
fn opacity_reset_caps_opacity_and_zeroes_its_moments() {
    let mut t = trainer();
    let mask: Vec<bool> = (0..N).map(|i| i < 6).collect();
    let before = t.model.gaussians.opacity_logits.clone();
    t.reset_opacity(Some(&mask));
    let cap = (0.01f32 / 0.99).ln();
    let m = &t.adam.groups[Group::Opacity.index()].m;
    for i in 0..N {
        let o = t.model.gaussians.opacity_logits[i];
        if i < 6 {
            assert!((o - before[i].min(cap)).abs() < 1e-6);
            assert_eq!(m[i], 0.0);
        } else {
            assert_eq!(o, before[i]);
            assert!(m[i] > 0.0);
        }
    }
}

#[test]
fn schedule_defaults_follow_inria() {
    let d = DensifyConfig::default();
    assert!(!d.densifies(500) && d.densifies(600) && !d.densifies(650) && !d.densifies(15_000));
    let run = 30_000;
    assert!(d.resets_opacity(3000, run) && !d.resets_opacity(3100, run) && !d.resets_opacity(15_000, run));
    // Never in the last 500 steps of a run: a 3000-step run keeps its opacities.
    assert!(d.resets_opacity(3000, 3500) && !d.resets_opacity(3000, 3499) && !d.resets_opacity(3000, 3000));
    assert!(!d.prunes_large(3000) && d.prunes_large(3001));
    assert!(!DensifyConfig::disabled().densifies(600) && !DensifyConfig::disabled().records(1));
}

/// `TrainConfig::validate` names the first setting out of its range; `Trainer::new`
/// refuses such a config.
#[test]
fn train_config_validates_itself() {
    let ok = TrainConfig::default();
    assert!(ok.validate().is_ok());
    let key = |c: TrainConfig| c.validate().unwrap_err().key;
    assert_eq!(key(TrainConfig { iterations: 0, ..ok.clone() }), "iterations");
    let d = |densify: DensifyConfig| TrainConfig { densify, ..TrainConfig::default() };
    assert_eq!(key(d(DensifyConfig { min_opacity: 1.0, ..Default::default() })), "densify.min_opacity");
    assert_eq!(
        key(d(DensifyConfig { grad_threshold: f32::NAN, ..Default::default() })),
        "densify.grad_threshold"
    );
    assert_eq!(
        key(d(DensifyConfig { camera_reach: Some(-1.0), ..Default::default() })),
        "densify.camera_reach"
    );
    assert_eq!(
        key(d(DensifyConfig { max_screen_radius: Some(0.0), ..Default::default() })),
        "densify.max_screen_radius"
    );
    let e = TrainConfig { lambda_dssim: 1.5, ..ok.clone() }.validate().unwrap_err();
    assert_eq!(e.to_string(), "lambda_dssim must be in [0, 1], got 1.5");
    let mut t = trainer();
    t.config.densify.min_opacity = -0.5;
    let model = t.model.clone();
    assert!(Trainer::new(model, EXTENT, t.config).is_err());
}
