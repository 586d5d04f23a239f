//! What this crate's CPU operations share: reading a contiguous f32 input from candle's
//! storage, a bounds-checked GEMM over row-major or transposed matrices on every rayon
//! thread (the `gemm` crate, AVX-512 kernels where the CPU has them),
//! [`simd_versions!`], which compiles an element-wise loop for the vector units the CPU
//! has, and [`lanes_fold`], a reduction such a loop can vectorise.

/// Defines `fn $name(args)` from a plain loop body compiled three times: for AVX-512F,
/// for AVX2 with FMA, and for the build's baseline (SSE2 on x86-64), the first the CPU
/// has picked at run time. The release build targets the baseline, where a loop gets 4
/// lanes and calls such as `round_ties_even` stay calls into the C library; compiled
/// for AVX2 the same loop gets 8 lanes, for AVX-512 16.
macro_rules! simd_versions {
    ($(#[$meta:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block) => {
        $(#[$meta])*
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[inline(always)]
            fn portable($($arg: $ty),*) $(-> $ret)? $body
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f")]
                unsafe fn avx512($($arg: $ty),*) $(-> $ret)? {
                    portable($($arg),*)
                }
                #[target_feature(enable = "avx2,fma")]
                unsafe fn avx2($($arg: $ty),*) $(-> $ret)? {
                    portable($($arg),*)
                }
                if std::arch::is_x86_feature_detected!("avx512f") {
                    // SAFETY: the CPU has AVX-512F, checked just above.
                    return unsafe { avx512($($arg),*) };
                }
                if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                    // SAFETY: the CPU has AVX2 and FMA, checked just above.
                    return unsafe { avx2($($arg),*) };
                }
            }
            portable($($arg),*)
        }
    };
}
pub(crate) use simd_versions;

/// Independent accumulators of [`lanes_fold`].
pub(crate) const LANES: usize = 16;

/// Folds `values` into [`LANES`] independent accumulators with `step`, then joins them
/// with `combine`: a reduction the compiler vectorises, where a single running one is a
/// chain of dependent operations. `init` must be `combine`'s identity.
#[inline(always)]
pub(crate) fn lanes_fold<A: Copy>(
    values: &[f32],
    init: A,
    step: impl Fn(A, f32) -> A,
    combine: impl Fn(A, A) -> A,
) -> A {
    let mut lanes = [init; LANES];
    let mut chunks = values.chunks_exact(LANES);
    for c in &mut chunks {
        for (l, &v) in lanes.iter_mut().zip(c) {
            *l = step(*l, v);
        }
    }
    let tail = chunks.remainder().iter().fold(init, |a, &v| step(a, v));
    lanes.iter().fold(tail, |a, &l| combine(a, l))
}

use candle_core::{CpuStorage, Layout};

/// The contiguous f32 values of an operation's input; an error naming `op` otherwise.
pub(crate) fn f32_input<'a>(
    storage: &'a CpuStorage,
    layout: &Layout,
    op: &str,
) -> candle_core::Result<&'a [f32]> {
    let CpuStorage::F32(x) = storage else { candle_core::bail!("{op}: the input must be f32") };
    let Some((start, end)) = layout.contiguous_offsets() else {
        candle_core::bail!("{op}: the input must be contiguous")
    };
    Ok(&x[start..end])
}

/// A matrix in a slice: element (i, j) at `i · rows + j · cols`.
#[derive(Clone, Copy)]
pub(crate) struct Matrix<'a> {
    pub data: &'a [f32],
    /// Stride between rows.
    pub rows: usize,
    /// Stride between columns.
    pub cols: usize,
}

impl Matrix<'_> {
    /// Whether an `r × c` matrix fits in the slice.
    fn holds(&self, r: usize, c: usize) -> bool {
        r == 0 || c == 0 || (r - 1) * self.rows + (c - 1) * self.cols < self.data.len()
    }
}

/// How [`gemm`] writes its product.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Product {
    /// Add to the destination (else overwrite it).
    pub accumulate: bool,
    /// The product's factor.
    pub scale: f32,
    /// Split the product over every rayon thread (else run it on the calling thread: for
    /// products that are themselves tasks of a parallel loop).
    pub parallel: bool,
}

/// dst += lhs · rhs for lhs `m × k` and rhs `k × n`; dst is `m × n` starting at `offset`
/// of `y`, rows `y_rows` apart, columns adjacent.
pub(crate) fn gemm_accumulate(
    y: &mut [f32],
    offset: usize,
    y_rows: usize,
    lhs: Matrix,
    rhs: Matrix,
    dims: (usize, usize, usize),
) {
    gemm(y, offset, y_rows, lhs, rhs, dims, Product { accumulate: true, scale: 1.0, parallel: true })
}

/// dst (+)= scale · lhs · rhs for lhs `m × k` and rhs `k × n` ([`Product`]); dst is
/// `m × n` starting at `offset` of `y`, rows `y_rows` apart, columns adjacent.
pub(crate) fn gemm(
    y: &mut [f32],
    offset: usize,
    y_rows: usize,
    lhs: Matrix,
    rhs: Matrix,
    (m, n, k): (usize, usize, usize),
    how: Product,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(lhs.holds(m, k) && rhs.holds(k, n), "gemm: an operand is smaller than {m}x{k} · {k}x{n}");
    assert!(offset + (m - 1) * y_rows + n <= y.len(), "gemm: the output is smaller than {m}x{n}");
    let threads = if how.parallel { rayon::current_num_threads() } else { 1 };
    let parallelism = if threads > 1 { gemm::Parallelism::Rayon(threads) } else { gemm::Parallelism::None };
    // SAFETY: the asserts above bound every access of the three matrices by their strides.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            y.as_mut_ptr().add(offset),
            1,
            y_rows as isize,
            how.accumulate,
            lhs.data.as_ptr(),
            lhs.cols as isize,
            lhs.rows as isize,
            rhs.data.as_ptr(),
            rhs.cols as isize,
            rhs.rows as isize,
            1.0,
            how.scale,
            false,
            false,
            false,
            parallelism,
        );
    }
}
