//! Linear layers, activations and MLPs with hand-derived reverse-mode gradients.

use osms_core::rng::{self, StreamRng};
use serde::{Deserialize, Serialize};

use crate::kernels::{Level, PackedB, matmul, matmul_acc_packed, matmul_nt, matmul_tn};
use crate::{Error, Matrix, Result};

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

    /// d² apply / dx² at `x`. At a kink (Relu's and Elu's 0) it is the one-sided value that
    /// [`Activation::derivative`] picks there: 0 for Relu, the left limit 1 for Elu.
    pub fn second_derivative(self, x: f32) -> f32 {
        self.derivatives(x).1
    }

    /// `(derivative(x), second_derivative(x))` with one evaluation of the transcendental; the
    /// first is bit-identical to [`Activation::derivative`].
    fn derivatives(self, x: f32) -> (f32, f32) {
        match self {
            Activation::Identity => (1.0, 0.0),
            Activation::Relu => (self.derivative(x), 0.0),
            Activation::Tanh => {
                let t = libm::tanhf(x);
                let d = 1.0 - t * t;
                (d, -2.0 * t * d)
            }
            Activation::Silu => {
                // With s = σ(x): silu' = s(1 + x(1 − s)), silu'' = s(1 − s)(2 + x(1 − 2s)). The
                // first is spelt exactly as in `math::silu_with_derivative` to keep its bits;
                // 1 − s rather than e·s keeps the second finite where e overflows to ∞.
                let e = crate::math::exp(-x);
                let s = 1.0 / (1.0 + e);
                let q = 1.0 - s;
                (s * (1.0 + x * q), s * q * (2.0 + x * (q - s)))
            }
            Activation::Elu => {
                if x > 0.0 {
                    (1.0, 0.0)
                } else {
                    let e = libm::expf(x);
                    (e, e)
                }
            }
        }
    }

    /// `z ← apply(z)` element-wise, SiLU in SIMD lanes; the one code path for every forward
    /// value so that [`Mlp::forward`] and [`Mlp::jet`] give the same bits.
    fn apply_slice(self, z: &mut [f32]) {
        if self == Activation::Silu {
            crate::math::silu_slice(z);
        } else {
            z.iter_mut().for_each(|v| *v = self.apply(*v));
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
        add_bias(&mut y, &self.b);
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

/// Forward-mode derivatives of an MLP at one input row (see [`Mlp::jet`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Jet {
    /// The output at x (as `forward` gives it).
    pub y: Vec<f32>,
    /// Row k: ∂y/∂x · tangents[k] (k × outputs).
    pub dy: Matrix,
    /// ∂²y/∂x²[v, v] for the `curve` direction v, if one was given.
    pub ddy: Option<Vec<f32>>,
}

/// What the backward pass needs from the forward pass: each layer's input and the slope of its
/// activation at the pre-activation.
pub struct MlpCache {
    inputs: Vec<Matrix>,
    slopes: Vec<Matrix>,
}

impl Mlp {
    /// `sizes` = [inputs, hidden…, outputs]; layer `l` draws from stream (name, l). Refuses
    /// fewer than two sizes and a layer without units (a width of 0 in params).
    pub fn new(
        sizes: &[usize],
        hidden: Activation,
        output: Activation,
        seed: u64,
        name: &str,
    ) -> Result<Self> {
        if sizes.len() < 2 {
            return Err(Error::TooFewSizes {
                sizes: sizes.to_vec(),
            });
        }
        if let Some(layer) = sizes.iter().position(|&s| s == 0) {
            return Err(Error::EmptyLayer {
                layer,
                sizes: sizes.to_vec(),
            });
        }
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(l, w)| Linear::new(w[0], w[1], &mut rng::stream(seed, "nn", name, l as u64)))
            .collect();
        Ok(Mlp {
            layers,
            hidden,
            output,
        })
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
            a = layer.forward(&a);
            self.activation(l).apply_slice(&mut a.data);
        }
        a
    }

    /// The output at one input row `x` and its forward-mode derivatives: the directional
    /// derivative ∂y/∂x · d for every row d of `tangents` (`k × inputs`; the unit vectors on
    /// inputs `r` give the transpose of [`Mlp::input_jacobian`] over `r`) and, given a `curve`
    /// direction v, the second directional derivative ∂²y/∂x²[v, v], the acceleration of
    /// t ↦ y(x + t v) at t = 0.
    ///
    /// `y` has the bits of [`Mlp::forward`] on the one-row matrix of `x`. Every product goes
    /// through [`matmul`], so the derivatives' bits are fixed too; each row of `dy` has the same
    /// bits whatever the other rows are and whether or not a curve is given.
    pub fn jet(&self, x: &[f32], tangents: &Matrix, curve: Option<&[f32]>) -> Jet {
        let n = x.len();
        assert_eq!(
            tangents.cols, n,
            "jet: {} tangent columns for {n} inputs",
            tangents.cols
        );
        let k = tangents.rows;
        // All derivatives ride in one matrix so that each layer is one product: the tangents,
        // then with a curve its velocity v and acceleration (0 at the input, where x + t v is
        // linear in t). The kernels compute each row of a product independently of the others,
        // so stacking changes no bits.
        let mut d = tangents.clone();
        if let Some(v) = curve {
            assert_eq!(
                v.len(),
                n,
                "jet: curve direction of {} for {n} inputs",
                v.len()
            );
            d.data.extend_from_slice(v);
            d.data.extend(std::iter::repeat_n(0.0, n));
            d.rows += 2;
        }
        let mut a = Matrix::from_vec(1, n, x.to_vec());
        for (l, layer) in self.layers.iter().enumerate() {
            let act = self.activation(l);
            let mut z = layer.forward(&a);
            // Tangents are differences of inputs, so the bias drops out.
            let mut dz = matmul(&d, &layer.w);
            let width = z.cols;
            let slopes: Vec<(f32, f32)> = z.data.iter().map(|&u| act.derivatives(u)).collect();
            if curve.is_some() {
                // The acceleration needs the curve's velocity before the activation scales it.
                let (first, acc) = dz.data.split_at_mut((dz.rows - 1) * width);
                let velocity = &first[(dz.rows - 2) * width..];
                for ((dd, &v), &(s1, s2)) in acc.iter_mut().zip(velocity).zip(&slopes) {
                    *dd = s2 * (v * v) + s1 * *dd;
                }
            }
            let first_order = dz.rows - usize::from(curve.is_some());
            for row in dz.data[..first_order * width].chunks_exact_mut(width) {
                for (t, &(s1, _)) in row.iter_mut().zip(&slopes) {
                    *t *= s1;
                }
            }
            act.apply_slice(&mut z.data);
            a = z;
            d = dz;
        }
        let outputs = a.cols;
        let ddy = curve.map(|_| d.row(d.rows - 1).to_vec());
        d.data.truncate(k * outputs);
        Jet {
            y: a.data,
            dy: Matrix::from_vec(k, outputs, d.data),
            ddy,
        }
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

/// An [`Mlp`] prepared to run forward many times: every layer's weights packed once
/// ([`PackedB`]; [`Mlp::forward`] packs them on every call), and the first layer's weight rows
/// split after the first `fixed` inputs, so that inputs which stay the same over many calls (a
/// flow's condition over its Euler steps) are multiplied once ([`MlpInference::prefix`]).
/// [`MlpInference::forward`] has the bits of [`Mlp::forward`] on the joined input: a product
/// sums k in order, so continuing the fixed inputs' sums over the others is the whole sum.
#[derive(Debug, Clone)]
pub struct MlpInference {
    fixed: PackedB,
    varying: PackedB,
    rest: Vec<PackedB>,
    biases: Vec<Vec<f32>>,
    activations: Vec<Activation>,
}

impl MlpInference {
    /// `mlp` with its first `fixed` inputs multiplied apart (at most its input width).
    pub fn new(mlp: &Mlp, fixed: usize) -> Self {
        let first = &mlp.layers[0].w;
        let fixed = fixed.min(first.rows);
        let rows = |r: std::ops::Range<usize>| {
            PackedB::new(Matrix::from_vec(
                r.len(),
                first.cols,
                first.data[r.start * first.cols..r.end * first.cols].to_vec(),
            ))
        };
        MlpInference {
            fixed: rows(0..fixed),
            varying: rows(fixed..first.rows),
            rest: mlp.layers[1..]
                .iter()
                .map(|l| PackedB::new(l.w.clone()))
                .collect(),
            biases: mlp.layers.iter().map(|l| l.b.clone()).collect(),
            activations: (0..mlp.layers.len()).map(|l| mlp.activation(l)).collect(),
        }
    }

    /// The first layer's sums over the fixed inputs, one row per row of `fixed` (no bias).
    pub fn prefix(&self, fixed: &Matrix) -> Matrix {
        let mut c = Matrix::zeros(fixed.rows, self.fixed.matrix().cols);
        matmul_acc_packed(fixed, &self.fixed, &mut c);
        c
    }

    /// The output on rows [fixed, varying], from `prefix` = [`MlpInference::prefix`] of the
    /// fixed part: [`Mlp::forward`]'s bits.
    pub fn forward(&self, prefix: &Matrix, varying: &Matrix) -> Matrix {
        let mut a = prefix.clone();
        matmul_acc_packed(varying, &self.varying, &mut a);
        self.finish(0, &mut a);
        for (l, w) in self.rest.iter().enumerate() {
            let mut y = Matrix::zeros(a.rows, w.matrix().cols);
            matmul_acc_packed(&a, w, &mut y);
            self.finish(l + 1, &mut y);
            a = y;
        }
        a
    }

    /// Layer `l`'s bias and activation, as [`Linear::forward`] and [`Mlp::forward`] apply them.
    fn finish(&self, l: usize, y: &mut Matrix) {
        add_bias(y, &self.biases[l]);
        self.activations[l].apply_slice(&mut y.data);
    }
}

/// `b` added to every row of `y`.
fn add_bias(y: &mut Matrix, b: &[f32]) {
    for row in y.data.chunks_exact_mut(y.cols.max(1)) {
        for (v, b) in row.iter_mut().zip(b) {
            *v += b;
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    const ACTIVATIONS: [Activation; 5] = [
        Activation::Identity,
        Activation::Relu,
        Activation::Tanh,
        Activation::Silu,
        Activation::Elu,
    ];

    fn net(hidden: Activation, output: Activation, seed: u64) -> Mlp {
        Mlp::new(&[5, 7, 6, 3], hidden, output, seed, "t").expect("a valid MLP")
    }

    fn random(rows: usize, cols: usize, seed: u64) -> Matrix {
        let mut r = rng::stream(seed, "nn-jet", "data", (rows * 97 + cols) as u64);
        Matrix::from_fn(rows, cols, |_, _| rng::uniform(&mut r, -1.0, 1.0) as f32)
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn prepared_inference_has_the_bits_of_forward_for_any_split_and_batch() {
        // Wide enough for the tiled path and the threads; one layer alone as well.
        let deep = Mlp::new(
            &[70, 64, 48, 20],
            Activation::Silu,
            Activation::Tanh,
            3,
            "t",
        )
        .expect("a valid MLP");
        let single =
            Mlp::new(&[9, 4], Activation::Silu, Activation::Elu, 4, "t").expect("a valid MLP");
        for mlp in [deep, single] {
            let inputs = mlp.layers[0].w.rows;
            for rows in [1, 2, 3, 16, 150] {
                let x = random(rows, inputs, 11);
                let want = bits(&mlp.forward(&x).data);
                for fixed in [0, 1, inputs / 2, inputs - 1, inputs] {
                    let prepared = MlpInference::new(&mlp, fixed);
                    let cols = |r: std::ops::Range<usize>| {
                        Matrix::from_fn(rows, r.len(), |i, j| x.get(i, r.start + j))
                    };
                    let prefix = prepared.prefix(&cols(0..fixed));
                    let got = prepared.forward(&prefix, &cols(fixed..inputs));
                    assert_eq!(
                        bits(&got.data),
                        want,
                        "{inputs} inputs, {rows} rows, fixed {fixed}"
                    );
                }
            }
        }
    }

    fn act_f64(act: Activation, x: f64) -> f64 {
        match act {
            Activation::Identity => x,
            Activation::Relu => x.max(0.0),
            Activation::Tanh => x.tanh(),
            Activation::Silu => x / (1.0 + (-x).exp()),
            Activation::Elu => {
                if x > 0.0 {
                    x
                } else {
                    x.exp_m1()
                }
            }
        }
    }

    /// The same network in f64, and the pre-activations of every layer whose activation has a
    /// kink at 0 (where differences across the kink say nothing about the derivatives there).
    fn forward_f64(net: &Mlp, x: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let mut a = x.to_vec();
        let mut kinks = Vec::new();
        for (l, layer) in net.layers.iter().enumerate() {
            let act = net.activation(l);
            let z: Vec<f64> = (0..layer.w.cols)
                .map(|j| {
                    let dot: f64 = a
                        .iter()
                        .enumerate()
                        .map(|(i, &ai)| ai * f64::from(layer.w.get(i, j)))
                        .sum();
                    dot + f64::from(layer.b[j])
                })
                .collect();
            if matches!(act, Activation::Relu | Activation::Elu) {
                kinks.extend(&z);
            }
            a = z.into_iter().map(|u| act_f64(act, u)).collect();
        }
        (a, kinks)
    }

    /// x + t·d in f64.
    fn along(x: &[f32], d: &[f32], t: f64) -> Vec<f64> {
        x.iter()
            .zip(d)
            .map(|(&xi, &di)| f64::from(xi) + t * f64::from(di))
            .collect()
    }

    /// Whether a kinked pre-activation changes sign on x ± h·d.
    fn crosses_kink(net: &Mlp, x: &[f32], d: &[f32], h: f64) -> bool {
        let signs = |t| {
            forward_f64(net, &along(x, d, t))
                .1
                .iter()
                .map(|&u| u > 0.0)
                .collect::<Vec<_>>()
        };
        let mid = signs(0.0);
        signs(h) != mid || signs(-h) != mid
    }

    /// |a − b| / max(1, |b|): the tolerance the f32 differences are held to.
    fn err(a: f32, b: f64) -> f64 {
        (f64::from(a) - b).abs() / b.abs().max(1.0)
    }

    /// max |a − b| / max(|b|, floor) over a vector: relative to the vector's size, so that
    /// small entries are neither excused nor blown up by cancellation in the reference.
    fn normwise(a: &[f32], b: &[f64], floor: f64) -> f64 {
        let size = b.iter().fold(floor, |m, v| m.max(v.abs()));
        a.iter()
            .zip(b)
            .map(|(&a, &b)| (f64::from(a) - b).abs() / size)
            .fold(0.0, f64::max)
    }

    /// The network with every weight scaled, for pre-activations well into the curved parts.
    fn sharpened(mut net: Mlp, scale: f32) -> Mlp {
        for layer in &mut net.layers {
            layer.w.data.iter_mut().for_each(|w| *w *= scale);
        }
        net
    }

    #[test]
    fn derivatives_agree_with_derivative_and_closed_forms() {
        let mut worst = 0.0f64;
        for act in ACTIVATIONS {
            for i in -400..=400 {
                let x = i as f32 * 0.0173;
                let (d1, d2) = act.derivatives(x);
                assert_eq!(d1.to_bits(), act.derivative(x).to_bits(), "{act:?} {x}");
                assert_eq!(d2.to_bits(), act.second_derivative(x).to_bits());
                let xf = f64::from(x);
                let exact = match act {
                    Activation::Identity | Activation::Relu => 0.0,
                    Activation::Tanh => {
                        let t = xf.tanh();
                        -2.0 * t * (1.0 - t * t)
                    }
                    Activation::Silu => {
                        let s = 1.0 / (1.0 + (-xf).exp());
                        s * (1.0 - s) * (2.0 + xf * (1.0 - 2.0 * s))
                    }
                    Activation::Elu => {
                        if xf > 0.0 {
                            0.0
                        } else {
                            xf.exp()
                        }
                    }
                };
                worst = worst.max((f64::from(d2) - exact).abs());
            }
            for x in [-1e30, -1e4, -100.0, 100.0, 1e4, 1e30] {
                assert!(act.second_derivative(x).is_finite(), "{act:?} {x}");
            }
        }
        eprintln!("second_derivative vs f64 closed form: worst absolute {worst:.2e}");
        assert!(worst < 1e-6, "{worst}");
    }

    #[test]
    fn jet_value_is_forward_bit_for_bit() {
        for hidden in ACTIVATIONS {
            for output in ACTIVATIONS {
                for scale in [1.0, 3.0] {
                    let net = sharpened(net(hidden, output, 3), scale);
                    for p in 0..4 {
                        let x = random(1, 5, 10 + p).data;
                        let forward = net.forward(&Matrix::from_vec(1, 5, x.clone()));
                        let v = random(1, 5, 20 + p).data;
                        for jet in [
                            net.jet(&x, &random(3, 5, p), Some(&v)),
                            net.jet(&x, &Matrix::zeros(0, 5), None),
                        ] {
                            assert_eq!(bits(&jet.y), bits(&forward.data), "{hidden:?} {output:?}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn jet_tangents_match_reverse_mode_and_f64_differences() {
        let (mut vs_reverse, mut vs_fd) = (0.0f64, 0.0f64);
        let mut checked = 0;
        for hidden in ACTIVATIONS {
            for output in ACTIVATIONS {
                for scale in [1.0, 3.0] {
                    let net = sharpened(net(hidden, output, 5), scale);
                    for p in 0..4 {
                        let x = random(1, 5, 30 + p).data;
                        let eye = Matrix::from_fn(5, 5, |i, j| if i == j { 1.0 } else { 0.0 });
                        let jet = net.jet(&x, &eye, None);
                        let reverse = net.input_jacobian(&x, 0..5).transpose();
                        let reverse: Vec<f64> = reverse.data.iter().map(|&v| v.into()).collect();
                        vs_reverse = vs_reverse.max(normwise(&jet.dy.data, &reverse, 1e-3));
                        let tangents = random(4, 5, 40 + p);
                        let jet = net.jet(&x, &tangents, None);
                        let h = 1e-6;
                        let (mut ours, mut fd) = (Vec::new(), Vec::new());
                        for k in 0..tangents.rows {
                            let d = tangents.row(k);
                            if crosses_kink(&net, &x, d, h) {
                                continue;
                            }
                            checked += 1;
                            let up = forward_f64(&net, &along(&x, d, h)).0;
                            let down = forward_f64(&net, &along(&x, d, -h)).0;
                            ours.extend_from_slice(jet.dy.row(k));
                            fd.extend((0..3).map(|o| (up[o] - down[o]) / (2.0 * h)));
                        }
                        vs_fd = vs_fd.max(normwise(&ours, &fd, 1e-3));
                    }
                }
            }
        }
        eprintln!(
            "dy vs input_jacobian: worst {vs_reverse:.2e}; vs f64 central differences: \
             worst {vs_fd:.2e} over {checked} directions (relative to the largest entry)"
        );
        assert!(vs_reverse < 1e-5, "{vs_reverse}");
        assert!(vs_fd < 1e-5, "{vs_fd}");
        assert!(checked > 700, "{checked}");
    }

    #[test]
    fn jet_curvature_matches_second_differences() {
        let (mut vs_f64, mut vs_f32) = (0.0f64, 0.0f64);
        let (mut checked, mut biggest) = (0, 0.0f32);
        let piecewise_linear = |a| matches!(a, Activation::Identity | Activation::Relu);
        for hidden in ACTIVATIONS {
            for output in ACTIVATIONS {
                for scale in [1.0, 3.0] {
                    let net = sharpened(net(hidden, output, 7), scale);
                    for p in 0..8 {
                        let x = random(1, 5, 50 + p).data;
                        let v = random(1, 5, 60 + p).data;
                        let jet = net.jet(&x, &Matrix::zeros(0, 5), Some(&v));
                        let ddy = jet.ddy.expect("a curve gives ddy");
                        biggest = ddy.iter().fold(biggest, |m, d| m.max(d.abs()));
                        if piecewise_linear(hidden) && piecewise_linear(output) {
                            assert_eq!(bits(&ddy), bits(&[0.0; 3]), "{hidden:?} {output:?}");
                        }
                        // f64 differences of the same network. Their rounding error, about
                        // 1e-16·|y|/h², reaches 1e-7 on the sharpened networks (|y| up to ~40),
                        // hence the floor of 1 under the scale.
                        let h = 1e-4;
                        if !crosses_kink(&net, &x, &v, h) {
                            checked += 1;
                            let y = |t| forward_f64(&net, &along(&x, &v, t)).0;
                            let (up, mid, down) = (y(h), y(0.0), y(-h));
                            let fd: Vec<f64> = (0..3)
                                .map(|o| (up[o] - 2.0 * mid[o] + down[o]) / (h * h))
                                .collect();
                            vs_f64 = vs_f64.max(normwise(&ddy, &fd, 1.0));
                        }
                        // The f32 network itself, where rounding (about 1e-7·|y|/h²) limits h
                        // and the tolerance; only the unsharpened networks keep it below 2e-2.
                        let h = 1e-2f32;
                        if scale == 1.0 && !crosses_kink(&net, &x, &v, f64::from(h)) {
                            let y = |t: f32| {
                                let at: Vec<f32> =
                                    x.iter().zip(&v).map(|(a, b)| a + t * b).collect();
                                net.forward(&Matrix::from_vec(1, 5, at)).data
                            };
                            let (up, mid, down) = (y(h), y(0.0), y(-h));
                            for o in 0..3 {
                                let fd = (up[o] - 2.0 * mid[o] + down[o]) / (h * h);
                                vs_f32 = vs_f32.max(err(ddy[o], f64::from(fd)));
                            }
                        }
                    }
                }
            }
        }
        eprintln!(
            "ddy vs f64 second differences: worst {vs_f64:.2e} over {checked} points \
             (largest |ddy| {biggest:.2}); vs f32 second differences: worst {vs_f32:.2e}"
        );
        assert!(vs_f64 < 2e-5, "{vs_f64}");
        assert!(vs_f32 < 2e-2, "{vs_f32}");
        assert!(checked > 300, "{checked}");
    }

    #[test]
    fn identity_mlp_jet_is_the_linear_map() {
        let net = net(Activation::Identity, Activation::Identity, 9);
        // W₁·W₂·W₃ in f64.
        let mut map: Vec<Vec<f64>> = (0..5)
            .map(|i| (0..5).map(|j| f64::from(u8::from(i == j))).collect())
            .collect();
        for layer in &net.layers {
            map = map
                .iter()
                .map(|row| {
                    (0..layer.w.cols)
                        .map(|j| {
                            row.iter()
                                .enumerate()
                                .map(|(i, &r)| r * f64::from(layer.w.get(i, j)))
                                .sum()
                        })
                        .collect()
                })
                .collect();
        }
        let tangents = random(6, 5, 70);
        let v = random(1, 5, 71).data;
        let first = net.jet(&random(1, 5, 72).data, &tangents, Some(&v));
        let second = net.jet(&random(1, 5, 73).data, &tangents, Some(&v));
        assert_eq!(first.ddy, Some(vec![0.0; 3]));
        assert_eq!(second.ddy, Some(vec![0.0; 3]));
        assert_eq!(bits(&first.dy.data), bits(&second.dy.data));
        let exact: Vec<f64> = (0..tangents.rows * 3)
            .map(|e| {
                let (k, o) = (e / 3, e % 3);
                map.iter()
                    .enumerate()
                    .map(|(i, row)| f64::from(tangents.get(k, i)) * row[o])
                    .sum()
            })
            .collect();
        let worst = normwise(&first.dy.data, &exact, 1e-3);
        eprintln!("identity MLP dy vs f64 W1·W2·W3: worst {worst:.2e} (relative to the largest)");
        assert!(worst < 1e-6, "{worst}");
    }

    #[test]
    fn jet_rows_do_not_depend_on_each_other() {
        let net = net(Activation::Silu, Activation::Tanh, 11);
        let x = random(1, 5, 80).data;
        let tangents = random(5, 5, 81);
        let v = random(1, 5, 82).data;
        let all = net.jet(&x, &tangents, Some(&v));
        assert_eq!(all.dy, net.jet(&x, &tangents, None).dy);
        assert_eq!(all.ddy, net.jet(&x, &Matrix::zeros(0, 5), Some(&v)).ddy);
        for k in 0..tangents.rows {
            let one = net.jet(&x, &Matrix::from_vec(1, 5, tangents.row(k).to_vec()), None);
            assert_eq!(bits(one.dy.row(0)), bits(all.dy.row(k)));
        }
        let none = net.jet(&x, &Matrix::zeros(0, 5), None);
        assert_eq!((none.dy.rows, none.dy.cols, none.ddy), (0, 3, None));
    }
}
