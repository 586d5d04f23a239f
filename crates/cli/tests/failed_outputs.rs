//! Output folders appear only when complete, whatever the failure: a stopped or failed
//! `train` (stop request, missing checkpoint, no initial points, NaN) and a write that
//! fails part-way (a full disk, simulated with a file-size limit: `ulimit -f` with
//! SIGXFSZ ignored makes every write past the limit fail, as ENOSPC would) leave no
//! output folder and no staging folder, and a rerun works without cleanup. Training
//! masks are used only when asked for, and the log says which.

mod common;
use common::*;
use std::path::Path;
use std::process::{Command, Output};

/// Runs the binary with `args` in `dir` under a file-size limit of `kib` KiB.
fn limited(dir: &Path, kib: u32, args: &[&str]) -> Output {
    let quoted: Vec<String> = args.iter().map(|a| format!("'{a}'")).collect();
    let script = format!(
        "trap '' XFSZ; ulimit -f {kib}; exec '{}' {}",
        env!("CARGO_BIN_EXE_transsplat"),
        quoted.join(" ")
    );
    Command::new("bash").current_dir(dir).args(["-c", &script]).output().unwrap()
}

/// Asserts exit 2, and that neither `dir/out` nor a staging folder for it exists.
fn nothing_left(dir: &Path, out: &str, o: &Output, words: &[&str]) {
    assert_eq!(o.status.code(), Some(2), "{}", text(o));
    let err = String::from_utf8_lossy(&o.stderr);
    for w in words {
        assert!(err.contains(w), "expected {w:?} in {err}");
    }
    assert!(!dir.join(out).exists(), "{out} was left behind: {err}");
    let partial = format!(".{out}.partial-");
    let left: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(&partial))
        .collect();
    assert!(left.is_empty(), "staging folders left: {left:?}");
}

const TRAIN: [&str; 7] = ["train", "--data", "data", "--iters", "6", "--resolution", "8"];

#[test]
fn failed_and_stopped_training_leaves_no_output_folder() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    quick_scene_in(d, "data");
    let train = |extra: &[&str]| bin().current_dir(d).args(TRAIN).args(extra).output().unwrap();

    let o = train(&["--checkpoint-every", "0", "--stop-after", "3", "--out", "t"]);
    nothing_left(d, "t", &o, &["interrupted after step 3; nothing was written"]);
    let o = train(&["--resume", "nowhere", "--out", "t"]);
    nothing_left(d, "t", &o, &["nowhere", "no checkpoint"]);
    let o = train(&["--random-points", "20000000", "--out", "t"]);
    nothing_left(d, "t", &o, &["--random-points must be at most 10000000"]);
    let o = train(&["--opacity-lr", "3e38", "--out", "t"]);
    nothing_left(d, "t", &o, &["NaN or infinite", "no scene was written"]);

    // No point cloud and no random points.
    std::fs::remove_file(d.join("data/sparse/0/points3D.txt")).unwrap();
    let o = train(&["--random-points", "0", "--out", "t"]);
    nothing_left(d, "t", &o, &["no initial Gaussians"]);

    // A write that fails part-way (the PLY is far above 64 KiB).
    let mut args = TRAIN.to_vec();
    args.extend(["--random-points", "2000", "--out", "t"]);
    nothing_left(d, "t", &limited(d, 64, &args), &["point_cloud.ply"]);

    // The rerun works without cleanup, and a second rerun replaces the first output.
    for _ in 0..2 {
        ok(&train(&["--random-points", "2000", "--out", "t"]));
        let summary: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.join("t/train.json")).unwrap()).unwrap();
        assert_eq!(summary["steps"], 6);
        assert!(d.join("t/point_cloud/iteration_6/point_cloud.ply").is_file());
    }
}

#[test]
fn render_views_edit_and_scene_on_a_full_disk_leave_nothing_and_rerun() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    quick_scene_in(d, "data");
    let render = ["render", "--scene", "data", "--out", "r"];
    nothing_left(d, "r", &limited(d, 4, &render), &[".png"]);
    ok(&bin().current_dir(d).args(render).output().unwrap());
    assert!(d.join("r/render.json").is_file());

    let export = ["views", "export", "--scene", "data", "--out", "v"];
    nothing_left(d, "v", &limited(d, 4, &export), &[".png"]);
    ok(&bin().current_dir(d).args(export).output().unwrap());
    assert!(d.join("v/views.json").is_file());

    let edit = ["edit", "--scene", "data", "--prompt", "make the ball blue", "--editor", "simulated"];
    let edit: Vec<&str> =
        edit.into_iter().chain(["--steps", "5", "--checkpoint-every", "0", "--out", "e"]).collect();
    nothing_left(d, "e", &limited(d, 4, &edit), &[]);
    ok(&bin().current_dir(d).args(&edit).output().unwrap());
    assert!(d.join("e/transport.json").is_file());

    let scene = ["scene", "tabletop", "--quick", "--out", "s"];
    nothing_left(d, "s", &limited(d, 4, &scene), &[]);
    ok(&bin().current_dir(d).args(scene).output().unwrap());
    assert!(d.join("s/labels.json").is_file());
}

#[test]
fn training_masks_are_used_only_when_asked_for() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    quick_scene_in(d, "data");
    // The built-in dataset carries masks/ (object labels): not used unless asked for.
    let o = bin().current_dir(d).args(TRAIN).args(["--out", "plain"]).output().unwrap();
    ok(&o);
    assert!(String::from_utf8_lossy(&o.stderr).contains("not used as training masks"), "{}", text(&o));
    let plain: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("plain/train.json")).unwrap()).unwrap();
    assert!(plain["test_psnr"].as_f64().is_some() && plain["test_psnr_masked"].is_null(), "{plain}");

    let o =
        bin().current_dir(d).args(TRAIN).args(["--masks", "data/masks", "--out", "masked"]).output().unwrap();
    ok(&o);
    assert!(String::from_utf8_lossy(&o.stderr).contains("training masks from data/masks"), "{}", text(&o));
    let masked: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("masked/train.json")).unwrap()).unwrap();
    // Whole-image and in-mask PSNR are both reported, and differ.
    let (whole, inside) =
        (masked["test_psnr"].as_f64().unwrap(), masked["test_psnr_masked"].as_f64().unwrap());
    assert!(whole.is_finite() && inside.is_finite() && whole != inside, "{masked}");

    let o = bin().current_dir(d).args(TRAIN).args(["--masks", "nowhere", "--out", "x"]).output().unwrap();
    nothing_left(d, "x", &o, &["nowhere", "no mask for camera"]);
}
