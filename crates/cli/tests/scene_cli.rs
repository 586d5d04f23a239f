//! End-to-end test of `transsplat scene` through the binary.

use std::process::Command;
use transsplat_scene::{cameras, image, ply, scene_paths};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_transsplat"))
}

#[test]
fn scene_writes_a_dataset_the_readers_open() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("tabletop");
    let args = ["--quick", "--views", "9", "--width", "64", "--height", "48", "--seed", "3"];
    let st = bin().args(["scene", "tabletop", "--out"]).arg(&out).args(args).status().unwrap();
    assert!(st.success());

    let cams = cameras::load(&out).unwrap();
    assert_eq!(cams.len(), 9);
    let g = ply::read(&scene_paths::resolve_scene(&out).unwrap()).unwrap();
    let labels = transsplat_builtin::labels_from_extra(&g).expect("label property");
    let cfg =
        transsplat_builtin::SceneConfig { seed: 3, width: 64, height: 48, views: 9, ..Default::default() };
    let cfg =
        transsplat_builtin::SceneConfig { detail: transsplat_builtin::SceneConfig::quick().detail, ..cfg };
    let lib = transsplat_builtin::build("tabletop", &cfg).unwrap();
    assert_eq!(labels, lib.labels, "binary and library disagree");
    for cam in &cams {
        let stem = cam.stem();
        let img = image::read(&out.join(format!("images/{stem}.png"))).unwrap();
        assert_eq!((img.width, img.height), (64, 48));
        let mask = image::read(&out.join(format!("masks/{stem}.png"))).unwrap();
        assert!(mask.data.iter().all(|&v| (v * 255.0).round() <= 4.0));
    }
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("labels.json")).unwrap()).unwrap();
    assert_eq!(meta["test_views"], serde_json::json!(["view_000", "view_008"]));

    // a rerun replaces the earlier dataset; a foreign non-empty folder is refused (exit 2)
    // unless --force
    let st = bin().args(["scene", "tabletop", "--out"]).arg(&out).args(args).status().unwrap();
    assert!(st.success());
    std::fs::remove_file(out.join("labels.json")).unwrap();
    let o = bin().args(["scene", "tabletop", "--out"]).arg(&out).args(args).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("error:") && err.contains("not empty"), "{err}");
    let st = bin().args(["scene", "tabletop", "--force", "--out"]).arg(&out).args(args).status().unwrap();
    assert!(st.success());
}

#[test]
fn unknown_scene_lists_the_available_ones() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("x");
    let o = bin().args(["scene", "kitchen", "--quick", "--out"]).arg(&out).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("kitchen") && err.contains("tabletop") && err.contains("occluded"), "{err}");
    assert!(!out.exists());
    let o =
        bin().args(["scene", "occluded", "--quick", "--detail", "0", "--out"]).arg(&out).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", String::from_utf8_lossy(&o.stderr));
}
