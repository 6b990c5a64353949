//! Running a make on a Slurm cluster: the driver that submits stages as their inputs become
//! ready, the tasks that build on compute nodes, and what status shows of them (the
//! `[executor]` settings are [`crate::executor`]'s).
//! `docs/slurm.md` explains the design.

pub mod cmd;
mod driver;
pub mod ledger;
mod task;

pub use driver::{ClusterStatus, Launch, cluster_status, log_path, make_slurm};
pub use task::{TaskOutcome, run_task, shard_cpu_secs};
