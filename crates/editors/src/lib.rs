//! 2D editors: from the source renders of the edit views and an instruction, each
//! returns per view the edited image Î_v, a text-relevant attention map A_v and an
//! optional mask (docs/method.md#e1-the-editor-contract). The features E_v and Φ_v of the edited
//! images are not the editor's business: the edit engine computes them with the one
//! feature model of the job, for source renders and edited images alike.
//!
//! - [`folder`]: edited images made by any 2D tool, named like the views (by content),
//!   possibly assembled from shards.
//! - [`command`]: runs a user command on an exported folder (a file protocol), as a
//!   [`child`] process: own process group, output to logs, time limit, cancellation.
//! - [`segment`]: segmenters (views → target masks) and [`Segmented`], the one door
//!   through which a segmenter's masks reach the engine: CLIPSeg from a phrase
//!   (`transsplat_models`), [`MaskFolder`] (masks made elsewhere), a Python callable.
//! - [`features`]: built-in appearance features Φ (CIELAB + local texture statistics),
//!   the fallback semantic features E used when no feature model is given, and the
//!   change map that serves as attention when an editor gives none.

pub mod child;
pub mod command;
pub mod features;
pub mod folder;
pub mod phrase;
pub mod resize;
pub mod segment;

pub use command::CommandEditor;
pub use features::{appearance, change_attention, semantic_fallback};
pub use folder::{
    content_name, export_views, exported_shard, ExportSpec, Exported, FolderEditor, Shard, ViewEntry,
    ViewsListing,
};
pub use resize::resize_bilinear;
pub use segment::{check_masks, MaskFolder, Segmented, Segmenter};

use transsplat_scene::Camera;

/// One edit view as the editor receives it.
#[derive(Clone, Copy, Debug)]
pub struct SourceView<'a> {
    /// Index of the view in the scene's camera list.
    pub index: usize,
    pub camera: &'a Camera,
    /// The current render, `H × W × 3` in [0, 1].
    pub image: &'a [f32],
}

impl SourceView<'_> {
    /// `(width, height)` of the view (its camera's image size).
    pub fn size(&self) -> (usize, usize) {
        (self.camera.width as usize, self.camera.height as usize)
    }

    /// Errors unless `image` holds `H × W × 3` values for the camera's size.
    pub fn check(&self) -> Result<(), Error> {
        let (w, h) = self.size();
        if w == 0 || h == 0 || self.image.len() != w * h * 3 {
            return Err(Error::Invalid(format!(
                "view {} ({}): image has {} values but the camera is {w}x{h} (needs {})",
                self.index,
                self.camera.name,
                self.image.len(),
                w * h * 3
            )));
        }
        Ok(())
    }
}

/// The editor's output for one view; every plane is row-major at the view's size.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EditedView {
    pub width: usize,
    pub height: usize,
    /// Edited image Î_v, `H × W × 3`.
    pub image: Vec<f32>,
    /// Text-relevant attention A_v ≥ 0, `H × W`.
    pub attention: Vec<f32>,
    /// Optional target mask in [0, 1], `H × W` (inside where > 0.5): the editor's own,
    /// or a segmenter's ([`Segmented`] replaces the editor's).
    pub mask: Option<Vec<f32>>,
}

impl EditedView {
    /// An edited view from its image (`H × W × 3`), attention (`H × W`; NaN and
    /// negative values become 0) and optional mask (`H × W`, clamped to [0, 1], NaN
    /// read as 0): the one way every editor builds its output. The edit engine checks
    /// every plane against its camera.
    ///
    /// # Panics
    /// When the attention does not match `w × h` (an editor's own bug, not bad input).
    pub fn new(image: Vec<f32>, w: usize, h: usize, mut attention: Vec<f32>, mask: Option<Vec<f32>>) -> Self {
        assert_eq!(attention.len(), w * h, "attention does not match {w}x{h}");
        for a in attention.iter_mut() {
            if !(a.is_finite() && *a > 0.0) {
                *a = 0.0;
            }
        }
        let mask =
            mask.map(|m| m.into_iter().map(|v| if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) }).collect());
        EditedView { width: w, height: h, image, attention, mask }
    }
}

/// Errors of the editors; messages are one line meant for the user.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The instruction cannot be carried out (empty, or names nothing known).
    #[error("{0}")]
    Instruction(String),
    /// No usable edited view at all.
    #[error("{0}")]
    NoEdits(String),
    /// An external command failed.
    #[error("{0}")]
    Command(String),
    /// A view or argument the editor cannot work with (e.g. an image whose size does
    /// not match its camera).
    #[error("{0}")]
    Invalid(String),
    #[error(transparent)]
    Io(#[from] transsplat_scene::Error),
}

/// A 2D editor. `edit` returns one entry per input view, `None` where the editor
/// produced nothing for that view (the engine uses the rest and warns); it errors
/// when no view could be edited.
pub trait Editor {
    /// Short name for logs and reports.
    fn name(&self) -> &str;
    /// Edits the views for `prompt`.
    fn edit(&mut self, views: &[SourceView], prompt: &str) -> Result<Vec<Option<EditedView>>, Error>;
    /// Says that the next calls will, together, ask for `views` views (a caller that
    /// hands the views over in groups), so progress can count them as one stage.
    fn expect_views(&mut self, _views: usize) {}
}

impl<E: Editor + ?Sized> Editor for Box<E> {
    fn name(&self) -> &str {
        (**self).name()
    }

    fn edit(&mut self, views: &[SourceView], prompt: &str) -> Result<Vec<Option<EditedView>>, Error> {
        (**self).edit(views, prompt)
    }

    fn expect_views(&mut self, views: usize) {
        (**self).expect_views(views)
    }
}

#[cfg(test)]
mod tests {
    use super::EditedView;

    #[test]
    fn new_sanitises_attention_and_mask() {
        let v = EditedView::new(
            vec![0.2; 12],
            2,
            2,
            vec![f32::NAN, -1.0, 0.5, 2.0],
            Some(vec![1.5, -0.5, 0.3, f32::NAN]),
        );
        assert_eq!(v.attention, vec![0.0, 0.0, 0.5, 2.0]);
        assert_eq!(v.mask, Some(vec![1.0, 0.0, 0.3, 0.0]));
        assert_eq!((v.width, v.height, v.image.len()), (2, 2, 12));
    }
}
