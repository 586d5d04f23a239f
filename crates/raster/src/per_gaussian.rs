//! The backward's per-Gaussian pass: from each reached splat's accumulated gradients
//! (one row of the tile pass's accumulator) through [`project_backward`] to the
//! Gaussian's parameter gradients, added into its rows.
//!
//! The projection's backward is some 1,500 instructions a Gaussian, so the reached
//! Gaussians of a run of rows are taken eight at a time, one per lane of [`F8`]: the same
//! operations in the same order per lane, so every Gaussian's gradients have the bits the
//! one-at-a-time `project_backward` gives (a run's last group of fewer than eight fills
//! its spare lanes with a copy of its last Gaussian, whose results are dropped). Rows are walked
//! in index order, so parameter reads and gradient writes stream; the accumulator row (in
//! depth order) is the random read, fetched ahead with the SH rows. With the arithmetic
//! eight-wide, the pass waits on memory about as long as it computes (docs/method.md
//! M10 item 10).

use crate::kernel::{self, slot};
use crate::lanes::F8;
use crate::project::{project_backward, ClampGrad, Splat2dGrads, View};
use crate::Splats;
use transsplat_scene::cpu::prefetch_bytes;

/// Rows per unit of parallel work.
pub(crate) const ROWS: usize = 2048;

/// [`Run::at`] of a Gaussian no pixel's gradient reached.
pub(crate) const NOT_REACHED: u32 = u32::MAX;

/// What every row of the pass reads.
pub(crate) struct Inputs<'a> {
    pub splats: &'a Splats<'a>,
    pub view: &'a View,
    /// The accumulator, `stride` floats per splat in depth order.
    pub acc: &'a [f32],
    pub stride: usize,
    pub clamp: ClampGrad,
}

/// The gradient rows of one run of Gaussians (`first..first + at.len()`), and which of
/// them were reached.
pub(crate) struct Run<'a> {
    pub first: usize,
    /// Each Gaussian's accumulator row (its position in depth order), or [`NOT_REACHED`].
    pub at: &'a [u32],
    pub means: &'a mut [[f32; 3]],
    pub log_scales: &'a mut [[f32; 3]],
    pub rotations: &'a mut [[f32; 4]],
    pub opacity_logits: &'a mut [f32],
    /// `kc` values a row (every coefficient of the SH layout).
    pub sh: &'a mut [f32],
    /// `num_features` values a row (empty when there are none).
    pub features: &'a mut [f32],
    pub means2d: &'a mut [[f32; 2]],
}

/// Adds the gradients of every reached Gaussian of `run`, compiled for AVX2 when the CPU
/// has it (the same results: no fused operations are formed); returns those Gaussians,
/// ascending.
pub(crate) fn run(avx2: bool, inp: &Inputs, run: Run) -> Vec<u32> {
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        // SAFETY: the CPU has AVX2 and FMA (checked by the caller at run time).
        return unsafe { run_avx2(inp, run) };
    }
    let _ = avx2;
    run_any(inp, run)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn run_avx2(inp: &Inputs, run: Run) -> Vec<u32> {
    run_any(inp, run)
}

#[inline(always)]
fn run_any(inp: &Inputs, mut run: Run) -> Vec<u32> {
    let s = inp.splats;
    let kc = crate::sh_coeffs(s.sh_degree) * 3;
    let mut reached = [0u16; ROWS];
    let mut count = 0;
    for (k, &j) in run.at.iter().enumerate() {
        reached[count] = k as u16;
        count += (j != NOT_REACHED) as usize;
    }
    let reached = &reached[..count];
    // The reached rows are scattered (a third of them at 1M Gaussians, 256²), so the
    // hardware cannot guess the next one: fetch the SH rows (read and written) and the
    // accumulator row of the Gaussians three groups ahead.
    const AHEAD: usize = 24;
    let (sh_at, gsh_at, acc_at) =
        (s.sh.as_ptr() as usize, run.sh.as_ptr() as usize, inp.acc.as_ptr() as usize);
    for (gi, group) in reached.chunks(8).enumerate() {
        for &k in reached.iter().skip(gi * 8 + AHEAD).take(8) {
            let (k, i) = (k as usize, run.first + k as usize);
            prefetch_bytes(sh_at + i * kc * 4, kc * 4);
            prefetch_bytes(gsh_at + k * kc * 4, kc * 4);
            prefetch_bytes(acc_at + run.at[k] as usize * inp.stride * 4, inp.stride * 4);
        }
        eight(inp, &mut run, group);
    }
    reached.iter().map(|&k| (run.first + k as usize) as u32).collect()
}

/// The accumulator row of row `k` of `run`.
#[inline(always)]
fn acc_row<'a>(inp: &Inputs<'a>, run: &Run, k: usize) -> &'a [f32] {
    let j = run.at[k] as usize;
    &inp.acc[j * inp.stride..(j + 1) * inp.stride]
}

/// The gradients of up to eight rows of `run` (`group`, local indices) at once, one per
/// lane (a group of fewer repeats its last row in the spare lanes, whose results are
/// dropped): the inputs gathered into lanes, each lane's results added to its row.
#[inline(always)]
fn eight(inp: &Inputs, run: &mut Run, group: &[u16]) {
    let s = inp.splats;
    let rows: [usize; 8] = std::array::from_fn(|l| group[l.min(group.len() - 1)] as usize);
    let a: [&[f32]; 8] = rows.map(|k| acc_row(inp, run, k));
    let sg1: [Splat2dGrads; 8] = a.map(kernel::splat_grads);
    let lanes = |f: fn(&Splat2dGrads) -> f32| F8::from_fn(|l| f(&sg1[l]));
    let sg = Splat2dGrads {
        xy: [lanes(|g| g.xy[0]), lanes(|g| g.xy[1])],
        conic: [lanes(|g| g.conic[0]), lanes(|g| g.conic[1]), lanes(|g| g.conic[2])],
        opacity: lanes(|g| g.opacity),
        color: [lanes(|g| g.color[0]), lanes(|g| g.color[1]), lanes(|g| g.color[2])],
        depth: lanes(|g| g.depth),
    };
    let mut sh = [F8::default(); 48];
    let p = s.params8(rows.map(|k| run.first + k), &mut sh);
    let nsh = p.sh.len();
    let mut vsh = [F8::default(); 48];
    let gg = project_backward(inp.view, &p, &sg, &mut vsh[..nsh], inp.clamp);
    let (kc, f) = (crate::sh_coeffs(s.sh_degree) * 3, s.num_features);
    for (l, &k) in rows.iter().enumerate().take(group.len()) {
        for c in 0..3 {
            run.means[k][c] += gg.mean[c].0[l];
            run.log_scales[k][c] += gg.log_scale[c].0[l];
        }
        for c in 0..4 {
            run.rotations[k][c] += gg.quat[c].0[l];
        }
        run.opacity_logits[k] += gg.opacity_logit.0[l];
        for (d, v) in run.sh[k * kc..k * kc + nsh].iter_mut().zip(&vsh) {
            *d += v.0[l];
        }
        for (d, v) in run.features[k * f..(k + 1) * f].iter_mut().zip(&a[l][slot::FEATURES..]) {
            *d += v;
        }
        run.means2d[k][0] += sg1[l].xy[0];
        run.means2d[k][1] += sg1[l].xy[1];
    }
}
