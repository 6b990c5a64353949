//! Candidate generation on one thread: geodesic candidate sets per second, the share of their
//! time spent in osms-nn (decoder passes), and the geodesic solver against the plain RK4 on
//! finite-difference Christoffel symbols, measured in the same run (best of 3). The manifold
//! has the production shape (latent 8, ω̄ of the small profile's length, hidden [128, 128]),
//! trained briefly on synthetic snippets: timing does not depend on how good it is. Prints
//! figures; asserts nothing about time.

use std::cell::Cell;
use std::time::{Duration, Instant};

use osms_core::rng;
use osms_method::candidates::{DecoderChart, Generator, SearchParams, candidate_set};
use osms_method::cvae::{ManifoldParams, Window, train};
use osms_method::geodesic::{Chart, PullbackMetric, ShootSpec, shoot, shoot_fd};
use osms_method::project::project;
use osms_method::sobol;
use osms_policy::osw::OMEGA_BAR_LEN;

const SETS: usize = 40;

/// A chart that clocks the decoder passes it makes.
struct Timed<'a> {
    inner: DecoderChart<'a>,
    spent: &'a Cell<Duration>,
}
impl Chart for Timed<'_> {
    fn dim(&self) -> usize {
        self.inner.dim()
    }
    fn jacobian(&self, z: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let t = Instant::now();
        let out = self.inner.jacobian(z);
        self.spent.set(self.spent.get() + t.elapsed());
        out
    }
    fn curvature(&self, z: &[f64], v: &[f64]) -> Vec<f64> {
        let t = Instant::now();
        let out = self.inner.curvature(z, v);
        self.spent.set(self.spent.get() + t.elapsed());
        out
    }
    fn jacobian_and_curvature(&self, z: &[f64], v: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let t = Instant::now();
        let out = self.inner.jacobian_and_curvature(z, v);
        self.spent.set(self.spent.get() + t.elapsed());
        out
    }
    fn decode(&self, z: &[f64]) -> Vec<f64> {
        let t = Instant::now();
        let out = self.inner.decode(z);
        self.spent.set(self.spent.get() + t.elapsed());
        out
    }
}

fn best(f: impl Fn() -> Duration) -> f64 {
    (0..3)
        .map(|_| f().as_secs_f64())
        .fold(f64::INFINITY, f64::min)
}

fn main() {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    pool.install(run);
}

fn run() {
    let mut r = rng::stream(0, "bench", "data", 0);
    let n = 400;
    let zetas: Vec<Vec<f32>> = (0..n)
        .map(|_| {
            let u: Vec<f64> = (0..4).map(|_| rng::uniform(&mut r, -1.0, 1.0)).collect();
            (0..56)
                .map(|j| {
                    let (t, c) = ((j / 7) as f64 / 7.0, (j % 7) as f64);
                    (0.5 * u[0] * (1.0 - t) + 0.3 * u[1] * t * (0.5 * c).cos() + 0.2 * u[2] * u[3])
                        .tanh() as f32
                })
                .collect()
        })
        .collect();
    let omegas: Vec<Vec<f32>> = (0..n)
        .map(|_| {
            (0..OMEGA_BAR_LEN)
                .map(|_| rng::normal(&mut r) as f32)
                .collect()
        })
        .collect();
    let windows: Vec<Window<'_>> = zetas
        .iter()
        .zip(&omegas)
        .map(|(zeta, omega_bar)| Window { zeta, omega_bar })
        .collect();
    let params = ManifoldParams {
        epochs: 5,
        ..ManifoldParams::default()
    };
    let t = Instant::now();
    let model = train(&windows, 8, 7, &params, (0, "bench"), &|| {}).expect("train");
    let train_secs = t.elapsed().as_secs_f64();
    println!(
        "manifold: {} windows × {} epochs in {train_secs:.2} s ({:.1} ms per epoch; the small profile's 900 windows × {} epochs scale from this)",
        n,
        params.epochs,
        1e3 * train_secs / f64::from(params.epochs),
        ManifoldParams::default().epochs
    );

    let p = SearchParams::default();
    let total = best(|| {
        let t = Instant::now();
        for i in 0..SETS {
            let mut s = rng::stream(0, "bench", "projection", i as u64);
            candidate_set(&model, &zetas[i], &omegas[i], None, &p, &mut s).expect("set");
        }
        t.elapsed()
    });
    let per_set = total / SETS as f64;
    println!(
        "geodesic candidate sets (|η| = {}): {:.1} per second, {:.1} ms each",
        2 * p.directions + 1,
        1.0 / per_set,
        1e3 * per_set
    );

    // The parts: projection (its time is decoder passes and Adam's few flops) and the
    // geodesics with their decoder passes clocked.
    let spent = Cell::new(Duration::ZERO);
    let mut proj_secs = 0.0;
    let mut geo_secs = 0.0;
    let mut fd_secs = 0.0;
    let mut drift_fd: f64 = 0.0;
    let metric = PullbackMetric {
        weights: model.w_a.iter().map(|w| f64::from(*w)).collect(),
        lambda_reg: p.lambda_reg,
    };
    let spec = ShootSpec { steps: p.rk4_steps };
    for i in 0..SETS {
        let omega_n = model.normalise(&omegas[i]);
        let t = Instant::now();
        let proj = project(
            &model,
            &zetas[i],
            &omega_n,
            p.bound,
            &p.projection,
            &mut rng::stream(0, "bench", "projection", i as u64),
        );
        proj_secs += t.elapsed().as_secs_f64();
        let chart = Timed {
            inner: DecoderChart {
                model: &model,
                omega_n: &omega_n,
            },
            spent: &spent,
        };
        let z0: Vec<f64> = proj.z0.iter().map(|v| f64::from(*v)).collect();
        let m0 = metric.metric(&chart, &z0);
        let raw = sobol::directions(8, p.sobol_first, p.directions).expect("sobol");
        let xi = metric.orthonormalise(&m0, &raw).expect("independent");
        let t = Instant::now();
        let mut ends = Vec::new();
        for x in &xi {
            for sign in [1.0, -1.0] {
                let v0: Vec<f64> = x.iter().map(|c| sign * p.radius * c).collect();
                ends.push(shoot(&metric, &chart, &z0, &v0, &spec, None).end);
            }
        }
        geo_secs += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let mut k = 0;
        for x in &xi {
            for sign in [1.0, -1.0] {
                let v0: Vec<f64> = x.iter().map(|c| sign * p.radius * c).collect();
                let g = shoot_fd(&metric, &chart.inner, &z0, &v0, &spec, 1e-3);
                let d: f64 = g
                    .end
                    .iter()
                    .zip(&ends[k])
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum::<f64>()
                    .sqrt();
                drift_fd = drift_fd.max(d);
                k += 1;
            }
        }
        fd_secs += t.elapsed().as_secs_f64();
    }
    let nn_geo = spent.get().as_secs_f64();
    println!(
        "per set: projection {:.1} ms (decoder passes and Adam), {} geodesics {:.1} ms of which decoder passes (osms-nn jets) {:.1} ms = {:.0} %",
        1e3 * proj_secs / SETS as f64,
        2 * p.directions,
        1e3 * geo_secs / SETS as f64,
        1e3 * nn_geo / SETS as f64,
        100.0 * nn_geo / geo_secs
    );
    println!(
        "geodesic solver (exact acceleration from forward-mode curvature) vs RK4 on finite-difference Christoffel symbols (h = 1e-3), same {} steps: {:.1} ms vs {:.1} ms per set, ratio {:.2}× faster; largest endpoint difference {:.2e}",
        p.rk4_steps,
        1e3 * geo_secs / SETS as f64,
        1e3 * fd_secs / SETS as f64,
        fd_secs / geo_secs,
        drift_fd
    );
    let reference: Vec<_> = (0..SETS)
        .map(|i| {
            let mut s = rng::stream(0, "bench", "projection", i as u64);
            candidate_set(&model, &zetas[i], &omegas[i], None, &p, &mut s).expect("set")
        })
        .collect();
    for g in [Generator::Euclidean, Generator::Direct] {
        let q = SearchParams {
            generator: g,
            ..SearchParams::default()
        };
        let secs = best(|| {
            let t = Instant::now();
            for i in 0..SETS {
                let mut s = rng::stream(0, "bench", "projection", i as u64);
                candidate_set(
                    &model,
                    &zetas[i],
                    &omegas[i],
                    Some(&reference[i]),
                    &q,
                    &mut s,
                )
                .expect("set");
            }
            t.elapsed()
        });
        println!(
            "{} sets matched to the geodesic sets: {:.1} ms each",
            g.name(),
            1e3 * secs / SETS as f64
        );
    }
}
