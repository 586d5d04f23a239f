//! The floater check of the trainer issue, small: the quick tabletop with open
//! surroundings (`scene --open`: a checkerboard floor reaching 20 m under a sky dome, a
//! 360° orbit at low elevation) is trained briefly from a sparse cloud (every 12th true
//! centre with its true colour, as `scene` writes `points3D.txt`), and no held-out view
//! may fall far below the others: haze in front of one camera shows as exactly that.
//!
//! **Scored where a training view sees.** The orbit's cameras stand at three heights
//! in turn, and the lowest pitch up the most; test view 0 is one of them, and no
//! training camera at its height is within 45° of it. So its top 17 rows' middle, the
//! sky about 4.5–13° above the horizon in its direction (1,070 of its 6,912 pixels),
//! is seen by no training view (tested below, from the true scene's depth). What a
//! trainer puts there is extrapolation, which the quality issue rules is not an error,
//! and it swung view 0 by up to 11 dB between seeds (16.42 to 27.57 dB with the sky
//! dome, whose hole shows the black background; without it a smeared sky), so the
//! checks score each view over the pixels whose true surface some training view has in
//! its frame. Whole-view figures are printed.
//!
//! Measured over seeds 4 / 5 / 6 / 7 (mean test PSNR where a training view sees, the
//! worst view's distance below it; the whole views' mean after the semicolon):
//! - the trainer's defaults (the camera-reach rule, the sky dome and Gaussians that start
//!   flat on the cloud's surfaces, docs/method.md T6): 31.00 (2.67) / 30.28 (1.27) /
//!   30.42 (2.42) / 31.20 (2.30) dB, mean 30.73; whole 27.90 / 26.59 / 29.19 / 29.73;
//! - the same with INRIA's balls (`surface_init` off; the rows below start so too): 27.83 (1.36) /
//!   28.39 (0.73) / 27.96 (0.86) / 27.81 (0.87) dB, mean 28.00; whole 26.51 / 27.23 /
//!   26.05 / 25.61;
//! - the camera-reach rule without the dome (`sky_spacing` 0, the default before the
//!   dome's horizon was level): 28.12 (0.59) / 28.89 (0.41) / 28.11 (0.85) / 27.85
//!   (1.06) dB, mean 28.24; whole 26.10 / 27.47 / 27.35 / 26.22;
//! - the defaults with the 3D filter (`filter_3d` 0.2; this row and the next measured
//!   while the dome's horizon came from the mean image-up):
//!   28.06 (1.05) / 28.38 (1.19) / 28.69 (1.39) / 28.52 (0.49), mean 28.41; whole 27.60 /
//!   27.23 / 27.10 / 26.94;
//! - the dome and the filter without the camera-reach rule: 27.71 (0.84) / 27.02 (2.34) /
//!   28.41 (0.66) / 26.64 (1.02), mean 27.45;
//! - INRIA's rules (none of the three): 25.28 (2.80) / 26.93 (0.37) / 27.19 (1.21) / 27.82
//!   (0.46), mean 26.81; whole 23.65 / 25.14 / 25.71 / 24.85.
//!
//! Where the training views see, no setting leaves a view 3 dB below its mean; what
//! the whole-view scores called haze in view 0 was mostly its unseen sky. Single runs
//! at this size (96×72, 1500 steps) vary by a dB or more, so the test checks the mean
//! over four seeds against a floor between the defaults and the defaults with INRIA's
//! balls, and that at most one seed has a view more than 3 dB below its mean.

mod common;

use transsplat_builtin::{Scene, SceneConfig};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::Camera;
use transsplat_train::{
    fit, psnr, start, Dataset, DensifyConfig, PointCloud, Strategy, TrainConfig, Trainer, View,
};

/// The bound: no test view more than 3 dB below the mean.
const MAX_BELOW_MEAN_DB: f32 = 3.0;
/// A floor on the mean test PSNR where a training view sees, over the four seeds:
/// between the defaults with INRIA's balls (28.00 dB) and the defaults (30.73 dB), so
/// losing the flat start fails it.
const MIN_TEST_PSNR: f32 = 29.3;

/// The quick open tabletop at 96×72 (24 views, 3 held out) with a sparse cloud: every
/// 12th true centre with its true colour, as `scene` writes `points3D.txt`.
fn open_capture() -> ([f32; 3], Dataset, Vec<Vec<f32>>) {
    let config = SceneConfig { open: true, views: 24, ..SceneConfig::quick() };
    let (scene, mut ds) = common::scene_dataset(&config, 96, 72);
    assert_eq!(ds.test.len(), 3);
    let mut cloud = PointCloud::default();
    for (i, m) in scene.gaussians.means.iter().enumerate().step_by(12) {
        cloud.positions.push(*m);
        cloud.colors.push(transsplat_builtin::edit::dc_colour(&scene.gaussians, i));
    }
    ds.points = Some(cloud);
    let seen = ds.test.iter().map(|v| seen_by_training(&scene, &v.camera, &ds.train)).collect();
    (scene.background, ds, seen)
}

/// Per pixel of `camera`, 1 where the true surface it shows (the true scene's expected
/// depth, back-projected) lies inside some training view's frame, else 0. Occlusion is
/// not tested, so "seen" errs towards scoring a pixel. A pixel that shows no surface
/// (the background) counts as seen: it is the same from everywhere.
fn seen_by_training(scene: &Scene, camera: &Camera, train: &[View]) -> Vec<f32> {
    let (truth, _) =
        render(&Splats::new(&scene.gaussians), camera, &RenderOptions { background: scene.background });
    let (w, h) = (camera.width as usize, camera.height as usize);
    let (rotation, centre) = (camera.rotation, camera.centre());
    let in_frame = |c: &Camera, p: [f32; 3]| {
        let q: [f32; 3] =
            std::array::from_fn(|i| (0..3).map(|j| c.rotation[i][j] * p[j]).sum::<f32>() + c.translation[i]);
        let (u, v) = (c.fx * q[0] / q[2] + c.cx, c.fy * q[1] / q[2] + c.cy);
        q[2] > 0.0 && (0.0..c.width as f32).contains(&u) && (0.0..c.height as f32).contains(&v)
    };
    (0..w * h)
        .map(|k| {
            if truth.alpha[k] < 1e-3 {
                return 1.0;
            }
            let z = truth.depth[k] / truth.alpha[k];
            let (x, y) = ((k % w) as f32 + 0.5, (k / w) as f32 + 0.5);
            let q = [(x - camera.cx) / camera.fx * z, (y - camera.cy) / camera.fy * z, z];
            // World point: the camera centre plus Rᵀ q.
            let p: [f32; 3] =
                std::array::from_fn(|j| centre[j] + (0..3).map(|i| rotation[i][j] * q[i]).sum::<f32>());
            f32::from(train.iter().any(|v| in_frame(&v.camera, p)))
        })
        .collect()
}

/// Test PSNR of each view over the pixels a training view sees, and over the whole view.
fn scores(trainer: &Trainer, test: &[View], seen: &[Vec<f32>]) -> Vec<(String, f32, f32)> {
    test.iter()
        .zip(seen)
        .map(|(v, mask)| {
            let (img, _) = trainer.render(&v.camera);
            (v.camera.name.clone(), psnr(&img.rgb, &v.image, Some(mask)), psnr(&img.rgb, &v.image, None))
        })
        .collect()
}

/// Trains `config` on the capture with the trainer's default initialisation; returns the Gaussian count, the mean test PSNR where a training view sees
/// and the worst view's distance below it (named).
fn train(ds: &Dataset, seen: &[Vec<f32>], config: TrainConfig, what: &str) -> (usize, f32, (String, f32)) {
    let opts = common::options(config);
    let (mut trainer, _) = start(ds, &opts).unwrap();
    let points = trainer.model.len();
    fit(ds, &mut trainer, 0, |_| {}).unwrap();
    let views = scores(&trainer, &ds.test, seen);
    let n = views.len() as f32;
    let (mean, whole) =
        (views.iter().map(|v| v.1).sum::<f32>() / n, views.iter().map(|v| v.2).sum::<f32>() / n);
    let listed: Vec<String> =
        views.iter().map(|v| format!("{} {:.2} (whole {:.2})", v.0, v.1, v.2)).collect();
    eprintln!(
        "open tabletop, {what}: {points} -> {} Gaussians, test PSNR where seen {mean:.2} dB, whole views {whole:.2} ({})",
        trainer.model.len(),
        listed.join(", ")
    );
    let worst = views.iter().min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
    (trainer.model.len(), mean, (worst.0.clone(), mean - worst.1))
}

/// The test view with sky no training view sees is view 0 (a seventh of it, in its
/// top rows); the others have at most a few pixels at their edges that none sees.
#[test]
fn only_the_first_test_views_top_is_unseen() {
    let (_, ds, seen) = open_capture();
    let unseen: Vec<usize> = seen.iter().map(|m| m.iter().filter(|&&s| s == 0.0).count()).collect();
    let pixels = seen[0].len();
    assert!(
        unseen[0] > pixels / 8 && unseen[1..].iter().all(|&u| u < pixels / 100),
        "unseen pixels per test view: {unseen:?} of {pixels}"
    );
    let w = ds.test[0].camera.width as usize;
    let top: usize =
        seen[0][..w * ds.test[0].camera.height as usize / 4].iter().filter(|&&s| s == 0.0).count();
    assert!(top * 10 >= unseen[0] * 9, "view 0: {top} of its {} unseen pixels in its top quarter", unseen[0]);
}

#[test]
fn open_surroundings_train_without_a_hazy_view() {
    let (background, ds, seen) = open_capture();
    let (mut hazy, mut means) = (Vec::new(), Vec::new());
    for seed in 4..8 {
        let config = TrainConfig {
            iterations: 1500,
            densify: common::densify(100, 1000, 600, 300),
            background,
            seed,
            ..Default::default()
        };
        let (_, mean, (worst, below)) = train(&ds, &seen, config, &format!("adaptive, seed {seed}"));
        if below > MAX_BELOW_MEAN_DB {
            hazy.push(format!("seed {seed}: {worst} {below:.2} dB below the mean {mean:.2}"));
        }
        means.push(mean);
    }
    let mean = means.iter().sum::<f32>() / means.len() as f32;
    assert!(
        mean >= MIN_TEST_PSNR,
        "test PSNR where seen {mean:.2} dB over the seeds ({means:?}) is below {MIN_TEST_PSNR} dB"
    );
    assert!(
        hazy.len() <= 1,
        "a view far below the mean (haze in front of it?) in more than one seed: {hazy:?}"
    );
}

/// The MCMC strategy on the same capture at a fixed budget, about a seventeenth of the
/// adaptive runs' Gaussians: it ends at the budget exactly, and at this seed without a
/// view 3 dB below the mean where a training view sees (27.65 dB, the worst view 0.96
/// below; 26.21 over the whole views).
#[test]
fn mcmc_ends_at_its_budget_on_open_surroundings() {
    let (background, ds, seen) = open_capture();
    let budget = 1100;
    let config = TrainConfig {
        iterations: 1500,
        densify: DensifyConfig { max_gaussians: Some(budget), ..common::densify(100, 1000, 0, 300) },
        background,
        seed: 4,
        strategy: Strategy::from_name("mcmc").unwrap(),
        ..Default::default()
    };
    let (count, mean, (worst, below)) = train(&ds, &seen, config, "mcmc");
    assert_eq!(count, budget);
    assert!(below <= MAX_BELOW_MEAN_DB, "MCMC: {worst} {below:.2} dB below the mean {mean:.2} where seen");
}
