//! What the driver keeps in the store about cluster work, under `state/slurm/`:
//!
//! ```text
//! state/slurm/tasks/<key>.json   the instance a task builds, with its input hashes (TaskSpec)
//! state/slurm/jobs/<key>.json    the jobs submitted for it (Submission)
//! state/slurm/logs/              the jobs' stdout and stderr
//! ```
//!
//! A task reads its spec and recomputes the key from the pipeline it loads: a pipeline or osms
//! changed between submission and run is caught there, not built under the old key.

use osms_store::{Hash, Store};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

const TASKS: &str = "slurm/tasks";
const JOBS: &str = "slurm/jobs";
/// Where job logs go, relative to the store's `state/` directory.
pub const LOGS: &str = "slurm/logs";

/// Everything a cluster task needs to rebuild its instance's key and inputs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TaskSpec {
    pub instance: String,
    pub key: Hash,
    pub profile: String,
    /// The run seeds of the make (a gather over `@*` reads every one).
    pub seeds: Vec<u64>,
    pub input_hashes: Vec<(String, Hash)>,
    /// Threads each task runs (its `--cpus-per-task`).
    pub threads: u32,
    /// The submit host's platform class; a task elsewhere refuses to run.
    pub platform: String,
}

/// The jobs submitted for one instance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Submission {
    pub instance: String,
    pub key: Hash,
    /// The job array computing the shards, and which shard indices it runs.
    pub array: Option<ArrayJob>,
    /// The job that builds the instance (merges the shards, or runs an unsharded stage).
    pub job: u64,
    /// The stage's declared shard count.
    pub shards: u32,
    /// Set once the driver saw every job end without the artifact appearing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub failed: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArrayJob {
    pub id: u64,
    pub tasks: Vec<u32>,
}

impl Submission {
    /// Every Slurm job id it holds.
    pub fn job_ids(&self) -> Vec<u64> {
        self.array
            .iter()
            .map(|a| a.id)
            .chain(std::iter::once(self.job))
            .collect()
    }
}

fn name(dir: &str, key: &Hash) -> String {
    format!("{dir}/{}.json", key.to_hex())
}

fn read<T: serde::de::DeserializeOwned>(store: &Store, file: &str) -> Result<Option<T>> {
    match store.read_state(file)? {
        None => Ok(None),
        Some(bytes) => serde_json::from_slice(&bytes).map(Some).map_err(|e| {
            Error::usage(format!(
                "{}: unreadable: {e}; hint: remove it (osms writes it again on the next make)",
                store.root().join("state").join(file).display()
            ))
        }),
    }
}

fn write(store: &Store, file: &str, value: &impl Serialize) -> Result<()> {
    let mut text = serde_json::to_vec_pretty(value).expect("ledger entries serialise");
    text.push(b'\n');
    Ok(store.write_state(file, &text)?)
}

pub fn read_task(store: &Store, key: &Hash) -> Result<Option<TaskSpec>> {
    read(store, &name(TASKS, key))
}

pub fn write_task(store: &Store, spec: &TaskSpec) -> Result<()> {
    write(store, &name(TASKS, &spec.key), spec)
}

pub fn read_submission(store: &Store, key: &Hash) -> Result<Option<Submission>> {
    read(store, &name(JOBS, key))
}

pub fn write_submission(store: &Store, sub: &Submission) -> Result<()> {
    write(store, &name(JOBS, &sub.key), sub)
}

/// Forgets an instance's jobs and task (once its artifact is in the store).
pub fn remove(store: &Store, key: &Hash) -> Result<()> {
    for dir in [TASKS, JOBS] {
        store.remove_state(&name(dir, key))?;
    }
    Ok(())
}

/// Every submission on record, in key order.
pub fn submissions(store: &Store) -> Result<Vec<Submission>> {
    let mut out = Vec::new();
    for file in store.list_state(JOBS)? {
        if let Some(sub) = read(store, &format!("{JOBS}/{file}"))? {
            out.push(sub);
        }
    }
    Ok(out)
}
