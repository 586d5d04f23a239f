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

#[test]
fn projected_features_are_the_projection_of_the_features() {
    // Projecting the patch tokens before upsampling equals projecting the upsampled
    // features (both maps are linear): compare with full features times the matrix.
    let dir = ModelDir::open(&fixtures(), "DINOv2", "hf download facebook/dinov2-small").unwrap();
    let model = Dinov2::load(&dir, &Device::Cpu).unwrap();
    let (w, h) = (37, 23);
    let img: Vec<f32> = (0..w * h * 3).map(|i| ((i * 7919) % 101) as f32 / 100.0).collect();
    let (full, c) = model.features(&img, w, h).unwrap();
    let d = c / 2;
    let (proj, dp) = model.features_projected(&img, w, h, d).unwrap();
    assert_eq!((dp, proj.len()), (d, w * h * d));
    let m = transsplat_models::dinov2::projection(c, d);
    let want: Vec<f32> = (0..w * h)
        .flat_map(|p| {
            let (full, m) = (&full, &m);
            (0..d).map(move |k| (0..c).map(|ch| full[p * c + ch] * m[ch * d + k]).sum::<f32>())
        })
        .collect();
    assert_close(&proj, &want, 1e-4, "projected features");
    // A width at or above C is a no-op.
    assert_eq!(model.features_projected(&img, w, h, c + 10).unwrap().0, full);
}
