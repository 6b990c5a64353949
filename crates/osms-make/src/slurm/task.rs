//! One cluster task: `osms run-task KEY [--shard I]` on a compute node.

use std::collections::BTreeSet;
use std::time::Instant;

use osms_store::{Hash, ObjectState, Store};

use crate::cpu::{self, MeteredPool};
use crate::error::{Error, Result};
use crate::exec::{BadInput, build, load_inputs, record, record_state, with_env};
use crate::kind::{Progress, ShardRun};
use crate::plan::Plan;
use crate::slurm::ledger::TaskSpec;

/// What a task did.
#[derive(Debug, Clone, PartialEq)]
pub enum TaskOutcome {
    /// The instance's artifact was already in the store (a resubmitted or duplicate task).
    AlreadyBuilt {
        content_hash: Hash,
    },
    Built {
        content_hash: Hash,
        wall_secs: f64,
    },
    Shard(ShardRun),
}

/// Builds `spec`'s instance (`shard: None`: the merge, or an unsharded stage) or one shard of
/// it, in `store` (a [`Store::for_task`] view of the shared store). `plan` is the pipeline as
/// the task loaded it; its key must still be the spec's.
pub fn run_task(
    plan: &Plan,
    store: &Store,
    spec: &TaskSpec,
    shard: Option<u32>,
    progress: &dyn Progress,
) -> Result<TaskOutcome> {
    let id = plan
        .instance_named(&spec.instance, &spec.seeds)
        .ok_or_else(|| {
            Error::usage(format!(
                "instance `{}` (submitted for key {}) is not in the pipeline any more; hint: the \
             pipeline changed after submission; run `osms make --executor slurm` again",
                spec.instance,
                spec.key.short()
            ))
        })?;
    let key = plan.key(id, &spec.input_hashes);
    if key != spec.key {
        return Err(Error::usage(format!(
            "`{}` has key {} here, but was submitted as {}; hint: pipeline.toml, the profile or \
             osms itself changed between submission and this task; run `osms make --executor \
             slurm` again",
            spec.instance,
            key.short(),
            spec.key.short()
        )));
    }
    if let Some(rec) = store.record(&key)?
        && record_state(store, &rec)?.1 == ObjectState::Present
    {
        return Ok(TaskOutcome::AlreadyBuilt {
            content_hash: rec.content_hash,
        });
    }
    let inputs = plan.input_instances(id, &spec.seeds);
    let labels: Vec<&str> = inputs.iter().map(|i| i.label.as_str()).collect();
    let spec_labels: Vec<&str> = spec.input_hashes.iter().map(|(l, _)| l.as_str()).collect();
    if labels != spec_labels {
        return Err(Error::usage(format!(
            "`{}`: the pipeline's inputs {labels:?} differ from the submitted {spec_labels:?}",
            spec.instance
        )));
    }
    let loaded = match load_inputs(plan, store, &inputs, &spec.input_hashes) {
        Ok(Ok(loaded)) => loaded,
        Ok(Err(e)) => return Err(Error::usage(format!("`{}`: {e}", spec.instance))),
        Err(BadInput::Damaged { input, hash }) => {
            return Err(Error::usage(format!(
                "`{}`: input `{}` (object {}) is damaged; hint: `osms make` rebuilds it",
                spec.instance,
                plan.display(input),
                hash.short()
            )));
        }
        Err(BadInput::Stale {
            input,
            hash,
            tag,
            reason,
        }) => {
            return Err(Error::usage(format!(
                "`{}`: input `{}` (object {}) does not decode as `{tag}` ({reason}); hint: `osms make` rebuilds it",
                spec.instance,
                plan.display(input),
                hash.short()
            )));
        }
    };
    let pool = MeteredPool::new(spec.threads.max(1) as usize, "osms-task")
        .map_err(|e| Error::usage(format!("cannot start {} threads: {e}", spec.threads)))?;
    let failed =
        |e: crate::kind::StageError| Error::usage(format!("`{}` failed: {e}", spec.instance));
    match shard {
        Some(index) => with_env(
            plan,
            store,
            id,
            key,
            &loaded,
            &spec.input_hashes,
            &pool,
            progress,
            |kind, env| kind.run_shard(env, index),
        )
        .map(TaskOutcome::Shard)
        .map_err(failed),
        None => {
            // Shards other tasks computed count towards the stage's core-seconds; shards this
            // merge computes itself are inside its own wall time.
            let before = shard_cpu_secs(store, &key)?;
            let started = Instant::now();
            let own_cpu = cpu::thread_secs();
            let (content_hash, size_bytes, parts) = build(
                plan,
                store,
                id,
                key,
                loaded,
                &spec.input_hashes,
                &pool,
                progress,
            )
            .map_err(failed)?;
            let wall_secs = started.elapsed().as_secs_f64();
            let mut rec = record(
                plan,
                id,
                key,
                content_hash,
                &spec.input_hashes,
                size_bytes,
                wall_secs,
                before.0 + pool.secs() + cpu::thread_secs() - own_cpu,
            );
            rec.parts = parts;
            store.put_record(&rec)?;
            Ok(TaskOutcome::Built {
                content_hash,
                wall_secs,
            })
        }
    }
}

/// The core-seconds of the stored shards of the stage with key `stage_key`, and their indices.
pub fn shard_cpu_secs(store: &Store, stage_key: &Hash) -> Result<(f64, BTreeSet<u32>)> {
    let (records, _) = store.records()?;
    let mut secs = 0.0;
    let mut done = BTreeSet::new();
    for r in records {
        if let Some(s) = r.shard
            && s.stage_key == *stage_key
        {
            secs += r.cpu_secs.unwrap_or(0.0);
            if let Some(i) = s.index {
                done.insert(i);
            }
        }
    }
    Ok((secs, done))
}
