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

mod fit;
mod model;
mod perturb;
mod table3;
#[cfg(test)]
pub(crate) mod testdata;

pub use fit::fit;
pub use model::{
    ErrorFitParams, ErrorModel, ErrorVariant, N_PHASES, PAPER_KAPPA, PairSequence, PhaseModel,
    StationaryFit,
};
pub use perturb::Perturber;
pub use table3::{Table3Bootstrap, Table3Metrics, table3_bootstrap, table3_metrics};
