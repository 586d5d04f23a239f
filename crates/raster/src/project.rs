//! Per-Gaussian projection (EWA splatting) in the classic 3DGS / gsplat 1.5
//! semantics, and its exact backward pass.
//!
//! Σ = R S Sᵀ Rᵀ from the normalised quaternion and exp(log-scale); camera-space
//! mean t = R_w x + t_w; 2D mean (fx t_x/t_z + c_x, fy t_y/t_z + c_y); Jacobian with
//! the 1.3× tan-fov clamp; Σ₂ = J R_w Σ R_wᵀ Jᵀ + 0.3 I; conic = Σ₂⁻¹; per-axis
//! radius ⌈3.33 √diag Σ₂⌉; colour = SH(x − camera centre) + 0.5, clamped at 0.
//!
//! The projection's geometry, colour and opacity and the backward are generic over
//! [`Real`]: one Gaussian in `f32`, or eight in the lanes of [`crate::lanes::F8`] with
//! the same bits per lane (the per-Gaussian passes use both).

use crate::lanes::Real;
use crate::sh;
use transsplat_scene::Camera;

/// Near and far clipping planes on camera-space depth.
pub const NEAR: f32 = 0.01;
pub const FAR: f32 = 1e10;
/// Added to the 2D covariance diagonal (low-pass filter).
pub const EPS2D: f32 = 0.3;
/// Bounding-box extent in standard deviations.
pub const EXTENT: f32 = 3.33;

type M3<T = f32> = [[T; 3]; 3];

/// Camera quantities shared by every Gaussian of a view.
#[derive(Clone, Debug)]
pub struct View {
    pub width: u32,
    pub height: u32,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub rot: M3,
    pub trans: [f32; 3],
    pub centre: [f32; 3],
    lim_x_pos: f32,
    lim_x_neg: f32,
    lim_y_pos: f32,
    lim_y_neg: f32,
}

impl View {
    /// Precomputes the per-view constants.
    pub fn new(cam: &Camera) -> Self {
        let (w, h) = (cam.width as f32, cam.height as f32);
        let tan_fovx = 0.5 * w / cam.fx;
        let tan_fovy = 0.5 * h / cam.fy;
        View {
            width: cam.width,
            height: cam.height,
            fx: cam.fx,
            fy: cam.fy,
            cx: cam.cx,
            cy: cam.cy,
            rot: cam.rotation,
            trans: cam.translation,
            centre: cam.centre(),
            lim_x_pos: (w - cam.cx) / cam.fx + 0.3 * tan_fovx,
            lim_x_neg: cam.cx / cam.fx + 0.3 * tan_fovx,
            lim_y_pos: (h - cam.cy) / cam.fy + 0.3 * tan_fovy,
            lim_y_neg: cam.cy / cam.fy + 0.3 * tan_fovy,
        }
    }

    /// World point to camera coordinates.
    #[inline(always)]
    pub fn to_camera<T: Real>(&self, p: [T; 3]) -> [T; 3] {
        let r = lanes_m3::<T>(&self.rot);
        std::array::from_fn(|i| r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2] + T::from(self.trans[i]))
    }
}

/// A projected Gaussian: everything the per-pixel compositing needs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Splat2d {
    /// 2D mean in pixels.
    pub xy: [f32; 2],
    /// Inverse 2D covariance (a, b, c): σ = ½(a dx² + c dy²) + b dx dy.
    pub conic: [f32; 3],
    /// Activated opacity.
    pub opacity: f32,
    /// Colour after SH evaluation, +0.5 and the clamp at 0.
    pub color: [f32; 3],
    /// Camera-space depth of the mean.
    pub depth: f32,
}

/// Parameters of one Gaussian as stored (unactivated); of eight in the lanes of
/// [`crate::lanes::F8`].
#[derive(Clone, Copy, Debug)]
pub struct GaussianParams<'a, T = f32> {
    pub mean: [T; 3],
    pub log_scale: [T; 3],
    pub quat: [T; 4],
    pub opacity_logit: T,
    /// `[coefficient][channel]`, at least `(active_degree+1)²` coefficients.
    pub sh: &'a [T],
    pub active_degree: u32,
}

/// Gradients of one Gaussian's parameters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GaussianGrads<T = f32> {
    pub mean: [T; 3],
    pub log_scale: [T; 3],
    pub quat: [T; 4],
    pub opacity_logit: T,
}

/// Gradients arriving at a projected Gaussian from compositing.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Splat2dGrads<T = f32> {
    pub xy: [T; 2],
    pub conic: [T; 3],
    pub opacity: T,
    pub color: [T; 3],
    pub depth: T,
}

/// Rotation matrix of a (w, x, y, z) quaternion after normalisation (the identity
/// for a zero or non-finite quaternion).
pub fn rotation_matrix(q: [f32; 4]) -> M3 {
    let n = q.iter().map(|v| v * v).sum::<f32>();
    if n > 0.0 && n.is_finite() {
        quat_to_rotmat(q).2
    } else {
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    }
}

/// The (w, x, y, z) unit quaternion of a proper rotation matrix (row-major), the inverse
/// of [`rotation_matrix`] up to the quaternion's sign (Shepperd's method: the largest of
/// the four squared components picks the stable formula).
pub fn quat_from_matrix(r: M3) -> [f32; 4] {
    let tr = r[0][0] + r[1][1] + r[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [0.25 * s, (r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s]
    } else if r[0][0] > r[1][1] && r[0][0] > r[2][2] {
        let s = (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt() * 2.0;
        [(r[2][1] - r[1][2]) / s, 0.25 * s, (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s]
    } else if r[1][1] > r[2][2] {
        let s = (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt() * 2.0;
        [(r[0][2] - r[2][0]) / s, (r[0][1] + r[1][0]) / s, 0.25 * s, (r[1][2] + r[2][1]) / s]
    } else {
        let s = (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt() * 2.0;
        [(r[1][0] - r[0][1]) / s, (r[0][2] + r[2][0]) / s, (r[1][2] + r[2][1]) / s, 0.25 * s]
    };
    let n = (q.iter().map(|v| v * v).sum::<f32>()).sqrt();
    q.map(|v| v / n)
}

#[inline(always)]
fn quat_to_rotmat<T: Real>(q: [T; 4]) -> ([T; 4], T, M3<T>) {
    let (one, two) = (T::from(1.0), T::from(2.0));
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let [w, x, y, z] = [q[0] / n, q[1] / n, q[2] / n, q[3] / n];
    let r = [
        [one - two * (y * y + z * z), two * (x * y - w * z), two * (x * z + w * y)],
        [two * (x * y + w * z), one - two * (x * x + z * z), two * (y * z - w * x)],
        [two * (x * z - w * y), two * (y * z + w * x), one - two * (x * x + y * y)],
    ];
    ([w, x, y, z], n, r)
}

#[inline(always)]
fn matmul<T: Real>(a: &M3<T>, b: &M3<T>) -> M3<T> {
    std::array::from_fn(|i| {
        std::array::from_fn(|j| a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j])
    })
}

#[inline(always)]
fn transpose<T: Real>(a: &M3<T>) -> M3<T> {
    std::array::from_fn(|i| std::array::from_fn(|j| a[j][i]))
}

/// A view matrix in every lane.
#[inline(always)]
fn lanes_m3<T: Real>(a: &M3) -> M3<T> {
    a.map(|r| r.map(T::from))
}

/// `a + b + c`: what `[a, b, c].into_iter().sum()` computes (its fold starts at −0.0,
/// which leaves the first term as it is).
#[inline(always)]
fn sum3<T: Real>(a: T, b: T, c: T) -> T {
    a + b + c
}

/// Intermediate quantities of the projection, recomputed by the backward pass.
struct Fwd<T: Real> {
    qn: [T; 4],
    qnorm: T,
    rot: M3<T>,
    scale: [T; 3],
    m: M3<T>,
    cov_cam: M3<T>,
    t: [T; 3],
    tx_c: T,
    ty_c: T,
    clamped_x: T::Mask,
    clamped_y: T::Mask,
    j: [[T; 3]; 2],
    cov2d: [T; 3],
    det: T,
}

#[inline(always)]
fn forward_internals<T: Real>(view: &View, p: &GaussianParams<T>) -> Fwd<T> {
    let (qn, qnorm, rot) = quat_to_rotmat(p.quat);
    let scale = p.log_scale.map(T::exp);
    // M = R S
    let m: M3<T> = std::array::from_fn(|i| std::array::from_fn(|j| rot[i][j] * scale[j]));
    let cov = matmul(&m, &transpose(&m));
    let vrot = lanes_m3::<T>(&view.rot);
    let wc = matmul(&vrot, &cov);
    let cov_cam = matmul(&wc, &transpose(&vrot));
    let t = view.to_camera(p.mean);
    let tz = t[2];
    let rx = t[0] / tz;
    let ry = t[1] / tz;
    let cx_ = rx.clamp(T::from(-view.lim_x_neg), T::from(view.lim_x_pos));
    let cy_ = ry.clamp(T::from(-view.lim_y_neg), T::from(view.lim_y_pos));
    let clamped_x = cx_.ne(rx);
    let clamped_y = cy_.ne(ry);
    let tx_c = tz * cx_;
    let ty_c = tz * cy_;
    let (fx, fy, zero) = (T::from(view.fx), T::from(view.fy), T::from(0.0));
    let j = [
        [fx / tz, zero, T::from(-view.fx) * tx_c / (tz * tz)],
        [zero, fy / tz, T::from(-view.fy) * ty_c / (tz * tz)],
    ];
    // cov2d = J cov_cam Jᵀ (symmetric 2x2: a, b, c)
    let jc: [[T; 3]; 2] = std::array::from_fn(|i| {
        std::array::from_fn(|k| {
            sum3(j[i][0] * cov_cam[0][k], j[i][1] * cov_cam[1][k], j[i][2] * cov_cam[2][k])
        })
    });
    let eps = T::from(EPS2D);
    let c00 = sum3(jc[0][0] * j[0][0], jc[0][1] * j[0][1], jc[0][2] * j[0][2]) + eps;
    let c01 = sum3(jc[0][0] * j[1][0], jc[0][1] * j[1][1], jc[0][2] * j[1][2]);
    let c11 = sum3(jc[1][0] * j[1][0], jc[1][1] * j[1][1], jc[1][2] * j[1][2]) + eps;
    let det = c00 * c11 - c01 * c01;
    Fwd {
        qn,
        qnorm,
        rot,
        scale,
        m,
        cov_cam,
        t,
        tx_c,
        ty_c,
        clamped_x,
        clamped_y,
        j,
        cov2d: [c00, c01, c11],
        det,
    }
}

#[inline(always)]
fn view_dir<T: Real>(view: &View, mean: [T; 3]) -> ([T; 3], T) {
    let c = view.centre.map(T::from);
    let d = [mean[0] - c[0], mean[1] - c[1], mean[2] - c[2]];
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(T::from(1e-12));
    ([d[0] / n, d[1] / n, d[2] / n], n)
}

#[inline(always)]
/// SH colour before the clamp (`Σ_k sh_k Y_k(d) + 0.5`).
fn sh_color<T: Real>(view: &View, p: &GaussianParams<T>) -> [T; 3] {
    let (d, _) = view_dir(view, p.mean);
    sh_color_from(&sh::basis(p.active_degree, d), p)
}

/// [`sh_color`] from the SH basis `b` of the view direction.
#[inline(always)]
fn sh_color_from<T: Real>(b: &[T; 16], p: &GaussianParams<T>) -> [T; 3] {
    let k = crate::sh_coeffs(p.active_degree);
    let mut c = [T::from(0.5); 3];
    for (kk, bk) in b.iter().enumerate().take(k) {
        for (ch, cc) in c.iter_mut().enumerate() {
            *cc += *bk * p.sh[kk * 3 + ch];
        }
    }
    c
}

/// The colour a Gaussian is rendered with from `view`: c = max(Σ_k sh_k Y_k(d) + 0.5, 0)
/// over the active SH degree, d the unit direction from the camera centre.
#[inline(always)]
pub fn view_colour<T: Real>(view: &View, p: &GaussianParams<T>) -> [T; 3] {
    sh_color(view, p).map(|c| c.max(T::from(0.0)))
}

/// How the colour clamp `c = max(raw, 0)` passes gradients to the SH coefficients.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ClampGrad {
    /// The clamp's own derivative: nothing where the SH colour is below 0 (INRIA's and
    /// gsplat's backward; the gradient of the function actually rendered).
    #[default]
    Exact,
    /// A one-sided straight-through estimate (docs/method.md#m11-colour-clamp): where a
    /// channel is below 0, a gradient asking it to *rise* still reaches the SH
    /// coefficients; one asking it to fall does not (it is already black). With the
    /// exact derivative a channel that overshoots below 0 in every view that sees it
    /// never receives a gradient again, a dead channel: a dark red trained that way
    /// cannot turn cyan in an edit, nor recover in training. The forward is unchanged,
    /// and the mean's gradient (through the view direction) stays exact.
    Revive,
}

impl ClampGrad {
    pub const ALL: [ClampGrad; 2] = [ClampGrad::Exact, ClampGrad::Revive];

    /// The rule's name (`exact`, `revive`), as in configuration files.
    pub fn name(self) -> &'static str {
        match self {
            ClampGrad::Exact => "exact",
            ClampGrad::Revive => "revive",
        }
    }

    /// The rule named `s`, if any.
    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|r| r.name() == s)
    }
}

/// Backward of [`view_colour`] to the SH coefficients (mean held fixed): writes
/// ∂L/∂sh_{k,c} = Y_k(d) ∂L/∂c_c into `v_sh` (`[coefficient][channel]`, the active
/// coefficients), where below the clamp ∂L/∂c_c is 0 or, under [`ClampGrad::Revive`],
/// kept when negative (the loss asks the channel to rise). Returns the exact ∂L/∂c
/// (0 where the SH colour is below 0), which the mean's gradient uses.
#[inline(always)]
pub fn colour_backward(
    view: &View,
    p: &GaussianParams,
    v_colour: [f32; 3],
    v_sh: &mut [f32],
    clamp: ClampGrad,
) -> [f32; 3] {
    let (d, _) = view_dir(view, p.mean);
    colour_backward_from(&sh::basis(p.active_degree, d), p, v_colour, v_sh, clamp)
}

/// [`colour_backward`] from the SH basis `b` of the view direction (the caller has it).
#[inline(always)]
fn colour_backward_from<T: Real>(
    b: &[T; 16],
    p: &GaussianParams<T>,
    v_colour: [T; 3],
    v_sh: &mut [T],
    clamp: ClampGrad,
) -> [T; 3] {
    let raw = sh_color_from(b, p);
    let zero = T::from(0.0);
    let vcol: [T; 3] = std::array::from_fn(|c| T::select(raw[c].lt(zero), zero, v_colour[c]));
    let vsh: [T; 3] = match clamp {
        ClampGrad::Exact => vcol,
        ClampGrad::Revive => std::array::from_fn(|c| T::select(v_colour[c].lt(zero), v_colour[c], vcol[c])),
    };
    for kk in 0..crate::sh_coeffs(p.active_degree) {
        for c in 0..3 {
            v_sh[kk * 3 + c] = b[kk] * vsh[c];
        }
    }
    vcol
}

/// Projects one Gaussian. Returns `None` when it is culled (behind the near plane,
/// degenerate covariance, or a bounding box that misses the image), else the splat
/// and its per-axis pixel radius.
#[inline(always)]
pub fn project(view: &View, p: &GaussianParams) -> Option<(Splat2d, [u32; 2])> {
    let g = geometry(view, p);
    let (xy, depth, radius) = cull(view, &g)?;
    let color = view_colour(view, p);
    let opacity = sigmoid(p.opacity_logit);
    Some((Splat2d { xy, conic: g.conic, opacity, color, depth }, radius))
}

/// The geometric part of [`project`], before its culls: camera-space depth, the 2D
/// covariance's determinant, the conic, the per-axis radius and the 2D mean. Generic
/// over [`Real`], so eight Gaussians can be projected at once with the same bits per
/// lane ([`Geometry::lane`]).
pub(crate) struct Geometry<T> {
    pub tz: T,
    pub det: T,
    pub conic: [T; 3],
    pub radius: [T; 2],
    pub xy: [T; 2],
}

impl Geometry<crate::lanes::F8> {
    /// Lane `l`'s geometry.
    #[inline(always)]
    pub(crate) fn lane(&self, l: usize) -> Geometry<f32> {
        Geometry {
            tz: self.tz.0[l],
            det: self.det.0[l],
            conic: self.conic.map(|v| v.0[l]),
            radius: self.radius.map(|v| v.0[l]),
            xy: self.xy.map(|v| v.0[l]),
        }
    }
}

/// [`Geometry`] of `p` (its SH coefficients are not read): Σ₂ = (J W R S)(J W R S)ᵀ,
/// the same quantity as in `forward_internals`, with fewer operations (the backward
/// pass recomputes the factored form).
#[inline(always)]
pub(crate) fn geometry<T: Real>(view: &View, p: &GaussianParams<T>) -> Geometry<T> {
    let c = T::from;
    let t = view.to_camera(p.mean);
    let tz = t[2];
    let (_, _, rot) = quat_to_rotmat(p.quat);
    let scale = p.log_scale.map(T::exp);
    let wr = matmul(&lanes_m3::<T>(&view.rot), &rot);
    let rx_ = (t[0] / tz).clamp(c(-view.lim_x_neg), c(view.lim_x_pos));
    let ry_ = (t[1] / tz).clamp(c(-view.lim_y_neg), c(view.lim_y_pos));
    let (j00, j02) = (c(view.fx) / tz, c(-view.fx) * rx_ / tz);
    let (j11, j12) = (c(view.fy) / tz, c(-view.fy) * ry_ / tz);
    let mut r0 = [c(0.0); 3];
    let mut r1 = [c(0.0); 3];
    for k in 0..3 {
        r0[k] = (j00 * wr[0][k] + j02 * wr[2][k]) * scale[k];
        r1[k] = (j11 * wr[1][k] + j12 * wr[2][k]) * scale[k];
    }
    let eps = c(EPS2D);
    let c00 = r0[0] * r0[0] + r0[1] * r0[1] + r0[2] * r0[2] + eps;
    let c01 = r0[0] * r1[0] + r0[1] * r1[1] + r0[2] * r1[2];
    let c11 = r1[0] * r1[0] + r1[1] * r1[1] + r1[2] * r1[2] + eps;
    let det = c00 * c11 - c01 * c01;
    let inv = c(1.0) / det;
    Geometry {
        tz,
        det,
        conic: [c11 * inv, -c01 * inv, c00 * inv],
        radius: [(c(EXTENT) * c00.sqrt()).ceil(), (c(EXTENT) * c11.sqrt()).ceil()],
        xy: [c(view.fx) * t[0] / tz + c(view.cx), c(view.fy) * t[1] / tz + c(view.cy)],
    }
}

/// The culls of [`project`] on its [`geometry`] `g`: the 2D mean, depth and radius of
/// a Gaussian that passes them.
#[inline(always)]
pub(crate) fn cull(view: &View, g: &Geometry<f32>) -> Option<([f32; 2], f32, [u32; 2])> {
    let tz = g.tz;
    if !(tz > NEAR && tz < FAR && g.det > 0.0) {
        return None;
    }
    let [rx, ry] = g.radius;
    if rx <= 0.0 && ry <= 0.0 {
        return None;
    }
    let xy = g.xy;
    if !(xy[0] + rx > 0.0
        && xy[0] - rx < view.width as f32
        && xy[1] + ry > 0.0
        && xy[1] - ry < view.height as f32)
    {
        return None;
    }
    Some((xy, tz, [rx as u32, ry as u32]))
}

/// The activated opacity, 1 / (1 + exp(−x)) as `transsplat_scene::sigmoid`, lane-wise.
#[inline(always)]
pub(crate) fn sigmoid<T: Real>(x: T) -> T {
    T::from(1.0) / (T::from(1.0) + (-x).exp())
}

/// Backward of [`project`] for a visible Gaussian: from the gradients on its
/// splat to the gradients on its parameters. SH coefficient gradients are written
/// into `v_sh` (`[coefficient][channel]`, the active coefficients only), through the
/// colour clamp as `clamp` says. Generic over [`Real`]: one Gaussian (`f32`) or eight
/// in lanes, with the same bits per Gaussian.
#[inline(always)]
pub fn project_backward<T: Real>(
    view: &View,
    p: &GaussianParams<T>,
    g: &Splat2dGrads<T>,
    v_sh: &mut [T],
    clamp: ClampGrad,
) -> GaussianGrads<T> {
    let c = T::from;
    let f = forward_internals(view, p);
    let [c00, c01, c11] = f.cov2d;
    let inv = c(1.0) / f.det;
    let q = [[c11 * inv, -c01 * inv], [-c01 * inv, c00 * inv]];
    // σ = ½ dᵀ Q d with Q = [[a, b], [b, c]]: dL/dQ = [[va, vb/2], [vb/2, vc]].
    let vq = [[g.conic[0], c(0.5) * g.conic[1]], [c(0.5) * g.conic[1], g.conic[2]]];
    // Q = C⁻¹ ⇒ dL/dC = −Q (dL/dQ) Q.
    let qv: [[T; 2]; 2] =
        std::array::from_fn(|i| std::array::from_fn(|k| q[i][0] * vq[0][k] + q[i][1] * vq[1][k]));
    let vc: [[T; 2]; 2] =
        std::array::from_fn(|i| std::array::from_fn(|k| -(qv[i][0] * q[0][k] + qv[i][1] * q[1][k])));

    // C = J Σc Jᵀ: dΣc = Jᵀ dC J; dJ = dC J Σc + dCᵀ J Σcᵀ = 2 dC J Σc (dC, Σc symmetric).
    let j = &f.j;
    let v_cov_cam: M3<T> = std::array::from_fn(|a| {
        std::array::from_fn(|b| {
            let term = |i: usize| j[i][a] * vc[i][0] * j[0][b] + j[i][a] * vc[i][1] * j[1][b];
            term(0) + term(1)
        })
    });
    let jsc: [[T; 3]; 2] = std::array::from_fn(|i| {
        std::array::from_fn(|k| {
            sum3(j[i][0] * f.cov_cam[0][k], j[i][1] * f.cov_cam[1][k], j[i][2] * f.cov_cam[2][k])
        })
    });
    let vj: [[T; 3]; 2] = std::array::from_fn(|i| {
        std::array::from_fn(|k| (vc[i][0] * jsc[0][k] + vc[i][1] * jsc[1][k]) * c(2.0))
    });

    // Camera-space mean gradient: from the 2D mean, the depth and the Jacobian.
    let [tx, ty, tz] = f.t;
    let (fx, fy) = (c(view.fx), c(view.fy));
    let (nfx, nfy) = (c(-view.fx), c(-view.fy));
    let mut vt = [c(0.0); 3];
    vt[0] += fx / tz * g.xy[0];
    vt[1] += fy / tz * g.xy[1];
    vt[2] += nfx * tx / (tz * tz) * g.xy[0] - fy * ty / (tz * tz) * g.xy[1];
    vt[2] += g.depth;
    let tz2 = tz * tz;
    let tz3 = tz2 * tz;
    // J00 = fx/tz, J11 = fy/tz, J02 = -fx tx'/tz², J12 = -fy ty'/tz² with
    // tx' = tz·clamp(tx/tz): unclamped ∂tx'/∂tx = 1; clamped ∂tx'/∂tz = tx'/tz.
    vt[2] += nfx / tz2 * vj[0][0] - fy / tz2 * vj[1][1];
    vt[2] += c(2.0) * fx * f.tx_c / tz3 * vj[0][2] + c(2.0) * fy * f.ty_c / tz3 * vj[1][2];
    let v_txc = nfx / tz2 * vj[0][2];
    let v_tyc = nfy / tz2 * vj[1][2];
    vt[2] = T::select(f.clamped_x, vt[2] + v_txc * f.tx_c / tz, vt[2]);
    vt[0] = T::select(f.clamped_x, vt[0], vt[0] + v_txc);
    vt[2] = T::select(f.clamped_y, vt[2] + v_tyc * f.ty_c / tz, vt[2]);
    vt[1] = T::select(f.clamped_y, vt[1], vt[1] + v_tyc);
    // t = R_w x + t_w
    let w = lanes_m3::<T>(&view.rot);
    let mut v_mean: [T; 3] = std::array::from_fn(|k| w[0][k] * vt[0] + w[1][k] * vt[1] + w[2][k] * vt[2]);

    // Σc = W Σ Wᵀ ⇒ dΣ = Wᵀ dΣc W.
    let wt = transpose(&w);
    let v_cov = matmul(&matmul(&wt, &v_cov_cam), &w);
    // Σ = M Mᵀ ⇒ dM = (dΣ + dΣᵀ) M.
    let v_m: M3<T> = std::array::from_fn(|i| {
        std::array::from_fn(|k| {
            let term = |l: usize| (v_cov[i][l] + v_cov[l][i]) * f.m[l][k];
            sum3(term(0), term(1), term(2))
        })
    });
    // M = R S.
    let v_log_scale: [T; 3] = std::array::from_fn(|k| {
        sum3(v_m[0][k] * f.rot[0][k], v_m[1][k] * f.rot[1][k], v_m[2][k] * f.rot[2][k]) * f.scale[k]
    });
    let gr: M3<T> = std::array::from_fn(|i| std::array::from_fn(|k| v_m[i][k] * f.scale[k]));
    let [qw, qx, qy, qz] = f.qn;
    let two = c(2.0);
    let vqn = [
        two * (-qz * gr[0][1] + qy * gr[0][2] + qz * gr[1][0] - qx * gr[1][2] - qy * gr[2][0]
            + qx * gr[2][1]),
        two * (qy * gr[0][1] + qz * gr[0][2] + qy * gr[1][0] - two * qx * gr[1][1] - qw * gr[1][2]
            + qz * gr[2][0]
            + qw * gr[2][1]
            - two * qx * gr[2][2]),
        two * (-two * qy * gr[0][0] + qx * gr[0][1] + qw * gr[0][2] + qx * gr[1][0] + qz * gr[1][2]
            - qw * gr[2][0]
            + qz * gr[2][1]
            - two * qy * gr[2][2]),
        two * (-two * qz * gr[0][0] - qw * gr[0][1] + qx * gr[0][2] + qw * gr[1][0] - two * qz * gr[1][1]
            + qy * gr[1][2]
            + qx * gr[2][0]
            + qy * gr[2][1]),
    ];
    // The four-term sum, as `Iterator::sum` folds it from −0.0.
    let dot = vqn[0] * f.qn[0] + vqn[1] * f.qn[1] + vqn[2] * f.qn[2] + vqn[3] * f.qn[3];
    let v_quat: [T; 4] = std::array::from_fn(|k| (vqn[k] - f.qn[k] * dot) / f.qnorm);

    // Colour: c = max(Σ_k sh_k Y_k(d) + 0.5, 0).
    let (d, dn) = view_dir(view, p.mean);
    let vcol = colour_backward_from(&sh::basis(p.active_degree, d), p, g.color, v_sh, clamp);
    let k = crate::sh_coeffs(p.active_degree);
    let mut gk = [c(0.0); 16];
    for kk in 0..k {
        for ch in 0..3 {
            gk[kk] += p.sh[kk * 3 + ch] * vcol[ch];
        }
    }
    let vd = sh::basis_vjp(p.active_degree, d, &gk);
    let dd = vd[0] * d[0] + vd[1] * d[1] + vd[2] * d[2];
    for a in 0..3 {
        v_mean[a] += (vd[a] - d[a] * dd) / dn;
    }

    let o = sigmoid(p.opacity_logit);
    GaussianGrads {
        mean: v_mean,
        log_scale: v_log_scale,
        quat: v_quat,
        opacity_logit: g.opacity * o * (c(1.0) - o),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use transsplat_scene::Camera;

    const C0: f32 = 0.282_094_8;

    /// `quat_from_matrix` inverts `rotation_matrix` (up to the quaternion's sign) in each
    /// of Shepperd's four branches: near the identity, near half turns about x, y and z,
    /// and at pseudo-random rotations.
    #[test]
    fn quat_from_matrix_inverts_rotation_matrix() {
        let mut quats = vec![
            [1.0f32, 0.01, -0.02, 0.03],
            [0.02, 1.0, 0.05, -0.01],
            [0.03, -0.02, 1.0, 0.04],
            [0.01, 0.03, -0.05, 1.0],
        ];
        // A fixed spread of rotations (a low-discrepancy sequence, no rng needed).
        quats.extend((1..60).map(|k| {
            let f = |a: f32| ((k as f32 * a).fract() - 0.5) * 2.0;
            [f(0.618_034), f(0.414_214), f(0.732_051), f(0.236_068)]
        }));
        for q in quats {
            let n = q.iter().map(|v| v * v).sum::<f32>().sqrt();
            let q = q.map(|v| v / n);
            let back = quat_from_matrix(rotation_matrix(q));
            let dot: f32 = back.iter().zip(&q).map(|(a, b)| a * b).sum();
            assert!(dot.abs() > 1.0 - 1e-5, "{q:?} came back as {back:?}");
        }
    }

    fn view() -> View {
        View::new(&Camera::pinhole("c", 8, 8, 8.0))
    }

    fn params(sh: &[f32], degree: u32) -> GaussianParams<'_> {
        GaussianParams {
            mean: [0.1, -0.2, 3.0],
            log_scale: [-2.0; 3],
            quat: [1.0, 0.0, 0.0, 0.0],
            opacity_logit: 0.0,
            sh,
            active_degree: degree,
        }
    }

    /// Degree 0, by hand: raw = 0.5 + C0 f = (−0.064, 0.782, −0.346). The clamp passes
    /// nothing to the clamped channels 0 and 2 under `Exact`; under `Revive` channel 0
    /// (its gradient −1 asks it to rise) gets C0 · (−1), channel 2 (0.5 asks it to
    /// fall) still nothing. The returned ∂L/∂c, which the mean uses, is exact in both.
    #[test]
    fn revive_passes_only_the_gradients_that_raise_a_clamped_channel() {
        let sh = [-2.0, 1.0, -3.0];
        let v = [-1.0, 2.0, 0.5];
        let mut exact = [0.0; 3];
        let mut revive = [0.0; 3];
        let a = colour_backward(&view(), &params(&sh, 0), v, &mut exact, ClampGrad::Exact);
        let b = colour_backward(&view(), &params(&sh, 0), v, &mut revive, ClampGrad::Revive);
        assert_eq!(a, [0.0, 2.0, 0.0]);
        assert_eq!(b, a);
        assert_eq!(exact, [0.0, 2.0 * C0, 0.0]);
        assert_eq!(revive, [-C0, 2.0 * C0, 0.0]);
    }

    /// Degree 2: under `Revive`, a clamped channel asked to rise gets the gradient every
    /// coefficient would get with the channel unclamped (the same Gaussian with the
    /// channel's DC raised above 0, through the exact rule), and every other channel
    /// what `Exact` gives.
    #[test]
    fn a_revived_channel_gets_the_unclamped_gradient_at_every_degree() {
        let k = crate::sh_coeffs(2);
        let mut sh: Vec<f32> = (0..k * 3).map(|j| 0.05 * ((j * 7 % 11) as f32 - 5.0)).collect();
        sh[0] = -4.0; // channel 0 clamped
        sh[1] = 1.5;
        sh[2] = -4.0; // channel 2 clamped
        let v = [-0.7, 0.3, 0.9];
        let raw = sh_color(&view(), &params(&sh, 2));
        assert!(raw[0] < 0.0 && raw[1] > 0.0 && raw[2] < 0.0, "{raw:?}");
        let mut revive = vec![0.0; k * 3];
        colour_backward(&view(), &params(&sh, 2), v, &mut revive, ClampGrad::Revive);
        let mut lifted = sh.clone();
        lifted[0] = 4.0;
        let mut unclamped = vec![0.0; k * 3];
        colour_backward(&view(), &params(&lifted, 2), v, &mut unclamped, ClampGrad::Exact);
        let mut exact = vec![0.0; k * 3];
        colour_backward(&view(), &params(&sh, 2), v, &mut exact, ClampGrad::Exact);
        for kk in 0..k {
            assert_eq!(revive[kk * 3], unclamped[kk * 3], "coefficient {kk}, revived channel");
            assert_ne!(revive[kk * 3], 0.0);
            assert_eq!(revive[kk * 3 + 1], exact[kk * 3 + 1], "coefficient {kk}, live channel");
            assert_eq!(revive[kk * 3 + 2], 0.0, "coefficient {kk}, channel asked to fall");
        }
    }

    #[test]
    fn eight_lanes_give_each_gaussian_the_bits_of_the_scalar_backward() {
        use crate::lanes::F8;
        // A camera whose frustum clamp some Gaussians pass (x or y far outside the
        // image), colours below 0 in some channels, every degree, both clamp rules.
        let mut cam = Camera::pinhole("c", 64, 48, 40.0);
        cam.rotation = rotation_matrix([0.9, 0.1, -0.2, 0.3]);
        cam.translation = [0.2, -0.1, 4.0];
        let view = View::new(&cam);
        let wave = |k: usize, a: f32| (k as f32 * a).sin();
        for degree in 0..=3u32 {
            for clamp in ClampGrad::ALL {
                let nsh = crate::sh_coeffs(degree) * 3;
                let (mut seen_clamped, mut seen_black) = (false, false);
                for base in (0..64).step_by(8) {
                    let ps: Vec<(GaussianParams, Vec<f32>, Splat2dGrads)> = (base..base + 8)
                        .map(|i| {
                            let sh: Vec<f32> = (0..48).map(|k| 2.5 * wave(i * 48 + k, 0.71)).collect();
                            let wide = if i % 5 == 0 { 9.0 } else { 1.0 };
                            let p = GaussianParams {
                                mean: [wide * wave(i, 0.37), wave(i, 0.91), 0.5 * wave(i, 1.3)],
                                log_scale: [wave(i, 0.2) - 2.0, wave(i, 0.5) - 1.5, wave(i, 0.8) - 2.5],
                                quat: [1.0 + wave(i, 0.3), wave(i, 0.6), wave(i, 1.1), wave(i, 1.7)],
                                opacity_logit: 2.0 * wave(i, 0.45),
                                sh: &[],
                                active_degree: degree,
                            };
                            let g = Splat2dGrads {
                                xy: [wave(i, 2.1), wave(i, 2.3)],
                                conic: [wave(i, 2.7), wave(i, 2.9), wave(i, 3.1)],
                                opacity: wave(i, 3.7),
                                color: [wave(i, 4.1), wave(i, 4.3), wave(i, 4.7)],
                                depth: wave(i, 5.3),
                            };
                            (p, sh, g)
                        })
                        .collect();
                    let one: Vec<(GaussianGrads, Vec<f32>)> = ps
                        .iter()
                        .map(|(p, sh, g)| {
                            let p = GaussianParams { sh, ..*p };
                            let f = forward_internals(&view, &p);
                            seen_clamped |= f.clamped_x || f.clamped_y;
                            seen_black |= sh_color(&view, &p).iter().any(|&c| c < 0.0);
                            let mut vsh = vec![0.0; nsh];
                            (project_backward(&view, &p, g, &mut vsh, clamp), vsh)
                        })
                        .collect();
                    let lanes = |f: &dyn Fn(usize) -> f32| F8(std::array::from_fn(f));
                    let sh: Vec<F8> = (0..nsh).map(|t| lanes(&|l| ps[l].1[t])).collect();
                    let p = GaussianParams {
                        mean: std::array::from_fn(|c| lanes(&|l| ps[l].0.mean[c])),
                        log_scale: std::array::from_fn(|c| lanes(&|l| ps[l].0.log_scale[c])),
                        quat: std::array::from_fn(|c| lanes(&|l| ps[l].0.quat[c])),
                        opacity_logit: lanes(&|l| ps[l].0.opacity_logit),
                        sh: &sh,
                        active_degree: degree,
                    };
                    let g = Splat2dGrads {
                        xy: std::array::from_fn(|c| lanes(&|l| ps[l].2.xy[c])),
                        conic: std::array::from_fn(|c| lanes(&|l| ps[l].2.conic[c])),
                        opacity: lanes(&|l| ps[l].2.opacity),
                        color: std::array::from_fn(|c| lanes(&|l| ps[l].2.color[c])),
                        depth: lanes(&|l| ps[l].2.depth),
                    };
                    let mut vsh = vec![F8::default(); nsh];
                    let eight = project_backward(&view, &p, &g, &mut vsh, clamp);
                    for (l, (gg, vs)) in one.iter().enumerate() {
                        let bits = |x: &[f32]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                        let lane = |x: &[F8]| x.iter().map(|v| v.0[l]).collect::<Vec<_>>();
                        let what = format!("degree {degree}, {clamp:?}, Gaussian {}", base + l);
                        assert_eq!(bits(&lane(&eight.mean)), bits(&gg.mean), "{what}");
                        assert_eq!(bits(&lane(&eight.log_scale)), bits(&gg.log_scale), "{what}");
                        assert_eq!(bits(&lane(&eight.quat)), bits(&gg.quat), "{what}");
                        assert_eq!(eight.opacity_logit.0[l].to_bits(), gg.opacity_logit.to_bits(), "{what}");
                        assert_eq!(bits(&lane(&vsh)), bits(vs), "{what}");
                    }
                }
                assert!(
                    seen_clamped && seen_black,
                    "the cases must include clamped means and black channels"
                );
            }
        }
    }

    #[test]
    fn rules_round_trip_their_names() {
        for r in ClampGrad::ALL {
            assert_eq!(ClampGrad::from_name(r.name()), Some(r));
        }
        assert_eq!(ClampGrad::from_name("leaky"), None);
    }
}
