//! Parity with the independent oracle: gsplat 1.5's PyTorch projection and SH plus a
//! dense PyTorch compositor with the same skip and stop rules, gradients by autograd
//! (fixtures written by `tools/raster_fixtures.py`, float64 reference).

use std::path::{Path, PathBuf};
use transsplat_raster::{
    backward, gaussian_stats, render, ClampGrad, Grads, ImageGrads, RenderOptions, Splats,
};
use transsplat_scene::{npy, Camera, Gaussians};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

fn load(dir: &Path, name: &str) -> npy::Array {
    npy::read(&dir.join(format!("{name}.npy"))).unwrap_or_else(|e| panic!("{e}"))
}

fn load_opt(dir: &Path, name: &str) -> Vec<f32> {
    let p = dir.join(format!("{name}.npy"));
    if p.exists() {
        npy::read(&p).unwrap().data
    } else {
        Vec::new()
    }
}

struct Fixture {
    name: String,
    dir: PathBuf,
    g: Gaussians,
    feats: Vec<f32>,
    nf: usize,
    cam: Camera,
    bg: [f32; 3],
}

fn fixture(name: &str) -> Fixture {
    let dir = fixtures().join(name);
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("meta.json")).unwrap()).unwrap();
    let f = |k: &str| meta[k].as_f64().unwrap_or_else(|| panic!("{name}: meta.{k}")) as f32;
    let vm: Vec<Vec<f32>> = meta["viewmat"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r.as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect())
        .collect();
    let cam = Camera {
        name: name.into(),
        width: meta["width"].as_u64().unwrap() as u32,
        height: meta["height"].as_u64().unwrap() as u32,
        fx: f("fx"),
        fy: f("fy"),
        cx: f("cx"),
        cy: f("cy"),
        rotation: std::array::from_fn(|i| std::array::from_fn(|j| vm[i][j])),
        translation: std::array::from_fn(|i| vm[i][3]),
    };
    let bg: Vec<f32> =
        meta["background"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect();
    let sh_degree = meta["sh_degree"].as_u64().unwrap() as u32;
    let nf = meta["num_features"].as_u64().unwrap() as usize;
    let v3 = |a: npy::Array| a.data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
    let g = Gaussians {
        means: v3(load(&dir, "means")),
        log_scales: v3(load(&dir, "log_scales")),
        rotations: load(&dir, "quats").data.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect(),
        opacity_logits: load(&dir, "opacity_logits").data,
        sh_degree,
        sh: load(&dir, "sh").data,
        extra: Default::default(),
    };
    g.validate().unwrap();
    let feats = load_opt(&dir, "features");
    Fixture { name: name.into(), dir, g, feats, nf, cam, bg: [bg[0], bg[1], bg[2]] }
}

/// max |a − b| ≤ atol + rtol · max |b|, reporting the worst element.
fn close(what: &str, a: &[f32], b: &[f32], atol: f32, rtol: f32) {
    assert_eq!(a.len(), b.len(), "{what}: length");
    let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let (mut worst, mut at) = (0.0f32, 0);
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        let e = (x - y).abs();
        if e > worst || e.is_nan() {
            worst = e;
            at = i;
        }
    }
    let tol = atol + rtol * scale;
    if std::env::var_os("ORACLE_VERBOSE").is_some() {
        eprintln!("{what}: max error {worst:.3e} (scale {scale:.3e}, tolerance {tol:.3e})");
    }
    assert!(
        worst <= tol,
        "{what}: max error {worst} at {at} (ours {}, oracle {}), tolerance {tol}",
        a[at],
        b[at]
    );
}

fn cases() -> Vec<String> {
    let index: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(fixtures().join("index.json")).expect("fixtures/index.json"),
    )
    .unwrap();
    let cases: Vec<String> =
        index["cases"].as_array().unwrap().iter().map(|c| c.as_str().unwrap().into()).collect();
    assert!(cases.len() >= 8, "expected at least 8 oracle cases");
    cases
}

#[test]
fn forward_matches_oracle() {
    for name in cases() {
        let fx = fixture(&name);
        let s = Splats::new(&fx.g).with_features(&fx.feats, fx.nf);
        let (img, _) = render(&s, &fx.cam, &RenderOptions { background: fx.bg });
        let n = &fx.name;
        close(&format!("{n} rgb"), &img.rgb, &load(&fx.dir, "rgb").data, 1e-5, 0.0);
        close(&format!("{n} alpha"), &img.alpha, &load(&fx.dir, "alpha").data, 1e-5, 0.0);
        close(&format!("{n} depth"), &img.depth, &load(&fx.dir, "depth").data, 1e-5, 2e-4);
        if fx.nf > 0 {
            close(&format!("{n} features"), &img.features, &load(&fx.dir, "features_out").data, 1e-5, 1e-5);
        }
    }
}

#[test]
fn stats_and_splat_back_match_oracle() {
    for name in cases() {
        let fx = fixture(&name);
        let s = Splats::new(&fx.g);
        let splat_in = load(&fx.dir, "splat_in");
        let c = *splat_in.shape.last().unwrap();
        let st = gaussian_stats(&s, &fx.cam, Some((&splat_in.data, c)));
        let n = &fx.name;
        let count: Vec<f32> = st.pixel_count.iter().map(|&v| v as f32).collect();
        close(&format!("{n} pixel_count"), &count, &load(&fx.dir, "pixel_count").data, 0.0, 0.0);
        close(&format!("{n} weight_sum"), &st.weight_sum, &load(&fx.dir, "weight_sum").data, 1e-4, 1e-4);
        close(&format!("{n} alpha_sum"), &st.alpha_sum, &load(&fx.dir, "alpha_sum").data, 1e-4, 1e-4);
        close(&format!("{n} visibility"), &st.visibility, &load(&fx.dir, "visibility").data, 1e-4, 0.0);
        close(&format!("{n} splat-back"), &st.splat, &load(&fx.dir, "splat_out").data, 1e-4, 1e-4);
        let visible: Vec<bool> =
            load(&fx.dir, "radii").data.chunks(2).map(|r| r[0] > 0.0 || r[1] > 0.0).collect();
        let m2d: Vec<f32> =
            st.means2d.iter().zip(&visible).flat_map(|(m, &v)| if v { *m } else { [0.0; 2] }).collect();
        let want: Vec<f32> = load(&fx.dir, "means2d")
            .data
            .chunks(2)
            .zip(&visible)
            .flat_map(|(m, &v)| if v { [m[0], m[1]] } else { [0.0; 2] })
            .collect();
        close(&format!("{n} means2d"), &m2d, &want, 1e-3, 1e-5);
        let (_, frame) = render(&s, &fx.cam, &RenderOptions { background: fx.bg });
        let radii: Vec<f32> = frame.radii().iter().flat_map(|r| [r[0] as f32, r[1] as f32]).collect();
        close(&format!("{n} radii"), &radii, &load(&fx.dir, "radii").data, 0.0, 0.0);
    }
}

#[test]
fn backward_matches_oracle() {
    for name in cases() {
        let fx = fixture(&name);
        let s = Splats::new(&fx.g).with_features(&fx.feats, fx.nf);
        let (_, frame) = render(&s, &fx.cam, &RenderOptions { background: fx.bg });
        let (vr, va, vd) =
            (load(&fx.dir, "v_rgb").data, load(&fx.dir, "v_alpha").data, load(&fx.dir, "v_depth").data);
        let vf = load_opt(&fx.dir, "v_features");
        let mut grads = Grads::zeros(fx.g.len(), fx.g.sh_degree, fx.nf);
        backward(
            &s,
            &fx.cam,
            &frame,
            &ImageGrads { rgb: &vr, alpha: &va, depth: &vd, features: &vf, clamp: ClampGrad::Exact },
            &mut grads,
        );
        let n = &fx.name;
        let flat = |v: &[[f32; 3]]| v.iter().flatten().copied().collect::<Vec<_>>();
        let (a, r) = (1e-6, 1e-4);
        close(&format!("{n} grad means"), &flat(&grads.means), &load(&fx.dir, "grad_means").data, a, r);
        close(
            &format!("{n} grad log_scales"),
            &flat(&grads.log_scales),
            &load(&fx.dir, "grad_log_scales").data,
            a,
            r,
        );
        let q: Vec<f32> = grads.rotations.iter().flatten().copied().collect();
        close(&format!("{n} grad quats"), &q, &load(&fx.dir, "grad_quats").data, a, r);
        close(
            &format!("{n} grad opacity"),
            &grads.opacity_logits,
            &load(&fx.dir, "grad_opacity_logits").data,
            a,
            r,
        );
        close(&format!("{n} grad sh"), &grads.sh, &load(&fx.dir, "grad_sh").data, a, r);
        if fx.nf > 0 {
            close(&format!("{n} grad features"), &grads.features, &load(&fx.dir, "grad_features").data, a, r);
        }
        let m2: Vec<f32> = grads.means2d.iter().flatten().copied().collect();
        close(&format!("{n} grad means2d"), &m2, &load(&fx.dir, "grad_means2d").data, a, r);
    }
}
