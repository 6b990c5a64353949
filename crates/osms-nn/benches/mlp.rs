//! One Adam training step of the MLP (batch 256, input 64, 3 × 256 SiLU, output 24),
//! single-threaded, and batch-1 inference latency; the matrix kernel against the scalar
//! reference in the same run. With `OSMS_BENCH_TORCH_PYTHON` set (as `scripts/bench-nn` does),
//! PyTorch runs the same shapes right after and the ratios are printed. Asserts nothing about
//! time.

use std::collections::BTreeMap;
use std::process::Command;
use std::time::{Duration, Instant};

use osms_core::rng;
use osms_nn::kernels::{Level, matmul, matmul_reference};
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

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// PyTorch's figures from `torch_mlp.py`, or why there are none.
fn torch() -> Result<BTreeMap<String, String>, String> {
    let python = std::env::var("OSMS_BENCH_TORCH_PYTHON")
        .map_err(|_| "not measured: run scripts/bench-nn to compare with PyTorch".to_string())?;
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/benches/torch_mlp.py");
    let out = Command::new(&python)
        .arg(script)
        .output()
        .map_err(|e| format!("could not run {python}: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "{script} failed: {}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    Ok(String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_once(' '))
        .map(|(k, v)| (k.to_string(), v.trim().to_string()))
        .collect())
}

fn main() {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let (t_step, t_infer, t_tiled, t_ref) = pool.install(|| {
        let sizes = [64, 256, 256, 256, 24];
        let mut net = Mlp::new(&sizes, Activation::Silu, Activation::Identity, 0, "bench")
            .expect("a valid MLP");
        let mut opt = Adam::new(AdamConfig::default(), Schedule::Constant { lr: 1e-3 });
        let x = random(256, 64, 1);
        let y = random(256, 24, 2);
        let mut step = || {
            let (pred, cache) = net.forward_cached(&x);
            let (_, dy) = mse(&pred, &y);
            let grads = net.param_gradients(&cache, &dy);
            opt.update(&mut net.params_mut(), &flatten_grads(&grads));
        };
        step();
        let t_step = best(30, &mut step);
        let one = random(1, 64, 3);
        let t_infer = best(1000, || {
            std::hint::black_box(net.forward(&one));
        });
        let a = random(256, 256, 4);
        let b = random(256, 256, 5);
        let t_tiled = best(30, || {
            std::hint::black_box(matmul(&a, &b));
        });
        let t_ref = best(3, || {
            std::hint::black_box(matmul_reference(&a, &b));
        });
        (t_step, t_infer, t_tiled, t_ref)
    });

    // Forward F multiply-adds; backward F for the weights and F − 256·64·256 for the layer
    // inputs (the network's own input needs no gradient).
    let forward = 256.0 * (64.0 * 256.0 + 2.0 * 256.0 * 256.0 + 256.0 * 24.0);
    let step_flops = 2.0 * (3.0 * forward - 256.0 * 64.0 * 256.0);
    let mm_flops = 2.0 * 256f64.powi(3);
    println!("osms-nn, one thread, {:?} kernels", Level::detected());
    println!(
        "  MLP 64-256-256-256-24 SiLU, batch 256, Adam: training step {:7.2} ms  ({:.1} GFLOP/s in the products)",
        ms(t_step),
        step_flops / t_step.as_secs_f64() / 1e9
    );
    println!(
        "  same MLP, batch-1 inference                 {:7.1} us  (a 50 Hz policy has 20,000 us per step)",
        t_infer.as_secs_f64() * 1e6
    );
    println!(
        "  256 x 256 x 256 product: tiled {:.3} ms ({:.1} GFLOP/s), scalar reference {:.2} ms, ratio tiled/reference {:.3}",
        ms(t_tiled),
        mm_flops / t_tiled.as_secs_f64() / 1e9,
        ms(t_ref),
        t_tiled.as_secs_f64() / t_ref.as_secs_f64()
    );

    match torch() {
        Err(why) => println!("PyTorch: {why}"),
        Ok(figures) => {
            let get = |k: &str| figures.get(k).and_then(|v| v.parse::<f64>().ok());
            let version = figures.get("torch_version").map_or("?", String::as_str);
            println!(
                "PyTorch {version}, one thread, same shapes, same run (ratio = osms time / PyTorch time)"
            );
            if let Some(t) = get("train_step_ms") {
                println!(
                    "  training step      {t:7.2} ms   ratio {:.2}",
                    ms(t_step) / t
                );
            }
            if let Some(t) = get("infer_us") {
                println!(
                    "  batch-1 inference  {t:7.1} us   ratio {:.2}",
                    t_infer.as_secs_f64() * 1e6 / t
                );
            }
            if let Some(t) = get("matmul_256_ms") {
                println!(
                    "  256^3 product      {t:7.3} ms   ratio {:.2}  ({:.1} GFLOP/s; PyTorch may fuse multiply and add, osms may not)",
                    ms(t_tiled) / t,
                    mm_flops / t / 1e6
                );
            }
        }
    }
}
