//! The catching world for policies written outside osms: evaluation protocols read from a project's pipeline and store, episode pools stepped in parallel for one batch policy, and the store's teacher, students and scripted catcher as batch policies, row for row the evaluations osms makes itself.
//!
//! A [`Protocol`] is an evaluation stage of the pipeline (`eval_teacher`, `eval_naive@1`,
//! `dev_teacher`, …) read as the rules of a rollout: its world, its condition set, its rollout
//! spec and the seed and name of its random streams. Rollout `i` of a protocol is the rollout the
//! stage itself runs on condition `i` (domain randomisation from its ("item", i) stream, a
//! student's noise from ("policy", i)), whichever policy acts, however many rollouts run at once
//! and whatever order they finish in. A [`Pool`] steps many of them in parallel and hands their
//! observations to one batch policy per control step; [`VectorEpisodes`] keeps a fixed number of
//! episodes running for a vector environment; [`Native`] is a policy of the store (teacher,
//! student, scripted catcher) acting on a pool's or a vector environment's episodes. The Python package (crate
//! `osms-py`) is a thin layer over this crate.

pub mod baseline;
mod error;
pub mod native;
pub mod pool;
pub mod project;
mod slot;
pub mod vector;

pub use error::{ActionProblem, GymError, Result};
pub use native::{Native, NativeKind};
pub use osms_policy::protocol::ScriptedSetup;
pub use pool::{Pool, SingleEpisode, StepInfo, check_action, rows_csv};
pub use project::{Project, Protocol};
pub use vector::{Autoreset, Frame, SubStep, VectorEpisodes};

/// The Wilson score interval of `successes` out of `n` at the normal quantile `z` (95 %,
/// z = 1.96, if `None`), as osms's tables compute it, exact at its ends
/// ([`osms_core::stats::wilson_bounds`]); `None` for `n` = 0 or more successes than trials.
pub fn wilson(successes: usize, n: usize, z: Option<f64>) -> Option<(f64, f64)> {
    let z = z.unwrap_or_else(|| osms_core::stats::normal_quantile(0.975));
    osms_core::stats::wilson_bounds(successes, n, z)
}
