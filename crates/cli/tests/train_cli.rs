//! End-to-end tests of `transsplat train` through the binary: a built-in quick scene
//! trained briefly into an INRIA folder that `transsplat render` opens, and bad input
//! (exit status 2, one-line error naming the file).

mod common;

use common::{bin, ok, quick_scene_in};
use std::path::Path;
use std::process::Output;

/// `transsplat train ARGS --data DATA --out OUT`.
fn train(data: &Path, out: &Path, args: &[&str]) -> Output {
    bin().arg("train").args(args).arg("--data").arg(data).arg("--out").arg(out).output().unwrap()
}

/// The `train.json` of a finished run.
fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("train.json")).unwrap()).unwrap()
}

#[test]
fn train_on_a_built_in_scene_writes_an_inria_folder() {
    let dir = tempfile::tempdir().unwrap();
    let data = quick_scene_in(dir.path(), "data");
    let out = dir.path().join("out");
    let st = train(&data, &out, &["--iters", "60", "--resolution", "4", "--eval-every", "30"]);
    ok(&st);
    let stdout = String::from_utf8_lossy(&st.stdout);
    let last: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert_eq!(last["steps"], 60);
    assert!(last["test_psnr"].as_f64().unwrap() > 5.0);
    assert!(out.join("point_cloud/iteration_60/point_cloud.ply").is_file());
    assert!(out.join("cameras.json").is_file());
    // Every test view is scored (whole image) and rendered; the mean is their mean.
    let summary = summary(&out);
    let views = summary["per_test_view"].as_array().unwrap();
    assert_eq!(views.len() as u64, summary["test_views"].as_u64().unwrap());
    assert!(views.len() >= 2, "{summary}");
    let mut sum = 0.0;
    for v in views {
        let (psnr, ssim) = (v["psnr"].as_f64().unwrap(), v["ssim"].as_f64().unwrap());
        assert!(psnr.is_finite() && ssim > 0.0 && ssim <= 1.0, "{v}");
        sum += psnr;
        let stem = std::path::Path::new(v["name"].as_str().unwrap()).file_stem().unwrap().to_owned();
        assert!(out.join("test_renders").join(stem).with_extension("png").is_file(), "{v}");
    }
    assert!((sum / views.len() as f64 - summary["test_psnr"].as_f64().unwrap()).abs() < 1e-3);
    let worst = summary["worst_test_view"]["psnr"].as_f64().unwrap();
    assert!(views.iter().all(|v| v["psnr"].as_f64().unwrap() >= worst));
    assert!(summary["train_psnr_sample"].as_f64().unwrap().is_finite());
    // The typed reader of train.json reads what the command wrote.
    let typed = transsplat_train::fit::TrainSummary::read(&out).unwrap();
    assert_eq!((typed.steps, typed.test_views), (60, views.len()));
    assert_eq!(typed.camera_reach, Some(3.33));
    let renders = dir.path().join("renders");
    ok(&bin().args(["render", "--scene"]).arg(&out).arg("--out").arg(&renders).output().unwrap());
    assert!(renders.join("view_001.png").is_file());
}

/// A test PSNR far below the training views' with no test view far below the others
/// (every test image brightened alike, as an exposure change between the held-out
/// photos and the rest would): the warning diagnoses the worst test view, and
/// train.json records that diagnosis on its entry only.
#[test]
fn a_gap_every_test_view_shares_is_diagnosed_by_the_worst() {
    let dir = tempfile::tempdir().unwrap();
    let data = quick_scene_in(dir.path(), "data");
    for stem in ["view_000", "view_008"] {
        let path = data.join("images").join(format!("{stem}.png"));
        let img = transsplat_scene::image::read(&path).unwrap();
        let brighter: Vec<f32> = img.data.iter().map(|v| (v + 0.3).min(1.0)).collect();
        transsplat_scene::image::write_png(&path, img.width, img.height, &brighter).unwrap();
    }
    let out = dir.path().join("out");
    let st = train(&data, &out, &["--iters", "60", "--resolution", "4", "--eval-every", "0"]);
    ok(&st);
    let typed = transsplat_train::fit::TrainSummary::read(&out).unwrap();
    let (test, train) = (typed.test_psnr.unwrap(), typed.train_psnr_sample.unwrap());
    assert!(train - test > 3.0, "{typed:?}");
    let worst = typed.worst_test_view.as_ref().unwrap();
    assert!(typed.per_test_view.iter().all(|v| v.psnr > test - 3.0), "no view is an outlier: {typed:?}");
    // An exposure change puts nothing in front of the training views' depths.
    for v in &typed.per_test_view {
        let want = (v.name == worst.name).then_some("extrapolation");
        assert_eq!(v.cause.as_deref(), want, "{v:?}");
    }
    let stderr = String::from_utf8_lossy(&st.stderr);
    let line = stderr.lines().find(|l| l.contains("below the training views'")).expect("the gap warning");
    assert!(line.contains(&worst.name) && line.contains("not floaters"), "{line}");
}

/// By default the Gaussians on the cloud's surfaces start flat (one scale far below the
/// other two); `--isotropic-init` starts them as INRIA's balls and says so in train.json.
/// One step moves a log-scale by at most about Adam's step (0.005), so the shapes written
/// after it are the initial ones.
#[test]
fn gaussians_start_flat_on_surfaces_unless_asked_for_balls() {
    let dir = tempfile::tempdir().unwrap();
    let data = quick_scene_in(dir.path(), "data");
    let flat_share = |extra: &[&str]| {
        let out = dir.path().join(format!("out{}", extra.len()));
        let mut args = vec!["--iters", "1", "--eval-every", "0"];
        args.extend_from_slice(extra);
        ok(&train(&data, &out, &args));
        let typed = transsplat_train::fit::TrainSummary::read(&out).unwrap();
        let scene = transsplat_scene::ply::read(&typed.scene).unwrap();
        let flat = scene
            .log_scales
            .iter()
            .filter(|s| {
                s.iter().fold(f32::MIN, |a, &b| a.max(b)) - s.iter().fold(f32::MAX, |a, &b| a.min(b)) > 1.0
            })
            .count();
        (flat as f32 / scene.len() as f32, typed.isotropic_init)
    };
    let (share, isotropic) = flat_share(&[]);
    assert!(share > 0.5 && !isotropic, "{share} of the Gaussians start flat by default");
    let (share, isotropic) = flat_share(&["--isotropic-init"]);
    assert!(share == 0.0 && isotropic, "{share} of INRIA's balls are flat");
}

/// `--filter-3d` is recorded in train.json, and the written scene is an ordinary INRIA PLY
/// (the filter baked in, no carried column) whose render of a test view is the one
/// training wrote in `test_renders/`.
#[test]
fn train_with_the_3d_filter_writes_it_baked_in() {
    let dir = tempfile::tempdir().unwrap();
    let data = quick_scene_in(dir.path(), "data");
    let out = dir.path().join("out");
    ok(&train(&data, &out, &["--iters", "40", "--eval-every", "0", "--filter-3d", "0.2"]));
    let typed = transsplat_train::fit::TrainSummary::read(&out).unwrap();
    assert_eq!(typed.filter_3d, Some(0.2));
    let scene = transsplat_scene::ply::read(&typed.scene).unwrap();
    assert!(scene.extra.column(transsplat_train::filter3d::EXTRA_NAME).is_none(), "{:?}", scene.extra.names);
    let renders = dir.path().join("renders");
    ok(&bin().args(["render", "--scene"]).arg(&out).arg("--out").arg(&renders).output().unwrap());
    let name = typed.per_test_view[0].name.clone();
    let stem = Path::new(&name).file_stem().unwrap().to_string_lossy().to_string();
    let read = |p: std::path::PathBuf| transsplat_scene::image::read(&p).unwrap().data;
    let a = read(out.join("test_renders").join(format!("{stem}.png")));
    let b = read(renders.join(format!("{stem}.png")));
    assert_eq!(a.len(), b.len());
    let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
    assert!(worst <= 1.5 / 255.0, "the written scene renders {worst} from training's own render");
}

/// `--strategy mcmc` grows to its budget and says so in train.json; an unknown strategy
/// is refused (status 2) naming the ones there are.
#[test]
fn train_with_the_mcmc_strategy_ends_at_its_budget() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    ok(&bin()
        .args(["scene", "tabletop", "--quick", "--points", "2000", "--out"])
        .arg(&data)
        .output()
        .unwrap());
    let out = dir.path().join("out");
    // Densification runs at steps 600 and 700 (5 % growth each, capped at 1,950 (from about 1,820)).
    let st = train(
        &data,
        &out,
        &[
            "--iters",
            "700",
            "--resolution",
            "4",
            "--eval-every",
            "0",
            "--strategy",
            "mcmc",
            "--max-gaussians",
            "1950",
        ],
    );
    ok(&st);
    let summary = summary(&out);
    assert_eq!(summary["strategy"], "mcmc");
    assert_eq!(summary["gaussians"], 1950, "{summary}");
    assert!(summary["test_psnr"].as_f64().unwrap() > 15.0, "{summary}");
    let st = train(&data, &dir.path().join("out2"), &["--strategy", "splatfacto"]);
    assert_eq!(st.status.code(), Some(2));
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(err.contains("splatfacto") && err.contains("adaptive, mcmc"), "{err}");
}

#[test]
fn bad_datasets_exit_with_status_2_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let data = quick_scene_in(dir.path(), "data");
    let victim = data.join("images/view_003.png");
    std::fs::write(&victim, b"not an image").unwrap();
    let out = dir.path().join("out");
    let st = train(&data, &out, &["--iters", "5"]);
    assert_eq!(st.status.code(), Some(2));
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(err.contains("view_003.png") && err.contains("not a PNG or JPEG"), "{err}");
    std::fs::remove_file(&victim).unwrap();
    let st = train(&data, &out, &["--iters", "5"]);
    assert_eq!(st.status.code(), Some(2));
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(err.contains("view_003") && err.contains("missing"), "{err}");
    let st = train(&dir.path().join("nowhere"), &out, &[]);
    assert_eq!(st.status.code(), Some(2));
}
