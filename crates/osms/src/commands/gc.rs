use std::collections::BTreeSet;
use std::process::ExitCode;

use anyhow::{Result, bail};
use osms_make::slurm::cmd::{Scheduler, SlurmCli};
use osms_make::slurm::ledger;
use osms_make::{Pipeline, Plan, State};

use crate::cli::GcArgs;
use crate::commands::{human_bytes, print_json};
use crate::context::Context;

pub fn run(ctx: &Context, args: &GcArgs) -> Result<ExitCode> {
    // The pipeline first: a mistyped --pipeline must not leave a new store beside it.
    let default = Pipeline::load(&ctx.pipeline_path, None)?;
    let store = ctx.store()?;
    let profiles = if args.profiles.is_empty() {
        default.profiles.clone()
    } else {
        args.profiles.clone()
    };
    for p in &profiles {
        if !default.profiles.contains(p) {
            bail!(
                "unknown profile `{p}`\nhint: declared profiles are {}",
                default.profiles.join(", ")
            );
        }
    }
    // Everything gc decides from the store is read under the lock: a make that finishes while
    // gc waits (its `@9` heads, say) is then seen and kept.
    let _lock =
        store.lock(|| errln!("waiting for another osms process to release the store lock..."))?;
    if store.is_read_only() && !args.dry_run {
        anyhow::bail!(
            "store {} is read-only: gc cannot remove anything from it\nhint: `osms gc --dry-run` lists what a gc would remove",
            store.root().display()
        );
    }
    let seeds: Vec<u64> = match &args.seeds {
        Some(s) => s.clone(),
        None => {
            // Every seed some instance was built with, so gc never removes a sweep's results.
            let mut seeds: BTreeSet<u64> = default.default_seeds.iter().copied().collect();
            for name in store.list_state("heads")? {
                if let Some(seed) = name
                    .strip_suffix(".json")
                    .and_then(|n| n.rsplit_once('@'))
                    .and_then(|(_, s)| s.parse().ok())
                {
                    seeds.insert(seed);
                }
            }
            seeds.into_iter().collect()
        }
    };
    if !args.dry_run {
        refuse_while_tasks_run(&store)?;
    }
    let mut keep = BTreeSet::new();
    // Every key the plan can compute now, built or not: an unbuilt one may have shards from an
    // interrupted make, which the store keeps until the stage is complete.
    let mut planned = BTreeSet::new();
    for profile in &profiles {
        let pipeline = Pipeline::load(&ctx.pipeline_path, Some(profile))?;
        let plan = Plan::new(&pipeline, &ctx.registry)?;
        for s in osms_make::status(&plan, &store, &[], &seeds)? {
            if s.state == State::Cached {
                keep.extend(s.key);
            }
            planned.extend(s.key);
        }
    }
    // Named experiments keep every instance they recorded until `osms exp rm`.
    let experiments = osms_make::experiment::kept_keys(&store)?;
    let kept_by_experiments = experiments.iter().filter(|k| !keep.contains(*k)).count();
    keep.extend(experiments);
    let report = store.gc(&keep, &planned, args.dry_run)?;
    if args.json {
        print_json(&report)?;
    } else if ctx.printer.says() {
        let verb = if args.dry_run {
            "would remove"
        } else {
            "removed"
        };
        if ctx.printer.verbose || args.dry_run {
            for h in &report.objects_removed {
                outln!("{verb} object {h}");
            }
        }
        errln!(
            "osms gc: {verb} {} objects ({}) and {} index records; kept {} objects reachable from profiles {} at seeds {:?}{}",
            report.objects_removed.len(),
            human_bytes(report.bytes_removed),
            report.records_removed.len(),
            report.objects_kept,
            profiles.join(", "),
            seeds,
            if kept_by_experiments == 0 {
                String::new()
            } else {
                format!(" and {kept_by_experiments} instance(s) only named experiments hold")
            }
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// Cluster tasks write objects before their records, without the lock: a gc while one runs
/// could remove an object its record is about to name. Refuses while any job on record is
/// still queued or running, or when Slurm cannot say.
fn refuse_while_tasks_run(store: &osms_store::Store) -> Result<()> {
    let subs: Vec<_> = ledger::submissions(store)?
        .into_iter()
        .filter(|s| s.failed.is_none())
        .collect();
    if subs.is_empty() {
        return Ok(());
    }
    let ids: Vec<u64> = subs.iter().flat_map(|s| s.job_ids()).collect();
    let queued = SlurmCli.queue(&ids).map_err(|e| {
        anyhow::anyhow!(
            "the store has Slurm jobs on record ({}) and Slurm cannot be asked whether they \
             still run: {e}\nhint: run gc where squeue works, or after `osms make --executor \
             slurm` has finished",
            subs.iter()
                .map(|s| s.instance.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )
    })?;
    if let Some(q) = queued.first() {
        bail!(
            "Slurm job {} of this store is still {} ({} job(s) in all); gc could remove objects \
             a running task is about to record\nhint: wait for `osms make --executor slurm` to \
             finish, or scancel the jobs",
            q.task_name(),
            q.state.to_lowercase(),
            queued.len()
        );
    }
    Ok(())
}
