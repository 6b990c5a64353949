//! Conditional flow matching (Lipman et al. 2023) with the linear, rectified-flow probability
//! path: x_t = (1 − t) x₀ + t x₁ with x₀ ~ N(0, I), whose conditional velocity is x₁ − x₀. A
//! network v(x_t, t, c) regresses that velocity (the CFM loss); sampling integrates
//! dx/dt = v(x, t, c) from noise at t = 0 to t = 1 with explicit Euler steps.
//!
//! The network is either an MLP over [c, emb(t), x_t] (the condition first, then a sinusoidal
//! embedding of t, then the noisy sample), or a temporal U-Net over x_t's steps whose residual
//! blocks are modulated (FiLM) by an encoding of [c, emb(t)] (Diffusion Policy's
//! low-dimensional design, [`osms_nn::UNet1d`]). Nothing here knows about robots; the students
//! of [`crate::student`] put an observation history in c and an action chunk in x.

use osms_core::rng::{self, StreamRng};
use osms_nn::{Activation, LinearGrad, Matrix, Mlp, MlpInference, UNet1d, sinusoidal_embedding};
use serde::{Deserialize, Serialize};

/// t is scaled by this before its sinusoidal embedding, so the embedding's periods (from
/// 2π / TIME_SCALE up to 2π · MAX_PERIOD / TIME_SCALE) resolve t ∈ [0, 1].
const TIME_SCALE: f32 = 100.0;
const MAX_PERIOD: f32 = 1000.0;

/// The shape of the U-Net backbone (see [`Backbone::UNet`]). Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct UNetSpec {
    /// Channels per level; the chunk's steps halve from one level to the next.
    pub widths: Vec<usize>,
    /// Convolution kernel along time (odd).
    pub kernel: usize,
    /// Width of the condition encoding that drives every block's FiLM.
    pub cond: usize,
}

impl Default for UNetSpec {
    fn default() -> Self {
        UNetSpec {
            widths: vec![64, 128, 256],
            kernel: 3,
            cond: 256,
        }
    }
}

/// What computes the velocity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Backbone {
    /// An MLP over [c, emb(t), x].
    Mlp(Mlp),
    /// `encoder` maps [c, emb(t)] to the FiLM condition (SiLU after every layer, so each
    /// block's FiLM is Diffusion Policy's activation-then-linear); `unet` runs over x as
    /// `steps` rows of `x_len / steps` channels.
    UNet { encoder: Mlp, unet: Box<UNet1d> },
}

/// A velocity network v(x, t, c).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlowNet {
    pub backbone: Backbone,
    /// Width of the sample x (and of the velocity).
    pub x_len: usize,
    /// Width of the condition c.
    pub cond_len: usize,
    /// Width of t's sinusoidal embedding (even).
    pub time_embedding: usize,
}

/// One training batch of the conditional flow-matching loss: targets x₁, their conditions, the
/// noise x₀ and the times t, and optionally a 0/1 mask over x₁'s elements (padding).
pub struct FlowBatch<'a> {
    pub x1: &'a Matrix,
    pub cond: &'a Matrix,
    pub x0: &'a Matrix,
    pub t: &'a [f32],
    pub mask: Option<&'a Matrix>,
}

impl FlowNet {
    /// SiLU hidden layers of the given widths; weights from streams (`name`, layer) of `seed`.
    pub fn new(
        x_len: usize,
        cond_len: usize,
        hidden: &[usize],
        time_embedding: usize,
        seed: u64,
        name: &str,
    ) -> osms_nn::Result<Self> {
        let mut sizes = vec![cond_len + time_embedding + x_len];
        sizes.extend_from_slice(hidden);
        sizes.push(x_len);
        Ok(FlowNet {
            backbone: Backbone::Mlp(Mlp::new(
                &sizes,
                Activation::Silu,
                Activation::Identity,
                seed,
                name,
            )?),
            x_len,
            cond_len,
            time_embedding,
        })
    }

    /// A U-Net backbone over `steps` steps of `x_len / steps` channels; the encoder draws from
    /// streams (`name/encoder`, layer), the U-Net from (`name/unet`, 0).
    pub fn new_unet(
        x_len: usize,
        cond_len: usize,
        steps: usize,
        spec: &UNetSpec,
        time_embedding: usize,
        seed: u64,
        name: &str,
    ) -> osms_nn::Result<Self> {
        let channels = if steps > 0 && x_len.is_multiple_of(steps) {
            x_len / steps
        } else {
            0
        };
        let unet = UNet1d::new(
            channels,
            spec.cond,
            &spec.widths,
            steps,
            spec.kernel,
            seed,
            &format!("{name}/unet"),
        )?;
        let encoder = Mlp::new(
            &[cond_len + time_embedding, spec.cond, spec.cond],
            Activation::Silu,
            Activation::Silu,
            seed,
            &format!("{name}/encoder"),
        )?;
        Ok(FlowNet {
            backbone: Backbone::UNet {
                encoder,
                unet: Box::new(unet),
            },
            x_len,
            cond_len,
            time_embedding,
        })
    }

    /// Rows [c, emb(t)], then x if `with_x`.
    fn input(&self, x: &Matrix, t: &[f32], cond: &Matrix, with_x: bool) -> Matrix {
        assert_eq!(cond.cols, self.cond_len, "flow: condition width");
        assert!(x.rows == cond.rows, "flow: batch sizes");
        assert_eq!(x.cols, self.x_len, "flow: sample width");
        self.joined(Some(cond), t, with_x.then_some(x), x.rows)
    }

    /// `rows` rows [c (if given), emb(t), x (if given)].
    fn joined(&self, cond: Option<&Matrix>, t: &[f32], x: Option<&Matrix>, rows: usize) -> Matrix {
        assert!(rows == t.len(), "flow: batch sizes");
        let scaled: Vec<f32> = t.iter().map(|t| t * TIME_SCALE).collect();
        let emb = sinusoidal_embedding(&scaled, self.time_embedding, MAX_PERIOD);
        let width = cond.map_or(0, |c| c.cols) + self.time_embedding + x.map_or(0, |x| x.cols);
        let mut data = Vec::with_capacity(rows * width);
        for i in 0..rows {
            if let Some(c) = cond {
                data.extend_from_slice(c.row(i));
            }
            data.extend_from_slice(emb.row(i));
            if let Some(x) = x {
                data.extend_from_slice(x.row(i));
            }
        }
        Matrix::from_vec(rows, width, data)
    }

    /// The network prepared for sampling ([`FlowSampler`]).
    pub fn sampler(&self) -> FlowSampler<'_> {
        FlowSampler {
            net: self,
            mlp: match &self.backbone {
                Backbone::Mlp(mlp) => Some(MlpInference::new(mlp, self.cond_len)),
                Backbone::UNet { .. } => None,
            },
        }
    }

    /// v(x, t, c) for every row.
    pub fn velocity(&self, x: &Matrix, t: &[f32], cond: &Matrix) -> Matrix {
        match &self.backbone {
            Backbone::Mlp(mlp) => mlp.forward(&self.input(x, t, cond, true)),
            Backbone::UNet { encoder, unet } => {
                let film = encoder.forward(&self.input(x, t, cond, false));
                let steps = unet.steps;
                let (v, _) = unet.forward(&as_steps(x, steps), &film);
                Matrix::from_vec(x.rows, x.cols, v.data)
            }
        }
    }

    /// Every parameter slice, in the order of [`FlowGrads`].
    pub fn params_mut(&mut self) -> Vec<&mut [f32]> {
        match &mut self.backbone {
            Backbone::Mlp(mlp) => mlp.params_mut(),
            Backbone::UNet { encoder, unet } => {
                let mut out = encoder.params_mut();
                out.extend(unet.params_mut());
                out
            }
        }
    }

    pub fn parameter_count(&self) -> usize {
        match &self.backbone {
            Backbone::Mlp(mlp) => mlp.parameter_count(),
            Backbone::UNet { encoder, unet } => encoder.parameter_count() + unet.parameter_count(),
        }
    }

    /// x_t and the regression target x₁ − x₀ of a batch.
    fn interpolate(b: &FlowBatch<'_>) -> (Matrix, Matrix) {
        let (rows, cols) = (b.x1.rows, b.x1.cols);
        assert_eq!((b.x0.rows, b.x0.cols), (rows, cols), "flow: noise shape");
        let mut xt = Matrix::zeros(rows, cols);
        let mut target = Matrix::zeros(rows, cols);
        for i in 0..rows {
            let t = b.t[i];
            for j in 0..cols {
                let (x0, x1) = (b.x0.get(i, j), b.x1.get(i, j));
                xt.set(i, j, (1.0 - t) * x0 + t * x1);
                target.set(i, j, x1 - x0);
            }
        }
        (xt, target)
    }

    /// The loss of [`FlowNet::loss_and_gradients`] alone, with its bits, for a fraction of the
    /// work (a validation loss needs no backward pass).
    pub fn loss(&self, b: &FlowBatch<'_>) -> f32 {
        let (xt, target) = Self::interpolate(b);
        masked_mse(&self.velocity(&xt, b.t, b.cond), &target, b.mask).0
    }

    /// The conditional flow-matching loss of a batch and its parameter gradients:
    /// mean over unmasked elements of (v(x_t, t, c) − (x₁ − x₀))².
    pub fn loss_and_gradients(&self, b: &FlowBatch<'_>) -> (f32, FlowGrads) {
        let (rows, cols) = (b.x1.rows, b.x1.cols);
        let (xt, target) = Self::interpolate(b);
        match &self.backbone {
            Backbone::Mlp(mlp) => {
                let (pred, cache) = mlp.forward_cached(&self.input(&xt, b.t, b.cond, true));
                let (loss, grad) = masked_mse(&pred, &target, b.mask);
                (loss, FlowGrads(slices(mlp.param_gradients(&cache, &grad))))
            }
            Backbone::UNet { encoder, unet } => {
                let (film, encoder_cache) =
                    encoder.forward_cached(&self.input(&xt, b.t, b.cond, false));
                let (pred, cache) = unet.forward(&as_steps(&xt, unet.steps), &film);
                let pred = Matrix::from_vec(rows, cols, pred.data);
                let (loss, grad) = masked_mse(&pred, &target, b.mask);
                let (_, dfilm, unet_grads) =
                    unet.backward(&cache, &as_steps(&grad, unet.steps), &film);
                let mut grads = slices(encoder.param_gradients(&encoder_cache, &dfilm));
                grads.extend(unet_grads);
                (loss, FlowGrads(grads))
            }
        }
    }

    /// A sample for condition `cond` (one row), integrating from `noise` (x at t = 0) with
    /// `steps` Euler steps.
    pub fn sample(&self, cond: &[f32], noise: Vec<f32>, steps: usize) -> Vec<f32> {
        let c = Matrix::from_vec(1, cond.len(), cond.to_vec());
        self.sample_batch(&c, Matrix::from_vec(1, noise.len(), noise), steps)
            .data
    }

    /// One sample per row of `cond`, row i integrating from row i of `noise`. Row i is bit for
    /// bit the one-row [`FlowNet::sample`]: every kernel sums each output element in the same
    /// order whatever the number of rows, and Euler's update is element-wise.
    pub fn sample_batch(&self, cond: &Matrix, noise: Matrix, steps: usize) -> Matrix {
        self.sampler().sample_batch(cond, noise, steps)
    }
}

/// A [`FlowNet`] prepared to sample many times (a policy's every action): an MLP backbone's
/// weights packed once, and the condition's share of its first layer computed once per sample
/// rather than at every Euler step ([`MlpInference`]). Its samples have the bits of integrating
/// [`FlowNet::velocity`]: the condition leads the MLP's input, and a product sums its inputs in
/// order. A U-Net backbone samples through [`FlowNet::velocity`].
pub struct FlowSampler<'n> {
    net: &'n FlowNet,
    mlp: Option<MlpInference>,
}

impl FlowSampler<'_> {
    /// [`FlowNet::sample_batch`].
    pub fn sample_batch(&self, cond: &Matrix, noise: Matrix, steps: usize) -> Matrix {
        let (rows, cols) = (noise.rows, noise.cols);
        assert_eq!(cond.rows, rows, "flow: batch sizes");
        let x = match &self.mlp {
            Some(mlp) => {
                assert_eq!(cols, self.net.x_len, "flow: sample width");
                let prefix = mlp.prefix(cond);
                euler(noise.data, steps, |x, t| {
                    let x = Matrix::from_vec(rows, cols, x.to_vec());
                    let varying = self.net.joined(None, &vec![t; rows], Some(&x), rows);
                    mlp.forward(&prefix, &varying).data
                })
            }
            None => euler(noise.data, steps, |x, t| {
                self.net
                    .velocity(
                        &Matrix::from_vec(rows, cols, x.to_vec()),
                        &vec![t; rows],
                        cond,
                    )
                    .data
            }),
        };
        Matrix::from_vec(rows, cols, x)
    }
}

/// Gradients of every parameter slice, in the order of [`FlowNet::params_mut`].
pub struct FlowGrads(pub Vec<Vec<f32>>);

impl FlowGrads {
    pub fn slices(&self) -> Vec<&[f32]> {
        self.0.iter().map(Vec::as_slice).collect()
    }
}

/// An MLP's layer gradients as slices in the order of `Mlp::params_mut` (moved, not copied).
fn slices(grads: Vec<LinearGrad>) -> Vec<Vec<f32>> {
    grads.into_iter().flat_map(|g| [g.w.data, g.b]).collect()
}

/// `B × (steps·channels)` rows (step-major) as `B·steps × channels`: the same values.
fn as_steps(x: &Matrix, steps: usize) -> Matrix {
    Matrix::from_vec(x.rows * steps, x.cols / steps, x.data.clone())
}

/// Explicit Euler integration of dx/dt = v(x, t) from t = 0 to t = 1 in `steps` equal steps:
/// x_{k+1} = x_k + h v(x_k, k h), h = 1 / steps. Exact for velocity fields whose solutions are
/// straight lines traversed at constant speed (the rectified-flow ideal).
pub fn euler(
    mut x: Vec<f32>,
    steps: usize,
    mut v: impl FnMut(&[f32], f32) -> Vec<f32>,
) -> Vec<f32> {
    let steps = steps.max(1);
    let h = 1.0 / steps as f32;
    for k in 0..steps {
        let dx = v(&x, k as f32 * h);
        for (x, d) in x.iter_mut().zip(&dx) {
            *x += h * d;
        }
    }
    x
}

/// `n` standard-normal draws (as f32) from `rng`.
pub fn normals(rng: &mut StreamRng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng::normal(rng) as f32).collect()
}

/// Mean over unmasked elements of (pred − target)², and its gradient. Without a mask every
/// element counts.
fn masked_mse(pred: &Matrix, target: &Matrix, mask: Option<&Matrix>) -> (f32, Matrix) {
    assert_eq!((pred.rows, pred.cols), (target.rows, target.cols));
    if let Some(m) = mask {
        assert_eq!((m.rows, m.cols), (pred.rows, pred.cols), "flow: mask shape");
    }
    let weight = |i: usize| mask.map_or(1.0, |m| m.data[i]);
    let count = osms_nn::kernels::sum(&(0..pred.data.len()).map(weight).collect::<Vec<_>>());
    let scale = 1.0 / count.max(1.0);
    let mut grad = Matrix::zeros(pred.rows, pred.cols);
    let mut terms = Vec::with_capacity(pred.data.len());
    for i in 0..pred.data.len() {
        let d = (pred.data[i] - target.data[i]) * weight(i);
        terms.push(d * d);
        grad.data[i] = 2.0 * d * scale;
    }
    (osms_nn::kernels::sum(&terms) * scale, grad)
}

#[cfg(test)]
mod tests {
    use super::*;
    use osms_nn::{Adam, AdamConfig, Schedule};

    #[test]
    fn a_batch_samples_each_row_as_one_row_alone() {
        let spec = UNetSpec {
            widths: vec![16, 16],
            kernel: 3,
            cond: 16,
        };
        let unet = FlowNet::new_unet(6, 7, 2, &spec, 8, 3, "batch").expect("net");
        for net in [
            FlowNet::new(6, 7, &[16, 16], 8, 3, "batch").expect("net"),
            unet,
        ] {
            a_batch_samples_each_row_as_one_row_alone_with(&net);
        }
    }

    fn a_batch_samples_each_row_as_one_row_alone_with(net: &FlowNet) {
        let mut r = rng::stream(0, "test", "batch", 0);
        // 1 row (the row-by-row kernel path) and 37 (tiled, with a ragged last block).
        for rows in [1, 37] {
            let cond = Matrix::from_vec(rows, 7, normals(&mut r, rows * 7));
            let noise = Matrix::from_vec(rows, 6, normals(&mut r, rows * 6));
            let batch = net.sample_batch(&cond, noise.clone(), 4);
            for i in 0..rows {
                let alone = net.sample(cond.row(i), noise.row(i).to_vec(), 4);
                let (a, b): (Vec<u32>, Vec<u32>) = (
                    alone.iter().map(|x| x.to_bits()).collect(),
                    batch.row(i).iter().map(|x| x.to_bits()).collect(),
                );
                assert_eq!(a, b, "row {i} of {rows}");
            }
        }
    }

    #[test]
    fn the_prepared_sampler_integrates_the_velocity_network_bit_for_bit() {
        // Wide enough that the first layer's products take the tiled kernels at 16 rows.
        let net = FlowNet::new(24, 90, &[64, 64], 8, 5, "sampler").expect("net");
        let mut r = rng::stream(0, "test", "sampler", 0);
        for rows in [1, 2, 3, 16] {
            let cond = Matrix::from_vec(rows, 90, normals(&mut r, rows * 90));
            let noise = Matrix::from_vec(rows, 24, normals(&mut r, rows * 24));
            let direct = euler(noise.data.clone(), 10, |x, t| {
                net.velocity(
                    &Matrix::from_vec(rows, 24, x.to_vec()),
                    &vec![t; rows],
                    &cond,
                )
                .data
            });
            let sampled = net.sampler().sample_batch(&cond, noise, 10);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&sampled.data), bits(&direct), "{rows} rows");
        }
    }

    #[test]
    fn the_loss_alone_has_the_bits_of_the_loss_with_gradients() {
        let spec = UNetSpec {
            widths: vec![8, 8],
            kernel: 3,
            cond: 8,
        };
        let mut r = rng::stream(0, "test", "loss", 0);
        let rows = 21;
        let x1 = Matrix::from_vec(rows, 6, normals(&mut r, rows * 6));
        let x0 = Matrix::from_vec(rows, 6, normals(&mut r, rows * 6));
        let cond = Matrix::from_vec(rows, 7, normals(&mut r, rows * 7));
        let mask = Matrix::from_fn(rows, 6, |i, j| f32::from(u8::from((i + j) % 4 != 0)));
        let t: Vec<f32> = (0..rows).map(|_| rng::uniform01(&mut r) as f32).collect();
        for net in [
            FlowNet::new(6, 7, &[16, 16], 8, 3, "loss").expect("net"),
            FlowNet::new_unet(6, 7, 2, &spec, 8, 3, "loss").expect("net"),
        ] {
            let batch = FlowBatch {
                x1: &x1,
                cond: &cond,
                x0: &x0,
                t: &t,
                mask: Some(&mask),
            };
            let (with, _) = net.loss_and_gradients(&batch);
            assert_eq!(net.loss(&batch).to_bits(), with.to_bits());
        }
    }

    #[test]
    fn euler_is_exact_on_straight_line_fields() {
        // v(x, t) = (c − x) / (1 − t): every solution runs straight to c at constant speed, so
        // any number of Euler steps lands on c (up to rounding).
        let c = [0.7f32, -1.3, 2.0];
        for steps in [1, 3, 10] {
            let x = euler(vec![-0.4, 0.9, 0.1], steps, |x, t| {
                x.iter().zip(&c).map(|(x, c)| (c - x) / (1.0 - t)).collect()
            });
            for (x, c) in x.iter().zip(&c) {
                assert!((x - c).abs() < 1e-5, "{steps} steps: {x} vs {c}");
            }
        }
        // A constant field moves x by exactly v.
        let x = euler(vec![1.0, 2.0], 10, |_, _| vec![0.5, -0.25]);
        assert!(
            (x[0] - 1.5).abs() < 1e-6 && (x[1] - 1.75).abs() < 1e-6,
            "{x:?}"
        );
    }

    #[test]
    fn the_masked_loss_ignores_masked_elements_and_matches_finite_differences() {
        let pred = Matrix::from_vec(2, 2, vec![1.0, 2.0, 3.0, 4.0]);
        let target = Matrix::from_vec(2, 2, vec![0.0, 0.0, 1.0, 100.0]);
        let mask = Matrix::from_vec(2, 2, vec![1.0, 1.0, 1.0, 0.0]);
        let (loss, grad) = masked_mse(&pred, &target, Some(&mask));
        assert!((loss - (1.0 + 4.0 + 4.0) / 3.0).abs() < 1e-6, "{loss}");
        assert_eq!(grad.data[3], 0.0);
        for i in 0..3 {
            let mut p = pred.clone();
            p.data[i] += 1e-2;
            let (up, _) = masked_mse(&p, &target, Some(&mask));
            p.data[i] -= 2e-2;
            let (down, _) = masked_mse(&p, &target, Some(&mask));
            let fd = (up - down) / 2e-2;
            assert!(
                (fd - grad.data[i]).abs() < 1e-3,
                "{i}: {fd} vs {}",
                grad.data[i]
            );
        }
    }

    /// Adds `delta` to parameter `idx` in the order of [`FlowNet::params_mut`].
    fn bump(net: &mut FlowNet, idx: usize, delta: f32) {
        let mut k = idx;
        for slice in net.params_mut() {
            if k < slice.len() {
                slice[k] += delta;
                return;
            }
            k -= slice.len();
        }
    }

    /// Both backbones: the MLP, and a U-Net over 4 steps of 2 channels.
    #[test]
    fn the_loss_gradient_matches_finite_differences() {
        let spec = UNetSpec {
            widths: vec![4, 6],
            kernel: 3,
            cond: 5,
        };
        for net in [
            FlowNet::new(8, 2, &[8], 4, 7, "fd").expect("a valid network"),
            FlowNet::new_unet(8, 2, 4, &spec, 4, 7, "fd").expect("a valid network"),
        ] {
            loss_gradient_matches_finite_differences(&net);
        }
    }

    fn loss_gradient_matches_finite_differences(net: &FlowNet) {
        let mut r = rng::stream(0, "test", "fd", 0);
        let x1 = Matrix::from_vec(4, 8, normals(&mut r, 32));
        let x0 = Matrix::from_vec(4, 8, normals(&mut r, 32));
        let cond = Matrix::from_vec(4, 2, normals(&mut r, 8));
        let t = [0.1, 0.4, 0.6, 0.9];
        let mask = Matrix::from_fn(4, 8, |i, j| if i == 3 && j > 0 { 0.0 } else { 1.0 });
        let batch = FlowBatch {
            x1: &x1,
            cond: &cond,
            x0: &x0,
            t: &t,
            mask: Some(&mask),
        };
        let (_, grads) = net.loss_and_gradients(&batch);
        let analytic: Vec<f32> = grads.slices().concat();
        let mut probe = net.clone();
        let n = analytic.len();
        for idx in (0..n).step_by((n / 24).max(1)).chain([n - 1]) {
            let eps = 1e-2f32;
            bump(&mut probe, idx, eps);
            let (up, _) = probe.loss_and_gradients(&batch);
            bump(&mut probe, idx, -2.0 * eps);
            let (down, _) = probe.loss_and_gradients(&batch);
            bump(&mut probe, idx, eps);
            let fd = (up - down) / (2.0 * eps);
            assert!(
                (fd - analytic[idx]).abs() < 2e-3 + 0.02 * fd.abs(),
                "param {idx}: finite difference {fd}, analytic {}",
                analytic[idx]
            );
        }
    }

    /// Target: x ∈ R² given a scalar c ∈ {−1, +1}: an equal mixture of N((±1.5, c), 0.2² I)
    /// (bimodal in the first coordinate, the second follows c). After training, 4,000 samples
    /// per condition match the target's moments and keep both modes.
    #[test]
    fn flow_matching_learns_a_conditional_mixture() {
        let sigma = 0.2f32;
        let target = |c: f32, r: &mut StreamRng| -> [f32; 2] {
            let mode = if rng::uniform01(r) < 0.5 { -1.5 } else { 1.5 };
            [
                mode + sigma * rng::normal(r) as f32,
                c + sigma * rng::normal(r) as f32,
            ]
        };
        let mut net = FlowNet::new(2, 1, &[64, 64], 16, 3, "mixture").expect("a valid network");
        let mut opt = Adam::new(
            AdamConfig::default(),
            Schedule::Cosine {
                lr: 3e-3,
                min_lr: 1e-4,
                steps: 2500,
            },
        );
        let batch = 128;
        for step in 0..2500u64 {
            let mut r = rng::stream(0, "test", "mixture-batch", step);
            let cond: Vec<f32> = (0..batch)
                .map(|_| {
                    if rng::uniform01(&mut r) < 0.5 {
                        -1.0
                    } else {
                        1.0
                    }
                })
                .collect();
            let x1: Vec<f32> = cond.iter().flat_map(|&c| target(c, &mut r)).collect();
            let x0 = normals(&mut r, 2 * batch);
            let t: Vec<f32> = (0..batch).map(|_| rng::uniform01(&mut r) as f32).collect();
            let (x1, x0) = (
                Matrix::from_vec(batch, 2, x1),
                Matrix::from_vec(batch, 2, x0),
            );
            let cond = Matrix::from_vec(batch, 1, cond);
            let (_, grads) = net.loss_and_gradients(&FlowBatch {
                x1: &x1,
                cond: &cond,
                x0: &x0,
                t: &t,
                mask: None,
            });
            opt.update(&mut net.params_mut(), &grads.slices());
        }
        for c in [-1.0f32, 1.0] {
            let mut r = rng::stream(0, "test", "mixture-sample", c as i64 as u64);
            let n = 4000;
            let samples: Vec<Vec<f32>> = (0..n)
                .map(|_| net.sample(&[c], normals(&mut r, 2), 10))
                .collect();
            let mean = |k: usize| samples.iter().map(|s| f64::from(s[k])).sum::<f64>() / n as f64;
            let var = |k: usize, m: f64| {
                samples
                    .iter()
                    .map(|s| (f64::from(s[k]) - m).powi(2))
                    .sum::<f64>()
                    / n as f64
            };
            let (m0, m1) = (mean(0), mean(1));
            // Target: E x₀ = 0, Var x₀ = 1.5² + σ² = 2.29; E x₁ = c, Var x₁ = σ² = 0.04.
            assert!(m0.abs() < 0.15, "c = {c}: mean of x₀ {m0}");
            assert!(
                (var(0, m0) - 2.29).abs() < 0.3,
                "c = {c}: var x₀ {}",
                var(0, m0)
            );
            assert!((m1 - f64::from(c)).abs() < 0.1, "c = {c}: mean of x₁ {m1}");
            assert!(var(1, m1) < 0.1, "c = {c}: var x₁ {}", var(1, m1));
            // Both modes are kept, and little mass sits between them.
            let right = samples.iter().filter(|s| s[0] > 0.0).count() as f64 / n as f64;
            let between = samples.iter().filter(|s| s[0].abs() < 0.75).count() as f64 / n as f64;
            assert!(
                (right - 0.5).abs() < 0.08,
                "c = {c}: right-mode share {right}"
            );
            assert!(between < 0.1, "c = {c}: share between the modes {between}");
        }
    }
}
