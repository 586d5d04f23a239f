//! The first stage of an edit (docs/method.md#m9-the-edit-loop): render the edit
//! views of the source scene, have the 2D editor edit them once, check what it
//! returned, and gather each usable view's evidence for the method.

use crate::error::EditError;
use crate::prototypes::{attention_peak, PrototypeConfig, ViewEvidence};
use crate::semantic::SemanticSpace;
use transsplat_editors::{EditedView, Editor, SourceView};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::{Camera, Gaussians};

/// One usable edit view, prepared once: its camera, the edited image Î_v (the target
/// of L_img) and the appearance plane Φ_v of the edited image.
pub struct ViewData {
    /// Index of the view's camera in the scene.
    pub cam: usize,
    pub target: Vec<f32>,
    pub appearance: Vec<f32>,
    pub d_app: usize,
}

/// Renders the source scene at each of `cams` (`H × W × 3` each).
pub fn render_sources(g: &Gaussians, cams: &[&Camera], background: [f32; 3]) -> Vec<Vec<f32>> {
    let s = Splats::new(g);
    let opts = RenderOptions { background };
    cams.iter().map(|c| render(&s, c, &opts).0.rgb).collect()
}

/// Has `editor` edit the source renders of the views `views` (camera indices into
/// `cameras`) for `prompt`, and checks that every output matches its camera and that
/// at least one view was edited.
pub fn edit_views(
    editor: &mut dyn Editor,
    cameras: &[Camera],
    views: &[usize],
    sources: &[Vec<f32>],
    prompt: &str,
) -> Result<Vec<Option<EditedView>>, EditError> {
    let src: Vec<SourceView> = views
        .iter()
        .zip(sources)
        .map(|(&v, img)| SourceView { index: v, camera: &cameras[v], image: img })
        .collect();
    let edited = editor.edit(&src, prompt)?;
    check_outputs(editor.name(), &edited, cameras, views)?;
    Ok(edited)
}

/// Errors unless there is one output per view, each matching its camera's size, and
/// at least one of them is an edited view.
pub fn check_outputs(
    editor: &str,
    edited: &[Option<EditedView>],
    cameras: &[Camera],
    views: &[usize],
) -> Result<(), EditError> {
    if edited.len() != views.len() {
        return Err(EditError::Input(format!(
            "editor {editor} returned {} views for {} inputs",
            edited.len(),
            views.len()
        )));
    }
    for (e, &v) in edited.iter().zip(views) {
        let Some(e) = e else { continue };
        let c = &cameras[v];
        let px = c.width as usize * c.height as usize;
        let ok = e.width == c.width as usize
            && e.height == c.height as usize
            && e.image.len() == px * 3
            && e.attention.len() == px
            && e.mask.as_ref().is_none_or(|m| m.len() == px);
        if !ok {
            return Err(EditError::Input(format!(
                "editor {editor} returned an output for view {:?} whose planes do not match the view size {}x{}",
                c.name, c.width, c.height
            )));
        }
    }
    if edited.iter().all(Option::is_none) {
        return Err(EditError::Input(format!("editor {editor} produced no edited view")));
    }
    Ok(())
}

/// The usable edit views in order, each handed with its evidence (attention, mask,
/// projected semantic and appearance planes, and the peak its attention is normalised
/// by, [`PrototypeConfig::view_peak`]) and camera index to `take`, which returns how many
/// prototypes it made of the view. Returns the views and the prototype count of every
/// edit view (0 where the editor gave nothing).
pub fn gather(
    views: &[usize],
    edited: &[Option<EditedView>],
    prototypes: &PrototypeConfig,
    space: &mut SemanticSpace,
    mut take: impl FnMut(usize, &ViewEvidence) -> usize,
) -> (Vec<ViewData>, Vec<usize>) {
    let mut out = Vec::new();
    let mut counts = vec![0; views.len()];
    let typical = prototypes.normalise.typical(edited.iter().flatten().map(|e| &e.attention[..]));
    for (k, (e, &cam)) in edited.iter().zip(views).enumerate() {
        let (Some(e), Some(f)) = (e, space.edited[k].take()) else { continue };
        let semantic = space.pca.project(&f.semantic);
        let ev = ViewEvidence {
            width: e.width,
            height: e.height,
            attention: &e.attention,
            mask: e.mask.as_deref(),
            semantic: &semantic,
            d: space.pca.d,
            appearance: &f.appearance,
            d_app: f.d_app,
            peak: prototypes.view_peak(&e.attention, typical),
        };
        if crate::prototypes::below_floor(&ev, prototypes.threshold) {
            tracing::info!(
                "edit view {cam}: its attention peaks at {:.2} of the edited views' median, under δ_a = {}: \
                 no support (a gate counts it as a view that changed nothing it sees)",
                attention_peak(&e.attention) / typical,
                prototypes.threshold
            );
        }
        counts[k] = take(cam, &ev);
        out.push(ViewData { cam, target: e.image.clone(), appearance: f.appearance, d_app: f.d_app });
    }
    (out, counts)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A 4×3 pinhole camera at the origin, for tests of the stages.
    pub(crate) fn camera(name: &str) -> Camera {
        let eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let (fx, fy, cx, cy) = (4.0, 4.0, 2.0, 1.5);
        Camera {
            name: name.into(),
            width: 4,
            height: 3,
            fx,
            fy,
            cx,
            cy,
            rotation: eye,
            translation: [0.0; 3],
        }
    }

    fn view(w: usize, h: usize) -> EditedView {
        EditedView::new(vec![0.5; w * h * 3], w, h, vec![1.0; w * h], None)
    }

    #[test]
    fn outputs_must_match_their_cameras_and_one_must_be_edited() {
        let cams = [camera("a"), camera("b")];
        assert!(check_outputs("e", &[Some(view(4, 3)), None], &cams, &[0, 1]).is_ok());
        let e = check_outputs("e", &[Some(view(4, 3))], &cams, &[0, 1]).unwrap_err().to_string();
        assert!(e.contains("returned 1 views for 2 inputs"), "{e}");
        let e = check_outputs("e", &[None, Some(view(3, 4))], &cams, &[0, 1]).unwrap_err().to_string();
        assert!(e.contains("view \"b\"") && e.contains("4x3"), "{e}");
        let mut masked = view(4, 3);
        masked.mask = Some(vec![1.0; 5]);
        assert!(check_outputs("e", &[Some(masked), None], &cams, &[0, 1]).is_err());
        let e = check_outputs("e", &[None, None], &cams, &[0, 1]).unwrap_err().to_string();
        assert!(e.contains("produced no edited view"), "{e}");
    }
}
