//! End-to-end tests of the segmentation constraint's doors on `transsplat edit`:
//! `--masks DIR` (masks made elsewhere) and `--segment PHRASE --segment-weights DIR`
//! (CLIPSeg, `--sam-weights DIR` to sharpen its masks with SAM): bad requests exit 2 with one line and write nothing; masks reach the edit,
//! its `transport.json` and its report.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Output;
use transsplat_scene::{cameras, image};

fn edit(ds: &Path, out: &Path, extra: &[&str]) -> Output {
    bin()
        .args(["edit", "--scene"])
        .arg(ds)
        .args(["--prompt", "make the ball blue", "--editor", "simulated", "--steps", "30"])
        .args(extra)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

/// Asserts exit 2, a one-line error holding every needle (log lines aside), and no
/// output folder.
fn refused(o: &Output, out: &Path, needles: &[&str]) {
    assert_eq!(o.status.code(), Some(2), "{}", text(o));
    let stderr = String::from_utf8_lossy(&o.stderr);
    let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("error")).collect();
    assert_eq!(errors.len(), 1, "one error line: {stderr}");
    let after = stderr.split_once(errors[0]).map(|(_, rest)| rest.trim()).unwrap_or_default();
    assert!(after.is_empty(), "nothing after the error line: {stderr}");
    for n in needles {
        assert!(errors[0].contains(n), "{n:?} not in: {}", errors[0]);
    }
    assert!(!out.exists(), "an output folder was written");
}

/// Writes one binary mask per camera of the dataset `ds` into `dir`: 1 where the
/// dataset's label mask shows the object `name` (the label masks of `transsplat scene`
/// hold label ids, not binary masks), or `f(stem, w, h)` when given.
fn write_masks(ds: &Path, dir: &Path, name: &str) -> Vec<String> {
    let labels = transsplat_builtin::Labels::read(&ds.join("labels.json")).unwrap();
    let id = labels.labels.iter().find(|l| l.name == name).unwrap().id as f32;
    std::fs::create_dir_all(dir).unwrap();
    let mut stems = Vec::new();
    for cam in cameras::load(&ds.join("cameras.json")).unwrap() {
        let stem = cam.stem();
        let ids = image::read(&ds.join("masks").join(format!("{stem}.png"))).unwrap();
        let mask: Vec<f32> = ids
            .data
            .chunks_exact(3)
            .flat_map(|p| [if (p[0] * 255.0).round() == id { 1.0 } else { 0.0 }; 3])
            .collect();
        image::write_png(&dir.join(format!("{stem}.png")), ids.width, ids.height, &mask).unwrap();
        stems.push(stem);
    }
    stems
}

fn clipseg_fixture() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/tests/fixtures/clipseg/simple")
}

#[test]
fn bad_segmenter_requests_exit_2_with_one_line_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let out = dir.path().join("edit");
    let s = |p: &Path| p.display().to_string();
    // usage errors
    refused(&edit(&ds, &out, &["--segment", "the ball"]), &out, &["--segment-weights"]);
    let fixture = s(&clipseg_fixture());
    let both = ["--segment", "the ball", "--segment-weights", &fixture, "--masks", "/tmp"];
    refused(&edit(&ds, &out, &both), &out, &["--masks", "--segment"]);
    // a mask folder that is not there
    refused(
        &edit(&ds, &out, &["--masks", "/nonexistent-masks"]),
        &out,
        &["/nonexistent-masks", "does not exist"],
    );
    // missing CLIPSeg weights: the folder and the download command
    let missing = dir.path().join("no-clipseg");
    refused(
        &edit(&ds, &out, &["--segment", "the ball", "--segment-weights", &s(&missing)]),
        &out,
        &[&s(&missing), &format!("hf download CIDAS/clipseg-rd64-refined --local-dir {}", s(&missing))],
    );
    // a folder without weights
    std::fs::create_dir(&missing).unwrap();
    std::fs::copy(clipseg_fixture().join("config.json"), missing.join("config.json")).unwrap();
    refused(
        &edit(&ds, &out, &["--segment", "the ball", "--segment-weights", &s(&missing)]),
        &out,
        &["model.safetensors", "hf download CIDAS/clipseg-rd64-refined"],
    );
    // the tiny random CLIPSeg loads but cannot take a real phrase (its vocabulary has
    // 500 tokens): refused before the editor runs, naming the folder and the phrase
    refused(
        &edit(&ds, &out, &["--segment", "the ball", "--segment-weights", &fixture]),
        &out,
        &[&fixture, "\"the ball\"", "outside vocab_size 500"],
    );
    // a bare --segment segments the object the instruction ("make the ball blue") edits
    refused(
        &edit(&ds, &out, &["--segment-weights", &fixture, "--segment"]),
        &out,
        &[&fixture, "\"the ball\"", "outside vocab_size 500"],
    );
    // SAM sharpens --segment's masks only: alone it is a usage error; a missing SAM
    // folder is named with its download command before anything runs
    refused(&edit(&ds, &out, &["--sam-weights", &fixture]), &out, &["--segment"]);
    let no_sam = dir.path().join("no-sam");
    refused(
        &edit(
            &ds,
            &out,
            &["--segment", "the ball", "--segment-weights", &fixture, "--sam-weights", &s(&no_sam)],
        ),
        &out,
        &[&s(&no_sam), &format!("hf download Zigeng/SlimSAM-uniform-77 --local-dir {}", s(&no_sam))],
    );
    // masks: a missing file, a file of the wrong size, nothing found anywhere
    let masks = dir.path().join("masks");
    let stems = write_masks(&ds, &masks, "ball");
    let stem = &stems[1]; // an edit view (every 8th camera is held out)
    let file = masks.join(format!("{stem}.png"));
    std::fs::remove_file(&file).unwrap();
    refused(&edit(&ds, &out, &["--masks", &s(&masks)]), &out, &[&s(&file), "no mask for view"]);
    image::write_png(&file, 3, 2, &[1.0; 18]).unwrap();
    refused(&edit(&ds, &out, &["--masks", &s(&masks)]), &out, &[&s(&file), "mask is 3x2"]);
    let empty = dir.path().join("empty-masks");
    write_masks(&ds, &empty, "ball");
    for e in std::fs::read_dir(&empty).unwrap() {
        let p = e.unwrap().path();
        let m = image::read(&p).unwrap();
        image::write_png(&p, m.width, m.height, &vec![0.0; m.data.len()]).unwrap();
    }
    refused(
        &edit(&ds, &out, &["--masks", &s(&empty)]),
        &out,
        &["the segmenter (masks) found nothing in any view"],
    );
}

#[test]
fn masks_made_elsewhere_reach_the_edit_its_summary_and_its_report() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let masks = dir.path().join("masks");
    let stems = write_masks(&ds, &masks, "ball");
    let out = dir.path().join("edit");
    let o = edit(&ds, &out, &["--masks", masks.to_str().unwrap()]);
    ok(&o);
    assert!(out.join("point_cloud/iteration_30/point_cloud.ply").is_file());
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("transport.json")).unwrap()).unwrap();
    assert_eq!(stats["segmenter"]["name"], "masks", "{stats}");
    assert_eq!(stats["editor"], "simulated");
    // the report shows the mask beside the attention of the views it shows; the first
    // edit view is one of them, and its mask is the one handed over
    let report = std::fs::read_to_string(out.join("report.html")).unwrap();
    let shown = &stems[1];
    assert!(report.contains(&format!("renders/mask_{shown}.png")), "no mask in the report");
    let back = image::read(&out.join(format!("renders/mask_{shown}.png"))).unwrap();
    let given = image::read(&masks.join(format!("{shown}.png"))).unwrap();
    assert_eq!(back.data, given.data);
    // the inputs are untouched
    assert_eq!(std::fs::read_dir(&masks).unwrap().count(), stems.len());
    // the masks changed the edit (the simulated editor spills outside the ball)
    let plain = dir.path().join("plain");
    ok(&edit(&ds, &plain, &[]));
    let ply = "point_cloud/iteration_30/point_cloud.ply";
    assert_ne!(std::fs::read(out.join(ply)).unwrap(), std::fs::read(plain.join(ply)).unwrap());
}
