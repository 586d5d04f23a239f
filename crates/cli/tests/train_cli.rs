//! End-to-end tests of `transsplat train` through the binary: a built-in quick scene
//! trained briefly into an INRIA folder that `transsplat render` opens, and bad input
//! (exit status 2, one-line error naming the file).

use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_transsplat"))
}

#[test]
fn train_on_a_built_in_scene_writes_an_inria_folder() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let st = bin().args(["scene", "tabletop", "--quick", "--out"]).arg(&data).output().unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let out = dir.path().join("out");
    let st = bin()
        .args(["train", "--iters", "60", "--resolution", "4", "--eval-every", "30", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let stdout = String::from_utf8_lossy(&st.stdout);
    let last: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert_eq!(last["steps"], 60);
    assert!(last["test_psnr"].as_f64().unwrap() > 5.0);
    assert!(out.join("point_cloud/iteration_60/point_cloud.ply").is_file());
    assert!(out.join("cameras.json").is_file());
    let renders = dir.path().join("renders");
    let st = bin().args(["render", "--scene"]).arg(&out).arg("--out").arg(&renders).output().unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    assert!(renders.join("view_001.png").is_file());
}

#[test]
fn bad_datasets_exit_with_status_2_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let st = bin().args(["scene", "tabletop", "--quick", "--out"]).arg(&data).output().unwrap();
    assert!(st.status.success());
    let victim = data.join("images/view_003.png");
    std::fs::write(&victim, b"not an image").unwrap();
    let out = dir.path().join("out");
    let st =
        bin().args(["train", "--iters", "5", "--data"]).arg(&data).arg("--out").arg(&out).output().unwrap();
    assert_eq!(st.status.code(), Some(2));
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(err.contains("view_003.png") && err.contains("not a PNG or JPEG"), "{err}");
    std::fs::remove_file(&victim).unwrap();
    let st =
        bin().args(["train", "--iters", "5", "--data"]).arg(&data).arg("--out").arg(&out).output().unwrap();
    assert_eq!(st.status.code(), Some(2));
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(err.contains("view_003") && err.contains("missing"), "{err}");
    let st = bin()
        .args(["train", "--data"])
        .arg(dir.path().join("nowhere"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(st.status.code(), Some(2));
}
