//! CLIP-sim and CLIP-dir (docs/method.md#v1-clip-metrics), by the Instruct-NeRF2NeRF `ClipSimilarity`
//! protocol, over folders of renders from any method:
//!
//! - CLIP-sim = cos(f(Î), g(t_target)),
//! - CLIP-dir = cos(f(Î) − f(I), g(t_target) − g(t_source)),
//!
//! with f, g the CLIP image and text features, each L2-normalised before any difference;
//! images resized bicubically to 224 × 224 without centre crop and normalised by CLIP's
//! mean/std ([`transsplat_models::clip::Clip::preprocess`]). Views are paired by file
//! stem and every `every`-th view (sorted by name, index % every == 0) is scored, the
//! llffhold = 8 test views of the compared papers.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use transsplat_models::clip::{l2_normalize, Clip};
use transsplat_scene::cameras::is_held_out;
use transsplat_scene::image;

/// Score of one view.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ViewScore {
    pub view: String,
    pub clip_sim: f32,
    pub clip_dir: f32,
}

/// Scores of a whole evaluation.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ClipScores {
    pub source_prompt: String,
    pub target_prompt: String,
    pub every: usize,
    pub views: Vec<ViewScore>,
    pub mean_clip_sim: f32,
    pub mean_clip_dir: f32,
}

/// Errors of the CLIP evaluation; messages name the folder or file.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{0}")]
    Input(String),
    #[error(transparent)]
    Image(#[from] transsplat_scene::Error),
    #[error(transparent)]
    Model(#[from] transsplat_models::Error),
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
    /// The progress callback asked to stop.
    #[error("interrupted")]
    Interrupted,
}

fn images_by_stem(dir: &Path) -> Result<Vec<(String, PathBuf)>, Error> {
    let entries = std::fs::read_dir(dir)
        .map_err(|e| Error::Input(format!("{}: cannot read folder: {e}", dir.display())))?;
    let mut out = Vec::new();
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_file() && image::has_image_extension(&path) {
            if let Some(stem) = path.file_stem().and_then(|s| s.to_str()) {
                out.push((stem.to_string(), path));
            }
        }
    }
    out.sort();
    Ok(out)
}

/// `(stem, source, edited)` of the scored views: source images sorted by name, every
/// `every`-th one, each with the edited image of the same stem (which must exist).
pub fn pair_views(
    source: &Path,
    edited: &Path,
    every: usize,
) -> Result<Vec<(String, PathBuf, PathBuf)>, Error> {
    if every == 0 {
        return Err(Error::Input("--every must be at least 1".into()));
    }
    let src = images_by_stem(source)?;
    if src.is_empty() {
        return Err(Error::Input(format!("{}: no PNG or JPEG images", source.display())));
    }
    let edits = images_by_stem(edited)?;
    src.into_iter()
        .enumerate()
        .filter(|&(i, _)| is_held_out(i, every))
        .map(|(_, (stem, path))| {
            let e = edits.iter().find(|(s, _)| *s == stem).ok_or_else(|| {
                Error::Input(format!(
                    "{}: no edited image for view {stem} ({})",
                    edited.display(),
                    path.display()
                ))
            })?;
            Ok((stem, path, e.1.clone()))
        })
        .collect()
}

fn cosine(a: &[f32], b: &[f32]) -> f32 {
    let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
    let na = a.iter().map(|x| x * x).sum::<f32>().sqrt();
    let nb = b.iter().map(|x| x * x).sum::<f32>().sqrt();
    // torch's cosine_similarity clamps each norm at 1e-8.
    dot / (na.max(1e-8) * nb.max(1e-8))
}

fn normalized_rows(x: &candle_core::Tensor) -> Result<Vec<Vec<f32>>, Error> {
    Ok(l2_normalize(x)?.to_vec2::<f32>()?)
}

/// Scores `(name, source image, edited image)` triples; images `H × W × 3` in [0, 1]
/// with their width and height (source and edit may differ in size). `progress` is
/// called with the number of views done after each; `Break` stops with
/// [`Error::Interrupted`].
#[allow(clippy::type_complexity)]
pub fn score(
    clip: &Clip,
    views: &[(String, (&[f32], usize, usize), (&[f32], usize, usize))],
    source_prompt: &str,
    target_prompt: &str,
    every: usize,
    progress: &mut dyn FnMut(usize) -> ControlFlow<()>,
) -> Result<ClipScores, Error> {
    let text = normalized_rows(&clip.text_features(&[source_prompt, target_prompt])?)?;
    let text_dir: Vec<f32> = text[1].iter().zip(&text[0]).map(|(t, s)| t - s).collect();
    let mut scores = Vec::with_capacity(views.len());
    for (i, (name, src, edit)) in views.iter().enumerate() {
        let f = normalized_rows(&clip.image_features(&[*src, *edit])?)?;
        let img_dir: Vec<f32> = f[1].iter().zip(&f[0]).map(|(e, s)| e - s).collect();
        scores.push(ViewScore {
            view: name.clone(),
            clip_sim: cosine(&f[1], &text[1]),
            clip_dir: cosine(&img_dir, &text_dir),
        });
        if progress(i + 1).is_break() {
            return Err(Error::Interrupted);
        }
    }
    let n = scores.len().max(1) as f32;
    Ok(ClipScores {
        source_prompt: source_prompt.to_string(),
        target_prompt: target_prompt.to_string(),
        every,
        mean_clip_sim: scores.iter().map(|s| s.clip_sim).sum::<f32>() / n,
        mean_clip_dir: scores.iter().map(|s| s.clip_dir).sum::<f32>() / n,
        views: scores,
    })
}
