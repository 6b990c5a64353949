//! Small dense linear algebra on row-major `f64` matrices, each operation in one fixed order
//! (its results enter artifacts): the crate's one Cholesky factorisation, with the solve the
//! geodesic equation needs and the ridge-regularised factor of a possibly singular covariance
//! the action-error model needs.

// Row-major indexing by (i, j) reads as the formulas do; iterator zips would obscure them.
#![allow(clippy::needless_range_loop)]

/// Lower Cholesky factor L (M = L Lᵀ) of a symmetric d × d matrix, reading its lower triangle;
/// None if a pivot is not positive and finite.
pub(crate) fn cholesky(m: &[f64], d: usize) -> Option<Vec<f64>> {
    let mut l = vec![0.0; d * d];
    for j in 0..d {
        let mut s = m[j * d + j];
        for k in 0..j {
            s -= l[j * d + k] * l[j * d + k];
        }
        if !s.is_finite() || s <= 0.0 {
            return None;
        }
        let ljj = s.sqrt();
        l[j * d + j] = ljj;
        for i in j + 1..d {
            let mut s = m[i * d + j];
            for k in 0..j {
                s -= l[i * d + k] * l[j * d + k];
            }
            l[i * d + j] = s / ljj;
        }
    }
    Some(l)
}

/// M x = b for symmetric positive definite M; all NaN if the factorisation fails.
pub(crate) fn solve_spd(m: &[f64], d: usize, b: &[f64]) -> Vec<f64> {
    let Some(l) = cholesky(m, d) else {
        return vec![f64::NAN; d];
    };
    let mut y = vec![0.0; d];
    for i in 0..d {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i * d + k] * y[k];
        }
        y[i] = s / l[i * d + i];
    }
    let mut x = vec![0.0; d];
    for i in (0..d).rev() {
        let mut s = y[i];
        for k in i + 1..d {
            s -= l[k * d + i] * x[k];
        }
        x[i] = s / l[i * d + i];
    }
    x
}

/// L Lᵀ for a c×c row-major L.
pub(crate) fn lower_times_transpose(l: &[f64], c: usize) -> Vec<f64> {
    let mut q = vec![0.0; c * c];
    for i in 0..c {
        for j in 0..c {
            let mut s = 0.0;
            for m in 0..c {
                s += l[i * c + m] * l[j * c + m];
            }
            q[i * c + j] = s;
        }
    }
    q
}

/// Cholesky factor of a covariance that may be singular (a channel the student copies
/// exactly, collinear channels). A ridge of 1e-12·trace/c, then ten times larger each retry,
/// is added to the diagonal until the factorization succeeds: it is far below any physically
/// meaningful action noise but lets the AR process be driven by a valid L. A zero matrix gives
/// a zero L.
pub(crate) fn robust_cholesky(a: &[f64], c: usize) -> Vec<f64> {
    if let Some(l) = cholesky(a, c) {
        return l;
    }
    let trace: f64 = (0..c).map(|k| a[k * c + k]).sum();
    if trace.is_nan() || trace <= 0.0 {
        return vec![0.0; c * c];
    }
    let mut ridge = 1e-12 * trace / c as f64;
    // A ridge of trace/c·10 exceeds the largest eigenvalue of a PSD matrix, so 14 attempts
    // always suffice for a covariance.
    for _ in 0..16 {
        let mut b = a.to_vec();
        for k in 0..c {
            b[k * c + k] += ridge;
        }
        if let Some(l) = cholesky(&b, c) {
            return l;
        }
        ridge *= 10.0;
    }
    // Unreachable for a covariance; keep the per-channel scale rather than fail.
    let mut l = vec![0.0; c * c];
    for k in 0..c {
        l[k * c + k] = a[k * c + k].max(0.0).sqrt();
    }
    l
}

#[cfg(test)]
mod tests {
    use super::*;

    fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
    }

    /// A symmetric positive definite 4 × 4 matrix: Bᵀ B + I for a fixed B.
    fn spd() -> Vec<f64> {
        let b = [
            1.0, 2.0, 0.5, -1.0, 0.0, 1.5, -0.5, 2.0, 3.0, -1.0, 1.0, 0.0, 0.5, 0.5, 2.5, 1.0,
        ];
        let mut m = vec![0.0; 16];
        for i in 0..4 {
            for j in 0..4 {
                m[i * 4 + j] = (0..4).map(|k| b[k * 4 + i] * b[k * 4 + j]).sum::<f64>()
                    + if i == j { 1.0 } else { 0.0 };
            }
        }
        m
    }

    #[test]
    fn cholesky_matches_the_closed_form_of_a_2x2_matrix() {
        // [[a, b], [b, c]] = L Lᵀ with L = [[√a, 0], [b/√a, √(c − b²/a)]].
        let (a, b, c) = (4.0, 2.0, 5.0);
        let l = cholesky(&[a, b, b, c], 2).expect("positive definite");
        let expected = [a.sqrt(), 0.0, b / a.sqrt(), (c - b * b / a).sqrt()];
        assert!(max_abs_diff(&l, &expected) < 1e-15, "{l:?}");
    }

    #[test]
    fn cholesky_reproduces_the_matrix_and_solve_inverts_it() {
        let m = spd();
        let l = cholesky(&m, 4).expect("positive definite");
        assert!(
            (0..4).all(|i| (i + 1..4).all(|j| l[i * 4 + j] == 0.0)),
            "lower"
        );
        assert!(max_abs_diff(&lower_times_transpose(&l, 4), &m) < 1e-12);
        let x = [0.5, -1.0, 2.0, 0.25];
        let b: Vec<f64> = (0..4)
            .map(|i| (0..4).map(|j| m[i * 4 + j] * x[j]).sum())
            .collect();
        assert!(max_abs_diff(&solve_spd(&m, 4, &b), &x) < 1e-12);
    }

    #[test]
    fn indefinite_and_singular_matrices() {
        assert_eq!(cholesky(&[1.0, 2.0, 2.0, 1.0], 2), None, "indefinite");
        assert!(
            solve_spd(&[1.0, 2.0, 2.0, 1.0], 2, &[1.0, 1.0])
                .iter()
                .all(|v| v.is_nan())
        );
        // A rank-one covariance (two copies of one channel) gets a tiny ridge, not a failure.
        let singular = [1.0, 1.0, 1.0, 1.0];
        assert_eq!(cholesky(&singular, 2), None);
        let l = robust_cholesky(&singular, 2);
        assert!(
            max_abs_diff(&lower_times_transpose(&l, 2), &singular) < 1e-9,
            "{l:?}"
        );
        assert_eq!(robust_cholesky(&[0.0; 4], 2), vec![0.0; 4]);
    }
}
