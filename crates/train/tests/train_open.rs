//! The floater check of the trainer issue, small: the quick tabletop with open
//! surroundings (`scene --open`: a checkerboard floor reaching 20 m under a sky dome, a
//! 360° orbit at low elevation) is trained briefly from a sparse cloud (every 12th true
//! centre with its true colour, as `scene` writes `points3D.txt`), and no held-out view
//! may fall far below the others: haze in front of one camera shows as exactly that.
//!
//! Measured (test PSNR, worst view below the mean), seeds 4 / 5 / 6 / 7: with the
//! distance-scaled world-size prune rule 25.94 (1.98) / 25.47 (5.05) / 26.65 (2.09) /
//! 25.64 (1.56) dB; with INRIA's fixed rule 18.03 (3.22) / 24.41 (1.65) / 19.66 (3.08) /
//! 22.64 (1.78) dB. The rule removes most of the loss, not every uneven view (seed 5),
//! so this fixed-seed test checks one run, not the distribution.
//!
//! The run uses the paper's 20 px screen-size prune, which the trainer's default leaves
//! off (as INRIA's code and gsplat do; at 256² over 7000 steps it cost 8 dB,
//! docs/results.md "Against reference trainers"). At this toy scale — 96×72, where 20 px is a fifth of
//! the image, and 900 steps after the only reset — it helps: seeds 4–8 score 25.94 /
//! 25.47 / 26.65 / 25.64 / 26.42 dB with it and 23.65 / 25.14 / 25.72 / 24.86 / 24.87 dB
//! without, whose worst views fall 2.50 / 3.95 / 4.16 / 6.39 / 3.47 dB below the mean.
//! So without the rule this short run does show haze; the test checks the run with it.

mod common;

use transsplat_scenes::SceneConfig;
use transsplat_train::{
    evaluate, fit, start, Dataset, DensifyConfig, Eval, PointCloud, Strategy, TrainConfig,
};

/// The bound: no test view more than 3 dB below the mean.
const MAX_BELOW_MEAN_DB: f32 = 3.0;
/// A floor on the mean: above every seed measured with INRIA's rule (at most 24.41 dB),
/// below every seed with ours (at least 25.47 dB).
const MIN_TEST_PSNR: f32 = 25.0;

/// The quick open tabletop at 96×72 (24 views, 3 held out) with a sparse cloud: every
/// 12th true centre with its true colour, as `scene` writes `points3D.txt`.
fn open_capture() -> ([f32; 3], Dataset) {
    let config = SceneConfig { open: true, views: 24, ..SceneConfig::quick() };
    let (scene, mut ds) = common::scene_dataset(&config, 96, 72);
    assert_eq!(ds.test.len(), 3);
    let mut cloud = PointCloud::default();
    for (i, m) in scene.gaussians.means.iter().enumerate().step_by(12) {
        cloud.positions.push(*m);
        cloud.colors.push(transsplat_scenes::edit::dc_colour(&scene.gaussians, i));
    }
    ds.points = Some(cloud);
    (scene.background, ds)
}

/// Trains `config` on the capture; returns the Gaussian count and the test scores.
fn train(ds: &Dataset, config: TrainConfig, what: &str) -> (usize, Eval) {
    let opts = common::options(config);
    let (mut trainer, _) = start(ds, &opts).unwrap();
    let points = trainer.model.len();
    fit(ds, &mut trainer, 0, |_| {}).unwrap();
    let eval = evaluate(&trainer, &ds.test);
    let views: Vec<String> = eval.per_view.iter().map(|v| format!("{} {:.2}", v.name, v.psnr)).collect();
    eprintln!(
        "open tabletop, {what}: {points} -> {} Gaussians, test PSNR {:.2} dB ({})",
        trainer.model.len(),
        eval.psnr,
        views.join(", ")
    );
    assert!(eval.psnr >= MIN_TEST_PSNR, "test PSNR {:.2} dB is below {MIN_TEST_PSNR} dB", eval.psnr);
    (trainer.model.len(), eval)
}

#[test]
fn open_surroundings_train_without_a_hazy_view() {
    let (background, ds) = open_capture();
    let config = TrainConfig {
        iterations: 1500,
        densify: DensifyConfig { max_screen_radius: Some(20.0), ..common::densify(100, 1000, 600, 300) },
        background,
        seed: 4,
        ..Default::default()
    };
    let (_, eval) = train(&ds, config, "adaptive");
    let worst = eval.worst().unwrap();
    assert!(
        worst.psnr >= eval.psnr - MAX_BELOW_MEAN_DB,
        "{} is {:.2} dB below the mean {:.2} dB: haze in front of it?",
        worst.name,
        eval.psnr - worst.psnr,
        eval.psnr
    );
}

/// The MCMC strategy on the same capture at a fixed budget, about a ninth of the
/// adaptive run's 10,411 Gaussians: it ends at the budget exactly and, at this seed,
/// reaches the same floor on the mean. Not the spread, and not every seed: at this toy
/// size and budget seeds 4 / 5 / 6 score 27.16 / 26.37 / 24.33 dB with the first test
/// view 1.68 / 4.89 / 6.44 dB below the mean (a dark floater in its sky; the adaptive
/// run has that view 2.0 dB below).
#[test]
fn mcmc_ends_at_its_budget_on_open_surroundings() {
    let (background, ds) = open_capture();
    let budget = 1100;
    let config = TrainConfig {
        iterations: 1500,
        densify: DensifyConfig { max_gaussians: Some(budget), ..common::densify(100, 1000, 0, 300) },
        background,
        seed: 4,
        strategy: Strategy::from_name("mcmc").unwrap(),
        ..Default::default()
    };
    assert_eq!(train(&ds, config, "mcmc").0, budget);
}
