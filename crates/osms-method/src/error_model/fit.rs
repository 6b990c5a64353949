//! Fitting Eq. 7 to paired student and teacher actions: per phase the delay, gain, bias, AR
//! coefficients and innovation covariance; the pooled fallback; the global i.i.d. model.

// The numerics index several parallel row-major arrays by the same channel index; iterator
// zips would obscure the formulas.
#![allow(clippy::needless_range_loop)]

use super::model::*;
use crate::linalg::{lower_times_transpose, robust_cholesky};
use crate::{Error, Result};

/// Fits Eq. 7 to paired student/teacher actions (section 4.3).
///
/// Per phase (all phases pooled for [`ErrorVariant::GlobalIid`]): the delay minimizing the
/// total least-squares residual of `a_n = S ā_{n−d} + μ + r_n`, then for
/// [`ErrorVariant::PhaseCorrelated`] a per-channel AR(1) fit of the residual within runs of
/// the phase, and the Cholesky factor of the innovation covariance. See the module
/// documentation for the fallback of unvisited phases.
pub fn fit(
    sequences: &[PairSequence<'_>],
    channels: usize,
    params: &ErrorFitParams,
) -> Result<ErrorModel> {
    if !params.kappa.is_finite() {
        return Err(Error::InvalidFitParams(format!(
            "kappa {} is not finite",
            params.kappa
        )));
    }
    if !(0.0..1.0).contains(&params.max_ar) {
        return Err(Error::InvalidFitParams(format!(
            "max_ar {} is not in [0, 1)",
            params.max_ar
        )));
    }
    if channels == 0 {
        return Err(Error::NoChannels);
    }
    if sequences.is_empty() {
        return Err(Error::NoSequences);
    }
    check_sequences(sequences, channels)?;

    let phases = match params.variant {
        ErrorVariant::Unperturbed => Vec::new(),
        ErrorVariant::GlobalIid => vec![fit_global(sequences, channels)?; N_PHASES],
        ErrorVariant::Calibrated => {
            return Err(Error::InvalidFitParams(
                "a calibrated model is not fitted on the pairs: `calibrate_error_model` scales the unit-gain fit in closed loop".into(),
            ));
        }
        ErrorVariant::PhaseIndependent
        | ErrorVariant::PhaseCorrelated
        | ErrorVariant::UnitGain
        | ErrorVariant::Orthogonal => {
            let mut pooled: Option<PhaseModel> = None;
            let mut out = Vec::with_capacity(N_PHASES);
            for phase in 0..N_PHASES {
                let group = Group::Phase(phase as u8);
                let own = match fit_group(sequences, channels, group, params) {
                    GroupFit::Model(m) => {
                        out.push(m);
                        continue;
                    }
                    GroupFit::Empty => 0,
                    GroupFit::TooFew { samples, .. } => samples,
                };
                let p = match &pooled {
                    Some(p) => p.clone(),
                    None => {
                        let p = match fit_group(sequences, channels, Group::All, params) {
                            GroupFit::Model(m) => m,
                            GroupFit::Empty => {
                                return Err(Error::TooFewPooledSamples {
                                    samples: 0,
                                    needed: needed_samples(channels),
                                    what: "regression samples",
                                });
                            }
                            GroupFit::TooFew {
                                samples,
                                needed,
                                what,
                            } => {
                                return Err(Error::TooFewPooledSamples {
                                    samples,
                                    needed,
                                    what,
                                });
                            }
                        };
                        pooled = Some(p.clone());
                        p
                    }
                };
                out.push(PhaseModel {
                    samples: own,
                    pooled: true,
                    ..p
                });
            }
            out
        }
    };
    Ok(ErrorModel {
        variant: params.variant,
        channels,
        kappa: params.kappa,
        phases,
    })
}

pub(super) fn check_sequences(sequences: &[PairSequence<'_>], c: usize) -> Result<()> {
    for (i, s) in sequences.iter().enumerate() {
        let steps = s.steps();
        let expected = steps * c;
        if s.student.len() != expected || s.teacher.len() != expected {
            return Err(Error::LengthMismatch {
                sequence: i,
                student: s.student.len(),
                teacher: s.teacher.len(),
                steps,
                channels: c,
                expected,
            });
        }
        for n in 0..steps {
            if usize::from(s.phase[n]) >= N_PHASES {
                return Err(Error::PhaseOutOfRange {
                    sequence: i,
                    step: n,
                    phase: s.phase[n],
                });
            }
            let row = n * c..(n + 1) * c;
            let finite = s.student[row.clone()].iter().all(|v| v.is_finite())
                && s.teacher[row].iter().all(|v| v.is_finite());
            if !finite {
                return Err(Error::NonFinite {
                    sequence: i,
                    step: n,
                });
            }
        }
    }
    Ok(())
}

/// Fewest samples for which a c×c sample covariance can be full rank, with one to spare.
fn needed_samples(c: usize) -> usize {
    c + 2
}

#[derive(Clone, Copy)]
enum Group {
    Phase(u8),
    All,
}

impl Group {
    fn contains(self, phase: u8) -> bool {
        match self {
            Group::Phase(p) => p == phase,
            Group::All => true,
        }
    }
}

enum GroupFit {
    Model(PhaseModel),
    /// No regression samples at all: the phase was not visited.
    Empty,
    TooFew {
        samples: usize,
        needed: usize,
        what: &'static str,
    },
}

/// Running means and centered cross-products of (x, y) pairs (Welford), which stays accurate
/// where raw power sums would cancel.
#[derive(Clone, Copy, Default)]
struct Bivariate {
    n: usize,
    mx: f64,
    my: f64,
    cxx: f64,
    cxy: f64,
    cyy: f64,
}

impl Bivariate {
    fn push(&mut self, x: f64, y: f64) {
        self.n += 1;
        let inv = 1.0 / self.n as f64;
        let dx = x - self.mx;
        let dy = y - self.my;
        self.mx += dx * inv;
        self.my += dy * inv;
        self.cxx += dx * (x - self.mx);
        self.cxy += dx * (y - self.my);
        self.cyy += dy * (y - self.my);
    }

    /// `(gain, bias, residual sum of squares)` of `y ≈ gain·x + bias`, the gain by `how`.
    fn regress(&self, how: GainFit) -> (f64, f64, f64) {
        // A teacher channel that barely moves cannot tell gain from bias (see module docs).
        let moves = self.cxx > 1e-12 * self.n as f64;
        let gain = match how {
            GainFit::LeastSquares if moves => self.cxy / self.cxx,
            // The major axis of the (x, y) scatter: the slope minimising the summed squared
            // perpendicular distances, (s_yy − s_xx + √((s_yy − s_xx)² + 4 s_xy²)) / (2 s_xy).
            GainFit::Orthogonal if moves && self.cxy.abs() > 1e-12 * self.n as f64 => {
                let d = self.cyy - self.cxx;
                (d + (d * d + 4.0 * self.cxy * self.cxy).sqrt()) / (2.0 * self.cxy)
            }
            _ => 1.0,
        };
        let bias = self.my - gain * self.mx;
        let rss = (self.cyy - 2.0 * gain * self.cxy + gain * gain * self.cxx).max(0.0);
        (gain, bias, rss)
    }
}

/// How a channel's gain S_kk is estimated.
#[derive(Clone, Copy)]
enum GainFit {
    /// Ordinary least squares of π̄'s action on the teacher's (the paper's).
    LeastSquares,
    /// Orthogonal regression: errors in both actions.
    Orthogonal,
    /// S = 1: μ is the mean deviation.
    Unit,
}

impl GainFit {
    fn of(variant: ErrorVariant) -> GainFit {
        match variant {
            ErrorVariant::UnitGain | ErrorVariant::Calibrated => GainFit::Unit,
            ErrorVariant::Orthogonal => GainFit::Orthogonal,
            _ => GainFit::LeastSquares,
        }
    }
}

/// Running mean and centered cross-product matrix of vectors (Welford).
struct Covariance {
    n: usize,
    mean: Vec<f64>,
    m2: Vec<f64>,
    delta: Vec<f64>,
}

impl Covariance {
    fn new(c: usize) -> Self {
        Self {
            n: 0,
            mean: vec![0.0; c],
            m2: vec![0.0; c * c],
            delta: vec![0.0; c],
        }
    }

    fn push(&mut self, x: &[f64]) {
        let c = self.mean.len();
        self.n += 1;
        let inv = 1.0 / self.n as f64;
        for k in 0..c {
            self.delta[k] = x[k] - self.mean[k];
            self.mean[k] += self.delta[k] * inv;
        }
        for i in 0..c {
            for j in 0..c {
                self.m2[i * c + j] += self.delta[i] * (x[j] - self.mean[j]);
            }
        }
    }

    /// Unbiased sample covariance (divisor n − 1).
    fn covariance(&self) -> Vec<f64> {
        let div = (self.n.max(2) - 1) as f64;
        self.m2.iter().map(|v| v / div).collect()
    }
}

/// The least-squares fit of `a_n = S ā_{n−d} + μ + r_n` at one delay of the grid.
struct DelayFit {
    delay: usize,
    rss: f64,
    gain: Vec<f64>,
    bias: Vec<f64>,
    samples: usize,
}

fn fit_group(
    sequences: &[PairSequence<'_>],
    c: usize,
    group: Group,
    params: &ErrorFitParams,
) -> GroupFit {
    let start = params.max_delay;
    let needed = needed_samples(c);
    let mut best: Option<DelayFit> = None;
    for d in 0..=params.max_delay {
        let mut acc = vec![Bivariate::default(); c];
        for s in sequences {
            for n in start..s.steps() {
                if !group.contains(s.phase[n]) {
                    continue;
                }
                for (k, a) in acc.iter_mut().enumerate() {
                    a.push(
                        f64::from(s.teacher[(n - d) * c + k]),
                        f64::from(s.student[n * c + k]),
                    );
                }
            }
        }
        // The sample set does not depend on d, so one check covers the grid.
        let samples = acc[0].n;
        if samples == 0 {
            return GroupFit::Empty;
        }
        if samples < needed {
            return GroupFit::TooFew {
                samples,
                needed,
                what: "regression samples",
            };
        }
        let mut gain = Vec::with_capacity(c);
        let mut bias = Vec::with_capacity(c);
        let mut total = 0.0;
        for a in &acc {
            let (g, b, rss) = a.regress(GainFit::of(params.variant));
            gain.push(g);
            bias.push(b);
            total += rss;
        }
        // Strict comparison keeps the smaller delay on ties.
        if best.as_ref().is_none_or(|b| total < b.rss) {
            best = Some(DelayFit {
                delay: d,
                rss: total,
                gain,
                bias,
                samples,
            });
        }
    }
    let Some(DelayFit {
        delay,
        gain,
        bias,
        samples,
        ..
    }) = best
    else {
        return GroupFit::Empty;
    };

    let residual = |s: &PairSequence<'_>, n: usize, k: usize| {
        f64::from(s.student[n * c + k])
            - gain[k] * f64::from(s.teacher[(n - delay) * c + k])
            - bias[k]
    };

    let mut ar = vec![0.0; c];
    let mut ar_pairs = 0usize;
    if params.variant.correlated() {
        // Only consecutive steps of the same phase within one sequence form a pair, so a
        // phase's dynamics are not mixed with the jump at a phase change.
        let mut num = vec![0.0; c];
        let mut den = vec![0.0; c];
        let mut pairs = 0usize;
        for s in sequences {
            for n in start + 1..s.steps() {
                if !(group.contains(s.phase[n]) && group.contains(s.phase[n - 1])) {
                    continue;
                }
                pairs += 1;
                for k in 0..c {
                    let prev = residual(s, n - 1, k);
                    num[k] += residual(s, n, k) * prev;
                    den[k] += prev * prev;
                }
            }
        }
        // Too few pairs (the contact phase lasts one control step, so it has none) leave no
        // dynamics to estimate: A = 0 and the innovations are the residuals themselves.
        if pairs >= needed {
            ar_pairs = pairs;
            for k in 0..c {
                let raw = if den[k] > 0.0 { num[k] / den[k] } else { 0.0 };
                ar[k] = raw.clamp(-params.max_ar, params.max_ar);
            }
        }
    }
    // The residuals' covariance over the group's regression samples.
    let residual_covariance = || {
        let mut cov = Covariance::new(c);
        let mut u = vec![0.0; c];
        for s in sequences {
            for n in start..s.steps() {
                if group.contains(s.phase[n]) {
                    for (k, uk) in u.iter_mut().enumerate() {
                        *uk = residual(s, n, k);
                    }
                    cov.push(&u);
                }
            }
        }
        cov.covariance()
    };
    let l = if ar_pairs > 0 {
        let mut cov = Covariance::new(c);
        let mut u = vec![0.0; c];
        for s in sequences {
            for n in start + 1..s.steps() {
                if !(group.contains(s.phase[n]) && group.contains(s.phase[n - 1])) {
                    continue;
                }
                for (k, uk) in u.iter_mut().enumerate() {
                    *uk = residual(s, n, k) - ar[k] * residual(s, n - 1, k);
                }
                cov.push(&u);
            }
        }
        let mut l = robust_cholesky(&cov.covariance(), c);
        if params.stationary == StationaryFit::Residual {
            match_variances(&mut l, &ar, &residual_covariance(), c);
        }
        l
    } else {
        robust_cholesky(&residual_covariance(), c)
    };
    GroupFit::Model(PhaseModel {
        ar_pairs,
        ..assemble(delay, gain, bias, ar, l, samples)
    })
}

/// Scales row k of `l` by √(γ_k / Σ_kk), with Σ_kk = (LLᵀ)_kk / (1 − a_k²) the Lyapunov
/// solution's variance and γ_k = `target[k·c + k]`, so that the stationary variances equal γ
/// and the innovations' correlations are kept (D L Lᵀ D stays positive semi-definite).
fn match_variances(l: &mut [f64], ar: &[f64], target: &[f64], c: usize) {
    let q = lower_times_transpose(l, c);
    for k in 0..c {
        let stationary = q[k * c + k] / (1.0 - ar[k] * ar[k]);
        if stationary > 0.0 {
            let d = (target[k * c + k] / stationary).sqrt();
            for v in &mut l[k * c..(k + 1) * c] {
                *v *= d;
            }
        }
    }
}

/// Table III's global i.i.d. Gaussian: one mean and covariance of `a − ā` over every step.
fn fit_global(sequences: &[PairSequence<'_>], c: usize) -> Result<PhaseModel> {
    let mut cov = Covariance::new(c);
    let mut dev = vec![0.0; c];
    for s in sequences {
        for n in 0..s.steps() {
            for (k, v) in dev.iter_mut().enumerate() {
                *v = f64::from(s.student[n * c + k]) - f64::from(s.teacher[n * c + k]);
            }
            cov.push(&dev);
        }
    }
    let needed = needed_samples(c);
    if cov.n < needed {
        return Err(Error::TooFewPooledSamples {
            samples: cov.n,
            needed,
            what: "samples",
        });
    }
    let l = robust_cholesky(&cov.covariance(), c);
    Ok(assemble(
        0,
        vec![1.0; c],
        cov.mean.clone(),
        vec![0.0; c],
        l,
        cov.n,
    ))
}

/// Completes a phase model with the stationary covariance of its AR process.
pub(crate) fn assemble(
    delay: usize,
    gain: Vec<f64>,
    bias: Vec<f64>,
    ar: Vec<f64>,
    l: Vec<f64>,
    samples: usize,
) -> PhaseModel {
    let c = ar.len();
    let q = lower_times_transpose(&l, c);
    // For diagonal A the Lyapunov equation Σ = A Σ Aᵀ + Q decouples entrywise:
    // Σ_ij (1 − a_i a_j) = Q_ij. Q is rebuilt from the stored L so the identity holds for the
    // model exactly as stored.
    let mut stationary = vec![0.0; c * c];
    for i in 0..c {
        for j in 0..c {
            stationary[i * c + j] = q[i * c + j] / (1.0 - ar[i] * ar[j]);
        }
    }
    let spectral_radius = ar.iter().fold(0.0f64, |m, a| m.max(a.abs()));
    PhaseModel {
        delay,
        gain,
        bias,
        ar,
        l,
        stationary,
        spectral_radius,
        samples,
        ar_pairs: 0,
        pooled: false,
    }
}

#[cfg(test)]
mod tests {
    use osms_core::rng::normal;

    use super::*;
    use crate::error_model::testdata::*;

    #[test]
    fn fit_recovers_known_parameters() {
        let data = all_phases_data();
        let model = fit(&data.pairs(), C, &ErrorFitParams::default()).expect("fit");
        assert_eq!(model.phases.len(), N_PHASES);
        let (mut ws, mut wm, mut wa, mut wq) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for (phase, (p, t)) in model.phases.iter().zip(truths()).enumerate() {
            assert_eq!(p.delay, t.d, "phase {phase}");
            assert!(p.samples >= 19_000, "phase {phase}: {}", p.samples);
            let ds = max_abs_diff(&p.gain, &t.s);
            let dm = max_abs_diff(&p.bias, &t.mu);
            let da = max_abs_diff(&p.ar, &t.ar);
            let q_true = llt(&t.l);
            let scale = (0..C).fold(0.0f64, |m, k| m.max(q_true[k * C + k]));
            let dq = max_abs_diff(&llt(&p.l), &q_true) / scale;
            println!(
                "phase {phase}: |ΔS| {ds:.4} |Δμ| {dm:.4} |Δar| {da:.4} |ΔLLᵀ|/max diag {dq:.4}"
            );
            assert!(ds < 0.05, "phase {phase}: gain off by {ds}");
            assert!(dm < 0.03, "phase {phase}: bias off by {dm}");
            assert!(da < 0.03, "phase {phase}: ar off by {da}");
            assert!(
                dq < 0.08,
                "phase {phase}: LLᵀ off by {dq} of its largest diagonal"
            );
            ws = ws.max(ds);
            wm = wm.max(dm);
            wa = wa.max(da);
            wq = wq.max(dq);
        }
        println!("worst: S {ws:.4} μ {wm:.4} ar {wa:.4} LLᵀ {wq:.4}");
        // Determinism: a second fit is bit-identical.
        let again = fit(&data.pairs(), C, &ErrorFitParams::default()).expect("fit");
        assert_eq!(model, again);
    }

    #[test]
    fn stationary_covariance_solves_lyapunov_and_ar_is_clamped() {
        let data = all_phases_data();
        let model = fit(&data.pairs(), C, &ErrorFitParams::default()).expect("fit");
        let mut worst = 0.0f64;
        for p in &model.phases {
            let q = llt(&p.l);
            for i in 0..C {
                for j in 0..C {
                    let s = p.stationary[i * C + j];
                    let resid = s - p.ar[i] * s * p.ar[j] - q[i * C + j];
                    worst = worst.max(resid.abs());
                }
            }
        }
        println!("worst Lyapunov residual {worst:e}");
        assert!(worst < 1e-12);

        // Student = teacher + an independent random walk per channel (AR coefficient 1), in
        // long runs of phase 0: the raw AR estimate is ≈ 1 and must be clamped.
        let mut student = Vec::new();
        let mut teacher = Vec::new();
        let mut phase = Vec::new();
        for q in 0..4 {
            let mut r = rng("walk", q);
            let t = teacher_sequence(5000, &mut r);
            let mut w = [0.0; C];
            let mut s = Vec::with_capacity(t.len());
            for n in 0..5000 {
                for k in 0..C {
                    w[k] += 0.01 * normal(&mut r);
                    s.push((t[n * C + k] + w[k]) as f32);
                }
            }
            student.push(s);
            teacher.push(t.iter().map(|v| *v as f32).collect::<Vec<f32>>());
            phase.push(vec![0u8; 5000]);
        }
        let seqs: Vec<PairSequence<'_>> = (0..4)
            .map(|i| PairSequence {
                student: &student[i],
                teacher: &teacher[i],
                phase: &phase[i],
            })
            .collect();
        let params = ErrorFitParams::default();
        let model = fit(&seqs, C, &params).expect("fit");
        let p = &model.phases[0];
        println!(
            "random walk: ar {:?}, spectral radius {}",
            p.ar, p.spectral_radius
        );
        assert!(p.ar.iter().all(|a| *a == params.max_ar));
        assert_eq!(p.spectral_radius, params.max_ar);
        assert!(p.spectral_radius < 1.0);
        assert!(model.validate().is_ok());

        // The walk's spread over the data, computed here from the deviations themselves
        // (the gain is 1): the residual fit keeps it, the innovations' Lyapunov solution does
        // not (0.99 is not 1, so the clamped process forgets the walk's excursions).
        let spread: Vec<f64> = (0..C)
            .map(|k| {
                let d: Vec<f64> = (0..4)
                    .flat_map(|i| (4..5000).map(move |n| (i, n)))
                    .map(|(i, n)| f64::from(student[i][n * C + k] - teacher[i][n * C + k]))
                    .collect();
                let m = d.iter().sum::<f64>() / d.len() as f64;
                d.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (d.len() - 1) as f64
            })
            .collect();
        let innovations = fit(
            &seqs,
            C,
            &ErrorFitParams {
                stationary: StationaryFit::Innovations,
                ..params.clone()
            },
        )
        .expect("fit");
        for k in 0..C {
            let matched = p.stationary[k * C + k] / spread[k];
            let lyapunov = innovations.phases[0].stationary[k * C + k] / spread[k];
            println!(
                "channel {k}: residual fit {matched:.3}, innovations {lyapunov:.3} of the spread"
            );
            assert!((matched - 1.0).abs() < 0.02, "{k}: {matched}");
            assert!(!(0.5..2.0).contains(&lyapunov), "{k}: {lyapunov}");
        }
        assert_eq!(p.ar, innovations.phases[0].ar);
    }

    #[test]
    fn global_iid_fits_the_pooled_deviation() {
        let data = all_phases_data();
        let params = ErrorFitParams {
            variant: ErrorVariant::GlobalIid,
            ..ErrorFitParams::default()
        };
        let model = fit(&data.pairs(), C, &params).expect("fit");
        // Independent truth: the sample mean and covariance of a − ā over every step.
        let mut n = 0.0;
        let mut sum = [0.0; C];
        for (s, t) in data.student.iter().zip(&data.teacher) {
            for i in 0..s.len() {
                sum[i % C] += f64::from(s[i]) - f64::from(t[i]);
            }
            n += (s.len() / C) as f64;
        }
        let mean: Vec<f64> = sum.iter().map(|v| v / n).collect();
        let mut cov = [0.0; C * C];
        for (s, t) in data.student.iter().zip(&data.teacher) {
            for row in 0..s.len() / C {
                for i in 0..C {
                    for j in 0..C {
                        let di = f64::from(s[row * C + i]) - f64::from(t[row * C + i]) - mean[i];
                        let dj = f64::from(s[row * C + j]) - f64::from(t[row * C + j]) - mean[j];
                        cov[i * C + j] += di * dj / (n - 1.0);
                    }
                }
            }
        }
        for p in &model.phases {
            assert_eq!(p, &model.phases[0]);
            assert_eq!(p.delay, 0);
            assert_eq!(p.gain, vec![1.0; C]);
            assert_eq!(p.ar, vec![0.0; C]);
            assert!(max_abs_diff(&p.bias, &mean) < 1e-12);
            assert!(max_abs_diff(&llt(&p.l), &cov) < 1e-12);
        }
    }

    #[test]
    fn errors_and_pooled_fallback() {
        let data = simulate(&truths(), &[0, 1, 2], 300, 4, 3);
        let pairs = data.pairs();
        let params = ErrorFitParams::default();

        // Phases 3 and 4 never occur: they take the pooled fit with samples = 0, which equals
        // the fit of the same data with every step relabelled as one phase.
        let model = fit(&pairs, C, &params).expect("fit");
        let relabelled: Vec<Vec<u8>> = data.phase.iter().map(|p| vec![0; p.len()]).collect();
        let merged: Vec<PairSequence<'_>> = pairs
            .iter()
            .zip(&relabelled)
            .map(|(p, ph)| PairSequence { phase: ph, ..*p })
            .collect();
        let pooled = fit(&merged, C, &params).expect("fit").phases[0].clone();
        for phase in [3, 4] {
            assert_eq!(
                model.phases[phase],
                PhaseModel {
                    samples: 0,
                    pooled: true,
                    ..pooled.clone()
                }
            );
        }
        for phase in 0..3 {
            assert!(model.phases[phase].samples > 0);
        }

        // Mismatched lengths name the sequence.
        let short = &data.student[1][..data.student[1].len() - 1];
        let mut bad = pairs.clone();
        bad[1].student = short;
        let err = fit(&bad, C, &params).expect_err("length");
        assert!(
            matches!(err, Error::LengthMismatch { sequence: 1, .. }),
            "{err}"
        );
        let mut bad = pairs.clone();
        bad[2].phase = &data.phase[2][1..];
        assert!(matches!(
            fit(&bad, C, &params),
            Err(Error::LengthMismatch { sequence: 2, .. })
        ));
        assert!(matches!(
            fit(&pairs, 2, &params),
            Err(Error::LengthMismatch { sequence: 0, .. })
        ));

        // Phase out of range.
        let mut phases = data.phase[0].clone();
        phases[17] = 5;
        let mut bad = pairs.clone();
        bad[0].phase = &phases;
        let err = fit(&bad, C, &params).expect_err("phase");
        assert!(matches!(
            err,
            Error::PhaseOutOfRange {
                sequence: 0,
                step: 17,
                phase: 5
            }
        ));
        println!("{err}");

        // A phase with some but too few samples takes the pooled fit, with its own count.
        let mut phases = data.phase[0].clone();
        phases[100] = 4;
        let mut bad = pairs.clone();
        bad[0].phase = &phases;
        let rare = fit(&bad, C, &params).expect("a rare phase falls back");
        assert!(rare.phases[3].pooled && rare.phases[3].samples == 0);
        assert_eq!(
            rare.phases[4],
            PhaseModel {
                samples: 1,
                ..rare.phases[3].clone()
            }
        );
        // Isolated steps give the correlated model no consecutive pairs: A = 0, and the phase
        // is fitted exactly as the phase-independent model fits it.
        let mut phases = data.phase[0].clone();
        for n in (50..250).step_by(2) {
            phases[n] = 4;
        }
        let mut bad = pairs.clone();
        bad[0].phase = &phases;
        let isolated = fit(&bad, C, &params).expect("no pairs");
        let p4 = &isolated.phases[4];
        assert_eq!((p4.samples, p4.ar_pairs, p4.pooled), (100, 0, false));
        assert!(p4.ar.iter().all(|&a| a == 0.0) && p4.spectral_radius == 0.0);
        let indep = ErrorFitParams {
            variant: ErrorVariant::PhaseIndependent,
            ..params.clone()
        };
        assert_eq!(&fit(&bad, C, &indep).expect("fit").phases[4], p4);
        assert!(isolated.phases[0].ar_pairs > 0);

        // Too little data: 6 steps leave two samples at n ≥ max_delay, too few even pooled; 4
        // steps leave none.
        let head = |steps: usize| PairSequence {
            student: &data.student[0][..steps * C],
            teacher: &data.teacher[0][..steps * C],
            phase: &data.phase[0][..steps],
        };
        assert!(matches!(
            fit(&[head(6)], C, &params),
            Err(Error::TooFewPooledSamples { samples: 2, .. })
        ));
        let err = fit(&[head(4)], C, &params).expect_err("nothing");
        println!("{err}");
        assert!(matches!(err, Error::TooFewPooledSamples { samples: 0, .. }));
        let global = ErrorFitParams {
            variant: ErrorVariant::GlobalIid,
            ..params.clone()
        };
        assert!(matches!(
            fit(&[head(4)], C, &global),
            Err(Error::TooFewPooledSamples { samples: 4, .. })
        ));

        // Non-finite actions, bad parameters, nothing to fit.
        let mut nan = data.student[0].clone();
        nan[7] = f32::NAN;
        let mut bad = pairs.clone();
        bad[0].student = &nan;
        assert!(matches!(
            fit(&bad, C, &params),
            Err(Error::NonFinite {
                sequence: 0,
                step: 2
            })
        ));
        let unstable = ErrorFitParams {
            max_ar: 1.0,
            ..params.clone()
        };
        assert!(matches!(
            fit(&pairs, C, &unstable),
            Err(Error::InvalidFitParams(_))
        ));
        assert!(matches!(fit(&[], C, &params), Err(Error::NoSequences)));
        assert!(matches!(fit(&pairs, 0, &params), Err(Error::NoChannels)));
    }

    /// Errors in both variables: x = u + e₁, y = g u + b + e₂ with Var(u) = 1 and equal noise
    /// variances σ². Least squares is attenuated to g / (1 + σ²); the major axis recovers g;
    /// the unit gain is 1 with b = mean(y − x).
    #[test]
    fn the_gain_estimators_against_errors_in_both_variables() {
        let (g, b, sigma) = (0.8f64, 0.1f64, 0.6f64);
        let mut r = rng("eiv", 0);
        let mut acc = Bivariate::default();
        let (mut sx, mut sy, n) = (0.0, 0.0, 200_000);
        for _ in 0..n {
            let u = normal(&mut r);
            let x = u + sigma * normal(&mut r);
            let y = g * u + b + sigma * normal(&mut r);
            acc.push(x, y);
            sx += x;
            sy += y;
        }
        let (ls, _, _) = acc.regress(GainFit::LeastSquares);
        let attenuated = g / (1.0 + sigma * sigma);
        assert!(
            (ls - attenuated).abs() < 0.01,
            "least squares {ls} against {attenuated}"
        );
        let (tls, tls_bias, _) = acc.regress(GainFit::Orthogonal);
        assert!((tls - g).abs() < 0.01, "orthogonal {tls} against {g}");
        assert!((tls_bias - b).abs() < 0.01, "orthogonal bias {tls_bias}");
        let (unit, unit_bias, rss) = acc.regress(GainFit::Unit);
        assert_eq!(unit, 1.0);
        assert!((unit_bias - (sy - sx) / n as f64).abs() < 1e-9);
        assert!(rss > 0.0);
    }

    /// The unit-gain fit keeps S = I in every phase and still fits the AR dynamics; scaling
    /// its deviation scales μ, and Σ by the square, and leaves the rest; a calibrated model is
    /// not fitted on pairs.
    #[test]
    fn the_unit_gain_fit_keeps_s_at_one_and_a_scaled_deviation_scales_bias_and_sigma() {
        let data = all_phases_data();
        let model = fit(
            &data.pairs(),
            C,
            &ErrorFitParams {
                variant: ErrorVariant::UnitGain,
                ..ErrorFitParams::default()
            },
        )
        .expect("fit");
        for p in &model.phases {
            assert!(p.gain.iter().all(|&g| g == 1.0));
            assert!(p.ar_pairs > 0 || p.pooled);
        }
        let calibrated = model.with_deviation_scale(0.5, ErrorVariant::Calibrated);
        for (a, b) in model.phases.iter().zip(&calibrated.phases) {
            assert_eq!(a.gain, b.gain);
            assert_eq!(a.ar, b.ar);
            for (x, y) in a.bias.iter().zip(&b.bias) {
                assert_eq!(0.5 * x, *y);
            }
            for (x, y) in a.stationary.iter().zip(&b.stationary) {
                assert!((0.25 * x - y).abs() <= 1e-15 * x.abs().max(1.0));
            }
        }
        assert!(calibrated.validate().is_ok());
        let refused = fit(
            &data.pairs(),
            C,
            &ErrorFitParams {
                variant: ErrorVariant::Calibrated,
                ..ErrorFitParams::default()
            },
        );
        assert!(matches!(refused, Err(Error::InvalidFitParams(_))));
    }
}
