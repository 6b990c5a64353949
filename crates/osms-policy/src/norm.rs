//! Observation normalisation with statistics that are updated between PPO iterations and frozen
//! into the trained artifact.

use serde::{Deserialize, Serialize};

/// Per-feature running mean and variance (Chan et al.'s parallel update, merged in a fixed
/// order), in f64 so long runs stay accurate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunningNorm {
    pub count: f64,
    pub mean: Vec<f64>,
    pub var: Vec<f64>,
    /// Normalised values are clipped to ±`clip`.
    pub clip: f32,
}

impl RunningNorm {
    pub fn new(width: usize, clip: f32) -> Self {
        RunningNorm {
            count: 0.0,
            mean: vec![0.0; width],
            var: vec![1.0; width],
            clip,
        }
    }

    /// Folds a batch of rows (`width` each, in order) into the statistics.
    pub fn update(&mut self, rows: &[f32]) {
        let width = self.mean.len();
        if width == 0 || rows.is_empty() {
            return;
        }
        let n = (rows.len() / width) as f64;
        let mut mean = vec![0.0f64; width];
        for row in rows.chunks_exact(width) {
            for (m, &v) in mean.iter_mut().zip(row) {
                *m += f64::from(v);
            }
        }
        mean.iter_mut().for_each(|m| *m /= n);
        let mut var = vec![0.0f64; width];
        for row in rows.chunks_exact(width) {
            for ((s, &v), m) in var.iter_mut().zip(row).zip(&mean) {
                let d = f64::from(v) - m;
                *s += d * d;
            }
        }
        var.iter_mut().for_each(|s| *s /= n);
        let total = self.count + n;
        for j in 0..width {
            let delta = mean[j] - self.mean[j];
            let m2 = self.var[j] * self.count + var[j] * n + delta * delta * self.count * n / total;
            self.mean[j] += delta * n / total;
            self.var[j] = m2 / total;
        }
        self.count = total;
    }

    /// (x − mean) / √(var + 1e-8), clipped.
    pub fn apply(&self, x: &[f32]) -> Vec<f32> {
        x.iter()
            .zip(self.mean.iter().zip(&self.var))
            .map(|(&v, (m, s))| {
                (((f64::from(v) - m) / (s + 1e-8).sqrt()) as f32).clamp(-self.clip, self.clip)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batched_updates_equal_one_pass_over_everything() {
        let rows: Vec<f32> = (0..60).map(|i| ((i * 37) % 11) as f32 - 3.0).collect();
        let mut whole = RunningNorm::new(3, 5.0);
        whole.update(&rows);
        let mut parts = RunningNorm::new(3, 5.0);
        for chunk in rows.chunks(9) {
            parts.update(chunk);
        }
        for j in 0..3 {
            let col: Vec<f64> = rows
                .iter()
                .skip(j)
                .step_by(3)
                .map(|&v| f64::from(v))
                .collect();
            let mean = col.iter().sum::<f64>() / col.len() as f64;
            let var = col.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / col.len() as f64;
            assert!((whole.mean[j] - mean).abs() < 1e-12 && (whole.var[j] - var).abs() < 1e-12);
            assert!((parts.mean[j] - mean).abs() < 1e-12 && (parts.var[j] - var).abs() < 1e-12);
        }
        let z = whole.apply(&rows[..3]);
        assert!(z.iter().all(|v| v.abs() <= 5.0));
    }
}
