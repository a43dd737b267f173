//! Compiling a loop for AVX where the CPU has it.
//!
//! The x86-64 baseline has four-lane vectors; most CPUs that run focusd on a desktop have AVX's
//! eight. A hot loop written as an `#[inline(always)]` body and called through [`with_avx`] is
//! compiled twice, once inside an AVX function, and the CPU picks at run time. The same
//! operations in the same order either way (no fused multiply-add), so the same values.

/// Runs `f`, told whether it runs as AVX code; inlined into an AVX-compiled function where the
/// CPU has AVX (x86-64 only). `f` and what it calls must be `#[inline(always)]` for their loops
/// to be compiled so.
#[inline(always)]
pub(crate) fn with_avx<R>(f: impl FnOnce(bool) -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        #[target_feature(enable = "avx")]
        unsafe fn avx<R>(f: impl FnOnce(bool) -> R) -> R {
            f(true)
        }
        // SAFETY: the CPU has AVX, checked just above.
        return unsafe { avx(f) };
    }
    f(false)
}
