//! LayerNorm, the sinusoidal scalar embedding, the diagonal-Gaussian head and softmax
//! cross-entropy, each with its gradient.

// The loops index several parallel arrays (mean, log-std, gradients) by the same i, j.
#![allow(clippy::needless_range_loop)]

use serde::{Deserialize, Serialize};

use crate::Matrix;

const LN_2PI: f32 = 1.837_877_1;

/// Per-row normalisation with a learned scale and shift.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LayerNorm {
    pub gamma: Vec<f32>,
    pub beta: Vec<f32>,
    pub eps: f32,
}

/// What LayerNorm's backward pass needs.
pub struct LayerNormCache {
    normed: Matrix,
    inv_std: Vec<f32>,
}

impl LayerNorm {
    pub fn new(width: usize) -> Self {
        LayerNorm {
            gamma: vec![1.0; width],
            beta: vec![0.0; width],
            eps: 1e-5,
        }
    }

    pub fn forward(&self, x: &Matrix) -> (Matrix, LayerNormCache) {
        let n = x.cols as f32;
        let mut normed = Matrix::zeros(x.rows, x.cols);
        let mut y = Matrix::zeros(x.rows, x.cols);
        let mut inv_std = Vec::with_capacity(x.rows);
        for i in 0..x.rows {
            let row = x.row(i);
            let mean = row.iter().sum::<f32>() / n;
            let var = row.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / n;
            let r = 1.0 / libm::sqrtf(var + self.eps);
            inv_std.push(r);
            for (j, v) in row.iter().enumerate() {
                let h = (v - mean) * r;
                normed.set(i, j, h);
                y.set(i, j, h * self.gamma[j] + self.beta[j]);
            }
        }
        (y, LayerNormCache { normed, inv_std })
    }

    /// dL/dx, dL/dγ and dL/dβ from dL/dy.
    pub fn backward(&self, cache: &LayerNormCache, dy: &Matrix) -> (Matrix, Vec<f32>, Vec<f32>) {
        let n = dy.cols as f32;
        let mut dx = Matrix::zeros(dy.rows, dy.cols);
        let mut dgamma = vec![0.0; dy.cols];
        let mut dbeta = vec![0.0; dy.cols];
        for i in 0..dy.rows {
            let h = cache.normed.row(i);
            let g = dy.row(i);
            let dh: Vec<f32> = g
                .iter()
                .zip(&self.gamma)
                .map(|(g, gamma)| g * gamma)
                .collect();
            let sum_dh: f32 = dh.iter().sum();
            let sum_dh_h: f32 = dh.iter().zip(h).map(|(a, b)| a * b).sum();
            for j in 0..dy.cols {
                dgamma[j] += g[j] * h[j];
                dbeta[j] += g[j];
                dx.set(
                    i,
                    j,
                    cache.inv_std[i] / n * (n * dh[j] - sum_dh - h[j] * sum_dh_h),
                );
            }
        }
        (dx, dgamma, dbeta)
    }
}

/// The sinusoidal embedding of a scalar (flow-matching time): `[sin(t·f_k)…, cos(t·f_k)…]` with
/// `f_k = max_period^(-k / half)`.
pub fn sinusoidal_embedding(t: &[f32], dim: usize, max_period: f32) -> Matrix {
    assert!(
        dim.is_multiple_of(2),
        "the embedding dimension must be even"
    );
    let half = dim / 2;
    let freqs: Vec<f32> = (0..half)
        .map(|k| libm::expf(-libm::logf(max_period) * k as f32 / half as f32))
        .collect();
    Matrix::from_fn(t.len(), dim, |i, j| {
        if j < half {
            libm::sinf(t[i] * freqs[j])
        } else {
            libm::cosf(t[i] * freqs[j - half])
        }
    })
}

/// d L / d t of [`sinusoidal_embedding`], from d L / d embedding.
pub fn sinusoidal_embedding_backward(t: &[f32], d_emb: &Matrix, max_period: f32) -> Vec<f32> {
    let half = d_emb.cols / 2;
    (0..t.len())
        .map(|i| {
            (0..half)
                .map(|k| {
                    let f = libm::expf(-libm::logf(max_period) * k as f32 / half as f32);
                    d_emb.get(i, k) * f * libm::cosf(t[i] * f)
                        - d_emb.get(i, k + half) * f * libm::sinf(t[i] * f)
                })
                .sum()
        })
        .collect()
}

/// A diagonal Gaussian per row: mean and log standard deviation.
pub struct DiagGaussian<'a> {
    pub mean: &'a Matrix,
    pub log_std: &'a Matrix,
}

/// Gradients with respect to the mean and the log standard deviation.
pub struct GaussianGrad {
    pub mean: Matrix,
    pub log_std: Matrix,
}

impl DiagGaussian<'_> {
    /// Per-row log-density of `x`, and d(Σ_rows upstream·logp)/d(mean, log_std).
    pub fn log_prob(&self, x: &Matrix, upstream: &[f32]) -> (Vec<f32>, GaussianGrad) {
        let (m, s) = (self.mean, self.log_std);
        let mut lp = vec![0.0; m.rows];
        let mut gm = Matrix::zeros(m.rows, m.cols);
        let mut gs = Matrix::zeros(m.rows, m.cols);
        for i in 0..m.rows {
            for j in 0..m.cols {
                let sigma = libm::expf(s.get(i, j));
                let z = (x.get(i, j) - m.get(i, j)) / sigma;
                lp[i] += -0.5 * z * z - s.get(i, j) - 0.5 * LN_2PI;
                gm.set(i, j, upstream[i] * z / sigma);
                gs.set(i, j, upstream[i] * (z * z - 1.0));
            }
        }
        (
            lp,
            GaussianGrad {
                mean: gm,
                log_std: gs,
            },
        )
    }

    /// Per-row entropy; its gradient with respect to every log_std entry is 1 (none for the mean).
    pub fn entropy(&self) -> Vec<f32> {
        let s = self.log_std;
        (0..s.rows)
            .map(|i| s.row(i).iter().map(|ls| ls + 0.5 * (LN_2PI + 1.0)).sum())
            .collect()
    }

    /// Per-row KL(self ‖ N(0, I)) (the CVAE's prior term), and its gradient (upstream 1 per row).
    pub fn kl_to_standard(&self) -> (Vec<f32>, GaussianGrad) {
        let (m, s) = (self.mean, self.log_std);
        let mut kl = vec![0.0; m.rows];
        let mut gm = Matrix::zeros(m.rows, m.cols);
        let mut gs = Matrix::zeros(m.rows, m.cols);
        for i in 0..m.rows {
            for j in 0..m.cols {
                let (mu, ls) = (m.get(i, j), s.get(i, j));
                let var = libm::expf(2.0 * ls);
                kl[i] += 0.5 * (var + mu * mu - 1.0) - ls;
                gm.set(i, j, mu);
                gs.set(i, j, var - 1.0);
            }
        }
        (
            kl,
            GaussianGrad {
                mean: gm,
                log_std: gs,
            },
        )
    }
}

/// Mean softmax cross-entropy of `logits` against class `labels`, and d loss / d logits.
pub fn softmax_cross_entropy(logits: &Matrix, labels: &[usize]) -> (f32, Matrix) {
    assert_eq!(labels.len(), logits.rows);
    let n = logits.rows as f32;
    let mut losses = Vec::with_capacity(logits.rows);
    let mut grad = Matrix::zeros(logits.rows, logits.cols);
    for (i, &label) in labels.iter().enumerate() {
        let row = logits.row(i);
        let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let exps: Vec<f32> = row.iter().map(|v| libm::expf(v - max)).collect();
        let total: f32 = exps.iter().sum();
        losses.push(libm::logf(total) + max - row[label]);
        for j in 0..logits.cols {
            let p = exps[j] / total;
            grad.set(i, j, (p - if j == label { 1.0 } else { 0.0 }) / n);
        }
    }
    (crate::kernels::sum(&losses) / n, grad)
}
