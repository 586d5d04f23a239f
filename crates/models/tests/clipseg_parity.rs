//! CLIPSeg against transformers' `CLIPSegForImageSegmentation` on two tiny random models
//! (fixtures by `tools/model_fixtures_clipseg.py`): `simple` (one transposed convolution,
//! patch 8, legacy end-token pooling, FiLM at the first decoder step, an unused last
//! vision layer) and `complex` (`use_complex_transposed_convolution`, patch 16, FiLM at
//! the second step). Each is compared at its config's `image_size`, at another size
//! (position embeddings interpolated), and through the whole `segment` pipeline (resize to
//! the processor's size, normalisation, sigmoid, resize back). Errors are relative to the
//! largest reference magnitude, 1e-4 as in the other parity tests.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{DType, Device, Tensor};
use transsplat_models::clipseg::{download_hint, ClipSeg, ClipSegSegmenter, CLIPSEG_HINT, SEGMENT_BATCH};

const VARIANTS: [&str; 2] = ["simple", "complex"];
const TOLERANCE: f32 = 1e-4;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/clipseg")
}

fn reference() -> HashMap<String, Tensor> {
    candle_core::safetensors::load(fixtures().join("reference.safetensors"), &Device::Cpu).unwrap()
}

fn f32s(t: &Tensor) -> Tensor {
    t.to_dtype(DType::F32).unwrap()
}

fn values(t: &Tensor) -> Vec<f32> {
    f32s(t).flatten_all().unwrap().to_vec1().unwrap()
}

fn ids_of(t: &Tensor) -> Vec<Vec<u32>> {
    t.to_dtype(DType::I64)
        .unwrap()
        .to_vec2::<i64>()
        .unwrap()
        .into_iter()
        .map(|r| r.into_iter().map(|v| v as u32).collect())
        .collect()
}

/// Largest |got − want| over the largest |want|; fails above `TOLERANCE`. Returns the error.
fn assert_close(got: &[f32], want: &[f32], what: &str) -> f32 {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-12);
    let err = got.iter().zip(want).fold(0f32, |m, (a, b)| m.max((a - b).abs())) / scale;
    assert!(err <= TOLERANCE, "{what}: relative error {err:e} (scale {scale:e})");
    eprintln!("{what}: relative error {err:.2e}");
    err
}

fn load(variant: &str) -> ClipSeg {
    ClipSeg::load(&fixtures().join(variant), &Device::Cpu).unwrap()
}

#[test]
fn logits_match_transformers_at_the_config_image_size() {
    let r = reference();
    for variant in VARIANTS {
        let model = load(variant);
        let key = |k: &str| &r[&format!("{variant}.{k}")];
        let conditional = model.conditional_embeddings(&ids_of(key("input_ids"))).unwrap();
        assert_close(
            &values(&conditional),
            &values(key("conditional_embeddings")),
            &format!("{variant} conditional embeddings"),
        );
        let pixels = f32s(key("pixels"));
        assert_eq!(pixels.dim(2).unwrap(), model.config().vision_config.image_size);
        let out = model.forward(&pixels, &conditional).unwrap();
        assert_eq!(out.logits.dims(), key("logits").dims(), "{variant}: logits shape");
        assert_close(
            &values(&out.decoder_features),
            &values(key("decoder_features")),
            &format!("{variant} decoder features"),
        );
        assert_close(&values(&out.logits), &values(key("logits")), &format!("{variant} logits"));
    }
}

#[test]
fn logits_match_transformers_at_another_size_with_interpolated_positions() {
    let r = reference();
    for variant in VARIANTS {
        let model = load(variant);
        let key = |k: &str| &r[&format!("{variant}.{k}")];
        let pixels = f32s(key("big.pixels"));
        assert_ne!(pixels.dim(2).unwrap(), model.config().vision_config.image_size);
        let ids = ids_of(key("input_ids"));
        let conditional = model.conditional_embeddings(&ids[..1]).unwrap();
        let out = model.forward(&pixels, &conditional).unwrap();
        assert_eq!(out.logits.dims(), key("big.logits").dims(), "{variant}: logits shape");
        assert_close(
            &values(&out.decoder_features),
            &values(key("big.decoder_features")),
            &format!("{variant} decoder features, interpolated positions"),
        );
        assert_close(
            &values(&out.logits),
            &values(key("big.logits")),
            &format!("{variant} logits, interpolated"),
        );
    }
}

#[test]
fn segment_matches_the_processor_pipeline() {
    let r = reference();
    for variant in VARIANTS {
        let model = load(variant);
        let key = |k: &str| &r[&format!("{variant}.{k}")];
        let image = key("image");
        let (h, w, _) = image.dims3().unwrap();
        let ids = ids_of(key("prompt_ids")).remove(0);
        let probabilities = model.segment_ids(&values(image), w, h, &ids).unwrap();
        assert_eq!(probabilities.len(), w * h);
        assert!(probabilities.iter().all(|p| (0.0..=1.0).contains(p)));
        assert_close(&probabilities, &values(key("probabilities")), &format!("{variant} segment {w}x{h}"));
    }
}

#[test]
fn bad_inputs_are_errors() {
    let model = load("simple");
    let err = model.segment_ids(&[0.5; 10], 4, 4, &[0, 5, 499]).unwrap_err().to_string();
    assert!(err.contains("not 4 x 4 x 3"), "{err}");
    // The bundled tokenizer's ids do not fit the tiny model's vocabulary of 500.
    let err = model.segment(&[0.5; 4 * 4 * 3], 4, 4, "a cat").unwrap_err().to_string();
    assert!(err.contains("outside vocab_size 500"), "{err}");
    let conditional = model.conditional_embeddings(&[vec![0, 7, 499]]).unwrap();
    let pixels = Tensor::zeros((1, 3, 32, 40), DType::F32, &Device::Cpu).unwrap();
    let err = model.forward(&pixels, &conditional).unwrap_err().to_string();
    assert!(err.contains("a square"), "{err}");
}

fn copy_without(from: &Path, to: &Path, skip: &str) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        if entry.file_name() != skip {
            std::fs::copy(entry.path(), to.join(entry.file_name())).unwrap();
        }
    }
}

#[test]
fn missing_folder_or_weights_name_the_file_and_the_download_command() {
    let err = ClipSeg::load(Path::new("/nonexistent/clipseg"), &Device::Cpu).unwrap_err().to_string();
    let hint = download_hint(Path::new("/nonexistent/clipseg"));
    assert!(err.contains(&hint), "{err}");
    assert!(CLIPSEG_HINT.contains("hf download CIDAS/clipseg-rd64-refined --local-dir"));

    let tmp = tempfile::tempdir().unwrap();
    for missing in ["model.safetensors", "config.json"] {
        let dir = tmp.path().join(missing);
        copy_without(&fixtures().join("complex"), &dir, missing);
        let err = ClipSeg::load(&dir, &Device::Cpu).unwrap_err().to_string();
        assert!(!err.contains('\n'), "{err}");
        assert!(err.contains(missing) && err.contains(&download_hint(&dir)), "{err}");
    }
}

/// Copies a fixture, applies `edit` to one of its configs, loads the copy and returns the
/// error, checked to be one line naming the folder.
fn load_edited(variant: &str, file: &str, edit: impl FnOnce(&mut serde_json::Value)) -> String {
    let tmp = tempfile::tempdir().unwrap();
    let tmp = tmp.path();
    copy_without(&fixtures().join(variant), tmp, "");
    let path = tmp.join(file);
    let mut value: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut value);
    std::fs::write(&path, value.to_string()).unwrap();
    let err = ClipSeg::load(tmp, &Device::Cpu).expect_err("the edited config must be refused").to_string();
    assert!(!err.contains('\n'), "not one line: {err}");
    assert!(err.contains(&tmp.display().to_string()), "folder not named: {err}");
    err
}

#[test]
fn a_config_that_disagrees_with_the_weights_is_a_one_line_error() {
    let err = load_edited("complex", "config.json", |c| c["vision_config"]["hidden_size"] = 32.into());
    assert!(err.contains("tensor ") && err.contains("[24]") && err.contains("[32]"), "{err}");
    let err = load_edited("complex", "config.json", |c| c["reduce_dim"] = 8.into());
    assert!(err.contains("decoder.") && err.contains("does not match these weights"), "{err}");
    let err = load_edited("simple", "config.json", |c| c["use_complex_transposed_convolution"] = true.into());
    assert!(err.contains("no tensor") && err.contains("transposed_convolution.0"), "{err}");
    let err = load_edited("simple", "config.json", |c| c["extract_layers"] = serde_json::json!([0, 1, 2]));
    assert!(err.contains("no tensor") && err.contains("decoder.reduces.2"), "{err}");
}

/// `(file, fixture, edit, words the error must hold)`.
type ConfigCase = (&'static str, &'static str, fn(&mut serde_json::Value), &'static str);

#[test]
fn impossible_configs_are_refused_naming_the_field() {
    let cases: [ConfigCase; 8] = [
        (
            "config.json",
            "simple",
            |c| c["extract_layers"] = serde_json::json!([0, 3]),
            "extract_layers[1] is 3",
        ),
        (
            "config.json",
            "simple",
            |c| c["extract_layers"] = serde_json::json!([]),
            "extract_layers must list",
        ),
        (
            "config.json",
            "simple",
            |c| c["conditional_layer"] = 2.into(),
            "conditional_layer 2 is not a decoder step",
        ),
        ("config.json", "simple", |c| c["decoder_num_attention_heads"] = 3.into(), "does not divide"),
        ("config.json", "simple", |c| c["reduce_dim"] = (1u64 << 40).into(), "reduce_dim is"),
        (
            "config.json",
            "complex",
            |c| c["vision_config"]["patch_size"] = 2.into(),
            "patch_size of at least 4",
        ),
        (
            "preprocessor_config.json",
            "simple",
            |c| c["size"] = serde_json::json!({"height": 48, "width": 40}),
            "square",
        ),
        (
            "preprocessor_config.json",
            "simple",
            |c| c["size"] = 4.into(),
            "below the vision tower's patch_size 8",
        ),
    ];
    for (file, variant, edit, words) in cases {
        let err = load_edited(variant, file, edit);
        assert!(err.contains(file) && err.contains(words), "{variant} {file}: expected {words:?} in {err:?}");
    }
}

#[test]
fn many_views_in_batches_give_each_views_own_segmentation() {
    let model = load("complex");
    let ids = [0u32, 7, 42, 499];
    let sizes = [(20, 12), (8, 8), (33, 17), (16, 24), (5, 9), (12, 12)];
    assert!(sizes.len() > SEGMENT_BATCH, "crosses a batch boundary");
    let images: Vec<Vec<f32>> = sizes
        .iter()
        .enumerate()
        .map(|(k, &(w, h))| (0..w * h * 3).map(|i| ((i * (k + 3)) % 97) as f32 / 96.0).collect())
        .collect();
    let batch: Vec<(&[f32], usize, usize)> =
        images.iter().zip(&sizes).map(|(img, &(w, h))| (img.as_slice(), w, h)).collect();
    let conditional = model.conditional_embeddings(&[ids.to_vec()]).unwrap();
    let many = model.segment_many(&batch, &conditional).unwrap();
    assert_eq!(many.len(), sizes.len());
    for (k, &(img, w, h)) in batch.iter().enumerate() {
        let one = model.segment_ids(img, w, h, &ids).unwrap();
        assert_eq!(many[k].len(), w * h);
        assert_close(&many[k], &one, &format!("image {k} in a batch"));
    }
}

#[test]
fn the_segmenter_refuses_a_phrase_the_model_cannot_take_naming_it() {
    use transsplat_editors::Segmenter;
    let mut seg = ClipSegSegmenter::load(&fixtures().join("simple"), &Device::Cpu).unwrap();
    // The bundled tokenizer's start token does not fit the tiny model's vocabulary.
    let err = seg.prepare("the ball").unwrap_err().to_string();
    assert!(err.contains("outside vocab_size 500"), "{err}");
    let cam = transsplat_scene::Camera::pinhole("v.png", 8, 8, 10.0);
    let img = vec![0.5f32; 8 * 8 * 3];
    let views = [transsplat_editors::SourceView { index: 3, camera: &cam, image: &img }];
    let err = seg.segment(&views, "the ball").unwrap_err().to_string();
    assert!(err.contains("CLIPSeg") && err.contains("\"the ball\"") && !err.contains('\n'), "{err}");
}
