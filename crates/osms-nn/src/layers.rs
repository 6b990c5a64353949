//! Linear layers, activations and MLPs with hand-derived reverse-mode gradients.

use osms_make::rng::{self, StreamRng};
use serde::{Deserialize, Serialize};

use crate::Matrix;
use crate::kernels::{Level, matmul, matmul_nt, matmul_tn};

/// Element-wise activations. SiLU uses [`crate::math::exp`], which runs in SIMD lanes; the
/// others use `libm`; never the platform's maths library.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Activation {
    Identity,
    Relu,
    Tanh,
    Silu,
    Elu,
}

impl Activation {
    pub fn apply(self, x: f32) -> f32 {
        match self {
            Activation::Identity => x,
            Activation::Relu => x.max(0.0),
            Activation::Tanh => libm::tanhf(x),
            Activation::Silu => crate::math::silu(x),
            Activation::Elu => {
                if x > 0.0 {
                    x
                } else {
                    libm::expm1f(x)
                }
            }
        }
    }

    /// `(apply(x), derivative(x))` with one evaluation of the transcendental, bit-identical to
    /// the two separate calls.
    pub fn apply_with_derivative(self, x: f32) -> (f32, f32) {
        match self {
            Activation::Silu => crate::math::silu_with_derivative(x),
            Activation::Tanh => {
                let t = libm::tanhf(x);
                (t, 1.0 - t * t)
            }
            _ => (self.apply(x), self.derivative(x)),
        }
    }

    /// d apply / dx at `x`.
    pub fn derivative(self, x: f32) -> f32 {
        match self {
            Activation::Identity => 1.0,
            Activation::Relu => {
                if x > 0.0 {
                    1.0
                } else {
                    0.0
                }
            }
            Activation::Tanh => {
                let t = libm::tanhf(x);
                1.0 - t * t
            }
            Activation::Silu => crate::math::silu_with_derivative(x).1,
            Activation::Elu => {
                if x > 0.0 {
                    1.0
                } else {
                    libm::expf(x)
                }
            }
        }
    }
}

/// y = x · W + b, W stored `inputs × outputs`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Linear {
    pub w: Matrix,
    pub b: Vec<f32>,
}

/// Gradients of a [`Linear`].
#[derive(Debug, Clone, PartialEq)]
pub struct LinearGrad {
    pub w: Matrix,
    pub b: Vec<f32>,
}

impl Linear {
    /// PyTorch's default initialisation: weights and biases uniform in ±1/√inputs.
    pub fn new(inputs: usize, outputs: usize, rng: &mut StreamRng) -> Self {
        let bound = 1.0 / (inputs as f64).sqrt();
        let w = Matrix::from_fn(inputs, outputs, |_, _| {
            rng::uniform(rng, -bound, bound) as f32
        });
        let b = (0..outputs)
            .map(|_| rng::uniform(rng, -bound, bound) as f32)
            .collect();
        Linear { w, b }
    }

    pub fn forward(&self, x: &Matrix) -> Matrix {
        let mut y = matmul(x, &self.w);
        for i in 0..y.rows {
            for (v, b) in y.data[i * y.cols..(i + 1) * y.cols].iter_mut().zip(&self.b) {
                *v += b;
            }
        }
        y
    }

    /// Given the input `x` and dL/dy, returns dL/dx and the parameter gradients.
    pub fn backward(&self, x: &Matrix, dy: &Matrix) -> (Matrix, LinearGrad) {
        (self.input_gradient(dy), self.param_gradients(x, dy))
    }

    /// dL/dx from dL/dy.
    pub fn input_gradient(&self, dy: &Matrix) -> Matrix {
        matmul_nt(dy, &self.w)
    }

    /// dL/dW and dL/db from the input `x` and dL/dy.
    pub fn param_gradients(&self, x: &Matrix, dy: &Matrix) -> LinearGrad {
        LinearGrad {
            w: matmul_tn(x, dy),
            b: dy.column_sums(),
        }
    }
}

/// A multilayer perceptron: Linear layers with `hidden` activations between them and `output`
/// after the last.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Mlp {
    pub layers: Vec<Linear>,
    pub hidden: Activation,
    pub output: Activation,
}

/// What the backward pass needs from the forward pass: each layer's input and the slope of its
/// activation at the pre-activation.
pub struct MlpCache {
    inputs: Vec<Matrix>,
    slopes: Vec<Matrix>,
}

impl Mlp {
    /// `sizes` = [inputs, hidden…, outputs]; layer `l` draws from stream (name, l).
    pub fn new(
        sizes: &[usize],
        hidden: Activation,
        output: Activation,
        seed: u64,
        name: &str,
    ) -> Self {
        assert!(sizes.len() >= 2, "an MLP needs at least inputs and outputs");
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(l, w)| Linear::new(w[0], w[1], &mut rng::stream(seed, "nn", name, l as u64)))
            .collect();
        Mlp {
            layers,
            hidden,
            output,
        }
    }

    fn activation(&self, layer: usize) -> Activation {
        if layer + 1 == self.layers.len() {
            self.output
        } else {
            self.hidden
        }
    }

    pub fn forward(&self, x: &Matrix) -> Matrix {
        let mut a = x.clone();
        for (l, layer) in self.layers.iter().enumerate() {
            let act = self.activation(l);
            a = layer.forward(&a);
            if act == Activation::Silu {
                crate::math::silu_slice(&mut a.data);
            } else {
                a.data.iter_mut().for_each(|v| *v = act.apply(*v));
            }
        }
        a
    }

    pub fn forward_cached(&self, x: &Matrix) -> (Matrix, MlpCache) {
        let mut cache = MlpCache {
            inputs: Vec::with_capacity(self.layers.len()),
            slopes: Vec::with_capacity(self.layers.len()),
        };
        let mut a = x.clone();
        for (l, layer) in self.layers.iter().enumerate() {
            let mut z = layer.forward(&a);
            let act = self.activation(l);
            let mut slope = Matrix::zeros(z.rows, z.cols);
            if act == Activation::Silu {
                crate::math::silu_slice_with_slope_at(
                    Level::detected(),
                    &mut z.data,
                    &mut slope.data,
                );
            } else {
                for (v, d) in z.data.iter_mut().zip(&mut slope.data) {
                    (*v, *d) = act.apply_with_derivative(*v);
                }
            }
            cache.inputs.push(std::mem::replace(&mut a, z));
            cache.slopes.push(slope);
        }
        (a, cache)
    }

    /// dL/dx and the gradient of every layer, from dL/d output.
    pub fn backward(&self, cache: &MlpCache, dy: &Matrix) -> (Matrix, Vec<LinearGrad>) {
        let (dx, grads) = self.backward_to(cache, dy, true);
        (dx.unwrap_or_else(|| Matrix::zeros(dy.rows, 0)), grads)
    }

    /// The gradient of every layer, from dL/d output, without the product for dL/dx that
    /// training does not need.
    pub fn param_gradients(&self, cache: &MlpCache, dy: &Matrix) -> Vec<LinearGrad> {
        self.backward_to(cache, dy, false).1
    }

    fn backward_to(
        &self,
        cache: &MlpCache,
        dy: &Matrix,
        input_gradient: bool,
    ) -> (Option<Matrix>, Vec<LinearGrad>) {
        let mut grads = Vec::with_capacity(self.layers.len());
        let mut d = Some(dy.clone());
        for l in (0..self.layers.len()).rev() {
            let Some(upstream) = d else { break };
            let dz = upstream.zip(&cache.slopes[l], |g, s| g * s);
            let layer = &self.layers[l];
            grads.push(layer.param_gradients(&cache.inputs[l], &dz));
            d = (l > 0 || input_gradient).then(|| layer.input_gradient(&dz));
        }
        grads.reverse();
        (d, grads)
    }

    /// ∂ outputs / ∂ inputs[range] at one input row `x` (paper Eq. 4's decoder Jacobian J_G with
    /// respect to z): one batched reverse pass with a unit cotangent per output.
    pub fn input_jacobian(&self, x: &[f32], range: std::ops::Range<usize>) -> Matrix {
        let outputs = self.layers.last().map(|l| l.b.len()).unwrap_or(0);
        let batch = Matrix::from_fn(outputs, x.len(), |_, j| x[j]);
        let (_, cache) = self.forward_cached(&batch);
        let eye = Matrix::from_fn(outputs, outputs, |i, j| if i == j { 1.0 } else { 0.0 });
        let (dx, _) = self.backward(&cache, &eye);
        Matrix::from_fn(outputs, range.len(), |o, k| dx.get(o, range.start + k))
    }

    /// Every parameter slice, in a fixed order (layer by layer, weights then bias).
    pub fn params_mut(&mut self) -> Vec<&mut [f32]> {
        self.layers
            .iter_mut()
            .flat_map(|l| [l.w.data.as_mut_slice(), l.b.as_mut_slice()])
            .collect()
    }

    pub fn parameter_count(&self) -> usize {
        self.layers.iter().map(|l| l.w.data.len() + l.b.len()).sum()
    }
}

/// Flattens layer gradients in the order of [`Mlp::params_mut`].
pub fn flatten_grads(grads: &[LinearGrad]) -> Vec<&[f32]> {
    grads
        .iter()
        .flat_map(|g| [g.w.data.as_slice(), g.b.as_slice()])
        .collect()
}

/// Mean squared error over all elements, and its gradient.
pub fn mse(pred: &Matrix, target: &Matrix) -> (f32, Matrix) {
    weighted_mse(pred, target, &vec![1.0; pred.rows])
}

/// Σ_i w_i · mean_j (pred_ij - target_ij)² / Σ_i w_i, and its gradient (per-row weights).
pub fn weighted_mse(pred: &Matrix, target: &Matrix, weights: &[f32]) -> (f32, Matrix) {
    assert_eq!((pred.rows, pred.cols), (target.rows, target.cols));
    assert_eq!(weights.len(), pred.rows);
    let total_w = crate::kernels::sum(weights);
    let scale = 1.0 / (total_w * pred.cols as f32);
    let mut terms = Vec::with_capacity(pred.data.len());
    let mut grad = Matrix::zeros(pred.rows, pred.cols);
    for (i, &w) in weights.iter().enumerate() {
        for j in 0..pred.cols {
            let d = pred.get(i, j) - target.get(i, j);
            terms.push(w * d * d);
            grad.set(i, j, 2.0 * w * d * scale);
        }
    }
    (crate::kernels::sum(&terms) * scale, grad)
}
