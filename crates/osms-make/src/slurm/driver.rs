//! `osms make --executor slurm`: a driver on the submit host that hands every instance to Slurm
//! as soon as its inputs are in the store, and waits.
//!
//! Why a driver and not one up-front DAG of `afterok` jobs: an instance's key hashes its
//! inputs' content hashes, and an itemised stage's number of items comes from its inputs, so
//! neither the key a job must build nor the shards it has are known before the inputs exist.
//! The driver computes both exactly as a local make does, so the keys are the same by
//! construction. Within one stage it does use `afterok`: the merge job waits for the stage's
//! job array and is cancelled with it if a shard fails. The driver holds the store lock (it is
//! the one writer of the store's state); tasks write only objects and their own records. It can
//! be stopped and started again: the jobs it submitted are in `state/slurm/jobs/`, and a new
//! driver adopts those still queued or running instead of submitting them twice.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use osms_store::{Hash, ObjectState, Store};

use crate::error::{Error, Result};
use crate::exec::{Found, cached_report, find, record_state};
use crate::exec::{InstanceReport, MakeOptions, MakeReport, Observer, Outcome};
use crate::executor::ExecutorConfig;
use crate::heads::Heads;
use crate::plan::{InstanceId, Plan};
use crate::slurm::cmd::{JobRequest, Queued, Scheduler};
use crate::slurm::ledger::{self, ArrayJob, Submission, TaskSpec};
use crate::slurm::task::shard_cpu_secs;

/// How tasks start `osms` on a compute node.
#[derive(Debug, Clone)]
pub struct Launch {
    /// The osms binary as the nodes see it.
    pub binary: PathBuf,
    /// Absolute paths, so a task finds them whatever its working directory.
    pub pipeline: PathBuf,
    pub store: PathBuf,
    /// The jobs' working directory (the project).
    pub workdir: PathBuf,
    /// The platform class of the submit host: a task on a node of another class refuses to
    /// run, since glibc's libm may give other bits there (docs/store.md, "Platform classes").
    pub platform: String,
}

enum State {
    Waiting,
    Running {
        sub: Submission,
        reason: String,
        since: Instant,
        /// When its jobs were first seen gone from the queue without its record.
        gone_since: Option<Instant>,
    },
    Available(Hash),
    Unavailable(String),
}

/// Builds the targets through `sched`, with the same keys and bytes as a local make.
pub fn make_slurm(
    plan: &Plan,
    store: &Store,
    opts: &MakeOptions,
    config: &ExecutorConfig,
    sched: &dyn Scheduler,
    launch: &Launch,
    observer: &dyn Observer,
) -> Result<MakeReport> {
    let lock = store.lock(|| observer.waiting_for_lock())?;
    let fs = store.check_for_cluster(&lock, config.slurm.trust_filesystem.unwrap_or(false))?;
    observer.note(&match fs.class {
        osms_store::FsClass::Local => format!(
            "store on {} (a local disk: fine for a single-node cluster; the compute nodes of a \
             larger one must see the same store)",
            fs.name
        ),
        _ => format!("store on {}", fs.name),
    });
    let instances = plan.instances(&opts.targets, &opts.seeds)?;
    let heads = Heads::load(store)?;
    let mut states: BTreeMap<InstanceId, State> =
        instances.iter().map(|id| (*id, State::Waiting)).collect();
    let mut built: BTreeSet<InstanceId> = BTreeSet::new();
    let mut report = MakeReport::default();
    let poll = Duration::from_secs_f64(config.poll_secs());
    // A record written on another node may take a while to show on a network filesystem
    // (NFS caches a missing name for up to a minute): only then is a job that left the queue
    // without it taken to have failed.
    let grace = match fs.class {
        osms_store::FsClass::Local => Duration::ZERO,
        _ => Duration::from_secs(90),
    };
    let mut queue: Vec<Queued> = sched.queue_all()?;
    clean_task_dirs(store, &queue)?;
    let mut noted_waits: BTreeSet<(u64, String)> = BTreeSet::new();

    loop {
        // Hand out everything whose inputs are available, in dependency order.
        for &id in &instances {
            if !matches!(states[&id], State::Waiting) {
                continue;
            }
            let name = plan.display(id);
            let inputs = plan.input_instances(id, &opts.seeds);
            let mut input_hashes = Vec::with_capacity(inputs.len());
            let mut waiting = false;
            let mut failed_input = None;
            for input in &inputs {
                match states.get(&input.id) {
                    Some(State::Available(h)) => input_hashes.push((input.label.clone(), *h)),
                    Some(State::Unavailable(up)) => {
                        failed_input = Some(up.clone());
                        break;
                    }
                    _ => {
                        waiting = true;
                        break;
                    }
                }
            }
            if let Some(up) = failed_input {
                let r = InstanceReport {
                    instance: name,
                    key: None,
                    content_hash: None,
                    outcome: Outcome::Skipped {
                        failed_input: up.clone(),
                    },
                    wall_time_secs: 0.0,
                    cpu_secs: 0.0,
                };
                observer.finished(&r);
                report.instances.push(r);
                states.insert(id, State::Unavailable(up));
                continue;
            }
            if waiting {
                continue;
            }
            let key = plan.key(id, &input_hashes);
            let reason = match find(plan, store, &heads, id, &name, &key, &input_hashes)? {
                Found::Present(rec) => {
                    heads.update(&name, &rec)?;
                    // Built by jobs of an earlier driver that stopped before they ended.
                    ledger::remove(store, &key)?;
                    let cut_off = inputs.iter().any(|i| built.contains(&i.id));
                    let r = cached_report(name, key, &rec, cut_off);
                    observer.finished(&r);
                    report.instances.push(r);
                    states.insert(id, State::Available(rec.content_hash));
                    continue;
                }
                Found::Build(reason) => reason,
            };
            let adopted = ledger::read_submission(store, &key)?.filter(|sub| {
                sub.failed.is_none() && queue.iter().any(|q| sub.job_ids().contains(&q.job))
            });
            let sub = match adopted {
                Some(sub) => {
                    observer.note(&format!(
                        "{name}: adopting jobs {} submitted earlier",
                        list_ids(&sub.job_ids())
                    ));
                    sub
                }
                None => match submit(
                    plan,
                    store,
                    config,
                    sched,
                    launch,
                    opts,
                    id,
                    key,
                    &input_hashes,
                ) {
                    Ok(sub) => sub,
                    // One stage that cannot be submitted (a QOS limit, a bad partition) fails
                    // alone; everything that does not need it goes on.
                    Err(e) => {
                        let r = InstanceReport {
                            instance: name.clone(),
                            key: Some(key),
                            content_hash: None,
                            outcome: Outcome::Failed {
                                error: format!("cannot submit: {e}"),
                            },
                            wall_time_secs: 0.0,
                            cpu_secs: 0.0,
                        };
                        observer.finished(&r);
                        report.instances.push(r);
                        states.insert(id, State::Unavailable(name));
                        continue;
                    }
                },
            };
            observer.note(&format!("{name} ({reason}): {}", describe_jobs(&sub)));
            states.insert(
                id,
                State::Running {
                    sub,
                    reason,
                    since: Instant::now(),
                    gone_since: None,
                },
            );
        }

        let running: Vec<InstanceId> = states
            .iter()
            .filter(|(_, s)| matches!(s, State::Running { .. }))
            .map(|(id, _)| *id)
            .collect();
        if running.is_empty() {
            break;
        }
        std::thread::sleep(poll);
        // The queue first, then the store: a job gone from the queue wrote its record before
        // it exited, so a record missing after that is really missing.
        queue = sched.queue_all()?;
        for id in running {
            let State::Running {
                sub,
                reason,
                since,
                gone_since,
            } = &states[&id]
            else {
                continue;
            };
            let name = plan.display(id);
            if let Some(rec) = store.record(&sub.key)?
                && record_state(store, &rec)?.1 == ObjectState::Present
            {
                heads.update(&name, &rec)?;
                ledger::remove(store, &sub.key)?;
                let r = InstanceReport {
                    instance: name,
                    key: Some(sub.key),
                    content_hash: Some(rec.content_hash),
                    outcome: Outcome::Built {
                        reason: reason.clone(),
                    },
                    wall_time_secs: since.elapsed().as_secs_f64(),
                    cpu_secs: rec.cpu_secs.unwrap_or(0.0),
                };
                observer.finished(&r);
                report.instances.push(r);
                built.insert(id);
                states.insert(id, State::Available(rec.content_hash));
                continue;
            }
            let alive: Vec<&Queued> = queue
                .iter()
                .filter(|q| sub.job_ids().contains(&q.job))
                .collect();
            let array_alive = sub
                .array
                .as_ref()
                .is_some_and(|a| alive.iter().any(|q| q.job == a.id));
            let merge = alive.iter().find(|q| q.job == sub.job);
            // The merge may wait on a dependency that can never be met (a shard failed and
            // this Slurm keeps such jobs): it will never run.
            let stuck = !array_alive
                && merge.is_some_and(|q| q.reason.contains("DependencyNeverSatisfied"));
            if stuck {
                sched.cancel(&[sub.job])?;
            }
            // Reasons a job may wait on for ever: say so once, and leave it to the user.
            for q in &alive {
                if q.state == "PENDING"
                    && NEVER_CLEARS.iter().any(|r| q.reason.starts_with(r))
                    && noted_waits.insert((q.job, q.reason.clone()))
                {
                    observer.note(&format!(
                        "{name}: job {} is pending with reason {}, which may never clear; \
                         check [executor.slurm] (partition, account, time, mem) or scancel it",
                        q.task_name(),
                        q.reason
                    ));
                }
            }
            if alive.is_empty() && !stuck {
                let first_gone = gone_since.unwrap_or_else(Instant::now);
                if first_gone.elapsed() < grace {
                    let (sub, reason, since) = (sub.clone(), reason.clone(), *since);
                    states.insert(
                        id,
                        State::Running {
                            sub,
                            reason,
                            since,
                            gone_since: Some(first_gone),
                        },
                    );
                    continue;
                }
            }
            if alive.is_empty() || stuck {
                let why = failure(store, sched, sub)?;
                let mut failed = sub.clone();
                failed.failed = Some(why.clone());
                ledger::write_submission(store, &failed)?;
                let r = InstanceReport {
                    instance: name.clone(),
                    key: Some(sub.key),
                    content_hash: None,
                    outcome: Outcome::Failed { error: why },
                    wall_time_secs: since.elapsed().as_secs_f64(),
                    cpu_secs: 0.0,
                };
                observer.finished(&r);
                report.instances.push(r);
                states.insert(id, State::Unavailable(name));
            }
        }
        clean_task_dirs(store, &queue)?;
    }
    store.save_stat_cache();
    Ok(report)
}

/// Pending reasons that do not clear by waiting.
const NEVER_CLEARS: &[&str] = &[
    "PartitionTimeLimit",
    "PartitionNodeLimit",
    "InvalidAccount",
    "InvalidQOS",
    "BadConstraints",
    "QOSMax",
    "AssocMax",
];

/// Removes the temp directories of tasks that are no longer queued or running. A task's
/// directory is named after its own job id (`SLURM_JOB_ID`, squeue's `%A`); `queue` is every
/// job of this user, so a task of another make on the same store is not touched either.
fn clean_task_dirs(store: &Store, queue: &[Queued]) -> Result<()> {
    let alive: BTreeSet<String> = queue.iter().map(|q| q.id.to_string()).collect();
    for dir in store.task_dirs()? {
        // Directories osms did not name after a job (a task run by hand) are left alone.
        if dir.parse::<u64>().is_ok() && !alive.contains(&dir) {
            store.remove_task_dir(&dir)?;
        }
    }
    Ok(())
}

fn list_ids(ids: &[u64]) -> String {
    ids.iter()
        .map(u64::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

fn describe_jobs(sub: &Submission) -> String {
    match &sub.array {
        Some(a) => format!(
            "array job {} ({} of {} shards), merge job {}",
            a.id,
            a.tasks.len(),
            sub.shards,
            sub.job
        ),
        None => format!("job {}", sub.job),
    }
}

/// The path of a job's log (`task` for an array task).
pub fn log_path(store: &Store, instance: &str, job: u64, task: Option<u32>) -> PathBuf {
    let file = match task {
        Some(t) => format!("osms-{instance}-{job}_{t}.log"),
        None => format!("osms-{instance}-{job}.log"),
    };
    store.state_path(ledger::LOGS).join(file)
}

#[allow(clippy::too_many_arguments)]
fn submit(
    plan: &Plan,
    store: &Store,
    config: &ExecutorConfig,
    sched: &dyn Scheduler,
    launch: &Launch,
    opts: &MakeOptions,
    id: InstanceId,
    key: Hash,
    input_hashes: &[(String, Hash)],
) -> Result<Submission> {
    let stage = &plan.stages[id.stage];
    let name = plan.display(id);
    let resources = config.resources(&stage.name);
    let spec = TaskSpec {
        instance: name.clone(),
        key,
        profile: plan.profile.clone(),
        seeds: opts.seeds.clone(),
        input_hashes: input_hashes.to_vec(),
        threads: resources.cpus(),
        platform: launch.platform.clone(),
    };
    ledger::write_task(store, &spec)?;
    let log_dir = store.state_path(ledger::LOGS);
    std::fs::create_dir_all(&log_dir)
        .map_err(|e| Error::usage(format!("cannot create {}: {e}", log_dir.display())))?;
    // Slurm expands `%` in --output; a literal one is `%%`.
    let logs = PathBuf::from(log_dir.to_string_lossy().replace('%', "%%"));
    let job_name = format!("osms-{name}");
    let array = if stage.info.itemised && stage.shards > 1 {
        let (_, done) = shard_cpu_secs(store, &key)?;
        let tasks: Vec<u32> = (0..stage.shards).filter(|i| !done.contains(i)).collect();
        if tasks.is_empty() {
            None
        } else {
            let id = sched.submit(&JobRequest {
                name: job_name.clone(),
                flags: resources.sbatch_flags(),
                array: Some(tasks.clone()),
                after_ok: None,
                log: logs.join(format!("{job_name}-%A_%a.log")),
                workdir: launch.workdir.clone(),
                script: script(launch, &key, true),
            })?;
            Some(ArrayJob { id, tasks })
        }
    } else {
        None
    };
    // On record before the merge is submitted: a driver that dies in between, or a merge that
    // cannot be submitted, must not leave shards running that no ledger knows (gc asks it).
    if let Some(a) = &array {
        ledger::write_submission(
            store,
            &Submission {
                instance: name.clone(),
                key,
                array: Some(a.clone()),
                job: a.id,
                shards: stage.shards,
                failed: None,
            },
        )?;
    }
    let merge = sched.submit(&JobRequest {
        name: job_name.clone(),
        flags: resources.sbatch_flags(),
        array: None,
        after_ok: array.as_ref().map(|a| a.id),
        log: logs.join(format!("{job_name}-%j.log")),
        workdir: launch.workdir.clone(),
        script: script(launch, &key, false),
    });
    let job = match merge {
        Ok(job) => job,
        Err(e) => {
            if let Some(a) = &array {
                let _ = sched.cancel(&[a.id]);
                ledger::remove(store, &key)?;
            }
            return Err(e);
        }
    };
    let sub = Submission {
        instance: name,
        key,
        array,
        job,
        shards: stage.shards,
        failed: None,
    };
    ledger::write_submission(store, &sub)?;
    Ok(sub)
}

/// Single-quotes `s` for the shell.
fn quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// The batch script of a task.
fn script(launch: &Launch, key: &Hash, shard: bool) -> String {
    let shard_arg = if shard {
        " --shard \"$SLURM_ARRAY_TASK_ID\""
    } else {
        ""
    };
    format!(
        "#!/bin/sh\n# osms cluster task (osms make --executor slurm); see docs/slurm.md\nexec {} --pipeline {} --store {} --no-progress run-task {}{shard_arg}\n",
        quote(&launch.binary.to_string_lossy()),
        quote(&launch.pipeline.to_string_lossy()),
        quote(&launch.store.to_string_lossy()),
        key.to_hex()
    )
}

/// Why an instance's jobs ended without its artifact: which shards are missing, how Slurm
/// says they ended (where it keeps accounting) and the end of their logs.
fn failure(store: &Store, sched: &dyn Scheduler, sub: &Submission) -> Result<String> {
    let ended = sched.ended(&sub.job_ids()).unwrap_or_default();
    let how = |job: u64, task: Option<u32>| {
        ended
            .iter()
            .find(|e| e.job == job && e.task == task)
            .map(|e| format!(" ({}, exit {})", e.state, e.exit_code))
            .unwrap_or_default()
    };
    let mut parts = Vec::new();
    if let Some(a) = &sub.array {
        let (_, done) = shard_cpu_secs(store, &sub.key)?;
        let missing: Vec<u32> = a
            .tasks
            .iter()
            .copied()
            .filter(|t| !done.contains(t))
            .collect();
        for t in &missing {
            let log = log_path(store, &sub.instance, a.id, Some(*t));
            parts.push(format!(
                "shard {t} (job {}_{t}{}) did not finish{}",
                a.id,
                how(a.id, Some(*t)),
                tail(&log)
            ));
        }
    }
    if parts.is_empty() {
        let log = log_path(store, &sub.instance, sub.job, None);
        parts.push(format!(
            "job {}{} ended without writing the artifact{}",
            sub.job,
            how(sub.job, None),
            tail(&log)
        ));
    }
    parts.push("the next `osms make --executor slurm` resubmits what is missing".into());
    Ok(parts.join("; "))
}

/// The last lines of a log, for an error message.
fn tail(log: &std::path::Path) -> String {
    match std::fs::read_to_string(log) {
        Ok(text) => {
            let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
            let last = &lines[lines.len().saturating_sub(3)..];
            if last.is_empty() {
                format!(" [log {} is empty]", log.display())
            } else {
                format!(" [log {}: {}]", log.display(), last.join(" / "))
            }
        }
        Err(_) => format!(" [no log at {}]", log.display()),
    }
}

/// What the cluster is doing for one instance, from the ledger, the queue and the store.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ClusterStatus {
    pub instance: String,
    pub key: Hash,
    /// The array job and the job that builds the instance.
    pub array_job: Option<u64>,
    pub job: u64,
    /// The stage's shard count; and how many shards are done, running, waiting in the queue
    /// (submitted), and gone from it without their shard (failed).
    pub shards: u32,
    pub shards_done: u32,
    pub shards_running: u32,
    pub shards_submitted: u32,
    pub shards_failed: Vec<u32>,
    /// The job's state (`PENDING`, `RUNNING`, ...), `DONE` once the artifact is in the store,
    /// or `FAILED`.
    pub job_state: String,
    /// Why it waits, or why it failed.
    pub reason: String,
}

/// The cluster status of every instance with jobs on record.
pub fn cluster_status(store: &Store, sched: &dyn Scheduler) -> Result<Vec<ClusterStatus>> {
    let subs = ledger::submissions(store)?;
    if subs.is_empty() {
        return Ok(Vec::new());
    }
    let ids: Vec<u64> = subs.iter().flat_map(Submission::job_ids).collect();
    let queue = sched.queue(&ids)?;
    let mut out = Vec::new();
    for sub in subs {
        let done_record = store
            .record(&sub.key)?
            .is_some_and(|r| record_state(store, &r).is_ok_and(|(_, s)| s == ObjectState::Present));
        let (_, done) = shard_cpu_secs(store, &sub.key)?;
        let mut st = ClusterStatus {
            instance: sub.instance.clone(),
            key: sub.key,
            array_job: sub.array.as_ref().map(|a| a.id),
            job: sub.job,
            shards: sub.shards,
            shards_done: done.len() as u32,
            shards_running: 0,
            shards_submitted: 0,
            shards_failed: Vec::new(),
            job_state: String::new(),
            reason: String::new(),
        };
        if let Some(a) = &sub.array {
            for t in a.tasks.iter().filter(|t| !done.contains(t)) {
                match queue.iter().find(|q| q.job == a.id && q.task == Some(*t)) {
                    Some(q) if q.state == "PENDING" => st.shards_submitted += 1,
                    Some(_) => st.shards_running += 1,
                    None => st.shards_failed.push(*t),
                }
            }
        }
        match queue.iter().find(|q| q.job == sub.job) {
            _ if done_record => st.job_state = "DONE".into(),
            Some(q) => {
                st.job_state = q.state.clone();
                st.reason = q.reason.clone();
            }
            None => {
                st.job_state = "FAILED".into();
                st.reason = sub
                    .failed
                    .clone()
                    .unwrap_or_else(|| "gone from the queue without its artifact".into());
            }
        }
        out.push(st);
    }
    Ok(out)
}
