//! The semantic space of an edit (docs/method.md#m8-semantic-space), and the one owner
//! of per-view features (docs/method.md#e5-semantic-and-appearance-features).
//!
//! The job's [`SemanticFn`] gives the semantic features E_v of the source renders and
//! of the edited images alike (DINOv2, or the built-in [`builtin`]); a failure stops
//! the edit with an error naming the view. The appearance features Φ_v of the edited
//! images are built in. A PCA basis of size d is fitted once on the source and edited
//! features together and applied to both; the semantic latents s_i start as the
//! lifted projected source features.

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

    /// The initial semantic latents s_i: the source features of every edit view
    /// projected and lifted onto `g` (`N × d`). Drops the source features.
    pub fn initial_latents(&mut self, g: &Gaussians, views: &[&Camera]) -> Vec<f32> {
        let projected: Vec<Vec<f32>> =
            std::mem::take(&mut self.source).iter().map(|p| self.pca.project(p)).collect();
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
