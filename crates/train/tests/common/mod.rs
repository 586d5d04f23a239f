//! Shared by the integration tests that train on the built-in tabletop scene.
#![allow(dead_code)] // each test file uses some of these helpers

use transsplat_builtin::{build, is_test, Scene, SceneConfig};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_train::dataset::{scale_camera, Dataset, DatasetKind, View};
use transsplat_train::{DensifyConfig, FitOptions, TrainConfig};

/// The short runs' densification: every 100 steps from `from_step` until `until_step`,
/// an opacity reset every `reset` steps (0: none), the SH degree raised every
/// `sh_interval` steps; INRIA's thresholds otherwise.
pub fn densify(from_step: u64, until_step: u64, reset: u64, sh_interval: u64) -> DensifyConfig {
    DensifyConfig {
        from_step,
        interval: 100,
        until_step,
        opacity_reset_interval: reset,
        sh_degree_interval: sh_interval,
        ..Default::default()
    }
}

/// A short run of `config`: SH degree at most 1, no random points, no evaluation
/// during the run.
pub fn options(config: TrainConfig) -> FitOptions {
    FitOptions { config, max_sh_degree: 1, random_points: 0, eval_every: 0, ..Default::default() }
}

/// The quick tabletop scene and a dataset of its renders at `width × height`, every
/// 8th view held out for testing; no point cloud.
pub fn tabletop(width: usize, height: usize) -> (Scene, Dataset) {
    scene_dataset(&SceneConfig::quick(), width, height)
}

/// The tabletop built with `config` and a dataset of its renders at `width × height`,
/// every 8th view held out for testing; no point cloud.
pub fn scene_dataset(config: &SceneConfig, width: usize, height: usize) -> (Scene, Dataset) {
    let scene = build("tabletop", config).unwrap();
    let splats = Splats::new(&scene.gaussians);
    let mut ds = Dataset {
        kind: DatasetKind::Inria,
        cameras: scene.cameras.clone(),
        train: Vec::new(),
        test: Vec::new(),
        points: None,
        points_path: None,
    };
    for (k, cam) in scene.cameras.iter().enumerate() {
        let camera = scale_camera(cam, width, height);
        let (img, _) = render(&splats, &camera, &RenderOptions { background: scene.background });
        let view = View { camera, image: img.rgb, weights: None, path: cam.name.clone().into() };
        if is_test(k) {
            ds.test.push(view)
        } else {
            ds.train.push(view)
        }
    }
    (scene, ds)
}
