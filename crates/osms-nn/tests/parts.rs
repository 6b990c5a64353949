//! LayerNorm, the embedding, the Gaussian head, cross-entropy and input Jacobians against finite
//! differences and closed forms; a small classification trained to a known loss.

use osms_core::rng;
use osms_nn::{
    Activation, Adam, AdamConfig, DiagGaussian, LayerNorm, Matrix, Mlp, Schedule, flatten_grads,
    sinusoidal_embedding, sinusoidal_embedding_backward, softmax_cross_entropy,
};

fn random(rows: usize, cols: usize, seed: u64, scale: f64) -> Matrix {
    let mut r = rng::stream(seed, "nn-parts", "data", (rows * 97 + cols) as u64);
    Matrix::from_fn(rows, cols, |_, _| {
        rng::uniform(&mut r, -scale, scale) as f32
    })
}

fn close(analytic: f32, numeric: f32, what: &str) {
    let tol = 2e-3 + 2e-2 * numeric.abs().max(analytic.abs());
    assert!(
        (analytic - numeric).abs() <= tol,
        "{what}: analytic {analytic} vs numeric {numeric}"
    );
}

/// Central difference of `f` in coordinate `i` of `v`.
fn fd(v: &[f32], i: usize, f: &dyn Fn(&[f32]) -> f32) -> f32 {
    let eps = 1e-2;
    let mut up = v.to_vec();
    up[i] += eps;
    let mut down = v.to_vec();
    down[i] -= eps;
    (f(&up) - f(&down)) / (2.0 * eps)
}

fn dot(a: &Matrix, b: &Matrix) -> f32 {
    a.data.iter().zip(&b.data).map(|(x, y)| x * y).sum()
}

#[test]
fn layer_norm_gradients() {
    let x = random(4, 6, 1, 2.0);
    let c = random(4, 6, 2, 1.0);
    let mut ln = LayerNorm::new(6);
    ln.gamma = random(1, 6, 3, 1.0).data;
    ln.beta = random(1, 6, 4, 1.0).data;
    let (_, cache) = ln.forward(&x);
    let (dx, dgamma, dbeta) = ln.backward(&cache, &c);
    for i in 0..x.data.len() {
        let f = |v: &[f32]| dot(&ln.forward(&Matrix::from_vec(4, 6, v.to_vec())).0, &c);
        close(dx.data[i], fd(&x.data, i, &f), &format!("dx {i}"));
    }
    for j in 0..6 {
        let fg = |v: &[f32]| {
            let mut l = ln.clone();
            l.gamma = v.to_vec();
            dot(&l.forward(&x).0, &c)
        };
        close(dgamma[j], fd(&ln.gamma, j, &fg), &format!("dgamma {j}"));
        let fb = |v: &[f32]| {
            let mut l = ln.clone();
            l.beta = v.to_vec();
            dot(&l.forward(&x).0, &c)
        };
        close(dbeta[j], fd(&ln.beta, j, &fb), &format!("dbeta {j}"));
    }
    // Each normalised row has mean 0 and variance 1 (up to eps).
    let (y, _) = LayerNorm::new(6).forward(&x);
    for i in 0..4 {
        let mean: f32 = y.row(i).iter().sum::<f32>() / 6.0;
        let var: f32 = y
            .row(i)
            .iter()
            .map(|v| (v - mean) * (v - mean))
            .sum::<f32>()
            / 6.0;
        assert!(mean.abs() < 1e-5 && (var - 1.0).abs() < 1e-3);
    }
}

#[test]
fn sinusoidal_embedding_gradient_and_values() {
    let t = vec![0.0f32, 0.3, 0.77, 1.0];
    let c = random(4, 8, 5, 1.0);
    let grad = sinusoidal_embedding_backward(&t, &c, 100.0);
    let f = |v: &[f32]| dot(&sinusoidal_embedding(v, 8, 100.0), &c);
    for (i, &g) in grad.iter().enumerate() {
        close(g, fd(&t, i, &f), &format!("dt {i}"));
    }
    let e = sinusoidal_embedding(&[0.5], 4, 100.0);
    // Frequencies 1 and 100^(-1/2) = 0.1.
    let expected = [0.5f32.sin(), 0.05f32.sin(), 0.5f32.cos(), 0.05f32.cos()];
    for (a, b) in e.data.iter().zip(expected) {
        assert!((a - b).abs() < 1e-6);
    }
}

#[test]
fn gaussian_head_log_prob_entropy_and_kl() {
    let mean = random(3, 4, 6, 1.0);
    let log_std = random(3, 4, 7, 0.5);
    let x = random(3, 4, 8, 1.5);
    let upstream = [0.5f32, -1.0, 2.0];
    let g = DiagGaussian {
        mean: &mean,
        log_std: &log_std,
    };
    let (lp, grad) = g.log_prob(&x, &upstream);
    // Closed form for one entry: N(x; μ, σ) density.
    let (mu, ls, xv) = (mean.get(0, 0), log_std.get(0, 0), x.get(0, 0));
    let sigma = ls.exp();
    let single =
        -0.5 * ((xv - mu) / sigma).powi(2) - sigma.ln() - 0.5 * (2.0 * std::f32::consts::PI).ln();
    let rest: f32 = (1..4)
        .map(|j| {
            let s = log_std.get(0, j).exp();
            -0.5 * ((x.get(0, j) - mean.get(0, j)) / s).powi(2)
                - s.ln()
                - 0.5 * (2.0 * std::f32::consts::PI).ln()
        })
        .sum();
    assert!((lp[0] - (single + rest)).abs() < 1e-5);
    let weighted = |m: &Matrix, s: &Matrix| {
        let (lp, _) = DiagGaussian {
            mean: m,
            log_std: s,
        }
        .log_prob(&x, &upstream);
        lp.iter().zip(&upstream).map(|(a, b)| a * b).sum::<f32>()
    };
    for i in 0..mean.data.len() {
        close(
            grad.mean.data[i],
            fd(&mean.data, i, &|v| {
                weighted(&Matrix::from_vec(3, 4, v.to_vec()), &log_std)
            }),
            "dmean",
        );
        close(
            grad.log_std.data[i],
            fd(&log_std.data, i, &|v| {
                weighted(&mean, &Matrix::from_vec(3, 4, v.to_vec()))
            }),
            "dlogstd",
        );
    }
    // Entropy of N(μ, σ²) per dimension is ½ ln(2πe σ²).
    let h = g.entropy();
    let expected: f32 = (0..4)
        .map(|j| {
            0.5 * (2.0
                * std::f32::consts::PI
                * std::f32::consts::E
                * (2.0 * log_std.get(1, j)).exp())
            .ln()
        })
        .sum();
    assert!((h[1] - expected).abs() < 1e-5);
    let (kl, kgrad) = g.kl_to_standard();
    assert!(kl.iter().all(|k| *k >= 0.0));
    let zero = Matrix::zeros(3, 4);
    assert!(
        DiagGaussian {
            mean: &zero,
            log_std: &zero
        }
        .kl_to_standard()
        .0
        .iter()
        .all(|k| k.abs() < 1e-7)
    );
    let total = |m: &Matrix, s: &Matrix| {
        DiagGaussian {
            mean: m,
            log_std: s,
        }
        .kl_to_standard()
        .0
        .iter()
        .sum::<f32>()
    };
    for i in 0..mean.data.len() {
        close(
            kgrad.mean.data[i],
            fd(&mean.data, i, &|v| {
                total(&Matrix::from_vec(3, 4, v.to_vec()), &log_std)
            }),
            "kl dmean",
        );
        close(
            kgrad.log_std.data[i],
            fd(&log_std.data, i, &|v| {
                total(&mean, &Matrix::from_vec(3, 4, v.to_vec()))
            }),
            "kl dlogstd",
        );
    }
}

#[test]
fn cross_entropy_gradient() {
    let logits = random(5, 3, 9, 2.0);
    let labels = [0usize, 2, 1, 1, 0];
    let (_, grad) = softmax_cross_entropy(&logits, &labels);
    for i in 0..logits.data.len() {
        let f = |v: &[f32]| softmax_cross_entropy(&Matrix::from_vec(5, 3, v.to_vec()), &labels).0;
        close(
            grad.data[i],
            fd(&logits.data, i, &f),
            &format!("dlogit {i}"),
        );
    }
}

#[test]
fn input_jacobian_matches_finite_differences() {
    let net = Mlp::new(
        &[6, 16, 16, 5],
        Activation::Silu,
        Activation::Tanh,
        11,
        "decoder",
    )
    .expect("a valid MLP");
    let x: Vec<f32> = random(1, 6, 12, 1.0).data;
    let range = 2..5;
    let jac = net.input_jacobian(&x, range.clone());
    assert_eq!((jac.rows, jac.cols), (5, 3));
    for o in 0..5 {
        for (k, i) in range.clone().enumerate() {
            let f = |v: &[f32]| net.forward(&Matrix::from_vec(1, 6, v.to_vec())).get(0, o);
            close(jac.get(o, k), fd(&x, i, &f), &format!("J[{o}][{i}]"));
        }
    }
}

#[test]
fn a_small_classification_reaches_a_known_loss() {
    // Three Gaussian blobs in the plane, 0.3 apart in standard deviations of 0.15: separable.
    let centres = [(0.0f32, 1.0f32), (-0.87, -0.5), (0.87, -0.5)];
    let mut r = rng::stream(0, "nn-parts", "blobs", 0);
    let n = 300;
    let labels: Vec<usize> = (0..n).map(|i| i % 3).collect();
    let x = Matrix::from_fn(n, 2, |i, j| {
        let c = centres[labels[i]];
        (if j == 0 { c.0 } else { c.1 }) + 0.15 * rng::normal(&mut r) as f32
    });
    let mut net = Mlp::new(
        &[2, 16, 3],
        Activation::Relu,
        Activation::Identity,
        1,
        "blobs",
    )
    .expect("a valid MLP");
    let mut opt = Adam::new(AdamConfig::default(), Schedule::Constant { lr: 0.02 });
    let mut loss = f32::NAN;
    for _ in 0..300 {
        let (logits, cache) = net.forward_cached(&x);
        let (l, dlogits) = softmax_cross_entropy(&logits, &labels);
        let (_, grads) = net.backward(&cache, &dlogits);
        let owned: Vec<Vec<f32>> = flatten_grads(&grads)
            .into_iter()
            .map(<[f32]>::to_vec)
            .collect();
        let refs: Vec<&[f32]> = owned.iter().map(Vec::as_slice).collect();
        opt.update(&mut net.params_mut(), &refs);
        loss = l;
    }
    assert!(loss < 0.05, "cross-entropy {loss}");
}

#[test]
fn an_mlp_without_an_output_or_with_an_empty_layer_is_refused() {
    let build = |sizes: &[usize]| Mlp::new(sizes, Activation::Silu, Activation::Identity, 0, "bad");
    assert!(matches!(
        build(&[4]),
        Err(osms_nn::Error::TooFewSizes { .. })
    ));
    let err = build(&[4, 8, 0, 2]).expect_err("a layer without units");
    assert!(
        matches!(err, osms_nn::Error::EmptyLayer { layer: 2, .. }),
        "{err}"
    );
    assert!(
        err.to_string().contains("hint: every width in `hidden`"),
        "{err}"
    );
    assert!(build(&[4, 8, 2]).is_ok());
}
