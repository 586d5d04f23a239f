//! Problem data: masses, and the cost on a dense or sparse support.
//!
//! A dense cost is a row-major `n x m` slice (n sources, m targets). A sparse support
//! is a list of (source, target, cost) entries; every pair outside it has infinite cost
//! (its plan entry is 0). "Top-k" builds the sparse support in which each target keeps
//! its k cheapest sources (paper appendix, k = 128).

use crate::error::{Error, Result};
use rayon::prelude::*;
use std::cmp::Ordering;

/// A sparse cost: entries grouped by source (CSR over the sources that have at least
/// one entry), targets ascending within a source. Costs are >= 0 or +inf.
#[derive(Clone, Debug, PartialEq)]
pub struct SparseCost {
    n: usize,
    m: usize,
    /// Sources with at least one entry, ascending.
    rows: Vec<u32>,
    /// `ptr[r]..ptr[r+1]` are the entries of `rows[r]`.
    ptr: Vec<usize>,
    cols: Vec<u32>,
    costs: Vec<f32>,
}

/// Costs are >= 0 or +inf; NaN and negatives are rejected.
#[inline(always)]
fn bad_cost(c: f32) -> bool {
    c.is_nan() || c < 0.0
}

/// Per-target candidate lists of one block of rows.
type Candidates = Vec<Vec<(f32, u32)>>;

fn check_cost(value: f32, source_index: usize, target: usize) -> Result<()> {
    if value >= 0.0 {
        Ok(())
    } else {
        Err(Error::BadCost { source_index, target, value })
    }
}

impl SparseCost {
    /// Builds a support from (source, target, cost) triplets in any order. Repeated
    /// pairs, out-of-range indices, and negative or NaN costs are errors.
    pub fn from_triplets(
        n: usize,
        m: usize,
        sources: &[u32],
        targets: &[u32],
        costs: &[f32],
    ) -> Result<Self> {
        if targets.len() != sources.len() {
            return Err(Error::Shape { what: "targets", got: targets.len(), expected: sources.len() });
        }
        if costs.len() != sources.len() {
            return Err(Error::Shape { what: "costs", got: costs.len(), expected: sources.len() });
        }
        if n > u32::MAX as usize || m > u32::MAX as usize {
            return Err(Error::BadSupport("more than 2^32 sources or targets".into()));
        }
        let mut e: Vec<(u32, u32, f32)> = Vec::with_capacity(sources.len());
        for k in 0..sources.len() {
            let (i, j, c) = (sources[k], targets[k], costs[k]);
            if i as usize >= n || j as usize >= m {
                return Err(Error::BadSupport(format!("entry ({i}, {j}) outside {n} x {m}")));
            }
            check_cost(c, i as usize, j as usize)?;
            e.push((i, j, c));
        }
        e.par_sort_unstable_by_key(|t| (t.0, t.1));
        if let Some(w) = e.windows(2).find(|w| w[0].0 == w[1].0 && w[0].1 == w[1].1) {
            return Err(Error::BadSupport(format!("entry ({}, {}) given twice", w[0].0, w[0].1)));
        }
        Ok(Self::from_sorted(n, m, &e))
    }

    /// `e` sorted by (source, target), unique.
    fn from_sorted(n: usize, m: usize, e: &[(u32, u32, f32)]) -> Self {
        let mut rows = Vec::new();
        let mut ptr = vec![0usize];
        let mut cols = Vec::with_capacity(e.len());
        let mut costs = Vec::with_capacity(e.len());
        for (k, &(i, j, c)) in e.iter().enumerate() {
            if k == 0 || e[k - 1].0 != i {
                if k > 0 {
                    ptr.push(cols.len());
                }
                rows.push(i);
            }
            cols.push(j);
            costs.push(c);
        }
        if !e.is_empty() {
            ptr.push(cols.len());
        }
        SparseCost { n, m, rows, ptr, cols, costs }
    }

    /// Top-k support of a dense row-major `n x m` cost: each target keeps its `k`
    /// cheapest sources (ties broken by lower source index; +inf costs never kept, so a
    /// target may keep fewer). Validates the costs in the same pass. Selection is one
    /// parallel streaming pass over the rows with a per-target candidate buffer and a
    /// running threshold (partial selection by `select_nth_unstable`), then a merge.
    pub fn top_k(cost: &[f32], n: usize, m: usize, k: usize) -> Result<Self> {
        if cost.len() != n * m {
            return Err(Error::Shape { what: "cost", got: cost.len(), expected: n * m });
        }
        if n > u32::MAX as usize {
            return Err(Error::BadSupport("more than 2^32 sources".into()));
        }
        if k == 0 || m == 0 || n == 0 {
            return Ok(SparseCost { n, m, rows: vec![], ptr: vec![0], cols: vec![], costs: vec![] });
        }
        let threads = rayon::current_num_threads().max(1);
        let block = n.div_ceil(threads * 4).max(4096);
        let blocks: Vec<Result<Candidates>> = cost
            .par_chunks(block * m)
            .enumerate()
            .map(|(bi, chunk)| select_block(chunk, bi * block, m, k))
            .collect();
        let mut per_col: Vec<Vec<(f32, u32)>> = vec![Vec::new(); m];
        for b in blocks {
            for (j, cand) in b?.into_iter().enumerate() {
                per_col[j].extend(cand);
            }
        }
        let mut e: Vec<(u32, u32, f32)> = Vec::with_capacity(k * m);
        for (j, mut cand) in per_col.into_iter().enumerate() {
            keep_smallest(&mut cand, k);
            e.extend(cand.into_iter().map(|(c, i)| (i, j as u32, c)));
        }
        e.sort_unstable_by_key(|t| (t.0, t.1));
        Ok(Self::from_sorted(n, m, &e))
    }

    /// Number of sources.
    pub fn n(&self) -> usize {
        self.n
    }
    /// Number of targets.
    pub fn m(&self) -> usize {
        self.m
    }
    /// Number of support entries.
    pub fn nnz(&self) -> usize {
        self.cols.len()
    }
    /// Sources with at least one entry, ascending.
    pub fn active_sources(&self) -> &[u32] {
        &self.rows
    }
    /// Entries as (source, target, cost), by source then target; plan vectors from
    /// [`crate::Solution::sparse_plan`] follow this order.
    pub fn iter(&self) -> impl Iterator<Item = (usize, usize, f32)> + '_ {
        self.rows.iter().enumerate().flat_map(move |(r, &i)| {
            (self.ptr[r]..self.ptr[r + 1]).map(move |e| (i as usize, self.cols[e] as usize, self.costs[e]))
        })
    }
    pub(crate) fn ptr(&self) -> &[usize] {
        &self.ptr
    }
    pub(crate) fn cols(&self) -> &[u32] {
        &self.cols
    }
    pub(crate) fn costs(&self) -> &[f32] {
        &self.costs
    }
}

/// Total order on candidates: cost, then source index.
fn cand_cmp(x: &(f32, u32), y: &(f32, u32)) -> Ordering {
    x.0.partial_cmp(&y.0).unwrap_or(Ordering::Equal).then(x.1.cmp(&y.1))
}

fn keep_smallest(c: &mut Vec<(f32, u32)>, k: usize) {
    if c.len() > k {
        c.select_nth_unstable_by(k - 1, cand_cmp);
        c.truncate(k);
    }
}

/// Streaming per-column top-k over a block of rows starting at row `row0`.
fn select_block(chunk: &[f32], row0: usize, m: usize, k: usize) -> Result<Candidates> {
    let cap = 4 * k;
    let mut buf: Vec<Vec<(f32, u32)>> = (0..m).map(|_| Vec::with_capacity(cap)).collect();
    let mut thr = vec![f32::INFINITY; m];
    // Until a column's buffer first fills, its threshold is +inf: every finite cost is
    // a candidate.
    for (r, row) in chunk.chunks_exact(m).enumerate() {
        let mut any = false;
        let mut bad = false;
        for (c, t) in row.iter().zip(&thr) {
            any |= *c < *t;
            bad |= bad_cost(*c);
        }
        if bad {
            let j = row.iter().position(|c| bad_cost(*c)).unwrap_or(0);
            check_cost(row[j], row0 + r, j)?;
        }
        if !any {
            continue;
        }
        let i = (row0 + r) as u32;
        for j in 0..m {
            let c = row[j];
            if c < thr[j] {
                let b = &mut buf[j];
                b.push((c, i));
                if b.len() == cap {
                    keep_smallest(b, k);
                    thr[j] = b.iter().map(|x| x.0).fold(f32::NEG_INFINITY, f32::max);
                    // Equal costs at the threshold from later rows lose the tie anyway
                    // (larger index), so `c < thr` admits exactly the candidates that can
                    // still make the cut.
                }
            }
        }
    }
    for b in buf.iter_mut() {
        keep_smallest(b, k);
    }
    Ok(buf)
}

/// The cost of a [`Problem`].
#[derive(Clone, Debug)]
pub enum Support<'a> {
    /// Row-major `n x m`.
    Dense(&'a [f32]),
    /// Sparse support; pairs outside it have infinite cost.
    Sparse(SparseCost),
}

/// One transport problem: source masses `a` (n), target masses `b` (m) and the cost.
/// Masses are finite and >= 0 (they need not sum to 1); costs are >= 0 or +inf.
#[derive(Clone, Debug)]
pub struct Problem<'a> {
    pub(crate) a: &'a [f32],
    pub(crate) b: &'a [f32],
    pub(crate) support: Support<'a>,
}

fn check_masses(which: &'static str, x: &[f32]) -> Result<()> {
    match x.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        Some(index) => Err(Error::BadMass { which, index, value: x[index] }),
        None => Ok(()),
    }
}

impl<'a> Problem<'a> {
    /// Dense problem; `cost` is row-major `a.len() x b.len()`. Validates everything.
    pub fn dense(a: &'a [f32], b: &'a [f32], cost: &'a [f32]) -> Result<Self> {
        let (n, m) = (a.len(), b.len());
        if cost.len() != n * m {
            return Err(Error::Shape { what: "cost", got: cost.len(), expected: n * m });
        }
        check_masses("source", a)?;
        check_masses("target", b)?;
        if m > 0 {
            let bad = cost.par_chunks(4096 * m).enumerate().find_map_first(|(ci, ch)| {
                let mut bad = false;
                for c in ch {
                    bad |= bad_cost(*c);
                }
                if !bad {
                    return None;
                }
                let p = ch.iter().position(|c| bad_cost(*c))?;
                let flat = ci * 4096 * m + p;
                Some((flat / m, flat % m, ch[p]))
            });
            if let Some((i, j, v)) = bad {
                return Err(Error::BadCost { source_index: i, target: j, value: v });
            }
        }
        Ok(Problem { a, b, support: Support::Dense(cost) })
    }

    /// Problem on a sparse support of `a.len() x b.len()`.
    pub fn sparse(a: &'a [f32], b: &'a [f32], cost: SparseCost) -> Result<Self> {
        if cost.n != a.len() {
            return Err(Error::Shape { what: "sparse support rows", got: cost.n, expected: a.len() });
        }
        if cost.m != b.len() {
            return Err(Error::Shape { what: "sparse support columns", got: cost.m, expected: b.len() });
        }
        check_masses("source", a)?;
        check_masses("target", b)?;
        Ok(Problem { a, b, support: Support::Sparse(cost) })
    }

    /// Top-k problem from a dense cost: each target keeps its `k` cheapest sources;
    /// `k = 0` (or `k >= n`) means the dense problem.
    pub fn top_k(a: &'a [f32], b: &'a [f32], cost: &'a [f32], k: usize) -> Result<Self> {
        if k == 0 || k >= a.len() {
            return Self::dense(a, b, cost);
        }
        check_masses("source", a)?;
        check_masses("target", b)?;
        let s = SparseCost::top_k(cost, a.len(), b.len(), k)?;
        Ok(Problem { a, b, support: Support::Sparse(s) })
    }

    /// Number of sources.
    pub fn n(&self) -> usize {
        self.a.len()
    }
    /// Number of targets.
    pub fn m(&self) -> usize {
        self.b.len()
    }
    /// Source masses.
    pub fn source_mass(&self) -> &[f32] {
        self.a
    }
    /// Target masses.
    pub fn target_mass(&self) -> &[f32] {
        self.b
    }
    /// The cost support.
    pub fn support(&self) -> &Support<'a> {
        &self.support
    }
    /// Number of entries the plan can be nonzero on (n * m when dense).
    pub fn nnz(&self) -> usize {
        match &self.support {
            Support::Dense(c) => c.len(),
            Support::Sparse(s) => s.nnz(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn top_k_matches_sort() {
        let (n, m, k) = (10_000usize, 5usize, 7usize);
        let mut state = 12345u64;
        let cost: Vec<f32> = (0..n * m)
            .map(|_| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                // coarse values so that ties happen
                ((state >> 40) % 1000) as f32 * 0.01
            })
            .collect();
        let s = SparseCost::top_k(&cost, n, m, k).unwrap();
        assert_eq!(s.nnz(), k * m);
        for j in 0..m {
            let mut col: Vec<(f32, u32)> = (0..n).map(|i| (cost[i * m + j], i as u32)).collect();
            col.sort_by(cand_cmp);
            let mut want: Vec<usize> = col[..k].iter().map(|x| x.1 as usize).collect();
            want.sort();
            let got: Vec<usize> = s.iter().filter(|e| e.1 == j).map(|e| e.0).collect();
            assert_eq!(got, want, "column {j}");
        }
    }

    #[test]
    fn top_k_rejects_nan() {
        let mut cost = vec![1.0f32; 20_000];
        cost[12_345] = f32::NAN;
        let e = SparseCost::top_k(&cost, 10_000, 2, 3).unwrap_err();
        assert!(matches!(e, Error::BadCost { source_index: 6172, target: 1, .. }), "{e}");
    }

    #[test]
    fn triplets() {
        let s = SparseCost::from_triplets(4, 3, &[2, 0, 2], &[1, 2, 0], &[1.0, 2.0, 3.0]).unwrap();
        let v: Vec<_> = s.iter().collect();
        assert_eq!(v, vec![(0, 2, 2.0), (2, 0, 3.0), (2, 1, 1.0)]);
        assert!(SparseCost::from_triplets(4, 3, &[2, 2], &[1, 1], &[1.0, 2.0]).is_err());
        assert!(SparseCost::from_triplets(4, 3, &[4], &[1], &[1.0]).is_err());
        assert!(SparseCost::from_triplets(4, 3, &[1], &[1], &[-1.0]).is_err());
    }
}
