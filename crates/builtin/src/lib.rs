//! Built-in benchmark scenes for transsplat: procedural, deterministic 3DGS scenes
//! built directly as Gaussians, with a label per Gaussian and ground truth.
//!
//! - [`catalog`]: the scenes ([`SCENE_NAMES`]: `tabletop`, `occluded`, `garden`), [`build`],
//!   [`Scene`], [`SceneObject`], [`SceneConfig`] (seed, detail, resolution, views).
//! - [`rig`]: cameras on rings in front of the backdrop looking at the scene centre;
//!   [`is_test`] marks every 8th camera (llffhold = 8).
//! - [`edit`]: ground-truth edits by label, [`recolor`] and [`retexture`] with a
//!   [`Material`], and the global [`restyle`] with a [`Style`]; they return new
//!   Gaussians.
//! - [`masks`]: per-view label masks and soft masks rendered with the rasterizer.
//! - [`dataset`]: [`write_dataset`], the folder `transsplat scene NAME --out DIR` writes.
//! - [`texture`]: the procedural noise and patterns.
//! - [`simulated`]: the simulated 2D editor: ground-truth edits of these scenes,
//!   corrupted per view the way 2D editors fail, at a chosen severity. It is the
//!   benchmark's editor, not a production one, so it lives beside the scenes.
//!
//! Same name, config and seed give the same Gaussians bit for bit: sampling uses a
//! built-in SplitMix64 generator and no parallelism.

pub mod build;
pub mod catalog;
pub mod dataset;
pub mod edit;
pub mod masks;
pub mod rig;
mod rng;
pub mod segmenter;
pub mod simulated;
pub mod texture;

pub use catalog::{
    build, labels_from_extra, with_labels, Scene, SceneConfig, SceneObject, LABEL_PROPERTY, SCENE_NAMES,
};
pub use dataset::{write_dataset, DatasetSummary, Labels, WriteOptions};
pub use edit::{recolor, restyle, retexture, Material, Style};
pub use masks::{one_hot, render_labels, LabelRender};
pub use rig::{is_test, Rig};
pub use segmenter::SimulatedSegmenter;
pub use simulated::{Corruption, SimulatedEditor};

use std::path::PathBuf;

/// Errors of this crate; every message is one line meant for the user.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("unknown scene {name:?}; available scenes: {}", available.join(", "))]
    UnknownScene { name: String, available: Vec<String> },
    #[error("unknown object {name:?}; the scene's objects are: {objects}")]
    UnknownObject { name: String, objects: String },
    #[error("{0}")]
    Invalid(String),
    #[error("{}: {msg}", path.display())]
    Output { path: PathBuf, msg: String },
    #[error(transparent)]
    Io(#[from] transsplat_scene::Error),
}

/// A scene error met by the simulated editor, as an editor error.
impl From<Error> for transsplat_editors::Error {
    fn from(e: Error) -> Self {
        match e {
            Error::Io(io) => transsplat_editors::Error::Io(io),
            e => transsplat_editors::Error::Invalid(e.to_string()),
        }
    }
}

impl Scene {
    /// [`recolor`] of this scene's Gaussians; `label` must be an object's label.
    pub fn recolor(&self, label: u32, rgb: [f32; 3]) -> Result<transsplat_scene::Gaussians, Error> {
        self.check_label(label)?;
        recolor(&self.gaussians, &self.labels, label, rgb)
    }

    /// [`retexture`] of this scene's Gaussians; `label` must be an object's label.
    pub fn retexture(&self, label: u32, material: Material) -> Result<transsplat_scene::Gaussians, Error> {
        self.check_label(label)?;
        retexture(&self.gaussians, &self.labels, label, material)
    }

    /// [`restyle`] of this scene's Gaussians (every Gaussian, the background included).
    pub fn restyle(&self, style: Style) -> Result<transsplat_scene::Gaussians, Error> {
        restyle(&self.gaussians, style)
    }

    fn check_label(&self, label: u32) -> Result<(), Error> {
        if self.object_by_label(label).is_none() {
            return Err(Error::UnknownObject { name: format!("label {label}"), objects: self.object_list() });
        }
        Ok(())
    }
}
