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
use crate::project::Splat2dGrads;
use transsplat_scene::cpu::prefetch_bytes;

pub(crate) const ALPHA_MIN: f32 = 1.0 / 255.0;
pub(crate) const T_MIN: f32 = 1e-4;

/// Lanes per vector: a tile row is processed as two halves of 8 pixels.
const HALF: usize = 8;

/// Row range `[r0, r1)` of pixels inside both the tile `[y0, y1)` and the support of `s`.
#[inline(always)]
fn rows(s: &Packed, y0: usize, y1: usize) -> (usize, usize) {
    let lo = (s.y - s.ey - 0.5).ceil().max(y0 as f32) as usize;
    let hi = ((s.y + s.ey - 0.5).floor() + 1.0).clamp(0.0, y1 as f32) as usize;
    (lo.max(y0), hi.max(lo.max(y0)))
}

/// The halves `[h0, h1)` of a tile row holding the pixel columns whose centres lie in
/// `[lo, hi]` (pixels from the tile's left edge, padding included); a NaN bound keeps
/// the halves it cannot rule out.
#[inline(always)]
fn span_halves(lo: f32, hi: f32) -> (usize, usize) {
    if hi < 0.0 || lo > (TILE - 1) as f32 {
        return (0, 0);
    }
    let lo = lo.max(0.0) as usize / HALF;
    let hi = (hi.min((TILE - 1) as f32) as usize) / HALF + 1;
    (lo, hi)
}

/// Which halves of a tile's rows a splat can reach, worked out once per splat and tile.
struct Columns {
    /// The halves `[h0, h1)` its box `x ± ex` reaches, padded by 0.05 px as the rows' are.
    /// Every half [`Columns::row_halves`] solves for lies in them (the box is the extent
    /// of the ellipse σ ≤ thr), so where they are one half the rows need no solving: a
    /// half the ellipse misses on some row only gives pairs with α < 1/255, which the
    /// compositing rule skips, as it skips the other lanes of a half.
    halves: (usize, usize),
    /// 1/a of the conic, for solving the rows of a splat that spans both halves.
    inv_a: f32,
}

impl Columns {
    #[inline(always)]
    fn of(s: &Packed, x0: usize) -> Self {
        let left = s.x - 0.5 - x0 as f32;
        Columns { halves: span_halves(left - s.ex - 0.05, left + s.ex + 0.05), inv_a: 1.0 / s.a }
    }

    /// The bits of [`forward_tile`]'s live mask for these halves in every row.
    #[inline(always)]
    fn mask(&self) -> u32 {
        const FIRST: u32 = 0x5555_5555;
        match self.halves {
            (0, 1) => FIRST,
            (1, 2) => FIRST << 1,
            (0, 2) => u32::MAX,
            _ => 0,
        }
    }

    /// The halves of the row at `dy` (mean − pixel-centre y) to evaluate: the box's where
    /// it is one half, else those that can hold a pixel with σ ≤ thr, the roots of
    /// ½a dx² + b dy dx + ½c dy² = thr padded by 0.05 px (using 1/a: the product differs
    /// from the quotient by an ulp or so, far inside the padding).
    #[inline(always)]
    fn row_halves(&self, s: &Packed, dy: f32, x0: usize) -> (usize, usize) {
        if self.halves.1 - self.halves.0 <= 1 {
            return self.halves;
        }
        let disc = (s.b * s.b - s.a * s.c) * dy * dy + 2.0 * s.a * s.thr;
        if !(disc >= 0.0) {
            return (0, 0);
        }
        let r = disc.sqrt();
        // Pixel centre px = x0 + x + 0.5 = s.x − dx with dx between the roots.
        let left = s.x - 0.5 - x0 as f32;
        span_halves(left - (-s.b * dy + r) * self.inv_a - 0.05, left - (-s.b * dy - r) * self.inv_a + 0.05)
    }
}

/// The bits of [`forward_tile`]'s live mask for tile rows `[r0, r1)` (both halves).
#[inline(always)]
fn half_mask(r0: usize, r1: usize) -> u32 {
    let upto = |r: usize| if r >= TILE { u32::MAX } else { (1u32 << (2 * r)) - 1 };
    upto(r1) & !upto(r0)
}

/// How many list entries ahead the splat data is prefetched.
const PREFETCH: usize = 12;

/// Hints the CPU to fetch the splat at `list[i]` (the lists index a large array
/// in depth order, so consecutive entries are far apart in memory).
#[inline(always)]
fn prefetch(b: &Binned, list: &[u32], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(&j) = list.get(i) {
        let p = b.splats.as_ptr().wrapping_add(j as usize) as *const i8;
        // SAFETY: prefetching is a hint; it never faults, even for a bad address.
        unsafe { std::arch::x86_64::_mm_prefetch(p, std::arch::x86_64::_MM_HINT_T0) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (b, list, i);
}

#[inline(always)]
fn half<T>(row: &[T; TILE], h: usize) -> &[T; HALF] {
    (&row[h * HALF..h * HALF + HALF]).try_into().expect("half row")
}

#[inline(always)]
fn half_mut<T>(row: &mut [T; TILE], h: usize) -> &mut [T; HALF] {
    (&mut row[h * HALF..h * HALF + HALF]).try_into().expect("half row")
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
    /// The last `capped` channels accumulate min(w, G(p)) instead of w G(p)
    /// ([`crate::gaussian_stats_capped`]).
    pub capped: usize,
}

impl Accum<'_> {
    /// Floats per splat in the accumulation buffer.
    pub fn stride(&self) -> usize {
        3 + self.channels
    }
}

#[inline(always)]
fn forward_tile_impl<const WEIGHTS: bool>(
    b: &Binned,
    tile: usize,
    out: &mut TileOut,
    acc: Option<(&Accum, &mut [f32])>,
) {
    let (x0, y0, x1, y1) = b.tile_rect(tile);
    let f = b.num_features;
    // A pixel is live while its T is positive; when it stops, T is stored negated
    // (|T| is its final transmittance). Pixels outside the image start stopped.
    out.t = [[-1.0; TILE]; TILE];
    for row in out.t.iter_mut().take(y1 - y0) {
        row[..x1 - x0].iter_mut().for_each(|t| *t = 1.0);
    }
    out.rgb = [[[0.0; TILE]; TILE]; 3];
    out.depth = [[0.0; TILE]; TILE];
    out.last = [[0; TILE]; TILE];
    out.feat.iter_mut().for_each(|p| *p = [[0.0; TILE]; TILE]);
    let (acc, acc_buf) = match acc {
        Some((a, buf)) => (Some(a), buf),
        None => (None, &mut [][..]),
    };
    // Known at compile time, so the plain render (no features, no sums: training) keeps
    // no per-lane weights at all.
    debug_assert_eq!(WEIGHTS, f > 0 || acc.is_some());
    let need_weights = WEIGHTS;
    let px: Row = std::array::from_fn(|x| (x0 + x) as f32 + 0.5);
    // Bit 2r + h: half h of row r still has a live pixel. A splat whose rows are all
    // stopped is skipped before any per-row work, and the tile ends when none is live.
    let mut live = 0u32;
    for r in 0..TILE {
        for h in 0..TILE / HALF {
            if half(&out.t[r], h).iter().any(|&v| v > 0.0) {
                live |= 1 << (2 * r + h);
            }
        }
    }
    let list = b.tile_list(tile);
    for (li, &j) in list.iter().enumerate() {
        if live == 0 {
            break;
        }
        prefetch(b, list, li + PREFETCH);
        let s = &b.splats[j as usize];
        let (r0, r1) = rows(s, y0, y1);
        let columns = Columns::of(s, x0);
        let cols = columns.mask();
        if live & half_mask(r0 - y0, r1 - y0) & cols == 0 {
            continue;
        }
        let mut sums = [0.0f32; 3];
        let (sx, sa, sb, sc, so) = (s.x, s.a, s.b, s.c, s.opacity);
        let [cr, cg, cb] = s.color;
        let sz = s.depth;
        let lnext = li as u32 + 1;
        for py in r0..r1 {
            let r = py - y0;
            if (live & cols) >> (2 * r) & 3 == 0 {
                continue;
            }
            let dy = s.y - (py as f32 + 0.5);
            let (h0, h1) = columns.row_halves(s, dy, x0);
            let cdy = 0.5 * sc * dy * dy;
            let bdy = sb * dy;
            for h in h0..h1 {
                let bit = 1u32 << (2 * r + h);
                if live & bit == 0 {
                    continue;
                }
                let t = half_mut(&mut out.t[r], h);
                let mut wrow = [0.0f32; HALF];
                let mut arow = [0.0f32; HALF];
                let mut any_stop = false;
                {
                    let [o0, o1, o2] = &mut out.rgb;
                    let (o0, o1, o2) =
                        (half_mut(&mut o0[r], h), half_mut(&mut o1[r], h), half_mut(&mut o2[r], h));
                    let od = half_mut(&mut out.depth[r], h);
                    let ol = half_mut(&mut out.last[r], h);
                    let pxh = half(&px, h);
                    for x in 0..HALF {
                        let dx = sx - pxh[x];
                        let sigma = 0.5 * sa * dx * dx + cdy + bdy * dx;
                        let alpha = (so * exp_neg(-sigma)).min(0.999);
                        let tt = t[x];
                        let ok = (tt > 0.0) & (sigma >= 0.0) & (alpha >= ALPHA_MIN);
                        let next_t = tt * (1.0 - alpha);
                        let stop = ok & (next_t <= T_MIN);
                        let blend = ok & !stop;
                        let w = if blend { alpha * tt } else { 0.0 };
                        o0[x] += w * cr;
                        o1[x] += w * cg;
                        o2[x] += w * cb;
                        od[x] += w * sz;
                        t[x] = if blend {
                            next_t
                        } else if stop {
                            -tt
                        } else {
                            tt
                        };
                        ol[x] = if blend { lnext } else { ol[x] };
                        wrow[x] = w;
                        arow[x] = if blend { alpha } else { 0.0 };
                        any_stop |= stop;
                    }
                    if any_stop && t.iter().all(|&v| v <= 0.0) {
                        live &= !bit;
                    }
                }
                if !need_weights {
                    continue;
                }
                if f > 0 {
                    let fj = &b.feats[j as usize * f..(j as usize + 1) * f];
                    for (plane, &fk) in out.feat.iter_mut().zip(fj) {
                        let dst = half_mut(&mut plane[r], h);
                        for x in 0..HALF {
                            dst[x] += wrow[x] * fk;
                        }
                    }
                }
                if let Some(a) = acc {
                    sums[0] += wrow.iter().sum::<f32>();
                    sums[1] += arow.iter().sum::<f32>();
                    sums[2] += arow.iter().filter(|&&v| v > 0.0).count() as f32;
                    if a.channels > 0 {
                        let stride = a.stride();
                        let dst = &mut acc_buf[j as usize * stride + 3..(j as usize + 1) * stride];
                        let plain = a.channels - a.capped.min(a.channels);
                        for (x, &w) in wrow.iter().enumerate() {
                            if w > 0.0 {
                                let col = x0 + h * HALF + x;
                                let g = &a.image[(py * b.width + col) * a.channels..][..a.channels];
                                for (d, gv) in dst[..plain].iter_mut().zip(&g[..plain]) {
                                    *d += w * gv;
                                }
                                for (d, &gv) in dst[plain..].iter_mut().zip(&g[plain..]) {
                                    *d += w.min(gv);
                                }
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
    }
    for v in out.t.iter_mut().flatten() {
        *v = v.abs();
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

/// Where each gradient sits in one splat's row of the backward accumulation buffer
/// ([`grad_stride`] floats): ∂L with respect to the splat's 2D quantities.
pub mod slot {
    /// ∂L/∂(x, y) of the projected mean (2 floats).
    pub const XY: usize = 0;
    /// ∂L/∂(a, b, c) of the conic (3 floats).
    pub const CONIC: usize = 2;
    /// ∂L/∂o of the activated opacity.
    pub const OPACITY: usize = 5;
    /// ∂L/∂(r, g, b) of the view-dependent colour (3 floats).
    pub const COLOR: usize = 6;
    /// ∂L/∂z of the view depth.
    pub const DEPTH: usize = 9;
    /// ∂L/∂f_k of the features (`num_features` floats).
    pub const FEATURES: usize = 10;
}

/// Floats per splat in the backward accumulation buffer (layout [`slot`]).
pub fn grad_stride(num_features: usize) -> usize {
    slot::FEATURES + num_features
}

/// The named 2D gradients of one accumulator row (without the features).
pub fn splat_grads(row: &[f32]) -> Splat2dGrads {
    let at = |k: usize| row[k];
    Splat2dGrads {
        xy: [at(slot::XY), at(slot::XY + 1)],
        conic: [at(slot::CONIC), at(slot::CONIC + 1), at(slot::CONIC + 2)],
        opacity: at(slot::OPACITY),
        color: [at(slot::COLOR), at(slot::COLOR + 1), at(slot::COLOR + 2)],
        depth: at(slot::DEPTH),
    }
}

/// `rows[k][0] + rows[k][1] + … + rows[k][7]` for every k, added in that order, so each
/// is `rows[k].iter().sum()` to the bit. With `AVX` (only in the AVX2 instance of a
/// kernel) the eight rows are transposed in registers and their columns added, eight
/// sums at once, instead of reducing each row across its lanes one by one.
#[inline(always)]
fn lane_sums<const AVX: bool>(rows: &[[f32; HALF]; HALF]) -> [f32; HALF] {
    #[cfg(target_arch = "x86_64")]
    if AVX {
        // SAFETY: the AVX2 instance runs only where the CPU has AVX2.
        return unsafe { transposed_sums(rows) };
    }
    std::array::from_fn(|k| rows[k].iter().sum())
}

/// [`lane_sums`] by an 8×8 transpose (unpack, shuffle, exchange of 128-bit halves).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn transposed_sums(rows: &[[f32; HALF]; HALF]) -> [f32; HALF] {
    use std::arch::x86_64::*;
    let mut r = [_mm256_setzero_ps(); HALF];
    for k in 0..HALF {
        // SAFETY: each row is 8 floats, read unaligned.
        r[k] = unsafe { _mm256_loadu_ps(rows[k].as_ptr()) };
    }
    // Rows 2i and 2i+1 interleaved: t[2i] holds their columns 0, 1 | 4, 5, t[2i+1] 2, 3 | 6, 7.
    let mut t = r;
    for i in 0..HALF / 2 {
        t[2 * i] = _mm256_unpacklo_ps(r[2 * i], r[2 * i + 1]);
        t[2 * i + 1] = _mm256_unpackhi_ps(r[2 * i], r[2 * i + 1]);
    }
    // u[4q + c] holds column c of rows 4q..4q+4 in its low half, column c + 4 in its high.
    let mut u = t;
    for q in 0..2 {
        let (t0, t1, t2, t3) = (t[4 * q], t[4 * q + 1], t[4 * q + 2], t[4 * q + 3]);
        u[4 * q] = _mm256_shuffle_ps::<0x44>(t0, t2);
        u[4 * q + 1] = _mm256_shuffle_ps::<0xEE>(t0, t2);
        u[4 * q + 2] = _mm256_shuffle_ps::<0x44>(t1, t3);
        u[4 * q + 3] = _mm256_shuffle_ps::<0xEE>(t1, t3);
    }
    // Column c of all eight rows, added in column order.
    let mut s = _mm256_permute2f128_ps::<0x20>(u[0], u[4]);
    for c in 1..4 {
        s = _mm256_add_ps(s, _mm256_permute2f128_ps::<0x20>(u[c], u[4 + c]));
    }
    for c in 0..4 {
        s = _mm256_add_ps(s, _mm256_permute2f128_ps::<0x31>(u[c], u[4 + c]));
    }
    let mut out = [0.0f32; HALF];
    // SAFETY: `out` holds 8 floats.
    unsafe { _mm256_storeu_ps(out.as_mut_ptr(), s) };
    out
}

#[inline(always)]
fn backward_tile_impl<const AVX: bool, const FEATURES: bool>(
    b: &Binned,
    tile: usize,
    st: &ForwardState,
    g: &PixelGrads,
    buf: &mut [f32],
) {
    let (x0, y0, x1, y1) = b.tile_rect(tile);
    let f = b.num_features;
    let stride = grad_stride(f);
    let w = b.width;
    let mut t: Plane = [[0.0; TILE]; TILE];
    let mut last = [[0u32; TILE]; TILE];
    let mut vrgb: [Plane; 3] = [[[0.0; TILE]; TILE]; 3];
    let mut vd: Plane = [[0.0; TILE]; TILE];
    let mut tfv: Plane = [[0.0; TILE]; TILE];
    let mut vf: Vec<Plane> = vec![[[0.0; TILE]; TILE]; f];
    let mut bf: Vec<Plane> = vec![[[0.0; TILE]; TILE]; f];
    let mut brgb: [Plane; 3] = [[[0.0; TILE]; TILE]; 3];
    let mut bd: Plane = [[0.0; TILE]; TILE];
    let mut max_last = 0u32;
    for y in 0..(y1 - y0) {
        for x in 0..(x1 - x0) {
            let q = (y0 + y) * w + x0 + x;
            t[y][x] = st.final_t[q];
            last[y][x] = st.last[q];
            max_last = max_last.max(last[y][x]);
            let mut bgv = 0.0;
            if !g.rgb.is_empty() {
                for c in 0..3 {
                    vrgb[c][y][x] = g.rgb[q * 3 + c];
                    bgv += st.background[c] * vrgb[c][y][x];
                }
            }
            let va = if g.alpha.is_empty() { 0.0 } else { g.alpha[q] };
            // ∂(1 − T_N)/∂α_i = T_N/(1−α_i); ∂(T_N bg)/∂α_i = −T_N bg/(1−α_i).
            tfv[y][x] = t[y][x] * (va - bgv);
            if !g.depth.is_empty() {
                vd[y][x] = g.depth[q];
            }
            if !g.features.is_empty() {
                for (k, plane) in vf.iter_mut().enumerate() {
                    plane[y][x] = g.features[q * f + k];
                }
            }
        }
    }
    // Highest `last` per half row and per row: a half row (a row, a splat whose rows all
    // are) is skipped while the list position is past it.
    let mut half_last = [[0u32; 2]; TILE];
    for (hl, row) in half_last.iter_mut().zip(&last) {
        for (h, v) in hl.iter_mut().enumerate() {
            *v = half(row, h).iter().copied().max().unwrap_or(0);
        }
    }
    let row_last: [u32; TILE] = std::array::from_fn(|r| half_last[r][0].max(half_last[r][1]));
    let px: Row = std::array::from_fn(|x| (x0 + x) as f32 + 0.5);
    let list = b.tile_list(tile);
    let mut gfeat = vec![0.0f32; f];
    for li in (0..max_last as usize).rev() {
        if li >= PREFETCH {
            prefetch(b, list, li - PREFETCH);
            // The accumulator row it will add to: depth order scatters them over a
            // buffer of every splat, so each would otherwise be a miss to memory.
            let ahead = list[li - PREFETCH] as usize;
            prefetch_bytes(buf.as_ptr() as usize + ahead * stride * 4, stride * 4);
        }
        let j = list[li] as usize;
        let s = &b.splats[j];
        let (r0, r1) = rows(s, y0, y1);
        let li32 = li as u32;
        if row_last[r0 - y0..r1 - y0].iter().all(|&l| li32 >= l) {
            continue;
        }
        let columns = Columns::of(s, x0);
        let (sx, sa, sb, sc, so, sz) = (s.x, s.a, s.b, s.c, s.opacity, s.depth);
        let [cr, cg, cb] = s.color;
        let mut gx = [0.0f32; HALF];
        let mut gy = [0.0f32; HALF];
        let mut ga = [0.0f32; HALF];
        let mut gb = [0.0f32; HALF];
        let mut gc = [0.0f32; HALF];
        let mut go = [0.0f32; HALF];
        let mut gcol = [[0.0f32; HALF]; 3];
        let mut gz = [0.0f32; HALF];
        let mut touched = false;
        gfeat.iter_mut().for_each(|v| *v = 0.0);
        let fj = &b.feats[j * f..(j + 1) * f];
        for py in r0..r1 {
            let r = py - y0;
            if li32 >= row_last[r] {
                continue;
            }
            let dy = s.y - (py as f32 + 0.5);
            let (h0, h1) = columns.row_halves(s, dy, x0);
            for h in h0..h1 {
                if li32 >= half_last[r][h] {
                    continue;
                }
                // Masked per-lane values (0 where the pair was not blended).
                let mut tbm = [0.0f32; HALF];
                let mut ram = [0.0f32; HALF];
                let mut facm = [0.0f32; HALF];
                let mut okm = [0.0f32; HALF];
                let mut visr = [0.0f32; HALF];
                {
                    let pxh = half(&px, h);
                    let lst = half(&last[r], h);
                    let tt = half_mut(&mut t[r], h);
                    let [v0, v1, v2] = &vrgb;
                    let (v0, v1, v2) = (half(&v0[r], h), half(&v1[r], h), half(&v2[r], h));
                    let [b0, b1, b2] = &mut brgb;
                    let (b0, b1, b2) =
                        (half_mut(&mut b0[r], h), half_mut(&mut b1[r], h), half_mut(&mut b2[r], h));
                    let vdr = half(&vd[r], h);
                    let bdr = half_mut(&mut bd[r], h);
                    let tf = half(&tfv[r], h);
                    for x in 0..HALF {
                        let dx = sx - pxh[x];
                        let sigma = 0.5 * sa * dx * dx + 0.5 * sc * dy * dy + sb * dx * dy;
                        let vis = exp_neg(-sigma);
                        let alpha = (so * vis).min(0.999);
                        let ok = (li32 < lst[x]) & (sigma >= 0.0) & (alpha >= ALPHA_MIN);
                        let ra = if ok { 1.0 / (1.0 - alpha) } else { 0.0 };
                        let tb = tt[x] * ra;
                        let fac = alpha * tb;
                        // ∂L/∂α_i without the feature channels (added below).
                        let v = (cr * tb - b0[x] * ra) * v0[x]
                            + (cg * tb - b1[x] * ra) * v1[x]
                            + (cb * tb - b2[x] * ra) * v2[x]
                            + (sz * tb - bdr[x] * ra) * vdr[x]
                            + tf[x] * ra;
                        gcol[0][x] += fac * v0[x];
                        gcol[1][x] += fac * v1[x];
                        gcol[2][x] += fac * v2[x];
                        b0[x] += fac * cr;
                        b1[x] += fac * cg;
                        b2[x] += fac * cb;
                        gz[x] += fac * vdr[x];
                        bdr[x] += fac * sz;
                        tt[x] = if ok { tb } else { tt[x] };
                        // α = min(0.999, o e^{−σ}) has no gradient where it is clamped.
                        let va = if so * vis <= 0.999 { v } else { 0.0 };
                        let vsig = -so * vis * va;
                        go[x] += vis * va;
                        ga[x] += 0.5 * vsig * dx * dx;
                        gb[x] += vsig * dx * dy;
                        gc[x] += 0.5 * vsig * dy * dy;
                        gx[x] += vsig * (sa * dx + sb * dy);
                        gy[x] += vsig * (sb * dx + sc * dy);
                        tbm[x] = tb;
                        ram[x] = ra;
                        facm[x] = fac;
                        okm[x] = if ok { 1.0 } else { 0.0 };
                        visr[x] = vis;
                    }
                }
                touched = true;
                if !FEATURES {
                    continue;
                }
                let mut vfa = [0.0f32; HALF];
                for (k, &fk) in fj.iter().enumerate() {
                    let vfk = half(&vf[k][r], h);
                    let bfk = half_mut(&mut bf[k][r], h);
                    let mut gk = 0.0;
                    for x in 0..HALF {
                        vfa[x] += (fk * tbm[x] - bfk[x] * ram[x]) * vfk[x];
                        bfk[x] += facm[x] * fk;
                        gk += facm[x] * vfk[x];
                    }
                    gfeat[k] += gk;
                }
                let pxh = half(&px, h);
                for x in 0..HALF {
                    let dx = sx - pxh[x];
                    let va = if so * visr[x] <= 0.999 { vfa[x] * okm[x] } else { 0.0 };
                    let vsig = -so * visr[x] * va;
                    go[x] += visr[x] * va;
                    ga[x] += 0.5 * vsig * dx * dx;
                    gb[x] += vsig * dx * dy;
                    gc[x] += 0.5 * vsig * dy * dy;
                    gx[x] += vsig * (sa * dx + sb * dy);
                    gy[x] += vsig * (sb * dx + sc * dy);
                }
            }
        }
        if !touched {
            continue;
        }
        let dst = &mut buf[j * stride..(j + 1) * stride];
        // Slots 0..8 in order: ∂(x, y), ∂(a, b, c), ∂o, ∂(r, g).
        const _: () = assert!(slot::XY == 0 && slot::CONIC == 2 && slot::OPACITY == 5 && slot::COLOR == 6);
        let first = lane_sums::<AVX>(&[gx, gy, ga, gb, gc, go, gcol[0], gcol[1]]);
        for (d, v) in dst[..HALF].iter_mut().zip(first) {
            *d += v;
        }
        let sum = |a: &[f32; HALF]| a.iter().sum::<f32>();
        dst[slot::COLOR + 2] += sum(&gcol[2]);
        dst[slot::DEPTH] += sum(&gz);
        for (d, g) in dst[slot::FEATURES..].iter_mut().zip(&gfeat[..f]) {
            *d += g;
        }
    }
}

/// The tile passes compiled for one instruction set: the same code (`forward_tile_impl`,
/// `backward_tile_impl`) with the CPU features enabled, so the compiler emits their vector
/// instructions. The same IEEE operations whatever the set (no fused multiply-adds are
/// formed), so the same bits; a test runs every instance the CPU has against the plain one.
macro_rules! tile_passes_for {
    ($forward:ident, $backward:ident, $features:literal) => {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        fn $forward<const WEIGHTS: bool>(
            b: &Binned,
            tile: usize,
            out: &mut TileOut,
            acc: Option<(&Accum, &mut [f32])>,
        ) {
            forward_tile_impl::<WEIGHTS>(b, tile, out, acc)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        fn $backward<const FEATURES: bool>(
            b: &Binned,
            tile: usize,
            st: &ForwardState,
            g: &PixelGrads,
            buf: &mut [f32],
        ) {
            backward_tile_impl::<true, FEATURES>(b, tile, st, g, buf)
        }
    };
}

tile_passes_for!(forward_tile_avx2, backward_tile_avx2, "avx2,fma");
// With AVX-512 the same 8-lane code has 32 vector registers instead of 16, so the
// compiler keeps more of a splat's per-lane sums and the row's planes in registers.
tile_passes_for!(forward_tile_avx512, backward_tile_avx512, "avx2,fma,avx512f,avx512vl,avx512bw,avx512dq");

/// [`forward_tile`] for one value of `WEIGHTS`: the best instance this CPU can run.
#[inline(always)]
fn forward_tile_best<const WEIGHTS: bool>(
    b: &Binned,
    tile: usize,
    out: &mut TileOut,
    acc: Option<(&Accum, &mut [f32])>,
) {
    #[cfg(target_arch = "x86_64")]
    if transsplat_scene::cpu::has_avx512() {
        // SAFETY: the CPU supports AVX2, FMA and AVX-512 (checked above).
        return unsafe { forward_tile_avx512::<WEIGHTS>(b, tile, out, acc) };
    }
    #[cfg(target_arch = "x86_64")]
    if transsplat_scene::cpu::has_avx2() {
        // SAFETY: the CPU supports AVX2 and FMA (checked above).
        return unsafe { forward_tile_avx2::<WEIGHTS>(b, tile, out, acc) };
    }
    forward_tile_impl::<WEIGHTS>(b, tile, out, acc)
}

/// [`backward_tile`] for one value of `FEATURES`: the best instance this CPU can run.
#[inline(always)]
fn backward_tile_best<const FEATURES: bool>(
    b: &Binned,
    tile: usize,
    st: &ForwardState,
    g: &PixelGrads,
    buf: &mut [f32],
) {
    #[cfg(target_arch = "x86_64")]
    if transsplat_scene::cpu::has_avx512() {
        // SAFETY: the CPU supports AVX2, FMA and AVX-512 (checked above).
        return unsafe { backward_tile_avx512::<FEATURES>(b, tile, st, g, buf) };
    }
    #[cfg(target_arch = "x86_64")]
    if transsplat_scene::cpu::has_avx2() {
        // SAFETY: the CPU supports AVX2 and FMA (checked above).
        return unsafe { backward_tile_avx2::<FEATURES>(b, tile, st, g, buf) };
    }
    backward_tile_impl::<false, FEATURES>(b, tile, st, g, buf)
}

/// Forward pass over one tile. Forward and backward always take the same code
/// path so that their skip and stop decisions agree bit for bit.
pub fn forward_tile(b: &Binned, tile: usize, out: &mut TileOut, acc: Option<(&Accum, &mut [f32])>) {
    // The plain render (no features, no sums: training) keeps no per-lane weights.
    if b.num_features > 0 || acc.is_some() {
        forward_tile_best::<true>(b, tile, out, acc)
    } else {
        forward_tile_best::<false>(b, tile, out, acc)
    }
}

/// Backward pass over one tile, accumulating per-splat gradients into `buf`
/// (layout [`grad_stride`]).
pub fn backward_tile(b: &Binned, tile: usize, st: &ForwardState, g: &PixelGrads, buf: &mut [f32]) {
    if b.num_features > 0 {
        backward_tile_best::<true>(b, tile, st, g, buf)
    } else {
        backward_tile_best::<false>(b, tile, st, g, buf)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::project::View;
    use crate::Splats;
    use transsplat_scene::{Camera, Gaussians};

    type ForwardFn = fn(&Binned, usize, &mut TileOut, Option<(&Accum, &mut [f32])>);
    type BackwardFn = fn(&Binned, usize, &ForwardState, &PixelGrads, &mut [f32]);

    /// The instances of both passes this CPU can run, the plain one first.
    fn instances<const W: bool, const F: bool>() -> Vec<(&'static str, ForwardFn, BackwardFn)> {
        let mut all: Vec<(&'static str, ForwardFn, BackwardFn)> = vec![(
            "plain",
            |b, t, o, a| forward_tile_impl::<W>(b, t, o, a),
            |b, t, st, g, buf| backward_tile_impl::<false, F>(b, t, st, g, buf),
        )];
        #[cfg(target_arch = "x86_64")]
        {
            if transsplat_scene::cpu::has_avx2() {
                all.push((
                    "avx2",
                    // SAFETY: the CPU has AVX2 and FMA (checked above).
                    |b, t, o, a| unsafe { forward_tile_avx2::<W>(b, t, o, a) },
                    |b, t, st, g, buf| unsafe { backward_tile_avx2::<F>(b, t, st, g, buf) },
                ));
            }
            if transsplat_scene::cpu::has_avx512() {
                all.push((
                    "avx512",
                    // SAFETY: the CPU has AVX2, FMA and AVX-512 (checked above).
                    |b, t, o, a| unsafe { forward_tile_avx512::<W>(b, t, o, a) },
                    |b, t, st, g, buf| unsafe { backward_tile_avx512::<F>(b, t, st, g, buf) },
                ));
            }
        }
        all
    }

    /// Runs every instance of both passes on every tile of `b` (with `accum`'s sums when
    /// given) and checks each output against the plain instance's, bit for bit.
    fn compare_instances<const W: bool, const F: bool>(b: &Binned, accum: Option<&Accum>) {
        let (w, h, f) = (b.width, b.height, b.num_features);
        let tiles = b.tiles_x * b.tiles_y;
        let acc_len = accum.map_or(0, |a| b.splats.len() * a.stride());
        // Whole-image forward state, the per-tile outputs and the sums of one instance.
        let forward = |fwd: ForwardFn| {
            let (mut final_t, mut last) = (vec![0.0f32; w * h], vec![0u32; w * h]);
            let (mut outs, mut sums) = (Vec::new(), vec![0.0f32; acc_len]);
            for tile in 0..tiles {
                let mut o = TileOut::new(f);
                fwd(b, tile, &mut o, accum.map(|a| (a, &mut sums[..])));
                let (x0, y0, x1, y1) = b.tile_rect(tile);
                for y in y0..y1 {
                    for x in x0..x1 {
                        final_t[y * w + x] = o.t[y - y0][x - x0];
                        last[y * w + x] = o.last[y - y0][x - x0];
                    }
                }
                outs.push(o);
            }
            (final_t, last, outs, sums)
        };
        let all = instances::<W, F>();
        let (final_t, last, want_outs, want_sums) = forward(all[0].1);
        let wave = |k: usize, a: f32| ((k as f32) * a).sin();
        let rgb: Vec<f32> = (0..w * h * 3).map(|k| wave(k, 0.37)).collect();
        let alpha: Vec<f32> = (0..w * h).map(|k| wave(k, 0.11)).collect();
        let depth: Vec<f32> = (0..w * h).map(|k| 0.1 * wave(k, 0.23)).collect();
        let features: Vec<f32> = (0..w * h * f).map(|k| wave(k, 0.61)).collect();
        let pg = PixelGrads { rgb: &rgb, alpha: &alpha, depth: &depth, features: &features };
        let st = ForwardState { final_t: &final_t, last: &last, background: [0.2, 0.5, 0.1] };
        let backward = |bwd: BackwardFn| {
            let mut buf = vec![0.0f32; b.splats.len() * grad_stride(f)];
            for tile in 0..tiles {
                bwd(b, tile, &st, &pg, &mut buf);
            }
            buf
        };
        let want_grads = backward(all[0].2);
        let blended = want_outs.iter().flat_map(|o| o.last.iter().flatten()).filter(|&&l| l > 0).count();
        assert!(b.splats.len() > 300 && blended > w * h / 2, "a scene worth comparing on");
        assert!(want_grads.iter().filter(|v| **v != 0.0).count() > 1000, "gradients reached the splats");
        assert!(accum.is_none() || want_sums.iter().any(|&v| v != 0.0), "sums were gathered");
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let first_diff =
            |got: &[f32], want: &[f32]| (0..want.len()).find(|&k| got[k].to_bits() != want[k].to_bits());
        for (name, fwd, bwd) in &all[1..] {
            let (_, _, outs, sums) = forward(*fwd);
            for (tile, (got, o)) in outs.iter().zip(&want_outs).enumerate() {
                let planes = |t: &TileOut| {
                    let mut v: Vec<f32> = t.t.as_flattened().to_vec();
                    t.rgb.iter().chain([&t.depth]).chain(&t.feat).for_each(|p| v.extend(p.as_flattened()));
                    v
                };
                assert_eq!(bits(&planes(got)), bits(&planes(o)), "{name} forward planes, tile {tile}");
                assert_eq!(got.last, o.last, "{name} forward last, tile {tile}");
            }
            assert_eq!(first_diff(&sums, &want_sums), None, "{name} forward sums");
            assert_eq!(first_diff(&backward(*bwd), &want_grads), None, "{name} backward");
        }
    }

    /// Every compiled instance of the tile passes this CPU can run (the plain one, AVX2,
    /// AVX-512) gives the plain one's bits, forward and backward, on a scene of narrow and
    /// wide, round and slanted, faint and opaque splats over several tiles: as a plain
    /// render (training), and with features and the splat-back sums (the edit's passes).
    #[test]
    fn every_compiled_instance_gives_the_bits_of_the_plain_one() {
        let mut g = Gaussians { sh_degree: 0, ..Default::default() };
        for k in 0..600 {
            let f = k as f32;
            g.means.push([(f * 0.37).sin() * 1.2, (f * 0.53).cos() * 0.9, 3.0 + 1.5 * (f * 0.29).sin()]);
            let s = -3.6 + 2.6 * (0.5 + 0.5 * (f * 0.71).sin());
            g.log_scales.push([s, s - 0.8 * (f * 0.13).cos().abs(), s - 0.3]);
            g.rotations.push([1.0, 0.6 * (f * 0.3).sin(), 0.4 * (f * 0.17).cos(), 0.5 * (f * 0.23).sin()]);
            g.opacity_logits.push(3.0 * (f * 0.41).cos());
            g.sh.extend([0.9 * (f * 0.11).sin(), 0.7 * (f * 0.19).cos(), 0.5 * (f * 0.07).sin()]);
        }
        let cam = Camera::pinhole("c", 72, 56, 60.0);
        let view = View::new(&cam);
        compare_instances::<false, false>(&crate::bin::bin(&Splats::new(&g), &view), None);
        let feats: Vec<f32> = (0..g.len() * 2).map(|k| (k as f32 * 0.29).cos()).collect();
        let splats = Splats { features: &feats, num_features: 2, ..Splats::new(&g) };
        let image: Vec<f32> = (0..72 * 56 * 2).map(|k| 0.5 + 0.5 * (k as f32 * 0.13).sin()).collect();
        let accum = Accum { image: &image, channels: 2, capped: 1 };
        compare_instances::<true, true>(&crate::bin::bin(&splats, &view), Some(&accum));
    }

    #[test]
    fn lane_sums_are_each_rows_sum_in_order_to_the_bit() {
        // Values whose sum depends on the order of addition.
        let rows: [[f32; HALF]; HALF] = std::array::from_fn(|k| {
            std::array::from_fn(|x| ((k * 8 + x) as f32 * 0.37).sin() * 10f32.powi((x % 5) as i32 - 2))
        });
        let want: [f32; HALF] = std::array::from_fn(|k| rows[k].iter().sum());
        for (k, w) in want.iter().enumerate() {
            let mut s = rows[k][0];
            for v in &rows[k][1..] {
                s += v;
            }
            assert_eq!(s.to_bits(), w.to_bits(), "row {k}: a sum in order");
        }
        let plain = lane_sums::<false>(&rows);
        assert_eq!(plain.map(f32::to_bits), want.map(f32::to_bits));
        #[cfg(target_arch = "x86_64")]
        if transsplat_scene::cpu::has_avx2() {
            let fast = lane_sums::<true>(&rows);
            assert_eq!(fast.map(f32::to_bits), want.map(f32::to_bits), "transposed");
        }
    }
}
