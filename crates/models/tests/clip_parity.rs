//! CLIP towers and the `ClipSimilarity` preprocessing against transformers on tiny random
//! models (fixtures by `tools/model_fixtures_clip.py`): a `CLIPTextModel` as Stable
//! Diffusion's text encoder (gelu, legacy `eos_token_id = 2`) and a whole `CLIPModel`
//! (quick_gelu text, gelu vision, 224 input, fp16 weights on disk) with the real tokenizer.

use std::path::PathBuf;

use candle_core::{Device, Tensor};
use transsplat_models::clip::{Clip, ClipTextModel};
use transsplat_models::tokenizer::{ClipTokenizer, END_OF_TEXT};
use transsplat_models::ModelDir;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/clip")
}

fn reference() -> std::collections::HashMap<String, Tensor> {
    candle_core::safetensors::load(fixtures().join("reference.safetensors"), &Device::Cpu).unwrap()
}

fn values(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_dtype(candle_core::DType::F32).unwrap().to_vec1().unwrap()
}

/// Largest |got − want| relative to the largest |want|.
fn assert_close(got: &[f32], want: &[f32], tol: f32, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-12);
    let err = got.iter().zip(want).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(err <= tol * scale, "{what}: max error {err:e} vs scale {scale:e}");
}

fn ids_of(t: &Tensor) -> Vec<Vec<u32>> {
    t.to_dtype(candle_core::DType::I64)
        .unwrap()
        .to_vec2::<i64>()
        .unwrap()
        .into_iter()
        .map(|r| r.into_iter().map(|v| v as u32).collect())
        .collect()
}

#[test]
fn text_model_matches_transformers() {
    let r = reference();
    let dir = ModelDir::open(&fixtures().join("text"), "CLIP text encoder", "hf download x").unwrap();
    let model = ClipTextModel::load(&dir, &Device::Cpu).unwrap();
    let out = model.forward(&ids_of(&r["text.input_ids"])).unwrap();
    assert_close(
        &values(&out.last_hidden_state),
        &values(&r["text.last_hidden_state"]),
        1e-4,
        "last_hidden_state",
    );
    assert_close(&values(&out.pooled), &values(&r["text.pooled"]), 1e-4, "pooled");
}

fn full() -> Clip {
    let dir = ModelDir::open(&fixtures().join("full"), "CLIP", "hf download x").unwrap();
    Clip::load(&dir, &Device::Cpu).unwrap()
}

#[test]
fn full_model_text_features_match_with_the_bundled_tokenizer() {
    let r = reference();
    let clip = full();
    let prompts: Vec<String> =
        serde_json::from_str(&std::fs::read_to_string(fixtures().join("prompts.json")).unwrap()).unwrap();
    let tok = ClipTokenizer::bundled();
    let want_ids = ids_of(&r["full.text_ids"]);
    for (p, want) in prompts.iter().zip(&want_ids) {
        assert_eq!(&tok.encode_padded(p, 77, END_OF_TEXT), want, "{p}");
    }
    let refs: Vec<&str> = prompts.iter().map(String::as_str).collect();
    let got = clip.text_features(&refs).unwrap();
    assert_close(&values(&got), &values(&r["full.text_features"]), 1e-4, "text features");
}

#[test]
fn image_preprocessing_and_features_match_clip_similarity() {
    let r = reference();
    let clip = full();
    assert_eq!(clip.image_size(), 224);
    for i in 0..3 {
        let img = &r[&format!("full.image{i}")];
        let (h, w, _) = img.dims3().unwrap();
        let rgb = values(img);
        let pix = clip.preprocess(&rgb, w, h);
        if let Some(want) = r.get(&format!("full.pixels{i}.rows7")) {
            let rows: Vec<f32> = (0..3)
                .flat_map(|c| (0..224).step_by(7).flat_map(move |y| (0..224).map(move |x| (c, y, x))))
                .map(|(c, y, x)| pix[c * 224 * 224 + y * 224 + x])
                .collect();
            assert_close(&rows, &values(want), 1e-5, &format!("pixels of image {i} ({w}x{h})"));
        }
        let f = clip.image_features(&[(&rgb, w, h)]).unwrap();
        assert_close(
            &values(&f),
            &values(&r[&format!("full.image_features{i}")]),
            1e-4,
            &format!("image {i}"),
        );
    }
}
