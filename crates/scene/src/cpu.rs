//! What the CPU can do, for kernels that pick their code path at run time.

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
