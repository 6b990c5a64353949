//! `osms run-task KEY [--shard I]`: one Slurm job of `osms make --executor slurm`.

use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context as _, Result, bail};
use osms_make::NoProgress;
use osms_make::ShardRun;
use osms_make::slurm::{TaskOutcome, ledger, run_task};
use osms_store::{Hash, Store, host_name};

use crate::cli::RunTaskArgs;
use crate::context::Context;

pub fn run(ctx: &Context, args: &RunTaskArgs) -> Result<ExitCode> {
    let started = Instant::now();
    let key: Hash = args.key.parse()?;
    // Never create a store here: a node that does not see the shared one must say so.
    let shared = Store::open_existing(&ctx.store_path)?;
    let spec = ledger::read_task(&shared, &key)?.with_context(|| {
        format!(
            "no task {} in the store at {} (host {}); hint: `osms make --executor slurm` writes \
             it when it submits the job",
            key.short(),
            ctx.store_path.display(),
            host_name()
        )
    })?;
    let here = crate::platform::class();
    if spec.platform != here {
        bail!(
            "this node ({}) is of platform class {here}, the submit host of {}: glibc's libm can \
             give other bits here, so its output would not match a local build\nhint: keep the \
             jobs on nodes like the submit host (`sbatch_args = [\"--constraint=...\"]` under \
             [executor.slurm]), or run the driver on such a node; docs/store.md explains \
             platform classes",
            host_name(),
            spec.platform
        );
    }
    let store = shared.for_task(&task_name())?;
    let plan = ctx.plan(Some(&spec.profile))?;
    if let Some(problem) = super::make::foreign_mujoco(&plan, osms_sim::MUJOCO_PINNED) {
        bail!("{problem}");
    }
    let what = match args.shard {
        Some(i) => format!("shard {i} of {}", spec.instance),
        None => spec.instance.clone(),
    };
    errln!(
        "osms run-task: {what} (key {}) on {}, {} threads",
        key.short(),
        host_name(),
        spec.threads
    );
    let outcome = run_task(&plan, &store, &spec, args.shard, &NoProgress)?;
    let secs = started.elapsed().as_secs_f64();
    match outcome {
        TaskOutcome::AlreadyBuilt { content_hash } => errln!(
            "osms run-task: {} is already in the store ({})",
            spec.instance,
            content_hash.short()
        ),
        TaskOutcome::Built { content_hash, .. } => errln!(
            "osms run-task: built {} -> {} in {secs:.2}s",
            spec.instance,
            content_hash.short()
        ),
        TaskOutcome::Shard(ShardRun::Computed { items }) => {
            errln!("osms run-task: {what}: {items} items in {secs:.2}s")
        }
        TaskOutcome::Shard(ShardRun::Stored) => {
            errln!("osms run-task: {what} was already in the store")
        }
        TaskOutcome::Shard(ShardRun::NoSuchShard { shards }) => errln!(
            "osms run-task: {what}: the stage has only {shards} shards (fewer items than shards); nothing to do"
        ),
    }
    Ok(ExitCode::SUCCESS)
}

/// The task's name for its temp directory: its own Slurm job id (squeue's `%A`; every array
/// task has one), so the driver can tell when it is gone.
fn task_name() -> String {
    match std::env::var("SLURM_JOB_ID") {
        Ok(job) if job.parse::<u64>().is_ok() => job,
        _ => format!("local-{}-{}", host_name(), std::process::id()),
    }
}
