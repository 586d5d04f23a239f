//! `transsplat bench raster --scene` and `bench edit` through the binary (quick sizes:
//! what is checked is that they run on the given input and report every stage).

mod common;
use common::*;

/// The JSON line a bench prints last.
fn json_line(o: &std::process::Output) -> serde_json::Value {
    let out = String::from_utf8_lossy(&o.stdout);
    let line = out.lines().rev().find(|l| l.starts_with('{')).unwrap_or_else(|| panic!("{}", text(o)));
    serde_json::from_str(line).unwrap()
}

#[test]
fn bench_raster_times_a_given_scene_and_camera() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let o = bin()
        .args(["bench", "raster", "--reps", "1", "--camera", "view_003", "--scene"])
        .arg(&ds)
        .output()
        .unwrap();
    ok(&o);
    let j = json_line(&o);
    let g = transsplat_scene::ply::read(&ds.join("point_cloud/iteration_0/point_cloud.ply")).unwrap();
    assert_eq!(j["gaussians"].as_u64(), Some(g.len() as u64), "the given scene, not the synthetic one");
    assert_eq!((j["width"].as_u64(), j["height"].as_u64()), (Some(128), Some(96)), "the camera's size");
    for k in ["forward_s", "backward_s", "backward_reused_s", "splat_back_s"] {
        assert!(j[k].as_f64().is_some_and(|v| v > 0.0), "{k}");
    }
    let o = bin().args(["bench", "raster", "--camera", "nope", "--scene"]).arg(&ds).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("cameras.json: no camera \"nope\""), "{}", text(&o));
}

#[test]
fn bench_edit_reports_every_stage() {
    let o = bin().args(["bench", "edit", "--size", "quick", "--steps", "10"]).output().unwrap();
    ok(&o);
    let j = json_line(&o);
    assert_eq!(j["steps"].as_u64(), Some(10));
    let stages = j["timing"]["stages"].as_object().unwrap();
    for k in ["binning", "tiles", "image_loss", "backward", "method_terms", "optimiser", "checkpoint"] {
        assert!(stages[k].as_f64().is_some(), "{k}");
    }
    assert!(j["metrics"]["target_psnr"].as_f64().is_some_and(f64::is_finite));
    assert_eq!(
        (j["editor"].as_str(), j["edit_views"].as_u64(), j["candidate_views"].as_u64()),
        (Some("simulated"), Some(14), Some(14))
    );
    // `--views` reaches the job: the editor edits 5 of the 14 views.
    let o =
        bin().args(["bench", "edit", "--size", "quick", "--steps", "10", "--views", "5"]).output().unwrap();
    ok(&o);
    assert_eq!(json_line(&o)["edit_views"].as_u64(), Some(5));
    let o = bin().args(["bench", "edit", "--size", "huge"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("sizes are: a, b, c, quick"), "{}", text(&o));
}

/// The suite's default is the small one: one severity-0 trained case runs through the
/// binary (training, the retrained reference, one method) and reports its source
/// fidelity; an unknown case name and `--full` with `--quick` are errors.
#[test]
fn bench_quality_runs_a_trained_case_and_rejects_bad_cases() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("q");
    let o = bin()
        .args(["bench", "quality", "--trained", "300", "--methods", "naive"])
        .args(["--cases", "tabletop-trained-recolour-s0", "--set", "schedule.steps=10", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    ok(&o);
    let j: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("quality.json")).unwrap()).unwrap();
    let case = &j["cases"][0];
    assert_eq!(case["name"], "tabletop-trained-recolour-s0");
    assert!(case["source_fidelity"].as_f64().is_some_and(|v| v > 12.0), "{case}");
    assert!(case["retrained"].as_f64().is_some_and(|v| v > 12.0), "{case}");
    let md = std::fs::read_to_string(out.join("quality.md")).unwrap();
    assert!(
        md.contains("| tabletop-trained-recolour-s0 |") && md.contains("retrained on the true edit"),
        "{md}"
    );
    let o = bin().args(["bench", "quality", "--cases", "nope"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("tabletop-built-recolour-s1"), "{}", text(&o));
    let o = bin().args(["bench", "quality", "--full", "--quick"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
}

#[test]
fn bench_train_times_every_step_rule_and_both_strategies() {
    let o = bin()
        .args(["bench", "train", "--gaussians", "3000", "--sizes", "32", "--reps", "1"])
        .output()
        .unwrap();
    ok(&o);
    let j = json_line(&o);
    assert_eq!(j["gaussians"].as_u64(), Some(3000));
    for k in [
        "forward_backward_s",
        "step_s",
        "step_selective_s",
        "step_mcmc_s",
        "adam_s",
        "densify_s",
        "relocate_s",
    ] {
        assert!(j[k].as_f64().is_some_and(|v| v > 0.0), "{k}: {j}");
    }
}
