/// Everything that can go wrong in the policy crate.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A param outside what training accepts; the message names it and what is valid.
    #[error("{0}")]
    Params(String),
    #[error("demonstration {index}: {why}")]
    Demo { index: usize, why: String },
    #[error(
        "no demonstrations to train on ({given} given, {heldout} held out)\nhint: give the student more rollouts or set params.holdout_every = 0"
    )]
    NoDemos { given: usize, heldout: usize },
    /// PPO stopped because an episode could not start (e.g. no condition could be drawn).
    #[error("PPO iteration {iteration}: episode {episode} could not start: {source}")]
    EpisodeStart {
        iteration: u32,
        episode: u64,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The checkpoint after `done` steps could not be stored (`why`, the store's own message,
    /// says what happened and what to do).
    #[error("{why}")]
    Checkpoint { done: u32, why: String },
    #[error("event step {event_step} is past the rollout's {steps} steps")]
    EventPastEnd { event_step: usize, steps: usize },
    #[error("the rollout kept no privileged frames (record_privileged = false)")]
    NoPrivilegedFrames,
    #[error("the rollout kept no arm servo targets")]
    NoArmTargets,
    #[error(transparent)]
    Network(#[from] osms_nn::Error),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl From<osms_core::check::Invalid> for Error {
    fn from(e: osms_core::check::Invalid) -> Self {
        Error::Params(format!("params.{}: {}", e.path.join("."), e.message))
    }
}
