//! Training from the rendered images of the built-in quick tabletop
//! (`transsplat_builtin`, ~5k Gaussians, 16 views), at 64x48, starting from a sparse
//! noisy point cloud: every 8th true centre, jittered by 2 cm, with random colours.
//! The held-out views (every 8th camera) must reach a stated PSNR within a bounded
//! number of steps.

mod common;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use transsplat_train::{evaluate, fit, start, PointCloud, TrainConfig};

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
    let opts = common::options(TrainConfig {
        iterations,
        densify: common::densify(100, 650, 0, 250),
        background: bg,
        seed: 2,
        ..Default::default()
    });
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
