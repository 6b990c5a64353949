//! Policies and their data: the catching task and PPO for the privileged teacher, teacher rollout
//! datasets with their outcome-sensitive windows (D_M, D_E, D_R), conditional flow-matching
//! students and demonstration sets, with their stage kinds.
//!
//! Rooms: library modules ([`catch`], [`ppo`], [`osw`], [`flow`], [`student`], [`norm`],
//! [`checkpoint`]) know nothing of the engine; [`artifacts`] holds the stored types (teacher,
//! Table I, datasets, OSW sets, students, error pairs, demonstration sets) with what `osms show`
//! prints of them;
//! [`stages`] holds one thin adapter per stage kind. [`ppo`] trains on any [`ppo::Task`] with
//! collection spread over threads and merged in episode order, so the trained bytes do not
//! depend on the thread count.

pub mod artifacts;
pub mod catch;
pub mod checkpoint;
mod error;
pub mod flow;
pub mod norm;
pub mod osw;
pub mod ppo;
pub mod protocol;
pub mod stages;
pub mod student;

pub use checkpoint::Checkpoints;
pub use error::{Error, Result};
pub use norm::RunningNorm;
pub use ppo::{Agent, EpisodeStats, IterationStats, PpoConfig, PpoState, Task, TaskEpisode, train};
