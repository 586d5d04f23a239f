//! Segmenters: the mask of the edit's target in each view, whichever way it is made.
//!
//! The paper restricts the support of view v to
//!
//! ```text
//! Ω_v = {Ā_v ≥ δ_a} ∩ M_sam^v
//! ```
//!
//! the thresholded, normalised edit attention intersected with a segmentation of the
//! target (App. A, Prototype Extraction). The edit engine already honours a mask when an
//! editor hands one over ([`EditedView::mask`]: inside where > 0.5); this module is the
//! one door through which a mask reaches it from a segmenter:
//!
//! - [`Segmenter`]: one job, views → masks. Implemented by the built-in CLIPSeg
//!   (`transsplat_models::clipseg`, from a phrase), by [`MaskFolder`] (masks made
//!   elsewhere, one grey PNG per view) and by the Python package (a callable).
//! - [`Segmented`]: any [`Editor`] with a segmenter attached. It runs the editor, then
//!   the segmenter on the source renders of the views the editor edited (the target is
//!   segmented as it is before the edit), checks every mask ([`check_masks`]) and sets
//!   each edited view's `mask` to it, **replacing any mask the editor gave**.
//!
//! A view where the segmenter finds nothing (it returns `None`, or a mask with no value
//! above 0.5) is a miss: the view gets no mask (the editor's is dropped too), so its
//! support is its attention alone, as without a segmenter. A miss is not evidence that
//! the target is absent; an empty mask would take away support the other views give
//! (docs/results.md, "Segmentation masks", measured both ways). Misses in some views are
//! logged with a warning naming them; a miss in every view is an error.

use crate::folder::{content_name, read_grey};
use crate::{EditedView, Editor, Error, SourceView};
use std::path::{Path, PathBuf};

/// A segmenter: per view, the mask of what `phrase` names.
pub trait Segmenter {
    /// Short name for logs and reports.
    fn name(&self) -> &str;
    /// One entry per view: a mask `H × W` at the view's size with values in [0, 1]
    /// (inside where > 0.5), or `None` where the target was not found.
    fn segment(&mut self, views: &[SourceView], phrase: &str) -> Result<Vec<Option<Vec<f32>>>, Error>;
}

impl<S: Segmenter + ?Sized> Segmenter for Box<S> {
    fn name(&self) -> &str {
        (**self).name()
    }

    fn segment(&mut self, views: &[SourceView], phrase: &str) -> Result<Vec<Option<Vec<f32>>>, Error> {
        (**self).segment(views, phrase)
    }
}

/// An editor whose edited views get their masks from a segmenter (see the module doc).
#[derive(Clone)]
pub struct Segmented<E, S> {
    editor: E,
    segmenter: S,
    phrase: String,
    name: String,
}

impl<E: Editor, S: Segmenter> Segmented<E, S> {
    /// `editor` with the masks of what `phrase` names, made by `segmenter`.
    pub fn new(editor: E, segmenter: S, phrase: impl Into<String>) -> Self {
        let name = format!("{}+{}", editor.name(), segmenter.name());
        Segmented { editor, segmenter, phrase: phrase.into(), name }
    }
}

impl<E: Editor, S: Segmenter> Editor for Segmented<E, S> {
    /// `<editor>+<segmenter>`.
    fn name(&self) -> &str {
        &self.name
    }

    fn expect_views(&mut self, views: usize) {
        self.editor.expect_views(views)
    }

    fn edit(&mut self, views: &[SourceView], prompt: &str) -> Result<Vec<Option<EditedView>>, Error> {
        let mut edited = self.editor.edit(views, prompt)?;
        if edited.len() != views.len() {
            // The engine refuses this, naming the editor.
            return Ok(edited);
        }
        let done: Vec<usize> = (0..views.len()).filter(|&k| edited[k].is_some()).collect();
        if done.is_empty() {
            return Ok(edited);
        }
        let sources: Vec<SourceView> = done.iter().map(|&k| views[k]).collect();
        let masks = self.segmenter.segment(&sources, &self.phrase)?;
        let masks = check_masks(self.segmenter.name(), &sources, masks, &self.phrase)?;
        for (k, mask) in done.into_iter().zip(masks) {
            if let Some(e) = edited[k].as_mut() {
                // a miss constrains nothing: the view's attention alone decides its support
                e.mask = mask.iter().any(|&m| m > 0.5).then_some(mask);
            }
        }
        Ok(edited)
    }
}

/// Checks a segmenter's output for `views` and returns one mask per view, the empty
/// mask for a miss. Errors ([`Error::Invalid`], naming the view by index and camera
/// name): a count that differs from the views', a mask of the wrong length, a value
/// outside [0, 1] or not finite, and a miss in every view. Misses in some views only
/// are logged with a warning.
pub fn check_masks(
    segmenter: &str,
    views: &[SourceView],
    masks: Vec<Option<Vec<f32>>>,
    phrase: &str,
) -> Result<Vec<Vec<f32>>, Error> {
    if masks.len() != views.len() {
        return Err(Error::Invalid(format!(
            "the segmenter ({segmenter}) returned {} masks for {} views",
            masks.len(),
            views.len()
        )));
    }
    let mut out = Vec::with_capacity(views.len());
    let mut misses = Vec::new();
    for (v, mask) in views.iter().zip(masks) {
        let (w, h) = v.size();
        let view = format!("view {} ({})", v.index, v.camera.name);
        let Some(mask) = mask else {
            misses.push(v.camera.name.clone());
            out.push(vec![0.0; w * h]);
            continue;
        };
        if mask.len() != w * h {
            return Err(Error::Invalid(format!(
                "{view}: the segmenter ({segmenter}) gave a mask of {} values, the view is {w}x{h} (needs {})",
                mask.len(),
                w * h
            )));
        }
        if let Some(p) = mask.iter().position(|m| !(0.0..=1.0).contains(m)) {
            return Err(Error::Invalid(format!(
                "{view}: the segmenter ({segmenter}) gave the value {} at pixel ({}, {}); masks are in [0, 1]",
                mask[p],
                p % w,
                p / w
            )));
        }
        if !mask.iter().any(|&m| m > 0.5) {
            misses.push(v.camera.name.clone());
        }
        out.push(mask);
    }
    let what = if phrase.trim().is_empty() { String::new() } else { format!(" for {phrase:?}") };
    if misses.len() == views.len() {
        return Err(Error::Invalid(format!(
            "the segmenter ({segmenter}) found nothing{what} in any view ({} views, no mask value above 0.5)",
            views.len()
        )));
    }
    if !misses.is_empty() {
        let shown: Vec<&str> = misses.iter().take(8).map(String::as_str).collect();
        let more = if misses.len() > shown.len() {
            format!(" and {} more", misses.len() - shown.len())
        } else {
            String::new()
        };
        tracing::warn!(
            "the segmenter ({segmenter}) found nothing{what} in {} of {} views ({}{more}); their attention alone decides their support",
            misses.len(),
            views.len(),
            shown.join(", ")
        );
    }
    Ok(out)
}

/// Masks made elsewhere, one grey PNG per view in a folder: `DIR/<stem>.png`, the stem
/// of the camera's image name (`00012.png` → `00012`), or the view's content name
/// (`<stem>.<key>.png`, as `transsplat views export` names the renders) when the scene is
/// known. Values are the grey level in [0, 1] (inside where > 0.5). A view without a
/// file, or with a file of another size than the view, is an error naming the file.
/// The phrase is not used.
#[derive(Clone, Debug)]
pub struct MaskFolder {
    dir: PathBuf,
    scene: Option<String>,
}

impl MaskFolder {
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        MaskFolder { dir: dir.into(), scene: None }
    }

    /// Also reads masks under the content names of the scene with this
    /// [`fingerprint::scene`](transsplat_scene::fingerprint::scene).
    pub fn for_scene(mut self, scene: impl Into<String>) -> Self {
        self.scene = Some(scene.into());
        self
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Errors unless the folder exists (cheap: nothing is read).
    pub fn check(&self) -> Result<(), Error> {
        if self.dir.is_dir() {
            Ok(())
        } else {
            Err(Error::Invalid(format!("{}: the mask folder does not exist", self.dir.display())))
        }
    }

    /// The mask file of view `v`: its content name if that file exists, else its stem.
    fn file_of(&self, v: &SourceView) -> PathBuf {
        if let Some(fp) = &self.scene {
            let named = self.dir.join(format!("{}.png", content_name(v.camera, Some(fp))));
            if named.is_file() {
                return named;
            }
        }
        self.dir.join(format!("{}.png", v.camera.stem()))
    }
}

impl Segmenter for MaskFolder {
    fn name(&self) -> &str {
        "masks"
    }

    fn segment(&mut self, views: &[SourceView], _phrase: &str) -> Result<Vec<Option<Vec<f32>>>, Error> {
        self.check()?;
        views
            .iter()
            .map(|v| {
                let path = self.file_of(v);
                if !path.is_file() {
                    return Err(Error::Invalid(format!(
                        "{}: no mask for view {} ({}); the mask folder needs a grey PNG for every edited view",
                        path.display(),
                        v.index,
                        v.camera.name
                    )));
                }
                let (grey, gw, gh) = read_grey(&path)?;
                let (w, h) = v.size();
                if (gw, gh) != (w, h) {
                    return Err(Error::Invalid(format!(
                        "{}: mask is {gw}x{gh} but view {} ({}) is {w}x{h}",
                        path.display(),
                        v.index,
                        v.camera.name
                    )));
                }
                Ok(Some(grey))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::folder::tests::camera;
    use transsplat_scene::{image, Camera};

    /// An editor that returns the source with a constant attention, an editor mask of
    /// ones, and `None` for the views listed in `skip`.
    struct Echo {
        skip: Vec<usize>,
    }

    impl Editor for Echo {
        fn name(&self) -> &str {
            "echo"
        }

        fn edit(&mut self, views: &[SourceView], _prompt: &str) -> Result<Vec<Option<EditedView>>, Error> {
            Ok(views
                .iter()
                .enumerate()
                .map(|(k, v)| {
                    let (w, h) = v.size();
                    (!self.skip.contains(&k)).then(|| {
                        EditedView::new(v.image.to_vec(), w, h, vec![1.0; w * h], Some(vec![1.0; w * h]))
                    })
                })
                .collect())
        }
    }

    /// A segmenter that hands out fixed masks and records the views it was asked about.
    struct Fixed {
        masks: Vec<Option<Vec<f32>>>,
        asked: Vec<usize>,
        phrase: String,
    }

    impl Segmenter for Fixed {
        fn name(&self) -> &str {
            "fixed"
        }

        fn segment(&mut self, views: &[SourceView], phrase: &str) -> Result<Vec<Option<Vec<f32>>>, Error> {
            self.asked = views.iter().map(|v| v.index).collect();
            self.phrase = phrase.to_string();
            Ok(self.masks.clone())
        }
    }

    fn fixed(masks: Vec<Option<Vec<f32>>>) -> Fixed {
        Fixed { masks, asked: Vec::new(), phrase: String::new() }
    }

    fn views_of<'a>(cams: &'a [Camera], src: &'a [f32]) -> Vec<SourceView<'a>> {
        cams.iter().enumerate().map(|(i, c)| SourceView { index: 10 + i, camera: c, image: src }).collect()
    }

    #[test]
    fn masks_replace_the_editors_on_the_edited_views_only() {
        let cams = [camera("a.png", 2, 2), camera("b.png", 2, 2), camera("c.png", 2, 2)];
        let src = vec![0.5f32; 12];
        let views = views_of(&cams, &src);
        // view b is not edited: the segmenter sees a and c only
        let seg = fixed(vec![Some(vec![1.0, 0.0, 0.25, 0.75]), None]);
        let mut e = Segmented::new(Echo { skip: vec![1] }, seg, "the ball");
        assert_eq!(e.name(), "echo+fixed");
        let out = e.edit(&views, "make the ball blue").unwrap();
        assert_eq!(e.segmenter.asked, vec![10, 12]);
        assert_eq!(e.segmenter.phrase, "the ball");
        assert_eq!(out[0].as_ref().unwrap().mask.as_deref(), Some(&[1.0, 0.0, 0.25, 0.75][..]));
        assert!(out[1].is_none());
        // a miss: no mask, not even the editor's mask of ones
        assert_eq!(out[2].as_ref().unwrap().mask, None);
        // the attention is the editor's
        assert_eq!(out[2].as_ref().unwrap().attention, vec![1.0; 4]);
    }

    #[test]
    fn bad_masks_are_refused_naming_the_view() {
        let cams = [camera("a.png", 2, 2), camera("b.png", 2, 2)];
        let src = vec![0.5f32; 12];
        let views = views_of(&cams, &src);
        let good = Some(vec![1.0; 4]);
        let cases: [(Vec<Option<Vec<f32>>>, &str); 6] = [
            (
                vec![good.clone(), Some(vec![1.0; 3])],
                "view 11 (b.png): the segmenter (fixed) gave a mask of 3 values",
            ),
            (
                vec![good.clone(), Some(vec![0.0, 1.5, 0.0, 0.0])],
                "view 11 (b.png): the segmenter (fixed) gave the value 1.5 at pixel (1, 0)",
            ),
            (
                vec![Some(vec![0.0, 0.0, -0.1, 0.0]), good.clone()],
                "view 10 (a.png): the segmenter (fixed) gave the value -0.1 at pixel (0, 1)",
            ),
            (
                vec![good.clone(), Some(vec![f32::NAN; 4])],
                "view 11 (b.png): the segmenter (fixed) gave the value NaN",
            ),
            (vec![good.clone()], "returned 1 masks for 2 views"),
            (
                vec![None, Some(vec![0.5; 4])],
                "the segmenter (fixed) found nothing for \"the ball\" in any view",
            ),
        ];
        for (masks, needle) in cases {
            let mut e = Segmented::new(Echo { skip: vec![] }, fixed(masks), "the ball");
            let err = e.edit(&views, "").unwrap_err();
            assert!(matches!(err, Error::Invalid(_)), "{err}");
            let err = err.to_string();
            assert!(err.contains(needle) && !err.contains('\n'), "{needle}: {err}");
        }
    }

    fn grey_png(path: &Path, w: usize, h: usize, f: impl Fn(usize, usize) -> f32) {
        let rgb: Vec<f32> = (0..w * h).flat_map(|i| [f(i % w, i / w); 3]).collect();
        image::write_png(path, w, h, &rgb).unwrap();
    }

    #[test]
    fn a_mask_folder_reads_one_png_per_view_and_names_missing_or_wrong_files() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let cams = [camera("x/00001.jpg", 4, 2), camera("00002.png", 4, 2)];
        let src = vec![0.0f32; 4 * 2 * 3];
        let views = views_of(&cams, &src);
        grey_png(&d.join("00001.png"), 4, 2, |x, _| if x < 2 { 1.0 } else { 0.0 });
        let mut folder = MaskFolder::new(d);
        // 00002 is missing
        let err = folder.segment(&views, "").unwrap_err().to_string();
        assert!(err.contains(&d.join("00002.png").display().to_string()) && err.contains("view 11"), "{err}");
        // wrong size
        grey_png(&d.join("00002.png"), 2, 2, |_, _| 1.0);
        let err = folder.segment(&views, "").unwrap_err().to_string();
        assert!(err.contains("00002.png") && err.contains("mask is 2x2") && err.contains("4x2"), "{err}");
        // both right: grey values as they are
        grey_png(&d.join("00002.png"), 4, 2, |_, y| if y == 0 { 0.6 } else { 0.0 });
        let masks = folder.segment(&views, "").unwrap();
        assert_eq!(masks[0].as_deref(), Some(&[1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0][..]));
        let m1 = masks[1].as_ref().unwrap();
        assert!((m1[0] - 0.6).abs() < 1.0 / 255.0 && m1[4] == 0.0, "{m1:?}");
        // a content-named mask wins over the plain one when the scene is known
        let fp = "3".repeat(16);
        let named = d.join(format!("{}.png", content_name(&cams[1], Some(&fp))));
        grey_png(&named, 4, 2, |_, _| 1.0);
        let masks = folder.clone().for_scene(&fp).segment(&views, "").unwrap();
        assert_eq!(masks[1].as_deref(), Some(&[1.0; 8][..]));
        // a folder that is not there
        let err = MaskFolder::new(d.join("nope")).segment(&views, "").unwrap_err().to_string();
        assert!(err.contains("nope") && err.contains("does not exist"), "{err}");
    }
}
