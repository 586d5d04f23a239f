//! The benchmark on a trained scene: a built-in scene trained from its own renders
//! reproduces the truth on the held-out views, and `demo` with `trained` edits that
//! scene (not the built-in Gaussians) and scores it against the same ground truth.

use transsplat_bench::demo::{self, DemoOptions};
use transsplat_bench::trained::train_from_renders;
use transsplat_builtin::{build, is_test, SceneConfig};
use transsplat_edit::{EditConfig, Method};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_train::psnr as psnr_of;

#[test]
fn a_scene_trained_from_its_renders_matches_the_truth_on_test_views() {
    let scene = build("tabletop", &SceneConfig::quick()).unwrap();
    let work = tempfile::tempdir().unwrap();
    let (g, psnr) = train_from_renders(&scene, 600, 0, work.path(), None, &mut |_, _| {}).unwrap();
    assert!(psnr > 20.0, "test PSNR {psnr}");
    assert!(!g.is_empty() && g.len() != scene.gaussians.len());
    // The returned scene is what the trainer scored (its 3D filter baked in): rendered
    // at the held-out views it reaches the same PSNR against the truth.
    let opts = RenderOptions { background: scene.background };
    let tests: Vec<f32> = (scene.cameras.iter().enumerate().filter(|(k, _)| is_test(*k)))
        .map(|(_, cam)| {
            let truth = render(&Splats::new(&scene.gaussians), cam, &opts).0.rgb;
            psnr_of(&render(&Splats::new(&g), cam, &opts).0.rgb, &truth, None)
        })
        .collect();
    let rendered = tests.iter().sum::<f32>() / tests.len() as f32;
    assert!(
        (rendered - psnr).abs() < 0.02,
        "the returned scene renders {rendered:.2} dB, the trainer scored {psnr:.2}"
    );
    assert_eq!(std::fs::read_dir(work.path()).unwrap().count(), 0, "the dataset is removed");
}

#[test]
fn demo_edits_the_trained_scene() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = EditConfig::default();
    config.schedule.steps = 20;
    let opts = DemoOptions {
        out: dir.path().join("demo"),
        quick: true,
        methods: vec![Method::Naive],
        config,
        trained: 300,
        retrain_truth: true,
        ..Default::default()
    };
    let demo::DemoOutcome { out, scores, trained, .. } = demo::run(&opts, None, &mut |_, _| {}).unwrap();
    let metrics: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(metrics["trained_steps"], 300);
    let trained = trained.expect("the trained source's fidelity");
    let retrained = trained.retrained.expect("the scene retrained from the true edit");
    assert!(retrained > 12.0 && retrained.is_finite(), "{retrained}");
    // serde_json's default parser may land one unit in the last place off the printed
    // shortest form (it is not correctly rounded without its `float_roundtrip` feature).
    let same = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(b.abs());
    let written = metrics["trained"]["retrained"].as_f64().unwrap();
    assert!(same(written, retrained), "retrained: metrics.json has {written}, the outcome {retrained}");
    for (k, v) in [
        ("test_psnr", trained.test_psnr),
        ("target_psnr", trained.target_psnr),
        ("background_psnr", trained.background_psnr),
    ] {
        assert!(metrics["trained"][k].as_f64().unwrap() > 12.0, "{k}: {metrics}");
        let written = metrics["trained"][k].as_f64().unwrap();
        assert!(same(written, v), "{k}: metrics.json has {written}, the outcome {v}");
    }
    let built_in = build("tabletop", &SceneConfig::quick()).unwrap().gaussians.len();
    assert_ne!(metrics["gaussians"].as_u64().unwrap() as usize, built_in, "the trained scene is edited");
    // No per-Gaussian labels on a trained scene: no gate AUROC, but the image metrics.
    assert!(scores[0].gate_auroc.is_none() && scores[0].metrics.target_psnr.is_finite());
}
