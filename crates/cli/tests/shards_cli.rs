//! The shard-and-assemble path without Ray (issue 18, items 1 and 4): `views export
//! --shard I/N` per job, each shard edited on its own, the shards' folders gathered
//! under one and lifted by `edit --editor folder`. The oracle is the unsharded path:
//! the same edits through one export must give a byte-identical scene.

mod common;
use common::*;
use std::path::{Path, PathBuf};

fn export(ds: &Path, out: &Path, shard: Option<&str>) -> std::process::Output {
    let mut c = bin();
    c.args(["views", "export", "--scene"]).arg(ds).arg("--out").arg(out);
    if let Some(s) = shard {
        c.args(["--shard", s]);
    }
    c.output().unwrap()
}

fn lift(ds: &Path, edits: &Path, out: &Path) -> std::process::Output {
    bin()
        .args(["edit", "--scene"])
        .arg(ds)
        .args(["--prompt", "make the right side blue", "--editor", "folder", "--steps", "20", "--edits"])
        .arg(edits)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

fn ply(out: &Path) -> Vec<u8> {
    std::fs::read(out.join("point_cloud/iteration_20/point_cloud.ply")).unwrap()
}

#[test]
fn sharded_edits_assemble_to_the_same_scene_as_one_export() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ds = quick_scene(d);

    // the oracle: one export, edited, lifted
    let all = d.join("all");
    ok(&export(&ds, &all, None));
    let mut all_names = tint(&all);
    ok(&lift(&ds, &all, &d.join("one")));

    // three shards, each exported and edited on its own, gathered under `edited/`
    let edited = d.join("edited");
    let mut shard_names = Vec::new();
    for i in 0..3 {
        let folder = edited.join(i.to_string());
        ok(&export(&ds, &folder, Some(&format!("{i}/3"))));
        let names = tint(&folder);
        assert!(!names.is_empty(), "shard {i}/3 is empty");
        shard_names.extend(names);
    }
    shard_names.sort();
    all_names.sort();
    assert_eq!(shard_names, all_names, "the shards partition the views, under the same content names");
    ok(&lift(&ds, &edited, &d.join("sharded")));
    assert!(ply(&d.join("sharded")) == ply(&d.join("one")), "sharded and unsharded lifts differ");

    // a rerun of a shard's export copies the views it already holds
    let again = export(&ds, &edited.join("0"), Some("0/3"));
    ok(&again);
    assert!(text(&again).contains("reused"), "{}", text(&again));
    // ... and shards never replace each other's folder
    let o = export(&ds, &edited.join("0"), Some("1/3"));
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("holds shard 0/3"), "{}", text(&o));
    // a shard past the views, and a malformed one, are refused
    let o = export(&ds, &d.join("empty"), Some("40/41"));
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("holds no view") && !d.join("empty").exists(), "{}", text(&o));
    let o = export(&ds, &d.join("bad"), Some("3/3"));
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("3/3") && !d.join("bad").exists(), "{}", text(&o));

    // the edits of this scene are never taken for another scene's views
    let other: PathBuf = quick_scene_in(d, "other");
    transsplat_scene::ply::write(&other.join("point_cloud/iteration_0/point_cloud.ply"), &{
        let mut g =
            transsplat_scene::ply::read(&other.join("point_cloud/iteration_0/point_cloud.ply")).unwrap();
        g.means[0][0] += 1e-3;
        g
    })
    .unwrap();
    let o = lift(&other, &edited, &d.join("mixed"));
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("made for another scene"), "{}", text(&o));
    assert!(!d.join("mixed").exists());
}
