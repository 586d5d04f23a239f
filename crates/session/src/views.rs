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
//! `auto` ([`auto`]) lets the edits say where the target is: the editor first edits a
//! quarter of the views chosen as above (the seeds), the support of each seed edit
//! (Ω_v: its thresholded attention within its mask, docs/method.md#m2-prototypes) is
//! lifted onto the Gaussians, and edit views are added greedily, each the one that sees
//! the most target mass still seen well by fewer than two chosen views, until at most
//! 2 % of the target mass is left so (the evidence the fusion's agreement between views
//! needs). A view sees a Gaussian well when its blend weight there is at least a
//! quarter of the Gaussian's largest over the edit views; a Gaussian's target mass is
//! its lifted support times that largest blend weight.

use std::collections::HashMap;

use crate::SessionError;
use transsplat_edit::edits::{edit_views, render_sources};
use transsplat_edit::lift::lift;
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
/// Chosen views that must see a target Gaussian well.
const AUTO_VIEWS_PER_GAUSSIAN: usize = 2;
/// A view sees a Gaussian well at this share of the Gaussian's largest blend weight.
const AUTO_SEEN_SHARE: f32 = 0.25;
/// Views are added until at most this share of the target mass is seen too rarely.
const AUTO_UNCOVERED: f64 = 0.02;
/// A Gaussian is part of the target when its lifted support is at least this.
const AUTO_TARGET: f32 = 0.5;

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

/// `--views auto` (module doc): edits the seeds, lifts their supports onto the
/// Gaussians and edits the views that the target needs as well. Errors when the seed
/// edits mark no target anywhere (the editor changed nothing).
pub fn auto(scene: &AutoScene, editor: &mut dyn Editor) -> Result<AutoChoice, SessionError> {
    let seeds = choose(scene.cameras, scene.edit_views, ViewChoice::Fraction(AUTO_SEED_FRACTION))?;
    let edit = |editor: &mut dyn Editor, views: &[usize]| -> Result<Vec<Option<EditedView>>, SessionError> {
        let cams: Vec<&Camera> = views.iter().map(|&v| &scene.cameras[v]).collect();
        let sources = render_sources(scene.gaussians, &cams, scene.background);
        Ok(edit_views(editor, scene.cameras, views, &sources, scene.prompt)?)
    };
    let seed_edits = edit(editor, &seeds)?;
    let support = lifted_support(scene, &seeds, &seed_edits);
    let target: Vec<usize> = (0..support.len()).filter(|&i| support[i] >= AUTO_TARGET).collect();
    let splats = Splats::new(scene.gaussians);
    // Blend weight of each target Gaussian in each edit view (views × target).
    let weights: Vec<Vec<f32>> = scene
        .edit_views
        .iter()
        .map(|&v| {
            let w = gaussian_stats(&splats, &scene.cameras[v], None).weight_sum;
            target.iter().map(|&i| w[i]).collect()
        })
        .collect();
    let best: Vec<f32> =
        (0..target.len()).map(|j| weights.iter().map(|w| w[j]).fold(0.0, f32::max)).collect();
    let mass: Vec<f64> = target.iter().zip(&best).map(|(&i, &b)| support[i] as f64 * b as f64).collect();
    if mass.iter().sum::<f64>() <= 0.0 {
        return Err(SessionError::Input(format!(
            "--views auto: the editor marked no target in its {} seed views (no attention or mask \
             anywhere), so there is nothing to choose views for; edit with --views all or a count",
            seeds.len()
        )));
    }
    let seen: Vec<Vec<bool>> = weights
        .iter()
        .map(|w| w.iter().zip(&best).map(|(&x, &b)| x > 0.0 && x >= AUTO_SEEN_SHARE * b).collect())
        .collect();
    let at = |v: usize| scene.edit_views.iter().position(|&e| e == v).expect("seeds are edit views");
    let chosen: Vec<usize> = seeds.iter().map(|&v| at(v)).collect();
    let added: Vec<usize> = cover(&mass, &seen, &chosen).into_iter().map(|k| scene.edit_views[k]).collect();
    tracing::info!(
        "--views auto: {} seed views, {} added for the target ({} Gaussians): {:?}",
        seeds.len(),
        added.len(),
        target.len(),
        added
    );
    let added_edits = if added.is_empty() { Vec::new() } else { edit(editor, &added)? };
    let mut all: Vec<(usize, Option<EditedView>)> = seeds.iter().copied().zip(seed_edits).collect();
    all.extend(added.iter().copied().zip(added_edits));
    all.sort_by_key(|(v, _)| *v);
    let (views, edited) = all.into_iter().unzip();
    Ok(AutoChoice { views, edited, seeds: seeds.len() })
}

/// Each Gaussian's support lifted from the edited views: the blend-weighted share of its
/// footprint in those views that lies in Ω_v (0 where no view blends it).
fn lifted_support(scene: &AutoScene, views: &[usize], edited: &[Option<EditedView>]) -> Vec<f32> {
    let mut cams = Vec::new();
    let mut planes = Vec::new();
    for (&v, e) in views.iter().zip(edited) {
        let Some(e) = e else { continue };
        let ev = ViewEvidence {
            width: e.width,
            height: e.height,
            attention: &e.attention,
            mask: e.mask.as_deref(),
            semantic: &[],
            d: 0,
            appearance: &[],
            d_app: 0,
        };
        let omega = view_support(&ev, scene.prototypes).omega;
        planes.push(omega.into_iter().map(|o| if o { 1.0f32 } else { 0.0 }).collect::<Vec<f32>>());
        cams.push(&scene.cameras[v]);
    }
    let planes: Vec<&[f32]> = planes.iter().map(Vec::as_slice).collect();
    lift(scene.gaussians, &cams, &planes, 1)
}

/// The greedy cover of `auto`: given each target Gaussian's mass, which candidate views
/// see it well (`seen[view][gaussian]`) and the views already chosen, adds the view
/// that sees the most mass still seen by fewer than two chosen views until at most 2 %
/// of the mass is left so, or no view adds any. Returns the added views in the order
/// added (ties to the lower index).
fn cover(mass: &[f64], seen: &[Vec<bool>], chosen: &[usize]) -> Vec<usize> {
    let need = AUTO_VIEWS_PER_GAUSSIAN.min(seen.len());
    let mut count: Vec<usize> =
        (0..mass.len()).map(|j| chosen.iter().filter(|&&v| seen[v][j]).count()).collect();
    let total: f64 = mass.iter().sum();
    let mut taken: Vec<bool> = (0..seen.len()).map(|v| chosen.contains(&v)).collect();
    let mut added = Vec::new();
    loop {
        let short = |j: usize| count[j] < need;
        let left: f64 = (0..mass.len()).filter(|&j| short(j)).map(|j| mass[j]).sum();
        if left <= AUTO_UNCOVERED * total {
            return added;
        }
        let gain =
            |v: usize| -> f64 { (0..mass.len()).filter(|&j| short(j) && seen[v][j]).map(|j| mass[j]).sum() };
        let best = (0..seen.len()).filter(|&v| !taken[v]).map(|v| (v, gain(v))).fold(
            None,
            |b: Option<(usize, f64)>, (v, g)| match b {
                Some((_, bg)) if bg >= g => b,
                _ => Some((v, g)),
            },
        );
        match best {
            Some((v, g)) if g > 0.0 => {
                taken[v] = true;
                added.push(v);
                for (j, c) in count.iter_mut().enumerate() {
                    if seen[v][j] {
                        *c += 1;
                    }
                }
            }
            _ => return added,
        }
    }
}

/// The file in the checkpoint folder that keeps the views `auto` chose, so a resumed
/// edit takes the same views (and their edits from the checkpoint) without the editor.
pub const AUTO_FILE: &str = "auto_views.json";

/// Writes `views` as the `auto` choice into the checkpoint folder `dir`.
pub fn write_auto_choice(dir: &std::path::Path, views: &[usize]) -> Result<(), SessionError> {
    std::fs::create_dir_all(dir).map_err(|e| transsplat_scene::Error::io(dir, e))?;
    let json = serde_json::to_vec(&serde_json::json!({ "views": views })).expect("a list of numbers");
    Ok(transsplat_scene::atomic::write_bytes(&dir.join(AUTO_FILE), &json)?)
}

/// The `auto` choice kept in the checkpoint folder `dir` (an error naming the file when
/// it is missing or not a list of views).
pub fn read_auto_choice(dir: &std::path::Path) -> Result<Vec<usize>, SessionError> {
    let path = dir.join(AUTO_FILE);
    let bad = |why: String| SessionError::Input(format!("{}: {why}", path.display()));
    let bytes =
        std::fs::read(&path).map_err(|e| bad(format!("cannot read the views --views auto chose ({e})")))?;
    #[derive(serde::Deserialize)]
    struct Choice {
        views: Vec<usize>,
    }
    let choice: Choice =
        serde_json::from_slice(&bytes).map_err(|e| bad(format!("not a list of views: {e}")))?;
    if choice.views.is_empty() {
        return Err(bad("no views".into()));
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

    /// Four Gaussians of mass 1, view 0 chosen. Short of two views: all four. Gains:
    /// view 1 sees {0} (1), view 2 {2, 3} (2), view 3 {1, 2, 3} (3): view 3 first; then
    /// {0, 2, 3} are short and view 2 gains 2, view 1 gains 1: view 2, then view 1 for
    /// Gaussian 0.
    #[test]
    fn the_cover_adds_the_view_that_sees_most_of_what_is_short() {
        let t = true;
        let f = false;
        let seen = vec![vec![t, t, f, f], vec![t, f, f, f], vec![f, f, t, t], vec![f, t, t, t]];
        assert_eq!(cover(&[1.0; 4], &seen, &[0]), vec![3, 2, 1]);
        // A Gaussian only one view sees: its mass stays short and the cover ends when
        // no view adds any.
        let seen = vec![vec![t, t], vec![f, t]];
        assert_eq!(cover(&[1.0, 1.0], &seen, &[0]), vec![1]);
        // 1 of 101 short is under 2 %: nothing to add.
        let seen = vec![vec![t, t], vec![t, f], vec![f, t]];
        assert_eq!(cover(&[100.0, 1.0], &seen, &[0, 1]), Vec::<usize>::new());
        // Equal gains go to the lower view.
        let seen = vec![vec![t, f], vec![f, t], vec![f, t], vec![t, f]];
        assert_eq!(cover(&[1.0, 1.0], &seen, &[]), vec![0, 1, 2, 3]);
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
