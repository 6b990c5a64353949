//! Run-time choice of instruction set. Kernels are written once as generic safe code and
//! compiled per level inside functions that carry that level's target features; lanes only ever
//! run the scalar sequence side by side, so a level changes the speed, never a bit.

use std::sync::OnceLock;

/// An instruction set the tiled kernel can run on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// The target's baseline (SSE2 on x86-64, NEON on aarch64).
    Baseline,
    Avx2,
    Avx512,
}

impl Level {
    /// The widest level this CPU supports (detected once).
    pub fn detected() -> Level {
        static LEVEL: OnceLock<Level> = OnceLock::new();
        *LEVEL.get_or_init(|| {
            #[cfg(target_arch = "x86_64")]
            {
                // The fused multiply-add runs in hardware only with FMA; without it the
                // baseline's `mul_add` is a (correctly rounded, slow) library call.
                let fma = std::arch::is_x86_feature_detected!("fma");
                if fma && std::arch::is_x86_feature_detected!("avx512f") {
                    return Level::Avx512;
                }
                if fma && std::arch::is_x86_feature_detected!("avx2") {
                    return Level::Avx2;
                }
            }
            Level::Baseline
        })
    }

    /// The level a kernel asked for `self` runs at: itself if the CPU has it, else the
    /// baseline (as [`dispatch!`] falls back), so that B is packed for the kernel that reads it.
    pub(crate) fn runnable(self) -> Level {
        if self as u8 <= Level::detected() as u8 {
            self
        } else {
            Level::Baseline
        }
    }

    /// Every level this CPU can run, narrowest first (tests compare them bit for bit).
    pub fn available() -> Vec<Level> {
        [Level::Baseline, Level::Avx2, Level::Avx512]
            .into_iter()
            .filter(|&l| l as u8 <= Level::detected() as u8)
            .collect()
    }

    /// Register-block rows (even: the block is two halves).
    pub(crate) const fn mr(self) -> usize {
        match self {
            Level::Baseline => 4,
            Level::Avx2 => 6,
            Level::Avx512 => 8,
        }
    }

    /// Register-block columns (the packed panel width).
    pub(crate) const fn nr(self) -> usize {
        match self {
            Level::Baseline => 8,
            Level::Avx2 => 16,
            Level::Avx512 => 32,
        }
    }
}

/// Defines one function per level around the same body. With `[NAME]`, the body sees the
/// level as the constant `NAME` (for register-block sizes).
macro_rules! per_level {
    ($baseline:ident, $avx2:ident, $avx512:ident, [$lvl:ident] $args:tt => $body:expr) => {
        fn $baseline $args {
            const $lvl: Level = Level::Baseline;
            $body
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        fn $avx2 $args {
            const $lvl: Level = Level::Avx2;
            $body
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,fma")]
        fn $avx512 $args {
            const $lvl: Level = Level::Avx512;
            $body
        }
    };
    ($baseline:ident, $avx2:ident, $avx512:ident, $args:tt => $body:expr) => {
        fn $baseline $args {
            $body
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        fn $avx2 $args {
            $body
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,fma")]
        fn $avx512 $args {
            $body
        }
    };
}

/// Calls the `level` variant of a [`per_level!`] kernel (a level the CPU lacks runs the
/// baseline). This is the one place that enters code compiled for a wider instruction set.
macro_rules! dispatch {
    ($level:expr, $baseline:ident, $avx2:ident, $avx512:ident ($($arg:expr),*)) => {{
        #[allow(unsafe_code)]
        match $level {
            #[cfg(target_arch = "x86_64")]
            $crate::level::Level::Avx512
                if $crate::level::Level::detected() == $crate::level::Level::Avx512 =>
            {
                // SAFETY: the CPU reported AVX-512F and FMA at run time; the body is safe code.
                unsafe { $avx512($($arg),*) }
            }
            #[cfg(target_arch = "x86_64")]
            $crate::level::Level::Avx2
                if $crate::level::Level::detected() as u8 >= $crate::level::Level::Avx2 as u8 =>
            {
                // SAFETY: the CPU reported AVX2 and FMA at run time; the body is safe code.
                unsafe { $avx2($($arg),*) }
            }
            _ => $baseline($($arg),*),
        }
    }};
}

pub(crate) use {dispatch, per_level};
