//! What the CPU can do, for kernels that pick their code path at run time, and
//! prefetch hints for kernels that visit scattered rows.

/// Whether the CPU has AVX2 and FMA, so code compiled with
/// `#[target_feature(enable = "avx2,fma")]` may run. Always false off x86-64.
#[inline]
pub fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the CPU also has AVX-512 (F, VL, BW, DQ), so code compiled with
/// `#[target_feature(enable = "avx2,fma,avx512f,avx512vl,avx512bw,avx512dq")]` may run.
/// Always false off x86-64.
#[inline]
pub fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        has_avx2()
            && std::is_x86_feature_detected!("avx512f")
            && std::is_x86_feature_detected!("avx512vl")
            && std::is_x86_feature_detected!("avx512bw")
            && std::is_x86_feature_detected!("avx512dq")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Hints the CPU to fetch the cache lines of `len` bytes at address `at`: for loops
/// over scattered rows (ascending but with gaps), whose next row the hardware cannot
/// guess. An address, not a reference: nothing is read, and a prefetch never faults.
#[inline(always)]
pub fn prefetch_bytes(at: usize, len: usize) {
    #[cfg(target_arch = "x86_64")]
    for line in (at & !63..at + len).step_by(64) {
        // SAFETY: prefetching is a hint; it never faults, even for a bad address.
        unsafe { std::arch::x86_64::_mm_prefetch(line as *const i8, std::arch::x86_64::_MM_HINT_T0) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (at, len);
}
