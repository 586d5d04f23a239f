//! The colour clamp's gradient rule in training (docs/method.md#m11-colour-clamp): a
//! Gaussian whose green channel starts below 0 must turn green when the images ask for
//! it under `ClampGrad::Revive`, and stays black under the exact rule (the dead
//! channel this rule exists for).

use transsplat_raster::{render, ClampGrad, RenderOptions};
use transsplat_scene::{Camera, Gaussians};
use transsplat_train::{DensifyConfig, LearningRates, Model, TrainConfig, Trainer};

const C0: f32 = 0.282_094_8;

fn camera() -> Camera {
    Camera::pinhole("v", 16, 16, 16.0)
}

/// Trains one large opaque Gaussian, colours only, towards a flat (0.2, 0.8, 0.5)
/// image; returns the rendered green at the centre pixel.
fn trained_green(rule: ClampGrad) -> f32 {
    // Raw colour 0.5 + C0 f: red 0.2, green −0.3 (clamped to 0), blue 0.5.
    let dc = [(0.2 - 0.5) / C0, (-0.3 - 0.5) / C0, 0.0];
    let g = Gaussians {
        sh_degree: 0,
        means: vec![[0.0, 0.0, 2.0]],
        log_scales: vec![[4f32.ln(); 3]], // nearly flat over the image
        rotations: vec![[1.0, 0.0, 0.0, 0.0]],
        opacity_logits: vec![6.0],
        sh: dc.to_vec(),
        ..Default::default()
    };
    let cam = camera();
    let config = TrainConfig {
        iterations: 300,
        lr: LearningRates {
            position_init: 0.0,
            position_final: 0.0,
            sh_dc: 0.05,
            opacity: 0.0,
            scaling: 0.0,
            rotation: 0.0,
            ..Default::default()
        },
        densify: DensifyConfig::disabled(),
        clamp_grad: rule,
        ..Default::default()
    };
    let mut t = Trainer::for_cameras(Model::new(g, 0), std::slice::from_ref(&cam), config).unwrap();
    let target: Vec<f32> = (0..16 * 16).flat_map(|_| [0.2, 0.8, 0.5]).collect();
    for _ in 0..300 {
        t.step(&cam, &target, None).unwrap();
    }
    let img = render(&t.splats(), &cam, &RenderOptions::default()).0;
    img.rgb[(8 * 16 + 8) * 3 + 1]
}

#[test]
fn a_channel_below_the_clamp_comes_back_only_when_revived() {
    let exact = trained_green(ClampGrad::Exact);
    let revive = trained_green(ClampGrad::Revive);
    assert_eq!(exact, 0.0, "the exact clamp passes no gradient to a clamped channel");
    assert!((revive - 0.8).abs() < 0.05, "revived green {revive}, wanted 0.8");
}
