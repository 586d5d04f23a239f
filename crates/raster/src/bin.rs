//! Projection of every Gaussian, front-to-back depth sort and tile binning.
//!
//! Visible Gaussians are sorted once by depth (radix sort on the float bits, which
//! are monotonic for positive depths) and then distributed over 16×16 tiles by a
//! counting sort that keeps depth order, so every tile list is front to back.

use crate::lanes::Real;
use crate::lanes::F8;
use crate::project::{cull, geometry, sigmoid, view_colour, Splat2d, View};
use crate::Splats;
use rayon::prelude::*;

/// Tile edge in pixels.
pub const TILE: usize = 16;

/// A projected Gaussian packed for the compositing loops.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C)]
pub struct Packed {
    pub x: f32,
    pub y: f32,
    pub a: f32,
    pub b: f32,
    pub c: f32,
    pub opacity: f32,
    pub color: [f32; 3],
    pub depth: f32,
    /// Half-extents (pixels) of the box outside which α < 1/255 for sure: the
    /// opacity-aware bound min(3.33, √(2 ln(255 o))) · √diag Σ₂, slightly inflated.
    pub ex: f32,
    pub ey: f32,
    /// σ above which α < 1/255: ln(255 o), slightly inflated.
    pub thr: f32,
}

/// The tight support of splats (lane-wise): (thr, ex, ey), where `thr > 0` says the
/// splat can blend somewhere, and then α < 1/255 outside the half-extents (ex, ey)
/// (pixels) and wherever σ > thr. Used only to skip work: every pair it excludes has
/// α < 1/255 and would be skipped by the compositing rule anyway.
#[inline(always)]
fn support<T: Real>(conic: [T; 3], opacity: T) -> (T, T, T) {
    let c = T::from;
    let thr = (c(255.0) * opacity).ln();
    let inflated = thr * c(1.0 + 1e-4) + c(1e-4);
    let [a, b, cc] = conic;
    let det = a * cc - b * b;
    let ext = (c(2.0) * inflated).sqrt().min(c(crate::project::EXTENT));
    let ex = ext * (cc / det).sqrt() * c(1.0 + 1e-4) + c(1e-3);
    let ey = ext * (a / det).sqrt() * c(1.0 + 1e-4) + c(1e-3);
    // Where ln(255 o) is not positive (or NaN) the splat blends nowhere: thr = 0 says so.
    (T::select(c(0.0).lt(thr), inflated, c(0.0)), ex, ey)
}

fn pack(s: &Splat2d, ex: f32, ey: f32, thr: f32) -> Packed {
    Packed {
        x: s.xy[0],
        y: s.xy[1],
        a: s.conic[0],
        b: s.conic[1],
        c: s.conic[2],
        opacity: s.opacity,
        color: s.color,
        depth: s.depth,
        ex,
        ey,
        thr,
    }
}

/// Everything the compositing passes need for one view.
#[derive(Clone, Debug, Default)]
pub struct Binned {
    pub width: usize,
    pub height: usize,
    pub tiles_x: usize,
    pub tiles_y: usize,
    /// Number of Gaussians in the scene.
    pub num_gaussians: usize,
    /// Global id of each Gaussian that can blend somewhere, front to back.
    pub ids: Vec<u32>,
    /// Packed splats in the same (depth) order.
    pub splats: Vec<Packed>,
    /// Extra features in depth order, `num_features` per splat.
    pub feats: Vec<f32>,
    pub num_features: usize,
    /// Per-Gaussian (global id) 2D mean, depth and radius; radius (0, 0) = culled.
    pub means2d: Vec<[f32; 2]>,
    pub depths: Vec<f32>,
    pub radii: Vec<[u32; 2]>,
    /// Tile `t` holds `lists[offsets[t]..offsets[t+1]]`, indices into `splats`.
    pub offsets: Vec<u32>,
    pub lists: Vec<u32>,
}

impl Binned {
    /// The pixel rectangle of tile `t`: (x0, y0, x1, y1), exclusive ends.
    pub fn tile_rect(&self, t: usize) -> (usize, usize, usize, usize) {
        let (tx, ty) = (t % self.tiles_x, t / self.tiles_x);
        let (x0, y0) = (tx * TILE, ty * TILE);
        (x0, y0, (x0 + TILE).min(self.width), (y0 + TILE).min(self.height))
    }

    /// The depth-ordered splat indices of tile `t`.
    pub fn tile_list(&self, t: usize) -> &[u32] {
        &self.lists[self.offsets[t] as usize..self.offsets[t + 1] as usize]
    }

    /// Total number of (tile, Gaussian) pairs.
    pub fn intersections(&self) -> usize {
        self.lists.len()
    }
}

fn tile_span(p: &Packed, tiles_x: usize, tiles_y: usize) -> (usize, usize, usize, usize) {
    let t = TILE as f32;
    // Floor and ceiling by conversion (x as usize truncates, and saturates below 0):
    // libm's floorf / ceilf are calls on baseline x86-64.
    let lo = |v: f32| (v / t).max(0.0) as usize;
    let hi = |v: f32| {
        let q = (v / t).max(0.0);
        let c = q as usize;
        c + ((c as f32) < q) as usize
    };
    let (x1, y1) = (hi(p.x + p.ex).min(tiles_x), hi(p.y + p.ey).min(tiles_y));
    // A splat inside the culling radius can have its opacity-aware support wholly
    // off the image (x0 past the last tile): an empty span, never a reversed one.
    (lo(p.x - p.ex).min(x1), lo(p.y - p.ey).min(y1), x1, y1)
}

/// Calls `f(tile)` for every tile of `p`'s span.
#[inline(always)]
fn for_each_tile(p: &Packed, tiles_x: usize, tiles_y: usize, mut f: impl FnMut(usize)) {
    let (x0, y0, x1, y1) = tile_span(p, tiles_x, tiles_y);
    for ty in y0..y1 {
        for t in ty * tiles_x + x0..ty * tiles_x + x1 {
            f(t);
        }
    }
}

/// Gaussians per projection chunk (a power of two: sort values are chunk << bits | index).
const PCH_BITS: usize = 12;
const PCH: usize = 1 << PCH_BITS;

/// One chunk of the per-Gaussian outputs of the projection pass.
struct Slots<'a> {
    means2d: &'a mut [[f32; 2]],
    depths: &'a mut [f32],
    radii: &'a mut [[u32; 2]],
}

/// Projects Gaussians `i0..i0 + out.depths.len()`: writes their 2D means, depths and
/// radii and returns the ids and packed splats of those that can blend somewhere.
#[inline(always)]
fn project_chunk(splats: &Splats, view: &View, i0: usize, out: Slots) -> (Vec<u32>, Vec<Packed>) {
    let len = out.depths.len();
    let (mut ids, mut pk) = (Vec::with_capacity(len), Vec::with_capacity(len));
    // Eight at a time, one per lane (the same bits as one at a time, crate::lanes; a
    // last group of fewer repeats its last Gaussian in the spare lanes), then the culls
    // per Gaussian.
    for k0 in (0..len).step_by(8) {
        let idx: [usize; 8] = std::array::from_fn(|l| i0 + (k0 + l).min(len - 1));
        let mut sh = [F8::default(); 48];
        let p = splats.params8(idx, &mut sh);
        let g = geometry(view, &p);
        let (color, opacity) = (view_colour(view, &p), sigmoid(p.opacity_logit));
        let (thr, ex, ey) = support(g.conic, opacity);
        for l in 0..(len - k0).min(8) {
            let k = k0 + l;
            let Some((xy, depth, r)) = cull(view, &g.lane(l)) else { continue };
            (out.means2d[k], out.depths[k], out.radii[k]) = (xy, depth, r);
            if thr.0[l] > 0.0 {
                ids.push((i0 + k) as u32);
                let s = Splat2d {
                    xy,
                    conic: g.conic.map(|v| v.0[l]),
                    opacity: opacity.0[l],
                    color: color.map(|v| v.0[l]),
                    depth,
                };
                pk.push(pack(&s, ex.0[l], ey.0[l], thr.0[l]));
            }
        }
    }
    (ids, pk)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn project_chunk_avx2(splats: &Splats, view: &View, i0: usize, out: Slots) -> (Vec<u32>, Vec<Packed>) {
    project_chunk(splats, view, i0, out)
}

/// [`project_chunk`], compiled for AVX2 + FMA when the CPU has them (same results: no
/// fused operations are formed, only the instruction encoding and rounding calls change).
fn project_chunk_dispatch(
    avx2: bool,
    splats: &Splats,
    view: &View,
    i0: usize,
    out: Slots,
) -> (Vec<u32>, Vec<Packed>) {
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        // SAFETY: the CPU has AVX2 and FMA (checked by the caller at run time).
        return unsafe { project_chunk_avx2(splats, view, i0, out) };
    }
    let _ = avx2;
    project_chunk(splats, view, i0, out)
}

/// Projects, sorts and bins the splats for `view`.
pub fn bin(splats: &Splats, view: &View) -> Binned {
    let n = splats.len();
    let prof = Profile::start();
    let (width, height) = (view.width as usize, view.height as usize);
    let tiles_x = width.div_ceil(TILE);
    let tiles_y = height.div_ceil(TILE);
    // One pass in index order: per-Gaussian outputs written in place, the splats that
    // can blend somewhere packed compactly (chunk by chunk, so still in index order).
    let mut means2d = vec![[0.0f32; 2]; n];
    let mut depths = vec![0.0f32; n];
    let mut radii = vec![[0u32; 2]; n];
    let avx2 = transsplat_scene::cpu::has_avx2();
    let parts: Vec<(Vec<u32>, Vec<Packed>)> =
        (means2d.par_chunks_mut(PCH), depths.par_chunks_mut(PCH), radii.par_chunks_mut(PCH))
            .into_par_iter()
            .enumerate()
            .map(|(c, (means2d, depths, radii))| {
                project_chunk_dispatch(avx2, splats, view, c * PCH, Slots { means2d, depths, radii })
            })
            .collect();
    prof.lap("project");
    // Stable sort by depth; ties keep index order, as the slots are in index order.
    // The value is the slot (chunk << PCH_BITS | position in the chunk).
    let mut keys: Vec<(u32, u32)> = Vec::with_capacity(parts.iter().map(|p| p.0.len()).sum());
    for (c, (_, pk)) in parts.iter().enumerate() {
        keys.extend(pk.iter().enumerate().map(|(k, p)| (p.depth.to_bits(), ((c << PCH_BITS) | k) as u32)));
    }
    radix_sort(&mut keys);
    prof.lap("keys+sort");
    let slot = |v: u32| (v as usize >> PCH_BITS, v as usize & (PCH - 1));
    let (ids, packed): (Vec<u32>, Vec<Packed>) = keys
        .par_iter()
        .with_min_len(4096)
        .map(|k| {
            let (c, i) = slot(k.1);
            (parts[c].0[i], parts[c].1[i])
        })
        .unzip();
    drop((keys, parts));
    prof.lap("gather");
    let f = splats.num_features;
    let mut feats = vec![0.0f32; ids.len() * f];
    if f > 0 {
        feats.par_chunks_mut(f).zip(ids.par_iter()).for_each(|(dst, &i)| {
            dst.copy_from_slice(&splats.features[i as usize * f..(i as usize + 1) * f]);
        });
    }

    // Counting sort into tiles, in parallel over chunks of the depth order.
    let num_tiles = tiles_x * tiles_y;
    let chunk = packed.len().div_ceil(rayon::current_num_threads() * 4).max(4096);
    let counts: Vec<Vec<u32>> = packed
        .par_chunks(chunk)
        .map(|ch| {
            let mut c = vec![0u32; num_tiles];
            for p in ch {
                for_each_tile(p, tiles_x, tiles_y, |t| c[t] += 1);
            }
            c
        })
        .collect();
    prof.lap("count");
    // starts[c][t] = offset of chunk c's first entry in tile t.
    let mut offsets = vec![0u32; num_tiles + 1];
    let mut starts = vec![vec![0u32; num_tiles]; counts.len()];
    let mut acc = 0u32;
    for t in 0..num_tiles {
        offsets[t] = acc;
        for (c, cnt) in counts.iter().enumerate() {
            starts[c][t] = acc;
            // The lists are indexed by u32: refuse (rather than wrap and write out of
            // bounds) a view with 2^32 tile–Gaussian pairs or more (16 GiB of lists).
            acc = acc.checked_add(cnt[t]).expect(
                "more than 2^32 tile-Gaussian pairs in one view: the Gaussians are too large or too many for this image size",
            );
        }
    }
    offsets[num_tiles] = acc;
    let mut lists = vec![0u32; acc as usize];
    let out = crate::par::SharedMut(lists.as_mut_ptr());
    packed.par_chunks(chunk).zip(starts.into_par_iter()).enumerate().for_each(|(c, (ch, mut start))| {
        let base = (c * chunk) as u32;
        for (k, p) in ch.iter().enumerate() {
            for_each_tile(p, tiles_x, tiles_y, |t| {
                let s = &mut start[t];
                // SAFETY: each (chunk, tile) owns the disjoint range reserved by the prefix sum
                // (the same tiles are visited as when counting).
                unsafe { *out.get().add(*s as usize) = base + k as u32 };
                *s += 1;
            });
        }
    });
    prof.lap("lists");

    Binned {
        width,
        height,
        tiles_x,
        tiles_y,
        num_gaussians: n,
        ids,
        splats: packed,
        feats,
        num_features: f,
        means2d,
        depths,
        radii,
        offsets,
        lists,
    }
}

/// Stage timings on stderr when `TRANSSPLAT_RASTER_PROFILE` is set.
pub(crate) struct Profile(Option<std::cell::Cell<std::time::Instant>>);

impl Profile {
    pub(crate) fn start() -> Self {
        Profile(
            std::env::var_os("TRANSSPLAT_RASTER_PROFILE")
                .map(|_| std::cell::Cell::new(std::time::Instant::now())),
        )
    }
    pub(crate) fn lap(&self, what: &str) {
        if let Some(t) = &self.0 {
            let now = std::time::Instant::now();
            eprintln!("raster-profile: {what} {:.2} ms", (now - t.get()).as_secs_f64() * 1e3);
            t.set(now);
        }
    }
}

/// Stable LSD radix sort of (key, value) pairs by key, 11 bits per pass.
fn radix_sort(v: &mut Vec<(u32, u32)>) {
    let mut tmp = vec![(0u32, 0u32); v.len()];
    for pass in 0..3 {
        let shift = pass * 11;
        let mut count = vec![0usize; 2049];
        for &(k, _) in v.iter() {
            count[((k >> shift) & 0x7ff) as usize + 1] += 1;
        }
        if count[1..].contains(&v.len()) {
            continue;
        }
        for i in 0..2048 {
            count[i + 1] += count[i];
        }
        for &e in v.iter() {
            let b = ((e.0 >> shift) & 0x7ff) as usize;
            tmp[count[b]] = e;
            count[b] += 1;
        }
        std::mem::swap(v, &mut tmp);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::project::project;
    use transsplat_scene::{Camera, Gaussians};

    #[test]
    fn eight_lanes_project_each_gaussian_as_one_at_a_time() {
        // 61 Gaussians (seven groups of eight and a remainder): some behind the camera,
        // off the image, faint (no support), dark in some channel; every SH degree.
        let cam = Camera::pinhole("c", 64, 48, 40.0);
        let view = View::new(&cam);
        let wave = |k: usize, a: f32| (k as f32 * a).sin();
        let n = 61;
        for degree in 0..=3u32 {
            let g = Gaussians {
                means: (0..n)
                    .map(|i| [6.0 * wave(i, 0.37), 4.0 * wave(i, 0.91), 3.0 + 4.0 * wave(i, 1.3)])
                    .collect(),
                log_scales: (0..n)
                    .map(|i| [wave(i, 0.2) - 2.0, wave(i, 0.5) - 1.0, wave(i, 0.8) - 3.0])
                    .collect(),
                rotations: (0..n)
                    .map(|i| [1.0 + wave(i, 0.3), wave(i, 0.6), wave(i, 1.1), wave(i, 1.7)])
                    .collect(),
                opacity_logits: (0..n).map(|i| 7.0 * wave(i, 0.45)).collect(),
                sh_degree: 3,
                sh: (0..n * 48).map(|k| 2.0 * wave(k, 0.71)).collect(),
                ..Default::default()
            };
            let splats = Splats { active_sh_degree: degree, ..Splats::new(&g) };
            let (mut means2d, mut depths, mut radii) = (vec![[0.0; 2]; n], vec![0.0; n], vec![[0; 2]; n]);
            let slots = Slots { means2d: &mut means2d, depths: &mut depths, radii: &mut radii };
            let (ids, packed) = project_chunk(&splats, &view, 0, slots);
            let (mut want_ids, mut culled, mut faint) = (Vec::new(), 0, 0);
            for i in 0..n {
                let Some((s, r)) = project(&view, &splats.params(i)) else {
                    culled += 1;
                    assert_eq!((means2d[i], depths[i], radii[i]), ([0.0; 2], 0.0, [0; 2]), "Gaussian {i}");
                    continue;
                };
                assert_eq!((means2d[i], depths[i], radii[i]), (s.xy, s.depth, r), "Gaussian {i}");
                let (thr, ex, ey) = support(s.conic, s.opacity);
                if !(thr > 0.0) {
                    faint += 1;
                    continue;
                }
                let (got, want) = (packed[want_ids.len()], pack(&s, ex, ey, thr));
                let bits = |p: &Packed| {
                    [
                        p.x, p.y, p.a, p.b, p.c, p.opacity, p.color[0], p.color[1], p.color[2], p.depth,
                        p.ex, p.ey, p.thr,
                    ]
                    .map(f32::to_bits)
                };
                assert_eq!(bits(&got), bits(&want), "Gaussian {i}, degree {degree}");
                want_ids.push(i as u32);
            }
            assert_eq!(ids, want_ids, "degree {degree}");
            assert!(culled > 0 && faint > 0 && want_ids.len() > 8, "{culled} culled, {faint} faint");
        }
    }

    #[test]
    fn radix_sort_is_a_stable_sort() {
        let mut v: Vec<(u32, u32)> =
            (0..5000u32).map(|i| ((i * 2_654_435_761) % 977 * 4_400_000, i)).collect();
        let mut want = v.clone();
        want.sort_by_key(|e| e.0);
        super::radix_sort(&mut v);
        assert_eq!(v, want);
    }
}
