//! End-to-end tests of `transsplat edit`, `transsplat views export` + the folder
//! editor, and `transsplat demo --quick` through the binary.

mod common;
use common::*;

#[test]
fn simulated_edit_writes_the_scene_renders_and_report() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let out = dir.path().join("edit");
    let o = bin()
        .args(["edit", "--scene"])
        .arg(&ds)
        .args(["--prompt", "make the ball blue", "--editor", "simulated", "--steps", "60", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    ok(&o);
    let g = transsplat_scene::ply::read(&out.join("point_cloud/iteration_60/point_cloud.ply")).unwrap();
    assert!(g.extra.names.iter().filter(|n| n.starts_with("sem_")).count() == 16, "{:?}", g.extra.names);
    assert!(g.extra.names.iter().any(|n| n == "label"));
    for f in [
        "report.html",
        "transport.json",
        "cameras.json",
        "renders/after_view_000.png",
        "renders/gate_view_000.png",
    ] {
        assert!(out.join(f).is_file(), "missing {f}");
    }
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("transport.json")).unwrap()).unwrap();
    let rounds = stats["rounds"].as_array().unwrap();
    assert!(!rounds.is_empty() && rounds[0]["objective"].as_f64().unwrap().is_finite());
    // A second run may replace its own output; a foreign folder is refused.
    let foreign = dir.path().join("foreign");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("keep.txt"), b"mine").unwrap();
    let o = bin()
        .args(["edit", "--scene"])
        .arg(&ds)
        .args(["--prompt", "make the ball blue", "--editor", "simulated", "--steps", "5", "--out"])
        .arg(&foreign)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(std::fs::read(foreign.join("keep.txt")).unwrap(), b"mine");
}

#[test]
fn bad_edit_inputs_exit_2_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let out = dir.path().join("edit");
    let cases: [(&[&str], &str); 4] = [
        (&["--prompt", "make the unicorn blue", "--editor", "simulated"], "ball, crate"),
        (&["--prompt", " ", "--editor", "simulated"], "empty"),
        (&["--prompt", "make the ball blue", "--editor", "folder"], "--edits"),
        (
            &["--prompt", "make the ball blue", "--editor", "folder", "--edits", "/nonexistent-edits"],
            "nonexistent-edits",
        ),
    ];
    for (args, needle) in cases {
        let o = bin().args(["edit", "--scene"]).arg(&ds).args(args).arg("--out").arg(&out).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?} left an output folder");
    }
}

/// The exported renders handed back unedited: exit 2 saying so, nothing written; with
/// `--views auto` the seeds already say there is no target.
#[test]
fn unedited_views_mean_nothing_to_edit() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let views = dir.path().join("views");
    ok(&bin().args(["views", "export", "--scene"]).arg(&ds).arg("--out").arg(&views).output().unwrap());
    for (choice, says) in
        [("all", "found nothing to edit"), ("auto", "--views auto: the editor marked no target")]
    {
        let out = dir.path().join(format!("edit-{choice}"));
        let o = bin()
            .args(["edit", "--scene"])
            .arg(&ds)
            .args(["--prompt", "make it nicer", "--editor", "folder", "--views", choice, "--edits"])
            .arg(&views)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(says), "{choice}: {err}");
        assert!(!out.exists());
    }
}

#[test]
fn exported_views_edited_elsewhere_come_back_through_the_folder_editor() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let views = dir.path().join("views");
    ok(&bin().args(["views", "export", "--scene"]).arg(&ds).arg("--out").arg(&views).output().unwrap());
    // "Edit" the exports elsewhere: every view's right half turned blue.
    assert!(!tint(&views).is_empty());
    let out = dir.path().join("edit");
    ok(&bin()
        .args(["edit", "--scene"])
        .arg(&ds)
        .args(["--prompt", "make the right side blue", "--editor", "folder", "--steps", "30", "--edits"])
        .arg(&views)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap());
    assert!(out.join("point_cloud/iteration_30/point_cloud.ply").is_file());
}

#[test]
fn quick_demo_writes_metrics_for_every_method_and_transsplat_leaks_less_than_naive() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    ok(&bin().args(["demo", "--quick", "--out"]).arg(&out).output().unwrap());
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    for name in ["transsplat", "paper", "naive", "masklift", "no_leaksup", "no_prototype", "geometric"] {
        let e = &m["methods"][name];
        for k in ["target_psnr", "background_psnr", "psnr", "ssim", "seconds"] {
            assert!(e[k].as_f64().is_some_and(f64::is_finite), "{name}.{k}");
        }
        assert!(e.get("gate_auroc").is_some(), "{name}.gate_auroc");
    }
    let bg = |n: &str| m["methods"][n]["background_psnr"].as_f64().unwrap();
    assert!(bg("transsplat") > bg("naive") + 1.0, "transsplat {} vs naive {}", bg("transsplat"), bg("naive"));
    assert!(m["methods"]["transsplat"]["gate_auroc"].as_f64().unwrap() > 0.9);
    assert!(out.join("report.html").is_file());
    // Each method's folder is an edit output folder (the same writer as `transsplat edit`).
    for f in ["point_cloud/iteration_150/point_cloud.ply", "renders/after_view_000.png", "transport.json"] {
        assert!(out.join("transsplat").join(f).is_file(), "transsplat/{f}");
    }
}

#[test]
fn quick_demo_honours_an_explicit_step_count() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    ok(&bin()
        .args(["demo", "--quick", "--methods", "naive", "--set", "schedule.steps=30", "--out"])
        .arg(&out)
        .output()
        .unwrap());
    assert!(
        out.join("naive/point_cloud/iteration_30/point_cloud.ply").is_file(),
        "the --set wins over --quick"
    );
}

/// `--views K`: the editor edits K of the edit views, and the edit still lands.
#[test]
fn views_k_edits_only_k_views() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let out = dir.path().join("edit");
    let o = bin()
        .args(["edit", "--scene"])
        .arg(&ds)
        .args(["--prompt", "make the ball blue", "--editor", "simulated", "--steps", "30", "--views", "3"])
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    ok(&o);
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(log.contains("editor simulated edited 3 views"), "{log}");
    assert!(out.join("transport.json").is_file());
}

/// `--views auto`: the editor edits a quarter of the views as seeds, then more while the
/// target's edit is uncertain: a consistent editor (severity 0) stops before every view,
/// an inconsistent one (severity 2) gets more views; the edit lands either way.
#[test]
fn views_auto_edits_seeds_and_what_the_target_needs() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let cams = transsplat_scene::cameras::load(&ds.join("cameras.json")).unwrap();
    let edit_views = transsplat_scene::cameras::split_views(cams.len()).1.len();
    let chosen = |severity: &str| -> (usize, usize) {
        let out = dir.path().join(format!("edit{severity}"));
        let o = bin()
            .args(["edit", "--scene"])
            .arg(&ds)
            .args(["--prompt", "make the ball blue", "--editor", "simulated", "--severity", severity])
            .args(["--steps", "30", "--views", "auto", "--out"])
            .arg(&out)
            .output()
            .unwrap();
        ok(&o);
        assert!(out.join("transport.json").is_file());
        let log = String::from_utf8_lossy(&o.stderr).into_owned();
        let line = log.lines().find(|l| l.contains("seed views,")).unwrap_or_else(|| panic!("{log}"));
        let numbers: Vec<usize> =
            line.split(|c: char| !c.is_ascii_digit()).filter_map(|t| t.parse().ok()).collect();
        // "--views auto: S seed views, A added in R rounds (E of T edit views)"
        let n = numbers.len();
        assert_eq!(numbers[n - 1], edit_views, "{line}");
        (numbers[n - 5], numbers[n - 2])
    };
    let (seeds, consistent) = chosen("0");
    assert_eq!(seeds, edit_views.div_ceil(4));
    assert!(consistent >= seeds && consistent < edit_views, "severity 0 edited {consistent} of {edit_views}");
    let (_, inconsistent) = chosen("2");
    assert!(inconsistent > consistent, "severity 2 edited {inconsistent}, severity 0 {consistent}");
}
