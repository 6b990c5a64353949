//! One Adam training step of the MLP (batch 256, input 64, 3 × 256 SiLU, output 24),
//! single-threaded, and batch-1 inference latency; the matrix kernel against the scalar
//! reference in the same run. Prints figures; asserts nothing about time.

use std::time::{Duration, Instant};

use osms_make::rng;
use osms_nn::kernels::{matmul, matmul_reference};
use osms_nn::{Activation, Adam, AdamConfig, Matrix, Mlp, Schedule, flatten_grads, mse};

fn best(runs: usize, mut f: impl FnMut()) -> Duration {
    (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed()
        })
        .min()
        .unwrap_or_default()
}

fn random(rows: usize, cols: usize, seed: u64) -> Matrix {
    let mut r = rng::stream(seed, "bench", "data", 0);
    Matrix::from_fn(rows, cols, |_, _| rng::uniform(&mut r, -1.0, 1.0) as f32)
}

fn main() {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    pool.install(|| {
        let mut net = Mlp::new(&[64, 256, 256, 256, 24], Activation::Silu, Activation::Identity, 0, "bench");
        let mut opt = Adam::new(AdamConfig::default(), Schedule::Constant { lr: 1e-3 });
        let x = random(256, 64, 1);
        let y = random(256, 24, 2);
        let mut step = || {
            let (pred, cache) = net.forward_cached(&x);
            let (_, dy) = mse(&pred, &y);
            let (_, grads) = net.backward(&cache, &dy);
            let owned: Vec<Vec<f32>> = flatten_grads(&grads).into_iter().map(<[f32]>::to_vec).collect();
            let refs: Vec<&[f32]> = owned.iter().map(Vec::as_slice).collect();
            opt.update(&mut net.params_mut(), &refs);
        };
        step();
        let t_step = best(10, &mut step);
        let flops = 3.0 * 2.0 * 256.0 * (64.0 * 256.0 + 2.0 * 256.0 * 256.0 + 256.0 * 24.0);
        println!("MLP 64-256-256-256-24 SiLU, batch 256, Adam, one thread");
        println!("  training step        {:8.2} ms   ({:.1} GFLOP/s in the matrix products)", t_step.as_secs_f64() * 1e3, flops / t_step.as_secs_f64() / 1e9);

        let one = random(1, 64, 3);
        let t_infer = best(200, || {
            std::hint::black_box(net.forward(&one));
        });
        println!("  batch-1 inference    {:8.1} us   (a 50 Hz policy has 20,000 us per step)", t_infer.as_secs_f64() * 1e6);

        let a = random(256, 256, 4);
        let b = random(256, 256, 5);
        let t_tiled = best(10, || {
            std::hint::black_box(matmul(&a, &b));
        });
        let t_ref = best(3, || {
            std::hint::black_box(matmul_reference(&a, &b));
        });
        let g = 2.0 * 256f64.powi(3) / 1e9;
        println!("256 x 256 x 256 matrix product, one thread");
        println!("  tiled kernel         {:8.2} ms   {:6.1} GFLOP/s", t_tiled.as_secs_f64() * 1e3, g / t_tiled.as_secs_f64());
        println!("  scalar reference     {:8.2} ms   {:6.1} GFLOP/s   (ratio tiled/reference time {:.3})", t_ref.as_secs_f64() * 1e3, g / t_ref.as_secs_f64(), t_tiled.as_secs_f64() / t_ref.as_secs_f64());
    });
}
