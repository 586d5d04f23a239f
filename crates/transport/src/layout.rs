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

/// Splits the flat per-entry array `k` and the per-row array `st` into chunks of
/// `rows_per_chunk` engine rows, for parallel iteration.
pub(crate) fn split_chunks<'k, 's, L: Layout, T>(
    l: &L,
    rows_per_chunk: usize,
    mut k: &'k mut [f32],
    mut st: &'s mut [T],
) -> Vec<(usize, usize, &'k mut [f32], &'s mut [T])> {
    let n = l.rows();
    let mut out = Vec::with_capacity(n.div_ceil(rows_per_chunk.max(1)));
    let mut r0 = 0;
    while r0 < n {
        let r1 = (r0 + rows_per_chunk).min(n);
        let (e0, _) = l.range(r0);
        let (_, e1) = l.range(r1 - 1);
        let (kh, kt) = std::mem::take(&mut k).split_at_mut(e1 - e0);
        let (sh, stail) = std::mem::take(&mut st).split_at_mut(r1 - r0);
        out.push((r0, e0, kh, sh));
        k = kt;
        st = stail;
        r0 = r1;
    }
    out
}

/// True if the problem is dense.
pub(crate) fn is_dense(p: &Problem<'_>) -> bool {
    matches!(p.support, Support::Dense(_))
}
