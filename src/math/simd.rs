//! The vector width a hot loop is compiled for. Such loops are written once, in plain Rust the
//! compiler vectorises, and compiled again with AVX2 and with AVX-512 enabled; the widest the CPU
//! offers is chosen at run time. Only additions, multiplications, divisions, square roots and bit
//! operations are used, never fused multiply-adds, so every width gives the same bits: results do
//! not depend on the machine's vector instructions.

/// A vector width for the loops compiled per width.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Width {
    /// The baseline of the target (SSE2 on x86-64).
    Baseline,
    /// 256-bit vectors.
    Avx2,
    /// 512-bit vectors (AVX-512 F).
    Avx512,
}

impl Width {
    /// The widest this CPU offers (detected once; later calls read a cached flag).
    #[inline]
    pub fn widest() -> Width {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                return Width::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                return Width::Avx2;
            }
        }
        Width::Baseline
    }

    /// Its name as the docs write it.
    pub fn name(self) -> &'static str {
        match self {
            Width::Baseline => "baseline (no AVX2)",
            Width::Avx2 => "AVX2",
            Width::Avx512 => "AVX-512",
        }
    }

    /// Every width this CPU can run, narrowest first (for the tests that compare them).
    pub fn available() -> Vec<Width> {
        let mut all = vec![Width::Baseline];
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                all.push(Width::Avx2);
            }
            if std::arch::is_x86_feature_detected!("avx512f") {
                all.push(Width::Avx512);
            }
        }
        all
    }
}
