//! Transcendentals that run in SIMD lanes with the same bits as scalar code.
//!
//! `libm` (a port of musl) gives the same bits on every CPU but looks values up in tables, so it
//! runs one element at a time; the activations of a batch-256 MLP spent more time in `expf` than
//! in the matrix products. [`exp`] uses only `+ − × /`, a min/max clamp and exponent bit
//! arithmetic, each exactly rounded by IEEE 754, so a lane computes what scalar code computes.

use crate::level::{Level, dispatch, per_level};

const LOG2E: f32 = std::f32::consts::LOG2_E;
/// ln 2 split so that `n · LN2_HI` is exact for |n| < 2¹⁵ (Cody–Waite reduction).
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;
/// Adding and subtracting 1.5 · 2²³ rounds an f32 below 2²² to the nearest integer (ties to
/// even) with two exactly specified additions.
const ROUND: f32 = 12_582_912.0;
/// Minimax coefficients of (eʳ − 1 − r) / r² on |r| ≤ ln2 / 2, from Cephes' `expf`.
const P: [f32; 6] = [
    1.987_569_1e-4,
    1.398_199_9e-3,
    8.333_452e-3,
    4.166_579_6e-2,
    0.166_666_65,
    0.5,
];

/// eˣ; +∞ above ~88.72, gradual underflow to +0 below ~−103.9, NaN for NaN. Tested against
/// `libm::expf`, not the true value: within 2 ulp on a sweep of about 262,000 points (step
/// 0.000731) over [−103, 88.7) where the result is normal; the sweep's subnormal results are
/// not held to any bound. Special values are tested separately.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    // Beyond these, the result is ∞ or 0 anyway; clamping keeps the exponent arithmetic in range
    // and passes NaN through.
    let x = x.clamp(-104.0, 89.0);
    let n = (x * LOG2E + ROUND) - ROUND;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let mut poly = P[0];
    for p in &P[1..] {
        poly = poly * r + *p;
    }
    let e_r = poly * (r * r) + r + 1.0;
    // 2ⁿ in two factors so both are normal floats for n in [−150, 129]; the first product is
    // exact, the second rounds once (only when the result is subnormal).
    let n = n as i32;
    let half = n >> 1;
    let scale = |k: i32| f32::from_bits(((k + 127) as u32) << 23);
    e_r * scale(half) * scale(n - half)
}

/// SiLU, x·σ(x) = x / (1 + e⁻ˣ).
#[inline(always)]
pub fn silu(x: f32) -> f32 {
    x / (1.0 + exp(-x))
}

/// SiLU and its derivative σ(x)·(1 + x·(1 − σ(x))), with one exponential.
#[inline(always)]
pub fn silu_with_derivative(x: f32) -> (f32, f32) {
    let e = exp(-x);
    let s = 1.0 / (1.0 + e);
    (x / (1.0 + e), s * (1.0 + x * (1.0 - s)))
}

#[inline(always)]
fn silu_in_place(z: &mut [f32]) {
    for v in z {
        *v = silu(*v);
    }
}

#[inline(always)]
fn silu_and_slope(z: &mut [f32], slope: &mut [f32]) {
    for (v, d) in z.iter_mut().zip(slope) {
        (*v, *d) = silu_with_derivative(*v);
    }
}

per_level!(silu_baseline, silu_avx2, silu_avx512, (z: &mut [f32]) => silu_in_place(z));
per_level!(silu_slope_baseline, silu_slope_avx2, silu_slope_avx512,
    (z: &mut [f32], slope: &mut [f32]) => silu_and_slope(z, slope));

/// `z ← silu(z)` on the widest level.
pub(crate) fn silu_slice(z: &mut [f32]) {
    dispatch!(Level::detected(), silu_baseline, silu_avx2, silu_avx512(z));
}

/// `z ← silu(z)`, `slope ← silu′(z)` on a given level.
pub(crate) fn silu_slice_with_slope_at(level: Level, z: &mut [f32], slope: &mut [f32]) {
    assert_eq!(z.len(), slope.len());
    dispatch!(
        level,
        silu_slope_baseline,
        silu_slope_avx2,
        silu_slope_avx512(z, slope)
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distance in units in the last place between two finite f32 of the same sign.
    fn ulps(a: f32, b: f32) -> u32 {
        (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs() as u32
    }

    #[test]
    fn exp_is_within_two_ulp_of_libm_over_the_whole_range() {
        let mut worst = (0u32, 0.0f32);
        let mut x = -103.0f32;
        while x < 88.7 {
            let (ours, theirs) = (exp(x), libm::expf(x));
            // Subnormal results have fewer significant bits; compare those absolutely.
            let err = if theirs < f32::MIN_POSITIVE {
                u32::from((ours - theirs).abs() > f32::from_bits(1))
            } else {
                ulps(ours, theirs)
            };
            if err > worst.0 {
                worst = (err, x);
            }
            x += 0.000_731;
        }
        assert!(worst.0 <= 2, "{} ulp at x = {}", worst.0, worst.1);
    }

    #[test]
    fn exp_special_values() {
        assert_eq!(exp(0.0), 1.0);
        assert_eq!(exp(1.0), libm::expf(1.0));
        assert_eq!(exp(f32::INFINITY), f32::INFINITY);
        assert_eq!(exp(89.0), f32::INFINITY);
        assert_eq!(exp(f32::NEG_INFINITY), 0.0);
        assert_eq!(exp(-200.0), 0.0);
        assert!(exp(f32::NAN).is_nan());
        assert!(exp(-100.0) > 0.0 && exp(-100.0) < f32::MIN_POSITIVE);
    }

    #[test]
    fn every_level_gives_the_scalar_bits() {
        let mut r = osms_core::rng::stream(5, "math", "test", 0);
        let z: Vec<f32> = (0..1003)
            .map(|_| osms_core::rng::uniform(&mut r, -30.0, 30.0) as f32)
            .chain([0.0, -0.0, 1e-30, -1e-30, 95.0, -95.0])
            .collect();
        let scalar: Vec<(u32, u32)> = z
            .iter()
            .map(|&x| {
                let (y, d) = silu_with_derivative(x);
                (y.to_bits(), d.to_bits())
            })
            .collect();
        for level in Level::available() {
            let mut y = z.clone();
            let mut d = vec![0.0; z.len()];
            silu_slice_with_slope_at(level, &mut y, &mut d);
            let got: Vec<(u32, u32)> = y
                .iter()
                .zip(&d)
                .map(|(y, d)| (y.to_bits(), d.to_bits()))
                .collect();
            assert_eq!(got, scalar, "{level:?}");
        }
        let mut y = z.clone();
        silu_slice(&mut y);
        assert!(y.iter().zip(&scalar).all(|(y, s)| y.to_bits() == s.0));
    }
}
