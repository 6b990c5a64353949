//! Policies of osms. [`ppo`] trains a privileged teacher on any [`ppo::Task`] with collection
//! spread over threads and merged in episode order, so the trained bytes do not depend on the
//! thread count.

pub mod artifacts;
pub mod catch;
mod error;
pub mod flow;
pub mod norm;
pub mod osw;
pub mod ppo;
pub mod stages;
pub mod student;

pub use error::{Error, Result};
pub use norm::RunningNorm;
pub use ppo::{Agent, EpisodeStats, IterationStats, PpoConfig, Task, TaskEpisode, train};
