//! Which views the 2D editor edits (`edit --views`): all edit views, or `K` of them
//! spread over the capture, so the editor — the slow stage on a CPU — runs K times
//! instead of once per view, and the transport, fusion and image loss work from those
//! K views.
//!
//! The K views are chosen by farthest-point sampling over the cameras: the first is the
//! edit view nearest the centroid of the edit cameras' centres (a central view, which
//! sees what the capture is about), and each next one maximises its distance to the
//! views already chosen, with the distance between views a and b
//!
//!   d(a, b) = ‖c_a − c_b‖ / D + (1 − f_a · f_b),
//!
//! c the camera centre, f the unit viewing direction (the camera's +z axis in the world)
//! and D the largest distance between two edit cameras' centres: positions and
//! directions count alike, so an orbit spreads around the ring and a forward-facing
//! grid over its plane. Ties go to the lower index; the choice is deterministic.
//!
//! `auto` ([`auto`]) lets the edits say where the target is and how many views it
//! needs. The editor first edits a quarter of the views chosen as above (the seeds).
//! Each edited view's support Ω_v (its thresholded attention within its mask,
//! docs/method.md#m2-prototypes) and its change Δ_v = edit − render are splatted back
//! onto the Gaussians; the target is where the support lifted over the edited views is
//! at least ½. For each target Gaussian, the views that see it well (blend weight at
//! least a quarter of its largest over the edit views) give a spread of its lifted
//! change, and the standard error of their mean, spread / √n, says how well the edit is
//! known there (with no view, spread · √2; fewer than two views take the target's pooled
//! spread). While the target's mean standard error (weighted by each Gaussian's largest
//! blend weight) is above the 8-bit floor 2/255, rounds of half as many views as the
//! seeds are added, each the view that lowers it most. A consistent editor stops at the
//! seeds; an editor whose views disagree gets more views, up to all of them: the fusion
//! averages its disagreement away only with enough views.

use std::collections::HashMap;

use crate::SessionError;
use transsplat_edit::edits::render_sources;
use transsplat_edit::prototypes::{view_support, PrototypeConfig, ViewEvidence};
use transsplat_editors::{EditedView, Editor, Error as EditorError, SourceView};
use transsplat_raster::{gaussian_stats, Splats};
use transsplat_scene::cameras::split_views;
use transsplat_scene::{Camera, Gaussians};

/// How many of the edit views the editor edits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ViewChoice {
    /// Every edit view (every camera but the held-out ones).
    #[default]
    All,
    /// This many edit views, spread over the capture.
    Count(usize),
    /// One in this many edit views (rounded up), spread over the capture: `1/N`.
    Fraction(usize),
    /// Seed views spread over the capture, then the views the target needs ([`auto`]).
    Auto,
}

impl ViewChoice {
    /// Parses `all`, `auto`, a positive count `K` or a fraction `1/N` (the message names
    /// no flag: fronts add theirs).
    pub fn parse(text: &str) -> Result<ViewChoice, String> {
        match text.trim() {
            "all" => Ok(ViewChoice::All),
            "auto" => Ok(ViewChoice::Auto),
            t if t.starts_with("1/") => match t[2..].parse::<usize>() {
                Ok(n) if n >= 1 => Ok(ViewChoice::Fraction(n)),
                _ => Err(format!("expected 1/N with N at least 1, got {t:?}")),
            },
            t => match t.parse::<usize>() {
                Ok(0) => Err("must be at least 1 (or all)".into()),
                Ok(k) => Ok(ViewChoice::Count(k)),
                Err(_) => Err(format!("expected all, auto, a number of views or 1/N, got {t:?}")),
            },
        }
    }
}

/// The held-out test views and the views the editor edits, as camera indices in order:
/// [`split_views`] (every 8th camera held out), then `choice` among its edit views
/// (`auto`: every edit view, the candidates [`auto`] chooses from).
pub fn split(cameras: &[Camera], choice: ViewChoice) -> Result<(Vec<usize>, Vec<usize>), SessionError> {
    let (test_views, edit_views) = split_views(cameras.len());
    Ok((test_views, choose(cameras, &edit_views, choice)?))
}

/// The views to edit among `edit_views` (camera indices, in order).
pub fn choose(
    cameras: &[Camera],
    edit_views: &[usize],
    choice: ViewChoice,
) -> Result<Vec<usize>, SessionError> {
    if edit_views.is_empty() {
        return Err(SessionError::Input("no edit views: every camera is a held-out test view".into()));
    }
    let k = match choice {
        ViewChoice::All | ViewChoice::Auto => return Ok(edit_views.to_vec()),
        ViewChoice::Count(0) => return Err(SessionError::Input("--views must be at least 1".into())),
        ViewChoice::Count(k) if k > edit_views.len() => {
            return Err(SessionError::Input(format!(
                "--views {k} is more than the {} edit views (every camera but each 8th)",
                edit_views.len()
            )))
        }
        ViewChoice::Count(k) => k,
        ViewChoice::Fraction(n) => edit_views.len().div_ceil(n.max(1)),
    };
    let centres: Vec<[f32; 3]> = edit_views.iter().map(|&v| cameras[v].centre()).collect();
    let forward: Vec<[f32; 3]> = edit_views.iter().map(|&v| cameras[v].rotation[2]).collect();
    let n = edit_views.len();
    let extent = (0..n)
        .flat_map(|a| (0..n).map(move |b| (a, b)))
        .map(|(a, b)| squared(&centres[a], &centres[b]).sqrt())
        .fold(0.0f32, f32::max)
        .max(1e-12);
    let distance = |a: usize, b: usize| {
        let dot: f32 = (0..3).map(|i| forward[a][i] * forward[b][i]).sum();
        squared(&centres[a], &centres[b]).sqrt() / extent + (1.0 - dot)
    };
    let mean: [f32; 3] = std::array::from_fn(|i| centres.iter().map(|c| c[i]).sum::<f32>() / n as f32);
    let first = (0..n)
        .min_by(|&a, &b| squared(&centres[a], &mean).total_cmp(&squared(&centres[b], &mean)))
        .expect("at least one edit view");
    let mut chosen = vec![first];
    // Distance of every view to the nearest chosen one.
    let mut nearest: Vec<f32> = (0..n).map(|v| distance(v, first)).collect();
    while chosen.len() < k {
        let next = (0..n)
            .filter(|v| !chosen.contains(v))
            .max_by(|&a, &b| nearest[a].total_cmp(&nearest[b]).then(b.cmp(&a)))
            .expect("fewer chosen than views");
        chosen.push(next);
        for (v, d) in nearest.iter_mut().enumerate() {
            *d = d.min(distance(v, next));
        }
    }
    chosen.sort_unstable();
    Ok(chosen.into_iter().map(|i| edit_views[i]).collect())
}

/// The seeds of `auto`: one in this many edit views.
const AUTO_SEED_FRACTION: usize = 4;
/// A view sees a Gaussian well at this share of the Gaussian's largest blend weight.
const AUTO_SEEN_SHARE: f32 = 0.25;
/// A Gaussian is part of the target when its lifted support is at least this.
const AUTO_TARGET: f32 = 0.5;
/// `auto` stops once the target's edit is known to within this (mean standard error
/// of the lifted change, colour in [0, 1]): the 8-bit quantisation floor
/// ([`transsplat_editors::features::CHANGE_FLOOR`]).
const AUTO_TOLERANCE: f32 = transsplat_editors::features::CHANGE_FLOOR;

/// What `auto` needs of the job.
pub struct AutoScene<'a> {
    pub gaussians: &'a Gaussians,
    pub cameras: &'a [Camera],
    /// The candidates: every edit view.
    pub edit_views: &'a [usize],
    pub background: [f32; 3],
    pub prompt: &'a str,
    /// The support Ω_v is the engine's ([`view_support`] with these settings).
    pub prototypes: &'a PrototypeConfig,
}

/// The views `auto` chose and the editor's outputs for them.
pub struct AutoChoice {
    /// Camera indices, in order.
    pub views: Vec<usize>,
    /// The editor's output for each of `views`.
    pub edited: Vec<Option<EditedView>>,
    /// How many of `views` were seeds (the rest were added for the target).
    pub seeds: usize,
}

/// One edited view's evidence on the Gaussians the seeds' supports touch: its support
/// Ω_v and its change Δ_v = edit − render, splatted back (blend-weighted means).
struct Lifted {
    support: Vec<f32>,
    change: Vec<[f32; 3]>,
}

/// `--views auto` (module doc): edits the seeds, then rounds of the views that most
/// reduce the uncertainty of the target's edit, until it is known to within
/// [`AUTO_TOLERANCE`] or every edit view is edited. Errors when the seed edits mark no
/// target anywhere (the editor changed nothing).
pub fn auto(scene: &AutoScene, editor: &mut dyn Editor) -> Result<AutoChoice, SessionError> {
    let seeds = choose(scene.cameras, scene.edit_views, ViewChoice::Fraction(AUTO_SEED_FRACTION))?;
    let splats = Splats::new(scene.gaussians);
    let mut edited: Vec<(usize, Option<EditedView>)> = Vec::new();
    let mut lifted: HashMap<usize, Lifted> = HashMap::new();
    // Edits `views`, keeps the outputs and lifts them onto the universe `on` (all
    // Gaussians before it is known).
    let mut edit_and_lift = |views: &[usize],
                             on: Option<&[usize]>,
                             edited: &mut Vec<(usize, Option<EditedView>)>,
                             lifted: &mut HashMap<usize, Lifted>|
     -> Result<(), SessionError> {
        let cams: Vec<&Camera> = views.iter().map(|&v| &scene.cameras[v]).collect();
        let sources = render_sources(scene.gaussians, &cams, scene.background);
        let src: Vec<SourceView> = views
            .iter()
            .zip(&sources)
            .map(|(&v, image)| SourceView { index: v, camera: &scene.cameras[v], image })
            .collect();
        // A round may leave every view unedited; the engine checks the whole set.
        let out = editor.edit(&src, scene.prompt).map_err(|e| SessionError::Edit(e.into()))?;
        if out.len() != views.len() {
            return Err(SessionError::Input(format!(
                "editor {} returned {} views for {} inputs",
                editor.name(),
                out.len(),
                views.len()
            )));
        }
        for (v, e) in src.iter().zip(&out) {
            if let Some(e) =
                e.as_ref().filter(|e| (e.width, e.height) != v.size() || e.image.len() != v.image.len())
            {
                return Err(SessionError::Input(format!(
                    "editor {}: view {} came back {}x{}, its camera is {}x{}",
                    editor.name(),
                    v.index,
                    e.width,
                    e.height,
                    v.size().0,
                    v.size().1
                )));
            }
        }
        // The typical attention peak over the views edited so far: the engine takes it over
        // the final set, so a view lifted early may have been measured against another peak
        // (views already lifted are not lifted again).
        let so_far = edited.iter().filter_map(|(_, e)| e.as_ref()).chain(out.iter().flatten());
        let typical = scene.prototypes.normalise.typical(so_far.map(|e| &e.attention[..]));
        for ((&v, source), e) in views.iter().zip(&sources).zip(out) {
            if let Some(e) = &e {
                lifted.insert(v, lift_view(scene, &splats, v, source, e, typical, on));
            }
            edited.push((v, e));
        }
        Ok(())
    };
    edit_and_lift(&seeds, None, &mut edited, &mut lifted)?;
    // The universe: Gaussians some seed's support touches.
    let universe: Vec<usize> =
        (0..scene.gaussians.len()).filter(|&i| lifted.values().any(|l| l.support[i] > 0.0)).collect();
    for l in lifted.values_mut() {
        l.support = universe.iter().map(|&i| l.support[i]).collect();
        l.change = universe.iter().map(|&i| l.change[i]).collect();
    }
    // Blend weight of every edit view on the universe.
    let weights: Vec<Vec<f32>> = scene
        .edit_views
        .iter()
        .map(|&v| {
            let w = gaussian_stats(&splats, &scene.cameras[v], None).weight_sum;
            universe.iter().map(|&i| w[i]).collect()
        })
        .collect();
    let best: Vec<f32> =
        (0..universe.len()).map(|j| weights.iter().map(|w| w[j]).fold(0.0, f32::max)).collect();
    let seen: Vec<Vec<bool>> = weights
        .iter()
        .map(|w| w.iter().zip(&best).map(|(&x, &b)| x > 0.0 && x >= AUTO_SEEN_SHARE * b).collect())
        .collect();
    let round_size = seeds.len().div_ceil(2).max(1);
    let mut rounds = 0;
    loop {
        let chosen: Vec<usize> = edited.iter().map(|(v, _)| *v).collect();
        let at =
            |v: usize| scene.edit_views.iter().position(|&e| e == v).expect("chosen views are edit views");
        let evidence =
            Evidence::of(&chosen.iter().map(|&v| at(v)).collect::<Vec<_>>(), &weights, &seen, |k| {
                lifted.get(&scene.edit_views[k])
            });
        if rounds == 0 && evidence.mass.iter().sum::<f64>() <= 0.0 {
            return Err(SessionError::Input(format!(
                "--views auto: the editor marked no target in its {} seed views (no attention or mask \
                 anywhere), so there is nothing to choose views for; edit with --views all or a count",
                seeds.len()
            )));
        }
        let error = evidence.standard_error();
        let taken: Vec<bool> =
            (0..scene.edit_views.len()).map(|k| chosen.contains(&scene.edit_views[k])).collect();
        let next = if error <= AUTO_TOLERANCE as f64 {
            Vec::new()
        } else {
            evidence.next_views(&seen, &taken, round_size)
        };
        tracing::info!(
            "--views auto: {} views edited ({} seeds), the target's edit known to ±{:.4}{}",
            chosen.len(),
            seeds.len(),
            error,
            if next.is_empty() { "; done".to_string() } else { format!("; adding {} views", next.len()) }
        );
        if next.is_empty() {
            break;
        }
        let next: Vec<usize> = next.into_iter().map(|k| scene.edit_views[k]).collect();
        edit_and_lift(&next, Some(&universe), &mut edited, &mut lifted)?;
        rounds += 1;
    }
    tracing::info!(
        "--views auto: {} seed views, {} added in {rounds} rounds ({} of {} edit views)",
        seeds.len(),
        edited.len() - seeds.len(),
        edited.len(),
        scene.edit_views.len()
    );
    edited.sort_by_key(|(v, _)| *v);
    let (views, edited) = edited.into_iter().unzip();
    Ok(AutoChoice { views, edited, seeds: seeds.len() })
}

/// View `v`'s support Ω_v (its attention normalised as `scene.prototypes.normalise` says,
/// given the job's `typical` attention peak, [`PrototypeConfig::view_peak`])
/// and change Δ_v = edit − render splatted back onto the Gaussians `on` (all when `None`).
fn lift_view(
    scene: &AutoScene,
    splats: &Splats,
    v: usize,
    source: &[f32],
    e: &EditedView,
    typical: f32,
    on: Option<&[usize]>,
) -> Lifted {
    let ev = ViewEvidence {
        width: e.width,
        height: e.height,
        attention: &e.attention,
        mask: e.mask.as_deref(),
        semantic: &[],
        d: 0,
        appearance: &[],
        d_app: 0,
        peak: scene.prototypes.view_peak(&e.attention, typical),
    };
    let omega = view_support(&ev, scene.prototypes).omega;
    // Four channels: Ω, then the change.
    let mut plane = Vec::with_capacity(omega.len() * 4);
    for (p, &o) in omega.iter().enumerate() {
        plane.push(if o { 1.0f32 } else { 0.0 });
        plane.extend((0..3).map(|c| e.image[3 * p + c] - source[3 * p + c].clamp(0.0, 1.0)));
    }
    let st = gaussian_stats(splats, &scene.cameras[v], Some((&plane, 4)));
    let pick = |i: usize| {
        let s = &st.splat[4 * i..4 * i + 4];
        (s[0], [s[1], s[2], s[3]])
    };
    let all: Vec<usize>;
    let on = match on {
        Some(on) => on,
        None => {
            all = (0..scene.gaussians.len()).collect();
            &all
        }
    };
    let (support, change) = on.iter().map(|&i| pick(i)).unzip();
    Lifted { support, change }
}

/// What the edited views say about the target (on the universe of [`auto`]): each
/// Gaussian's target mass, the spread of its lifted change over the views that see it
/// well, and how many do.
struct Evidence {
    /// Support lifted over the chosen views (blend-weighted) ≥ [`AUTO_TARGET`], times
    /// the Gaussian's largest blend weight; 0 off the target.
    mass: Vec<f64>,
    /// Standard deviation of the lifted change over the chosen views that see the
    /// Gaussian well (where fewer than two do, the target's pooled spread, or with no
    /// such Gaussian at all the target's mean change: the edit is then as uncertain as it
    /// is large).
    spread: Vec<f64>,
    /// Chosen views that see the Gaussian well.
    count: Vec<usize>,
}

impl Evidence {
    /// The evidence of the chosen views `chosen` (indices into the edit views), with
    /// `weights` and `seen` of every edit view and `lifted(k)` view k's lift (`None`
    /// where the editor left it unedited).
    fn of<'l>(
        chosen: &[usize],
        weights: &[Vec<f32>],
        seen: &[Vec<bool>],
        lifted: impl Fn(usize) -> Option<&'l Lifted>,
    ) -> Evidence {
        let n = weights.first().map_or(0, Vec::len);
        let mut mass = vec![0.0; n];
        let mut spread = vec![0.0; n];
        let mut size = vec![0.0; n];
        let mut count = vec![0; n];
        for j in 0..n {
            let (mut num, mut den) = (0.0f64, 0.0f64);
            let mut changes = Vec::new();
            for &k in chosen {
                let Some(l) = lifted(k) else { continue };
                let w = weights[k][j] as f64;
                num += w * l.support[j] as f64;
                den += w;
                if seen[k][j] {
                    changes.push(l.change[j]);
                }
            }
            let best = weights.iter().map(|w| w[j]).fold(0.0, f32::max);
            if den > 0.0 && num / den >= AUTO_TARGET as f64 {
                mass[j] = num / den * best as f64;
            }
            count[j] = changes.len();
            if changes.len() >= 2 {
                spread[j] = spread_of(&changes);
            }
            if !changes.is_empty() {
                let sq: f64 = changes.iter().flatten().map(|&x| (x as f64).powi(2)).sum();
                size[j] = (sq / (3 * changes.len()) as f64).sqrt();
            }
        }
        let pooled = |value: &[f64], take: &dyn Fn(usize) -> bool| {
            let (num, den) = (0..n)
                .filter(|&j| mass[j] > 0.0 && take(j))
                .fold((0.0, 0.0), |(a, b), j| (a + mass[j] * value[j], b + mass[j]));
            (den > 0.0).then(|| num / den)
        };
        let fallback =
            pooled(&spread, &|j| count[j] >= 2).or_else(|| pooled(&size, &|j| count[j] >= 1)).unwrap_or(0.0);
        for j in 0..n {
            if count[j] < 2 {
                spread[j] = fallback;
            }
        }
        Evidence { mass, spread, count }
    }

    /// The standard error of a Gaussian's mean change from `n` views: spread / √n,
    /// and spread · √2 when no view sees it well.
    fn error_at(&self, j: usize, n: usize) -> f64 {
        self.spread[j] / (n as f64).max(0.5).sqrt()
    }

    /// The target's mean standard error, weighted by mass.
    fn standard_error(&self) -> f64 {
        let (num, den) =
            (0..self.mass.len()).filter(|&j| self.mass[j] > 0.0).fold((0.0, 0.0), |(a, b), j| {
                (a + self.mass[j] * self.error_at(j, self.count[j]), b + self.mass[j])
            });
        if den > 0.0 {
            num / den
        } else {
            0.0
        }
    }

    /// Up to `r` views not `taken`, chosen greedily: each the one whose edit would lower
    /// the target's mass-weighted standard error most (counting the views chosen before
    /// it in the round); ties to the lower index; none that lowers nothing.
    fn next_views(&self, seen: &[Vec<bool>], taken: &[bool], r: usize) -> Vec<usize> {
        let mut count = self.count.clone();
        let mut taken = taken.to_vec();
        let mut out = Vec::new();
        while out.len() < r {
            let gain = |k: usize| -> f64 {
                (0..self.mass.len())
                    .filter(|&j| self.mass[j] > 0.0 && seen[k][j])
                    .map(|j| self.mass[j] * (self.error_at(j, count[j]) - self.error_at(j, count[j] + 1)))
                    .sum()
            };
            let best = (0..seen.len()).filter(|&k| !taken[k]).map(|k| (k, gain(k))).fold(
                None,
                |b: Option<(usize, f64)>, (k, g)| match b {
                    Some((_, bg)) if bg >= g => b,
                    _ => Some((k, g)),
                },
            );
            match best {
                Some((k, g)) if g > 0.0 => {
                    taken[k] = true;
                    out.push(k);
                    for (j, c) in count.iter_mut().enumerate() {
                        if seen[k][j] {
                            *c += 1;
                        }
                    }
                }
                _ => break,
            }
        }
        out
    }
}

/// The spread of colour changes: the root of the mean over channels of their variance.
fn spread_of(changes: &[[f32; 3]]) -> f64 {
    let n = changes.len() as f64;
    let var: f64 = (0..3)
        .map(|c| {
            let mean = changes.iter().map(|x| x[c] as f64).sum::<f64>() / n;
            changes.iter().map(|x| (x[c] as f64 - mean).powi(2)).sum::<f64>() / (n - 1.0)
        })
        .sum::<f64>()
        / 3.0;
    var.sqrt()
}

/// The file in the checkpoint folder that keeps the views `auto` chose, so a resumed
/// edit takes the same views (and their edits from the checkpoint) without the editor.
pub const AUTO_FILE: &str = "auto_views.json";

/// Writes `views` as the `auto` choice of the job `key` into the checkpoint folder `dir`.
pub fn write_auto_choice(dir: &std::path::Path, views: &[usize], key: u64) -> Result<(), SessionError> {
    std::fs::create_dir_all(dir).map_err(|e| transsplat_scene::Error::io(dir, e))?;
    let json = serde_json::to_vec(&serde_json::json!({ "key": key, "views": views })).expect("numbers");
    Ok(transsplat_scene::atomic::write_bytes(&dir.join(AUTO_FILE), &json)?)
}

/// The `auto` choice of the job `key` kept in the checkpoint folder `dir`: an error naming
/// the file when it is missing, another job's, or not a sorted list of `candidates`.
pub fn read_auto_choice(
    dir: &std::path::Path,
    candidates: &[usize],
    key: u64,
) -> Result<Vec<usize>, SessionError> {
    let path = dir.join(AUTO_FILE);
    let bad = |why: String| SessionError::Input(format!("{}: {why}", path.display()));
    let bytes =
        std::fs::read(&path).map_err(|e| bad(format!("cannot read the views --views auto chose ({e})")))?;
    #[derive(serde::Deserialize)]
    struct Choice {
        key: u64,
        views: Vec<usize>,
    }
    let choice: Choice =
        serde_json::from_slice(&bytes).map_err(|e| bad(format!("not a list of views: {e}")))?;
    if choice.key != key {
        return Err(bad("the views were chosen for another scene, instruction or editor".into()));
    }
    if choice.views.is_empty()
        || choice.views.windows(2).any(|w| w[0] >= w[1])
        || choice.views.iter().any(|v| !candidates.contains(v))
    {
        return Err(bad(format!("not a sorted list of edit views (of {candidates:?})")));
    }
    Ok(choice.views)
}

/// An editor that hands back outputs made earlier (by [`auto`]), under the name of the
/// editor that made them, so the engine edits nothing twice.
pub struct Prepared {
    name: String,
    outputs: HashMap<usize, Option<EditedView>>,
}

impl Prepared {
    pub fn new(name: &str, views: &[usize], edited: Vec<Option<EditedView>>) -> Prepared {
        Prepared { name: name.to_string(), outputs: views.iter().copied().zip(edited).collect() }
    }
}

impl Editor for Prepared {
    fn name(&self) -> &str {
        &self.name
    }

    fn edit(&mut self, views: &[SourceView], _prompt: &str) -> Result<Vec<Option<EditedView>>, EditorError> {
        views
            .iter()
            .map(|v| {
                self.outputs.remove(&v.index).ok_or_else(|| {
                    EditorError::Invalid(format!("view {} was not among the views edited first", v.index))
                })
            })
            .collect()
    }
}

fn squared(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera at `centre` looking along `forward` (only the centre and the +z axis
    /// matter here).
    fn camera(centre: [f32; 3], forward: [f32; 3]) -> Camera {
        let mut c = Camera::pinhole("c", 8, 8, 8.0);
        let up = if forward[2].abs() < 0.9 { [0.0, 0.0, 1.0] } else { [1.0, 0.0, 0.0] };
        let cross = |a: [f32; 3], b: [f32; 3]| {
            [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
        };
        let norm = |v: [f32; 3]| {
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|x| x / l)
        };
        let z = norm(forward);
        let x = norm(cross(up, z));
        let y = cross(z, x);
        c.rotation = [x, y, z];
        // t = −R c
        c.translation = std::array::from_fn(|r| -(0..3).map(|k| c.rotation[r][k] * centre[k]).sum::<f32>());
        c
    }

    #[test]
    fn counts_are_checked() {
        assert_eq!(ViewChoice::parse("all"), Ok(ViewChoice::All));
        assert_eq!(ViewChoice::parse("auto"), Ok(ViewChoice::Auto));
        assert_eq!(ViewChoice::parse(" 3 "), Ok(ViewChoice::Count(3)));
        assert_eq!(ViewChoice::parse("1/3"), Ok(ViewChoice::Fraction(3)));
        assert!(ViewChoice::parse("1/0").is_err() && ViewChoice::parse("2/3").is_err());
        assert!(ViewChoice::parse("0").is_err() && ViewChoice::parse("half").is_err());
        let cams = vec![camera([0.0, 0.0, 0.0], [0.0, 1.0, 0.0]); 3];
        assert!(choose(&cams, &[1, 2], ViewChoice::Count(3)).is_err());
        assert_eq!(choose(&cams, &[1, 2], ViewChoice::All).unwrap(), vec![1, 2]);
        assert_eq!(choose(&cams, &[1, 2], ViewChoice::Auto).unwrap(), vec![1, 2], "auto's candidates");
        assert_eq!(choose(&cams, &[1, 2], ViewChoice::Fraction(2)).unwrap().len(), 1);
        assert_eq!(choose(&cams, &[0, 1, 2], ViewChoice::Fraction(2)).unwrap().len(), 2, "rounded up");
    }

    /// Two Gaussians of spread 0.1, the first seen by one chosen view, the second by
    /// none; the error from n views is 0.1 / √max(n, ½). Gains: view 1 (the first) 0.1 (1 −
    /// 1/√2) = 0.0293, view 2 (the second) 0.1 (√2 − 1) = 0.0414, view 3 (both) 0.0707:
    /// view 3; then view 1 gains 0.1 (1/√2 − 1/√3) = 0.0130, view 2 0.1 (1 − 1/√2): view 2.
    #[test]
    fn the_next_views_lower_the_standard_error_most() {
        let (t, f) = (true, false);
        let evidence = Evidence { mass: vec![1.0, 1.0], spread: vec![0.1, 0.1], count: vec![1, 0] };
        let seen = vec![vec![t, f], vec![t, f], vec![f, t], vec![t, t]];
        assert_eq!(evidence.next_views(&seen, &[t, f, f, f], 2), vec![3, 2]);
        assert_eq!(evidence.next_views(&seen, &[t, f, f, f], 1), vec![3]);
        // Nothing left that lowers the error: none.
        assert_eq!(evidence.next_views(&seen, &[t, t, t, t], 2), Vec::<usize>::new());
        let zero = Evidence { mass: vec![1.0, 1.0], spread: vec![0.0, 0.0], count: vec![1, 0] };
        assert_eq!(zero.next_views(&seen, &[t, f, f, f], 2), Vec::<usize>::new());
    }

    /// Views 0 and 1 chosen over two Gaussians. Gaussian 0: support 1 in both (mass 1 ×
    /// its best weight 1), changes 0.1 and 0.3 in every channel: spread √0.02, error
    /// √0.02/√2 = 0.1. Gaussian 1: support 1 and 0 at weights 1 and 0.1, lifted 1/1.1,
    /// seen well by view 0 only (0.1 < ¼): the pooled spread √0.02, error √0.02 from one
    /// view. The mean error (0.1 + 0.9091 · 0.14142) / 1.9091 = 0.11972.
    #[test]
    fn the_evidence_weighs_support_by_blend_weight_and_pools_the_spread() {
        let weights = vec![vec![1.0, 1.0], vec![1.0, 0.1], vec![1.0, 0.0]];
        let seen: Vec<Vec<bool>> = weights.iter().map(|w| w.iter().map(|&x| x >= 0.25).collect()).collect();
        let lifted = [
            Lifted { support: vec![1.0, 1.0], change: vec![[0.1; 3], [0.0; 3]] },
            Lifted { support: vec![1.0, 0.0], change: vec![[0.3; 3], [0.0; 3]] },
        ];
        let e = Evidence::of(&[0, 1], &weights, &seen, |k| lifted.get(k));
        assert_eq!(e.count, vec![2, 1]);
        assert!((e.mass[0] - 1.0).abs() < 1e-6 && (e.mass[1] - 1.0 / 1.1).abs() < 1e-6, "{:?}", e.mass);
        assert!((e.spread[0] - 0.02f64.sqrt()).abs() < 1e-6 && (e.spread[1] - e.spread[0]).abs() < 1e-12);
        assert!((e.standard_error() - 0.119725).abs() < 1e-5, "{}", e.standard_error());
        // Below the support threshold a Gaussian is off the target.
        let lifted = [
            Lifted { support: vec![0.4, 0.0], change: vec![[0.1; 3], [0.0; 3]] },
            Lifted { support: vec![0.4, 0.0], change: vec![[0.3; 3], [0.0; 3]] },
        ];
        let e = Evidence::of(&[0, 1], &weights, &seen, |k| lifted.get(k));
        assert_eq!(e.mass, vec![0.0, 0.0]);
        assert_eq!(e.standard_error(), 0.0);
    }

    #[test]
    fn prepared_hands_back_each_output_once_by_view() {
        let out = |v: f32| Some(EditedView::new(vec![v; 3], 1, 1, vec![v], None));
        let mut e = Prepared::new("ip2p", &[4, 7], vec![out(0.25), out(0.5)]);
        assert_eq!(e.name(), "ip2p");
        let cams = [Camera::pinhole("c", 1, 1, 1.0)];
        let view = |index| SourceView { index, camera: &cams[0], image: &[0.0; 3] };
        let got = e.edit(&[view(7), view(4)], "").unwrap();
        assert_eq!(got[0].as_ref().unwrap().image, vec![0.5; 3]);
        assert_eq!(got[1].as_ref().unwrap().image, vec![0.25; 3]);
        let err = e.edit(&[view(4)], "").unwrap_err().to_string();
        assert!(err.contains("view 4 was not among the views edited first"), "{err}");
    }

    /// Eight cameras on a ring looking at its centre: after the first, the opposite
    /// camera, d = 2/2 + (1 − (−1)) = 3 (the largest), then the two at right angles,
    /// √2/2 + 1 from both (a neighbour is only 0.38 + 0.29 from the nearer).
    #[test]
    fn a_ring_is_sampled_at_opposite_then_right_angles() {
        let cams: Vec<Camera> = (0..8)
            .map(|i| {
                let a = i as f32 * std::f32::consts::FRAC_PI_4;
                let c = [a.cos(), a.sin(), 0.0];
                camera(c, [-c[0], -c[1], 0.0])
            })
            .collect();
        for c in &cams {
            let got = c.centre();
            assert!(
                got.iter().zip(c.rotation[2]).all(|(p, f)| (p + f).abs() < 1e-5),
                "camera looks at the centre"
            );
        }
        let all: Vec<usize> = (0..8).collect();
        let two = choose(&cams, &all, ViewChoice::Count(2)).unwrap();
        assert_eq!(two[1] - two[0], 4, "{two:?}");
        let four = choose(&cams, &all, ViewChoice::Count(4)).unwrap();
        let f = two[0] % 2;
        assert_eq!(four, vec![f, f + 2, f + 4, f + 6]);
    }

    /// A forward-facing grid (one direction): positions alone spread the choice, from
    /// the central camera to the corners.
    #[test]
    fn a_forward_grid_is_sampled_from_the_centre_to_the_corners() {
        let mut cams = Vec::new();
        for y in [-1.0f32, 0.0, 1.0] {
            for x in [-1.0f32, 0.0, 1.0] {
                cams.push(camera([x, y, 0.0], [0.0, 0.0, 1.0]));
            }
        }
        let all: Vec<usize> = (0..9).collect();
        // The centre (index 4), then a corner (0.5 from it; ties go to the lower index).
        assert_eq!(choose(&cams, &all, ViewChoice::Count(2)).unwrap(), vec![0, 4]);
        // Then the corners 0.5 from the centre and farther from corner 0 (an edge
        // midpoint is 0.35 from both): the lowest of them.
        assert_eq!(choose(&cams, &all, ViewChoice::Count(3)).unwrap(), vec![0, 2, 4]);
        assert_eq!(choose(&cams, &all, ViewChoice::Count(5)).unwrap(), vec![0, 2, 4, 6, 8]);
    }
}
