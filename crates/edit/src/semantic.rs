//! The semantic space of an edit (docs/method.md#m8-semantic-space), and the one owner
//! of per-view features (docs/method.md#e5-semantic-and-appearance-features).
//!
//! The job's [`SemanticFn`] gives the semantic features E_v of the source renders and
//! of the edited images alike (DINOv2, or the built-in [`builtin`]); a failure stops
//! the edit with an error naming the view. The appearance features Φ_v of the edited
//! images are built in. A PCA basis of size d is fitted once on the source and edited
//! features together and applied to both; the semantic latents s_i start as the
//! lifted projected features of the edited images (or of the source renders,
//! [`SemanticInit`]).

use crate::config::SemanticInit;

use crate::error::EditError;
use crate::lift::lift;
use crate::pca::Pca;
use rayon::prelude::*;
use transsplat_editors::EditedView;
use transsplat_scene::{Camera, Gaussians};

/// Semantic features of an `H × W × 3` image: `(image, w, h)` → `(H × W × d, d)`, or a
/// one-line reason it failed.
pub type SemanticFn = dyn Fn(&[f32], usize, usize) -> Result<(Vec<f32>, usize), String> + Sync;

/// Pixels sampled to fit the PCA basis.
const PCA_SAMPLES: usize = 20_000;

/// The built-in semantic model (no weights): [`transsplat_editors::semantic_fallback`].
pub fn builtin(image: &[f32], w: usize, h: usize) -> Result<(Vec<f32>, usize), String> {
    Ok(transsplat_editors::semantic_fallback(image, w, h))
}

/// The features of one usable edited view.
pub struct ViewFeatures {
    /// E_v before the projection, `H × W × d_in`.
    pub semantic: Vec<f32>,
    /// Φ_v, `H × W × d_app`.
    pub appearance: Vec<f32>,
    pub d_app: usize,
}

/// The fitted semantic space with the features of every edit view.
pub struct SemanticSpace {
    pub pca: Pca,
    /// E_v of the source renders, aligned with the edit views.
    source: Vec<Vec<f32>>,
    /// Features of the edited views (`None` where the editor gave nothing).
    pub edited: Vec<Option<ViewFeatures>>,
}

/// E_v of one image, checked: `w × h × d` values with the same `d` as `d_in` when given.
fn features_of(
    model: &SemanticFn,
    image: &[f32],
    cam: &Camera,
    what: &str,
) -> Result<(Vec<f32>, usize), EditError> {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let fail =
        |m: String| EditError::Input(format!("semantic features of the {what} of view {:?}: {m}", cam.name));
    let (plane, d) = model(image, w, h).map_err(fail)?;
    if d == 0 || plane.len() != w * h * d {
        return Err(fail(format!("{} values with {d} channels for a {w}x{h} image", plane.len())));
    }
    Ok((plane, d))
}

impl SemanticSpace {
    /// Computes E_v of the source renders (`sources`, aligned with `views`) and of the
    /// edited images, Φ_v of the edited images, and fits the PCA basis of size `d`.
    pub fn fit(
        model: &SemanticFn,
        views: &[&Camera],
        sources: &[Vec<f32>],
        edited: &[Option<EditedView>],
        d: usize,
        seed: u64,
    ) -> Result<SemanticSpace, EditError> {
        let source: Vec<(Vec<f32>, usize)> = views
            .par_iter()
            .zip(sources)
            .map(|(cam, img)| features_of(model, img, cam, "source render"))
            .collect::<Result<_, _>>()?;
        let edited: Vec<Option<(ViewFeatures, usize)>> = views
            .par_iter()
            .zip(edited)
            .map(|(cam, e)| {
                let Some(e) = e else { return Ok(None) };
                let (semantic, (appearance, d_app)) = rayon::join(
                    || features_of(model, &e.image, cam, "edited image"),
                    || transsplat_editors::appearance(&e.image, e.width, e.height),
                );
                let (semantic, d_in) = semantic?;
                Ok(Some((ViewFeatures { semantic, appearance, d_app }, d_in)))
            })
            .collect::<Result<_, EditError>>()?;
        let d_in = source[0].1;
        let channels = source.iter().map(|s| s.1).chain(edited.iter().flatten().map(|e| e.1));
        if let Some(other) = channels.into_iter().find(|&c| c != d_in) {
            return Err(EditError::Input(format!(
                "the semantic model gave {other} channels for one image and {d_in} for another"
            )));
        }
        let mut planes: Vec<&[f32]> = source.iter().map(|(p, _)| p.as_slice()).collect();
        planes.extend(edited.iter().flatten().map(|(e, _)| e.semantic.as_slice()));
        let pca = Pca::fit(&planes, d_in, d, PCA_SAMPLES, seed);
        Ok(SemanticSpace {
            pca,
            source: source.into_iter().map(|(p, _)| p).collect(),
            edited: edited.into_iter().map(|e| e.map(|(f, _)| f)).collect(),
        })
    }

    /// The initial semantic latents s_i (docs/method.md#m8-semantic-space): the
    /// features of every edit view projected and lifted onto `g` (`N × d`): with
    /// [`SemanticInit::Edited`] the edited image's where the editor gave one (the
    /// source render's otherwise), with [`SemanticInit::Source`] the source render's.
    /// Drops the source features; call it before the edited features are taken.
    ///
    /// *Why edited:* the transport compares s_i with prototypes e_m taken from the
    /// edited images. Latents lifted from the source renders describe the object as it
    /// was, so at the first round the semantic cost ranks the object against the edit
    /// it is to receive (measured: a red apple made cyan is costlier than the green
    /// grass around it, and the first round's gate closes on the whole apple).
    pub fn initial_latents(&mut self, g: &Gaussians, views: &[&Camera], init: SemanticInit) -> Vec<f32> {
        let sources = std::mem::take(&mut self.source);
        let projected: Vec<Vec<f32>> = sources
            .iter()
            .zip(&self.edited)
            .map(|(src, e)| match (init, e) {
                (SemanticInit::Edited, Some(e)) => self.pca.project(&e.semantic),
                _ => self.pca.project(src),
            })
            .collect();
        let planes: Vec<&[f32]> = projected.iter().map(|p| p.as_slice()).collect();
        lift(g, views, &planes, self.pca.d)
    }
}

/// Writes the semantic latents as extra properties `sem_0..sem_{d-1}`, replacing
/// any earlier `sem_*` properties and keeping the other extras.
pub fn set_semantic_extras(g: &mut Gaussians, s: &[f32], d: usize) {
    let n = g.len();
    let old = std::mem::take(&mut g.extra);
    let keep: Vec<usize> = (0..old.names.len()).filter(|&k| !old.names[k].starts_with("sem_")).collect();
    let mut names: Vec<String> = keep.iter().map(|&k| old.names[k].clone()).collect();
    names.extend((0..d).map(|k| format!("sem_{k}")));
    let w_old = old.names.len();
    let mut values = Vec::with_capacity(n * names.len());
    for i in 0..n {
        values.extend(keep.iter().map(|&k| old.values[i * w_old + k]));
        values.extend_from_slice(&s[i * d..(i + 1) * d]);
    }
    g.extra = transsplat_scene::Extra { names, values };
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::edits::tests::camera;

    /// The latents start from the edited image's features where the editor gave one
    /// and from the source render's elsewhere (`Edited`), or from the source renders
    /// alone (`Source`): each equals the lift of the chosen projected planes.
    #[test]
    fn initial_latents_lift_the_chosen_views_features() {
        use transsplat_builtin::{build, SceneConfig};
        let scene =
            build("tabletop", &SceneConfig { width: 32, height: 24, views: 3, ..SceneConfig::quick() })
                .unwrap();
        let (g, views) = (&scene.gaussians, [&scene.cameras[0], &scene.cameras[1]]);
        let src = crate::edits::render_sources(g, &views, [0.0; 3]);
        // Per-pixel features (r, g, b, r·g); the edit swaps red and blue in view 1.
        let model = |img: &[f32], _: usize, _: usize| -> Result<(Vec<f32>, usize), String> {
            Ok((img.chunks(3).flat_map(|p| [p[0], p[1], p[2], p[0] * p[1]]).collect(), 4))
        };
        let swapped: Vec<f32> = src[1].chunks(3).flat_map(|p| [p[2], p[1], p[0]]).collect();
        let edited = vec![None, Some(EditedView::new(swapped.clone(), 32, 24, vec![1.0; 32 * 24], None))];
        let latents = |init| {
            let mut space = SemanticSpace::fit(&model, &views, &src, &edited, 3, 0).unwrap();
            let pca = space.pca.clone();
            (space.initial_latents(g, &views, init), pca)
        };
        let planes = |pca: &Pca, imgs: [&[f32]; 2]| -> Vec<Vec<f32>> {
            imgs.iter().map(|img| pca.project(&model(img, 32, 24).unwrap().0)).collect()
        };
        for (init, second) in [(SemanticInit::Edited, &swapped), (SemanticInit::Source, &src[1])] {
            let (got, pca) = latents(init);
            let p = planes(&pca, [&src[0], second]);
            let want = lift(g, &views, &[&p[0], &p[1]], 3);
            assert_eq!(got, want, "{init:?}");
        }
        assert_ne!(latents(SemanticInit::Edited).0, latents(SemanticInit::Source).0);
    }

    /// One rule for source renders and edited images: a failing model stops the fit with
    /// a message naming the view and which image it was.
    #[test]
    fn a_failing_model_names_the_view_for_sources_and_edits_alike() {
        let cams = [camera("a"), camera("b")];
        let views: Vec<&Camera> = cams.iter().collect();
        let (src, dark) = (vec![vec![0.5f32; 36]; 2], vec![0.0f32; 36]);
        let edited = vec![None, Some(EditedView::new(dark, 4, 3, vec![1.0; 12], None))];
        // Fails on black images: only the edited image of view b is black.
        let model = |img: &[f32], w: usize, h: usize| -> Result<(Vec<f32>, usize), String> {
            if img.iter().all(|&v| v == 0.0) {
                return Err("no features for black".into());
            }
            Ok((vec![1.0; w * h * 2], 2))
        };
        let e = SemanticSpace::fit(&model, &views, &src, &edited, 2, 0).err().unwrap().to_string();
        assert!(e.contains("edited image of view \"b\": no features for black"), "{e}");
        let e = SemanticSpace::fit(&model, &views, &[vec![0.0; 36], vec![0.5; 36]], &[None, None], 2, 0)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("source render of view \"a\""), "{e}");
        // A wrong plane size and inconsistent channel counts are refused.
        let short =
            |_: &[f32], _: usize, _: usize| -> Result<(Vec<f32>, usize), String> { Ok((vec![0.0; 5], 2)) };
        let e = SemanticSpace::fit(&short, &views, &src, &[None, None], 2, 0).err().unwrap().to_string();
        assert!(e.contains("5 values with 2 channels for a 4x3 image"), "{e}");
        let edited = vec![Some(EditedView::new(vec![0.3; 36], 4, 3, vec![1.0; 12], None)), None];
        let by_image = |img: &[f32], w: usize, h: usize| -> Result<(Vec<f32>, usize), String> {
            let d = if img[0] == 0.3 { 3 } else { 2 };
            Ok((vec![0.1; w * h * d], d))
        };
        let e = SemanticSpace::fit(&by_image, &views, &src, &edited, 2, 0).err().unwrap().to_string();
        assert!(e.contains("3 channels for one image and 2 for another"), "{e}");
        let ok = SemanticSpace::fit(&model, &views, &src, &edited, 2, 0).unwrap();
        assert_eq!((ok.pca.d_in, ok.pca.d, ok.edited[0].as_ref().unwrap().d_app), (2, 2, 6));
    }
}
