//! SAM against transformers' `SamModel` on a tiny random model (fixtures by
//! `tools/model_fixtures_sam.py`): the image embeddings, the masks and IoU of a point
//! prompt (multimask) and of a box with a point (single mask), and the whole `segment`
//! pipeline (resize, normalisation, padding, prompt scaling, mask resizing, sigmoid) on
//! an image of another size. Errors are relative to the largest reference magnitude,
//! 1e-4 as in the other parity tests.

use std::collections::HashMap;
use std::path::PathBuf;

use candle_core::{DType, Device, Tensor};
use transsplat_models::sam::{PointLabel, Prompt, Sam};

const TOLERANCE: f32 = 1e-4;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/sam")
}

fn reference() -> HashMap<String, Tensor> {
    candle_core::safetensors::load(fixtures().join("reference.safetensors"), &Device::Cpu).unwrap()
}

fn values(t: &Tensor) -> Vec<f32> {
    t.to_dtype(DType::F32).unwrap().flatten_all().unwrap().to_vec1().unwrap()
}

fn assert_close(got: &[f32], want: &[f32], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-12);
    let err = got.iter().zip(want).fold(0f32, |m, (a, b)| m.max((a - b).abs())) / scale;
    assert!(err <= TOLERANCE, "{what}: relative error {err:e} (scale {scale:e})");
    eprintln!("{what}: relative error {err:.2e}");
}

fn load() -> Sam {
    Sam::load(&fixtures().join("tiny"), &Device::Cpu).unwrap()
}

/// The prompts of image `b`: its points (with labels) and, when given, its box.
fn prompt(r: &HashMap<String, Tensor>, b: usize, points: usize, with_box: bool) -> Prompt {
    let xy = values(&r["points"]);
    let labels = values(&r["labels"]);
    let boxes = values(&r["boxes"]);
    Prompt {
        points: (0..points)
            .map(|i| {
                let j = b * 2 + i;
                let label = if labels[j] == 1.0 { PointLabel::Positive } else { PointLabel::Negative };
                ([xy[2 * j], xy[2 * j + 1]], label)
            })
            .collect(),
        bbox: with_box.then(|| [boxes[4 * b], boxes[4 * b + 1], boxes[4 * b + 2], boxes[4 * b + 3]]),
    }
}

#[test]
fn image_embeddings_and_masks_match_transformers() {
    let r = reference();
    let sam = load();
    let pixels = r["pixels"].to_dtype(DType::F32).unwrap();
    let embeddings = sam.image_embeddings(&pixels).unwrap();
    assert_eq!(embeddings.dims(), r["image_embeddings"].dims());
    assert_close(&values(&embeddings), &values(&r["image_embeddings"]), "image embeddings");
    // Reference masks are [B, 1, K, 4g, 4g] (one prompt per image); ours [B, K, 4g, 4g].
    let by_points =
        sam.decode(&embeddings, &[prompt(&r, 0, 2, false), prompt(&r, 1, 2, false)], true).unwrap();
    assert_eq!(by_points.logits.dim(1).unwrap(), 3);
    assert_close(&values(&by_points.logits), &values(&r["points.masks"]), "point masks (multimask)");
    assert_close(&values(&by_points.iou), &values(&r["points.iou"]), "point IoU");
    let by_box = sam.decode(&embeddings, &[prompt(&r, 0, 1, true), prompt(&r, 1, 1, true)], false).unwrap();
    assert_eq!(by_box.logits.dim(1).unwrap(), 1);
    assert_close(&values(&by_box.logits), &values(&r["box.masks"]), "box masks");
    assert_close(&values(&by_box.iou), &values(&r["box.iou"]), "box IoU");
}

#[test]
fn the_segment_pipeline_matches_the_processor_and_post_processing() {
    let r = reference();
    let sam = load();
    let image = values(&r["image"]);
    let (h, w) = (r["image"].dim(0).unwrap(), r["image"].dim(1).unwrap());
    let b = values(&r["box_xyxy"]);
    let p = values(&r["point_xy"]);
    let prompt =
        Prompt { points: vec![([p[0], p[1]], PointLabel::Positive)], bbox: Some([b[0], b[1], b[2], b[3]]) };
    let got = sam.segment(&image, w, h, &prompt).unwrap();
    assert_eq!(got.len(), w * h);
    assert_close(&got, &values(&r["probabilities"]), "segment() probabilities");
}

#[test]
fn bad_configs_and_prompts_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::copy(fixtures().join("tiny/model.safetensors"), dir.join("model.safetensors")).unwrap();
    let mut config: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixtures().join("tiny/config.json")).unwrap()).unwrap();
    config["mask_decoder_config"]["hidden_size"] = 24.into();
    std::fs::write(dir.join("config.json"), config.to_string()).unwrap();
    let err = Sam::load(dir, &Device::Cpu).unwrap_err().to_string();
    assert!(err.contains("config.json") && err.contains("must agree"), "{err}");
    let missing = Sam::load(&dir.join("nothing"), &Device::Cpu).unwrap_err().to_string();
    assert!(missing.contains("hf download"), "{missing}");
    let sam = load();
    let pixels = Tensor::zeros((1, 3, 32, 32), DType::F32, &Device::Cpu).unwrap();
    assert!(sam.image_embeddings(&pixels).is_err());
    let s = sam.input_size();
    let embeddings =
        sam.image_embeddings(&Tensor::zeros((1, 3, s, s), DType::F32, &Device::Cpu).unwrap()).unwrap();
    assert!(sam.decode(&embeddings, &[Prompt::default()], false).is_err());
}

/// A segmenter handing out fixed masks, standing in for CLIPSeg.
struct Fixed(Vec<Option<Vec<f32>>>);

impl transsplat_editors::Segmenter for Fixed {
    fn name(&self) -> &str {
        "fixed"
    }

    fn segment(
        &mut self,
        _views: &[transsplat_editors::SourceView],
        _phrase: &str,
    ) -> Result<Vec<Option<Vec<f32>>>, transsplat_editors::Error> {
        Ok(self.0.clone())
    }
}

#[test]
fn sharpening_prompts_sam_with_the_coarse_masks_box_and_peak_and_keeps_misses() {
    use transsplat_editors::{Segmenter, SourceView};
    use transsplat_models::sam::{prompt_from_mask, SamSharpened};
    let (w, h) = (24usize, 18usize);
    let image: Vec<f32> = (0..w * h * 3).map(|i| ((i * 37) % 101) as f32 / 100.0).collect();
    let cam = transsplat_scene::Camera::pinhole("v.png", w as u32, h as u32, 20.0);
    let views = [
        SourceView { index: 0, camera: &cam, image: &image },
        SourceView { index: 1, camera: &cam, image: &image },
    ];
    // A coarse blob in the first view; the second view is a miss.
    let coarse: Vec<f32> = (0..w * h)
        .map(|i| if (5..12).contains(&(i % w)) && (4..9).contains(&(i / w)) { 0.8 } else { 0.1 })
        .collect();
    let mut sharpened = SamSharpened::new(Fixed(vec![Some(coarse.clone()), None]), load());
    assert_eq!(sharpened.name(), "fixed+sam");
    let masks = sharpened.segment(&views, "the ball").unwrap();
    let want = load().segment(&image, w, h, &prompt_from_mask(&coarse, w, h).unwrap()).unwrap();
    assert_eq!(masks[0].as_deref(), Some(want.as_slice()));
    assert_ne!(masks[0].as_deref(), Some(coarse.as_slice()));
    assert_eq!(masks[1], None);
}
