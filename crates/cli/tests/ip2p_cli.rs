//! `transsplat edit --editor ip2p`: missing weights are a clear error (folder, expected
//! file, download command; exit 2, nothing written), and the tiny fixture pipeline of
//! the models crate edits a quick scene end to end.

mod common;
use common::*;
use std::path::Path;
use std::process::Output;

fn edit(ds: &Path, out: &Path, extra: &[&str]) -> Output {
    bin()
        .args(["edit", "--scene"])
        .arg(ds)
        .args(["--prompt", "turn the ball into bronze", "--editor", "ip2p", "--steps", "5", "--out"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn missing_ip2p_weights_exit_2_naming_folder_file_and_download() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let out = dir.path().join("edit");

    let o = edit(&ds, &out, &[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o).contains("--ip2p-weights") && text(&o).contains("hf download timbrooks/instruct-pix2pix")
    );

    let missing = dir.path().join("no-such-weights");
    let o = edit(&ds, &out, &["--ip2p-weights", missing.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let t = text(&o);
    assert!(
        t.contains("no-such-weights") && t.contains("hf download timbrooks/instruct-pix2pix --local-dir"),
        "{t}"
    );

    // A folder with the components but no UNet weights names the file expected.
    let weights = dir.path().join("ip2p");
    std::fs::create_dir_all(weights.join("unet")).unwrap();
    std::fs::create_dir_all(weights.join("text_encoder")).unwrap();
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/tests/fixtures/ip2p");
    for f in ["unet/config.json", "text_encoder/config.json", "text_encoder/model.safetensors"] {
        std::fs::copy(fixture.join(f), weights.join(f)).unwrap();
    }
    let o = edit(&ds, &out, &["--ip2p-weights", weights.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let t = text(&o);
    assert!(
        t.contains("unet") && t.contains("diffusion_pytorch_model.safetensors") && t.contains("hf download"),
        "{t}"
    );
    assert!(!out.exists(), "nothing is written on error");
}

#[test]
fn tiny_ip2p_pipeline_edits_a_scene_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let out = dir.path().join("edit");
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/tests/fixtures/ip2p");
    let o = edit(&ds, &out, &["--ip2p-weights", fixture.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let report: serde_json::Value = serde_json::from_slice(
        &std::fs::read(out.join("transport.json")).unwrap_or_else(|e| panic!("{e}: {}", text(&o))),
    )
    .unwrap();
    assert!(report["rounds"].as_array().is_some_and(|r| !r.is_empty()), "{report}");
    assert!(out.join("point_cloud/iteration_5/point_cloud.ply").is_file());
}

/// A stop during the 2D edits (the hidden `--stop-after-views`, as Ctrl-C between views)
/// keeps the finished views; the printed command resumes without editing them again and
/// ends as an uninterrupted edit does (each view's noise and timestep are its own).
#[test]
fn a_stop_during_the_edits_resumes_without_editing_finished_views() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/tests/fixtures/ip2p");
    let weights =
        ["--ip2p-weights", fixture.to_str().unwrap(), "--ip2p-batch", "2", "--checkpoint-every", "2"];
    let whole = dir.path().join("whole");
    let o = edit(&ds, &whole, &weights);
    assert!(o.status.success(), "{}", text(&o));
    let out = dir.path().join("edit");
    let o = edit(&ds, &out, &[&weights[..], &["--stop-after-views", "4"]].concat());
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let t = text(&o);
    assert!(t.contains("interrupted during the 2D edits") && t.contains("4 edited views kept"), "{t}");
    assert!(!out.exists(), "nothing written");
    let cmd = t.split("continue with: ").nth(1).expect("the message gives the command").trim();
    assert!(cmd.contains("--resume") && !cmd.contains("--stop-after-views"), "{cmd}");
    let o = std::process::Command::new("sh").args(["-c", cmd]).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("4 of 14 views kept by the stopped run; 10 to edit"), "{}", text(&o));
    let ply = "point_cloud/iteration_5/point_cloud.ply";
    let read = |d: &Path| std::fs::read(d.join(ply)).unwrap();
    assert!(read(&whole) == read(&out), "the resumed edit differs from the uninterrupted one");
}
