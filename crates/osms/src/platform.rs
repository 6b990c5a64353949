//! The platform class: the part of the machine that can change MuJoCo's floating-point results
//! (the design sketch `../shared/design/ARCHITECTURE.md`, "Numerics that must not drift").
//! Golden content hashes are kept per class (`golden/outputs_<name>@<class>.snap`).
//!
//! # Why the class is the libm, not the SIMD level
//!
//! The class used to be `<arch>-<widest SIMD>` (`x86_64-avx2`, `x86_64-avx512`), but SIMD width
//! is not what changes bits: `osms-nn` is bit-identical across its SIMD levels by construction,
//! MuJoCo is one binary, and the engine and pipeline snapshots recorded on an AVX2 and an
//! AVX-512 machine were identical. What does change bits is glibc's libm: it picks FMA variants
//! of `exp`, `log`, `pow`, `sin`, `cos`, `tan`, `atan`, `atan2`, `asin`, `acos`, `tanh`,
//! `expm1`, `log1p` through ifuncs when the CPU has FMA and AVX2. Measured with glibc 2.36 on
//! 200 000 inputs per function, with and without `GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA`:
//! exp 152 results differ, pow 143, sin 118, cos 124, asin 135, expm1 290, atan2 27, tanh 39,
//! log1p 17, log 2, tan 1; also masking AVX and AVX512F changed nothing further. MuJoCo calls
//! these (`libmujoco.so` imports `exp`, `log`, `pow`, `sin`, `cos`, `tan`, `atan2`, `asin`,
//! `acos`, `cbrt`, `sinf`, `cosf`, `atan2f`, `powf`, `log10f` from libm), and so does any
//! `f64::exp`/`sin`/... in Rust. osms's own golden-path code uses the pure-Rust `libm` crate,
//! which is the same everywhere. It shows in the artifacts: the tiny pipeline built by one
//! binary with and without the tunable gives, under the same keys, different `teacher@0`,
//! `teacher_catch_only@0` and `eval_scripted@0` outputs (so everything downstream differs too),
//! while `world` and `heldout` stay the same.
//!
//! So the class is `<arch>-libm-<8 hex digits>`: a fingerprint of the libm actually loaded in
//! this process, found by evaluating those functions on a fixed set of inputs (including
//! inputs where glibc's FMA and non-FMA variants are known to differ) and hashing the result
//! bits. It follows whatever picks the variant (CPU, glibc version, `GLIBC_TUNABLES`, a
//! different libc) without naming any of them. It is a proxy: two libms that agree on these
//! ~86 000 evaluations could still differ elsewhere, which the golden snapshots would then show.
//!
//! Changing the input set or the function list renames every class; the golden snapshots must
//! then be renamed with it (`osms doctor` prints the class).

use std::hint::black_box;
use std::sync::OnceLock;

use osms_store::Hash;
use serde::Serialize;

/// Evaluations per function (besides the witnesses).
const SAMPLES: usize = 4096;

/// Bumped whenever the inputs or the function list change: every class name changes with it.
const FINGERPRINT_VERSION: &[u8] = b"osms libm fingerprint v1";

/// The libm as this process sees it: one digest over all probed functions and one per function.
#[derive(Clone, Debug, Serialize)]
pub struct LibmFingerprint {
    /// blake3 over the per-function digests, as 64 hex digits; the class uses the first 8.
    pub digest: String,
    /// `(libm symbol, first 8 hex digits of its digest)`, to see which functions differ between
    /// two machines.
    pub functions: Vec<(&'static str, String)>,
}

/// What `osms doctor` shows about the platform.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub class: String,
    pub arch: &'static str,
    pub libm: LibmFingerprint,
    /// The glibc in use (`gnu_get_libc_version`), where there is one.
    pub glibc_version: Option<String>,
    /// `GLIBC_TUNABLES` as set for this process: it can mask CPU features from glibc's ifuncs.
    pub glibc_tunables: Option<String>,
    /// x86_64 only: the CPU features glibc's libm chooses its variants by.
    pub cpu_fma: Option<bool>,
    pub cpu_avx2: Option<bool>,
    pub cpu_avx512f: Option<bool>,
}

/// `<arch>-libm-<8 hex>`, e.g. `x86_64-libm-1a2b3c4d`: the arch and the fingerprint of the
/// loaded libm (see the module documentation for why).
pub fn class() -> String {
    format!(
        "{}-libm-{}",
        std::env::consts::ARCH,
        &libm_fingerprint().digest[..8]
    )
}

/// The fingerprint of the libm loaded in this process, computed once.
pub fn libm_fingerprint() -> &'static LibmFingerprint {
    static FINGERPRINT: OnceLock<LibmFingerprint> = OnceLock::new();
    FINGERPRINT.get_or_init(compute_fingerprint)
}

/// Everything `osms doctor` prints about the platform.
pub fn report() -> Report {
    #[cfg(target_arch = "x86_64")]
    let (fma, avx2, avx512f) = (
        Some(std::arch::is_x86_feature_detected!("fma")),
        Some(std::arch::is_x86_feature_detected!("avx2")),
        Some(std::arch::is_x86_feature_detected!("avx512f")),
    );
    #[cfg(not(target_arch = "x86_64"))]
    let (fma, avx2, avx512f) = (None, None, None);
    Report {
        class: class(),
        arch: std::env::consts::ARCH,
        libm: libm_fingerprint().clone(),
        glibc_version: glibc_version(),
        glibc_tunables: std::env::var("GLIBC_TUNABLES").ok(),
        cpu_fma: fma,
        cpu_avx2: avx2,
        cpu_avx512f: avx512f,
    }
}

/// The running glibc's version, e.g. `2.36`.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(unsafe_code)]
pub fn glibc_version() -> Option<String> {
    unsafe extern "C" {
        fn gnu_get_libc_version() -> *const std::ffi::c_char;
    }
    // SAFETY: glibc documents the result as a pointer to a static NUL-terminated string.
    let p = unsafe { gnu_get_libc_version() };
    if p.is_null() {
        return None;
    }
    // SAFETY: non-null, NUL-terminated and static (see above).
    let version = unsafe { std::ffi::CStr::from_ptr(p) };
    Some(version.to_string_lossy().into_owned())
}

/// The running glibc's version: none on this target.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn glibc_version() -> Option<String> {
    None
}

/// A splitmix64 stream: deterministic inputs from plain integer arithmetic.
struct Inputs(u64);

impl Inputs {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[lo, hi)`, exactly reproducible (53 random bits, one multiply, one add).
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        let unit = (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        lo + (hi - lo) * unit
    }
}

type UnaryF32 = (&'static str, fn(f32) -> f32, f64, f64);
type BinaryF32 = (&'static str, fn(f32, f32) -> f32, [f64; 4]);
type Unary = (&'static str, fn(f64) -> f64, f64, f64, &'static [u64]);
type Binary = (
    &'static str,
    fn(f64, f64) -> f64,
    [f64; 4],
    &'static [[u64; 2]],
);

/// The f64 functions of one argument: name, function, input range and witnesses (bit patterns
/// of inputs where glibc 2.36's FMA and non-FMA variants give different results, found with
/// the measurement in the module documentation; they make sure the fingerprint separates the
/// two even where the sampled inputs happen not to).
const UNARY: &[Unary] = &[
    (
        "exp",
        f64::exp,
        -30.0,
        30.0,
        &[0xc031_9f9b_9adf_9347, 0x4030_7d95_8a11_7464],
    ),
    (
        "log",
        f64::ln,
        1e-3,
        1e3,
        &[0x408e_95af_fc65_167e, 0x407d_d30f_cebb_3bc3],
    ),
    (
        "sin",
        f64::sin,
        -10.0,
        10.0,
        &[0xc023_1dca_aa3c_c582, 0x400b_4624_6699_c9d4],
    ),
    (
        "cos",
        f64::cos,
        -10.0,
        10.0,
        &[0x4012_0570_e9d5_5884, 0x400e_3c37_00b5_8084],
    ),
    (
        "tan",
        f64::tan,
        -1.5,
        1.5,
        &[0xbfab_b24d_ba83_8b80, 0xbfa9_8aee_e4f3_d720],
    ),
    (
        "atan",
        f64::atan,
        -10.0,
        10.0,
        &[0xc004_2c82_003e_ca20, 0x3fc0_b048_205a_a900],
    ),
    (
        "tanh",
        f64::tanh,
        -5.0,
        5.0,
        &[0x3fc5_018d_7dd1_26a0, 0x3fba_48e9_249a_5bc0],
    ),
    (
        "asin",
        f64::asin,
        -1.0,
        1.0,
        &[0xbfec_9a00_fd1f_3598, 0x3fe2_bdd7_71ea_8992],
    ),
    (
        "acos",
        f64::acos,
        -1.0,
        1.0,
        &[0x3fd0_a7d9_a7e6_4d58, 0xbfdd_34e8_4bb0_c1ec],
    ),
    (
        "expm1",
        f64::exp_m1,
        -3.0,
        3.0,
        &[0x4004_5478_85d3_daea, 0x3fd9_be9f_66dc_cc90],
    ),
    (
        "log1p",
        f64::ln_1p,
        -0.9,
        10.0,
        &[0x4013_40f4_194c_d9b1, 0x3fdb_fb47_25fd_f366],
    ),
    ("cbrt", f64::cbrt, -100.0, 100.0, &[]),
];

/// The f64 functions of two arguments: name, function, ranges `[lo0, hi0, lo1, hi1]`, witnesses.
const BINARY: &[Binary] = &[
    (
        "pow",
        f64::powf,
        [0.01, 10.0, -5.0, 5.0],
        &[
            [0x4001_9604_ea65_535c, 0x4010_1e5f_9d75_ab6a],
            [0x4023_c957_f44d_0e9d, 0x4011_a410_6e33_6264],
        ],
    ),
    (
        "atan2",
        f64::atan2,
        [-10.0, 10.0, -10.0, 10.0],
        &[
            [0xc022_b41f_e714_4a7c, 0x4023_4143_c28a_aabc],
            [0xbffe_a387_307b_2630, 0x4018_0537_2e0e_bd20],
        ],
    ),
];

/// The f32 functions MuJoCo imports (`sinf`, `cosf`, `log10f`, `atan2f`, `powf`) and `expf`,
/// `logf`. glibc has FMA variants of some; none differed in the measurement, but a different
/// libm may.
const UNARY_F32: &[UnaryF32] = &[
    ("sinf", f32::sin, -10.0, 10.0),
    ("cosf", f32::cos, -10.0, 10.0),
    ("expf", f32::exp, -30.0, 30.0),
    ("logf", f32::ln, 1e-3, 1e3),
    ("log10f", f32::log10, 1e-3, 1e3),
];

const BINARY_F32: &[BinaryF32] = &[
    ("powf", f32::powf, [0.01, 10.0, -5.0, 5.0]),
    ("atan2f", f32::atan2, [-10.0, 10.0, -10.0, 10.0]),
];

/// Evaluates every function on its inputs (through `black_box`, so nothing is folded at
/// compile time and the loaded libm does the work) and hashes the result bits.
fn compute_fingerprint() -> LibmFingerprint {
    let mut functions: Vec<(&'static str, Hash)> = Vec::new();
    let mut seed = 0u64;
    let mut next_stream = || {
        seed += 1;
        Inputs(seed)
    };
    for &(name, f, lo, hi, witnesses) in UNARY {
        let mut inputs = next_stream();
        let mut bits = Vec::with_capacity(8 * (SAMPLES + witnesses.len()));
        let xs = witnesses
            .iter()
            .map(|&w| f64::from_bits(w))
            .chain((0..SAMPLES).map(|_| inputs.uniform(lo, hi)));
        for x in xs {
            bits.extend_from_slice(&black_box(f)(black_box(x)).to_bits().to_le_bytes());
        }
        functions.push((name, Hash::of(&bits)));
    }
    for &(name, f, [lo0, hi0, lo1, hi1], witnesses) in BINARY {
        let mut inputs = next_stream();
        let mut bits = Vec::with_capacity(8 * (SAMPLES + witnesses.len()));
        let mut pairs: Vec<(f64, f64)> = witnesses
            .iter()
            .map(|&[a, b]| (f64::from_bits(a), f64::from_bits(b)))
            .collect();
        for _ in 0..SAMPLES {
            let a = inputs.uniform(lo0, hi0);
            let b = inputs.uniform(lo1, hi1);
            pairs.push((a, b));
        }
        for (a, b) in pairs {
            bits.extend_from_slice(
                &black_box(f)(black_box(a), black_box(b))
                    .to_bits()
                    .to_le_bytes(),
            );
        }
        functions.push((name, Hash::of(&bits)));
    }
    for &(name, f, lo, hi) in UNARY_F32 {
        let mut inputs = next_stream();
        let mut bits = Vec::with_capacity(4 * SAMPLES);
        for _ in 0..SAMPLES {
            let x = inputs.uniform(lo, hi) as f32;
            bits.extend_from_slice(&black_box(f)(black_box(x)).to_bits().to_le_bytes());
        }
        functions.push((name, Hash::of(&bits)));
    }
    for &(name, f, [lo0, hi0, lo1, hi1]) in BINARY_F32 {
        let mut inputs = next_stream();
        let mut bits = Vec::with_capacity(4 * SAMPLES);
        for _ in 0..SAMPLES {
            let a = inputs.uniform(lo0, hi0) as f32;
            let b = inputs.uniform(lo1, hi1) as f32;
            bits.extend_from_slice(
                &black_box(f)(black_box(a), black_box(b))
                    .to_bits()
                    .to_le_bytes(),
            );
        }
        functions.push((name, Hash::of(&bits)));
    }
    let mut all = FINGERPRINT_VERSION.to_vec();
    for (name, digest) in &functions {
        all.extend_from_slice(name.as_bytes());
        all.push(0);
        all.extend_from_slice(&digest.0);
    }
    LibmFingerprint {
        digest: Hash::of(&all).to_hex(),
        functions: functions
            .into_iter()
            .map(|(name, digest)| (name, digest.to_hex()[..8].to_string()))
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_class_is_the_arch_and_eight_hex_digits_of_the_libm() {
        let class = class();
        let (arch, hex) = class.split_once("-libm-").expect("<arch>-libm-<hex>");
        assert_eq!(arch, std::env::consts::ARCH);
        assert_eq!(hex.len(), 8, "{class}");
        assert!(
            hex.bytes()
                .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b)),
            "{class}"
        );
        assert_eq!(hex, &libm_fingerprint().digest[..8]);
    }

    #[test]
    fn the_fingerprint_is_stable_across_computations() {
        let first = compute_fingerprint();
        let second = compute_fingerprint();
        assert_eq!(first.digest, second.digest);
        assert_eq!(first.functions, second.functions);
        assert_eq!(first.digest, libm_fingerprint().digest);
        assert_eq!(first.digest.len(), 64);
        let names: Vec<_> = first.functions.iter().map(|(n, _)| *n).collect();
        for used in [
            "exp", "log", "pow", "sin", "cos", "tan", "atan2", "asin", "acos",
        ] {
            assert!(names.contains(&used), "{used} is probed");
        }
    }

    #[test]
    fn every_function_is_probed_on_distinct_inputs() {
        // Guards the input generator: a stream stuck on one value would probe nothing.
        let mut inputs = Inputs(1);
        let xs: Vec<u64> = (0..SAMPLES)
            .map(|_| inputs.uniform(-1.0, 1.0).to_bits())
            .collect();
        let mut distinct = xs.clone();
        distinct.sort_unstable();
        distinct.dedup();
        assert_eq!(distinct.len(), xs.len());
        assert!(
            xs.iter()
                .map(|&b| f64::from_bits(b))
                .all(|x| (-1.0..1.0).contains(&x))
        );
    }
}
