//! `transsplat eval`: missing CLIP weights are a clear error (folder, file, download
//! command; exit 2, nothing written); with the tiny CLIP fixture it scores paired views
//! and writes the JSON. Also `edit --dino-weights` with a missing folder.

mod common;
use common::*;
use std::path::Path;
use std::process::Output;

fn write_views(dir: &Path, shift: f32) {
    std::fs::create_dir_all(dir).unwrap();
    for i in 0..3 {
        let (w, h) = (20, 16);
        let rgb: Vec<f32> =
            (0..w * h * 3).map(|k| ((k as f32 * 0.013 + i as f32 + shift).sin() + 1.0) / 2.0).collect();
        transsplat_scene::image::write_png(&dir.join(format!("view_{i}.png")), w, h, &rgb).unwrap();
    }
}

fn eval(clip: &Path, src: &Path, edit: &Path, out: &Path) -> Output {
    bin()
        .arg("eval")
        .arg("--clip")
        .arg(clip)
        .arg("--source")
        .arg(src)
        .arg("--edited")
        .arg(edit)
        .args(["--source-prompt", "a man", "--target-prompt", "a clown", "--every", "2", "--out"])
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn missing_clip_weights_exit_2_naming_folder_file_and_download() {
    let dir = tempfile::tempdir().unwrap();
    let (src, edit, out) = (dir.path().join("src"), dir.path().join("edit"), dir.path().join("m.json"));
    write_views(&src, 0.0);
    write_views(&edit, 0.5);

    let o = eval(&dir.path().join("no-clip"), &src, &edit, &out);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let t = text(&o);
    assert!(
        t.contains("no-clip") && t.contains("hf download openai/clip-vit-large-patch14 --local-dir"),
        "{t}"
    );

    // A folder with the config but no weights names the file expected.
    let clip = dir.path().join("clip");
    std::fs::create_dir_all(&clip).unwrap();
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/tests/fixtures/clip/full");
    std::fs::copy(fixture.join("config.json"), clip.join("config.json")).unwrap();
    let o = eval(&clip, &src, &edit, &out);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let t = text(&o);
    assert!(t.contains("model.safetensors") && t.contains("hf download"), "{t}");
    assert!(!out.exists(), "nothing is written on error");
}

#[test]
fn tiny_clip_scores_every_nth_view_and_writes_json() {
    let dir = tempfile::tempdir().unwrap();
    let (src, edit, out) = (dir.path().join("src"), dir.path().join("edit"), dir.path().join("m.json"));
    write_views(&src, 0.0);
    write_views(&edit, 0.5);
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/tests/fixtures/clip/full");
    let o = eval(&fixture, &src, &edit, &out);
    assert!(o.status.success(), "{}", text(&o));
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let views = json["views"].as_array().unwrap();
    assert_eq!(views.len(), 2, "views 0 and 2 of 3 with --every 2");
    assert_eq!(views[1]["view"], "view_2");
    for v in views {
        let s = v["clip_sim"].as_f64().unwrap();
        assert!((-1.0..=1.0).contains(&s));
    }
    let mean = json["mean_clip_sim"].as_f64().unwrap();
    let avg = views.iter().map(|v| v["clip_sim"].as_f64().unwrap()).sum::<f64>() / 2.0;
    assert!((mean - avg).abs() < 1e-5);
    assert!(text(&o).contains("CLIP-dir"));
}

#[test]
fn missing_dino_weights_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("ds");
    let o = bin().args(["scene", "tabletop", "--quick", "--out"]).arg(&ds).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let out = dir.path().join("edit");
    let o = bin()
        .args(["edit", "--scene"])
        .arg(&ds)
        .args(["--prompt", "turn the ball into bronze", "--editor", "simulated", "--steps", "5", "--out"])
        .arg(&out)
        .arg("--dino-weights")
        .arg(dir.path().join("no-dino"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let t = text(&o);
    assert!(t.contains("no-dino") && t.contains("hf download facebook/dinov2-small"), "{t}");
    assert!(!out.exists());
}

#[test]
fn scenes_with_cameras_are_rendered_then_scored_like_folders_of_renders() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("ds");
    let o = bin().args(["scene", "tabletop", "--quick", "--out"]).arg(&ds).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    // The edited scene: the source with its base colour shifted.
    let src_ply = transsplat_scene::scene_paths::resolve_scene(&ds).unwrap();
    let mut g = transsplat_scene::ply::read(&src_ply).unwrap();
    let k = g.sh.len() / g.len();
    for i in 0..g.len() {
        g.sh[i * k] += 0.8;
    }
    let edited = dir.path().join("edited.ply");
    transsplat_scene::ply::write(&edited, &g).unwrap();
    let cams = ds.join("cameras.json");
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/tests/fixtures/clip/full");

    // Folders rendered by `transsplat render`...
    for (scene, name) in [(ds.as_path(), "r_src"), (edited.as_path(), "r_edit")] {
        let o = bin()
            .args(["render", "--scene"])
            .arg(scene)
            .arg("--cameras")
            .arg(&cams)
            .arg("--out")
            .arg(dir.path().join(name))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", text(&o));
    }
    let by_folder = dir.path().join("folders.json");
    let o = eval(&fixture, &dir.path().join("r_src"), &dir.path().join("r_edit"), &by_folder);
    assert!(o.status.success(), "{}", text(&o));
    // ...score the same as the scenes rendered by `eval --cameras`.
    let by_scene = dir.path().join("scenes.json");
    let o = bin()
        .arg("eval")
        .arg("--clip")
        .arg(&fixture)
        .arg("--source")
        .arg(&ds)
        .arg("--edited")
        .arg(&edited)
        .arg("--cameras")
        .arg(&cams)
        .args(["--source-prompt", "a man", "--target-prompt", "a clown", "--every", "2", "--out"])
        .arg(&by_scene)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let a: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&by_folder).unwrap()).unwrap();
    let b: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&by_scene).unwrap()).unwrap();
    assert!(!a["views"].as_array().unwrap().is_empty());
    assert_eq!(a, b);
}
