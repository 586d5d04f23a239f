//! DINOv2 features against transformers' `Dinov2Model` on a tiny random model (fixture by
//! `tools/model_fixtures_dinov2.py`): the native grid (no position interpolation) and a
//! non-square grid (bicubic position interpolation), the raw hidden states and the whole
//! pipeline (bicubic resize, ImageNet normalisation, bilinear upsampling).

use std::path::PathBuf;

use candle_core::{Device, Tensor};
use transsplat_models::dinov2::Dinov2;
use transsplat_models::ModelDir;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/dinov2")
}

fn values(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1().unwrap()
}

fn assert_close(got: &[f32], want: &[f32], tol: f32, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-12);
    let err = got.iter().zip(want).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(err <= tol * scale, "{what}: max error {err:e} vs scale {scale:e}");
}

#[test]
fn features_match_transformers_on_native_and_interpolated_grids() {
    let r = candle_core::safetensors::load(fixtures().join("reference.safetensors"), &Device::Cpu).unwrap();
    let dir = ModelDir::open(&fixtures(), "DINOv2", "hf download facebook/dinov2-small").unwrap();
    let model = Dinov2::load(&dir, &Device::Cpu).unwrap();
    let c = model.channels();
    for (i, grid) in [(4, 4), (3, 5)].into_iter().enumerate() {
        let img = &r[&format!("image{i}")];
        let (h, w, _) = img.dims3().unwrap();
        assert_eq!(model.grid(w, h), grid);
        let (feat, channels) = model.features(&values(img), w, h).unwrap();
        assert_eq!(channels, c);
        assert_eq!(feat.len(), h * w * c);
        let rows: Vec<f32> =
            (0..h).step_by(4).flat_map(|y| feat[y * w * c..(y + 1) * w * c].to_vec()).collect();
        assert_close(&rows, &values(&r[&format!("features{i}.rows4")]), 1e-4, &format!("features {w}x{h}"));
    }
}

#[test]
fn bad_image_size_is_an_error() {
    let dir = ModelDir::open(&fixtures(), "DINOv2", "hf download facebook/dinov2-small").unwrap();
    let model = Dinov2::load(&dir, &Device::Cpu).unwrap();
    assert!(model.features(&[0.5; 10], 4, 4).is_err());
}
