//! Denormal handling for the dense element kernels.
//!
//! Measured (2026-12-02, the kernel timed alone in a loop vs the same kernel inside a reduced-model
//! evaluation): faer's small-matrix products ran 7× slower in the application than in
//! isolation (0.55 ms vs 74 µs per Hex27 tangent), with no subnormal number in their inputs or
//! outputs, and perf put 60 % of the time in the gemm microkernel. With flush-to-zero and
//! denormals-are-zero set for the duration of the kernel the time is 71 µs in place, so the
//! cause is subnormal arithmetic inside the products, most likely on the padding lanes of the
//! packed 27-row panels, which hold whatever the reused memory held (each subnormal operand
//! costs a microcode assist). No value the kernels produce is anywhere near the subnormal range
//! (|x| < 2.2e-308): a full-model evaluation gives the same result.json with and without it.

/// While alive, the calling thread runs with FTZ and DAZ set (x86-64 MXCSR); the previous mode
/// is restored on drop. A no-op on other architectures.
pub struct FlushDenormals {
    #[cfg(target_arch = "x86_64")]
    saved: u32,
}

impl FlushDenormals {
    #[inline]
    #[allow(clippy::new_without_default)]
    pub fn new() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            let mut saved: u32 = 0;
            // SAFETY: stmxcsr/ldmxcsr only read and write the SSE control/status register of
            // this thread through a valid pointer to a u32; FTZ (bit 15) and DAZ (bit 6) change
            // only how subnormal numbers are treated.
            unsafe { std::arch::asm!("stmxcsr [{0}]", in(reg) &mut saved as *mut u32, options(nostack, preserves_flags)) };
            let set = saved | 0x8040;
            if set != saved {
                unsafe { std::arch::asm!("ldmxcsr [{0}]", in(reg) &set as *const u32, options(nostack, preserves_flags, readonly)) };
            }
            FlushDenormals { saved }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            FlushDenormals {}
        }
    }
}

impl Drop for FlushDenormals {
    #[inline]
    fn drop(&mut self) {
        #[cfg(target_arch = "x86_64")]
        {
            let mut now: u32 = 0;
            unsafe { std::arch::asm!("stmxcsr [{0}]", in(reg) &mut now as *mut u32, options(nostack, preserves_flags)) };
            if now != self.saved {
                // SAFETY: as in `new`; restores the mode found there (the status flags included)
                unsafe { std::arch::asm!("ldmxcsr [{0}]", in(reg) &self.saved as *const u32, options(nostack, preserves_flags, readonly)) };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn flushes_inside_and_restores_after() {
        let tiny = std::hint::black_box(f64::MIN_POSITIVE);
        assert!((tiny / 4.0).is_subnormal());
        {
            let _g = super::FlushDenormals::new();
            let r = std::hint::black_box(tiny) / std::hint::black_box(4.0);
            if cfg!(target_arch = "x86_64") {
                assert_eq!(r, 0.0);
            }
        }
        let r = std::hint::black_box(tiny) / std::hint::black_box(4.0);
        assert!(r.is_subnormal(), "the thread's mode is restored");
    }
}
