//! Initial Gaussians from a point cloud, as INRIA's `create_from_pcd`: one Gaussian
//! per point, isotropic scale √(mean squared distance to the 3 nearest neighbours)
//! (INRIA `distCUDA2`, clamped at 1e-7 squared), identity rotation, opacity 0.1,
//! SH DC from the point colour (`(c − 0.5) / C0`), higher SH zero. Then, by default,
//! [`flatten_on_surfaces`] turns each Gaussian whose neighbourhood in the cloud is a
//! surface flat onto it (the cloud samples surfaces; docs/method.md T6).
//!
//! The nearest neighbours come from a k-d tree (O(n log n)). Without a point cloud,
//! [`random_points`] samples points inside the cameras' common view.

use crate::densify::normal;
use crate::points::PointCloud;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use transsplat_raster::project::quat_from_matrix;
use transsplat_scene::{sh_coeffs, Camera, Gaussians, SH_C0};

/// Mean squared distance from each point to its `k` nearest other points (fewer
/// when there are fewer points; `fallback` when alone).
pub fn knn_mean_sq_dist(points: &[[f32; 3]], k: usize, fallback: f32) -> Vec<f32> {
    let tree = KdTree::build(points);
    (0..points.len())
        .into_par_iter()
        .with_min_len(256)
        .map(|i| {
            let best = tree.nearest(i, k);
            if best.is_empty() {
                fallback
            } else {
                best.iter().sum::<f32>() / best.len() as f32
            }
        })
        .collect()
}

/// An implicit k-d tree: the median of each range is its node, split on the axis of
/// largest extent.
struct KdTree<'a> {
    pts: &'a [[f32; 3]],
    idx: Vec<u32>,
    axis: Vec<u8>,
}

impl<'a> KdTree<'a> {
    fn build(pts: &'a [[f32; 3]]) -> Self {
        let mut idx: Vec<u32> = (0..pts.len() as u32).collect();
        let mut axis = vec![0u8; pts.len()];
        Self::split(pts, &mut idx, &mut axis);
        KdTree { pts, idx, axis }
    }

    fn split(pts: &[[f32; 3]], idx: &mut [u32], axis: &mut [u8]) {
        if idx.len() <= 1 {
            return;
        }
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for &i in idx.iter() {
            for a in 0..3 {
                lo[a] = lo[a].min(pts[i as usize][a]);
                hi[a] = hi[a].max(pts[i as usize][a]);
            }
        }
        let a = (0..3).max_by(|&x, &y| (hi[x] - lo[x]).total_cmp(&(hi[y] - lo[y]))).unwrap_or(0);
        let mid = idx.len() / 2;
        idx.select_nth_unstable_by(mid, |&p, &q| pts[p as usize][a].total_cmp(&pts[q as usize][a]));
        axis[mid] = a as u8;
        let (l, r) = idx.split_at_mut(mid);
        let (la, ra) = axis.split_at_mut(mid);
        if l.len() + r.len() > 4096 {
            rayon::join(|| Self::split(pts, l, la), || Self::split(pts, &mut r[1..], &mut ra[1..]));
        } else {
            Self::split(pts, l, la);
            Self::split(pts, &mut r[1..], &mut ra[1..]);
        }
    }

    /// Squared distances to the `k` nearest points other than `query` itself.
    fn nearest(&self, query: usize, k: usize) -> Vec<f32> {
        self.nearest_ids(query, k).into_iter().map(|(d, _)| d).collect()
    }

    /// The `k` nearest points other than `query` itself: (squared distance, index),
    /// nearest first.
    fn nearest_ids(&self, query: usize, k: usize) -> Vec<(f32, u32)> {
        let mut best: Vec<(f32, u32)> = Vec::with_capacity(k + 1);
        self.visit(0, self.idx.len(), query, k, &mut best);
        best
    }

    fn visit(&self, lo: usize, hi: usize, query: usize, k: usize, best: &mut Vec<(f32, u32)>) {
        if lo >= hi || k == 0 {
            return;
        }
        let mid = lo + (hi - lo) / 2;
        let q = self.pts[query];
        let id = self.idx[mid] as usize;
        let p = self.pts[id];
        if id != query {
            let d = (0..3).map(|a| (p[a] - q[a]).powi(2)).sum::<f32>();
            if best.len() < k || d < best[best.len() - 1].0 {
                let at = best.partition_point(|&(b, _)| b <= d);
                best.insert(at, (d, id as u32));
                best.truncate(k);
            }
        }
        let a = self.axis[mid] as usize;
        let diff = q[a] - p[a];
        let (near, far) = if diff < 0.0 { ((lo, mid), (mid + 1, hi)) } else { ((mid + 1, hi), (lo, mid)) };
        self.visit(near.0, near.1, query, k, best);
        if best.len() < k || diff * diff < best[best.len() - 1].0 {
            self.visit(far.0, far.1, query, k, best);
        }
    }
}

/// INRIA `inverse_sigmoid`.
pub fn logit(p: f32) -> f32 {
    (p / (1.0 - p)).ln()
}

/// Gaussians from a point cloud (see the module docs). `fallback_scale` is used for
/// a lone point.
pub fn gaussians_from_points(cloud: &PointCloud, max_sh_degree: u32, fallback_scale: f32) -> Gaussians {
    let n = cloud.len();
    let d2 = knn_mean_sq_dist(&cloud.positions, 3, fallback_scale * fallback_scale);
    let kc = sh_coeffs(max_sh_degree) * 3;
    let mut sh = vec![0.0f32; n * kc];
    for (row, c) in sh.chunks_exact_mut(kc).zip(&cloud.colors) {
        for ch in 0..3 {
            row[ch] = (c[ch] - 0.5) / SH_C0;
        }
    }
    Gaussians {
        means: cloud.positions.clone(),
        log_scales: d2.iter().map(|&d| [d.max(1e-7).sqrt().ln(); 3]).collect(),
        rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
        opacity_logits: vec![logit(0.1); n],
        sh_degree: max_sh_degree,
        sh,
        extra: Default::default(),
    }
}

/// Neighbours whose spread decides a point's surface ([`flatten_on_surfaces`]).
pub const SURFACE_NEIGHBOURS: usize = 8;
/// A neighbourhood is a surface when its spread off its best plane is under this share
/// of its spread along the plane's shorter axis (standard deviations).
const PLANAR: f64 = 0.2;
/// The flattest initial Gaussian: its normal scale is at least this share of its
/// in-plane scale.
const MIN_FLATNESS: f32 = 0.1;

/// Flattens each initial Gaussian whose cloud neighbourhood is a surface onto that
/// surface: the cloud samples surfaces, so no point supports a Gaussian's extent off its
/// surface. With INRIA's isotropic start, a far floor's sparse points (tens of
/// centimetres apart) start as balls as tall as they are wide, and densification's splits,
/// which sample the children inside the parent, scatter them above and below the floor,
/// where views at grazing angles cannot tell their height (docs/method.md T6).
///
/// For each Gaussian whose point has [`SURFACE_NEIGHBOURS`] neighbours: the covariance of
/// the point and its neighbours, eigenvalues λ₀ ≤ λ₁ ≤ λ₂ with axes e₀, e₁, e₂. When
/// √λ₀ < [`PLANAR`] √λ₁ the Gaussian is turned to the axes (e₁, e₂, e₀) and its normal
/// scale set to max(√λ₀, [`MIN_FLATNESS`] × its in-plane scale); its in-plane scales and
/// everything else stay INRIA's. A Gaussian whose normal scale would not come out below
/// its in-plane scale stays a ball. Returns how many were flattened.
pub fn flatten_on_surfaces(g: &mut Gaussians, points: &[[f32; 3]]) -> usize {
    assert_eq!(g.len(), points.len(), "one Gaussian per point");
    let tree = KdTree::build(points);
    let shapes: Vec<Option<([f32; 4], f32)>> = (0..points.len())
        .into_par_iter()
        .with_min_len(256)
        .map(|i| {
            let near = tree.nearest_ids(i, SURFACE_NEIGHBOURS);
            (near.len() == SURFACE_NEIGHBOURS).then(|| surface_frame(points, i, &near)).flatten()
        })
        .collect();
    let mut flattened = 0;
    for (i, shape) in shapes.into_iter().enumerate() {
        let Some((quat, normal_sd)) = shape else { continue };
        let in_plane = g.log_scales[i][0];
        let normal = normal_sd.max(MIN_FLATNESS * in_plane.exp()).max(1e-7).ln();
        if normal < in_plane {
            g.log_scales[i] = [in_plane, in_plane, normal];
            g.rotations[i] = quat;
            flattened += 1;
        }
    }
    flattened
}

/// The quaternion whose rotation has columns (e₁, e₂, e₀) (e₀ the normal) and √λ₀, when
/// the neighbourhood of point `i` is a surface ([`flatten_on_surfaces`]).
fn surface_frame(points: &[[f32; 3]], i: usize, near: &[(f32, u32)]) -> Option<([f32; 4], f32)> {
    let members: Vec<[f64; 3]> = std::iter::once(i)
        .chain(near.iter().map(|&(_, j)| j as usize))
        .map(|j| points[j].map(f64::from))
        .collect();
    let n = members.len() as f64;
    let c: [f64; 3] = std::array::from_fn(|a| members.iter().map(|p| p[a]).sum::<f64>() / n);
    let mut cov = [0.0f64; 9];
    for p in &members {
        for a in 0..3 {
            for b in 0..3 {
                cov[a * 3 + b] += (p[a] - c[a]) * (p[b] - c[b]) / n;
            }
        }
    }
    let (values, vectors) = crate::linalg::symmetric_eigen(&cov, 3);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let [l0, l1] = [values[order[0]].max(0.0), values[order[1]].max(0.0)];
    if !(l1 > 0.0 && l0.sqrt() < PLANAR * l1.sqrt()) {
        return None;
    }
    let axis = |k: usize| -> [f64; 3] { std::array::from_fn(|r| vectors[r * 3 + order[k]]) };
    let (e1, e2, mut e0) = (axis(1), axis(2), axis(0));
    // A right-handed frame: e₀ = e₁ × e₂ up to sign.
    let cross = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]];
    if cross.iter().zip(&e0).map(|(a, b)| a * b).sum::<f64>() < 0.0 {
        e0 = e0.map(|v| -v);
    }
    let m = [[e1[0], e2[0], e0[0]], [e1[1], e2[1], e0[1]], [e1[2], e2[2], e0[2]]];
    Some((quat_from_matrix(m.map(|row| row.map(|v| v as f32))), l0.sqrt() as f32))
}

/// The point closest (least squares) to every camera's optical axis, pulled
/// slightly towards the mean camera centre so parallel axes stay well posed.
pub fn look_at_centre(cameras: &[Camera]) -> [f32; 3] {
    let n = cameras.len().max(1) as f64;
    let centres: Vec<[f64; 3]> = cameras.iter().map(|c| c.centre().map(f64::from)).collect();
    let mean: [f64; 3] = std::array::from_fn(|k| centres.iter().map(|c| c[k]).sum::<f64>() / n);
    // Σ (I − d dᵀ) x = Σ (I − d dᵀ) c, plus λ (x − mean).
    let mut a = [[0.0f64; 3]; 3];
    let mut b = [0.0f64; 3];
    for (cam, c) in cameras.iter().zip(&centres) {
        let d = cam.rotation[2].map(f64::from); // camera z axis in world coordinates
        let dn = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-12);
        let d = d.map(|v| v / dn);
        for i in 0..3 {
            for j in 0..3 {
                let m = if i == j { 1.0 } else { 0.0 } - d[i] * d[j];
                a[i][j] += m;
                b[i] += m * c[j];
            }
        }
    }
    let lambda = 1e-3 * n;
    for i in 0..3 {
        a[i][i] += lambda;
        b[i] += lambda * mean[i];
    }
    solve3(a, b).map(|x| x.map(|v| v as f32)).unwrap_or(mean.map(|v| v as f32))
}

fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    if !(d.abs() > 1e-12) {
        return None;
    }
    let x: [f64; 3] = std::array::from_fn(|k| {
        let mut m = a;
        for i in 0..3 {
            m[i][k] = b[i];
        }
        det(m) / d
    });
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Whether a world point projects inside a camera's image, in front of it.
fn sees(cam: &Camera, p: [f32; 3]) -> bool {
    pixel(cam, p).is_some()
}

/// Most random initial points a run may ask for (10 million: far more than any
/// capture needs, and about 2.5 GB of Gaussians with their optimiser state).
pub const MAX_RANDOM_POINTS: usize = 10_000_000;

/// `n` random points in the cameras' common view: uniform in a box around the point
/// the cameras look at (half-size: the mean camera distance to it), kept when at
/// least half the cameras see them (any camera, if too few pass), with random
/// colours. Deterministic for a seed.
pub fn random_points(cameras: &[Camera], n: usize, rng: &mut ChaCha8Rng) -> PointCloud {
    let mut cloud = PointCloud::default();
    if cameras.is_empty() || n == 0 {
        return cloud;
    }
    let centre = look_at_centre(cameras);
    let half = cameras
        .iter()
        .map(|c| {
            let p = c.centre();
            ((p[0] - centre[0]).powi(2) + (p[1] - centre[1]).powi(2) + (p[2] - centre[2]).powi(2)).sqrt()
        })
        .sum::<f32>()
        / cameras.len() as f32;
    let half = if half.is_finite() && half > 1e-6 { half } else { 1.0 };
    let need = cameras.len().div_ceil(2);
    for min_seen in [need, 1] {
        let mut tries = 0usize;
        while cloud.len() < n && tries < 50 * n {
            tries += 1;
            let p: [f32; 3] = std::array::from_fn(|k| centre[k] + half * rng.gen_range(-1.0f32..1.0));
            let seen = cameras.iter().filter(|c| sees(c, p)).take(min_seen).count();
            if seen >= min_seen {
                cloud.positions.push(p);
                cloud.colors.push([rng.gen(), rng.gen(), rng.gen()]);
            }
        }
        if cloud.len() >= n {
            break;
        }
    }
    if cloud.is_empty() {
        // Nothing visible at all (degenerate rig): a Gaussian ball at the centre.
        for _ in 0..n {
            cloud.positions.push(std::array::from_fn(|k| centre[k] + 0.3 * half * normal(rng)));
            cloud.colors.push([rng.gen(), rng.gen(), rng.gen()]);
        }
    }
    cloud
}

/// Most sky points a run places (before keeping those a training view sees).
pub const MAX_SKY_POINTS: usize = 200_000;

/// A sky dome: points on a sphere about the cameras' centre, far enough that the
/// training cameras' spread moves them by under a pixel, spaced `spacing_px` pixels
/// apart at the largest focal length, above the horizon the cameras give
/// ([`cameras_up`]), kept where at least half the training views that frame them see
/// them past the cloud's walls ([`walled`]) and the cloud does not already reach the sky
/// ([`sky_reached`]), each coloured by the mean of the training pixels it projects to in
/// those views. The sky is open from nearly every view that frames it; a gap between
/// the points a sparse cloud puts on a wall lines up with a direction from a few views
/// only, as the views' parallax moves the wall's points across it (docs/method.md T4).
/// A direction where every
/// view that sees it shows the training `background` (within 2/255 in every channel)
/// gets no point: the background already draws it, and a dome there would replace the
/// background a user renders over (an object shot against white, say).
///
/// The sky (and anything at infinity) has no SfM points, so without a dome it is
/// grown by densification from the nearest surface points and ends tens of metres
/// away, where the vertical spread of the cameras moves it by several pixels against
/// the far floor: the horizon lands in the wrong row of a held-out view (docs/method.md
/// T4). Hierarchical 3DGS (Kerbl et al. 2024) initialises a skybox of points for the
/// same reason. The radius is the larger of 10 × the farthest point and
/// `f · B` (B the largest distance between training cameras, so the parallax is at
/// most a pixel).
pub fn sky_points(
    views: &[crate::dataset::View],
    cloud: &PointCloud,
    spacing_px: f32,
    background: [f32; 3],
) -> PointCloud {
    let mut sky = PointCloud::default();
    let cameras: Vec<&Camera> = views.iter().map(|v| &v.camera).collect();
    if cameras.is_empty() || !(spacing_px > 0.0) {
        return sky;
    }
    let n = cameras.len() as f32;
    let centres: Vec<[f32; 3]> = cameras.iter().map(|c| c.centre()).collect();
    let centre: [f32; 3] = std::array::from_fn(|k| centres.iter().map(|c| c[k]).sum::<f32>() / n);
    let dist = |a: [f32; 3], b: [f32; 3]| {
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    };
    let farthest_point = cloud.positions.iter().map(|&p| dist(p, centre)).fold(0.0f32, f32::max);
    let spread = centres.iter().map(|&c| 2.0 * dist(c, centre)).fold(0.0f32, f32::max);
    let focal = cameras.iter().map(|c| c.fx.max(c.fy)).fold(0.0f32, f32::max);
    let radius = (10.0 * farthest_point).max(focal * spread).max(1.0);
    if !radius.is_finite() || !(focal > 0.0) {
        return sky;
    }
    // Without a consistent up there is no horizon to put the sky above, and no dome.
    let Some(up) = cameras_up(&cameras) else {
        return sky;
    };
    // Fibonacci sphere: N points whose spacing is about √(4π / N) radians.
    let spacing = spacing_px / focal;
    let total = ((4.0 * std::f32::consts::PI / (spacing * spacing)) as usize).clamp(2, MAX_SKY_POINTS);
    let directions = fibonacci_sphere(total);
    let reached = sky_reached(cloud, centre, spread / 2.0, up, spacing, &directions);
    // Only above the horizon: below it, a far backdrop would stand in for the ground,
    // right from the height of the views that trained it and wrong from any other.
    let candidates: Vec<[f32; 3]> = directions
        .into_iter()
        .zip(reached)
        .filter(|(dir, reached)| dir[0] * up[0] + dir[1] * up[1] + dir[2] * up[2] >= 0.0 && !reached)
        .map(|(dir, _)| std::array::from_fn(|k| centre[k] + radius * dir[k]))
        .collect();
    let walled = walled(views, cloud, centre, up, spacing_px, &candidates);
    for (i, &p) in candidates.iter().enumerate() {
        // Coloured by, and kept for, the views that see the direction open (not
        // behind a wall of the cloud's, [`walled`]).
        let mut sum = [0.0f32; 3];
        let mut seen = 0usize;
        let mut framed = 0usize;
        let mut shows_more_than_background = false;
        for (view, walled) in views.iter().zip(&walled) {
            let Some((u, v)) = pixel(&view.camera, p) else { continue };
            framed += 1;
            if !walled[i] {
                let k = (v * view.camera.width as usize + u) * 3;
                for ch in 0..3 {
                    sum[ch] += view.image[k + ch];
                    shows_more_than_background |= (view.image[k + ch] - background[ch]).abs() > 2.0 / 255.0;
                }
                seen += 1;
            }
        }
        if seen > 0 && 2 * seen >= framed && shows_more_than_background {
            sky.positions.push(p);
            sky.colors.push(sum.map(|s| s / seen as f32));
        }
    }
    sky
}

/// Largest share of the cameras' image-right axes' spread, off their main direction,
/// below which the right axes are taken as one direction (sin² 10°: every camera turned
/// within about 10° of the same way) and do not fix the up on their own ([`cameras_up`]).
const LEVEL_SPREAD: f64 = 0.03;

/// The world's up as the cameras give it, for the dome's horizon (docs/method.md T4):
/// a camera held without roll has a level image-right axis (its rotation's first row),
/// so the up is the direction most nearly perpendicular to all of them, the
/// eigenvector of the smallest eigenvalue of `Σ x_i x_iᵀ`, signed to agree with the
/// mean image-up (−y of OpenCV cameras, the rotation's second row, negated). The mean
/// image-up alone tilts towards the cameras' common viewing direction by their mean
/// pitch when they all look down at a subject from one side (an arc, a forward-facing
/// capture); the right axes do not. When the right axes are nearly one direction (the
/// middle eigenvalue under [`LEVEL_SPREAD`] of the count: every camera faces the same
/// way), the two smallest eigenvectors span both the up and that viewing direction, and
/// the mean image-up's part in their plane is all there is to go by. `None` when the
/// image-up axes do not agree (their mean shorter than half a unit), as cameras turned
/// every way round have no common up.
fn cameras_up(cameras: &[&Camera]) -> Option<[f32; 3]> {
    let n = cameras.len() as f64;
    let mean_up: [f64; 3] =
        std::array::from_fn(|k| -cameras.iter().map(|c| f64::from(c.rotation[1][k])).sum::<f64>() / n);
    if !(norm64(mean_up) > 0.5) {
        return None;
    }
    let mut scatter = vec![0.0f64; 9];
    for c in cameras {
        let right = c.rotation[0].map(f64::from);
        for i in 0..3 {
            for j in 0..3 {
                scatter[i * 3 + j] += right[i] * right[j];
            }
        }
    }
    let (values, vectors) = crate::linalg::symmetric_eigen(&scatter, 3);
    let mut ascending = [0usize, 1, 2];
    ascending.sort_by(|&i, &j| values[i].total_cmp(&values[j]));
    // The k-th smallest eigenvalue's eigenvector.
    let column = |k: usize| -> [f64; 3] { std::array::from_fn(|i| vectors[i * 3 + ascending[k]]) };
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let up = if values[ascending[1]] >= LEVEL_SPREAD * n {
        column(0)
    } else {
        let (a, b) = (column(0), column(1));
        let (pa, pb) = (dot(mean_up, a), dot(mean_up, b));
        std::array::from_fn(|i| pa * a[i] + pb * b[i])
    };
    let length = norm64(up);
    if !(length > 1e-6) {
        return None;
    }
    let sign = if dot(up, mean_up) < 0.0 { -1.0 } else { 1.0 };
    Some(up.map(|v| (sign * v / length) as f32))
}

fn norm64(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// `n` unit vectors spread evenly over the sphere (a Fibonacci lattice), ordered by
/// decreasing z: z_i = 1 − 2 (i + ½) / n, azimuth i × the golden angle.
fn fibonacci_sphere(n: usize) -> Vec<[f32; 3]> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let theta = golden * i as f32;
            [r * theta.cos(), r * theta.sin(), z]
        })
        .collect()
}

/// The directions, seen from the cameras' centre, where the cloud already reaches
/// the sky: each cloud point above the horizon and outside the rig (farther from the
/// centre than twice `rig`, the farthest camera's distance) covers the cap of its neighbour spacing as
/// seen from the centre (at least the dome's own spacing). Densification grows what
/// lies there from those points, at their depth, so a dome behind them would only add
/// a second sky at the wrong distance: the built-in open scenes' sky is a sphere 30 m
/// out that the cloud samples, with 40 px of parallax across their orbit (docs/method.md
/// T4). Points inside the rig (the table, the objects) cover nothing: from the other
/// cameras they move off the directions they hide from the centre.
fn sky_reached(
    cloud: &PointCloud,
    centre: [f32; 3],
    rig: f32,
    up: [f32; 3],
    spacing: f32,
    directions: &[[f32; 3]],
) -> Vec<bool> {
    let norm = |a: [f32; 3]| (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let outside: Vec<[f32; 3]> = cloud
        .positions
        .iter()
        .map(|&p| std::array::from_fn(|k| p[k] - centre[k]))
        .filter(|&d: &[f32; 3]| norm(d) > 2.0 * rig && dot(d, up) >= 0.0)
        .collect();
    let mut reached = vec![false; directions.len()];
    if outside.is_empty() {
        return reached;
    }
    let neighbour = knn_mean_sq_dist(&outside, 3, 0.0);
    let n = directions.len() as f32;
    for (d, sq) in outside.iter().zip(neighbour) {
        let r = norm(*d);
        let cap = (sq.sqrt() / r).max(spacing).min(std::f32::consts::FRAC_PI_2);
        let axis = d.map(|v| v / r);
        // The Fibonacci directions are ordered by z: only the band of z the cap spans
        // needs testing.
        let polar = axis[2].clamp(-1.0, 1.0).acos();
        let z_high = (polar - cap).max(0.0).cos();
        let z_low = (polar + cap).min(std::f32::consts::PI).cos();
        let first = (((1.0 - z_high) * n / 2.0 - 0.5).floor().max(0.0)) as usize;
        let last = (((1.0 - z_low) * n / 2.0 - 0.5).ceil().max(0.0) as usize).min(directions.len() - 1);
        let cos_cap = cap.cos();
        for i in first..=last {
            reached[i] |= dot(directions[i], axis) >= cos_cap;
        }
    }
    reached
}

/// Per training view, which of the dome's `points` a wall of the cloud's hides: each
/// cloud point above the horizon, at any distance, drawn into the view as a disc of its
/// neighbour spacing (at least half a pixel, at most [`WALL_DISC_SPACINGS`] dome
/// spacings: a wider disc would be a lone point's, not a surface's), hides the dome
/// points that project inside it. A room's walls and a building's façade rise above the
/// cameras' horizon all round them, so from every view the sky they hide is behind them:
/// a dome there is a second backdrop at the wrong depth, and cost the built-in tabletop,
/// a room without a ceiling, 1.7 dB (docs/method.md T5). Below the horizon the far floor
/// lies in front of no sky. An object above the horizon inside the rig hides a direction
/// from some views only; the others keep it. A view's discs live only while its answer
/// is computed, so the memory is one image per thread.
fn walled(
    views: &[crate::dataset::View],
    cloud: &PointCloud,
    centre: [f32; 3],
    up: [f32; 3],
    spacing_px: f32,
    points: &[[f32; 3]],
) -> Vec<Vec<bool>> {
    let max_radius = (WALL_DISC_SPACINGS * spacing_px).max(0.5);
    let above: Vec<[f32; 3]> = cloud
        .positions
        .iter()
        .copied()
        .filter(|p| (0..3).map(|k| (p[k] - centre[k]) * up[k]).sum::<f32>() >= 0.0)
        .collect();
    if above.is_empty() {
        return vec![vec![false; points.len()]; views.len()];
    }
    let spacing: Vec<f32> = knn_mean_sq_dist(&above, 3, 0.0).into_iter().map(f32::sqrt).collect();
    views
        .par_iter()
        .map(|view| {
            let cam = &view.camera;
            let (w, h) = (cam.width as usize, cam.height as usize);
            let mut discs = vec![false; w * h];
            for (&p, s) in above.iter().zip(&spacing) {
                let Some((u, v, depth)) = project(cam, p) else { continue };
                let radius = (s * cam.fx.max(cam.fy) / depth).clamp(0.5, max_radius);
                let (x0, x1) = ((u - radius).floor().max(0.0), (u + radius).ceil().min(w as f32 - 1.0));
                let (y0, y1) = ((v - radius).floor().max(0.0), (v + radius).ceil().min(h as f32 - 1.0));
                if x0 > x1 || y0 > y1 {
                    continue;
                }
                for y in y0 as usize..=y1 as usize {
                    for x in x0 as usize..=x1 as usize {
                        let (dx, dy) = (x as f32 + 0.5 - u, y as f32 + 0.5 - v);
                        if dx * dx + dy * dy <= radius * radius {
                            discs[y * w + x] = true;
                        }
                    }
                }
            }
            points.iter().map(|&p| pixel(cam, p).is_some_and(|(u, v)| discs[v * w + u])).collect()
        })
        .collect()
}

/// The largest disc a cloud point draws in [`walled`], in dome spacings.
const WALL_DISC_SPACINGS: f32 = 4.0;

/// Where a world point lands in a camera's image, (u, v) in pixels, and its depth, when
/// it lies in front of the camera.
fn project(cam: &Camera, p: [f32; 3]) -> Option<(f32, f32, f32)> {
    let r = &cam.rotation;
    let t = &cam.translation;
    let c: [f32; 3] = std::array::from_fn(|i| r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2] + t[i]);
    (c[2] > 0.01).then(|| (cam.fx * c[0] / c[2] + cam.cx, cam.fy * c[1] / c[2] + cam.cy, c[2]))
}

/// The pixel a world point projects to, when in front of the camera and inside its
/// image.
fn pixel(cam: &Camera, p: [f32; 3]) -> Option<(usize, usize)> {
    let (u, v, _) = project(cam, p)?;
    (u >= 0.0 && v >= 0.0 && u < cam.width as f32 && v < cam.height as f32)
        .then_some((u as usize, v as usize))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn kd_tree_matches_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut pts: Vec<[f32; 3]> = (0..2000)
            .map(|_| [rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen::<f32>() * 0.1])
            .collect();
        pts.push(pts[5]); // a duplicate
        let got = knn_mean_sq_dist(&pts, 3, 1.0);
        for i in (0..pts.len()).step_by(37).chain([5, pts.len() - 1]) {
            let mut d: Vec<f32> = (0..pts.len())
                .filter(|&j| j != i)
                .map(|j| (0..3).map(|a| (pts[i][a] - pts[j][a]).powi(2)).sum())
                .collect();
            d.sort_by(f32::total_cmp);
            let want = (d[0] + d[1] + d[2]) / 3.0;
            assert!((got[i] - want).abs() <= 1e-6 * want.max(1e-6), "point {i}: {} vs {want}", got[i]);
        }
        assert_eq!(knn_mean_sq_dist(&[[0.0; 3]], 3, 0.25), vec![0.25]);
        assert_eq!(knn_mean_sq_dist(&[[0.0; 3], [0.0, 0.0, 2.0]], 3, 0.25), vec![4.0, 4.0]);
    }

    /// Points on a tilted plane: every Gaussian turns its third axis to the plane's normal
    /// with a small scale there; a point inside a lattice is on no surface and stays a ball.
    #[test]
    fn gaussians_on_a_plane_are_flattened_onto_it() {
        let normal = {
            let v = [0.3f32, -0.2, 1.0];
            let l = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            v.map(|x| x / l)
        };
        // Two in-plane axes orthogonal to the normal.
        let u = {
            let v = [1.0f32, 0.0, -normal[0] / normal[2]];
            let l = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            v.map(|x| x / l)
        };
        let w = [
            normal[1] * u[2] - normal[2] * u[1],
            normal[2] * u[0] - normal[0] * u[2],
            normal[0] * u[1] - normal[1] * u[0],
        ];
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let points: Vec<[f32; 3]> = (0..400)
            .map(|k| {
                let (a, b) = ((k % 20) as f32 * 0.3, (k / 20) as f32 * 0.3);
                let off = rng.gen_range(-0.002f32..0.002);
                std::array::from_fn(|c| a * u[c] + b * w[c] + off * normal[c] + [1.0, 2.0, 3.0][c])
            })
            .collect();
        let cloud = PointCloud { positions: points.clone(), colors: vec![[0.5; 3]; points.len()] };
        let mut g = gaussians_from_points(&cloud, 0, 0.1);
        let before = g.log_scales.clone();
        assert_eq!(flatten_on_surfaces(&mut g, &points), points.len());
        for i in 0..points.len() {
            let r = transsplat_raster::project::rotation_matrix(g.rotations[i]);
            let axis = [r[0][2], r[1][2], r[2][2]];
            let along = axis.iter().zip(&normal).map(|(a, b)| a * b).sum::<f32>().abs();
            assert!(along > 0.999, "point {i}: third axis {axis:?}, normal {normal:?}");
            let [s0, s1, s2] = g.log_scales[i];
            assert!(s0 == before[i][0] && s1 == before[i][1], "in-plane scales are INRIA's");
            assert!((s2 - (s0.exp() * MIN_FLATNESS).ln()).abs() < 1e-4, "flattened to the floor: {s2} {s0}");
        }
        // The centre of a 3 × 3 × 3 lattice has neighbours on every side: no surface.
        let lattice: Vec<[f32; 3]> =
            (0..27).map(|k| [(k % 3) as f32, ((k / 3) % 3) as f32, (k / 9) as f32]).collect();
        let cloud = PointCloud { positions: lattice.clone(), colors: vec![[0.5; 3]; lattice.len()] };
        let mut g = gaussians_from_points(&cloud, 0, 0.1);
        let before = g.log_scales[13];
        flatten_on_surfaces(&mut g, &lattice);
        assert_eq!(g.log_scales[13], before, "the lattice's centre stays a ball");
    }

    #[test]
    fn gaussians_from_points_follow_inria() {
        let cloud = PointCloud {
            positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            colors: vec![[0.5, 1.0, 0.0]; 4],
        };
        let g = gaussians_from_points(&cloud, 3, 0.1);
        g.validate().unwrap();
        assert_eq!(g.len(), 4);
        assert!((g.log_scales[0][0] - 0.0).abs() < 1e-6, "three neighbours at distance 1");
        assert!((crate::densify::quat_matrix(g.rotations[0])[0][0] - 1.0).abs() < 1e-6);
        assert!((transsplat_scene::sigmoid(g.opacity_logits[0]) - 0.1).abs() < 1e-6);
        assert!((g.sh[0] - 0.0).abs() < 1e-6 && (g.sh[1] - 0.5 / SH_C0).abs() < 1e-5);
        assert!(g.sh[3..48].iter().all(|&v| v == 0.0));
    }

    /// Four cameras on a ring of radius 4 about the origin at height 0, looking at it,
    /// world up +y (the cameras' image-down axis is −y); `flip` turns the odd ones
    /// upside down.
    fn ring(flip: bool) -> Vec<Camera> {
        (0..4)
            .map(|k| {
                let a = k as f32 * std::f32::consts::FRAC_PI_2;
                let c = [4.0 * a.cos(), 0.0, 4.0 * a.sin()];
                let z = [-a.cos(), 0.0, -a.sin()];
                let y = if flip && k % 2 == 1 { [0.0, 1.0, 0.0] } else { [0.0, -1.0, 0.0] };
                let x = [y[1] * z[2] - y[2] * z[1], y[2] * z[0] - y[0] * z[2], y[0] * z[1] - y[1] * z[0]];
                let r = [[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]];
                Camera::from_c2w(format!("{k}"), 64, 48, 50.0, 50.0, 32.0, 24.0, r, c)
            })
            .collect()
    }

    #[test]
    fn sky_dome_lies_far_above_the_horizon_in_the_views_colours() {
        let colour = |k: usize| [k as f32 / 4.0, 0.5, 1.0 - k as f32 / 4.0];
        let views: Vec<crate::dataset::View> = ring(false)
            .into_iter()
            .enumerate()
            .map(|(k, camera)| crate::dataset::View {
                image: colour(k).repeat(64 * 48),
                camera,
                weights: None,
                path: Default::default(),
            })
            .collect();
        let cloud = PointCloud { positions: vec![[0.0, -0.5, 2.0]], colors: vec![[0.0; 3]] };
        let sky = sky_points(&views, &cloud, 2.0, [0.0; 3]);
        // Radius: max(10 × the farthest point (2.06), f · B (50 × 8)) = 400.
        assert!(sky.len() > 100, "{} points", sky.len());
        for (p, c) in sky.positions.iter().zip(&sky.colors) {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            assert!((r - 400.0).abs() < 1e-2, "radius {r}");
            assert!(p[1] >= 0.0, "below the horizon: {p:?}");
            let seen: Vec<usize> = (0..4).filter(|&k| sees(&views[k].camera, *p)).collect();
            assert!(!seen.is_empty(), "{p:?} is seen by no view");
            for ch in 0..3 {
                let want = seen.iter().map(|&k| colour(k)[ch]).sum::<f32>() / seen.len() as f32;
                assert!((c[ch] - want).abs() < 1e-6, "{p:?}: {c:?}, views {seen:?}");
            }
        }
        // Spacing: 2 px at f = 50, i.e. 0.04 rad, 16 units at the radius.
        let d2 = knn_mean_sq_dist(&sky.positions, 3, 0.0);
        let mut d: Vec<f32> = d2.iter().map(|v| v.sqrt()).collect();
        d.sort_by(f32::total_cmp);
        let median = d[d.len() / 2];
        assert!((12.0..20.0).contains(&median), "median neighbour distance {median}");
        // A cloud that reaches the sky on one side (a shell 30 units out, about 2
        // apart, where x > 0) keeps the dome off that side and leaves the other whole.
        let mut shell = cloud.clone();
        for d in fibonacci_sphere(2800).into_iter().filter(|d| d[0] > 0.0) {
            shell.positions.push(d.map(|v| 30.0 * v));
            shell.colors.push([0.5; 3]);
        }
        let half = sky_points(&views, &shell, 2.0, [0.0; 3]);
        let far_side = |pc: &PointCloud| pc.positions.iter().filter(|p| p[0] < -0.1 * 400.0).count();
        assert!(half.positions.iter().all(|p| p[0] < 0.1 * 400.0), "a dome point behind the shell");
        assert!(
            far_side(&sky) > 20 && far_side(&half) == far_side(&sky),
            "{} / {}",
            far_side(&half),
            far_side(&sky)
        );
        // Walls all round the ring, rising above every view's frame (a room without a
        // ceiling, 0.25 apart): the sky above the horizon is behind them from every view,
        // and there is no dome; with one wall gone, the dome is back on that side only.
        let mut room = cloud.clone();
        let steps = |a: f32, b: f32| (0..=((b - a) / 0.25) as usize).map(move |i| a + 0.25 * i as f32);
        for along in steps(-6.0, 6.0) {
            for y in steps(-1.0, 8.0) {
                for wall in [[along, y, -6.0], [along, y, 6.0], [-6.0, y, along], [6.0, y, along]] {
                    room.positions.push(wall);
                    room.colors.push([0.5; 3]);
                }
            }
        }
        let behind = sky_points(&views, &room, 2.0, [0.0; 3]);
        assert!(behind.is_empty(), "a dome behind the walls");
        let open_side = PointCloud {
            positions: room.positions.iter().copied().filter(|p| p[0] > -5.9).collect(),
            colors: vec![[0.5; 3]; room.positions.iter().filter(|p| p[0] > -5.9).count()],
        };
        let three_walls = sky_points(&views, &open_side, 2.0, [0.0; 3]);
        assert!(
            !three_walls.is_empty() && three_walls.positions.iter().all(|p| p[0] < -0.3 * 400.0),
            "{} dome points, some not beyond the missing wall",
            three_walls.len()
        );
        // Cameras with no common up: no horizon, no dome.
        let flipped: Vec<crate::dataset::View> = ring(true)
            .into_iter()
            .map(|camera| crate::dataset::View {
                image: vec![0.5; 64 * 48 * 3],
                camera,
                weights: None,
                path: Default::default(),
            })
            .collect();
        assert!(sky_points(&flipped, &cloud, 2.0, [0.0; 3]).is_empty());
        // Where every view shows the background, the background draws the sky.
        assert!(sky_points(&flipped[..1], &cloud, 2.0, [0.5; 3]).is_empty());
        let one_view = sky_points(&views[..1], &cloud, 2.0, colour(0));
        assert!(one_view.is_empty(), "{} points where the only view shows the background", one_view.len());
        let two_views = sky_points(&views[..2], &cloud, 2.0, colour(0));
        assert!(!two_views.is_empty() && two_views.positions.iter().all(|&p| sees(&views[1].camera, p)));
    }

    #[test]
    fn a_dome_direction_needs_half_the_views_that_frame_it_open() {
        // Three cameras side by side, 1 apart, looking the same way and a little up,
        // so every one frames the sky straight ahead (elevation 3°–24°, azimuth ±15°).
        let views: Vec<crate::dataset::View> = [-1.0f32, 0.0, 1.0]
            .into_iter()
            .map(|x| crate::dataset::View {
                image: vec![0.6; 64 * 48 * 3],
                camera: looking([x, 0.0, 0.0], [x, 10.0, 2.0]),
                weights: None,
                path: Default::default(),
            })
            .collect();
        // A dense screen 1 ahead of the cameras from x = -1.3 to `right`: it hides the
        // sky ahead from the cameras it stands in front of, not from the others.
        let screen = |right: f32| {
            let mut cloud = PointCloud::default();
            let (nx, nz) = (((right + 1.3) / 0.02) as usize, 20);
            for i in 0..=nx {
                for k in 0..=nz {
                    cloud.positions.push([-1.3 + 0.02 * i as f32, 1.0, 0.05 + 0.02 * k as f32]);
                    cloud.colors.push([0.5; 3]);
                }
            }
            cloud
        };
        let ahead = |pc: &PointCloud| {
            pc.positions
                .iter()
                .filter(|p| {
                    let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                    let (azimuth, elevation) =
                        (p[0].atan2(p[1]).to_degrees(), (p[2] / r).asin().to_degrees());
                    azimuth.abs() < 8.0 && (8.0..18.0).contains(&elevation)
                })
                .count()
        };
        // In front of one camera: two of three see the sky ahead, which keeps its dome.
        let one = sky_points(&views, &screen(-0.7), 2.0, [0.0; 3]);
        assert!(ahead(&one) > 10, "{} dome points ahead", ahead(&one));
        // In front of two: one of three does, and a lone view's gap is no sky.
        let two = sky_points(&views, &screen(0.3), 2.0, [0.0; 3]);
        assert_eq!(ahead(&two), 0, "a dome point ahead, seen open by one view of three");
    }

    /// A camera at `eye` looking at `target`, world up +z, image-right level.
    fn looking(eye: [f32; 3], target: [f32; 3]) -> Camera {
        let unit = |v: [f32; 3]| {
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|x| x / l)
        };
        let cross = |a: [f32; 3], b: [f32; 3]| {
            [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
        };
        let z = unit(std::array::from_fn(|k| target[k] - eye[k]));
        let x = unit(cross(z, [0.0, 0.0, 1.0]));
        let y = cross(z, x);
        let r = [[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]];
        Camera::from_c2w("c".into(), 64, 48, 50.0, 50.0, 32.0, 24.0, r, eye)
    }

    #[test]
    fn the_up_is_level_with_cameras_on_an_arc_looking_down() {
        // An arc of 120° at radius 3 and height 2 about a subject at the origin: every
        // camera pitches down 34°, and the mean image-up tilts towards the arc's middle
        // viewing direction (−x); the right axes give the true up.
        let cams: Vec<Camera> = (0..7)
            .map(|k| {
                let a = (-60.0 + 20.0 * k as f32).to_radians();
                looking([3.0 * a.cos(), 3.0 * a.sin(), 2.0], [0.0; 3])
            })
            .collect();
        let refs: Vec<&Camera> = cams.iter().collect();
        let mean_up: [f32; 3] = std::array::from_fn(|k| -cams.iter().map(|c| c.rotation[1][k]).sum::<f32>());
        let tilt = (mean_up[2] / (mean_up.iter().map(|v| v * v).sum::<f32>()).sqrt()).acos().to_degrees();
        assert!(tilt > 20.0, "the mean image-up tilts {tilt}°");
        let up = cameras_up(&refs).unwrap();
        assert!((up[2] - 1.0).abs() < 1e-5 && up[0].abs() < 1e-3 && up[1].abs() < 1e-3, "{up:?}");
        // All facing the same way (a forward-facing grid of eyes): the right axes are one
        // direction, and the up is the mean image-up, tilted as it is.
        let grid: Vec<Camera> = (0..6)
            .map(|k| {
                let eye = [3.0, (k % 3) as f32 - 1.0, 1.5 + (k / 3) as f32 * 0.5];
                looking(eye, [eye[0] - 3.0, eye[1], eye[2] - 2.0])
            })
            .collect();
        let up = cameras_up(&grid.iter().collect::<Vec<_>>()).unwrap();
        let y = -grid[0].rotation[1][2];
        assert!((up[2] - y).abs() < 1e-5 && (up[0] + grid[0].rotation[1][0]).abs() < 1e-5, "{up:?}");
        // Upside-down cameras flip the sign of the right axes without changing the
        // scatter; the sign follows the image-up.
        let flipped: Vec<Camera> = cams
            .iter()
            .map(|c| {
                let mut c = c.clone();
                for k in 0..3 {
                    c.rotation[0][k] = -c.rotation[0][k];
                    c.rotation[1][k] = -c.rotation[1][k];
                }
                c
            })
            .collect();
        let up = cameras_up(&flipped.iter().collect::<Vec<_>>()).unwrap();
        assert!((up[2] + 1.0).abs() < 1e-5, "{up:?}");
    }

    #[test]
    fn random_points_are_seen_by_the_cameras() {
        // Four cameras on a ring around the origin, looking at it.
        let cams: Vec<Camera> = (0..4)
            .map(|k| {
                let a = k as f32 * std::f32::consts::FRAC_PI_2;
                let c = [4.0 * a.cos(), 0.0, 4.0 * a.sin()];
                let z = [-a.cos(), 0.0, -a.sin()];
                let y = [0.0, -1.0, 0.0];
                let x = [y[1] * z[2] - y[2] * z[1], y[2] * z[0] - y[0] * z[2], y[0] * z[1] - y[1] * z[0]];
                let r = [[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]];
                Camera::from_c2w(format!("{k}"), 64, 48, 50.0, 50.0, 32.0, 24.0, r, c)
            })
            .collect();
        let c = look_at_centre(&cams);
        assert!(c.iter().all(|v| v.abs() < 1e-3), "{c:?}");
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let cloud = random_points(&cams, 500, &mut rng);
        assert_eq!(cloud.len(), 500);
        for p in &cloud.positions {
            assert!(cams.iter().filter(|c| sees(c, *p)).count() >= 2);
        }
        let again = random_points(&cams, 500, &mut ChaCha8Rng::seed_from_u64(1));
        assert_eq!(cloud, again);
    }
}
