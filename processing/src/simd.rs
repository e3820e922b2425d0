//! Whether this processor has AVX2 and FMA, for the hot loops compiled twice: once
//! portable, once with those features (chosen at run time). No operation is fused in the
//! AVX2 copy that the portable one does not fuse, so both give the same values.

/// True on an x86-64 processor with AVX2 and FMA (the answer is cached by `std`).
#[cfg(target_arch = "x86_64")]
pub(crate) fn avx2_fma() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}
