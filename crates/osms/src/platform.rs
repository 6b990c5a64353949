//! The platform class: the part of the machine that can change MuJoCo's floating-point results
//! (the design sketch `../shared/design/ARCHITECTURE.md`, "Numerics that must not drift").
//! Golden content hashes are kept per class.

/// `<arch>-<widest SIMD that MuJoCo may use>`, e.g. `x86_64-avx512`, `x86_64-avx2`, `aarch64`.
pub fn class() -> String {
    let arch = std::env::consts::ARCH;
    #[cfg(target_arch = "x86_64")]
    {
        // Only names the class; nothing numeric is dispatched on it.
        let simd = if std::arch::is_x86_feature_detected!("avx512f") {
            "avx512"
        } else if std::arch::is_x86_feature_detected!("avx2") {
            "avx2"
        } else {
            "sse"
        };
        format!("{arch}-{simd}")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        arch.to_string()
    }
}
