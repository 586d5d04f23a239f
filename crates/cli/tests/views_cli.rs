//! End-to-end test of `transsplat views export` through the binary.

use std::process::Command;
use transsplat_editors::{content_name, Editor, FolderEditor, SourceView};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::{cameras, fingerprint, image, ply};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_transsplat"))
}

#[test]
fn views_export_writes_the_edit_views_and_refuses_foreign_files() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("ds");
    let st =
        bin().args(["scene", "tabletop", "--quick", "--views", "10", "--out"]).arg(&ds).status().unwrap();
    assert!(st.success());
    let out = dir.path().join("views");
    let st = bin().args(["views", "export", "--scene"]).arg(&ds).arg("--out").arg(&out).status().unwrap();
    assert!(st.success());

    let cams = cameras::load(&ds.join("cameras.json")).unwrap();
    let g = ply::read(&ds.join("point_cloud/iteration_0/point_cloud.ply")).unwrap();
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("views.json")).unwrap()).unwrap();
    let listed: Vec<u64> =
        json["views"].as_array().unwrap().iter().map(|v| v["index"].as_u64().unwrap()).collect();
    assert_eq!(listed, vec![1, 2, 3, 4, 5, 6, 7, 9], "every camera but each 8th");
    // files named by content: the view's stem and a fingerprint of scene and camera
    let fp = fingerprint::scene(&g);
    let file = |i: usize| out.join(format!("{}.png", content_name(&cams[i], Some(&fp))));
    assert_eq!(json["scene"], fp.as_str());
    assert!(file(1).is_file() && !file(0).exists() && !file(8).exists());

    // the PNG is the library's render of that camera on black
    let (want, _) = render(&Splats::new(&g), &cams[3], &RenderOptions::default());
    let got = image::read(&file(3)).unwrap();
    assert_eq!((got.width, got.height), (want.width, want.height));
    assert!(got.data.iter().zip(&want.rgb).all(|(a, b)| (a - b.clamp(0.0, 1.0)).abs() <= 0.5 / 255.0 + 1e-6));

    // the exported folder read back by the folder editor: every view, no change
    let views: Vec<SourceView> = [3usize, 8]
        .iter()
        .map(|&i| SourceView {
            index: i,
            camera: &cams[i],
            image: if i == 3 { &got.data } else { &want.rgb },
        })
        .collect();
    let back = FolderEditor::new(&out).for_scene(&fp).edit(&views, "").unwrap();
    assert!(back[0].as_ref().unwrap().attention.iter().all(|&a| a < 1e-5));
    assert!(back[1].is_none(), "test view 8 was not exported");

    // the dataset's own images folder is refused by the output rule, exit status 2
    let name = format!("{}.png", cams[1].stem());
    let before = std::fs::read(ds.join("images").join(&name)).unwrap();
    let export = |out: &std::path::Path| {
        bin().args(["views", "export", "--scene"]).arg(&ds).arg("--out").arg(out).output().unwrap()
    };
    let o = export(&ds.join("images"));
    assert_eq!(o.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("lies inside the input folder"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(std::fs::read(ds.join("images").join(&name)).unwrap(), before);
    // a folder elsewhere holding other images of the same names is refused too
    let foreign = dir.path().join("foreign");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join(&name), &before).unwrap();
    let o = export(&foreign);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("was not written by this command"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(std::fs::read(foreign.join(&name)).unwrap(), before);
}
