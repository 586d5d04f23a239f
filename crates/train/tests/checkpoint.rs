//! Checkpoints and numerical health of training, through the library: a run stopped
//! at step k and resumed from its checkpoint ends bit-identical to an uninterrupted
//! run (with densification, splits drawing random numbers, an opacity reset and the
//! SH schedule inside the stopped span); a checkpoint from other settings or inputs,
//! or a truncated one, is refused naming the file; a poisoned learning rate stops
//! the run naming the step and the parameter group.

mod common;

use transsplat_train::dataset::Dataset;
use transsplat_train::fit::{train_run_id, TRAIN_FILE};
use transsplat_train::{
    fit_with, start, Checkpointer, Control, DensifyConfig, FitOptions, FitState, LoadOptions, PointCloud,
    Strategy, TrainConfig, TrainError, Trainer,
};

const ITERS: u64 = 48;

fn dataset() -> Dataset {
    let (scene, mut ds) = common::tabletop(40, 30);
    let mut cloud = PointCloud::default();
    for (i, m) in scene.gaussians.means.iter().enumerate().step_by(10) {
        cloud.positions.push(*m);
        cloud.colors.push([(i % 7) as f32 / 7.0, 0.5, 0.3]);
    }
    ds.points = Some(cloud);
    ds
}

fn options() -> FitOptions {
    FitOptions {
        config: TrainConfig {
            iterations: ITERS,
            densify: DensifyConfig {
                from_step: 5,
                interval: 8,
                until_step: 40,
                opacity_reset_interval: 24,
                sh_degree_interval: 12,
                grad_threshold: 1e-5,
                ..Default::default()
            },
            seed: 5,
            ..Default::default()
        },
        max_sh_degree: 2,
        random_points: 0,
        eval_every: 0,
        ..Default::default()
    }
}

fn fresh(ds: &Dataset, opts: &FitOptions) -> (Trainer, FitState) {
    let (t, _) = start(ds, opts).unwrap();
    (t, FitState::new(opts.config.seed))
}

/// A fresh run stopped (as if interrupted) after `k` steps, checkpointing into `dir`.
fn stopped_at(
    ds: &Dataset,
    opts: &FitOptions,
    dir: &std::path::Path,
    k: u64,
) -> (Trainer, FitState, Control<'static>) {
    let (mut t, mut state) = fresh(ds, opts);
    let mut control =
        Control { checkpoint: Some(checkpointer(dir, ds, opts)), stop_after: Some(k), ..Default::default() };
    let e = fit_with(ds, &mut t, &mut state, 0, &mut control, |_| {}).unwrap_err();
    assert!(matches!(e, TrainError::Interrupted { step } if step == k), "{e}");
    (t, state, control)
}

fn checkpointer(dir: &std::path::Path, ds: &Dataset, opts: &FitOptions) -> Checkpointer {
    let mut ck = Checkpointer::new(dir, 10);
    ck.id = train_run_id(ds, opts, &LoadOptions::default());
    ck
}

#[test]
fn stopped_and_resumed_training_is_bit_identical() {
    resumes_bit_identically(options());
}

/// The same with the MCMC strategy: relocation, growth and the position noise draw
/// from the checkpointed generator; a budget the run reaches on the way.
#[test]
fn stopped_and_resumed_mcmc_training_is_bit_identical() {
    let mut opts = options();
    opts.config.strategy = Strategy::from_name("mcmc").unwrap();
    opts.config.densify.max_gaussians = Some(dataset().points.unwrap().len() + 3);
    resumes_bit_identically(opts);
}

/// The same with Mip-Splatting's 3D filter: the variances are carried through the
/// checkpoint (the stop falls between two recomputations), so the resumed run
/// renders and updates with the filter the uninterrupted one had.
#[test]
fn stopped_and_resumed_training_with_the_3d_filter_is_bit_identical() {
    let mut opts = options();
    opts.config.filter_3d = 0.2;
    resumes_bit_identically(opts);
}

/// The scene written with the 3D filter on draws, in a renderer without the filter,
/// what the trainer drew; the filter changes what is drawn (it is not a no-op here).
#[test]
fn the_written_scene_has_the_3d_filter_baked_in() {
    use transsplat_raster::{render, Splats};
    let ds = dataset();
    let mut opts = options();
    opts.config.filter_3d = 2.0;
    let (mut t, mut state) = fresh(&ds, &opts);
    fit_with(&ds, &mut t, &mut state, 0, &mut Control::default(), |_| {}).unwrap();
    let cam = &ds.test.first().unwrap_or(&ds.train[0]).camera;
    let (drawn, _) = t.render(cam);
    let exported = t.exported();
    assert!(exported.extra.column(transsplat_train::filter3d::EXTRA_NAME).is_none());
    let mut splats = Splats::new(&exported);
    splats.active_sh_degree = t.active_sh_degree;
    let (baked, _) = render(&splats, cam, &t.render_options());
    let worst = drawn.rgb.iter().zip(&baked.rgb).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(worst < 1e-5, "baked scene differs by {worst}");
    let mut raw = Splats::new(&t.model.gaussians);
    raw.active_sh_degree = t.active_sh_degree;
    let (unfiltered, _) = render(&raw, cam, &t.render_options());
    let moved = drawn.rgb.iter().zip(&unfiltered.rgb).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(moved > 1e-3, "the filter changed nothing ({moved})");
}

fn resumes_bit_identically(opts: FitOptions) {
    let ds = dataset();
    let (mut whole, mut state) = fresh(&ds, &opts);
    let mut densified = 0;
    fit_with(&ds, &mut whole, &mut state, 0, &mut Control::default(), |p| {
        densified += p.last.densified.is_some() as usize
    })
    .unwrap();
    assert!(densified >= 3, "densification must run inside the test span");
    let dir = tempfile::tempdir().unwrap();
    let ckdir = dir.path().join("ck");

    // Stop after step 27 (a checkpoint at 10 and 20 on the way, a final one at 27).
    let (mut t, mut state) = fresh(&ds, &opts);
    let mut control = Control {
        checkpoint: Some(checkpointer(&ckdir, &ds, &opts)),
        stop_after: Some(27),
        ..Default::default()
    };
    let e = fit_with(&ds, &mut t, &mut state, 0, &mut control, |_| {}).unwrap_err();
    assert!(matches!(e, TrainError::Interrupted { step: 27 }), "{e}");
    assert_eq!(control.checkpoint.as_ref().unwrap().last, Some(27));
    drop(t);

    // Resume in a fresh trainer and finish.
    let mut ck = checkpointer(&ckdir, &ds, &opts);
    let (mut t, mut state) = ck.load_train(opts.config.clone()).unwrap();
    t.attach_filter(&ds.cameras); // as the session does; nothing without the filter
    assert_eq!(t.step, 27);
    let mut control = Control { checkpoint: Some(ck), ..Default::default() };
    fit_with(&ds, &mut t, &mut state, 0, &mut control, |_| {}).unwrap();
    assert_eq!(control.checkpoint.as_ref().unwrap().last, Some(40), "periodic checkpoints continue");

    assert_eq!(t.step, whole.step);
    assert!(t.model.len() != ds.points.as_ref().unwrap().len(), "the Gaussian count changed on the way");
    let (a, b) = (&t.model.gaussians, &whole.model.gaussians);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    assert_eq!(bits(a.means.as_flattened()), bits(b.means.as_flattened()));
    assert_eq!(bits(a.log_scales.as_flattened()), bits(b.log_scales.as_flattened()));
    assert_eq!(bits(a.rotations.as_flattened()), bits(b.rotations.as_flattened()));
    assert_eq!(bits(&a.opacity_logits), bits(&b.opacity_logits));
    assert_eq!(bits(&a.sh), bits(&b.sh));
    assert_eq!(a.extra.names, b.extra.names);
    assert_eq!(bits(&a.extra.values), bits(&b.extra.values));
    let (ra, rb) = (t.render(&ds.train[0].camera).0, whole.render(&ds.train[0].camera).0);
    assert_eq!(bits(&ra.rgb), bits(&rb.rgb));
    assert_eq!(t.adam, whole.adam);
    assert_eq!(t.stats, whole.stats);
    assert_eq!(t.active_sh_degree, whole.active_sh_degree);
}

#[test]
fn checkpoints_of_other_runs_and_damaged_files_are_refused() {
    let ds = dataset();
    let opts = options();
    let dir = tempfile::tempdir().unwrap();
    let ckdir = dir.path().join("ck");
    stopped_at(&ds, &opts, &ckdir, 3);

    // Other settings: the message names the differing line.
    let mut other = options();
    other.config.lambda_dssim = 0.3;
    let e = checkpointer(&ckdir, &ds, &other).load_train(other.config.clone()).unwrap_err().to_string();
    assert!(
        e.contains("other settings") && e.contains("lambda_dssim: 0.2") && e.contains("lambda_dssim: 0.3"),
        "{e}"
    );
    // Other inputs: one pixel changed.
    let mut ds2 = ds.clone();
    ds2.train[2].image[7] += 0.25;
    let e = checkpointer(&ckdir, &ds2, &opts).load_train(opts.config.clone()).unwrap_err().to_string();
    assert!(e.contains("other inputs") && e.contains(TRAIN_FILE), "{e}");
    // Truncated: an error naming the file.
    let file = ckdir.join(TRAIN_FILE);
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, &bytes[..bytes.len() / 2]).unwrap();
    let e = checkpointer(&ckdir, &ds, &opts).load_train(opts.config.clone()).unwrap_err().to_string();
    assert!(e.contains(&file.display().to_string()) && e.contains("truncated"), "{e}");
    // Missing.
    std::fs::remove_file(&file).unwrap();
    let e = checkpointer(&ckdir, &ds, &opts).load_train(opts.config.clone()).unwrap_err().to_string();
    assert!(e.contains("no checkpoint"), "{e}");
}

#[test]
fn a_poisoned_learning_rate_stops_naming_the_step_and_group() {
    let ds = dataset();
    let mut opts = options();
    // Finite but absurd: the scales overflow to infinity within two updates.
    opts.config.lr.scaling = 3e38;
    let (mut t, mut state) = fresh(&ds, &opts);
    let e = fit_with(&ds, &mut t, &mut state, 0, &mut Control::default(), |_| {}).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, TrainError::NonFinite { step: 1 | 2, .. }), "{msg}");
    assert!(msg.contains("scales") && msg.contains("NaN or infinite"), "{msg}");
    // NaN learning rate on the opacities, poisoned after the start (a NaN setting is
    // refused by TrainConfig::validate before it): caught at step 1 after the update.
    let opts = options();
    let (mut t, mut state) = fresh(&ds, &opts);
    t.config.lr.opacity = f32::NAN;
    let e = fit_with(&ds, &mut t, &mut state, 0, &mut Control::default(), |_| {}).unwrap_err().to_string();
    assert!(e.starts_with("step 1: the opacities became NaN"), "{e}");
    // The output writer refuses such a model.
    let dir = tempfile::tempdir().unwrap();
    let e = transsplat_train::write_output(dir.path(), &t, &ds.cameras).unwrap_err().to_string();
    assert!(e.contains("opacities") && e.contains("not written"), "{e}");
    assert!(!dir.path().join("point_cloud").exists());
}

#[test]
fn a_failure_after_a_checkpoint_leaves_it_loadable_and_says_so() {
    let ds = dataset();
    let opts = options();
    let dir = tempfile::tempdir().unwrap();
    let ckdir = dir.path().join("ck");
    let (mut t, mut state, mut control) = stopped_at(&ds, &opts, &ckdir, 20);
    // Poison the run in flight: the rotations' learning rate becomes NaN at step 21.
    control.stop_after = None;
    t.config.lr.rotation = f32::NAN;
    let e = fit_with(&ds, &mut t, &mut state, 0, &mut control, |_| {}).unwrap_err().to_string();
    assert!(e.starts_with("step 21: the rotations became NaN or infinite"), "{e}");
    let note = control.note();
    assert!(
        note.contains("last good checkpoint (step 20)") && note.contains(&ckdir.display().to_string()),
        "{note}"
    );
    let (good, _) = checkpointer(&ckdir, &ds, &opts).load_train(opts.config.clone()).unwrap();
    assert_eq!(good.step, 20);
    assert!(transsplat_train::checkpoint::non_finite_parameters(&good.model).is_none());
}
