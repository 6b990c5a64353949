//! The OSW motion manifold (paper 4.1): a conditional VAE over arm-action snippets ζ
//! (N_ARM channels × H_OS steps, normalised actions) conditioned on ω̄.
//!
//! Encoder q(z | ζ, ω̄) and conditional prior p(z | ω̄) are diagonal Gaussians; the decoder
//! G(z, ω̄) ends in tanh, so decoded actions respect the action bounds. The loss per window is
//! ‖G − ζ‖²_{W_a} + λ_s Σ ‖Δ²_t G‖²_{W_a} + β KL(q ‖ p), with z drawn by reparameterisation.
//! The unconditional variant (an ablation, paper 6.4) drops ω̄ everywhere and uses the prior
//! N(0, I).

use osms_core::rng::{self, StreamRng};
use osms_nn::{Activation, Adam, AdamConfig, Matrix, Mlp, Schedule, flatten_grads};
use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// Log standard deviations are clamped here: keeps exp() finite early in training and keeps
/// the prior from collapsing onto a point.
const LOG_STD_MIN: f32 = -6.0;
const LOG_STD_MAX: f32 = 2.0;
/// Features whose spread over the training windows is below this are only centred.
const MIN_STD: f32 = 1e-6;

/// The manifold's network and training settings. Every default lives here; docs/method.md
/// says how they were chosen.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ManifoldParams {
    /// Condition on ω̄ (the method); false gives the unconditional ablation.
    pub conditional: bool,
    /// Latent dimension (paper: 8).
    pub latent: usize,
    /// Hidden widths of the encoder, prior and decoder MLPs.
    pub hidden: Vec<usize>,
    /// λ_s: weight of the squared second differences in time of the decoded actions.
    pub lambda_s: f32,
    /// β: weight of KL(q ‖ p).
    pub beta: f32,
    /// Weight of KL(p(z | ω̄) ‖ N(0, I)). A learned conditional prior leaves the latent scale
    /// free (q follows p wherever it goes); this anchors it, so the box Z = [−3, 3]^latent of the
    /// search means what it says.
    pub prior_anchor: f32,
    pub epochs: u32,
    pub batch: usize,
    pub lr: f32,
    /// Every `holdout_every`-th window (by index) is held out for the reconstruction error.
    pub holdout_every: usize,
}

impl Default for ManifoldParams {
    fn default() -> Self {
        ManifoldParams {
            conditional: true,
            latent: 8,
            hidden: vec![128, 128],
            lambda_s: 0.1,
            beta: 0.0005,
            prior_anchor: 0.01,
            epochs: 300,
            batch: 64,
            lr: 1e-3,
            holdout_every: 10,
        }
    }
}

/// One training window: ζ (step-major, N_ARM channels) and ω̄.
#[derive(Debug, Clone, PartialEq)]
pub struct Window<'a> {
    pub zeta: &'a [f32],
    pub omega_bar: &'a [f32],
}

/// One point of the learning curve.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CurvePoint {
    pub epoch: u32,
    /// Mean per-window training loss terms over the epoch's batches.
    pub reconstruction: f32,
    pub smoothness: f32,
    pub kl: f32,
    /// Held-out ‖G(μ_q, ω̄) − ζ‖²_{W_a} per element (encoder mean, no sampling).
    pub heldout_reconstruction: f32,
    /// The same from the prior mean, i.e. what ω̄ alone predicts.
    pub heldout_prior_reconstruction: f32,
}

/// A trained manifold: networks, frozen normalisation and W_a, and how training went.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Cvae {
    pub params: ManifoldParams,
    pub h_os: usize,
    pub channels: usize,
    /// Diagonal of W_a over ζ's entries: per channel 1 / variance over the training windows,
    /// repeated for every step, so ‖ζ − mean‖²_{W_a} is 1 per element on average. Every later
    /// stage measures ‖·‖_{W_a} with it.
    pub w_a: Vec<f32>,
    /// ω̄ normalisation frozen at training time (empty for the unconditional manifold).
    pub omega_mean: Vec<f32>,
    pub omega_std: Vec<f32>,
    /// [ζ ‖ ω̄n] → [μ_q ‖ log σ_q].
    pub encoder: Mlp,
    /// ω̄n → [μ_p ‖ log σ_p]; None: the prior is N(0, I).
    pub prior: Option<Mlp>,
    /// [z ‖ ω̄n] → ζ (tanh output).
    pub decoder: Mlp,
    pub windows_train: usize,
    pub windows_heldout: usize,
    pub curve: Vec<CurvePoint>,
}

impl Cvae {
    pub fn latent(&self) -> usize {
        self.params.latent
    }

    pub fn zeta_len(&self) -> usize {
        self.h_os * self.channels
    }

    /// ω̄ normalised with the frozen statistics; empty for the unconditional manifold.
    pub fn normalise(&self, omega_bar: &[f32]) -> Vec<f32> {
        if !self.params.conditional {
            return Vec::new();
        }
        omega_bar
            .iter()
            .zip(self.omega_mean.iter().zip(&self.omega_std))
            .map(|(x, (m, s))| (x - m) / s)
            .collect()
    }

    /// Decoder input rows [z ‖ ω̄n].
    pub fn decoder_input(&self, zs: &[Vec<f32>], omega_n: &[f32]) -> Matrix {
        let width = self.latent() + omega_n.len();
        let mut data = Vec::with_capacity(zs.len() * width);
        for z in zs {
            data.extend_from_slice(z);
            data.extend_from_slice(omega_n);
        }
        Matrix::from_vec(zs.len(), width, data)
    }

    /// G(z, ω̄) for each z (ω̄ already normalised).
    pub fn decode(&self, zs: &[Vec<f32>], omega_n: &[f32]) -> Vec<Vec<f32>> {
        let out = self.decoder.forward(&self.decoder_input(zs, omega_n));
        (0..out.rows).map(|i| out.row(i).to_vec()).collect()
    }

    /// The prior's mean and log σ at ω̄ (normalised): N(0, I) for the unconditional manifold.
    pub fn prior_at(&self, omega_n: &[f32]) -> (Vec<f32>, Vec<f32>) {
        let l = self.latent();
        match &self.prior {
            None => (vec![0.0; l], vec![0.0; l]),
            Some(p) => {
                let out = p.forward(&Matrix::from_vec(1, omega_n.len(), omega_n.to_vec()));
                let (m, s) = split_gaussian(&out, l);
                (m.row(0).to_vec(), s.row(0).to_vec())
            }
        }
    }

    /// The encoder's mean and log σ for one window (ω̄ normalised).
    pub fn encode(&self, zeta: &[f32], omega_n: &[f32]) -> (Vec<f32>, Vec<f32>) {
        let mut x = zeta.to_vec();
        x.extend_from_slice(omega_n);
        let out = self.encoder.forward(&Matrix::from_vec(1, x.len(), x));
        let (m, s) = split_gaussian(&out, self.latent());
        (m.row(0).to_vec(), s.row(0).to_vec())
    }

    /// ‖a − b‖²_{W_a}.
    pub fn weighted_sq(&self, a: &[f32], b: &[f32]) -> f64 {
        weighted_sq(&self.w_a, a, b)
    }
}

/// ‖a − b‖²_W for a diagonal W, summed in index order in f64.
pub fn weighted_sq(w: &[f32], a: &[f32], b: &[f32]) -> f64 {
    let mut s = 0.0f64;
    for ((w, a), b) in w.iter().zip(a).zip(b) {
        let d = f64::from(*a) - f64::from(*b);
        s += f64::from(*w) * d * d;
    }
    s
}

/// Splits [mean ‖ log σ] rows, clamping log σ.
fn split_gaussian(out: &Matrix, l: usize) -> (Matrix, Matrix) {
    let mean = Matrix::from_fn(out.rows, l, |i, j| out.get(i, j));
    let log_std = Matrix::from_fn(out.rows, l, |i, j| {
        out.get(i, l + j).clamp(LOG_STD_MIN, LOG_STD_MAX)
    });
    (mean, log_std)
}

/// Gradient of [mean ‖ log σ] outputs from gradients on the clamped parts: none where the
/// clamp held.
fn join_gaussian_grad(out: &Matrix, l: usize, gm: &Matrix, gs: &Matrix) -> Matrix {
    Matrix::from_fn(out.rows, 2 * l, |i, j| {
        if j < l {
            gm.get(i, j)
        } else {
            let raw = out.get(i, j);
            if (LOG_STD_MIN..=LOG_STD_MAX).contains(&raw) {
                gs.get(i, j - l)
            } else {
                0.0
            }
        }
    })
}

/// Per-element loss terms of one batch and the gradients of the three networks.
struct BatchLoss {
    reconstruction: f32,
    smoothness: f32,
    kl: f32,
}

/// Trains the manifold on `windows` (all complete, from D_M). Window i is held out when
/// i % holdout_every == holdout_every − 1. Randomness: the shuffle of epoch e from stream
/// (`name`, "shuffle", e) and the reparameterisation noise of epoch e from ("eps", e), so the
/// weights depend only on (seed, stage) and the data; `progress` is called once per epoch.
pub fn train(
    windows: &[Window<'_>],
    h_os: usize,
    channels: usize,
    params: &ManifoldParams,
    (seed, stage): (u64, &str),
    progress: &dyn Fn(),
) -> Result<Cvae> {
    let p = params;
    for (v, name) in [
        (p.latent, "latent"),
        (p.batch, "batch"),
        (p.holdout_every, "holdout_every"),
        (p.epochs as usize, "epochs"),
    ] {
        if v == 0 {
            return Err(Error::Params(format!("params.{name} must be at least 1")));
        }
    }
    let zeta_len = h_os * channels;
    let omega_len = windows.first().map_or(0, |w| w.omega_bar.len());
    for (index, w) in windows.iter().enumerate() {
        if w.zeta.len() != zeta_len {
            return Err(Error::WindowZetaLength {
                index,
                got: w.zeta.len(),
                expected: zeta_len,
            });
        }
        if w.omega_bar.len() != omega_len {
            return Err(Error::WindowOmegaLength {
                index,
                got: w.omega_bar.len(),
                expected: omega_len,
            });
        }
    }
    let held = |i: usize| p.holdout_every > 1 && i % p.holdout_every == p.holdout_every - 1;
    let train_idx: Vec<usize> = (0..windows.len()).filter(|&i| !held(i)).collect();
    let held_idx: Vec<usize> = (0..windows.len()).filter(|&i| held(i)).collect();
    if train_idx.len() < 2 {
        return Err(Error::TooFewWindows(train_idx.len()));
    }

    let w_a = channel_weights(windows, &train_idx, h_os, channels);
    let (omega_mean, omega_std) = if p.conditional {
        feature_stats(windows, &train_idx, omega_len)
    } else {
        (Vec::new(), Vec::new())
    };
    let cond_len = omega_mean.len();
    let l = p.latent;
    let sizes = |input: usize, output: usize| {
        let mut s = vec![input];
        s.extend(&p.hidden);
        s.push(output);
        s
    };
    let mut model = Cvae {
        params: p.clone(),
        h_os,
        channels,
        w_a,
        omega_mean,
        omega_std,
        encoder: Mlp::new(
            &sizes(zeta_len + cond_len, 2 * l),
            Activation::Elu,
            Activation::Identity,
            seed,
            &format!("{stage}/encoder"),
        )?,
        prior: (cond_len > 0)
            .then(|| {
                Mlp::new(
                    &sizes(cond_len, 2 * l),
                    Activation::Elu,
                    Activation::Identity,
                    seed,
                    &format!("{stage}/prior"),
                )
            })
            .transpose()?,
        decoder: Mlp::new(
            &sizes(l + cond_len, zeta_len),
            Activation::Elu,
            Activation::Tanh,
            seed,
            &format!("{stage}/decoder"),
        )?,
        windows_train: train_idx.len(),
        windows_heldout: held_idx.len(),
        curve: Vec::new(),
    };
    let omega_n: Vec<Vec<f32>> = windows
        .iter()
        .map(|w| model.normalise(w.omega_bar))
        .collect();

    let batches_per_epoch = train_idx.len().div_ceil(p.batch);
    let mut adam = Adam::new(
        AdamConfig {
            max_grad_norm: Some(5.0),
            ..AdamConfig::default()
        },
        Schedule::Cosine {
            lr: p.lr,
            min_lr: p.lr * 0.1,
            steps: p.epochs * batches_per_epoch as u32,
        },
    );
    for epoch in 0..p.epochs {
        let mut order = train_idx.clone();
        shuffle(
            &mut order,
            &mut rng::stream(seed, stage, "shuffle", u64::from(epoch)),
        );
        let mut eps_rng = rng::stream(seed, stage, "eps", u64::from(epoch));
        let mut sums = [0.0f64; 3];
        for batch in order.chunks(p.batch) {
            let (loss, grads) = batch_step(&model, windows, &omega_n, batch, &mut eps_rng);
            sums[0] += f64::from(loss.reconstruction);
            sums[1] += f64::from(loss.smoothness);
            sums[2] += f64::from(loss.kl);
            let mut params: Vec<&mut [f32]> = model.encoder.params_mut();
            if let Some(prior) = &mut model.prior {
                params.extend(prior.params_mut());
            }
            params.extend(model.decoder.params_mut());
            let flat: Vec<&[f32]> = grads.iter().flat_map(|g| flatten_grads(g)).collect();
            adam.update(&mut params, &flat);
        }
        let n = batches_per_epoch as f64;
        let (heldout, heldout_prior) = heldout_errors(&model, windows, &omega_n, &held_idx);
        model.curve.push(CurvePoint {
            epoch,
            reconstruction: (sums[0] / n) as f32,
            smoothness: (sums[1] / n) as f32,
            kl: (sums[2] / n) as f32,
            heldout_reconstruction: heldout,
            heldout_prior_reconstruction: heldout_prior,
        });
        progress();
    }
    Ok(model)
}

/// Fisher–Yates from the stream.
fn shuffle(v: &mut [usize], rng: &mut StreamRng) {
    for i in (1..v.len()).rev() {
        let j = rng::below(rng, i as u64 + 1) as usize;
        v.swap(i, j);
    }
}

/// W_a's diagonal: per channel 1 / variance over the training windows (all steps pooled), so
/// errors read as fractions of each channel's spread and λ_s, β and λ_p keep their meaning
/// whatever the action scale.
fn channel_weights(
    windows: &[Window<'_>],
    idx: &[usize],
    h_os: usize,
    channels: usize,
) -> Vec<f32> {
    let mut inv = vec![0.0f64; channels];
    for (c, inv) in inv.iter_mut().enumerate() {
        let values: Vec<f64> = idx
            .iter()
            .flat_map(|&i| (0..h_os).map(move |t| f64::from(windows[i].zeta[t * channels + c])))
            .collect();
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let var = values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
        *inv = 1.0 / var.max(1e-6);
    }
    (0..h_os * channels)
        .map(|j| inv[j % channels] as f32)
        .collect()
}

/// Mean and spread of each ω̄ feature over the training windows (spread 1 where constant).
fn feature_stats(windows: &[Window<'_>], idx: &[usize], len: usize) -> (Vec<f32>, Vec<f32>) {
    let n = idx.len() as f64;
    let mut mean = vec![0.0f32; len];
    let mut std = vec![1.0f32; len];
    for f in 0..len {
        let m = idx
            .iter()
            .map(|&i| f64::from(windows[i].omega_bar[f]))
            .sum::<f64>()
            / n;
        let var = idx
            .iter()
            .map(|&i| {
                let d = f64::from(windows[i].omega_bar[f]) - m;
                d * d
            })
            .sum::<f64>()
            / n;
        mean[f] = m as f32;
        let s = var.sqrt() as f32;
        std[f] = if s < MIN_STD { 1.0 } else { s };
    }
    (mean, std)
}

/// Held-out ‖G − ζ‖²_{W_a} per element, from the encoder mean and from the prior mean.
fn heldout_errors(
    model: &Cvae,
    windows: &[Window<'_>],
    omega_n: &[Vec<f32>],
    idx: &[usize],
) -> (f32, f32) {
    if idx.is_empty() {
        return (f32::NAN, f32::NAN);
    }
    let mut post = 0.0f64;
    let mut prior = 0.0f64;
    for &i in idx {
        let w = &windows[i];
        let (mu, _) = model.encode(w.zeta, &omega_n[i]);
        let (mu_p, _) = model.prior_at(&omega_n[i]);
        let g = model.decode(&[mu, mu_p], &omega_n[i]);
        post += model.weighted_sq(&g[0], w.zeta);
        prior += model.weighted_sq(&g[1], w.zeta);
    }
    let n = (idx.len() * model.zeta_len()) as f64;
    ((post / n) as f32, (prior / n) as f32)
}

/// One batch: forward, loss (per element of ζ for the first two terms, per window for KL,
/// averaged over the batch) and the parameter gradients of encoder, prior and decoder.
fn batch_step(
    model: &Cvae,
    windows: &[Window<'_>],
    omega_n: &[Vec<f32>],
    batch: &[usize],
    eps_rng: &mut StreamRng,
) -> (BatchLoss, Vec<Vec<osms_nn::LinearGrad>>) {
    let p = &model.params;
    let (b, l) = (batch.len(), p.latent);
    let zeta_len = model.zeta_len();
    let cond_len = model.omega_mean.len();
    let enc_in = Matrix::from_fn(b, zeta_len + cond_len, |i, j| {
        let w = batch[i];
        if j < zeta_len {
            windows[w].zeta[j]
        } else {
            omega_n[w][j - zeta_len]
        }
    });
    let (enc_out, enc_cache) = model.encoder.forward_cached(&enc_in);
    let (mu_q, ls_q) = split_gaussian(&enc_out, l);
    let prior_fw = model.prior.as_ref().map(|prior| {
        let input = Matrix::from_fn(b, cond_len, |i, j| omega_n[batch[i]][j]);
        prior.forward_cached(&input)
    });
    let (mu_p, ls_p) = match &prior_fw {
        Some((out, _)) => split_gaussian(out, l),
        None => (Matrix::zeros(b, l), Matrix::zeros(b, l)),
    };
    let eps = Matrix::from_fn(b, l, |_, _| rng::normal(eps_rng) as f32);
    let z = Matrix::from_fn(b, l, |i, j| {
        mu_q.get(i, j) + libm::expf(ls_q.get(i, j)) * eps.get(i, j)
    });
    let dec_in = Matrix::from_fn(b, l + cond_len, |i, j| {
        if j < l {
            z.get(i, j)
        } else {
            omega_n[batch[i]][j - l]
        }
    });
    let (g, dec_cache) = model.decoder.forward_cached(&dec_in);

    // Terms are normalised per element of ζ (reconstruction, smoothness) and per window (KL),
    // then averaged over the batch.
    let (h, c) = (model.h_os, model.channels);
    let norm = 1.0 / (b * zeta_len) as f32;
    let mut d_g = Matrix::zeros(b, zeta_len);
    let mut rec = 0.0f64;
    let mut smooth = 0.0f64;
    for i in 0..b {
        let target = windows[batch[i]].zeta;
        for (j, (&t, &w)) in target.iter().zip(&model.w_a).enumerate() {
            let d = g.get(i, j) - t;
            rec += f64::from(w * d * d);
            d_g.set(i, j, 2.0 * w * d * norm);
        }
        for t in 1..h.saturating_sub(1) {
            for ch in 0..c {
                let at = |s: usize| g.get(i, s * c + ch);
                let dd = at(t + 1) - 2.0 * at(t) + at(t - 1);
                let w = model.w_a[t * c + ch];
                smooth += f64::from(w * dd * dd);
                let gd = 2.0 * p.lambda_s * w * dd * norm;
                for (s, k) in [(t + 1, 1.0), (t, -2.0), (t - 1, 1.0)] {
                    let j = s * c + ch;
                    d_g.set(i, j, d_g.get(i, j) + k * gd);
                }
            }
        }
    }
    let (d_dec_in, dec_grads) = model.decoder.backward(&dec_cache, &d_g);

    let beta_n = p.beta / b as f32;
    let anchor_n = if model.prior.is_some() {
        p.prior_anchor / b as f32
    } else {
        0.0
    };
    let mut kl = 0.0f64;
    let mut g_mu_q = Matrix::zeros(b, l);
    let mut g_ls_q = Matrix::zeros(b, l);
    let mut g_mu_p = Matrix::zeros(b, l);
    let mut g_ls_p = Matrix::zeros(b, l);
    for i in 0..b {
        for j in 0..l {
            let (mq, lq, mp, lp) = (
                mu_q.get(i, j),
                ls_q.get(i, j),
                mu_p.get(i, j),
                ls_p.get(i, j),
            );
            let var_q = libm::expf(2.0 * lq);
            let var_p = libm::expf(2.0 * lp);
            let dm = mq - mp;
            kl += f64::from(lp - lq + (var_q + dm * dm) / (2.0 * var_p) - 0.5);
            g_mu_q.set(i, j, beta_n * dm / var_p);
            g_ls_q.set(i, j, beta_n * (var_q / var_p - 1.0));
            g_mu_p.set(i, j, -beta_n * dm / var_p + anchor_n * mp);
            g_ls_p.set(
                i,
                j,
                beta_n * (1.0 - (var_q + dm * dm) / var_p) + anchor_n * (var_p - 1.0),
            );
            // Reparameterisation: z = μ_q + σ_q ε.
            let dz = d_dec_in.get(i, j);
            g_mu_q.set(i, j, g_mu_q.get(i, j) + dz);
            g_ls_q.set(i, j, g_ls_q.get(i, j) + dz * libm::expf(lq) * eps.get(i, j));
        }
    }
    let enc_grads = model.encoder.param_gradients(
        &enc_cache,
        &join_gaussian_grad(&enc_out, l, &g_mu_q, &g_ls_q),
    );
    let mut grads = vec![enc_grads];
    if let (Some(prior), Some((out, cache))) = (&model.prior, &prior_fw) {
        grads.push(prior.param_gradients(cache, &join_gaussian_grad(out, l, &g_mu_p, &g_ls_p)));
    }
    grads.push(dec_grads);
    let loss = BatchLoss {
        reconstruction: (rec / (b * zeta_len) as f64) as f32,
        smoothness: (smooth / (b * zeta_len) as f64) as f32,
        kl: (kl / b as f64) as f32,
    };
    (loss, grads)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Snippets from a known generator: 2 latent factors u and a 3-dim condition c, smooth in
    /// time, inside (−1, 1). ω̄ carries c plus 2 constant features (only centred).
    fn synthetic(n: usize, seed: u64) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
        let (h, ch) = (8usize, 7usize);
        let mut rng = rng::stream(seed, "test", "synthetic", 0);
        let mut zetas = Vec::new();
        let mut omegas = Vec::new();
        for _ in 0..n {
            let u: Vec<f64> = (0..2).map(|_| rng::uniform(&mut rng, -1.0, 1.0)).collect();
            let c: Vec<f64> = (0..3).map(|_| rng::uniform(&mut rng, -1.0, 1.0)).collect();
            let mut zeta = Vec::with_capacity(h * ch);
            for t in 0..h {
                let s = t as f64 / (h - 1) as f64;
                for k in 0..ch {
                    let kf = k as f64 + 1.0;
                    let v = 0.5 * u[0] * (1.0 - s) * (0.3 * kf).cos()
                        + 0.4 * u[1] * s * (0.7 * kf).sin()
                        + 0.3 * c[k % 3] * (1.0 + 0.5 * s)
                        + 0.1 * c[(k + 1) % 3] * u[0];
                    zeta.push(v.tanh() as f32);
                }
            }
            zetas.push(zeta);
            let mut omega: Vec<f32> = c.iter().map(|v| *v as f32 * 3.0 + 1.0).collect();
            omega.extend([5.0, 0.0]);
            omegas.push(omega);
        }
        (zetas, omegas)
    }

    fn small() -> ManifoldParams {
        ManifoldParams {
            latent: 4,
            hidden: vec![48, 48],
            epochs: 120,
            batch: 32,
            lr: 3e-3,
            ..ManifoldParams::default()
        }
    }

    fn windows<'a>(z: &'a [Vec<f32>], o: &'a [Vec<f32>]) -> Vec<Window<'a>> {
        z.iter()
            .zip(o)
            .map(|(zeta, omega_bar)| Window { zeta, omega_bar })
            .collect()
    }

    /// The W_a-weighted error is per element in units of each channel's variance (W_a has
    /// mean 1): 1.0 would be no better than predicting a constant.
    #[test]
    fn learns_a_known_low_dimensional_generator() {
        let (z, o) = synthetic(400, 1);
        let model = train(&windows(&z, &o), 8, 7, &small(), (3, "t"), &|| {}).expect("train");
        let last = model.curve.last().expect("curve");
        let first = &model.curve[0];
        assert_eq!(model.windows_heldout, 40);
        assert!(
            last.heldout_reconstruction < 0.05,
            "held-out reconstruction {} (first epoch {})",
            last.heldout_reconstruction,
            first.heldout_reconstruction
        );
        assert!(last.heldout_reconstruction < 0.2 * first.heldout_reconstruction);
        // The condition explains a good part of ζ: the prior mean decodes better than chance.
        assert!(
            last.heldout_prior_reconstruction < 0.6,
            "prior-mean reconstruction {}",
            last.heldout_prior_reconstruction
        );
        // W_a is the inverse channel variance: the mean prediction scores 1 per element.
        let train_idx: Vec<usize> = (0..400).filter(|i| i % 10 != 9).collect();
        let mut mean = vec![0.0f64; 56];
        for &i in &train_idx {
            for (m, v) in mean.iter_mut().zip(&z[i]) {
                *m += f64::from(*v) / train_idx.len() as f64;
            }
        }
        let mean_err: f64 = train_idx
            .iter()
            .map(|&i| {
                (0..56)
                    .map(|j| {
                        let c = j % 7;
                        let pooled: f64 = (0..8).map(|t| mean[t * 7 + c]).sum::<f64>() / 8.0;
                        let d = f64::from(z[i][j]) - pooled;
                        f64::from(model.w_a[j]) * d * d
                    })
                    .sum::<f64>()
            })
            .sum::<f64>()
            / (train_idx.len() * 56) as f64;
        assert!((mean_err - 1.0).abs() < 1e-3, "{mean_err}");
        assert_eq!(
            model.omega_std[3], 1.0,
            "constant features are only centred"
        );
    }

    #[test]
    fn same_seed_same_bytes_and_threads_do_not_matter() {
        let (z, o) = synthetic(60, 2);
        let p = ManifoldParams {
            epochs: 3,
            ..small()
        };
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            pool.install(|| train(&windows(&z, &o), 8, 7, &p, (5, "t"), &|| {}).expect("train"))
        };
        let bytes = |m: &Cvae| postcard::to_stdvec(m).expect("encode");
        let one = bytes(&run(1));
        assert_eq!(one, bytes(&run(2)));
        assert_eq!(one, bytes(&run(1)));
        let other = train(&windows(&z, &o), 8, 7, &p, (6, "t"), &|| {}).expect("train");
        assert_ne!(one, bytes(&other));
    }

    #[test]
    fn unconditional_ignores_the_condition_and_bad_windows_are_errors() {
        let (z, o) = synthetic(40, 3);
        let p = ManifoldParams {
            conditional: false,
            epochs: 2,
            ..small()
        };
        let m = train(&windows(&z, &o), 8, 7, &p, (1, "t"), &|| {}).expect("train");
        assert!(m.prior.is_none() && m.omega_mean.is_empty());
        assert_eq!(m.normalise(&o[0]), Vec::<f32>::new());
        assert_eq!(m.prior_at(&[]), (vec![0.0; 4], vec![0.0; 4]));

        let mut bad = windows(&z, &o);
        bad[5].zeta = &z[0][..10];
        let e = train(&bad, 8, 7, &p, (1, "t"), &|| {}).expect_err("short ζ");
        assert!(e.to_string().contains("window 5"), "{e}");
        let few = train(&windows(&z[..1], &o[..1]), 8, 7, &p, (1, "t"), &|| {});
        assert!(matches!(few, Err(Error::TooFewWindows(1))));
    }
}

/// A small manifold trained on smooth synthetic snippets, for the tests of the search.
#[cfg(test)]
pub(crate) mod testing {
    use super::*;

    /// (model, ζs, ω̄s): 200 windows of 8 × 7 from 3 latent factors, the third also in ω̄.
    pub(crate) fn model(conditional: bool) -> (Cvae, Vec<Vec<f32>>, Vec<Vec<f32>>) {
        let mut rng = rng::stream(0, "test", "data", 0);
        let mut zetas = Vec::new();
        let mut omegas = Vec::new();
        for _ in 0..200 {
            let u: Vec<f64> = (0..3).map(|_| rng::uniform(&mut rng, -1.0, 1.0)).collect();
            let zeta: Vec<f32> = (0..56)
                .map(|j| {
                    let (t, c) = ((j / 7) as f64 / 7.0, (j % 7) as f64);
                    (0.6 * u[0] * (1.0 - t) + 0.4 * u[1] * t * (c * 0.5).cos() + 0.2 * u[2]).tanh()
                        as f32
                })
                .collect();
            zetas.push(zeta);
            omegas.push(vec![u[2] as f32]);
        }
        let windows: Vec<Window<'_>> = zetas
            .iter()
            .zip(&omegas)
            .map(|(zeta, omega_bar)| Window { zeta, omega_bar })
            .collect();
        let p = ManifoldParams {
            conditional,
            latent: 3,
            hidden: vec![32, 32],
            epochs: 40,
            batch: 32,
            lr: 3e-3,
            ..ManifoldParams::default()
        };
        let m = train(&windows, 8, 7, &p, (1, "t"), &|| {}).expect("train");
        (m, zetas, omegas)
    }
}
