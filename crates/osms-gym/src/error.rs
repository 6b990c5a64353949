//! What can go wrong between a caller and the world: a project that cannot be read, a stage or
//! artifact that is not there, a condition out of range, an action the world cannot run.

use std::fmt;

pub type Result<T, E = GymError> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum GymError {
    /// The pipeline, its profile or the store cannot be read.
    #[error("{0}")]
    Project(String),
    #[error("`{name}` is not {what} of {pipeline}\nhint: valid here: {known}")]
    UnknownStage {
        name: String,
        /// What was expected: `a stage`, `a condition set`, `an evaluation stage`.
        what: &'static str,
        pipeline: String,
        known: String,
    },
    /// The hint names the project the call opened, so it builds into the store the call reads
    /// from wherever it runs (`osms` is the command the package installs; `./osms` in a
    /// checkout is the same).
    #[error(
        "`{instance}` has no current build in {store} under profile `{profile}` ({reason})\nhint: `osms make {instance} --profile {profile} --pipeline {pipeline} --store {store}` builds it (the `osms` command comes with the package)"
    )]
    NotBuilt {
        instance: String,
        pipeline: String,
        store: String,
        profile: String,
        reason: String,
    },
    #[error("`{name}` is a `{kind}` stage: {expected}")]
    WrongKind {
        name: String,
        kind: String,
        expected: String,
    },
    #[error("cannot read `{instance}` from the store: {message}")]
    Decode { instance: String, message: String },
    #[error(
        "condition {index} is out of range: `{conditions}` has {n} conditions (valid: 0 to {last})",
        last = .n.saturating_sub(1)
    )]
    Condition {
        index: i64,
        conditions: String,
        n: usize,
    },
    #[error("the policy's action for condition {condition} at control step {step} {problem}")]
    Action {
        condition: usize,
        step: usize,
        problem: ActionProblem,
    },
    /// An argument outside what the call accepts (`n_envs`, an empty list of conditions, a
    /// condition listed twice); raised in Python as `ValueError`, as [`GymError::Condition`] is.
    #[error("{0}")]
    Argument(String),
    /// A call that does not fit the object's state (a step after the end, a stale batch).
    #[error("{0}")]
    State(String),
}

/// Why an action was refused.
#[derive(Debug, Clone, PartialEq)]
pub enum ActionProblem {
    /// Channel `channel` is NaN or infinite.
    NotFinite { channel: usize },
    /// Channel `channel` is outside [−1, 1].
    OutOfRange { channel: usize, value: f64 },
    /// The policy answered with the wrong number of values.
    Shape { expected: String, got: String },
}

impl fmt::Display for ActionProblem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ActionProblem::NotFinite { channel } => {
                write!(
                    f,
                    "is not finite in channel {channel} (actions are in [-1, 1])"
                )
            }
            ActionProblem::OutOfRange { channel, value } => write!(
                f,
                "is {value} in channel {channel}, outside [-1, 1] (clip it, e.g. np.clip(a, -1, 1))"
            ),
            ActionProblem::Shape { expected, got } => {
                write!(f, "has shape {got}; expected {expected}")
            }
        }
    }
}

impl From<osms_make::Error> for GymError {
    fn from(e: osms_make::Error) -> Self {
        GymError::Project(e.to_string())
    }
}

impl From<osms_store::Error> for GymError {
    fn from(e: osms_store::Error) -> Self {
        GymError::Project(e.to_string())
    }
}
