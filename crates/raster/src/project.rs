//! Per-Gaussian projection (EWA splatting) in the classic 3DGS / gsplat 1.5
//! semantics, and its exact backward pass.
//!
//! Σ = R S Sᵀ Rᵀ from the normalised quaternion and exp(log-scale); camera-space
//! mean t = R_w x + t_w; 2D mean (fx t_x/t_z + c_x, fy t_y/t_z + c_y); Jacobian with
//! the 1.3× tan-fov clamp; Σ₂ = J R_w Σ R_wᵀ Jᵀ + 0.3 I; conic = Σ₂⁻¹; per-axis
//! radius ⌈3.33 √diag Σ₂⌉; colour = SH(x − camera centre) + 0.5, clamped at 0.

use crate::sh;
use transsplat_scene::Camera;

/// Near and far clipping planes on camera-space depth.
pub const NEAR: f32 = 0.01;
pub const FAR: f32 = 1e10;
/// Added to the 2D covariance diagonal (low-pass filter).
pub const EPS2D: f32 = 0.3;
/// Bounding-box extent in standard deviations.
pub const EXTENT: f32 = 3.33;

type M3 = [[f32; 3]; 3];

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
    pub fn to_camera(&self, p: [f32; 3]) -> [f32; 3] {
        let r = &self.rot;
        std::array::from_fn(|i| r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2] + self.trans[i])
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

/// Parameters of one Gaussian as stored (unactivated).
#[derive(Clone, Copy, Debug)]
pub struct GaussianParams<'a> {
    pub mean: [f32; 3],
    pub log_scale: [f32; 3],
    pub quat: [f32; 4],
    pub opacity_logit: f32,
    /// `[coefficient][channel]`, at least `(active_degree+1)²` coefficients.
    pub sh: &'a [f32],
    pub active_degree: u32,
}

/// Gradients of one Gaussian's parameters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GaussianGrads {
    pub mean: [f32; 3],
    pub log_scale: [f32; 3],
    pub quat: [f32; 4],
    pub opacity_logit: f32,
}

/// Gradients arriving at a projected Gaussian from compositing.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Splat2dGrads {
    pub xy: [f32; 2],
    pub conic: [f32; 3],
    pub opacity: f32,
    pub color: [f32; 3],
    pub depth: f32,
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

fn quat_to_rotmat(q: [f32; 4]) -> ([f32; 4], f32, M3) {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let [w, x, y, z] = [q[0] / n, q[1] / n, q[2] / n, q[3] / n];
    let r = [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ];
    ([w, x, y, z], n, r)
}

fn matmul(a: &M3, b: &M3) -> M3 {
    std::array::from_fn(|i| {
        std::array::from_fn(|j| a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j])
    })
}

fn transpose(a: &M3) -> M3 {
    std::array::from_fn(|i| std::array::from_fn(|j| a[j][i]))
}

/// Intermediate quantities of the projection, recomputed by the backward pass.
struct Fwd {
    qn: [f32; 4],
    qnorm: f32,
    rot: M3,
    scale: [f32; 3],
    m: M3,
    cov_cam: M3,
    t: [f32; 3],
    tx_c: f32,
    ty_c: f32,
    clamped_x: bool,
    clamped_y: bool,
    j: [[f32; 3]; 2],
    cov2d: [f32; 3],
    det: f32,
}

fn forward_internals(view: &View, p: &GaussianParams) -> Fwd {
    let (qn, qnorm, rot) = quat_to_rotmat(p.quat);
    let scale = p.log_scale.map(f32::exp);
    // M = R S
    let m: M3 = std::array::from_fn(|i| std::array::from_fn(|j| rot[i][j] * scale[j]));
    let cov = matmul(&m, &transpose(&m));
    let wc = matmul(&view.rot, &cov);
    let cov_cam = matmul(&wc, &transpose(&view.rot));
    let t = view.to_camera(p.mean);
    let tz = t[2];
    let rx = t[0] / tz;
    let ry = t[1] / tz;
    let cx_ = rx.clamp(-view.lim_x_neg, view.lim_x_pos);
    let cy_ = ry.clamp(-view.lim_y_neg, view.lim_y_pos);
    let clamped_x = cx_ != rx;
    let clamped_y = cy_ != ry;
    let tx_c = tz * cx_;
    let ty_c = tz * cy_;
    let j =
        [[view.fx / tz, 0.0, -view.fx * tx_c / (tz * tz)], [0.0, view.fy / tz, -view.fy * ty_c / (tz * tz)]];
    // cov2d = J cov_cam Jᵀ (symmetric 2x2: a, b, c)
    let jc: [[f32; 3]; 2] =
        std::array::from_fn(|i| std::array::from_fn(|k| (0..3).map(|l| j[i][l] * cov_cam[l][k]).sum()));
    let c00 = (0..3).map(|l| jc[0][l] * j[0][l]).sum::<f32>() + EPS2D;
    let c01 = (0..3).map(|l| jc[0][l] * j[1][l]).sum::<f32>();
    let c11 = (0..3).map(|l| jc[1][l] * j[1][l]).sum::<f32>() + EPS2D;
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
fn view_dir(view: &View, mean: [f32; 3]) -> ([f32; 3], f32) {
    let d = [mean[0] - view.centre[0], mean[1] - view.centre[1], mean[2] - view.centre[2]];
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-12);
    ([d[0] / n, d[1] / n, d[2] / n], n)
}

#[inline(always)]
/// SH colour before the clamp (`Σ_k sh_k Y_k(d) + 0.5`).
fn sh_color(view: &View, p: &GaussianParams) -> [f32; 3] {
    let (d, _) = view_dir(view, p.mean);
    sh_color_from(&sh::basis(p.active_degree, d), p)
}

/// [`sh_color`] from the SH basis `b` of the view direction.
#[inline(always)]
fn sh_color_from(b: &[f32; 16], p: &GaussianParams) -> [f32; 3] {
    let k = crate::sh_coeffs(p.active_degree);
    let mut c = [0.5f32; 3];
    for (kk, bk) in b.iter().enumerate().take(k) {
        for (ch, cc) in c.iter_mut().enumerate() {
            *cc += bk * p.sh[kk * 3 + ch];
        }
    }
    c
}

/// The colour a Gaussian is rendered with from `view`: c = max(Σ_k sh_k Y_k(d) + 0.5, 0)
/// over the active SH degree, d the unit direction from the camera centre.
#[inline(always)]
pub fn view_colour(view: &View, p: &GaussianParams) -> [f32; 3] {
    sh_color(view, p).map(|c| c.max(0.0))
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
fn colour_backward_from(
    b: &[f32; 16],
    p: &GaussianParams,
    v_colour: [f32; 3],
    v_sh: &mut [f32],
    clamp: ClampGrad,
) -> [f32; 3] {
    let raw = sh_color_from(b, p);
    let vcol: [f32; 3] = std::array::from_fn(|c| if raw[c] < 0.0 { 0.0 } else { v_colour[c] });
    let vsh: [f32; 3] = match clamp {
        ClampGrad::Exact => vcol,
        ClampGrad::Revive => std::array::from_fn(|c| if v_colour[c] < 0.0 { v_colour[c] } else { vcol[c] }),
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
    let t = view.to_camera(p.mean);
    let tz = t[2];
    if !(tz > NEAR && tz < FAR) {
        return None;
    }
    // Σ₂ = (J W R S)(J W R S)ᵀ: the same quantity as in `forward_internals`, with
    // fewer operations (the backward pass recomputes the factored form).
    let (_, _, rot) = quat_to_rotmat(p.quat);
    let scale = p.log_scale.map(f32::exp);
    let wr = matmul(&view.rot, &rot);
    let rx_ = (t[0] / tz).clamp(-view.lim_x_neg, view.lim_x_pos);
    let ry_ = (t[1] / tz).clamp(-view.lim_y_neg, view.lim_y_pos);
    let (j00, j02) = (view.fx / tz, -view.fx * rx_ / tz);
    let (j11, j12) = (view.fy / tz, -view.fy * ry_ / tz);
    let mut r0 = [0.0f32; 3];
    let mut r1 = [0.0f32; 3];
    for k in 0..3 {
        r0[k] = (j00 * wr[0][k] + j02 * wr[2][k]) * scale[k];
        r1[k] = (j11 * wr[1][k] + j12 * wr[2][k]) * scale[k];
    }
    let c00 = r0[0] * r0[0] + r0[1] * r0[1] + r0[2] * r0[2] + EPS2D;
    let c01 = r0[0] * r1[0] + r0[1] * r1[1] + r0[2] * r1[2];
    let c11 = r1[0] * r1[0] + r1[1] * r1[1] + r1[2] * r1[2] + EPS2D;
    let det = c00 * c11 - c01 * c01;
    if !(det > 0.0) {
        return None;
    }
    let inv = 1.0 / det;
    let conic = [c11 * inv, -c01 * inv, c00 * inv];
    let rx = (EXTENT * c00.sqrt()).ceil();
    let ry = (EXTENT * c11.sqrt()).ceil();
    if rx <= 0.0 && ry <= 0.0 {
        return None;
    }
    let xy = [view.fx * t[0] / tz + view.cx, view.fy * t[1] / tz + view.cy];
    if !(xy[0] + rx > 0.0
        && xy[0] - rx < view.width as f32
        && xy[1] + ry > 0.0
        && xy[1] - ry < view.height as f32)
    {
        return None;
    }
    let color = view_colour(view, p);
    let opacity = transsplat_scene::sigmoid(p.opacity_logit);
    Some((Splat2d { xy, conic, opacity, color, depth: tz }, [rx as u32, ry as u32]))
}

/// Backward of [`project`] for a visible Gaussian: from the gradients on its
/// splat to the gradients on its parameters. SH coefficient gradients are written
/// into `v_sh` (`[coefficient][channel]`, the active coefficients only), through the
/// colour clamp as `clamp` says.
pub fn project_backward(
    view: &View,
    p: &GaussianParams,
    g: &Splat2dGrads,
    v_sh: &mut [f32],
    clamp: ClampGrad,
) -> GaussianGrads {
    let f = forward_internals(view, p);
    let [c00, c01, c11] = f.cov2d;
    let inv = 1.0 / f.det;
    let q = [[c11 * inv, -c01 * inv], [-c01 * inv, c00 * inv]];
    // σ = ½ dᵀ Q d with Q = [[a, b], [b, c]]: dL/dQ = [[va, vb/2], [vb/2, vc]].
    let vq = [[g.conic[0], 0.5 * g.conic[1]], [0.5 * g.conic[1], g.conic[2]]];
    // Q = C⁻¹ ⇒ dL/dC = −Q (dL/dQ) Q.
    let qv: [[f32; 2]; 2] =
        std::array::from_fn(|i| std::array::from_fn(|k| q[i][0] * vq[0][k] + q[i][1] * vq[1][k]));
    let vc: [[f32; 2]; 2] =
        std::array::from_fn(|i| std::array::from_fn(|k| -(qv[i][0] * q[0][k] + qv[i][1] * q[1][k])));

    // C = J Σc Jᵀ: dΣc = Jᵀ dC J; dJ = dC J Σc + dCᵀ J Σcᵀ = 2 dC J Σc (dC, Σc symmetric).
    let j = &f.j;
    let mut v_cov_cam = [[0.0f32; 3]; 3];
    for (a, row) in v_cov_cam.iter_mut().enumerate() {
        for (b, v) in row.iter_mut().enumerate() {
            *v = (0..2).map(|i| (0..2).map(|k| j[i][a] * vc[i][k] * j[k][b]).sum::<f32>()).sum();
        }
    }
    let jsc: [[f32; 3]; 2] =
        std::array::from_fn(|i| std::array::from_fn(|k| (0..3).map(|l| j[i][l] * f.cov_cam[l][k]).sum()));
    let vj: [[f32; 3]; 2] =
        std::array::from_fn(|i| std::array::from_fn(|k| (vc[i][0] * jsc[0][k] + vc[i][1] * jsc[1][k]) * 2.0));

    // Camera-space mean gradient: from the 2D mean, the depth and the Jacobian.
    let [tx, ty, tz] = f.t;
    let (fx, fy) = (view.fx, view.fy);
    let mut vt = [0.0f32; 3];
    vt[0] += fx / tz * g.xy[0];
    vt[1] += fy / tz * g.xy[1];
    vt[2] += -fx * tx / (tz * tz) * g.xy[0] - fy * ty / (tz * tz) * g.xy[1];
    vt[2] += g.depth;
    let tz2 = tz * tz;
    let tz3 = tz2 * tz;
    // J00 = fx/tz, J11 = fy/tz, J02 = -fx tx'/tz², J12 = -fy ty'/tz² with
    // tx' = tz·clamp(tx/tz): unclamped ∂tx'/∂tx = 1; clamped ∂tx'/∂tz = tx'/tz.
    vt[2] += -fx / tz2 * vj[0][0] - fy / tz2 * vj[1][1];
    vt[2] += 2.0 * fx * f.tx_c / tz3 * vj[0][2] + 2.0 * fy * f.ty_c / tz3 * vj[1][2];
    let v_txc = -fx / tz2 * vj[0][2];
    let v_tyc = -fy / tz2 * vj[1][2];
    if f.clamped_x {
        vt[2] += v_txc * f.tx_c / tz;
    } else {
        vt[0] += v_txc;
    }
    if f.clamped_y {
        vt[2] += v_tyc * f.ty_c / tz;
    } else {
        vt[1] += v_tyc;
    }
    // t = R_w x + t_w
    let w = &view.rot;
    let mut v_mean: [f32; 3] = std::array::from_fn(|k| w[0][k] * vt[0] + w[1][k] * vt[1] + w[2][k] * vt[2]);

    // Σc = W Σ Wᵀ ⇒ dΣ = Wᵀ dΣc W.
    let wt = transpose(w);
    let v_cov = matmul(&matmul(&wt, &v_cov_cam), w);
    // Σ = M Mᵀ ⇒ dM = (dΣ + dΣᵀ) M.
    let v_m: M3 = std::array::from_fn(|i| {
        std::array::from_fn(|k| (0..3).map(|l| (v_cov[i][l] + v_cov[l][i]) * f.m[l][k]).sum())
    });
    // M = R S.
    let mut v_log_scale = [0.0f32; 3];
    for (k, v) in v_log_scale.iter_mut().enumerate() {
        *v = (0..3).map(|i| v_m[i][k] * f.rot[i][k]).sum::<f32>() * f.scale[k];
    }
    let gr: M3 = std::array::from_fn(|i| std::array::from_fn(|k| v_m[i][k] * f.scale[k]));
    let [qw, qx, qy, qz] = f.qn;
    let vqn = [
        2.0 * (-qz * gr[0][1] + qy * gr[0][2] + qz * gr[1][0] - qx * gr[1][2] - qy * gr[2][0]
            + qx * gr[2][1]),
        2.0 * (qy * gr[0][1] + qz * gr[0][2] + qy * gr[1][0] - 2.0 * qx * gr[1][1] - qw * gr[1][2]
            + qz * gr[2][0]
            + qw * gr[2][1]
            - 2.0 * qx * gr[2][2]),
        2.0 * (-2.0 * qy * gr[0][0] + qx * gr[0][1] + qw * gr[0][2] + qx * gr[1][0] + qz * gr[1][2]
            - qw * gr[2][0]
            + qz * gr[2][1]
            - 2.0 * qy * gr[2][2]),
        2.0 * (-2.0 * qz * gr[0][0] - qw * gr[0][1] + qx * gr[0][2] + qw * gr[1][0] - 2.0 * qz * gr[1][1]
            + qy * gr[1][2]
            + qx * gr[2][0]
            + qy * gr[2][1]),
    ];
    let dot = (0..4).map(|k| vqn[k] * f.qn[k]).sum::<f32>();
    let v_quat: [f32; 4] = std::array::from_fn(|k| (vqn[k] - f.qn[k] * dot) / f.qnorm);

    // Colour: c = max(Σ_k sh_k Y_k(d) + 0.5, 0).
    let (d, dn) = view_dir(view, p.mean);
    let vcol = colour_backward_from(&sh::basis(p.active_degree, d), p, g.color, v_sh, clamp);
    let k = crate::sh_coeffs(p.active_degree);
    let mut gk = [0.0f32; 16];
    for kk in 0..k {
        for c in 0..3 {
            gk[kk] += p.sh[kk * 3 + c] * vcol[c];
        }
    }
    let vd = sh::basis_vjp(p.active_degree, d, &gk);
    let dd = vd[0] * d[0] + vd[1] * d[1] + vd[2] * d[2];
    for a in 0..3 {
        v_mean[a] += (vd[a] - d[a] * dd) / dn;
    }

    let o = transsplat_scene::sigmoid(p.opacity_logit);
    GaussianGrads {
        mean: v_mean,
        log_scale: v_log_scale,
        quat: v_quat,
        opacity_logit: g.opacity * o * (1.0 - o),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use transsplat_scene::Camera;

    const C0: f32 = 0.282_094_8;

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
    fn rules_round_trip_their_names() {
        for r in ClampGrad::ALL {
            assert_eq!(ClampGrad::from_name(r.name()), Some(r));
        }
        assert_eq!(ClampGrad::from_name("leaky"), None);
    }
}
