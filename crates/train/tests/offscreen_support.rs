//! Regression: a faint, large Gaussian just right of the image passes the
//! rasterizer's radius culling while its opacity-aware support lies wholly past the
//! last tile. Training produces such Gaussians; rendering and backward must not
//! panic (they did: a reversed tile span in binning).

use transsplat_raster::{backward, render, Grads, ImageGrads, RenderOptions, Splats};
use transsplat_scene::{Camera, Gaussians};

#[test]
fn faint_gaussian_beyond_the_right_edge_renders() {
    let cam = Camera::pinhole("c", 64, 48, 50.0);
    // At depth 5: pixel x = 50 * x / 5 + 32 = 95 for x = 6.3; sigma 10 px = 1.0 world.
    let g = Gaussians {
        means: vec![[6.3, 0.0, 5.0]],
        log_scales: vec![[0.0, 0.0, 0.0]],
        rotations: vec![[1.0, 0.0, 0.0, 0.0]],
        opacity_logits: vec![(0.0045f32 / 0.9955).ln()],
        sh_degree: 0,
        sh: vec![1.0, 1.0, 1.0],
        extra: Default::default(),
    };
    let s = Splats::new(&g);
    let (img, frame) = render(&s, &cam, &RenderOptions::default());
    assert!(frame.radii()[0][0] > 0, "the Gaussian passes the radius culling");
    let mut grads = Grads::zeros(1, 0, 0);
    let v = vec![1.0f32; img.rgb.len()];
    backward(&s, &cam, &frame, &ImageGrads { rgb: &v, ..Default::default() }, &mut grads);
}
