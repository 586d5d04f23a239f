//! The backward's per-Gaussian pass: from each reached splat's accumulated gradients
//! (one row of the tile pass's accumulator) through [`project_backward`] to the
//! Gaussian's parameter gradients, added into its rows.
//!
//! The projection's backward is some 1,500 instructions a Gaussian, so the reached
//! Gaussians of a run of rows are taken eight at a time, one per lane of [`F8`]: the same
//! operations in the same order per lane, so every Gaussian's gradients have the bits the
//! one-at-a-time path gives (the remainder of a run goes one at a time). Rows are walked
//! in index order, so parameter reads and gradient writes stream; the accumulator row (in
//! depth order) is the random read, fetched ahead with the SH rows. With the arithmetic
//! eight-wide, the pass waits on memory about as long as it computes (docs/method.md
//! M10 item 10).

use crate::kernel::{self, slot};
use crate::lanes::F8;
use crate::project::{project_backward, ClampGrad, GaussianParams, Splat2dGrads, View};
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
        match <&[u16; 8]>::try_from(group) {
            Ok(group) => eight(inp, &mut run, group),
            Err(_) => group.iter().for_each(|&k| one(inp, &mut run, k as usize)),
        }
    }
    reached.iter().map(|&k| (run.first + k as usize) as u32).collect()
}

/// The accumulator row of row `k` of `run`.
#[inline(always)]
fn acc_row<'a>(inp: &Inputs<'a>, run: &Run, k: usize) -> &'a [f32] {
    let j = run.at[k] as usize;
    &inp.acc[j * inp.stride..(j + 1) * inp.stride]
}

/// The gradients of row `k` of `run` alone.
#[inline(always)]
fn one(inp: &Inputs, run: &mut Run, k: usize) {
    let i = run.first + k;
    let a = acc_row(inp, run, k);
    let sg = kernel::splat_grads(a);
    let mut vsh = [0.0f32; 48];
    let p = inp.splats.params(i);
    let nsh = crate::sh_coeffs(p.active_degree) * 3;
    let gg = project_backward(inp.view, &p, &sg, &mut vsh[..nsh], inp.clamp);
    let g = Grads1 { mean: gg.mean, log_scale: gg.log_scale, quat: gg.quat, opacity_logit: gg.opacity_logit };
    add_row(inp, run, k, &g, &vsh[..nsh], a, sg.xy);
}

/// One Gaussian's gradients (a lane of the eight-wide result, or the scalar one).
struct Grads1 {
    mean: [f32; 3],
    log_scale: [f32; 3],
    quat: [f32; 4],
    opacity_logit: f32,
}

/// Adds one Gaussian's gradients into row `k` of `run`: the parameters', the SH
/// coefficients' (`vsh`, the active ones), the features' (from its accumulator row `a`)
/// and the 2D mean's (`xy`, for the densification statistics).
#[inline(always)]
fn add_row(inp: &Inputs, run: &mut Run, k: usize, g: &Grads1, vsh: &[f32], a: &[f32], xy: [f32; 2]) {
    let (kc, f) = (crate::sh_coeffs(inp.splats.sh_degree) * 3, inp.splats.num_features);
    for c in 0..3 {
        run.means[k][c] += g.mean[c];
        run.log_scales[k][c] += g.log_scale[c];
    }
    for (r, q) in run.rotations[k].iter_mut().zip(g.quat) {
        *r += q;
    }
    run.opacity_logits[k] += g.opacity_logit;
    for (s, v) in run.sh[k * kc..(k + 1) * kc].iter_mut().zip(vsh) {
        *s += v;
    }
    for (d, v) in run.features[k * f..(k + 1) * f].iter_mut().zip(&a[slot::FEATURES..]) {
        *d += v;
    }
    run.means2d[k][0] += xy[0];
    run.means2d[k][1] += xy[1];
}

/// The gradients of eight rows of `run` at once, one per lane: the inputs gathered into
/// lanes, each lane's results added to its row as [`one`] adds them.
#[inline(always)]
fn eight(inp: &Inputs, run: &mut Run, group: &[u16; 8]) {
    let s = inp.splats;
    let active_degree = s.active_sh_degree.min(s.sh_degree);
    let (kc, nsh) = (crate::sh_coeffs(s.sh_degree) * 3, crate::sh_coeffs(active_degree) * 3);
    let mut a: [&[f32]; 8] = [&[]; 8];
    let mut sg = Splat2dGrads::<F8>::default();
    let mut sh = [F8::default(); 48];
    let (mut mean, mut log_scale, mut quat, mut opacity_logit) =
        ([F8::default(); 3], [F8::default(); 3], [F8::default(); 4], F8::default());
    for l in 0..8 {
        let i = run.first + group[l] as usize;
        let r = acc_row(inp, run, group[l] as usize);
        a[l] = r;
        sg.xy[0].0[l] = r[slot::XY];
        sg.xy[1].0[l] = r[slot::XY + 1];
        for c in 0..3 {
            sg.conic[c].0[l] = r[slot::CONIC + c];
            sg.color[c].0[l] = r[slot::COLOR + c];
            mean[c].0[l] = s.means[i][c];
            log_scale[c].0[l] = s.log_scales[i][c];
        }
        sg.opacity.0[l] = r[slot::OPACITY];
        sg.depth.0[l] = r[slot::DEPTH];
        for c in 0..4 {
            quat[c].0[l] = s.rotations[i][c];
        }
        opacity_logit.0[l] = s.opacity_logits[i];
        for (t, v) in s.sh[i * kc..i * kc + nsh].iter().enumerate() {
            sh[t].0[l] = *v;
        }
    }
    let p = GaussianParams { mean, log_scale, quat, opacity_logit, sh: &sh[..nsh], active_degree };
    let mut vsh = [F8::default(); 48];
    let gg = project_backward(inp.view, &p, &sg, &mut vsh[..nsh], inp.clamp);
    for l in 0..8 {
        let g = Grads1 {
            mean: gg.mean.map(|v| v.0[l]),
            log_scale: gg.log_scale.map(|v| v.0[l]),
            quat: gg.quat.map(|v| v.0[l]),
            opacity_logit: gg.opacity_logit.0[l],
        };
        let mut vsh1 = [0.0f32; 48];
        for (d, v) in vsh1[..nsh].iter_mut().zip(&vsh) {
            *d = v.0[l];
        }
        let xy = [sg.xy[0].0[l], sg.xy[1].0[l]];
        add_row(inp, run, group[l] as usize, &g, &vsh1[..nsh], a[l], xy);
    }
}
