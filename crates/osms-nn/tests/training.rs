//! Gradients against central finite differences, training to a known loss, and bit-exact
//! reproducibility across reruns and thread counts.

use osms_core::rng;
use osms_nn::{
    Activation, Adam, AdamConfig, Matrix, Mlp, Schedule, flatten_grads, mse, weighted_mse,
};

fn random(rows: usize, cols: usize, seed: u64) -> Matrix {
    let mut r = rng::stream(seed, "nn-test", "data", (rows * 97 + cols) as u64);
    Matrix::from_fn(rows, cols, |_, _| rng::uniform(&mut r, -1.0, 1.0) as f32)
}

/// Checks dL/dθ and dL/dx of `net` under `loss` against central differences.
fn check_gradients(net: &Mlp, x: &Matrix, loss: &dyn Fn(&Matrix) -> (f32, Matrix), what: &str) {
    let (y, cache) = net.forward_cached(x);
    let (_, dy) = loss(&y);
    let (dx, grads) = net.backward(&cache, &dy);
    let flat: Vec<f32> = flatten_grads(&grads)
        .into_iter()
        .flatten()
        .copied()
        .collect();
    let eps = 1e-2f32;
    let value = |n: &Mlp, x: &Matrix| loss(&n.forward(x)).0;
    let close = |analytic: f32, numeric: f32, label: &str| {
        let tol = 2e-3 + 2e-2 * numeric.abs().max(analytic.abs());
        assert!(
            (analytic - numeric).abs() <= tol,
            "{what}: {label}: analytic {analytic} vs numeric {numeric}"
        );
    };
    // Every parameter of the network.
    let mut index = 0;
    let mut probe = net.clone();
    let count = probe.parameter_count();
    assert_eq!(flat.len(), count);
    for slice in 0..probe.params_mut().len() {
        let len = probe.params_mut()[slice].len();
        for i in 0..len {
            let orig = probe.params_mut()[slice][i];
            probe.params_mut()[slice][i] = orig + eps;
            let up = value(&probe, x);
            probe.params_mut()[slice][i] = orig - eps;
            let down = value(&probe, x);
            probe.params_mut()[slice][i] = orig;
            close(
                flat[index],
                (up - down) / (2.0 * eps),
                &format!("param {slice}/{i}"),
            );
            index += 1;
        }
    }
    // And the input.
    for i in 0..x.data.len() {
        let mut xp = x.clone();
        xp.data[i] += eps;
        let mut xm = x.clone();
        xm.data[i] -= eps;
        close(
            dx.data[i],
            (value(net, &xp) - value(net, &xm)) / (2.0 * eps),
            &format!("input {i}"),
        );
    }
}

#[test]
fn every_activation_layer_and_loss_has_the_finite_difference_gradient() {
    let x = random(6, 4, 1);
    let target = random(6, 3, 2);
    let weights: Vec<f32> = (0..6).map(|i| 0.5 + i as f32 * 0.3).collect();
    for act in [
        Activation::Identity,
        Activation::Relu,
        Activation::Tanh,
        Activation::Silu,
        Activation::Elu,
    ] {
        for out in [Activation::Identity, Activation::Tanh] {
            let net = Mlp::new(&[4, 5, 5, 3], act, out, 7, "gradcheck").expect("a valid MLP");
            check_gradients(
                &net,
                &x,
                &|y| mse(y, &target),
                &format!("{act:?}/{out:?} mse"),
            );
            check_gradients(
                &net,
                &x,
                &|y| weighted_mse(y, &target, &weights),
                &format!("{act:?}/{out:?} weighted mse"),
            );
        }
    }
}

/// Fits y = sin(x) on [-π, π]; returns the final loss and the weights' bytes.
fn fit_sine(steps: u32, seed: u64) -> (f32, Vec<u8>) {
    let mut net = Mlp::new(
        &[1, 32, 32, 1],
        Activation::Tanh,
        Activation::Identity,
        seed,
        "sine",
    )
    .expect("a valid MLP");
    let mut opt = Adam::new(
        AdamConfig {
            max_grad_norm: Some(10.0),
            ..AdamConfig::default()
        },
        Schedule::Cosine {
            lr: 1e-2,
            min_lr: 1e-3,
            steps,
        },
    );
    let n = 128;
    let x = Matrix::from_fn(n, 1, |i, _| {
        -std::f32::consts::PI + 2.0 * std::f32::consts::PI * i as f32 / (n - 1) as f32
    });
    let y = x.map(libm::sinf);
    let mut last = f32::NAN;
    for _ in 0..steps {
        let (pred, cache) = net.forward_cached(&x);
        let (loss, dy) = mse(&pred, &y);
        let (_, grads) = net.backward(&cache, &dy);
        let grads = flatten_grads(&grads)
            .into_iter()
            .map(<[f32]>::to_vec)
            .collect::<Vec<_>>();
        let grad_refs: Vec<&[f32]> = grads.iter().map(Vec::as_slice).collect();
        opt.update(&mut net.params_mut(), &grad_refs);
        last = loss;
    }
    (last, postcard::to_stdvec(&net).expect("encode"))
}

#[test]
fn a_small_regression_reaches_a_known_loss() {
    let (loss, _) = fit_sine(1500, 0);
    // sin on [-π, π] has variance 0.5; a fitted 2×32 tanh MLP gets below 1e-3.
    assert!(loss < 1e-3, "final MSE {loss}");
}

#[test]
fn training_is_bit_exact_across_reruns_and_thread_counts() {
    let run = |threads: usize, seed: u64| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        pool.install(|| blake3::hash(&fit_sine(200, seed).1))
    };
    let a = run(1, 3);
    assert_eq!(a, run(1, 3), "rerun");
    assert_eq!(a, run(2, 3), "1 vs 2 threads");
    assert_ne!(a, run(1, 4), "another seed");
}

#[test]
fn weights_round_trip_through_the_artifact_codec() {
    // The store keeps these bytes as they are (osms-store's tests); what matters here is that
    // the encoding loses nothing of a network.
    let net = Mlp::new(
        &[8, 16, 4],
        Activation::Silu,
        Activation::Identity,
        5,
        "store",
    )
    .expect("a valid MLP");
    let bytes = osms_core::encode(&net).expect("encode");
    let back: Mlp = osms_core::decode(&bytes).expect("decode");
    assert_eq!(back, net);
    let x = random(3, 8, 9);
    assert_eq!(back.forward(&x), net.forward(&x));
}

#[test]
fn adam_bias_correction_matches_its_closed_form_on_the_first_step() {
    // After one step from zero moments, m̂ = g and v̂ = g², so the step is lr·g/(|g| + eps).
    let mut p = vec![1.0f32, -2.0, 0.5];
    let g = vec![0.3f32, -4.0, 0.0];
    let mut opt = Adam::new(AdamConfig::default(), Schedule::Constant { lr: 0.1 });
    opt.update(&mut [p.as_mut_slice()], &[g.as_slice()]);
    let expected: Vec<f32> = [1.0f32, -2.0, 0.5]
        .iter()
        .zip(&g)
        .map(|(p, g)| p - 0.1 * g / (g.abs() + 1e-8))
        .collect();
    for (a, b) in p.iter().zip(&expected) {
        assert!((a - b).abs() < 1e-6, "{p:?} vs {expected:?}");
    }
}

#[test]
fn inference_and_training_forward_passes_agree_bit_for_bit() {
    // Batch 1 takes the row-by-row kernel, batch 9 the packed one with a ragged row group.
    for act in [
        Activation::Silu,
        Activation::Tanh,
        Activation::Elu,
        Activation::Relu,
        Activation::Identity,
    ] {
        let net = Mlp::new(&[5, 19, 7], act, act, 4, "agree").expect("a valid MLP");
        for batch in [1, 2, 9] {
            let x = random(batch, 5, 8);
            let bits = |m: &Matrix| m.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(&net.forward(&x)),
                bits(&net.forward_cached(&x).0),
                "{act:?}, batch {batch}"
            );
            let row = net.forward(&Matrix::from_vec(1, 5, x.row(0).to_vec()));
            assert_eq!(
                bits(&row),
                bits(&net.forward(&x))[..7],
                "{act:?}, row 0 of {batch}"
            );
        }
    }
}

#[test]
fn parameter_gradients_alone_equal_the_full_backward_pass() {
    let net = Mlp::new(
        &[6, 12, 12, 3],
        Activation::Silu,
        Activation::Tanh,
        9,
        "param-grads",
    )
    .expect("a valid MLP");
    let x = random(10, 6, 11);
    let (y, cache) = net.forward_cached(&x);
    let (_, dy) = mse(&y, &random(10, 3, 12));
    let (_, full) = net.backward(&cache, &dy);
    assert_eq!(net.param_gradients(&cache, &dy), full);
}
