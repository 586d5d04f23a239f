//! CLIP-sim / CLIP-dir against the reference `ClipSimilarity` computation (torch,
//! transformers) on the tiny CLIP fixture of the models crate
//! (`tools/model_fixtures_clip.py`): three views, two prompts.

use std::path::PathBuf;

use candle_core::Device;
use transsplat_eval::clip_metrics::{pair_views, score};
use transsplat_models::clip::Clip;
use transsplat_models::ModelDir;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/tests/fixtures/clip")
}

#[derive(serde::Deserialize)]
struct Reference {
    source_prompt: String,
    target_prompt: String,
    clip_sim: Vec<f32>,
    clip_dir: Vec<f32>,
    mean_clip_sim: f32,
    mean_clip_dir: f32,
}

#[test]
fn scores_match_the_reference_clip_similarity() {
    let r: Reference =
        serde_json::from_str(&std::fs::read_to_string(fixtures().join("metric.json")).unwrap()).unwrap();
    let t = candle_core::safetensors::load(fixtures().join("reference.safetensors"), &Device::Cpu).unwrap();
    let clip =
        Clip::load(&ModelDir::open(&fixtures().join("full"), "CLIP", "hf").unwrap(), &Device::Cpu).unwrap();
    let image = |k: String| {
        let x = &t[&k];
        let (h, w, _) = x.dims3().unwrap();
        (x.flatten_all().unwrap().to_vec1::<f32>().unwrap(), w, h)
    };
    let imgs: Vec<_> =
        (0..3).map(|i| (image(format!("metric.source{i}")), image(format!("metric.edited{i}")))).collect();
    let views: Vec<_> = imgs
        .iter()
        .enumerate()
        .map(|(i, (s, e))| (format!("v{i}"), (s.0.as_slice(), s.1, s.2), (e.0.as_slice(), e.1, e.2)))
        .collect();
    let mut done = 0;
    let got = score(&clip, &views, &r.source_prompt, &r.target_prompt, 1, &mut |n| {
        done = n;
        std::ops::ControlFlow::Continue(())
    })
    .unwrap();
    assert_eq!(done, 3);
    for i in 0..3 {
        assert!(
            (got.views[i].clip_sim - r.clip_sim[i]).abs() < 1e-4,
            "sim {i}: {} vs {}",
            got.views[i].clip_sim,
            r.clip_sim[i]
        );
        assert!(
            (got.views[i].clip_dir - r.clip_dir[i]).abs() < 1e-4,
            "dir {i}: {} vs {}",
            got.views[i].clip_dir,
            r.clip_dir[i]
        );
    }
    assert!((got.mean_clip_sim - r.mean_clip_sim).abs() < 1e-4);
    assert!((got.mean_clip_dir - r.mean_clip_dir).abs() < 1e-4);

    // A stop request after the first view ends the scoring there.
    let mut calls = 0;
    let stopped = score(&clip, &views, &r.source_prompt, &r.target_prompt, 1, &mut |_| {
        calls += 1;
        std::ops::ControlFlow::Break(())
    });
    assert!(matches!(stopped, Err(transsplat_eval::clip_metrics::Error::Interrupted)), "{stopped:?}");
    assert_eq!(calls, 1);
}

#[test]
fn views_pair_by_stem_every_nth_and_missing_edits_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let (src, edit) = (dir.path().join("src"), dir.path().join("edit"));
    std::fs::create_dir_all(&src).unwrap();
    std::fs::create_dir_all(&edit).unwrap();
    for i in 0..10 {
        std::fs::write(src.join(format!("view_{i:02}.png")), b"").unwrap();
        if i != 8 {
            std::fs::write(edit.join(format!("view_{i:02}.jpg")), b"").unwrap();
        }
    }
    std::fs::write(src.join("notes.txt"), b"").unwrap();
    let pairs = pair_views(&src, &edit, 3).unwrap();
    let stems: Vec<&str> = pairs.iter().map(|p| p.0.as_str()).collect();
    assert_eq!(stems, ["view_00", "view_03", "view_06", "view_09"]);
    assert!(pairs[1].2.ends_with("view_03.jpg"));
    let err = pair_views(&src, &edit, 8).unwrap_err().to_string();
    assert!(err.contains("view_08") && err.contains("edit"), "{err}");
}
