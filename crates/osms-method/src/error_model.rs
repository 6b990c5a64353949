//! The IL-student action-error model of section 4.3 (Eq. 7): fitting it from paired student and
//! teacher actions, applying it step by step during candidate validation, and the Table III
//! comparison metrics.
//!
//! Eq. 7, per phase φ (approach, velocity matching, contact, follow-through, grasping):
//!
//! ```text
//! e_n = A_φ e_{n−1} + L_φ ν_n,            ν_n ~ N(0, I)
//! ã_n = S_φ ā_{n−d_φ} + μ_φ + e_n
//! a_n = clip(ā_n + κ_ε (ã_n − ā_n), −1, 1)
//! ```
//!
//! with `A_φ` and `S_φ` diagonal. Everything is plain `f64` arithmetic in a fixed loop order
//! (sums are accumulated sequence by sequence, step by step, channel by channel), with
//! transcendental functions only from `libm`, so a fit is bit-identical on every platform.
//!
//! Choices the paper leaves open, made here:
//! - The delay grid `0..=max_delay` is compared on one common sample set, the steps
//!   `n ≥ max_delay` of each sequence. Comparing total residual sums over the sets `n ≥ d`
//!   would favour larger delays merely because they drop samples; the final `S`, `μ` are fitted
//!   on the same common set, so a fit loses at most `max_delay` steps per sequence.
//! - A teacher channel with (numerically) no variance in a phase cannot separate gain from
//!   bias; the gain is then fixed to 1 so the whole systematic deviation lands in `μ`.
//! - A phase with fewer regression samples than `channels + 2` (never visited at a step
//!   `n ≥ max_delay`, or visited too rarely to estimate a covariance) falls back to the fit
//!   that pools all phases, marked `pooled` with its own sample count.
//! - The AR coefficients need at least `channels + 2` consecutive same-phase pairs. A phase
//!   with fewer has A = 0 and the residual covariance as its innovation covariance: the
//!   contact phase lasts exactly one control step, so it never has a pair.
//! - Before `d` intended actions exist in a rollout, `ā_{n−d}` is the rollout's first intended
//!   action (the student cannot lag behind a command that was never issued).

// The numerics index several parallel row-major arrays by the same channel index; iterator
// zips would obscure the formulas.
#![allow(clippy::needless_range_loop)]

use osms_core::rng::{StreamRng, normal};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// Catching phases: approach, velocity matching, contact, follow-through, grasping.
pub const N_PHASES: usize = 5;

/// Deviations of the three calibrated models of Table III, plus unperturbed-only validation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorVariant {
    /// No action error: validation by the unperturbed rollout only.
    Unperturbed,
    /// One Gaussian for the deviation `a − ā`, ignoring phase and temporal correlation.
    GlobalIid,
    /// Per-phase delay, gain, bias and Gaussian residual, without temporal correlation.
    PhaseIndependent,
    /// The full model of Eq. 7.
    PhaseCorrelated,
}

/// Settings of [`fit`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ErrorFitParams {
    pub variant: ErrorVariant,
    /// The delay grid is `0..=max_delay` control steps.
    pub max_delay: usize,
    /// κ_ε of Eq. 7, the factor applied to the modeled deviation.
    pub kappa: f64,
    /// The AR coefficients are clamped to `[−max_ar, max_ar]` so that the process is stable
    /// and has a stationary distribution to start from; must lie in `[0, 1)`.
    pub max_ar: f64,
}

impl Default for ErrorFitParams {
    fn default() -> Self {
        Self {
            variant: ErrorVariant::PhaseCorrelated,
            max_delay: 4,
            kappa: 1.5,
            max_ar: 0.99,
        }
    }
}

/// One rollout's pairs, step-major: `student[n*c + k]`, `teacher[n*c + k]`, `phase[n]`.
///
/// `student` is the IL student's executed action, `teacher` the frozen teacher's action
/// queried at the same state.
#[derive(Debug, Clone, Copy)]
pub struct PairSequence<'a> {
    pub student: &'a [f32],
    pub teacher: &'a [f32],
    pub phase: &'a [u8],
}

impl PairSequence<'_> {
    /// Control steps in the rollout.
    pub fn steps(&self) -> usize {
        self.phase.len()
    }
}

/// The parameters of Eq. 7 for one phase.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhaseModel {
    /// d_φ in control steps.
    pub delay: usize,
    /// Diagonal of S_φ.
    pub gain: Vec<f64>,
    /// μ_φ.
    pub bias: Vec<f64>,
    /// diagonal AR(1) coefficients (A = diag(ar))
    pub ar: Vec<f64>,
    /// lower-triangular L (c×c row-major), L Lᵀ = innovation covariance
    pub l: Vec<f64>,
    /// stationary covariance Σ solving Σ = A Σ Aᵀ + L Lᵀ (c×c)
    pub stationary: Vec<f64>,
    /// max |ar_k|, below 1 by construction.
    pub spectral_radius: f64,
    /// Regression samples of this phase (its own, also when it fell back to the pooled fit).
    pub samples: usize,
    /// Consecutive same-phase pairs the AR fit used; 0 means A = 0 (not correlated, or a
    /// phase whose runs never last two steps, like contact).
    pub ar_pairs: usize,
    /// The phase had too few samples of its own and uses the fit over all phases.
    pub pooled: bool,
}

/// A fitted action-error model (Eq. 7).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorModel {
    pub variant: ErrorVariant,
    pub channels: usize,
    /// κ_ε.
    pub kappa: f64,
    /// N_PHASES entries (GlobalIid: the same model repeated; Unperturbed: empty)
    pub phases: Vec<PhaseModel>,
}

/// Why [`fit`] refused its input.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    #[error("the model needs at least one action channel")]
    NoChannels,
    #[error("no sequences to fit")]
    NoSequences,
    #[error("invalid fit parameters: {0}")]
    InvalidParams(String),
    #[error(
        "sequence {sequence}: student has {student} values and teacher {teacher}, \
         but {steps} phases × {channels} channels need {expected}"
    )]
    LengthMismatch {
        sequence: usize,
        student: usize,
        teacher: usize,
        steps: usize,
        channels: usize,
        expected: usize,
    },
    #[error("sequence {sequence}, step {step}: phase {phase} is out of range (phases are 0..=4)")]
    PhaseOutOfRange {
        sequence: usize,
        step: usize,
        phase: u8,
    },
    #[error("sequence {sequence}, step {step}: an action is not finite")]
    NonFinite { sequence: usize, step: usize },
    #[error("all phases pooled: {samples} {what}, at least {needed} needed")]
    TooFewPooledSamples {
        samples: usize,
        needed: usize,
        what: &'static str,
    },
}

/// An [`ErrorModel`] whose shapes do not fit together (e.g. hand-edited or deserialized).
#[derive(Debug, thiserror::Error)]
#[error("malformed action-error model: {0}")]
pub struct MalformedModel(pub String);

impl ErrorModel {
    /// The model of unperturbed-only validation.
    pub fn unperturbed(channels: usize) -> Self {
        Self {
            variant: ErrorVariant::Unperturbed,
            channels,
            kappa: 1.0,
            phases: Vec::new(),
        }
    }

    /// Checks that every phase carries vectors and matrices of `channels` entries and a stable
    /// AR process.
    pub fn validate(&self) -> Result<(), MalformedModel> {
        let c = self.channels;
        if self.variant == ErrorVariant::Unperturbed {
            return if self.phases.is_empty() {
                Ok(())
            } else {
                Err(MalformedModel("an unperturbed model has no phases".into()))
            };
        }
        if self.phases.len() != N_PHASES {
            return Err(MalformedModel(format!(
                "{} phases instead of {N_PHASES}",
                self.phases.len()
            )));
        }
        if !self.kappa.is_finite() {
            return Err(MalformedModel("kappa is not finite".into()));
        }
        for (i, p) in self.phases.iter().enumerate() {
            let shapes_ok = p.gain.len() == c
                && p.bias.len() == c
                && p.ar.len() == c
                && p.l.len() == c * c
                && p.stationary.len() == c * c;
            if !shapes_ok {
                return Err(MalformedModel(format!(
                    "phase {i}: parameter shapes do not match {c} channels"
                )));
            }
            let upper_zero = (0..c).all(|i| (i + 1..c).all(|j| p.l[i * c + j] == 0.0));
            if !upper_zero {
                return Err(MalformedModel(format!(
                    "phase {i}: L is not lower-triangular"
                )));
            }
            if p.ar.iter().any(|a| a.is_nan() || a.abs() >= 1.0) {
                return Err(MalformedModel(format!(
                    "phase {i}: an AR coefficient is not inside (−1, 1)"
                )));
            }
        }
        Ok(())
    }

    fn max_delay(&self) -> usize {
        self.phases.iter().map(|p| p.delay).max().unwrap_or(0)
    }
}

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
) -> Result<ErrorModel, FitError> {
    if !params.kappa.is_finite() {
        return Err(FitError::InvalidParams(format!(
            "kappa {} is not finite",
            params.kappa
        )));
    }
    if !(0.0..1.0).contains(&params.max_ar) {
        return Err(FitError::InvalidParams(format!(
            "max_ar {} is not in [0, 1)",
            params.max_ar
        )));
    }
    if channels == 0 {
        return Err(FitError::NoChannels);
    }
    if sequences.is_empty() {
        return Err(FitError::NoSequences);
    }
    check_sequences(sequences, channels)?;

    let phases = match params.variant {
        ErrorVariant::Unperturbed => Vec::new(),
        ErrorVariant::GlobalIid => vec![fit_global(sequences, channels)?; N_PHASES],
        ErrorVariant::PhaseIndependent | ErrorVariant::PhaseCorrelated => {
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
                                return Err(FitError::TooFewPooledSamples {
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
                                return Err(FitError::TooFewPooledSamples {
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

fn check_sequences(sequences: &[PairSequence<'_>], c: usize) -> Result<(), FitError> {
    for (i, s) in sequences.iter().enumerate() {
        let steps = s.steps();
        let expected = steps * c;
        if s.student.len() != expected || s.teacher.len() != expected {
            return Err(FitError::LengthMismatch {
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
                return Err(FitError::PhaseOutOfRange {
                    sequence: i,
                    step: n,
                    phase: s.phase[n],
                });
            }
            let row = n * c..(n + 1) * c;
            let finite = s.student[row.clone()].iter().all(|v| v.is_finite())
                && s.teacher[row].iter().all(|v| v.is_finite());
            if !finite {
                return Err(FitError::NonFinite {
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

    /// Least-squares `(gain, bias, residual sum of squares)` of `y ≈ gain·x + bias`.
    fn regress(&self) -> (f64, f64, f64) {
        // A teacher channel that barely moves cannot tell gain from bias (see module docs).
        let gain = if self.cxx > 1e-12 * self.n as f64 {
            self.cxy / self.cxx
        } else {
            1.0
        };
        let bias = self.my - gain * self.mx;
        let rss = (self.cyy - 2.0 * gain * self.cxy + gain * gain * self.cxx).max(0.0);
        (gain, bias, rss)
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
            let (g, b, rss) = a.regress();
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
    if params.variant == ErrorVariant::PhaseCorrelated {
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
    let mut cov = Covariance::new(c);
    let mut u = vec![0.0; c];
    for s in sequences {
        if ar_pairs > 0 {
            for n in start + 1..s.steps() {
                if !(group.contains(s.phase[n]) && group.contains(s.phase[n - 1])) {
                    continue;
                }
                for (k, uk) in u.iter_mut().enumerate() {
                    *uk = residual(s, n, k) - ar[k] * residual(s, n - 1, k);
                }
                cov.push(&u);
            }
        } else {
            for n in start..s.steps() {
                if !group.contains(s.phase[n]) {
                    continue;
                }
                for (k, uk) in u.iter_mut().enumerate() {
                    *uk = residual(s, n, k);
                }
                cov.push(&u);
            }
        }
    }
    let l = robust_cholesky(&cov.covariance(), c);
    GroupFit::Model(PhaseModel {
        ar_pairs,
        ..assemble(delay, gain, bias, ar, l, samples)
    })
}

/// Table III's global i.i.d. Gaussian: one mean and covariance of `a − ā` over every step.
fn fit_global(sequences: &[PairSequence<'_>], c: usize) -> Result<PhaseModel, FitError> {
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
        return Err(FitError::TooFewPooledSamples {
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
fn assemble(
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

/// L Lᵀ for a c×c row-major L.
fn lower_times_transpose(l: &[f64], c: usize) -> Vec<f64> {
    let mut q = vec![0.0; c * c];
    for i in 0..c {
        for j in 0..c {
            let mut s = 0.0;
            for m in 0..c {
                s += l[i * c + m] * l[j * c + m];
            }
            q[i * c + j] = s;
        }
    }
    q
}

/// Plain Cholesky factor of a symmetric matrix, `None` unless it is numerically positive
/// definite.
fn cholesky(a: &[f64], c: usize) -> Option<Vec<f64>> {
    let mut l = vec![0.0; c * c];
    for i in 0..c {
        for j in 0..=i {
            let mut s = a[i * c + j];
            for m in 0..j {
                s -= l[i * c + m] * l[j * c + m];
            }
            if i == j {
                if s.is_nan() || s <= 0.0 || !s.is_finite() {
                    return None;
                }
                l[i * c + i] = s.sqrt();
            } else {
                l[i * c + j] = s / l[j * c + j];
            }
        }
    }
    Some(l)
}

/// Cholesky factor of a covariance that may be singular (a channel the student copies
/// exactly, collinear channels). A ridge of 1e-12·trace/c, then ten times larger each retry,
/// is added to the diagonal until the factorization succeeds: it is far below any physically
/// meaningful action noise but lets the AR process be driven by a valid L. A zero matrix gives
/// a zero L.
fn robust_cholesky(a: &[f64], c: usize) -> Vec<f64> {
    if let Some(l) = cholesky(a, c) {
        return l;
    }
    let trace: f64 = (0..c).map(|k| a[k * c + k]).sum();
    if trace.is_nan() || trace <= 0.0 {
        return vec![0.0; c * c];
    }
    let mut ridge = 1e-12 * trace / c as f64;
    // A ridge of trace/c·10 exceeds the largest eigenvalue of a PSD matrix, so 14 attempts
    // always suffice for a covariance.
    for _ in 0..16 {
        let mut b = a.to_vec();
        for k in 0..c {
            b[k * c + k] += ridge;
        }
        if let Some(l) = cholesky(&b, c) {
            return l;
        }
        ridge *= 10.0;
    }
    // Unreachable for a covariance; keep the per-channel scale rather than fail.
    let mut l = vec![0.0; c * c];
    for k in 0..c {
        l[k * c + k] = a[k * c + k].max(0.0).sqrt();
    }
    l
}

/// Eq. 7 applied step by step within one rollout.
///
/// Every step of a perturbed model draws exactly `channels` standard normals, so rollouts that
/// share a stream share their noise step for step (common random numbers). A clone continues
/// exactly where the original is, so a perturbed rollout can branch.
#[derive(Clone)]
pub struct Perturber<'m> {
    model: &'m ErrorModel,
    /// Cholesky factors of each phase's stationary covariance, for the first draw of e.
    stationary_l: Vec<Vec<f64>>,
    /// Intended actions, most recent first, as deep as the longest delay needs.
    history: VecDeque<Vec<f64>>,
    depth: usize,
    e: Vec<f64>,
    started: bool,
    phase: Option<u8>,
    nu: Vec<f64>,
}

impl<'m> Perturber<'m> {
    /// # Panics
    /// If the model fails [`ErrorModel::validate`].
    pub fn new(model: &'m ErrorModel) -> Self {
        if let Err(e) = model.validate() {
            panic!("{e}");
        }
        let c = model.channels;
        let stationary_l = model
            .phases
            .iter()
            .map(|p| robust_cholesky(&p.stationary, c))
            .collect();
        Self {
            model,
            stationary_l,
            history: VecDeque::new(),
            depth: model.max_delay() + 1,
            e: vec![0.0; c],
            started: false,
            phase: None,
            nu: vec![0.0; c],
        }
    }

    /// Forgets the rollout so far; the next step starts a new one.
    pub fn reset(&mut self) {
        self.history.clear();
        self.e.iter_mut().for_each(|v| *v = 0.0);
        self.started = false;
        self.phase = None;
    }

    /// The phase of the last step, if any.
    pub fn phase(&self) -> Option<u8> {
        self.phase
    }

    /// The current AR state e_n (zero before the first step).
    pub fn state(&self) -> &[f64] {
        &self.e
    }

    /// The executed action for intended ā_n in phase φ_n: Eq. 7's
    /// `clip(ā_n + κ_ε (ã_n − ā_n), −1, 1)`.
    ///
    /// e is drawn from the phase's stationary distribution at the first step, then follows
    /// the AR recursion with the current phase's A and L (at a phase change e carries over).
    /// Unperturbed returns ā unchanged and draws nothing.
    ///
    /// # Panics
    /// If `intended` does not have `channels` entries or `phase ≥ N_PHASES`.
    pub fn step(&mut self, intended: &[f64], phase: u8, rng: &mut StreamRng) -> Vec<f64> {
        if self.model.variant == ErrorVariant::Unperturbed {
            self.check(intended, phase);
            self.phase = Some(phase);
            return intended.to_vec();
        }
        let kappa = self.model.kappa;
        let modeled = self.step_modeled(intended, phase, rng);
        intended
            .iter()
            .zip(&modeled)
            .map(|(a, m)| (a + kappa * (m - a)).clamp(-1.0, 1.0))
            .collect()
    }

    /// The modeled student action ã_n of Eq. 7 (before κ_ε and clipping); advances the state
    /// exactly like [`Perturber::step`].
    ///
    /// # Panics
    /// As [`Perturber::step`].
    pub fn step_modeled(&mut self, intended: &[f64], phase: u8, rng: &mut StreamRng) -> Vec<f64> {
        self.check(intended, phase);
        self.phase = Some(phase);
        if self.model.variant == ErrorVariant::Unperturbed {
            return intended.to_vec();
        }
        let c = self.model.channels;
        let p = &self.model.phases[usize::from(phase)];

        self.history.push_front(intended.to_vec());
        self.history.truncate(self.depth);

        for v in self.nu.iter_mut() {
            *v = normal(rng);
        }
        let (factor, carry): (&[f64], bool) = if self.started {
            (&p.l, true)
        } else {
            (&self.stationary_l[usize::from(phase)], false)
        };
        let mut next = vec![0.0; c];
        for (i, out) in next.iter_mut().enumerate() {
            let mut s = if carry { p.ar[i] * self.e[i] } else { 0.0 };
            for (j, nu) in self.nu.iter().enumerate().take(i + 1) {
                s += factor[i * c + j] * nu;
            }
            *out = s;
        }
        self.e = next;
        self.started = true;

        // Before d commands exist the oldest one stands in (see module docs).
        let lagged = self
            .history
            .get(p.delay)
            .or_else(|| self.history.back())
            .map_or(intended, |v| v.as_slice());
        (0..c)
            .map(|k| p.gain[k] * lagged[k] + p.bias[k] + self.e[k])
            .collect()
    }

    fn check(&self, intended: &[f64], phase: u8) {
        assert_eq!(
            intended.len(),
            self.model.channels,
            "intended action has the wrong number of channels"
        );
        assert!(
            usize::from(phase) < N_PHASES,
            "phase {phase} out of range (phases are 0..=4)"
        );
    }
}

/// Table III metrics: simulate the model's deviations ã − ā (before κ and clipping, i.e. with
/// κ = 1 and no clip) on the recorded teacher sequences (phases as recorded, fresh ν from
/// `rng`) and compare with the observed deviations a − ā, per phase and channel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Table3Metrics {
    /// mean over (phase, channel) of (|m_sim − m_obs| + |s_sim − s_obs|) / s_obs  (s = std;
    /// skip cells with s_obs < 1e-9 or < 2 samples)
    pub moment_error: f64,
    /// mean over (phase, channel) of |ρ1_sim − ρ1_obs|, ρ1 = lag-1 autocorrelation of the
    /// deviation within runs of consecutive steps of that phase
    pub lag1_error: f64,
    /// (phase, channel) cells averaged in `moment_error`; 0 means the metric is 0 by default.
    pub moment_cells: usize,
    /// (phase, channel) cells averaged in `lag1_error` (cells with consecutive same-phase
    /// pairs and s_obs ≥ 1e-9).
    pub lag1_cells: usize,
}

/// Computes [`Table3Metrics`]. Each sequence gets a fresh rollout state (e drawn from the
/// stationary distribution at its first step); sequences consume `rng` in order.
///
/// ρ1 of a cell is the mean lag-1 product over consecutive same-phase pairs divided by the
/// variance over all the phase's steps (both about the phase mean), so many short runs do not
/// bias it towards zero. A simulated deviation with no variance (Unperturbed) has ρ1 = 0.
///
/// # Panics
/// If the model fails [`ErrorModel::validate`], or a sequence's lengths or phases do not match
/// the model (checked as in [`fit`]).
pub fn table3_metrics(
    model: &ErrorModel,
    sequences: &[PairSequence<'_>],
    rng: &mut StreamRng,
) -> Table3Metrics {
    let c = model.channels;
    if let Err(e) = check_sequences(sequences, c) {
        panic!("{e}");
    }
    let mut perturber = Perturber::new(model);
    let mut observed = Vec::with_capacity(sequences.len());
    let mut simulated = Vec::with_capacity(sequences.len());
    let mut intended = vec![0.0; c];
    for s in sequences {
        perturber.reset();
        let mut obs = Vec::with_capacity(s.student.len());
        let mut sim = Vec::with_capacity(s.student.len());
        for n in 0..s.steps() {
            for k in 0..c {
                intended[k] = f64::from(s.teacher[n * c + k]);
                obs.push(f64::from(s.student[n * c + k]) - intended[k]);
            }
            let modeled = perturber.step_modeled(&intended, s.phase[n], rng);
            sim.extend(modeled.iter().zip(&intended).map(|(m, a)| m - a));
        }
        observed.push(obs);
        simulated.push(sim);
    }
    let obs = cell_stats(&observed, sequences, c);
    let sim = cell_stats(&simulated, sequences, c);

    let (mut moment_sum, mut moment_cells) = (0.0, 0usize);
    let (mut lag_sum, mut lag1_cells) = (0.0, 0usize);
    for phase in 0..N_PHASES {
        if obs.count[phase] < 2 {
            continue;
        }
        for k in 0..c {
            let i = phase * c + k;
            let s_obs = obs.std[i];
            if s_obs.is_nan() || s_obs < 1e-9 {
                continue;
            }
            moment_sum += ((sim.mean[i] - obs.mean[i]).abs() + (sim.std[i] - s_obs).abs()) / s_obs;
            moment_cells += 1;
            if let Some(rho_obs) = obs.rho1[i] {
                lag_sum += (sim.rho1[i].unwrap_or(0.0) - rho_obs).abs();
                lag1_cells += 1;
            }
        }
    }
    Table3Metrics {
        moment_error: if moment_cells > 0 {
            moment_sum / moment_cells as f64
        } else {
            0.0
        },
        lag1_error: if lag1_cells > 0 {
            lag_sum / lag1_cells as f64
        } else {
            0.0
        },
        moment_cells,
        lag1_cells,
    }
}

/// Per (phase, channel) mean, standard deviation (divisor n − 1) and lag-1 autocorrelation.
struct CellStats {
    count: Vec<usize>,
    mean: Vec<f64>,
    std: Vec<f64>,
    rho1: Vec<Option<f64>>,
}

fn cell_stats(devs: &[Vec<f64>], sequences: &[PairSequence<'_>], c: usize) -> CellStats {
    let cells = N_PHASES * c;
    let mut count = vec![0usize; N_PHASES];
    let mut sum = vec![0.0; cells];
    for (dev, s) in devs.iter().zip(sequences) {
        for n in 0..s.steps() {
            let p = usize::from(s.phase[n]);
            count[p] += 1;
            for k in 0..c {
                sum[p * c + k] += dev[n * c + k];
            }
        }
    }
    let mean: Vec<f64> = (0..cells)
        .map(|i| sum[i] / count[i / c].max(1) as f64)
        .collect();
    let mut ss = vec![0.0; cells];
    let mut lag = vec![0.0; cells];
    let mut pairs = [0usize; N_PHASES];
    for (dev, s) in devs.iter().zip(sequences) {
        for n in 0..s.steps() {
            let p = usize::from(s.phase[n]);
            let paired = n > 0 && s.phase[n - 1] == s.phase[n];
            if paired {
                pairs[p] += 1;
            }
            for k in 0..c {
                let i = p * c + k;
                let x = dev[n * c + k] - mean[i];
                ss[i] += x * x;
                if paired {
                    lag[i] += x * (dev[(n - 1) * c + k] - mean[i]);
                }
            }
        }
    }
    let mut std = vec![0.0; cells];
    let mut rho1 = vec![None; cells];
    for i in 0..cells {
        let (n, np) = (count[i / c], pairs[i / c]);
        if n >= 2 {
            std[i] = (ss[i] / (n - 1) as f64).sqrt();
        }
        let var = ss[i] / n.max(1) as f64;
        if np > 0 && var > 1e-18 {
            rho1[i] = Some((lag[i] / np as f64) / var);
        }
    }
    CellStats {
        count,
        mean,
        std,
        rho1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use osms_core::rng::stream;

    const C: usize = 3;

    fn rng(name: &str, i: u64) -> StreamRng {
        stream(7, "error_model_test", name, i)
    }

    /// Ground-truth parameters of one phase, with a full lower-triangular L.
    struct Truth {
        d: usize,
        s: [f64; C],
        mu: [f64; C],
        ar: [f64; C],
        l: [f64; C * C],
    }

    fn truths() -> Vec<Truth> {
        vec![
            Truth {
                d: 0,
                s: [1.0, 0.9, 1.1],
                mu: [0.02, -0.03, 0.0],
                ar: [0.8, 0.5, 0.9],
                l: [0.05, 0.0, 0.0, 0.02, 0.04, 0.0, -0.01, 0.01, 0.03],
            },
            Truth {
                d: 2,
                s: [0.8, 1.0, 0.95],
                mu: [0.0, 0.05, -0.02],
                ar: [0.6, 0.9, 0.3],
                l: [0.03, 0.0, 0.0, 0.01, 0.05, 0.0, 0.0, -0.02, 0.04],
            },
            Truth {
                d: 4,
                s: [1.2, 0.7, 1.0],
                mu: [-0.04, 0.0, 0.03],
                ar: [0.95, 0.7, 0.0],
                l: [0.02, 0.0, 0.0, 0.0, 0.03, 0.0, 0.01, 0.01, 0.06],
            },
            Truth {
                d: 1,
                s: [1.0, 1.0, 0.85],
                mu: [0.01, 0.01, 0.01],
                ar: [0.2, -0.4, 0.85],
                l: [0.06, 0.0, 0.0, 0.03, 0.03, 0.0, 0.0, 0.0, 0.02],
            },
            Truth {
                d: 3,
                s: [0.9, 1.15, 1.05],
                mu: [0.0, -0.05, 0.02],
                ar: [0.7, 0.7, 0.7],
                l: [0.04, 0.0, 0.0, -0.02, 0.04, 0.0, 0.02, 0.0, 0.03],
            },
        ]
    }

    fn llt(l: &[f64]) -> Vec<f64> {
        lower_times_transpose(l, l.len().isqrt())
    }

    /// Smooth teacher actions in (−1, 1): a sinusoid plus an AR(0.9) wander, squashed.
    fn teacher_sequence(steps: usize, r: &mut StreamRng) -> Vec<f64> {
        let mut x = [0.0; C];
        let mut out = Vec::with_capacity(steps * C);
        for n in 0..steps {
            for (k, xk) in x.iter_mut().enumerate() {
                *xk = 0.9 * *xk + 0.15 * normal(r);
                let wave = 0.3 * libm::sin(0.05 * n as f64 + k as f64);
                out.push(0.8 * libm::tanh(wave + *xk));
            }
        }
        out
    }

    struct Data {
        student: Vec<Vec<f32>>,
        teacher: Vec<Vec<f32>>,
        phase: Vec<Vec<u8>>,
    }

    impl Data {
        fn pairs(&self) -> Vec<PairSequence<'_>> {
            (0..self.phase.len())
                .map(|i| PairSequence {
                    student: &self.student[i],
                    teacher: &self.teacher[i],
                    phase: &self.phase[i],
                })
                .collect()
        }
    }

    /// Student actions generated directly from Eq. 7 (κ = 1, no clip) with the given truths;
    /// each sequence visits `phases` in runs of `run` steps. e starts at zero and carries over
    /// phase changes; a teacher warm-up of 8 steps supplies ā_{n−d} at the first steps.
    fn simulate(truths: &[Truth], phases: &[u8], run: usize, sequences: usize, seed: u64) -> Data {
        let warm = 8;
        let mut data = Data {
            student: Vec::new(),
            teacher: Vec::new(),
            phase: Vec::new(),
        };
        for q in 0..sequences {
            let mut r = rng("simulate", seed * 1000 + q as u64);
            let steps = run * phases.len();
            let teacher = teacher_sequence(steps + warm, &mut r);
            let mut e = [0.0; C];
            let mut student = Vec::with_capacity(steps * C);
            let mut phase = Vec::with_capacity(steps);
            for n in 0..steps {
                let ph = phases[n / run];
                let t = &truths[usize::from(ph)];
                let nu: Vec<f64> = (0..C).map(|_| normal(&mut r)).collect();
                for i in 0..C {
                    let mut s = t.ar[i] * e[i];
                    for j in 0..=i {
                        s += t.l[i * C + j] * nu[j];
                    }
                    e[i] = s;
                }
                for k in 0..C {
                    let lagged = teacher[(n + warm - t.d) * C + k];
                    student.push((t.s[k] * lagged + t.mu[k] + e[k]) as f32);
                }
                phase.push(ph);
            }
            data.student.push(student);
            data.teacher.push(
                teacher[warm * C..]
                    .iter()
                    .map(|v| *v as f32)
                    .collect::<Vec<f32>>(),
            );
            data.phase.push(phase);
        }
        data
    }

    fn all_phases_data() -> Data {
        // 40 sequences × 500 steps per phase = 20k steps per phase.
        simulate(&truths(), &[0, 1, 2, 3, 4], 500, 40, 1)
    }

    fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
    }

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
    }

    fn hand_model(variant: ErrorVariant, kappa: f64, p: PhaseModel) -> ErrorModel {
        ErrorModel {
            variant,
            channels: C,
            kappa,
            phases: vec![p; N_PHASES],
        }
    }

    fn hand_phase() -> PhaseModel {
        assemble(
            0,
            vec![0.9, 1.1, 1.0],
            vec![0.05, -0.02, 0.0],
            vec![0.8, 0.3, -0.5],
            vec![0.03, 0.0, 0.0, 0.01, 0.02, 0.0, -0.01, 0.0, 0.04],
            0,
        )
    }

    #[test]
    fn perturber_moments_match_the_model() {
        let model = hand_model(ErrorVariant::PhaseCorrelated, 1.0, hand_phase());
        let p = &model.phases[0];
        let intended = [0.3, -0.2, 0.1];
        let steps = 200_000;
        let mut r = rng("moments", 0);
        let mut pert = Perturber::new(&model);
        let mut dev: Vec<Vec<f64>> = (0..C).map(|_| Vec::with_capacity(steps)).collect();
        for _ in 0..steps {
            let m = pert.step_modeled(&intended, 2, &mut r);
            for k in 0..C {
                dev[k].push(m[k] - intended[k]);
            }
        }
        for k in 0..C {
            let x = &dev[k];
            let n = x.len() as f64;
            let mean = x.iter().sum::<f64>() / n;
            let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
            let lag = x
                .windows(2)
                .map(|w| (w[0] - mean) * (w[1] - mean))
                .sum::<f64>()
                / (n - 1.0)
                / var;
            let want_mean = (p.gain[k] - 1.0) * intended[k] + p.bias[k];
            let want_var = p.stationary[k * C + k];
            println!(
                "channel {k}: mean {mean:.5} (model {want_mean:.5}), var {var:.6} (model \
                 {want_var:.6}), lag-1 {lag:.4} (model {:.4})",
                p.ar[k]
            );
            let sd = want_var.sqrt();
            assert!((mean - want_mean).abs() < 0.03 * sd.max(0.01) + 3e-4);
            assert!((var / want_var - 1.0).abs() < 0.03);
            assert!((lag - p.ar[k]).abs() < 0.01);
        }

        // The first draw comes from the stationary distribution: across many fresh rollouts the
        // step-0 deviation has variance Σ_kk.
        let mut first = vec![Vec::new(); C];
        for i in 0..20_000 {
            let mut r = rng("first", i);
            let mut pert = Perturber::new(&model);
            let m = pert.step_modeled(&intended, 0, &mut r);
            for k in 0..C {
                first[k].push(m[k] - intended[k]);
            }
        }
        for k in 0..C {
            let n = first[k].len() as f64;
            let mean = first[k].iter().sum::<f64>() / n;
            let var = first[k]
                .iter()
                .map(|v| (v - mean) * (v - mean))
                .sum::<f64>()
                / n;
            let want = p.stationary[k * C + k];
            println!("step 0, channel {k}: var {var:.6} (stationary {want:.6})");
            assert!((var / want - 1.0).abs() < 0.05);
        }
    }

    #[test]
    fn perturber_kappa_clip_delay_unperturbed_and_determinism() {
        let base = hand_model(ErrorVariant::PhaseCorrelated, 1.0, hand_phase());
        let scaled = hand_model(ErrorVariant::PhaseCorrelated, 2.5, hand_phase());
        let intended = [0.1, 0.0, -0.1];
        let (mut r1, mut r2) = (rng("kappa", 0), rng("kappa", 0));
        let (mut p1, mut p2) = (Perturber::new(&base), Perturber::new(&scaled));
        let mut worst = 0.0f64;
        for _ in 0..1000 {
            let a1 = p1.step(&intended, 1, &mut r1);
            let a2 = p2.step(&intended, 1, &mut r2);
            for k in 0..C {
                worst = worst.max(((a2[k] - intended[k]) - 2.5 * (a1[k] - intended[k])).abs());
            }
        }
        println!("κ scaling residual {worst:e}");
        assert!(worst < 1e-12);

        // A bias far outside the action range is clipped.
        let mut far = hand_phase();
        far.bias = vec![5.0, -5.0, 0.0];
        let clipped = hand_model(ErrorVariant::PhaseCorrelated, 1.5, far);
        let mut p = Perturber::new(&clipped);
        let mut r = rng("clip", 0);
        for _ in 0..100 {
            let a = p.step(&[0.9, -0.9, 0.0], 0, &mut r);
            assert_eq!(a[0], 1.0);
            assert_eq!(a[1], -1.0);
            assert!(a.iter().all(|v| (-1.0..=1.0).contains(v)));
        }

        // A delay of 2 reproduces the intended action of two steps back (noise-free model);
        // before that the first action stands in.
        let mut delayed = assemble(2, vec![1.0; C], vec![0.0; C], vec![0.0; C], vec![0.0; 9], 0);
        delayed.samples = 1;
        let dm = hand_model(ErrorVariant::PhaseIndependent, 1.0, delayed);
        let mut p = Perturber::new(&dm);
        let mut r = rng("delay", 0);
        let inputs: Vec<[f64; C]> = (0..6).map(|n| [0.1 * n as f64, 0.0, -0.1]).collect();
        let outs: Vec<Vec<f64>> = inputs
            .iter()
            .map(|a| p.step_modeled(a, 3, &mut r))
            .collect();
        for n in 0..6usize {
            let src = inputs[n.saturating_sub(2)];
            assert_eq!(outs[n], src.to_vec(), "step {n}");
        }

        // Unperturbed returns ā and draws nothing.
        let none = ErrorModel::unperturbed(C);
        let mut p = Perturber::new(&none);
        let mut r = rng("none", 0);
        let a = p.step(&[0.4, 2.0, -0.3], 4, &mut r);
        assert_eq!(a, vec![0.4, 2.0, -0.3]);
        assert_eq!(r, rng("none", 0));

        // Same stream, same output.
        let run = |i| {
            let mut p = Perturber::new(&base);
            let mut r = rng("same", i);
            (0..50)
                .map(|n| p.step(&intended, (n / 10) as u8, &mut r))
                .collect::<Vec<_>>()
        };
        assert_eq!(run(0), run(0));
        assert_ne!(run(0), run(1));
    }

    #[test]
    fn phase_change_keeps_the_state() {
        // Phase 1 is noise-free with A = 0.5 I: after a switch from phase 0, e must be half of
        // phase 0's last state rather than a fresh stationary draw.
        let mut model2 = hand_model(ErrorVariant::PhaseCorrelated, 1.0, hand_phase());
        let mut carry = hand_phase();
        carry.ar = vec![0.5; C];
        carry.l = vec![0.0; C * C];
        model2.phases[1] = assemble(0, carry.gain, carry.bias, carry.ar, carry.l, 0);
        let mut p = Perturber::new(&model2);
        let mut r = rng("switch", 0);
        p.step_modeled(&[0.0; C], 0, &mut r);
        let e0 = p.state().to_vec();
        p.step_modeled(&[0.0; C], 1, &mut r);
        let want: Vec<f64> = e0.iter().map(|v| 0.5 * v).collect();
        assert_eq!(p.state(), want.as_slice());
        assert_eq!(p.phase(), Some(1));
    }

    #[test]
    fn table3_metrics_rank_models() {
        let data = all_phases_data();
        let pairs = data.pairs();
        let truth = ErrorModel {
            variant: ErrorVariant::PhaseCorrelated,
            channels: C,
            kappa: 1.0,
            phases: truths()
                .into_iter()
                .map(|t| {
                    assemble(
                        t.d,
                        t.s.to_vec(),
                        t.mu.to_vec(),
                        t.ar.to_vec(),
                        t.l.to_vec(),
                        1,
                    )
                })
                .collect(),
        };
        let m_truth = table3_metrics(&truth, &pairs, &mut rng("t3", 0));
        let variants = [
            ErrorVariant::PhaseCorrelated,
            ErrorVariant::PhaseIndependent,
            ErrorVariant::GlobalIid,
            ErrorVariant::Unperturbed,
        ];
        let mut fitted = Vec::new();
        for v in variants {
            let params = ErrorFitParams {
                variant: v,
                ..ErrorFitParams::default()
            };
            let model = fit(&pairs, C, &params).expect("fit");
            let m = table3_metrics(&model, &pairs, &mut rng("t3", 1));
            println!("{v:?}: {m:?}");
            fitted.push(m);
        }
        println!("truth: {m_truth:?}");
        assert_eq!(m_truth.moment_cells, N_PHASES * C);
        assert_eq!(m_truth.lag1_cells, N_PHASES * C);
        assert!(m_truth.moment_error < 0.1);
        assert!(m_truth.lag1_error < 0.03);
        let (corr, indep, global, none) = (&fitted[0], &fitted[1], &fitted[2], &fitted[3]);
        assert!(corr.moment_error < 0.1);
        assert!(corr.lag1_error < 0.03);
        // The teacher's own autocorrelation leaks into S ā_{n−d} − ā_n, so dropping the AR
        // term does not zero the simulated ρ1; it still misses it by far.
        assert!(indep.lag1_error > 0.1);
        assert!(indep.lag1_error > 10.0 * corr.lag1_error);
        assert!(global.lag1_error > 0.3);
        assert!(global.moment_error > corr.moment_error);
        assert!(none.moment_error > global.moment_error);
        // Same stream, same metrics.
        assert_eq!(m_truth, table3_metrics(&truth, &pairs, &mut rng("t3", 0)));
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
            matches!(err, FitError::LengthMismatch { sequence: 1, .. }),
            "{err}"
        );
        let mut bad = pairs.clone();
        bad[2].phase = &data.phase[2][1..];
        assert!(matches!(
            fit(&bad, C, &params),
            Err(FitError::LengthMismatch { sequence: 2, .. })
        ));
        assert!(matches!(
            fit(&pairs, 2, &params),
            Err(FitError::LengthMismatch { sequence: 0, .. })
        ));

        // Phase out of range.
        let mut phases = data.phase[0].clone();
        phases[17] = 5;
        let mut bad = pairs.clone();
        bad[0].phase = &phases;
        let err = fit(&bad, C, &params).expect_err("phase");
        assert!(matches!(
            err,
            FitError::PhaseOutOfRange {
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
            Err(FitError::TooFewPooledSamples { samples: 2, .. })
        ));
        let err = fit(&[head(4)], C, &params).expect_err("nothing");
        println!("{err}");
        assert!(matches!(
            err,
            FitError::TooFewPooledSamples { samples: 0, .. }
        ));
        let global = ErrorFitParams {
            variant: ErrorVariant::GlobalIid,
            ..params.clone()
        };
        assert!(matches!(
            fit(&[head(4)], C, &global),
            Err(FitError::TooFewPooledSamples { samples: 4, .. })
        ));

        // Non-finite actions, bad parameters, nothing to fit.
        let mut nan = data.student[0].clone();
        nan[7] = f32::NAN;
        let mut bad = pairs.clone();
        bad[0].student = &nan;
        assert!(matches!(
            fit(&bad, C, &params),
            Err(FitError::NonFinite {
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
            Err(FitError::InvalidParams(_))
        ));
        assert!(matches!(fit(&[], C, &params), Err(FitError::NoSequences)));
        assert!(matches!(fit(&pairs, 0, &params), Err(FitError::NoChannels)));
    }

    #[test]
    fn serde_round_trip_and_defaults() {
        let params: ErrorFitParams = serde_json::from_str("{}").expect("defaults");
        assert_eq!(params, ErrorFitParams::default());
        let params: ErrorFitParams =
            serde_json::from_str(r#"{"variant":"global_iid","kappa":2.0}"#).expect("partial");
        assert_eq!(params.variant, ErrorVariant::GlobalIid);
        assert_eq!(params.max_delay, 4);
        assert!(serde_json::from_str::<ErrorFitParams>(r#"{"kapa":2.0}"#).is_err());
        let model = hand_model(ErrorVariant::PhaseCorrelated, 1.5, hand_phase());
        let text = serde_json::to_string(&model).expect("serialize");
        let back: ErrorModel = serde_json::from_str(&text).expect("deserialize");
        assert_eq!(back, model);
    }
}
