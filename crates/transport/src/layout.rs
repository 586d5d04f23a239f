//! Row access shared by the dense and sparse solvers: the engine works on "rows"
//! (sources that can carry mass) whose entries are contiguous in a flat array.

use crate::fastmath;
use crate::problem::{Problem, SparseCost, Support};

/// Row-wise view of a cost support. Monomorphised, so the dense case compiles to
/// fixed-stride loops that vectorise.
pub(crate) trait Layout: Sync {
    /// Number of engine rows.
    fn rows(&self) -> usize;
    /// Number of targets.
    fn m(&self) -> usize;
    /// Entry range `[lo, hi)` of engine row `r`.
    fn range(&self, r: usize) -> (usize, usize);
    /// Source index of engine row `r`.
    fn source(&self, r: usize) -> usize;
    /// Costs, aligned with entries.
    fn costs(&self) -> &[f32];
    /// Target of entry `e` in a row starting at `lo`.
    fn col(&self, lo: usize, e: usize) -> usize;
    /// Entry of target `j` in row `[lo, hi)`, if any.
    fn find(&self, lo: usize, hi: usize, j: usize) -> Option<usize>;
    /// `sum_e k[e] * v[col(e)]` for the row's kernel slice `k`.
    fn dot(&self, lo: usize, k: &[f32], v: &[f32]) -> f32;
    /// `acc[col(e)] += w * k[e]`.
    fn axpy(&self, lo: usize, w: f32, k: &[f32], acc: &mut [f32]);
    /// Row products of a chunk of rows starting at `r0` whose kernel starts at entry
    /// `e0`: `out[rr] = dot(row r0 + rr, v)`.
    #[inline(always)]
    fn dots(&self, r0: usize, e0: usize, k: &[f32], v: &[f32], out: &mut [f32]) {
        for (rr, o) in out.iter_mut().enumerate() {
            let (lo, hi) = self.range(r0 + rr);
            *o = self.dot(lo, &k[lo - e0..hi - e0], v);
        }
    }
    /// `acc[col] += w[rr] * row r0 + rr` over a chunk (rows with w = 0 contribute 0).
    #[inline(always)]
    fn axpys(&self, r0: usize, e0: usize, k: &[f32], w: &[f32], acc: &mut [f32]) {
        for (rr, &wr) in w.iter().enumerate() {
            if wr > 0.0 {
                let (lo, hi) = self.range(r0 + rr);
                self.axpy(lo, wr, &k[lo - e0..hi - e0], acc);
            }
        }
    }
}

/// Dense with m = 8 NB targets: row products eight rows at a time and column sums in
/// registers (the hot path for m = 32).
pub(crate) struct DenseFixed<'a, const NB: usize> {
    pub cost: &'a [f32],
    pub n: usize,
    /// AVX2 + FMA available (explicit intrinsics; LLVM's own vectorisation of the
    /// eight-row blocks uses gathers).
    pub avx2: bool,
}

impl<const NB: usize> Layout for DenseFixed<'_, NB> {
    #[inline(always)]
    fn rows(&self) -> usize {
        self.n
    }
    #[inline(always)]
    fn m(&self) -> usize {
        8 * NB
    }
    #[inline(always)]
    fn range(&self, r: usize) -> (usize, usize) {
        (r * 8 * NB, (r + 1) * 8 * NB)
    }
    #[inline(always)]
    fn source(&self, r: usize) -> usize {
        r
    }
    #[inline(always)]
    fn costs(&self) -> &[f32] {
        self.cost
    }
    #[inline(always)]
    fn col(&self, lo: usize, e: usize) -> usize {
        e - lo
    }
    #[inline(always)]
    fn find(&self, lo: usize, _hi: usize, j: usize) -> Option<usize> {
        Some(lo + j)
    }
    #[inline(always)]
    fn dot(&self, _lo: usize, k: &[f32], v: &[f32]) -> f32 {
        fastmath::dot(k, v)
    }
    #[inline(always)]
    fn axpy(&self, _lo: usize, w: f32, k: &[f32], acc: &mut [f32]) {
        fastmath::axpy(w, k, acc)
    }
    #[inline(always)]
    fn dots(&self, r0: usize, e0: usize, k: &[f32], v: &[f32], out: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            let nr = out.len();
            assert!(k.len() >= nr * 8 * NB && v.len() >= 8 * NB);
            // SAFETY: AVX2/FMA detected at runtime (`avx2` field); bounds asserted.
            return unsafe { simd::dots::<NB>(k.as_ptr(), v.as_ptr(), out) };
        }
        for (rr, o) in out.iter_mut().enumerate() {
            let (lo, hi) = self.range(r0 + rr);
            *o = fastmath::dot(&k[lo - e0..hi - e0], v);
        }
    }
    #[inline(always)]
    fn axpys(&self, _r0: usize, _e0: usize, k: &[f32], wts: &[f32], acc: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            assert!(k.len() >= wts.len() * 8 * NB && acc.len() >= 8 * NB);
            // SAFETY: as above.
            return unsafe { simd::axpys::<NB>(k.as_ptr(), wts, acc) };
        }
        for (row, &wr) in k.chunks_exact(8 * NB).zip(wts) {
            fastmath::axpy(wr, row, acc);
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod simd {
    use std::arch::x86_64::*;

    /// Row products of `out.len()` rows of width 8 NB at `k` with `v`; eight rows
    /// at a time, reduced by a horizontal-add tree into one vector of 8 sums.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn dots<const NB: usize>(k: *const f32, v: *const f32, out: &mut [f32]) {
        let w = 8 * NB;
        let mut vb = [_mm256_setzero_ps(); NB];
        for (b, x) in vb.iter_mut().enumerate() {
            *x = _mm256_loadu_ps(v.add(8 * b));
        }
        let nr = out.len();
        let full = nr / 8 * 8;
        let mut r = 0;
        while r < full {
            let mut acc = [_mm256_setzero_ps(); 8];
            for (q, a) in acc.iter_mut().enumerate() {
                let row = k.add((r + q) * w);
                for (b, x) in vb.iter().enumerate() {
                    *a = _mm256_fmadd_ps(_mm256_loadu_ps(row.add(8 * b)), *x, *a);
                }
            }
            let t0 = _mm256_hadd_ps(acc[0], acc[1]);
            let t1 = _mm256_hadd_ps(acc[2], acc[3]);
            let t2 = _mm256_hadd_ps(acc[4], acc[5]);
            let t3 = _mm256_hadd_ps(acc[6], acc[7]);
            let u0 = _mm256_hadd_ps(t0, t1);
            let u1 = _mm256_hadd_ps(t2, t3);
            let s = _mm256_add_ps(_mm256_permute2f128_ps(u0, u1, 0x20), _mm256_permute2f128_ps(u0, u1, 0x31));
            _mm256_storeu_ps(out.as_mut_ptr().add(r), s);
            r += 8;
        }
        while r < nr {
            let row = k.add(r * w);
            let mut a = _mm256_setzero_ps();
            for (b, x) in vb.iter().enumerate() {
                a = _mm256_fmadd_ps(_mm256_loadu_ps(row.add(8 * b)), *x, a);
            }
            let mut t = [0f32; 8];
            _mm256_storeu_ps(t.as_mut_ptr(), a);
            out[r] = ((t[0] + t[4]) + (t[1] + t[5])) + ((t[2] + t[6]) + (t[3] + t[7]));
            r += 1;
        }
    }

    /// `acc += sum_r w[r] * row r` with the accumulators in registers.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn axpys<const NB: usize>(k: *const f32, w: &[f32], acc: &mut [f32]) {
        let width = 8 * NB;
        let mut a = [_mm256_setzero_ps(); NB];
        for (r, &wr) in w.iter().enumerate() {
            let row = k.add(r * width);
            let ww = _mm256_set1_ps(wr);
            for (b, x) in a.iter_mut().enumerate() {
                *x = _mm256_fmadd_ps(_mm256_loadu_ps(row.add(8 * b)), ww, *x);
            }
        }
        for (b, x) in a.iter().enumerate() {
            let p = acc.as_mut_ptr().add(8 * b);
            _mm256_storeu_ps(p, _mm256_add_ps(_mm256_loadu_ps(p), *x));
        }
    }
}

/// Dense row-major `n x m`.
pub(crate) struct Dense<'a> {
    pub cost: &'a [f32],
    pub n: usize,
    pub m: usize,
}

impl Layout for Dense<'_> {
    #[inline(always)]
    fn rows(&self) -> usize {
        self.n
    }
    #[inline(always)]
    fn m(&self) -> usize {
        self.m
    }
    #[inline(always)]
    fn range(&self, r: usize) -> (usize, usize) {
        (r * self.m, (r + 1) * self.m)
    }
    #[inline(always)]
    fn source(&self, r: usize) -> usize {
        r
    }
    #[inline(always)]
    fn costs(&self) -> &[f32] {
        self.cost
    }
    #[inline(always)]
    fn col(&self, lo: usize, e: usize) -> usize {
        e - lo
    }
    #[inline(always)]
    fn find(&self, lo: usize, _hi: usize, j: usize) -> Option<usize> {
        Some(lo + j)
    }
    #[inline(always)]
    fn dot(&self, _lo: usize, k: &[f32], v: &[f32]) -> f32 {
        fastmath::dot(k, v)
    }
    #[inline(always)]
    fn axpy(&self, _lo: usize, w: f32, k: &[f32], acc: &mut [f32]) {
        fastmath::axpy(w, k, acc)
    }
}

/// Sparse CSR over the sources that have entries.
pub(crate) struct Sparse<'a> {
    pub s: &'a SparseCost,
}

impl Layout for Sparse<'_> {
    #[inline(always)]
    fn rows(&self) -> usize {
        self.s.active_sources().len()
    }
    #[inline(always)]
    fn m(&self) -> usize {
        self.s.m()
    }
    #[inline(always)]
    fn range(&self, r: usize) -> (usize, usize) {
        (self.s.ptr()[r], self.s.ptr()[r + 1])
    }
    #[inline(always)]
    fn source(&self, r: usize) -> usize {
        self.s.active_sources()[r] as usize
    }
    #[inline(always)]
    fn costs(&self) -> &[f32] {
        self.s.costs()
    }
    #[inline(always)]
    fn col(&self, _lo: usize, e: usize) -> usize {
        self.s.cols()[e] as usize
    }
    #[inline(always)]
    fn find(&self, lo: usize, hi: usize, j: usize) -> Option<usize> {
        self.s.cols()[lo..hi].binary_search(&(j as u32)).ok().map(|p| lo + p)
    }
    #[inline(always)]
    fn dot(&self, lo: usize, k: &[f32], v: &[f32]) -> f32 {
        let cols = &self.s.cols()[lo..lo + k.len()];
        let mut s = 0.0f32;
        for (x, &j) in k.iter().zip(cols) {
            s += x * v[j as usize];
        }
        s
    }
    #[inline(always)]
    fn axpy(&self, lo: usize, w: f32, k: &[f32], acc: &mut [f32]) {
        let cols = &self.s.cols()[lo..lo + k.len()];
        for (x, &j) in k.iter().zip(cols) {
            acc[j as usize] += w * x;
        }
    }
}

/// Calls `$body` with `$l` bound to the problem's layout (monomorphised per layout).
macro_rules! with_layout {
    ($p:expr, $l:ident => $body:expr) => {
        match &$p.support {
            $crate::problem::Support::Dense(c) => {
                let $l = $crate::layout::Dense { cost: c, n: $p.a.len(), m: $p.b.len() };
                $body
            }
            $crate::problem::Support::Sparse(s) => {
                let $l = $crate::layout::Sparse { s };
                $body
            }
        }
    };
}
pub(crate) use with_layout;

/// Splits the flat per-entry array `k` into chunks of `rows_per_chunk` engine rows,
/// for parallel iteration: (first row, first entry, entries).
pub(crate) fn split_chunks<'k, L: Layout>(
    l: &L,
    rows_per_chunk: usize,
    mut k: &'k mut [f32],
) -> Vec<(usize, usize, &'k mut [f32])> {
    let n = l.rows();
    let mut out = Vec::with_capacity(n.div_ceil(rows_per_chunk.max(1)));
    let mut r0 = 0;
    while r0 < n {
        let r1 = (r0 + rows_per_chunk).min(n);
        let (e0, _) = l.range(r0);
        let (_, e1) = l.range(r1 - 1);
        let (kh, kt) = std::mem::take(&mut k).split_at_mut(e1 - e0);
        out.push((r0, e0, kh));
        k = kt;
        r0 = r1;
    }
    out
}

/// True if the problem is dense.
pub(crate) fn is_dense(p: &Problem<'_>) -> bool {
    matches!(p.support, Support::Dense(_))
}
