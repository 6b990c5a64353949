//! Riemannian geometry of the decoder's pullback metric (paper Eq. 4) and geodesic shooting
//! under it (Eq. 5), in f64 and generic over a smooth [`Chart`] z ↦ ζ (the conditional decoder
//! G(·, ω̄) with ω̄ fixed).
//!
//! Determinism: every result is plain f64 arithmetic in a fixed loop order (no `mul_add`, no
//! parallelism, no external linear algebra), so the same inputs give the same bits on every
//! machine. The only non-elementary operation here is `sqrt`, which IEEE 754 requires to be
//! correctly rounded, so `f64::sqrt` is as reproducible as `+` and `*`.

use serde::{Deserialize, Serialize};

use crate::linalg::solve_spd;

/// A smooth map z ↦ ζ with the derivatives the geodesic equation needs.
pub trait Chart {
    /// Latent dimension d.
    fn dim(&self) -> usize;
    /// G(z) (n values) and J_G(z), row-major n × d (J[i*d + k] = ∂G_i/∂z_k).
    fn jacobian(&self, z: &[f64]) -> (Vec<f64>, Vec<f64>);
    /// ∂²G(z)[v, v] (n values): the second derivative of t ↦ G(z + t v) at t = 0.
    fn curvature(&self, z: &[f64], v: &[f64]) -> Vec<f64>;
    /// G(z) alone (default: from `jacobian`).
    fn decode(&self, z: &[f64]) -> Vec<f64> {
        self.jacobian(z).0
    }
    /// J_G(z) and ∂²G(z)[v, v] together, what every step of the geodesic ODE needs (default:
    /// the two calls; a chart that gets both from one pass overrides it).
    fn jacobian_and_curvature(&self, z: &[f64], v: &[f64]) -> (Vec<f64>, Vec<f64>) {
        (self.jacobian(z).1, self.curvature(z, v))
    }
}

/// Relative size below which [`PullbackMetric::orthonormalise`] calls a direction dependent:
/// what is left of it after removing its components along the earlier directions, measured in
/// ‖·‖_M, over its own ‖·‖_M. Exactly dependent input leaves a residual of a few ulps times the
/// conditioning, far below this; genuinely independent Sobol directions stay far above it.
pub const DEPENDENCE_TOL: f64 = 1e-10;

/// The pullback metric's constants: W's diagonal and λ_reg.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PullbackMetric {
    /// The positive diagonal of W (n values; W_a of Eq. 4).
    pub weights: Vec<f64>,
    /// λ_reg of Eq. 4 (> 0 in production; 0 is allowed where J_G has full column rank).
    pub lambda_reg: f64,
}

impl PullbackMetric {
    /// M(z) = J_Gᵀ W J_G + λ_reg I (Eq. 4), row-major d × d, symmetric by construction.
    ///
    /// # Panics
    /// If the chart's Jacobian is not `weights.len()` × `chart.dim()`.
    pub fn metric(&self, chart: &dyn Chart, z: &[f64]) -> Vec<f64> {
        let d = chart.dim();
        let (_, jac) = chart.jacobian(z);
        self.metric_from_jacobian(d, &jac)
    }

    /// Geodesic acceleration γ̈ = −M⁻¹ J_Gᵀ W ∂²G[γ̇, γ̇] at (z, v), the right-hand side of the
    /// geodesic ODE behind Eq. 5.
    ///
    /// Exact for a pullback metric: M is the first fundamental form of the embedding
    /// z ↦ (W^{1/2} G(z), √λ_reg z), whose second part has no curvature, and a geodesic's
    /// acceleration in the embedding space is normal to the tangent space, i.e.
    /// J_Fᵀ(J_F γ̈ + ∂²F[γ̇, γ̇]) = 0. Solved with a Cholesky factorisation of M.
    ///
    /// If M is not numerically positive definite (λ_reg = 0 with a rank-deficient J_G) every
    /// component is NaN, so the failure cannot pass for a finite answer.
    ///
    /// # Panics
    /// If `z` or `v` is not `chart.dim()` long or the chart's outputs are not `weights.len()`
    /// long.
    pub fn acceleration(&self, chart: &dyn Chart, z: &[f64], v: &[f64]) -> Vec<f64> {
        self.acceleration_and_metric(chart, z, v).0
    }

    /// The same acceleration as [`Self::acceleration`] from Christoffel symbols of
    /// finite-difference derivatives of M: central differences with step `h` in each latent
    /// direction (2d metric evaluations, plus M(z) itself for the solve), contracted as
    /// a = −M⁻¹[(Σ_k v_k ∂_k M) v − ½ (vᵀ ∂_i M v)_i].
    ///
    /// This is the benchmark's baseline and an independent check of the exact form; its error
    /// is O(h²) truncation plus O(ε/h) rounding.
    ///
    /// # Panics
    /// As [`Self::acceleration`].
    pub fn acceleration_fd(&self, chart: &dyn Chart, z: &[f64], v: &[f64], h: f64) -> Vec<f64> {
        self.acceleration_fd_and_metric(chart, z, v, h).0
    }

    /// Orthonormalises `dirs` under M (modified Gram–Schmidt with the M inner product, in the
    /// given order); fails (None) if a direction is (numerically) dependent on the earlier ones
    /// (see [`DEPENDENCE_TOL`]), is zero or is not finite. Each direction is swept twice
    /// against the earlier ones ("twice is enough"), so ξ_iᵀ M ξ_j = δ_ij holds to rounding
    /// even for poorly conditioned M; the second sweep does not change the spanned flags.
    ///
    /// # Panics
    /// If `m` is not d × d for the directions' length d, or the directions differ in length.
    pub fn orthonormalise(&self, m: &[f64], dirs: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
        let Some(first) = dirs.first() else {
            return Some(Vec::new());
        };
        let d = first.len();
        assert_eq!(m.len(), d * d, "orthonormalise: M is not {d} × {d}");
        let mut basis: Vec<Vec<f64>> = Vec::with_capacity(dirs.len());
        for dir in dirs {
            assert_eq!(dir.len(), d, "orthonormalise: directions differ in length");
            let size = quad_form(m, dir);
            if !size.is_finite() || size <= 0.0 {
                return None;
            }
            let mut u = dir.clone();
            for _sweep in 0..2 {
                for e in &basis {
                    let c = bilinear(m, &u, e);
                    for (ui, ei) in u.iter_mut().zip(e) {
                        *ui -= c * ei;
                    }
                }
            }
            let rest = quad_form(m, &u);
            // Compared squared on both sides so no sqrt is needed for the test.
            if !rest.is_finite() || rest <= DEPENDENCE_TOL * DEPENDENCE_TOL * size {
                return None;
            }
            let inv = 1.0 / rest.sqrt();
            for ui in &mut u {
                *ui *= inv;
            }
            basis.push(u);
        }
        Some(basis)
    }

    /// ‖v‖_M = √(vᵀ M v) at a given M (row-major d × d).
    ///
    /// # Panics
    /// If `m` is not `v.len()` × `v.len()`.
    pub fn norm(&self, m: &[f64], v: &[f64]) -> f64 {
        assert_eq!(m.len(), v.len() * v.len(), "norm: M does not match v");
        quad_form(m, v).sqrt()
    }

    fn metric_from_jacobian(&self, d: usize, jac: &[f64]) -> Vec<f64> {
        let n = self.weights.len();
        assert_eq!(
            jac.len(),
            n * d,
            "pullback metric: Jacobian has {} entries, expected {n} × {d}",
            jac.len()
        );
        let mut m = vec![0.0; d * d];
        for a in 0..d {
            // Each off-diagonal entry is summed once and mirrored, so M is symmetric bit for
            // bit (summing both triangles would round them differently).
            for b in 0..=a {
                let mut s = 0.0;
                for i in 0..n {
                    s += jac[i * d + a] * self.weights[i] * jac[i * d + b];
                }
                m[a * d + b] = s;
                m[b * d + a] = s;
            }
            m[a * d + a] += self.lambda_reg;
        }
        m
    }

    /// The exact acceleration and M(z), which the integrator reuses for the speed at a node.
    fn acceleration_and_metric(
        &self,
        chart: &dyn Chart,
        z: &[f64],
        v: &[f64],
    ) -> (Vec<f64>, Vec<f64>) {
        let d = chart.dim();
        let n = self.weights.len();
        assert_eq!(z.len(), d, "acceleration: z has the wrong dimension");
        assert_eq!(v.len(), d, "acceleration: v has the wrong dimension");
        let (jac, curv) = chart.jacobian_and_curvature(z, v);
        let m = self.metric_from_jacobian(d, &jac);
        assert_eq!(
            curv.len(),
            n,
            "acceleration: curvature has the wrong length"
        );
        let mut rhs = vec![0.0; d];
        for (k, r) in rhs.iter_mut().enumerate() {
            let mut s = 0.0;
            for i in 0..n {
                s += jac[i * d + k] * (self.weights[i] * curv[i]);
            }
            *r = -s;
        }
        (solve_spd(&m, d, &rhs), m)
    }

    fn acceleration_fd_and_metric(
        &self,
        chart: &dyn Chart,
        z: &[f64],
        v: &[f64],
        h: f64,
    ) -> (Vec<f64>, Vec<f64>) {
        let d = chart.dim();
        assert_eq!(z.len(), d, "acceleration_fd: z has the wrong dimension");
        assert_eq!(v.len(), d, "acceleration_fd: v has the wrong dimension");
        let m = self.metric(chart, z);
        // dm[k] = ∂_k M, row-major d × d each.
        let mut dm: Vec<Vec<f64>> = Vec::with_capacity(d);
        let mut zs = z.to_vec();
        for k in 0..d {
            let plus = z[k] + h;
            let minus = z[k] - h;
            zs[k] = plus;
            let mp = self.metric(chart, &zs);
            zs[k] = minus;
            let mm = self.metric(chart, &zs);
            zs[k] = z[k];
            // The step actually taken, not 2h: z ± h rounds, and dividing by the represented
            // difference removes that error from the quotient.
            let step = plus - minus;
            dm.push(mp.iter().zip(&mm).map(|(p, q)| (p - q) / step).collect());
        }
        let mut rhs = vec![0.0; d];
        for (i, r) in rhs.iter_mut().enumerate() {
            // (Σ_k v_k ∂_k M) v, component i.
            let mut first = 0.0;
            for (k, dmk) in dm.iter().enumerate() {
                let mut row = 0.0;
                for j in 0..d {
                    row += dmk[i * d + j] * v[j];
                }
                first += v[k] * row;
            }
            // ½ vᵀ ∂_i M v.
            let second = quad_form(&dm[i], v);
            *r = -(first - 0.5 * second);
        }
        (solve_spd(&m, d, &rhs), m)
    }
}

/// How a geodesic is integrated.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShootSpec {
    /// RK4 steps over t ∈ [0, 1].
    pub steps: usize,
}

/// One integrated geodesic.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Geodesic {
    /// γ(1) (or, after an early stop at the box, the first node outside it).
    pub end: Vec<f64>,
    /// Length ∫₀¹ √(γ̇ᵀ M γ̇) dt over the integrated nodes: composite Simpson when the number
    /// of integrated steps is even, the trapezoid rule when it is odd. After an early stop it
    /// covers [0, t_stop] only.
    pub length: f64,
    /// Largest relative change of the speed γ̇ᵀMγ̇ along the solution (energy drift), for
    /// diagnostics: max_n |E_n − E_0| / E_0 over the nodes (absolute when E_0 = 0).
    pub energy_drift: f64,
    /// Whether every RK4 node stayed inside the box (if one was given).
    pub inside: bool,
}

/// Integrates the geodesic ODE (behind paper Eq. 5) from γ(0) = z0, γ̇(0) = v0 over
/// t ∈ [0, 1] with classical RK4 on the state (z, γ̇) and [`PullbackMetric::acceleration`].
///
/// `bounds` = Some((lo, hi)) checks every node (including z0) against the box [lo, hi]^d (the
/// latent region Z = [−3, 3]^8) and stops early (inside = false) at the first node outside; a
/// non-finite node (e.g. from a singular M) counts as outside.
///
/// # Panics
/// If `spec.steps` is 0 or the dimensions disagree.
pub fn shoot(
    metric: &PullbackMetric,
    chart: &dyn Chart,
    z0: &[f64],
    v0: &[f64],
    spec: &ShootSpec,
    bounds: Option<(f64, f64)>,
) -> Geodesic {
    integrate(
        z0,
        v0,
        spec.steps,
        bounds,
        |z, v| metric.acceleration_and_metric(chart, z, v),
        |z| metric.metric(chart, z),
    )
}

/// The same RK4 as [`shoot`] with [`PullbackMetric::acceleration_fd`] at step `h` (the
/// benchmark's baseline); no box check, so `inside` is always true.
///
/// # Panics
/// As [`shoot`].
pub fn shoot_fd(
    metric: &PullbackMetric,
    chart: &dyn Chart,
    z0: &[f64],
    v0: &[f64],
    spec: &ShootSpec,
    h: f64,
) -> Geodesic {
    integrate(
        z0,
        v0,
        spec.steps,
        None,
        |z, v| metric.acceleration_fd_and_metric(chart, z, v, h),
        |z| metric.metric(chart, z),
    )
}

/// Classical RK4 on (z, γ̇). `accel` returns the acceleration and M at its point; the M of
/// each step's first stage is the node's metric, so the speed costs one extra metric
/// evaluation (at the last node) per geodesic.
fn integrate<A, M>(
    z0: &[f64],
    v0: &[f64],
    steps: usize,
    bounds: Option<(f64, f64)>,
    mut accel: A,
    mut metric_at: M,
) -> Geodesic
where
    A: FnMut(&[f64], &[f64]) -> (Vec<f64>, Vec<f64>),
    M: FnMut(&[f64]) -> Vec<f64>,
{
    assert!(steps > 0, "shoot: ShootSpec::steps must be at least 1");
    let d = z0.len();
    assert_eq!(v0.len(), d, "shoot: z0 and v0 differ in dimension");
    let in_box = |z: &[f64]| match bounds {
        None => true,
        // Written as lo <= x <= hi so that NaN is outside.
        Some((lo, hi)) => z.iter().all(|&x| lo <= x && x <= hi),
    };
    if !in_box(z0) {
        return Geodesic {
            end: z0.to_vec(),
            length: 0.0,
            energy_drift: 0.0,
            inside: false,
        };
    }

    let dt = 1.0 / steps as f64;
    let half = 0.5 * dt;
    let sixth = dt / 6.0;
    let mut z = z0.to_vec();
    let mut v = v0.to_vec();
    let mut energies = Vec::with_capacity(steps + 1);
    let mut inside = true;
    let mut zs = vec![0.0; d];
    let mut vs = vec![0.0; d];
    for _ in 0..steps {
        let (a1, m) = accel(&z, &v);
        energies.push(quad_form(&m, &v));

        for i in 0..d {
            zs[i] = z[i] + half * v[i];
            vs[i] = v[i] + half * a1[i];
        }
        let v2 = vs.clone();
        let (a2, _) = accel(&zs, &vs);

        for i in 0..d {
            zs[i] = z[i] + half * v2[i];
            vs[i] = v[i] + half * a2[i];
        }
        let v3 = vs.clone();
        let (a3, _) = accel(&zs, &vs);

        for i in 0..d {
            zs[i] = z[i] + dt * v3[i];
            vs[i] = v[i] + dt * a3[i];
        }
        let (a4, _) = accel(&zs, &vs);

        for i in 0..d {
            z[i] += sixth * (v[i] + 2.0 * v2[i] + 2.0 * v3[i] + vs[i]);
            v[i] += sixth * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i]);
        }
        if !in_box(&z) {
            inside = false;
            break;
        }
    }
    let m_end = metric_at(&z);
    energies.push(quad_form(&m_end, &v));

    let intervals = energies.len() - 1;
    let length = if intervals % 2 == 0 {
        let mut s = 0.0;
        for (n, e) in energies.iter().enumerate() {
            let w = if n == 0 || n == intervals {
                1.0
            } else if n % 2 == 1 {
                4.0
            } else {
                2.0
            };
            s += w * e.sqrt();
        }
        s * (dt / 3.0)
    } else {
        let mut s = 0.0;
        for (n, e) in energies.iter().enumerate() {
            let w = if n == 0 || n == intervals { 0.5 } else { 1.0 };
            s += w * e.sqrt();
        }
        s * dt
    };

    let e0 = energies[0];
    let mut energy_drift: f64 = 0.0;
    for e in &energies {
        let change = if e0 > 0.0 {
            (e - e0).abs() / e0
        } else {
            (e - e0).abs()
        };
        // Not f64::max, which would drop a NaN drift.
        if change > energy_drift || change.is_nan() {
            energy_drift = change;
        }
    }

    Geodesic {
        end: z,
        length,
        energy_drift,
        inside,
    }
}

/// vᵀ M v, summed row by row.
fn quad_form(m: &[f64], v: &[f64]) -> f64 {
    bilinear(m, v, v)
}

/// aᵀ M b, summed row by row.
fn bilinear(m: &[f64], a: &[f64], b: &[f64]) -> f64 {
    let d = a.len();
    let mut s = 0.0;
    for i in 0..d {
        let mut row = 0.0;
        for j in 0..d {
            row += m[i * d + j] * b[j];
        }
        s += a[i] * row;
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SplitMix64: a test-only source of fixed "random" numbers.
    struct Mix(u64);

    impl Mix {
        fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut x = self.0;
            x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            x ^= x >> 31;
            let u = (x >> 11) as f64 / (1u64 << 53) as f64;
            lo + (hi - lo) * u
        }

        fn vec(&mut self, len: usize, lo: f64, hi: f64) -> Vec<f64> {
            (0..len).map(|_| self.uniform(lo, hi)).collect()
        }
    }

    /// G(z) = B z.
    struct Linear {
        b: Vec<f64>,
        n: usize,
        d: usize,
    }

    impl Chart for Linear {
        fn dim(&self) -> usize {
            self.d
        }
        fn jacobian(&self, z: &[f64]) -> (Vec<f64>, Vec<f64>) {
            let g = (0..self.n)
                .map(|i| (0..self.d).map(|k| self.b[i * self.d + k] * z[k]).sum())
                .collect();
            (g, self.b.clone())
        }
        fn curvature(&self, _z: &[f64], _v: &[f64]) -> Vec<f64> {
            vec![0.0; self.n]
        }
    }

    fn linear() -> Linear {
        #[rustfmt::skip]
        let b = vec![
            1.0, 0.5, -0.3,
            0.2, -1.1, 0.7,
            -0.4, 0.3, 0.9,
            0.8, 0.0, -0.6,
            0.1, 0.6, 0.25,
        ];
        Linear { b, n: 5, d: 3 }
    }

    /// The unit sphere in spherical coordinates (θ, φ) ↦ (sin θ cos φ, sin θ sin φ, cos θ).
    struct Sphere;

    impl Chart for Sphere {
        fn dim(&self) -> usize {
            2
        }
        fn jacobian(&self, z: &[f64]) -> (Vec<f64>, Vec<f64>) {
            let (st, ct) = (libm::sin(z[0]), libm::cos(z[0]));
            let (sp, cp) = (libm::sin(z[1]), libm::cos(z[1]));
            let g = vec![st * cp, st * sp, ct];
            #[rustfmt::skip]
            let j = vec![
                ct * cp, -st * sp,
                ct * sp, st * cp,
                -st, 0.0,
            ];
            (g, j)
        }
        fn curvature(&self, z: &[f64], v: &[f64]) -> Vec<f64> {
            let (st, ct) = (libm::sin(z[0]), libm::cos(z[0]));
            let (sp, cp) = (libm::sin(z[1]), libm::cos(z[1]));
            let (a, b) = (v[0], v[1]);
            // G_θθ a² + 2 G_θφ a b + G_φφ b².
            vec![
                -st * cp * a * a - 2.0 * ct * sp * a * b - st * cp * b * b,
                -st * sp * a * a + 2.0 * ct * cp * a * b - st * sp * b * b,
                -ct * a * a,
            ]
        }
    }

    /// A small two-layer tanh network ζ = tanh(C tanh(A z + b) + c), like the decoder's
    /// tanh output layer, with its derivatives by hand.
    struct TanhNet {
        a: Vec<f64>,
        b: Vec<f64>,
        c: Vec<f64>,
        c0: Vec<f64>,
        d: usize,
        h: usize,
        n: usize,
    }

    impl TanhNet {
        fn new(seed: u64) -> Self {
            let (d, h, n) = (3, 6, 5);
            let mut r = Mix(seed);
            TanhNet {
                a: r.vec(h * d, -1.2, 1.2),
                b: r.vec(h, -0.5, 0.5),
                c: r.vec(n * h, -1.0, 1.0),
                c0: r.vec(n, -0.3, 0.3),
                d,
                h,
                n,
            }
        }

        /// Hidden activations and outputs.
        fn forward(&self, z: &[f64]) -> (Vec<f64>, Vec<f64>) {
            let hid: Vec<f64> = (0..self.h)
                .map(|j| {
                    let u: f64 = (0..self.d).map(|k| self.a[j * self.d + k] * z[k]).sum();
                    libm::tanh(u + self.b[j])
                })
                .collect();
            let y = (0..self.n)
                .map(|i| {
                    let s: f64 = (0..self.h).map(|j| self.c[i * self.h + j] * hid[j]).sum();
                    libm::tanh(s + self.c0[i])
                })
                .collect();
            (hid, y)
        }
    }

    impl Chart for TanhNet {
        fn dim(&self) -> usize {
            self.d
        }
        fn jacobian(&self, z: &[f64]) -> (Vec<f64>, Vec<f64>) {
            let (hid, y) = self.forward(z);
            let mut j = vec![0.0; self.n * self.d];
            for i in 0..self.n {
                for k in 0..self.d {
                    let s: f64 = (0..self.h)
                        .map(|q| {
                            self.c[i * self.h + q]
                                * (1.0 - hid[q] * hid[q])
                                * self.a[q * self.d + k]
                        })
                        .sum();
                    j[i * self.d + k] = (1.0 - y[i] * y[i]) * s;
                }
            }
            (y, j)
        }
        fn curvature(&self, z: &[f64], v: &[f64]) -> Vec<f64> {
            let (hid, y) = self.forward(z);
            // u' = A v; h' = (1 − h²) u'; h'' = −2 h (1 − h²) u'².
            let mut h1 = vec![0.0; self.h];
            let mut h2 = vec![0.0; self.h];
            for q in 0..self.h {
                let du: f64 = (0..self.d).map(|k| self.a[q * self.d + k] * v[k]).sum();
                let s = 1.0 - hid[q] * hid[q];
                h1[q] = s * du;
                h2[q] = -2.0 * hid[q] * s * du * du;
            }
            (0..self.n)
                .map(|i| {
                    let s1: f64 = (0..self.h).map(|q| self.c[i * self.h + q] * h1[q]).sum();
                    let s2: f64 = (0..self.h).map(|q| self.c[i * self.h + q] * h2[q]).sum();
                    let sy = 1.0 - y[i] * y[i];
                    -2.0 * y[i] * sy * s1 * s1 + sy * s2
                })
                .collect()
        }
    }

    fn dist(a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y) * (x - y))
            .sum::<f64>()
            .sqrt()
    }

    fn norm2(a: &[f64]) -> f64 {
        a.iter().map(|x| x * x).sum::<f64>().sqrt()
    }

    fn cross(a: &[f64], b: &[f64]) -> [f64; 3] {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    }

    fn dot(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(x, y)| x * y).sum()
    }

    fn sphere_metric() -> PullbackMetric {
        PullbackMetric {
            weights: vec![1.0; 3],
            lambda_reg: 0.0,
        }
    }

    const Z0: [f64; 2] = [1.0, 0.3];
    /// A start and velocity on `TanhNet::new(11)` whose geodesic stays where the network is
    /// not saturated: a longer one runs into the region where M ≈ λ_reg I, where the latent
    /// speed grows and RK4 needs far more steps (0.02 drift at 32 steps at twice this speed).
    const NET_Z0: [f64; 3] = [0.2, -0.4, 0.1];
    const NET_V0: [f64; 3] = [0.4, 0.25, -0.3];
    const V0: [f64; 2] = [0.7, 1.1];

    /// The great-circle truth for the sphere chart: from p = G(z0) with ambient tangent
    /// t = J v0 the unit-speed circle ends at cos α p + sin α t/|t|, α = |t| = ‖v0‖_M.
    /// Returns (α, ambient endpoint, latent endpoint).
    fn great_circle(z0: &[f64], v0: &[f64]) -> (f64, Vec<f64>, Vec<f64>) {
        let (p, j) = Sphere.jacobian(z0);
        let t: Vec<f64> = (0..3)
            .map(|i| j[2 * i] * v0[0] + j[2 * i + 1] * v0[1])
            .collect();
        let alpha = norm2(&t);
        let q: Vec<f64> = (0..3)
            .map(|i| alpha.cos() * p[i] + alpha.sin() * t[i] / alpha)
            .collect();
        let latent = vec![q[2].acos(), q[1].atan2(q[0])];
        (alpha, q, latent)
    }

    #[test]
    fn geodesic_linear_chart_is_a_straight_line() {
        let chart = linear();
        let metric = PullbackMetric {
            weights: vec![0.5, 2.0, 1.0, 3.0, 0.25],
            lambda_reg: 0.1,
        };
        let z0 = [0.3, -0.2, 0.5];
        let v0 = [0.9, 0.4, -1.3];
        let g = shoot(&metric, &chart, &z0, &v0, &ShootSpec { steps: 16 }, None);
        let want: Vec<f64> = z0.iter().zip(&v0).map(|(a, b)| a + b).collect();
        let err = dist(&g.end, &want);
        let m = metric.metric(&chart, &z0);
        let speed = metric.norm(&m, &v0);
        println!(
            "linear: endpoint error {err:.3e}, length {} vs ‖v0‖_M {speed}, drift {:.3e}",
            g.length, g.energy_drift
        );
        assert!(err < 1e-12, "endpoint error {err}");
        assert!((g.length - speed).abs() < 1e-12 * speed);
        assert!(g.energy_drift < 1e-12);
        assert!(g.inside);
        // An odd step count integrates the length with the trapezoid rule, also exact here.
        let g = shoot(&metric, &chart, &z0, &v0, &ShootSpec { steps: 7 }, None);
        assert!((g.length - speed).abs() < 1e-12 * speed);
        assert!(dist(&g.end, &want) < 1e-12);
    }

    #[test]
    fn geodesic_metric_matches_independent_forms() {
        // Sphere: M = diag(1, sin²θ).
        let m = sphere_metric().metric(&Sphere, &Z0);
        let s2 = Z0[0].sin().powi(2);
        assert!((m[0] - 1.0).abs() < 1e-15 && m[1].abs() < 1e-15 && m[2].abs() < 1e-15);
        assert!((m[3] - s2).abs() < 1e-15);
        // Linear: Bᵀ W B + λ I entry by entry, and bitwise symmetric.
        let chart = linear();
        let metric = PullbackMetric {
            weights: vec![0.5, 2.0, 1.0, 3.0, 0.25],
            lambda_reg: 0.1,
        };
        let m = metric.metric(&chart, &[0.0; 3]);
        for a in 0..3 {
            for b in 0..3 {
                let mut want = if a == b { 0.1 } else { 0.0 };
                for i in 0..5 {
                    want += chart.b[i * 3 + a] * metric.weights[i] * chart.b[i * 3 + b];
                }
                assert!((m[a * 3 + b] - want).abs() < 1e-14);
                assert_eq!(m[a * 3 + b].to_bits(), m[b * 3 + a].to_bits());
            }
        }
    }

    #[test]
    fn geodesic_sphere_acceleration_matches_christoffel_symbols() {
        // On the round sphere θ̈ = sin θ cos θ φ̇², φ̈ = −2 cot θ θ̇ φ̇.
        let metric = sphere_metric();
        let mut r = Mix(7);
        for _ in 0..20 {
            let z = [r.uniform(0.3, 2.8), r.uniform(-3.0, 3.0)];
            let v = [r.uniform(-2.0, 2.0), r.uniform(-2.0, 2.0)];
            let a = metric.acceleration(&Sphere, &z, &v);
            let want = [
                z[0].sin() * z[0].cos() * v[1] * v[1],
                -2.0 * z[0].cos() / z[0].sin() * v[0] * v[1],
            ];
            assert!(
                dist(&a, &want) < 1e-12 * (1.0 + norm2(&want)),
                "{a:?} vs {want:?}"
            );
        }
    }

    #[test]
    fn geodesic_sphere_follows_the_great_circle() {
        let metric = sphere_metric();
        let g = shoot(&metric, &Sphere, &Z0, &V0, &ShootSpec { steps: 64 }, None);
        let (alpha, q_true, z_true) = great_circle(&Z0, &V0);
        let (p, j) = Sphere.jacobian(&Z0);
        let t: Vec<f64> = (0..3)
            .map(|i| j[2 * i] * V0[0] + j[2 * i + 1] * V0[1])
            .collect();
        let normal = cross(&p, &t);
        let normal: Vec<f64> = normal.iter().map(|x| x / norm2(&normal)).collect();
        let q = Sphere.decode(&g.end);
        let off_plane = dot(&q, &normal).abs();
        let angle = norm2(&cross(&p, &q)).atan2(dot(&p, &q));
        let speed = metric.norm(&metric.metric(&Sphere, &Z0), &V0);
        println!(
            "sphere 64 steps: off-plane {off_plane:.3e}, angle {angle} vs α {alpha} \
             (‖v0‖_M {speed}), length error {:.3e}, ambient endpoint error {:.3e}, \
             latent endpoint error {:.3e}",
            g.length - alpha,
            dist(&q, &q_true),
            dist(&g.end, &z_true)
        );
        assert!((speed - alpha).abs() < 1e-14);
        assert!(off_plane < 1e-6);
        assert!((angle - alpha).abs() < 1e-6);
        assert!((g.length - alpha).abs() < 1e-6);
        assert!(dist(&g.end, &z_true) < 1e-6);
    }

    #[test]
    fn geodesic_sphere_speed_is_conserved() {
        let metric = sphere_metric();
        let g = shoot(&metric, &Sphere, &Z0, &V0, &ShootSpec { steps: 32 }, None);
        println!("sphere 32 steps: energy drift {:.3e}", g.energy_drift);
        assert!(g.energy_drift < 1e-6, "drift {}", g.energy_drift);
        // Also on the nonlinear network under a non-uniform W.
        let net = TanhNet::new(11);
        let metric = PullbackMetric {
            weights: vec![1.0, 0.5, 2.0, 1.5, 0.75],
            lambda_reg: 1e-3,
        };
        let g = shoot(
            &metric,
            &net,
            &NET_Z0,
            &NET_V0,
            &ShootSpec { steps: 64 },
            None,
        );
        println!("tanh net 64 steps: energy drift {:.3e}", g.energy_drift);
        assert!(g.energy_drift < 1e-6, "drift {}", g.energy_drift);
    }

    #[test]
    fn geodesic_rk4_converges_with_order_four() {
        let metric = sphere_metric();
        let (_, _, z_true) = great_circle(&Z0, &V0);
        let errs: Vec<f64> = [4, 8, 16]
            .iter()
            .map(|&steps| {
                let g = shoot(&metric, &Sphere, &Z0, &V0, &ShootSpec { steps }, None);
                dist(&g.end, &z_true)
            })
            .collect();
        let orders = [(errs[0] / errs[1]).log2(), (errs[1] / errs[2]).log2()];
        println!(
            "sphere endpoint errors at 4/8/16 steps {:.3e} {:.3e} {:.3e}, observed orders \
             {:.3} {:.3}",
            errs[0], errs[1], errs[2], orders[0], orders[1]
        );
        for o in orders {
            assert!((3.5..=4.5).contains(&o), "observed order {o}");
        }

        // Self-convergence on the network against a 1024-step reference (no closed form).
        let net = TanhNet::new(11);
        let metric = PullbackMetric {
            weights: vec![1.0, 0.5, 2.0, 1.5, 0.75],
            lambda_reg: 1e-3,
        };
        let reference = shoot(
            &metric,
            &net,
            &NET_Z0,
            &NET_V0,
            &ShootSpec { steps: 1024 },
            None,
        );
        let errs: Vec<f64> = [16, 32, 64]
            .iter()
            .map(|&steps| {
                let g = shoot(&metric, &net, &NET_Z0, &NET_V0, &ShootSpec { steps }, None);
                dist(&g.end, &reference.end)
            })
            .collect();
        let orders = [(errs[0] / errs[1]).log2(), (errs[1] / errs[2]).log2()];
        println!(
            "tanh net endpoint errors at 16/32/64 steps vs 1024 {:.3e} {:.3e} {:.3e}, observed \
             orders {:.3} {:.3}",
            errs[0], errs[1], errs[2], orders[0], orders[1]
        );
        for o in orders {
            assert!((3.5..=4.5).contains(&o), "observed order {o}");
        }
    }

    #[test]
    fn geodesic_test_charts_derivatives_match_finite_differences() {
        let net = TanhNet::new(11);
        let charts: [(&dyn Chart, &str); 3] =
            [(&linear(), "linear"), (&Sphere, "sphere"), (&net, "tanh")];
        let mut r = Mix(3);
        for (chart, name) in charts {
            let d = chart.dim();
            let mut worst_j: f64 = 0.0;
            let mut worst_c: f64 = 0.0;
            for _ in 0..10 {
                let z = if name == "sphere" {
                    vec![r.uniform(0.3, 2.8), r.uniform(-3.0, 3.0)]
                } else {
                    r.vec(d, -1.5, 1.5)
                };
                let v = r.vec(d, -1.0, 1.0);
                let (g, j) = chart.jacobian(&z);
                assert_eq!(g, chart.decode(&z));
                let n = g.len();
                let eps = 1e-6;
                for k in 0..d {
                    let mut zp = z.clone();
                    let mut zm = z.clone();
                    zp[k] += eps;
                    zm[k] -= eps;
                    let (gp, gm) = (chart.decode(&zp), chart.decode(&zm));
                    for i in 0..n {
                        let fd = (gp[i] - gm[i]) / (zp[k] - zm[k]);
                        worst_j = worst_j.max((fd - j[i * d + k]).abs());
                    }
                }
                let eps = 1e-4;
                let zp: Vec<f64> = z.iter().zip(&v).map(|(a, b)| a + eps * b).collect();
                let zm: Vec<f64> = z.iter().zip(&v).map(|(a, b)| a - eps * b).collect();
                let (gp, gm) = (chart.decode(&zp), chart.decode(&zm));
                let c = chart.curvature(&z, &v);
                for i in 0..n {
                    let fd = (gp[i] - 2.0 * g[i] + gm[i]) / (eps * eps);
                    worst_c = worst_c.max((fd - c[i]).abs());
                }
            }
            println!("{name}: Jacobian vs FD {worst_j:.3e}, curvature vs FD {worst_c:.3e}");
            assert!(worst_j < 1e-8, "{name}: Jacobian off by {worst_j}");
            assert!(worst_c < 1e-6, "{name}: curvature off by {worst_c}");
        }
    }

    #[test]
    fn geodesic_exact_and_fd_acceleration_agree() {
        let net = TanhNet::new(11);
        let metric = PullbackMetric {
            weights: vec![1.0, 0.5, 2.0, 1.5, 0.75],
            lambda_reg: 1e-3,
        };
        let mut r = Mix(5);
        let mut worst: f64 = 0.0;
        for _ in 0..20 {
            let z = r.vec(3, -1.5, 1.5);
            let v = r.vec(3, -1.0, 1.0);
            let a = metric.acceleration(&net, &z, &v);
            let a_fd = metric.acceleration_fd(&net, &z, &v, 1e-5);
            worst = worst.max(dist(&a, &a_fd) / norm2(&a));
        }
        let sphere = sphere_metric();
        let mut worst_sphere: f64 = 0.0;
        for _ in 0..20 {
            let z = [r.uniform(0.3, 2.8), r.uniform(-3.0, 3.0)];
            let v = r.vec(2, -1.0, 1.0);
            let a = sphere.acceleration(&Sphere, &z, &v);
            let a_fd = sphere.acceleration_fd(&Sphere, &z, &v, 1e-5);
            worst_sphere = worst_sphere.max(dist(&a, &a_fd) / norm2(&a));
        }
        println!(
            "exact vs FD acceleration (h = 1e-5), worst relative difference: tanh net \
             {worst:.3e}, sphere {worst_sphere:.3e}"
        );
        assert!(worst < 1e-7, "tanh net: {worst}");
        assert!(worst_sphere < 1e-7, "sphere: {worst_sphere}");

        // The whole geodesic through the baseline lands on the same endpoint.
        let spec = ShootSpec { steps: 32 };
        let g = shoot(&metric, &net, &NET_Z0, &NET_V0, &spec, None);
        let g_fd = shoot_fd(&metric, &net, &NET_Z0, &NET_V0, &spec, 1e-5);
        let diff = dist(&g.end, &g_fd.end);
        println!(
            "tanh net 32 steps: shoot vs shoot_fd endpoint {diff:.3e}, lengths {} / {}",
            g.length, g_fd.length
        );
        assert!(diff < 1e-7);
        assert!((g.length - g_fd.length).abs() < 1e-7);
        assert!(g_fd.inside);
    }

    #[test]
    fn geodesic_orthonormalise_under_m() {
        let d = 8;
        let mut r = Mix(99);
        let a = r.vec(d * d, -1.0, 1.0);
        // M = AᵀA + 0.05 I: SPD with a spread of eigenvalues.
        let mut m = vec![0.0; d * d];
        for i in 0..d {
            for j in 0..d {
                let mut s = if i == j { 0.05 } else { 0.0 };
                for k in 0..d {
                    s += a[k * d + i] * a[k * d + j];
                }
                m[i * d + j] = s;
            }
        }
        let metric = sphere_metric();
        let dirs: Vec<Vec<f64>> = (0..d).map(|_| r.vec(d, -1.0, 1.0)).collect();
        let Some(xi) = metric.orthonormalise(&m, &dirs) else {
            panic!("independent directions rejected");
        };
        let mut worst: f64 = 0.0;
        for i in 0..d {
            assert!((metric.norm(&m, &xi[i]) - 1.0).abs() < 1e-12);
            for j in 0..d {
                let want = if i == j { 1.0 } else { 0.0 };
                worst = worst.max((bilinear(&m, &xi[i], &xi[j]) - want).abs());
            }
        }
        println!("orthonormalise: worst |ξ_iᵀ M ξ_j − δ_ij| = {worst:.3e}");
        assert!(worst < 1e-12);
        // Gram–Schmidt in order: the first vector is the first direction rescaled.
        let s = metric.norm(&m, &dirs[0]);
        assert!(dist(&xi[0], &dirs[0].iter().map(|x| x / s).collect::<Vec<_>>()) < 1e-15);

        let dependent: Vec<Vec<f64>> = vec![
            dirs[0].clone(),
            dirs[1].clone(),
            dirs[0]
                .iter()
                .zip(&dirs[1])
                .map(|(a, b)| 2.0 * a - 0.5 * b)
                .collect(),
        ];
        assert!(metric.orthonormalise(&m, &dependent).is_none());
        let too_many: Vec<Vec<f64>> = (0..=d).map(|_| r.vec(d, -1.0, 1.0)).collect();
        assert!(metric.orthonormalise(&m, &too_many).is_none());
        assert!(metric.orthonormalise(&m, &[vec![0.0; d]]).is_none());
        assert_eq!(metric.orthonormalise(&m, &[]), Some(Vec::new()));
    }

    #[test]
    fn geodesic_leaving_the_box_reports_outside() {
        let chart = linear();
        let metric = PullbackMetric {
            weights: vec![1.0; 5],
            lambda_reg: 0.1,
        };
        let spec = ShootSpec { steps: 10 };
        let bounds = Some((-3.0, 3.0));
        // Straight line from 0 at speed 5 leaves [−3, 3] at t = 0.6: node 6 is the last
        // inside (z = 3 up to rounding at most), node 7 the first outside.
        let g = shoot(&metric, &chart, &[0.0; 3], &[5.0, 0.0, 0.0], &spec, bounds);
        assert!(!g.inside);
        assert!(
            g.end[0] > 3.0 && (g.end[0] - 3.5).abs() < 1e-12,
            "{:?}",
            g.end
        );
        // It stopped there: the length covers [0, 0.7].
        let speed = metric.norm(&metric.metric(&chart, &[0.0; 3]), &[5.0, 0.0, 0.0]);
        assert!(
            (g.length - 0.7 * speed).abs() < 1e-12 * speed,
            "{}",
            g.length
        );
        let g = shoot(&metric, &chart, &[0.0; 3], &[2.0, -2.5, 1.0], &spec, bounds);
        assert!(g.inside);
        // On the sphere: φ runs past 3.
        let g = shoot(
            &sphere_metric(),
            &Sphere,
            &[1.5, 2.5],
            &[0.0, 2.0],
            &spec,
            bounds,
        );
        assert!(!g.inside && g.end[1] > 3.0);
        // A start outside the box is reported without integrating.
        let g = shoot(&metric, &chart, &[3.5, 0.0, 0.0], &[0.0; 3], &spec, bounds);
        assert!(!g.inside && g.length == 0.0);
    }

    #[test]
    fn geodesic_singular_metric_is_nan_not_finite() {
        // λ_reg = 0 and a Jacobian without full column rank: M is singular.
        let chart = Linear {
            b: vec![1.0, 0.0, 2.0, 0.0, -1.0, 0.0],
            n: 3,
            d: 2,
        };
        let metric = PullbackMetric {
            weights: vec![1.0; 3],
            lambda_reg: 0.0,
        };
        let a = metric.acceleration(&chart, &[0.1, 0.2], &[1.0, 1.0]);
        assert!(a.iter().all(|x| x.is_nan()));
        let g = shoot(
            &metric,
            &chart,
            &[0.1, 0.2],
            &[1.0, 1.0],
            &ShootSpec { steps: 4 },
            Some((-3.0, 3.0)),
        );
        assert!(!g.inside);
    }

    #[test]
    fn geodesic_results_are_reproducible_and_serialise() {
        let net = TanhNet::new(11);
        let metric = PullbackMetric {
            weights: vec![1.0, 0.5, 2.0, 1.5, 0.75],
            lambda_reg: 1e-3,
        };
        let spec = ShootSpec { steps: 8 };
        let run = || shoot(&metric, &net, &NET_Z0, &NET_V0, &spec, None);
        let (a, b) = (run(), run());
        let bits = |g: &Geodesic| -> Vec<u64> {
            g.end
                .iter()
                .chain([&g.length, &g.energy_drift])
                .map(|x| x.to_bits())
                .collect()
        };
        assert_eq!(bits(&a), bits(&b));
        // postcard, not serde_json: the latter's default float parsing may be off by an ulp.
        let bytes = postcard::to_stdvec(&a).expect("serialise");
        let back: Geodesic = postcard::from_bytes(&bytes).expect("deserialise");
        assert_eq!(bits(&back), bits(&a));
        let bytes = postcard::to_stdvec(&metric).expect("serialise");
        assert_eq!(
            postcard::from_bytes::<PullbackMetric>(&bytes).expect("deserialise"),
            metric
        );
        let bytes = postcard::to_stdvec(&spec).expect("serialise");
        assert_eq!(
            postcard::from_bytes::<ShootSpec>(&bytes).expect("deserialise"),
            spec
        );
    }
}
