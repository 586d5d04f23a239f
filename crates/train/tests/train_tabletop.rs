//! Training from the rendered images of the built-in quick tabletop
//! (`transsplat_scenes`, ~5k Gaussians, 16 views), at 64x48, starting from a sparse
//! noisy point cloud: every 8th true centre, jittered by 2 cm, with random colours.
//! The held-out views (every 8th camera) must reach a stated PSNR within a bounded
//! number of steps.

mod common;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use transsplat_train::{evaluate, fit, start, DensifyConfig, FitOptions, PointCloud, TrainConfig};

/// The quality bar on the held-out views. Measured: 9.1 dB at initialisation,
/// 26.8 dB after the 1000 steps (683 -> ~6200 Gaussians), about 7 s in release.
const MIN_TEST_PSNR: f32 = 24.0;

#[test]
fn tabletop_training_reaches_the_test_psnr() {
    let (scene, mut ds) = common::tabletop(64, 48);
    let bg = scene.background;
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut cloud = PointCloud::default();
    for m in scene.gaussians.means.iter().step_by(8) {
        let u: f32 = rng.gen_range(1e-6..1.0);
        let jitter: [f32; 3] =
            std::array::from_fn(|_| 0.02 * (-2.0 * u.ln()).sqrt() * rng.gen_range(-1.0f32..1.0));
        cloud.positions.push(std::array::from_fn(|k| m[k] + jitter[k]));
        cloud.colors.push([rng.gen(), rng.gen(), rng.gen()]);
    }
    let start_count = cloud.len();
    ds.points = Some(cloud);

    let iterations = 1000;
    let opts = FitOptions {
        config: TrainConfig {
            iterations,
            densify: DensifyConfig {
                from_step: 100,
                interval: 100,
                until_step: 650,
                opacity_reset_interval: 0,
                sh_degree_interval: 250,
                ..Default::default()
            },
            background: bg,
            seed: 2,
            ..Default::default()
        },
        max_sh_degree: 1,
        random_points: 0,
        eval_every: 0,
    };
    let (mut trainer, _) = start(&ds, &opts).unwrap();
    let before = evaluate(&trainer, &ds.test).psnr;
    let after = fit(&ds, &mut trainer, 0, |_| {}).unwrap().psnr;
    eprintln!(
        "tabletop: test PSNR {before:.2} dB -> {after:.2} dB after {iterations} steps; {start_count} -> {} Gaussians",
        trainer.model.len()
    );
    assert!(
        after >= MIN_TEST_PSNR,
        "test PSNR {after:.2} dB is below {MIN_TEST_PSNR} dB (started at {before:.2})"
    );
    assert!(after > before + 6.0);
}
