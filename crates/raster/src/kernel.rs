//! The per-tile compositing loops: forward (with optional per-Gaussian
//! accumulation for statistics and splat-back) and backward.
//!
//! A tile's 16×16 pixels are lanes; each Gaussian of the tile's depth-ordered list
//! is applied to the rows its box covers, 16 pixels at a time, branch-free so the
//! compiler vectorises the row. The rules are the classic 3DGS ones: pixel centres
//! at +0.5, σ = ½(a dx² + c dy²) + b dx dy, α = min(0.999, o e^{−σ}), skip
//! σ < 0 or α < 1/255, and stop a pixel (without blending) when T(1−α) ≤ 1e-4.

use crate::bin::{Binned, Packed, TILE};
use crate::fastexp::exp_neg;

const N: usize = TILE * TILE;
const ALPHA_MIN: f32 = 1.0 / 255.0;
const T_MIN: f32 = 1e-4;

/// Row range `[r0, r1)` of pixels inside both the tile `[y0, y1)` and the box of `s`.
#[inline(always)]
fn rows(s: &Packed, y0: usize, y1: usize) -> (usize, usize) {
    let lo = (s.y - s.ry - 0.5).ceil().max(y0 as f32) as usize;
    let hi = ((s.y + s.ry - 0.5).floor() + 1.0).clamp(0.0, y1 as f32) as usize;
    (lo.max(y0), hi.max(lo.max(y0)))
}

type Row = [f32; TILE];
type Plane = [Row; TILE];

/// Per-pixel output of one tile's forward pass (`[row][column]`).
pub struct TileOut {
    pub t: Plane,
    pub rgb: [Plane; 3],
    pub depth: Plane,
    pub last: [[u32; TILE]; TILE],
    /// `num_features` planes.
    pub feat: Vec<Plane>,
}

impl TileOut {
    pub fn new(num_features: usize) -> Self {
        TileOut {
            t: [[1.0; TILE]; TILE],
            rgb: [[[0.0; TILE]; TILE]; 3],
            depth: [[0.0; TILE]; TILE],
            last: [[0; TILE]; TILE],
            feat: vec![[[0.0; TILE]; TILE]; num_features],
        }
    }
}

/// Per-Gaussian sums gathered during a forward pass, per splat (depth order):
/// `[Σ w, Σ α, count, Σ w·G_0, ..]` where G is an optional per-pixel image.
pub struct Accum<'a> {
    /// `H × W × channels` image to splat back, or empty.
    pub image: &'a [f32],
    pub channels: usize,
}

impl Accum<'_> {
    /// Floats per splat in the accumulation buffer.
    pub fn stride(&self) -> usize {
        3 + self.channels
    }
}

#[inline(always)]
fn forward_tile_impl(b: &Binned, tile: usize, out: &mut TileOut, acc: Option<(&Accum, &mut [f32])>) {
    let (x0, y0, x1, y1) = b.tile_rect(tile);
    let f = b.num_features;
    let mut active = [[false; TILE]; TILE];
    for row in active.iter_mut().take(y1 - y0) {
        row[..x1 - x0].iter_mut().for_each(|a| *a = true);
    }
    let mut remaining = (y1 - y0) * (x1 - x0);
    out.t = [[1.0; TILE]; TILE];
    out.rgb = [[[0.0; TILE]; TILE]; 3];
    out.depth = [[0.0; TILE]; TILE];
    out.last = [[0; TILE]; TILE];
    out.feat.iter_mut().for_each(|p| *p = [[0.0; TILE]; TILE]);
    let (acc, acc_buf) = match acc {
        Some((a, buf)) => (Some(a), buf),
        None => (None, &mut [][..]),
    };
    let px: Row = std::array::from_fn(|x| (x0 + x) as f32 + 0.5);
    for (li, &j) in b.tile_list(tile).iter().enumerate() {
        if remaining == 0 {
            break;
        }
        let s = &b.splats[j as usize];
        let (r0, r1) = rows(s, y0, y1);
        let mut stops = 0usize;
        let mut sums = [0.0f32; 3];
        let (sx, sa, sb, sc, so) = (s.x, s.a, s.b, s.c, s.opacity);
        let [cr, cg, cb] = s.color;
        let sz = s.depth;
        for py in r0..r1 {
            let r = py - y0;
            let dy = s.y - (py as f32 + 0.5);
            let mut wrow: Row = [0.0; TILE];
            let mut arow: Row = [0.0; TILE];
            let mut nblend = 0u32;
            let mut nstop = 0u32;
            {
                let t = &mut out.t[r];
                let [o0, o1, o2] = &mut out.rgb;
                let (o0, o1, o2) = (&mut o0[r], &mut o1[r], &mut o2[r]);
                let od = &mut out.depth[r];
                let ol = &mut out.last[r];
                let act = &mut active[r];
                let cdy = 0.5 * sc * dy * dy;
                let bdy = sb * dy;
                for x in 0..TILE {
                    let dx = sx - px[x];
                    let sigma = 0.5 * sa * dx * dx + cdy + bdy * dx;
                    let alpha = (so * exp_neg(-sigma)).min(0.999);
                    let tt = t[x];
                    let ok = act[x] & (sigma >= 0.0) & (alpha >= ALPHA_MIN);
                    let next_t = tt * (1.0 - alpha);
                    let stop = ok & (next_t <= T_MIN);
                    let blend = ok & !stop;
                    let w = if blend { alpha * tt } else { 0.0 };
                    o0[x] += w * cr;
                    o1[x] += w * cg;
                    o2[x] += w * cb;
                    od[x] += w * sz;
                    t[x] = if blend { next_t } else { tt };
                    ol[x] = if blend { li as u32 + 1 } else { ol[x] };
                    act[x] &= !stop;
                    nstop += stop as u32;
                    nblend += blend as u32;
                    wrow[x] = w;
                    arow[x] = if blend { alpha } else { 0.0 };
                }
            }
            stops += nstop as usize;
            if nblend == 0 {
                continue;
            }
            if f > 0 {
                let fj = &b.feats[j as usize * f..(j as usize + 1) * f];
                for (plane, &fk) in out.feat.iter_mut().zip(fj) {
                    let dst = &mut plane[r];
                    for x in 0..TILE {
                        dst[x] += wrow[x] * fk;
                    }
                }
            }
            if let Some(a) = acc {
                sums[0] += wrow.iter().sum::<f32>();
                sums[1] += arow.iter().sum::<f32>();
                sums[2] += nblend as f32;
                if a.channels > 0 {
                    let stride = a.stride();
                    let dst = &mut acc_buf[j as usize * stride + 3..(j as usize + 1) * stride];
                    for (x, &w) in wrow.iter().enumerate().take(x1 - x0) {
                        if w > 0.0 {
                            let g = &a.image[(py * b.width + x0 + x) * a.channels..][..a.channels];
                            for (d, gv) in dst.iter_mut().zip(g) {
                                *d += w * gv;
                            }
                        }
                    }
                }
            }
        }
        if let Some(a) = acc {
            if sums[2] > 0.0 {
                let dst = &mut acc_buf[j as usize * a.stride()..][..3];
                for k in 0..3 {
                    dst[k] += sums[k];
                }
            }
        }
        remaining -= stops;
    }
}

/// Upstream gradients for one view, per pixel; empty slices mean zero.
#[derive(Clone, Copy, Debug, Default)]
pub struct PixelGrads<'a> {
    pub rgb: &'a [f32],
    pub alpha: &'a [f32],
    pub depth: &'a [f32],
    pub features: &'a [f32],
}

/// Per-view forward state the backward pass needs.
pub struct ForwardState<'a> {
    pub final_t: &'a [f32],
    pub last: &'a [u32],
    pub background: [f32; 3],
}

/// Floats per splat in the backward accumulation buffer:
/// `[x, y, a, b, c, opacity, r, g, b, depth, features..]`.
pub fn grad_stride(num_features: usize) -> usize {
    10 + num_features
}

#[inline(always)]
fn backward_tile_impl(b: &Binned, tile: usize, st: &ForwardState, g: &PixelGrads, buf: &mut [f32]) {
    let (x0, y0, x1, y1) = b.tile_rect(tile);
    let f = b.num_features;
    let stride = grad_stride(f);
    let w = b.width;
    let mut t = [0.0f32; N];
    let mut last = [0u32; N];
    let mut vrgb = [[0.0f32; N]; 3];
    let mut vd = [0.0f32; N];
    let mut tfv = [0.0f32; N];
    let mut vf = vec![0.0f32; f * N];
    let mut bf = vec![0.0f32; f * N];
    let mut brgb = [[0.0f32; N]; 3];
    let mut bd = [0.0f32; N];
    let mut max_last = 0u32;
    for y in 0..(y1 - y0) {
        for x in 0..(x1 - x0) {
            let p = y * TILE + x;
            let q = (y0 + y) * w + x0 + x;
            t[p] = st.final_t[q];
            last[p] = st.last[q];
            max_last = max_last.max(last[p]);
            let mut bgv = 0.0;
            if !g.rgb.is_empty() {
                for c in 0..3 {
                    vrgb[c][p] = g.rgb[q * 3 + c];
                    bgv += st.background[c] * vrgb[c][p];
                }
            }
            let va = if g.alpha.is_empty() { 0.0 } else { g.alpha[q] };
            // ∂(1 − T_N)/∂α_i = T_N/(1−α_i); ∂(T_N bg)/∂α_i = −T_N bg/(1−α_i).
            tfv[p] = t[p] * (va - bgv);
            if !g.depth.is_empty() {
                vd[p] = g.depth[q];
            }
            if !g.features.is_empty() {
                for k in 0..f {
                    vf[k * N + p] = g.features[q * f + k];
                }
            }
        }
    }
    let px: [f32; TILE] = std::array::from_fn(|x| (x0 + x) as f32 + 0.5);
    let list = b.tile_list(tile);
    let mut gfeat = vec![0.0f32; f];
    for li in (0..max_last as usize).rev() {
        let j = list[li] as usize;
        let s = &b.splats[j];
        let (r0, r1) = rows(s, y0, y1);
        if r0 >= r1 {
            continue;
        }
        let mut gx = [0.0f32; TILE];
        let mut gy = [0.0f32; TILE];
        let mut ga = [0.0f32; TILE];
        let mut gb = [0.0f32; TILE];
        let mut gc = [0.0f32; TILE];
        let mut go = [0.0f32; TILE];
        let mut gcol = [[0.0f32; TILE]; 3];
        let mut gz = [0.0f32; TILE];
        let mut touched = false;
        gfeat.iter_mut().for_each(|v| *v = 0.0);
        let fj = &b.feats[j * f..(j + 1) * f];
        for py in r0..r1 {
            let row = (py - y0) * TILE;
            let dy = s.y - (py as f32 + 0.5);
            let mut okr = [false; TILE];
            let mut tbr = [0.0f32; TILE];
            let mut rar = [0.0f32; TILE];
            let mut facr = [0.0f32; TILE];
            let mut val = [0.0f32; TILE];
            let mut visr = [0.0f32; TILE];
            let mut any = false;
            for x in 0..TILE {
                let p = row + x;
                let dx = s.x - px[x];
                let sigma = 0.5 * (s.a * dx * dx + s.c * dy * dy) + s.b * dx * dy;
                let vis = exp_neg(-sigma);
                let alpha = (s.opacity * vis).min(0.999);
                let ok = ((li as u32) < last[p]) & (sigma >= 0.0) & (alpha >= ALPHA_MIN);
                let ra = 1.0 / (1.0 - alpha);
                let tb = t[p] * ra;
                let fac = alpha * tb;
                let mut v = 0.0;
                for c in 0..3 {
                    v += (s.color[c] * tb - brgb[c][p] * ra) * vrgb[c][p];
                }
                v += (s.depth * tb - bd[p] * ra) * vd[p] + tfv[p] * ra;
                for c in 0..3 {
                    gcol[c][x] += if ok { fac * vrgb[c][p] } else { 0.0 };
                    brgb[c][p] += if ok { fac * s.color[c] } else { 0.0 };
                }
                gz[x] += if ok { fac * vd[p] } else { 0.0 };
                bd[p] += if ok { fac * s.depth } else { 0.0 };
                t[p] = if ok { tb } else { t[p] };
                okr[x] = ok;
                tbr[x] = tb;
                rar[x] = ra;
                facr[x] = fac;
                val[x] = v;
                visr[x] = vis;
                any |= ok;
            }
            if !any {
                continue;
            }
            touched = true;
            for (k, &fk) in fj.iter().enumerate() {
                let vfk = &vf[k * N + row..k * N + row + TILE];
                let bfk = &mut bf[k * N + row..k * N + row + TILE];
                let mut gk = 0.0;
                for x in 0..TILE {
                    let ok = okr[x];
                    val[x] += if ok { (fk * tbr[x] - bfk[x] * rar[x]) * vfk[x] } else { 0.0 };
                    bfk[x] += if ok { facr[x] * fk } else { 0.0 };
                    gk += if ok { facr[x] * vfk[x] } else { 0.0 };
                }
                gfeat[k] += gk;
            }
            for x in 0..TILE {
                let dx = s.x - px[x];
                let unclamped = okr[x] & (s.opacity * visr[x] <= 0.999);
                let va = if unclamped { val[x] } else { 0.0 };
                let vsig = -s.opacity * visr[x] * va;
                go[x] += visr[x] * va;
                ga[x] += 0.5 * vsig * dx * dx;
                gb[x] += vsig * dx * dy;
                gc[x] += 0.5 * vsig * dy * dy;
                gx[x] += vsig * (s.a * dx + s.b * dy);
                gy[x] += vsig * (s.b * dx + s.c * dy);
            }
        }
        if !touched {
            continue;
        }
        let dst = &mut buf[j * stride..(j + 1) * stride];
        let sum = |a: &[f32; TILE]| a.iter().sum::<f32>();
        dst[0] += sum(&gx);
        dst[1] += sum(&gy);
        dst[2] += sum(&ga);
        dst[3] += sum(&gb);
        dst[4] += sum(&gc);
        dst[5] += sum(&go);
        for c in 0..3 {
            dst[6 + c] += sum(&gcol[c]);
        }
        dst[9] += sum(&gz);
        for k in 0..f {
            dst[10 + k] += gfeat[k];
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn forward_tile_avx2(b: &Binned, tile: usize, out: &mut TileOut, acc: Option<(&Accum, &mut [f32])>) {
    forward_tile_impl(b, tile, out, acc)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn backward_tile_avx2(b: &Binned, tile: usize, st: &ForwardState, g: &PixelGrads, buf: &mut [f32]) {
    backward_tile_impl(b, tile, st, g, buf)
}

fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Forward pass over one tile. Forward and backward always take the same code
/// path so that their skip and stop decisions agree bit for bit.
pub fn forward_tile(b: &Binned, tile: usize, out: &mut TileOut, acc: Option<(&Accum, &mut [f32])>) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU supports AVX2 and FMA (checked above).
        return unsafe { forward_tile_avx2(b, tile, out, acc) };
    }
    forward_tile_impl(b, tile, out, acc)
}

/// Backward pass over one tile, accumulating per-splat gradients into `buf`
/// (layout [`grad_stride`]).
pub fn backward_tile(b: &Binned, tile: usize, st: &ForwardState, g: &PixelGrads, buf: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU supports AVX2 and FMA (checked above).
        return unsafe { backward_tile_avx2(b, tile, st, g, buf) };
    }
    backward_tile_impl(b, tile, st, g, buf)
}
