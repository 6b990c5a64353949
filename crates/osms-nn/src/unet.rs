//! A temporal U-Net over an action chunk: 1-D convolutions along time and FiLM conditioning
//! from a global condition vector in every residual block, the low-dimensional design of
//! Diffusion Policy (Chi et al. 2023), for issue 54's student comparison.
//!
//! Deviations from that design, for an 8-step chunk on two cores: LayerNorm over a step's
//! channels instead of GroupNorm, SiLU instead of Mish, one residual block per level, and
//! resolution changes without parameters (the mean of two adjacent steps down, each step twice
//! up) instead of strided and transposed convolutions.
//!
//! A batch of sequences is a matrix with one row per (sample, step), row `b·T + t`, and one
//! column per channel. Every product goes through the crate's kernels and every other loop has
//! a fixed order, so the bits do not depend on threads.

// The loops index rows, steps and channels of several matrices by the same indices.
#![allow(clippy::needless_range_loop)]

use osms_core::rng::{self, StreamRng};
use serde::{Deserialize, Serialize};

use crate::{Error, LayerNorm, LayerNormCache, Linear, LinearGrad, Matrix, Result, math};

/// A same-padded convolution along time (zero outside the sequence), as a [`Linear`] over the
/// `kernel` neighbouring steps' channels: weights `kernel·inputs × outputs`, step offsets
/// `-kernel/2 ..= kernel/2` in that order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Conv1d {
    pub kernel: usize,
    pub inputs: usize,
    pub linear: Linear,
}

/// The `kernel` neighbours of every step side by side (`rows × kernel·channels`).
fn im2col(x: &Matrix, steps: usize, kernel: usize) -> Matrix {
    let c = x.cols;
    let half = kernel / 2;
    let mut out = Matrix::zeros(x.rows, kernel * c);
    for r in 0..x.rows {
        let (b, t) = (r / steps, r % steps);
        for k in 0..kernel {
            let Some(s) = (t + k).checked_sub(half).filter(|&s| s < steps) else {
                continue;
            };
            let at = r * kernel * c + k * c;
            out.data[at..at + c].copy_from_slice(x.row(b * steps + s));
        }
    }
    out
}

/// The transpose of [`im2col`]: each neighbour's gradient added back to its step.
fn col2im(dcol: &Matrix, steps: usize, kernel: usize, c: usize) -> Matrix {
    let half = kernel / 2;
    let mut dx = Matrix::zeros(dcol.rows, c);
    for r in 0..dcol.rows {
        let (b, t) = (r / steps, r % steps);
        for k in 0..kernel {
            let Some(s) = (t + k).checked_sub(half).filter(|&s| s < steps) else {
                continue;
            };
            let from = r * kernel * c + k * c;
            let to = (b * steps + s) * c;
            for j in 0..c {
                dx.data[to + j] += dcol.data[from + j];
            }
        }
    }
    dx
}

impl Conv1d {
    /// PyTorch's initialisation (uniform in ±1/√(inputs·kernel), as [`Linear::new`]).
    pub fn new(inputs: usize, outputs: usize, kernel: usize, rng: &mut StreamRng) -> Self {
        Conv1d {
            kernel,
            inputs,
            linear: Linear::new(kernel * inputs, outputs, rng),
        }
    }

    /// The output and the unfolded input its backward pass needs.
    pub fn forward(&self, x: &Matrix, steps: usize) -> (Matrix, Matrix) {
        let col = im2col(x, steps, self.kernel);
        (self.linear.forward(&col), col)
    }

    /// dL/dx and the parameter gradients from the unfolded input and dL/dy.
    pub fn backward(&self, col: &Matrix, dy: &Matrix, steps: usize) -> (Matrix, LinearGrad) {
        let (dcol, grad) = self.linear.backward(col, dy);
        (col2im(&dcol, steps, self.kernel, self.inputs), grad)
    }
}

/// Two convolutions with LayerNorm and SiLU, the first's output modulated by FiLM from the
/// condition (`h·(1 + γ) + β`, γ and β a linear map of the condition, per sample), and a
/// residual connection (a 1×1 convolution where the width changes).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResBlock {
    pub conv1: Conv1d,
    pub norm1: LayerNorm,
    pub film: Linear,
    pub conv2: Conv1d,
    pub norm2: LayerNorm,
    pub skip: Option<Conv1d>,
}

/// What a [`ResBlock`]'s backward pass needs from its forward pass.
pub struct ResCache {
    col1: Matrix,
    ln1: LayerNormCache,
    a1: Matrix,
    slope1: Matrix,
    film: Matrix,
    col2: Matrix,
    ln2: LayerNormCache,
    slope2: Matrix,
    skip_col: Option<Matrix>,
}

/// SiLU of every element and its slope.
fn silu(x: &Matrix) -> (Matrix, Matrix) {
    let mut y = Matrix::zeros(x.rows, x.cols);
    let mut slope = Matrix::zeros(x.rows, x.cols);
    for (i, v) in x.data.iter().enumerate() {
        let (a, d) = math::silu_with_derivative(*v);
        y.data[i] = a;
        slope.data[i] = d;
    }
    (y, slope)
}

impl ResBlock {
    /// Parameters draw from `rng` in a fixed order: conv1, FiLM, conv2, skip.
    pub fn new(
        inputs: usize,
        outputs: usize,
        cond: usize,
        kernel: usize,
        rng: &mut StreamRng,
    ) -> Self {
        let conv1 = Conv1d::new(inputs, outputs, kernel, rng);
        let film = Linear::new(cond, 2 * outputs, rng);
        let conv2 = Conv1d::new(outputs, outputs, kernel, rng);
        let skip = (inputs != outputs).then(|| Conv1d::new(inputs, outputs, 1, rng));
        ResBlock {
            conv1,
            norm1: LayerNorm::new(outputs),
            film,
            conv2,
            norm2: LayerNorm::new(outputs),
            skip,
        }
    }

    fn outputs(&self) -> usize {
        self.norm1.gamma.len()
    }

    /// `x` (`B·steps × inputs`) under `cond` (`B × cond`).
    pub fn forward(&self, x: &Matrix, steps: usize, cond: &Matrix) -> (Matrix, ResCache) {
        let c = self.outputs();
        let (h1, col1) = self.conv1.forward(x, steps);
        let (n1, ln1) = self.norm1.forward(&h1);
        let (a1, slope1) = silu(&n1);
        let film = self.film.forward(cond);
        let mut f = Matrix::zeros(a1.rows, c);
        for r in 0..a1.rows {
            let gb = film.row(r / steps);
            for j in 0..c {
                f.data[r * c + j] = a1.data[r * c + j] * (1.0 + gb[j]) + gb[c + j];
            }
        }
        let (h2, col2) = self.conv2.forward(&f, steps);
        let (n2, ln2) = self.norm2.forward(&h2);
        let (mut y, slope2) = silu(&n2);
        let skip_col = match &self.skip {
            Some(skip) => {
                let (s, col) = skip.forward(x, steps);
                y.data.iter_mut().zip(&s.data).for_each(|(y, s)| *y += s);
                Some(col)
            }
            None => {
                y.data.iter_mut().zip(&x.data).for_each(|(y, x)| *y += x);
                None
            }
        };
        let cache = ResCache {
            col1,
            ln1,
            a1,
            slope1,
            film,
            col2,
            ln2,
            slope2,
            skip_col,
        };
        (y, cache)
    }

    /// dL/dx and dL/dcond from dL/dy; pushes the parameter gradients in the order of
    /// [`ResBlock::params_mut`].
    pub fn backward(
        &self,
        cache: &ResCache,
        dy: &Matrix,
        steps: usize,
        cond: &Matrix,
        grads: &mut Vec<Vec<f32>>,
    ) -> (Matrix, Matrix) {
        let c = self.outputs();
        let dn2 = dy.zip(&cache.slope2, |g, s| g * s);
        let (dh2, dgamma2, dbeta2) = self.norm2.backward(&cache.ln2, &dn2);
        let (df, gconv2) = self.conv2.backward(&cache.col2, &dh2, steps);
        let mut da1 = Matrix::zeros(df.rows, c);
        let mut dfilm = Matrix::zeros(cache.film.rows, 2 * c);
        for r in 0..df.rows {
            let b = r / steps;
            for j in 0..c {
                let g = df.data[r * c + j];
                da1.data[r * c + j] = g * (1.0 + cache.film.data[b * 2 * c + j]);
                dfilm.data[b * 2 * c + j] += g * cache.a1.data[r * c + j];
                dfilm.data[b * 2 * c + c + j] += g;
            }
        }
        let (dcond, gfilm) = self.film.backward(cond, &dfilm);
        let dn1 = da1.zip(&cache.slope1, |g, s| g * s);
        let (dh1, dgamma1, dbeta1) = self.norm1.backward(&cache.ln1, &dn1);
        let (mut dx, gconv1) = self.conv1.backward(&cache.col1, &dh1, steps);
        let gskip = match (&self.skip, &cache.skip_col) {
            (Some(skip), Some(col)) => {
                let (ds, g) = skip.backward(col, dy, steps);
                dx.data.iter_mut().zip(&ds.data).for_each(|(d, s)| *d += s);
                Some(g)
            }
            _ => {
                dx.data.iter_mut().zip(&dy.data).for_each(|(d, s)| *d += s);
                None
            }
        };
        grads.extend([gconv1.w.data, gconv1.b, dgamma1, dbeta1]);
        grads.extend([
            gfilm.w.data,
            gfilm.b,
            gconv2.w.data,
            gconv2.b,
            dgamma2,
            dbeta2,
        ]);
        if let Some(g) = gskip {
            grads.extend([g.w.data, g.b]);
        }
        (dx, dcond)
    }

    pub fn params_mut(&mut self) -> Vec<&mut [f32]> {
        let mut out: Vec<&mut [f32]> = vec![
            &mut self.conv1.linear.w.data,
            &mut self.conv1.linear.b,
            &mut self.norm1.gamma,
            &mut self.norm1.beta,
            &mut self.film.w.data,
            &mut self.film.b,
            &mut self.conv2.linear.w.data,
            &mut self.conv2.linear.b,
            &mut self.norm2.gamma,
            &mut self.norm2.beta,
        ];
        if let Some(skip) = &mut self.skip {
            out.push(&mut skip.linear.w.data);
            out.push(&mut skip.linear.b);
        }
        out
    }
}

/// The mean of each pair of adjacent steps (`steps` even).
fn pool(x: &Matrix, steps: usize) -> Matrix {
    let half = steps / 2;
    let rows = x.rows / 2;
    Matrix::from_fn(rows, x.cols, |r, j| {
        let (b, k) = (r / half, r % half);
        0.5 * (x.get(b * steps + 2 * k, j) + x.get(b * steps + 2 * k + 1, j))
    })
}

fn pool_backward(dy: &Matrix, steps: usize) -> Matrix {
    let half = steps / 2;
    Matrix::from_fn(dy.rows * 2, dy.cols, |r, j| {
        let (b, t) = (r / steps, r % steps);
        0.5 * dy.get(b * half + t / 2, j)
    })
}

/// Each step twice (`steps` of the input).
fn upsample(x: &Matrix, steps: usize) -> Matrix {
    let twice = 2 * steps;
    Matrix::from_fn(x.rows * 2, x.cols, |r, j| {
        let (b, t) = (r / twice, r % twice);
        x.get(b * steps + t / 2, j)
    })
}

fn upsample_backward(dy: &Matrix, steps: usize) -> Matrix {
    let twice = 2 * steps;
    Matrix::from_fn(dy.rows / 2, dy.cols, |r, j| {
        let (b, k) = (r / steps, r % steps);
        dy.get(b * twice + 2 * k, j) + dy.get(b * twice + 2 * k + 1, j)
    })
}

/// `[a | b]`, row by row.
fn concat(a: &Matrix, b: &Matrix) -> Matrix {
    Matrix::from_fn(a.rows, a.cols + b.cols, |i, j| {
        if j < a.cols {
            a.get(i, j)
        } else {
            b.get(i, j - a.cols)
        }
    })
}

fn split(d: &Matrix, left: usize) -> (Matrix, Matrix) {
    (
        Matrix::from_fn(d.rows, left, |i, j| d.get(i, j)),
        Matrix::from_fn(d.rows, d.cols - left, |i, j| d.get(i, left + j)),
    )
}

/// The U-Net: `down[l]` at `steps / 2^l` steps (the input of every level after the first is
/// the mean of the previous level's adjacent steps), `mid` at the coarsest level, `up[l]` at
/// `steps / 2^l` on the upsampled coarser output beside `down[l]`'s (the skip connection),
/// and a 1×1 convolution back to the channels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UNet1d {
    pub steps: usize,
    pub channels: usize,
    pub cond: usize,
    pub down: Vec<ResBlock>,
    pub mid: ResBlock,
    pub up: Vec<ResBlock>,
    pub out: Conv1d,
}

/// What [`UNet1d::backward`] needs from the forward pass.
pub struct UNetCache {
    down: Vec<ResCache>,
    mid: ResCache,
    up: Vec<ResCache>,
    out_col: Matrix,
}

impl UNet1d {
    /// `widths[l]` channels at level `l`; `steps` must halve `widths.len() − 1` times;
    /// `kernel` odd. Parameters draw from stream (name, 0).
    pub fn new(
        channels: usize,
        cond: usize,
        widths: &[usize],
        steps: usize,
        kernel: usize,
        seed: u64,
        name: &str,
    ) -> Result<Self> {
        let levels = widths.len();
        let halvings = levels.saturating_sub(1) as u32;
        if levels == 0
            || widths.contains(&0)
            || channels == 0
            || steps == 0
            || kernel.is_multiple_of(2)
            || !steps.is_multiple_of(1 << halvings)
        {
            return Err(Error::UNetShape {
                widths: widths.to_vec(),
                steps,
                kernel,
            });
        }
        let mut rng = rng::stream(seed, "nn", name, 0);
        let mut down = Vec::with_capacity(levels);
        for l in 0..levels {
            let inputs = if l == 0 { channels } else { widths[l - 1] };
            down.push(ResBlock::new(inputs, widths[l], cond, kernel, &mut rng));
        }
        let coarsest = widths[levels - 1];
        let mid = ResBlock::new(coarsest, coarsest, cond, kernel, &mut rng);
        let up = (0..levels - 1)
            .map(|l| ResBlock::new(widths[l + 1] + widths[l], widths[l], cond, kernel, &mut rng))
            .collect();
        let out = Conv1d::new(widths[0], channels, 1, &mut rng);
        Ok(UNet1d {
            steps,
            channels,
            cond,
            down,
            mid,
            up,
            out,
        })
    }

    /// `x` (`B·steps × channels`) under `cond` (`B × cond`).
    pub fn forward(&self, x: &Matrix, cond: &Matrix) -> (Matrix, UNetCache) {
        let levels = self.down.len();
        let mut steps = self.steps;
        let mut h = x.clone();
        let mut skips = Vec::with_capacity(levels);
        let mut down = Vec::with_capacity(levels);
        for (l, block) in self.down.iter().enumerate() {
            if l > 0 {
                h = pool(&h, steps);
                steps /= 2;
            }
            let (y, cache) = block.forward(&h, steps, cond);
            down.push(cache);
            skips.push(y.clone());
            h = y;
        }
        let (mut h, mid) = self.mid.forward(&h, steps, cond);
        let mut up = Vec::with_capacity(levels - 1);
        for l in (0..levels - 1).rev() {
            let u = upsample(&h, steps);
            steps *= 2;
            let (y, cache) = self.up[l].forward(&concat(&u, &skips[l]), steps, cond);
            up.push(cache);
            h = y;
        }
        up.reverse();
        let (y, out_col) = self.out.forward(&h, steps);
        let cache = UNetCache {
            down,
            mid,
            up,
            out_col,
        };
        (y, cache)
    }

    /// dL/dx, dL/dcond and the parameter gradients in the order of [`UNet1d::params_mut`].
    pub fn backward(
        &self,
        cache: &UNetCache,
        dy: &Matrix,
        cond: &Matrix,
    ) -> (Matrix, Matrix, Vec<Vec<f32>>) {
        let levels = self.down.len();
        let coarsest = self.steps >> (levels - 1);
        let (mut dh, gout) = self.out.backward(&cache.out_col, dy, self.steps);
        let mut dcond = Matrix::zeros(cond.rows, cond.cols);
        let add = |acc: &mut Matrix, d: &Matrix| {
            acc.data.iter_mut().zip(&d.data).for_each(|(a, d)| *a += d);
        };
        // Gradients are computed from the output back but listed in parameter order.
        let mut up_grads: Vec<Vec<Vec<f32>>> = vec![Vec::new(); levels - 1];
        let mut dskips: Vec<Option<Matrix>> = vec![None; levels];
        let mut steps = self.steps;
        for l in 0..levels - 1 {
            let (dcat, dc) = self.up[l].backward(&cache.up[l], &dh, steps, cond, &mut up_grads[l]);
            add(&mut dcond, &dc);
            // `up[l]` reads the upsampled coarser output beside `down[l]`'s.
            let (du, dskip) = split(&dcat, dcat.cols - self.down[l].outputs());
            dskips[l] = Some(dskip);
            steps /= 2;
            dh = upsample_backward(&du, steps);
        }
        debug_assert_eq!(steps, coarsest);
        let mut mid_grads = Vec::new();
        let (mut dh, dc) = self
            .mid
            .backward(&cache.mid, &dh, steps, cond, &mut mid_grads);
        add(&mut dcond, &dc);
        let mut down_grads: Vec<Vec<Vec<f32>>> = vec![Vec::new(); levels];
        for l in (0..levels).rev() {
            if let Some(d) = &dskips[l] {
                add(&mut dh, d);
            }
            let (dx, dc) =
                self.down[l].backward(&cache.down[l], &dh, steps, cond, &mut down_grads[l]);
            add(&mut dcond, &dc);
            dh = if l > 0 {
                steps *= 2;
                pool_backward(&dx, steps)
            } else {
                dx
            };
        }
        let mut grads: Vec<Vec<f32>> = down_grads.into_iter().flatten().collect();
        grads.extend(mid_grads);
        grads.extend(up_grads.into_iter().flatten());
        grads.extend([gout.w.data, gout.b]);
        (dh, dcond, grads)
    }

    /// Every parameter slice: `down`, `mid`, `up` (each block as [`ResBlock::params_mut`]),
    /// then the output convolution.
    pub fn params_mut(&mut self) -> Vec<&mut [f32]> {
        let mut out: Vec<&mut [f32]> = Vec::new();
        for b in &mut self.down {
            out.extend(b.params_mut());
        }
        out.extend(self.mid.params_mut());
        for b in &mut self.up {
            out.extend(b.params_mut());
        }
        out.push(&mut self.out.linear.w.data);
        out.push(&mut self.out.linear.b);
        out
    }

    pub fn parameter_count(&self) -> usize {
        self.clone().params_mut().iter().map(|p| p.len()).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random(rows: usize, cols: usize, seed: u64) -> Matrix {
        let mut r = rng::stream(seed, "test", "unet", 0);
        Matrix::from_fn(rows, cols, |_, _| rng::uniform(&mut r, -1.0, 1.0) as f32)
    }

    /// L = Σ y·w for a fixed w: dL/dy = w.
    fn loss(net: &UNet1d, x: &Matrix, cond: &Matrix, w: &Matrix) -> f64 {
        let (y, _) = net.forward(x, cond);
        y.data
            .iter()
            .zip(&w.data)
            .map(|(a, b)| f64::from(*a) * f64::from(*b))
            .sum()
    }

    /// Reverse-mode gradients against central differences for every parameter tensor (a few
    /// entries of each), the input and the condition, on a two-level net with a width change
    /// at every block (so every skip convolution is exercised) and a kernel of 3 (padding).
    #[test]
    fn gradients_match_finite_differences() {
        let (batch, steps, channels, cond_dim) = (2, 4, 3, 5);
        let net = UNet1d::new(channels, cond_dim, &[4, 6], steps, 3, 7, "fd").expect("net");
        let x = random(batch * steps, channels, 1);
        let cond = random(batch, cond_dim, 2);
        let w = random(batch * steps, channels, 3);
        let (_, cache) = net.forward(&x, &cond);
        let (dx, dcond, grads) = net.backward(&cache, &w, &cond);

        let h = 1e-2f32;
        let check = |analytic: f32, plus: f64, minus: f64, what: &str| {
            let fd = (plus - minus) / (2.0 * f64::from(h));
            let err = (f64::from(analytic) - fd).abs();
            assert!(
                err <= 2e-3 + 2e-2 * fd.abs(),
                "{what}: analytic {analytic}, finite difference {fd}"
            );
        };
        let mut probe = net.clone();
        let n_params = probe.params_mut().len();
        assert_eq!(grads.len(), n_params, "one gradient per parameter slice");
        for p in 0..n_params {
            let len = probe.params_mut()[p].len();
            assert_eq!(grads[p].len(), len, "slice {p}");
            for i in [0, len / 2, len - 1] {
                let orig = probe.params_mut()[p][i];
                probe.params_mut()[p][i] = orig + h;
                let plus = loss(&probe, &x, &cond, &w);
                probe.params_mut()[p][i] = orig - h;
                let minus = loss(&probe, &x, &cond, &w);
                probe.params_mut()[p][i] = orig;
                check(grads[p][i], plus, minus, &format!("param slice {p}[{i}]"));
            }
        }
        for (what, analytic) in [("x", &dx), ("cond", &dcond)] {
            for i in 0..analytic.data.len() {
                let at = |delta: f32| {
                    let (mut xs, mut cs) = (x.clone(), cond.clone());
                    let m = if what == "x" { &mut xs } else { &mut cs };
                    m.data[i] += delta;
                    loss(&net, &xs, &cs, &w)
                };
                check(analytic.data[i], at(h), at(-h), what);
            }
        }
    }

    /// The convolution is what its definition says: y[t] = b + Σ_k W_k · x[t + k − 1], zero
    /// outside the sequence, each sample on its own.
    #[test]
    fn conv_matches_its_definition() {
        let mut r = rng::stream(3, "test", "conv", 0);
        let conv = Conv1d::new(2, 3, 3, &mut r);
        let (batch, steps) = (2, 5);
        let x = random(batch * steps, 2, 4);
        let (y, _) = conv.forward(&x, steps);
        for b in 0..batch {
            for t in 0..steps {
                for o in 0..3 {
                    let mut want = f64::from(conv.linear.b[o]);
                    for k in 0..3 {
                        let s = t as isize + k as isize - 1;
                        if s < 0 || s >= steps as isize {
                            continue;
                        }
                        for c in 0..2 {
                            want += f64::from(conv.linear.w.get(k * 2 + c, o))
                                * f64::from(x.get(b * steps + s as usize, c));
                        }
                    }
                    let got = f64::from(y.get(b * steps + t, o));
                    assert!(
                        (got - want).abs() < 1e-5,
                        "b {b} t {t} o {o}: {got} vs {want}"
                    );
                }
            }
        }
    }

    /// A sample's output depends on its own steps and condition only, and the shape rules
    /// refuse what cannot be built.
    #[test]
    fn samples_are_independent_and_shapes_are_checked() {
        let net = UNet1d::new(3, 4, &[8, 8, 8], 8, 3, 1, "ind").expect("net");
        let x = random(2 * 8, 3, 5);
        let cond = random(2, 4, 6);
        let (both, _) = net.forward(&x, &cond);
        let first = Matrix::from_vec(8, 3, x.data[..24].to_vec());
        let (alone, _) = net.forward(&first, &Matrix::from_vec(1, 4, cond.data[..4].to_vec()));
        assert_eq!(&both.data[..24], &alone.data[..]);
        assert!(
            UNet1d::new(3, 4, &[8, 8, 8, 8], 4, 3, 1, "x").is_err(),
            "4 steps halve once"
        );
        assert!(
            UNet1d::new(3, 4, &[8], 8, 2, 1, "x").is_err(),
            "even kernel"
        );
        assert!(UNet1d::new(3, 4, &[], 8, 3, 1, "x").is_err(), "no level");
    }
}
