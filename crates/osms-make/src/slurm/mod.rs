//! Running a make on a Slurm cluster: settings, the driver that submits stages as their inputs
//! become ready, the tasks that build on compute nodes, and what status shows of them.
//! `docs/slurm.md` explains the design.

pub mod cmd;
mod config;
mod driver;
pub mod ledger;
mod task;

pub use config::{
    DEFAULT_POLL_SECS, ExecutorConfig, ExecutorKind, JobResources, SlurmConfig, load_user_config,
    user_config_path,
};
pub use driver::{ClusterStatus, Launch, cluster_status, log_path, make_slurm};
pub use task::{TaskOutcome, run_task, shard_cpu_secs};
