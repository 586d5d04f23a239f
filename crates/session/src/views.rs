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

use crate::SessionError;
use transsplat_scene::cameras::split_views;
use transsplat_scene::Camera;

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
}

impl ViewChoice {
    /// Parses `all`, a positive count `K` or a fraction `1/N` (the message names no flag:
    /// fronts add theirs).
    pub fn parse(text: &str) -> Result<ViewChoice, String> {
        match text.trim() {
            "all" => Ok(ViewChoice::All),
            t if t.starts_with("1/") => match t[2..].parse::<usize>() {
                Ok(n) if n >= 1 => Ok(ViewChoice::Fraction(n)),
                _ => Err(format!("expected 1/N with N at least 1, got {t:?}")),
            },
            t => match t.parse::<usize>() {
                Ok(0) => Err("must be at least 1 (or all)".into()),
                Ok(k) => Ok(ViewChoice::Count(k)),
                Err(_) => Err(format!("expected all, a number of views or 1/N, got {t:?}")),
            },
        }
    }
}

/// The held-out test views and the views the editor edits, as camera indices in order:
/// [`split_views`] (every 8th camera held out), then `choice` among its edit views.
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
        ViewChoice::All => return Ok(edit_views.to_vec()),
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
        assert_eq!(ViewChoice::parse(" 3 "), Ok(ViewChoice::Count(3)));
        assert_eq!(ViewChoice::parse("1/3"), Ok(ViewChoice::Fraction(3)));
        assert!(ViewChoice::parse("1/0").is_err() && ViewChoice::parse("2/3").is_err());
        assert!(ViewChoice::parse("0").is_err() && ViewChoice::parse("half").is_err());
        let cams = vec![camera([0.0, 0.0, 0.0], [0.0, 1.0, 0.0]); 3];
        assert!(choose(&cams, &[1, 2], ViewChoice::Count(3)).is_err());
        assert_eq!(choose(&cams, &[1, 2], ViewChoice::All).unwrap(), vec![1, 2]);
        assert_eq!(choose(&cams, &[1, 2], ViewChoice::Fraction(2)).unwrap().len(), 1);
        assert_eq!(choose(&cams, &[0, 1, 2], ViewChoice::Fraction(2)).unwrap().len(), 2, "rounded up");
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
