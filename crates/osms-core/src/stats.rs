//! Aggregation over run seeds: mean and sample standard deviation.

use serde::{Deserialize, Serialize};

/// Mean and sample standard deviation (n − 1) of per-seed values.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MeanSd {
    pub mean: f64,
    /// `None` for a single value.
    pub sd: Option<f64>,
    pub n: usize,
}

impl MeanSd {
    /// `None` for no values.
    pub fn of(values: &[f64]) -> Option<MeanSd> {
        let n = values.len();
        if n == 0 {
            return None;
        }
        let mean = values.iter().sum::<f64>() / n as f64;
        let sd = (n > 1).then(|| {
            let ss: f64 = values.iter().map(|v| (v - mean) * (v - mean)).sum();
            (ss / (n - 1) as f64).sqrt()
        });
        Some(MeanSd { mean, sd, n })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_sd_divides_by_n_minus_one() {
        let m = MeanSd::of(&[0.80, 0.90, 0.85]).expect("values");
        assert!((m.mean - 0.85).abs() < 1e-12);
        // Deviations ±0.05 and 0: (0.0025 + 0.0025) / 2 = 0.0025.
        assert!((m.sd.expect("sd") - 0.05).abs() < 1e-12);
        assert_eq!(m.n, 3);
        assert_eq!(MeanSd::of(&[2.0]).expect("one").sd, None);
        assert_eq!(MeanSd::of(&[]), None);
    }
}
