//! Policies of osms. [`ppo`] trains a privileged teacher on any [`ppo::Task`] with collection
//! spread over threads and merged in episode order, so the trained bytes do not depend on the
//! thread count.

pub mod catch;
pub mod dataset;
pub mod demos;
pub mod flow;
pub mod norm;
pub mod ppo;
pub mod stages;
pub mod student;
pub mod student_stages;

pub use norm::RunningNorm;
pub use ppo::{Agent, EpisodeStats, IterationStats, PpoConfig, Task, TaskEpisode, train};
