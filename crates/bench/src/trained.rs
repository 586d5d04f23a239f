//! A built-in scene as users bring it: trained from its own renders.
//!
//! The built-in scenes are built directly as Gaussians; a scene trained from photos is
//! different (many overlapping semi-transparent layers, view-dependent SH, colours near
//! the clamp). [`train_from_renders`] writes the built-in scene's dataset (its images,
//! cameras and sparse points, `transsplat_builtin::write_dataset`), loads it as `train`
//! does and trains a scene from it with the default settings, holding out the same test
//! views the benchmark scores. The ground truth stays the built-in scene's: the edit of
//! a trained scene is scored against the true edited renders.

use std::path::Path;
use std::sync::atomic::AtomicBool;
use transsplat_builtin::{write_dataset, Scene, WriteOptions};
use transsplat_scene::Gaussians;
use transsplat_train::dataset::{self, Dataset, LoadOptions};
use transsplat_train::{fit_with, start, Control, FitOptions, FitState, TrainConfig};

/// Why a scene could not be trained from its renders.
#[derive(Debug, thiserror::Error)]
pub enum TrainedError {
    #[error(transparent)]
    Scene(#[from] transsplat_builtin::Error),
    #[error(transparent)]
    Io(#[from] transsplat_scene::Error),
    #[error("training the scene from its renders: {0}")]
    Train(#[from] transsplat_train::TrainError),
}

/// The scene trained for `steps` steps from the renders of `scene`'s training views
/// (every 8th view held out), its dataset written under `work` and removed afterwards;
/// returns the Gaussians and the test PSNR of the trained scene against the true renders.
pub fn train_from_renders(
    scene: &Scene,
    steps: u64,
    seed: u64,
    work: &Path,
    cancel: Option<&AtomicBool>,
    on_step: &mut dyn FnMut(u64, u64),
) -> Result<(Gaussians, f32), TrainedError> {
    let data = work.join("dataset");
    write_dataset(scene, &data, &WriteOptions::default(), &mut |_, _| {})?;
    let ds = dataset::load(&data, &LoadOptions { background: scene.background, ..Default::default() })?;
    let (g, psnr) = train_dataset(&ds, steps, seed, scene.background, cancel, on_step)?;
    std::fs::remove_dir_all(&data).map_err(|e| transsplat_scene::Error::io(&data, e))?;
    tracing::info!(
        "trained {} from its renders: {steps} steps, {} Gaussians, test PSNR {psnr:.2} dB",
        scene.name,
        g.len()
    );
    Ok((g, psnr))
}

/// A scene trained from `ds` for `steps` steps with the default settings (as `transsplat
/// train` with its defaults, rendering over `background`); returns the Gaussians and the
/// test PSNR.
pub fn train_dataset(
    ds: &Dataset,
    steps: u64,
    seed: u64,
    background: [f32; 3],
    cancel: Option<&AtomicBool>,
    on_step: &mut dyn FnMut(u64, u64),
) -> Result<(Gaussians, f32), TrainedError> {
    let opts = FitOptions {
        config: TrainConfig { iterations: steps, background, seed, ..Default::default() },
        max_sh_degree: 3,
        random_points: 100_000,
        eval_every: 0,
        ..Default::default()
    };
    let (mut trainer, _) = start(ds, &opts)?;
    let mut control = Control { cancel, ..Default::default() };
    let eval =
        fit_with(ds, &mut trainer, &mut FitState::new(seed), 0, &mut control, |p| on_step(p.step, steps))?;
    // What a renderer draws: with the trainer's 3D filter baked in, as `train` writes it.
    Ok((trainer.exported().into_owned(), eval.psnr))
}
