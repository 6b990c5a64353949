//! Candidate sets η (paper Eqs. 5–6) and the ablation generators of paper 6.4.
//!
//! - `geodesic` (the method): project ζ_org (Eq. 3), take K Sobol directions orthonormal under
//!   M(z⁰, ω̄) (Eq. 4), shoot geodesics z⁰ ± r ξ_i (Eq. 5), decode the 2K endpoints and the centre.
//! - `euclidean`: the same centre and conditional manifold, straight lines z⁰ ± s r ξ_i with
//!   Euclidean-orthonormal directions.
//! - `unconditional`: the geodesic search on a manifold trained without ω̄.
//! - `direct`: ζ_org ± s δ_i with W_a-orthonormal Sobol directions δ_i in action space, clipped
//!   to the action bounds.
//!
//! The ablations are matched to the geodesic set of the same rollout as in the paper: same
//! |η| = 2K + 1, and the scale s is chosen so that the set's largest ‖ζ − ζ_org‖_{W_a} equals
//! the geodesic set's.

use osms_core::rng::StreamRng;
use osms_nn::Matrix;
use serde::{Deserialize, Serialize};

use crate::cvae::Cvae;
use crate::geodesic::{Chart, PullbackMetric, ShootSpec, shoot};
use crate::project::{Projection, ProjectionParams, project};
use crate::sobol;
use crate::{Error, Result};

/// Which generator builds the candidate sets (paper 6.4, "Candidate generation").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Generator {
    Geodesic,
    Euclidean,
    Unconditional,
    Direct,
}

impl Generator {
    pub fn name(self) -> &'static str {
        match self {
            Generator::Geodesic => "geodesic",
            Generator::Euclidean => "euclidean",
            Generator::Unconditional => "unconditional",
            Generator::Direct => "direct",
        }
    }
}

/// The search's settings: the paper's values as defaults (Z = [−3, 3]^8, K = 4, r = 0.75).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SearchParams {
    pub generator: Generator,
    /// Z = [−bound, bound]^latent.
    pub bound: f32,
    /// K: shooting directions (|η| = 2K + 1).
    pub directions: usize,
    /// r: shooting radius.
    pub radius: f64,
    /// λ_reg of Eq. 4.
    pub lambda_reg: f64,
    /// RK4 steps of a geodesic over t ∈ [0, 1].
    pub rk4_steps: usize,
    /// Halvings of r allowed for a direction whose geodesic would leave Z.
    pub max_shrinks: u32,
    /// Index of the first Sobol point used. Points 0 and 1 map to (−1, …, −1) and the origin,
    /// and the four points from index 2 or from index 4 span only three dimensions (in 8 and
    /// in 56 dimensions alike), so the paper's K = 4 directions start at point 6.
    pub sobol_first: u64,
    /// Bisection steps of the ablations' matching scale.
    pub match_iterations: u32,
    pub projection: ProjectionParams,
}

impl Default for SearchParams {
    fn default() -> Self {
        SearchParams {
            generator: Generator::Geodesic,
            bound: 3.0,
            directions: 4,
            radius: 0.75,
            lambda_reg: 0.1,
            rk4_steps: 8,
            max_shrinks: 6,
            sobol_first: 6,
            match_iterations: 16,
            projection: ProjectionParams::default(),
        }
    }
}

/// One member of η.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    /// 0 for the centre ζ₀, i for direction ξ_i.
    pub direction: u8,
    /// +1 or −1 (0 for the centre).
    pub sign: i8,
    /// Its latent code (empty for `direct`).
    pub z: Vec<f32>,
    /// The snippet, step-major like ζ_org.
    pub zeta: Vec<f32>,
    /// ‖z − z⁰‖₂ (0 for the centre and for `direct`).
    pub latent_displacement: f64,
    /// Length of the latent path under M: the geodesic's for geodesic generators, none for
    /// the straight-line ones.
    pub geodesic_length: Option<f64>,
    /// ‖ζ − ζ_org‖_{W_a}.
    pub deviation: f64,
    /// Factor applied to r so the path stays inside Z (1: none).
    pub shrink: f64,
}

/// η for one rollout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CandidateSet {
    /// The projection (none for `direct`).
    pub projection: Option<Projection>,
    /// The matching scale s (1 for `geodesic`).
    pub scale: f64,
    /// Whether the largest deviation was matched to the reference set's (always for
    /// `geodesic`); false when no scale reaches it.
    pub matched: bool,
    /// Directions whose radius was shrunk to stay inside Z.
    pub shrunk: u32,
    pub candidates: Vec<Candidate>,
}

impl CandidateSet {
    pub fn max_deviation(&self) -> f64 {
        max_dev(&self.candidates)
    }

    pub fn mean_deviation(&self) -> f64 {
        let n = self.candidates.len().max(1) as f64;
        self.candidates.iter().map(|c| c.deviation).sum::<f64>() / n
    }
}

/// The decoder G(·, ω̄) at a fixed ω̄ as a chart, its derivatives by osms-nn's forward mode.
pub struct DecoderChart<'a> {
    pub model: &'a Cvae,
    pub omega_n: &'a [f32],
}

impl DecoderChart<'_> {
    fn input(&self, z: &[f64]) -> Vec<f32> {
        let mut x: Vec<f32> = z.iter().map(|v| *v as f32).collect();
        x.extend_from_slice(self.omega_n);
        x
    }

    /// A latent direction as an input direction (zero on ω̄, which is fixed).
    fn direction(&self, v: &[f64]) -> Vec<f32> {
        let mut dir = vec![0.0f32; v.len() + self.omega_n.len()];
        for (d, v) in dir.iter_mut().zip(v) {
            *d = *v as f32;
        }
        dir
    }

    /// One forward-mode pass: G, J_G (from unit tangents on z) and, with `v`, ∂²G[v, v].
    fn jet(&self, z: &[f64], v: Option<&[f64]>) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let x = self.input(z);
        let d = z.len();
        let tangents = Matrix::from_fn(d, x.len(), |k, j| if k == j { 1.0 } else { 0.0 });
        let dir = v.map(|v| self.direction(v));
        let jet = self.model.decoder.jet(&x, &tangents, dir.as_deref());
        let n = jet.y.len();
        let mut jac = Vec::with_capacity(n * d);
        for i in 0..n {
            for k in 0..d {
                jac.push(f64::from(jet.dy.get(k, i)));
            }
        }
        (
            to_f64(&jet.y),
            jac,
            jet.ddy.as_deref().map(to_f64).unwrap_or_default(),
        )
    }
}

impl Chart for DecoderChart<'_> {
    fn dim(&self) -> usize {
        self.model.latent()
    }

    fn jacobian(&self, z: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let (g, jac, _) = self.jet(z, None);
        (g, jac)
    }

    fn curvature(&self, z: &[f64], v: &[f64]) -> Vec<f64> {
        let x = self.input(z);
        let jet = self
            .model
            .decoder
            .jet(&x, &Matrix::zeros(0, x.len()), Some(&self.direction(v)));
        jet.ddy.as_deref().map(to_f64).unwrap_or_default()
    }

    fn jacobian_and_curvature(&self, z: &[f64], v: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let (_, jac, curv) = self.jet(z, Some(v));
        (jac, curv)
    }

    fn decode(&self, z: &[f64]) -> Vec<f64> {
        let zs = vec![z.iter().map(|v| *v as f32).collect::<Vec<f32>>()];
        to_f64(&self.model.decode(&zs, self.omega_n)[0])
    }
}

fn to_f64(v: &[f32]) -> Vec<f64> {
    v.iter().map(|x| f64::from(*x)).collect()
}

fn metric_of(model: &Cvae, p: &SearchParams) -> PullbackMetric {
    PullbackMetric {
        weights: to_f64(&model.w_a),
        lambda_reg: p.lambda_reg,
    }
}

fn identity(d: usize) -> Vec<f64> {
    (0..d * d)
        .map(|i| if i / d == i % d { 1.0 } else { 0.0 })
        .collect()
}

/// A latent candidate: G(z, ω̄) with its deviation from ζ_org and displacement from z⁰.
struct Latent<'a> {
    model: &'a Cvae,
    omega_n: &'a [f32],
    zeta_org: &'a [f32],
    z0: &'a [f32],
}

impl Latent<'_> {
    fn candidate(
        &self,
        z: Vec<f32>,
        (direction, sign): (u8, i8),
        geodesic_length: Option<f64>,
        shrink: f64,
    ) -> Candidate {
        let zeta = self
            .model
            .decode(std::slice::from_ref(&z), self.omega_n)
            .remove(0);
        Candidate {
            direction,
            sign,
            latent_displacement: distance(&z, self.z0),
            geodesic_length,
            deviation: self.model.weighted_sq(&zeta, self.zeta_org).sqrt(),
            z,
            zeta,
            shrink,
        }
    }

    /// The centre ζ₀ = G(z⁰, ω̄).
    fn centre(&self) -> Candidate {
        self.candidate(self.z0.to_vec(), (0, 0), Some(0.0), 1.0)
    }
}

/// K Sobol directions, orthonormal under `m` (d × d).
fn directions(
    metric: &PullbackMetric,
    m: &[f64],
    d: usize,
    p: &SearchParams,
) -> Result<Vec<Vec<f64>>> {
    let raw = sobol::directions(d, p.sobol_first, p.directions).ok_or(Error::SobolDimension(d))?;
    metric
        .orthonormalise(m, &raw)
        .ok_or(Error::DependentDirections)
}

/// The 2K geodesic endpoints from z⁰ with initial velocities ± radius ξ_i (Eq. 5), each
/// radius halved (up to `max_shrinks` times) until its geodesic stays inside Z; an endpoint
/// still outside is clipped into Z.
fn geodesic_endpoints(
    at: &Latent<'_>,
    xi: &[Vec<f64>],
    radius: f64,
    p: &SearchParams,
) -> Vec<Candidate> {
    let chart = DecoderChart {
        model: at.model,
        omega_n: at.omega_n,
    };
    let metric = metric_of(at.model, p);
    let z0 = to_f64(at.z0);
    let bound = f64::from(p.bound);
    let spec = ShootSpec {
        steps: p.rk4_steps.max(1),
    };
    let mut out = Vec::with_capacity(2 * xi.len());
    for (i, x) in xi.iter().enumerate() {
        for sign in [1i8, -1] {
            let mut shrink = 1.0;
            let mut tries = 0;
            let g = loop {
                let v0: Vec<f64> = x
                    .iter()
                    .map(|c| f64::from(sign) * radius * shrink * c)
                    .collect();
                let g = shoot(&metric, &chart, &z0, &v0, &spec, Some((-bound, bound)));
                if g.inside || tries == p.max_shrinks {
                    break g;
                }
                tries += 1;
                shrink *= 0.5;
            };
            let z: Vec<f32> = g
                .end
                .iter()
                .map(|v| (*v as f32).clamp(-p.bound, p.bound))
                .collect();
            out.push(at.candidate(z, (i as u8 + 1, sign), Some(g.length), shrink));
        }
    }
    out
}

fn distance(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| {
            let d = f64::from(*x) - f64::from(*y);
            d * d
        })
        .sum::<f64>()
        .sqrt()
}

/// Straight latent lines z⁰ ± step · ξ_i (ξ_i Euclidean-orthonormal), each shortened so it
/// ends inside Z.
fn euclidean_endpoints(
    at: &Latent<'_>,
    xi: &[Vec<f64>],
    step: f64,
    p: &SearchParams,
) -> Vec<Candidate> {
    let bound = f64::from(p.bound);
    let mut out = Vec::with_capacity(2 * xi.len());
    for (i, x) in xi.iter().enumerate() {
        for sign in [1i8, -1] {
            let delta: Vec<f64> = x.iter().map(|c| f64::from(sign) * step * c).collect();
            // The largest fraction of the step that keeps every coordinate inside Z.
            let mut shrink: f64 = 1.0;
            for (z, dz) in at.z0.iter().zip(&delta) {
                let z = f64::from(*z);
                if z + dz > bound {
                    shrink = shrink.min((bound - z) / dz);
                } else if z + dz < -bound {
                    shrink = shrink.min((-bound - z) / dz);
                }
            }
            let shrink = shrink.max(0.0);
            let z: Vec<f32> = at
                .z0
                .iter()
                .zip(&delta)
                .map(|(z, dz)| ((f64::from(*z) + shrink * dz) as f32).clamp(-p.bound, p.bound))
                .collect();
            out.push(at.candidate(z, (i as u8 + 1, sign), None, shrink));
        }
    }
    out
}

/// ζ_org ± scale · δ_i clipped to [−1, 1], δ_i W_a-orthonormal Sobol directions in action
/// space.
fn direct_endpoints(
    model: &Cvae,
    zeta_org: &[f32],
    delta: &[Vec<f64>],
    scale: f64,
) -> Vec<Candidate> {
    let mut out = Vec::with_capacity(2 * delta.len());
    for (i, d) in delta.iter().enumerate() {
        for sign in [1i8, -1] {
            let zeta: Vec<f32> = zeta_org
                .iter()
                .zip(d)
                .map(|(z, d)| {
                    ((f64::from(*z) + f64::from(sign) * scale * d) as f32).clamp(-1.0, 1.0)
                })
                .collect();
            out.push(Candidate {
                direction: i as u8 + 1,
                sign,
                z: Vec::new(),
                latent_displacement: 0.0,
                geodesic_length: None,
                deviation: model.weighted_sq(&zeta, zeta_org).sqrt(),
                zeta,
                shrink: 1.0,
            });
        }
    }
    out
}

fn max_dev(c: &[Candidate]) -> f64 {
    c.iter().map(|c| c.deviation).fold(0.0, f64::max)
}

/// Relative error within which a matched set's largest deviation equals the target's.
const MATCH_TOLERANCE: f64 = 1e-3;

/// The scale s whose endpoints' largest deviation (with `floor`, the centre's) equals
/// `target`: doubling until it is reached, then bisection. None when no scale up to 64 reaches
/// it, the centre alone exceeds it, or the deviation jumps over the target (a direction shrunk
/// to stay in Z can make it discontinuous in s), so "matched" always means equal.
fn match_scale(
    target: f64,
    floor: f64,
    iterations: u32,
    mut eval: impl FnMut(f64) -> f64,
) -> Option<f64> {
    if floor > target {
        return None;
    }
    let (mut lo, mut hi) = (0.0, 1.0);
    while eval(hi).max(floor) < target {
        lo = hi;
        hi *= 2.0;
        if hi > 64.0 {
            return None;
        }
    }
    for _ in 0..iterations {
        let mid = 0.5 * (lo + hi);
        if eval(mid).max(floor) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let reached = eval(hi).max(floor);
    ((reached - target).abs() < MATCH_TOLERANCE * target).then_some(hi)
}

/// Builds η for one window. `reference` is the geodesic set of the same rollout (required by
/// every generator but `geodesic`): the ablations match its largest deviation, and
/// `euclidean` starts from its z⁰, so the two differ only in how they leave it. `rng` seeds
/// the projection's multi-start samples.
pub fn candidate_set(
    model: &Cvae,
    zeta_org: &[f32],
    omega_bar: &[f32],
    reference: Option<&CandidateSet>,
    p: &SearchParams,
    rng: &mut StreamRng,
) -> Result<CandidateSet> {
    if zeta_org.len() != model.zeta_len() {
        return Err(Error::SnippetLength {
            got: zeta_org.len(),
            expected: model.zeta_len(),
        });
    }
    let omega_n = model.normalise(omega_bar);
    let shrunk = |c: &[Candidate]| c.iter().filter(|c| c.shrink < 1.0).count() as u32;
    let target = reference.map(CandidateSet::max_deviation);
    let metric = metric_of(model, p);
    if p.generator == Generator::Direct {
        let n = zeta_org.len();
        let w = &metric.weights;
        let m: Vec<f64> = (0..n * n)
            .map(|i| if i / n == i % n { w[i / n] } else { 0.0 })
            .collect();
        let delta = directions(&metric, &m, n, p)?;
        let (scale, matched) = match target {
            Some(t) => match match_scale(t, 0.0, p.match_iterations, |s| {
                max_dev(&direct_endpoints(model, zeta_org, &delta, s))
            }) {
                Some(s) => (s, true),
                None => (p.radius, false),
            },
            None => (p.radius, false),
        };
        let mut candidates = vec![Candidate {
            direction: 0,
            sign: 0,
            z: Vec::new(),
            zeta: zeta_org.to_vec(),
            latent_displacement: 0.0,
            geodesic_length: None,
            deviation: 0.0,
            shrink: 1.0,
        }];
        candidates.extend(direct_endpoints(model, zeta_org, &delta, scale));
        return Ok(CandidateSet {
            projection: None,
            scale,
            matched,
            shrunk: 0,
            candidates,
        });
    }

    let shared = match (p.generator, reference) {
        (Generator::Euclidean, Some(r)) => r.projection.clone(),
        _ => None,
    };
    let proj = match shared {
        Some(proj) => proj,
        None => project(model, zeta_org, &omega_n, p.bound, &p.projection, rng),
    };
    let at = Latent {
        model,
        omega_n: &omega_n,
        zeta_org,
        z0: &proj.z0,
    };
    let c0 = at.centre();
    let d = model.latent();
    // The directions depend on z⁰ only, not on the radius the matching tries.
    let xi = match p.generator {
        Generator::Euclidean => directions(&metric, &identity(d), d, p)?,
        _ => {
            let chart = DecoderChart {
                model,
                omega_n: &omega_n,
            };
            directions(&metric, &metric.metric(&chart, &to_f64(&proj.z0)), d, p)?
        }
    };
    let endpoints = |s: f64| match p.generator {
        Generator::Euclidean => euclidean_endpoints(&at, &xi, s * p.radius, p),
        _ => geodesic_endpoints(&at, &xi, s * p.radius, p),
    };
    let (scale, matched) = match (p.generator, target) {
        (Generator::Geodesic, _) => (1.0, true),
        (_, Some(t)) => match match_scale(t, c0.deviation, p.match_iterations, |s| {
            max_dev(&endpoints(s))
        }) {
            Some(s) => (s, true),
            None => (1.0, false),
        },
        (_, None) => (1.0, false),
    };
    let mut candidates = vec![c0];
    candidates.extend(endpoints(scale));
    Ok(CandidateSet {
        projection: Some(proj),
        scale,
        matched,
        shrunk: shrunk(&candidates),
        candidates,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cvae::testing;
    use crate::geodesic::PullbackMetric;
    use osms_core::rng;

    fn params(generator: Generator) -> SearchParams {
        SearchParams {
            generator,
            directions: 3,
            radius: 0.5,
            ..SearchParams::default()
        }
    }

    /// A snippet a little off the manifold: a training window plus a smooth offset.
    fn target(zetas: &[Vec<f32>], i: usize) -> Vec<f32> {
        zetas[i]
            .iter()
            .enumerate()
            .map(|(j, v)| (v + 0.05 * ((j % 7) as f32 - 3.0) / 3.0).clamp(-1.0, 1.0))
            .collect()
    }

    #[test]
    fn geodesic_sets_have_the_papers_shape_and_stay_in_z() {
        let (m, zetas, omegas) = testing::model(true);
        let p = params(Generator::Geodesic);
        for i in [0usize, 7, 19] {
            let zeta_org = target(&zetas, i);
            let set = candidate_set(
                &m,
                &zeta_org,
                &omegas[i],
                None,
                &p,
                &mut rng::stream(0, "t", "c", i as u64),
            )
            .expect("set");
            assert_eq!(set.candidates.len(), 2 * p.directions + 1);
            assert!(set.matched && set.scale == 1.0);
            let proj = set.projection.as_ref().expect("projection");
            assert_eq!(set.candidates[0].z, proj.z0);
            assert!((set.candidates[0].deviation - proj.residual).abs() < 1e-9);
            for c in &set.candidates {
                assert!(c.z.iter().all(|v| v.abs() <= p.bound), "{:?}", c.z);
                let zeta = m
                    .decode(std::slice::from_ref(&c.z), &m.normalise(&omegas[i]))
                    .remove(0);
                assert_eq!(zeta, c.zeta, "ζ is G(z, ω̄)");
                assert!((c.deviation - m.weighted_sq(&c.zeta, &zeta_org).sqrt()).abs() < 1e-9);
            }
            // ξ_i is M-unit and a geodesic keeps its speed, so each length is r × shrink (up to
            // the default 8 RK4 steps' drift on an f32 decoder: 0.3 % measured).
            for c in &set.candidates[1..] {
                let length = c.geodesic_length.expect("length");
                let expected = p.radius * c.shrink;
                assert!(
                    (length - expected).abs() < 1e-2 * expected,
                    "direction {} sign {}: length {length}, r·shrink {expected}",
                    c.direction,
                    c.sign
                );
            }
            // Opposite directions leave z⁰ the opposite way.
            for pair in set.candidates[1..].chunks(2) {
                let z0 = &proj.z0;
                let dot: f32 = (0..z0.len())
                    .map(|k| (pair[0].z[k] - z0[k]) * (pair[1].z[k] - z0[k]))
                    .sum();
                assert!(dot < 0.0, "± directions point apart");
            }
        }
    }

    #[test]
    fn directions_are_orthonormal_under_the_metric() {
        let (m, _, omegas) = testing::model(true);
        let p = params(Generator::Geodesic);
        let omega_n = m.normalise(&omegas[3]);
        let chart = DecoderChart {
            model: &m,
            omega_n: &omega_n,
        };
        let metric = PullbackMetric {
            weights: to_f64(&m.w_a),
            lambda_reg: p.lambda_reg,
        };
        let z0 = [0.3, -0.2, 0.5];
        let mm = metric.metric(&chart, &z0);
        let raw = sobol::directions(3, p.sobol_first, 3).expect("sobol");
        let xi = metric.orthonormalise(&mm, &raw).expect("independent");
        for (a, xa) in xi.iter().enumerate() {
            for (b, xb) in xi.iter().enumerate() {
                let mut ip = 0.0;
                for r in 0..3 {
                    for c in 0..3 {
                        ip += xa[r] * mm[r * 3 + c] * xb[c];
                    }
                }
                let want = if a == b { 1.0 } else { 0.0 };
                assert!((ip - want).abs() < 1e-9, "ξ_{a}ᵀ M ξ_{b} = {ip}");
            }
        }
        // The paper's K = 4 directions from the default first point are independent in the
        // latent (8) and action (56) dimensions.
        for dim in [8usize, 56] {
            let raw =
                sobol::directions(dim, SearchParams::default().sobol_first, 4).expect("sobol");
            let eye: Vec<f64> = (0..dim * dim)
                .map(|i| if i / dim == i % dim { 1.0 } else { 0.0 })
                .collect();
            assert!(
                metric.orthonormalise(&eye, &raw).is_some(),
                "{dim} dimensions"
            );
        }
    }

    #[test]
    fn ablations_match_the_geodesic_deviation() {
        let (m, zetas, omegas) = testing::model(true);
        let (mu, _, _) = testing::model(false);
        for i in [2usize, 11] {
            let zeta_org = target(&zetas, i);
            let stream = || rng::stream(0, "t", "c", i as u64);
            let geo = candidate_set(
                &m,
                &zeta_org,
                &omegas[i],
                None,
                &params(Generator::Geodesic),
                &mut stream(),
            )
            .expect("geodesic");
            let reference = geo.max_deviation();
            for (g, model) in [
                (Generator::Euclidean, &m),
                (Generator::Direct, &m),
                (Generator::Unconditional, &mu),
            ] {
                let set = candidate_set(
                    model,
                    &zeta_org,
                    &omegas[i],
                    Some(&geo),
                    &params(g),
                    &mut stream(),
                )
                .expect("set");
                assert_eq!(
                    set.candidates.len(),
                    geo.candidates.len(),
                    "{g:?}: same |η|"
                );
                if set.matched {
                    let rel = (set.max_deviation() - reference).abs() / reference;
                    assert!(
                        rel < 1e-3,
                        "{g:?}: largest deviation {} vs {reference}",
                        set.max_deviation()
                    );
                } else {
                    assert_eq!(
                        g,
                        Generator::Unconditional,
                        "only another manifold's centre can miss"
                    );
                }
                if g == Generator::Direct {
                    assert_eq!(
                        set.candidates[0].zeta, zeta_org,
                        "the centre is ζ_org itself"
                    );
                    assert!(
                        set.candidates
                            .iter()
                            .all(|c| c.zeta.iter().all(|v| v.abs() <= 1.0))
                    );
                }
                if g == Generator::Euclidean {
                    let z0 = &geo.projection.as_ref().expect("p").z0;
                    assert_eq!(&set.projection.as_ref().expect("p").z0, z0, "same centre");
                    assert!(
                        set.candidates
                            .iter()
                            .all(|c| c.geodesic_length.is_none() || c.direction == 0)
                    );
                }
            }
        }
    }

    #[test]
    fn match_scale_finds_the_target_and_reports_the_impossible() {
        let f = |s: f64| 2.0 * s;
        let s = match_scale(3.0, 0.0, 40, f).expect("some");
        assert!((s - 1.5).abs() < 1e-9, "{s}");
        assert_eq!(
            match_scale(3.0, 4.0, 40, f),
            None,
            "the centre is already farther"
        );
        assert_eq!(match_scale(1e9, 0.0, 40, f), None, "out of reach");
        let step = |s: f64| if s < 1.0 { s } else { 5.0 };
        assert_eq!(
            match_scale(3.0, 0.0, 40, step),
            None,
            "a jump over the target is not a match"
        );
    }
}
