//! `osms make`: build the instances a target needs, in dependency order, reusing every
//! artifact whose key is already in the store.

use std::any::Any;
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::ops::Range;
use std::panic::{self, AssertUnwindSafe};
use std::sync::{Arc, Mutex, PoisonError, mpsc};
use std::time::Instant;

use osms_core::read_header;
use osms_store::{Hash, ObjectState, Record, ShardOf, Store};
use serde::Serialize;

use crate::cpu::{self, MeteredPool};
use crate::error::{Error, Result};
use crate::heads::{Heads, Reason};
use crate::kind::{
    CHECKPOINT_TAG, CheckpointIo, InputBytes, Objects, Progress, RunEnv, ShardIo, StageError,
};
use crate::plan::{InputInstance, InstanceId, Plan, checkpoint_key, shard_key, shard_ranges};

/// Options of one `make`.
#[derive(Debug, Clone)]
pub struct MakeOptions {
    /// Stage names (all stages if empty).
    pub targets: Vec<String>,
    pub seeds: Vec<u64>,
    pub jobs: usize,
    /// Instances built at the same time (at most `jobs`), each on `jobs` threads of its own:
    /// builds in flight share the cores.
    pub stages: usize,
    pub dry_run: bool,
}

/// What happened to one instance.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "outcome", rename_all = "snake_case")]
pub enum Outcome {
    /// Computed in this run.
    Built {
        reason: String,
    },
    /// Found in the store.
    Cached,
    /// Not in the store, found on a remote and downloaded (`osms make --remote`).
    Pulled {
        bytes: u64,
    },
    /// Found in the store although an input was rebuilt in this run: the rebuilt input
    /// reproduced the bytes it had before, so nothing downstream had to run.
    CutOff,
    /// `--dry-run`: would be computed.
    WouldBuild {
        reason: String,
    },
    Failed {
        error: String,
    },
    /// Not attempted because an input failed.
    Skipped {
        failed_input: String,
    },
}

#[derive(Debug, Clone, Serialize)]
pub struct InstanceReport {
    pub instance: String,
    pub key: Option<Hash>,
    pub content_hash: Option<Hash>,
    #[serde(flatten)]
    pub outcome: Outcome,
    pub wall_time_secs: f64,
    /// CPU seconds of the build's threads (0 for an instance this make did not build).
    pub cpu_secs: f64,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct MakeReport {
    pub instances: Vec<InstanceReport>,
}

impl MakeReport {
    pub fn count(&self, f: impl Fn(&Outcome) -> bool) -> usize {
        self.instances.iter().filter(|r| f(&r.outcome)).count()
    }

    pub fn failed(&self) -> Vec<&str> {
        self.instances
            .iter()
            .filter(|r| matches!(r.outcome, Outcome::Failed { .. }))
            .map(|r| r.instance.as_str())
            .collect()
    }
}

/// Hooks for the CLI's progress display and log lines.
pub trait Observer: Sync {
    fn waiting_for_lock(&self) {}
    /// A line about what a cluster make is doing (submissions, adopted jobs).
    fn note(&self, text: &str) {
        tracing::info!("{text}");
    }
    /// Called before an instance runs; the returned sink receives its progress.
    fn started(&self, instance: &str, reason: &str) -> Box<dyn Progress + '_>;
    fn finished(&self, report: &InstanceReport);
}

/// An observer that shows nothing: for makes run inside another program (the Python package
/// building a condition set on first use) and for tests.
pub struct Silent;
impl Observer for Silent {
    fn started(&self, _: &str, _: &str) -> Box<dyn Progress + '_> {
        Box::new(crate::NoProgress)
    }
    fn finished(&self, _: &InstanceReport) {}
}

pub const OSMS_VERSION: &str = env!("CARGO_PKG_VERSION");

/// Where a make looks for an artifact it lacks before building it: a remote cache
/// (`osms_remote`, which this crate does not depend on: the CLI joins the two).
pub trait Fetch: Sync {
    /// Brings the artifact of stage key `key` into `store` (objects first, then the record)
    /// and returns its record with the bytes downloaded, or `None` if the remote lacks it.
    /// An error is the remote's trouble, not the stage's: the make warns and builds.
    fn fetch(
        &self,
        store: &Store,
        key: &Hash,
    ) -> std::result::Result<Option<(Record, u64)>, String>;
}

/// Builds `opts.targets`, holding the store's lock for the make (none for a dry run).
pub fn make(
    plan: &Plan,
    store: &Store,
    opts: &MakeOptions,
    observer: &dyn Observer,
) -> Result<MakeReport> {
    make_locking(plan, store, opts, observer, None)
}

/// [`make`] that asks `fetch` for every instance it would build, and builds only what the
/// remote lacks. A dry run asks nothing.
pub fn make_fetching(
    plan: &Plan,
    store: &Store,
    opts: &MakeOptions,
    observer: &dyn Observer,
    fetch: &dyn Fetch,
) -> Result<MakeReport> {
    make_locking(plan, store, opts, observer, Some(fetch))
}

fn make_locking(
    plan: &Plan,
    store: &Store,
    opts: &MakeOptions,
    observer: &dyn Observer,
    fetch: Option<&dyn Fetch>,
) -> Result<MakeReport> {
    let _lock = if opts.dry_run {
        None
    } else {
        Some(store.lock(|| observer.waiting_for_lock())?)
    };
    make_locked(plan, store, opts, observer, fetch)
}

/// [`make`] for a caller that already holds the store's lock (`_held`) and keeps it past the
/// make, to record what the make built before any other process (a `gc`) can touch the store.
pub fn make_holding(
    plan: &Plan,
    store: &Store,
    _held: &osms_store::StoreLock,
    opts: &MakeOptions,
    observer: &dyn Observer,
) -> Result<MakeReport> {
    make_locked(plan, store, opts, observer, None)
}

fn make_locked(
    plan: &Plan,
    store: &Store,
    opts: &MakeOptions,
    observer: &dyn Observer,
    fetch: Option<&dyn Fetch>,
) -> Result<MakeReport> {
    let jobs = opts.jobs.max(1);
    let instances = plan.instances(&opts.targets, &opts.seeds)?;
    // The report lists instances in plan order, whatever order concurrent builds end in.
    let plan_order: BTreeMap<String, usize> = instances
        .iter()
        .enumerate()
        .map(|(k, &id)| (plan.display(id), k))
        .collect();
    let heads = Heads::load(store)?;
    let mut report = MakeReport::default();
    // Content hash of every instance that is available, and which ones ran in this make.
    let mut available: BTreeMap<InstanceId, Hash> = BTreeMap::new();
    let mut built: BTreeSet<InstanceId> = BTreeSet::new();
    let mut unavailable: BTreeMap<InstanceId, String> = BTreeMap::new();

    // A worklist rather than a loop: an input found damaged while loading it for a downstream
    // stage goes back to the front, to be rebuilt before that stage runs again.
    let mut queue: VecDeque<InstanceId> = instances.into();
    let mut requeued: BTreeSet<InstanceId> = BTreeSet::new();
    // Instances whose cached artifact no longer decodes: built again whatever their record says.
    let mut stale: BTreeMap<InstanceId, String> = BTreeMap::new();
    // Builds run on threads of their own, each with a worker pool of its own whose CPU time is
    // its cost; everything else (lookups, records, heads, the report) stays on this thread.
    // More than one build at a time pays off where a stage leaves cores idle (a student's
    // training uses ≈ 1.4 of 2).
    let slots = opts.stages.clamp(1, jobs);
    let mut running: BTreeMap<InstanceId, Running> = BTreeMap::new();
    let (done_tx, done_rx) = mpsc::channel::<Finished>();
    std::thread::scope(|scope| -> Result<()> {
        loop {
            // The first queued instance whose inputs are all settled (available, or given up on):
            // with one slot that is always the queue's head, the order a sequential make keeps.
            // An instance whose key is being built waits for that build and then finds it
            // cached: instances that share a key build once, at any number of stages.
            let ready = if running.len() < slots {
                queue.iter().position(|&id| {
                    let inputs = plan.input_instances(id, &opts.seeds);
                    let settled = inputs.iter().all(|input| {
                        available.contains_key(&input.id) || unavailable.contains_key(&input.id)
                    });
                    let key_free = || {
                        // Without every input available it is skipped, not built: no key.
                        let hashes: Option<Vec<(String, Hash)>> = inputs
                            .iter()
                            .map(|i| available.get(&i.id).map(|h| (i.label.clone(), *h)))
                            .collect();
                        hashes.is_none_or(|h| {
                            let key = plan.key(id, &h);
                            running.values().all(|r| r.key != key)
                        })
                    };
                    settled && (running.is_empty() || key_free())
                })
            } else {
                None
            };
            let Some(position) = ready else {
                if running.is_empty() {
                    if let Some(&id) = queue.front() {
                        return Err(Error::usage(format!(
                            "internal: `{}` waits for inputs that nothing builds",
                            plan.display(id)
                        )));
                    }
                    break;
                }
                let done = done_rx.recv().map_err(|_| {
                    Error::usage("internal: a build thread ended without reporting".to_string())
                })?;
                let Some(run) = running.remove(&done.id) else {
                    continue;
                };
                let id = done.id;
                let r = settle(plan, store, &heads, run, done);
                match r.content_hash {
                    Some(content_hash) => {
                        available.insert(id, content_hash);
                        built.insert(id);
                    }
                    None => {
                        unavailable.insert(id, r.instance.clone());
                    }
                }
                observer.finished(&r);
                report.instances.push(r);
                continue;
            };
            let Some(id) = queue.remove(position) else {
                continue;
            };
            let name = plan.display(id);
            let inputs = plan.input_instances(id, &opts.seeds);
            let mut input_hashes = Vec::with_capacity(inputs.len());
            let mut blocked = None;
            for input in &inputs {
                match available.get(&input.id) {
                    Some(h) => input_hashes.push((input.label.clone(), *h)),
                    None => {
                        blocked = Some(
                            unavailable
                                .get(&input.id)
                                .cloned()
                                .unwrap_or_else(|| plan.display(input.id)),
                        );
                        break;
                    }
                }
            }
            if let Some(up) = blocked {
                let outcome = if opts.dry_run {
                    Outcome::WouldBuild {
                        reason: format!("input `{up}` will be rebuilt"),
                    }
                } else {
                    Outcome::Skipped {
                        failed_input: up.clone(),
                    }
                };
                unavailable.insert(id, up);
                let r = InstanceReport {
                    instance: name,
                    key: None,
                    content_hash: None,
                    outcome,
                    wall_time_secs: 0.0,
                    cpu_secs: 0.0,
                };
                observer.finished(&r);
                report.instances.push(r);
                continue;
            }

            let key = plan.key(id, &input_hashes);
            // A store error here, as one while recording, ends the make only after the builds
            // in flight are settled.
            let found = match stale.get(&id) {
                Some(reason) => Found::Build(reason.clone()),
                None => match find(plan, store, &heads, id, &name, &key, &input_hashes) {
                    Ok(found) => found,
                    Err(e) => {
                        unavailable.insert(id, name.clone());
                        let error = storage_failure(
                            &format!("cannot look up key {} in the store", key.short()),
                            &e,
                            None,
                        );
                        let r = failed_report(name, key, error, 0.0, 0.0);
                        observer.finished(&r);
                        report.instances.push(r);
                        continue;
                    }
                },
            };
            let reason = match found {
                Found::Present(rec) => {
                    let cut_off = inputs.iter().any(|i| built.contains(&i.id));
                    available.insert(id, rec.content_hash);
                    // A dry run holds no lock, so it writes nothing but the stat cache.
                    // The artifact is whole; a head that cannot be written only leaves
                    // `status` an older reason to give later.
                    if !opts.dry_run
                        && plan.record_heads
                        && !store.is_read_only()
                        && let Err(e) = heads.update(&name, &rec)
                    {
                        tracing::warn!("`{name}`: cannot update its head in the store: {e}");
                    }
                    let r = cached_report(name, key, &rec, cut_off);
                    observer.finished(&r);
                    report.instances.push(r);
                    continue;
                }
                Found::Build(reason) => reason,
            };
            if let Some(fetch) = fetch.filter(|_| !opts.dry_run) {
                let started = Instant::now();
                match fetch.fetch(store, &key) {
                    Ok(Some((rec, bytes))) => {
                        available.insert(id, rec.content_hash);
                        if plan.record_heads
                            && let Err(e) = heads.update(&name, &rec)
                        {
                            tracing::warn!("`{name}`: cannot update its head in the store: {e}");
                        }
                        let r = InstanceReport {
                            instance: name,
                            key: Some(key),
                            content_hash: Some(rec.content_hash),
                            outcome: Outcome::Pulled { bytes },
                            wall_time_secs: started.elapsed().as_secs_f64(),
                            cpu_secs: 0.0,
                        };
                        observer.finished(&r);
                        report.instances.push(r);
                        continue;
                    }
                    Ok(None) => {}
                    Err(e) => observer.note(&format!(
                        "warning: `{name}`: the remote could not serve key {} ({e}); building it here",
                        key.short()
                    )),
                }
            }

            if opts.dry_run {
                unavailable.insert(id, name.clone());
                let r = InstanceReport {
                    instance: name,
                    key: Some(key),
                    content_hash: None,
                    outcome: Outcome::WouldBuild { reason },
                    wall_time_secs: 0.0,
                    cpu_secs: 0.0,
                };
                observer.finished(&r);
                report.instances.push(r);
                continue;
            }
            if store.is_read_only() {
                unavailable.insert(id, name.clone());
                let error = format!(
                    "store {} is read-only: cannot build `{name}` ({reason})\nhint: build into a store that can be written (--store DIR); a read-only store serves what it holds",
                    store.root().display()
                );
                let r = failed_report(name, key, error, 0.0, 0.0);
                observer.finished(&r);
                report.instances.push(r);
                continue;
            }

            let started = Instant::now();
            let loaded = match load_inputs(plan, store, &inputs, &input_hashes) {
                Ok(loaded) => loaded,
                // The stat cache vouched for this input when it was found cached, but its bytes no
                // longer match: rebuild it (once), then come back to this instance.
                Err(BadInput::Damaged { input, hash }) if !requeued.contains(&input) => {
                    let up = plan.display(input);
                    tracing::warn!(
                        "input `{up}` of `{name}`: object {} is damaged; rebuilding it",
                        hash.short()
                    );
                    store.distrust(&hash);
                    available.remove(&input);
                    requeued.insert(input);
                    report.instances.retain(|r| r.instance != up);
                    queue.push_front(id);
                    queue.push_front(input);
                    continue;
                }
                Err(BadInput::Damaged { input, hash }) => Err(format!(
                    "input `{}`: object {} is damaged again after a rebuild",
                    plan.display(input),
                    hash.short()
                )
                .into()),
                // Like a damaged input, but the bytes are intact: the kind's output type changed
                // under them. Said once, here, where the first consumer meets it.
                Err(BadInput::Stale {
                    input,
                    hash,
                    tag,
                    reason,
                }) if !requeued.contains(&input) => {
                    let up = plan.display(input);
                    observer.note(&format!(
                        "warning: stage `{up}`: its cached `{tag}` artifact {} does not decode ({reason}); rebuilding it",
                        hash.short()
                    ));
                    stale.insert(
                        input,
                        format!("its cached `{tag}` artifact does not decode as this osms's type"),
                    );
                    available.remove(&input);
                    requeued.insert(input);
                    report.instances.retain(|r| r.instance != up);
                    queue.push_front(id);
                    queue.push_front(input);
                    continue;
                }
                Err(BadInput::Stale {
                    input, tag, reason, ..
                }) => Err(format!(
                    "input `{}`: its `{tag}` artifact does not decode even after a rebuild: {reason}\nhint: the kind writes bytes its own output type cannot read; bump its SCHEMA_VERSION or fix its serialisation",
                    plan.display(input)
                )
                .into()),
            };
            let progress = observer.started(&name, &reason);
            running.insert(
                id,
                Running {
                    name,
                    key,
                    reason,
                    input_hashes: input_hashes.clone(),
                },
            );
            let loaded = match loaded {
                Ok(loaded) => loaded,
                // Settled with the builds, as a build that failed at once.
                Err(e) => {
                    drop(progress);
                    let _ = done_tx.send(Finished {
                        id,
                        result: Err(e),
                        wall_time_secs: started.elapsed().as_secs_f64(),
                        cpu_secs: 0.0,
                    });
                    continue;
                }
            };
            let reporter = Reporter {
                tx: done_tx.clone(),
                id,
                started,
                cpu_secs: 0.0,
                result: None,
            };
            scope.spawn(move || {
                // Every build reports, even one that panics outside its kind (which `build`
                // catches), in its progress display's drop say: the make waits for a report
                // from each, and `Reporter` sends one however this thread ends. (Bound whole
                // here: a closure that only assigned its field would leave it to drop, and
                // report, on the main thread at once.)
                let mut reporter = reporter;
                let own_cpu = cpu::thread_secs();
                let result = panic::catch_unwind(AssertUnwindSafe(|| {
                    let result = match cpu::MeteredPool::new(jobs, "osms-worker") {
                        Ok(pool) => {
                            let result = build(
                                plan,
                                store,
                                id,
                                key,
                                loaded,
                                &input_hashes,
                                &pool,
                                progress.as_ref(),
                            );
                            reporter.cpu_secs = pool.secs();
                            result
                        }
                        Err(e) => Err(format!("cannot start {jobs} worker threads: {e}").into()),
                    };
                    drop(progress);
                    result
                }))
                .unwrap_or_else(|payload| {
                    Err(format!("build panicked: {}", panic_message(payload.as_ref())).into())
                });
                reporter.cpu_secs += cpu::thread_secs() - own_cpu;
                reporter.result = Some(result);
            });
        }
        Ok(())
    })?;
    report
        .instances
        .sort_by_key(|r| plan_order.get(&r.instance).copied().unwrap_or(usize::MAX));
    store.save_stat_cache();
    Ok(report)
}

/// What a build gives back: its content hash, size and parts, or why it failed.
type BuildResult = Result<(Hash, u64, Vec<Hash>), StageError>;

/// Sends a build's [`Finished`] when dropped: its result, or a failure if its thread ended
/// without one (a panic the build's own guard could not catch).
struct Reporter {
    tx: mpsc::Sender<Finished>,
    id: InstanceId,
    started: Instant,
    /// CPU seconds of the build's pool and thread, once it ended.
    cpu_secs: f64,
    result: Option<BuildResult>,
}

impl Drop for Reporter {
    fn drop(&mut self) {
        let result = self.result.take().unwrap_or_else(|| {
            Err("the build's thread ended without a result (it panicked)".into())
        });
        // The receiver lives until every build has reported.
        let _ = self.tx.send(Finished {
            id: self.id,
            result,
            wall_time_secs: self.started.elapsed().as_secs_f64(),
            cpu_secs: self.cpu_secs,
        });
    }
}

/// A build in flight: what the report and the record need when it ends.
struct Running {
    name: String,
    key: Hash,
    reason: String,
    input_hashes: Vec<(String, Hash)>,
}

/// A build's end, sent from its thread.
struct Finished {
    id: InstanceId,
    result: BuildResult,
    wall_time_secs: f64,
    /// CPU seconds its threads used (its worker pool's and its own).
    cpu_secs: f64,
}

/// Stores a finished build's record (and head) if it succeeded, and reports it: a report with
/// a content hash is a build, one without a failure (its own, or that of recording it).
fn settle(
    plan: &Plan,
    store: &Store,
    heads: &Heads,
    run: Running,
    done: Finished,
) -> InstanceReport {
    let Running {
        name,
        key,
        reason,
        input_hashes,
    } = run;
    let wall_time_secs = done.wall_time_secs;
    match done.result {
        Ok((content_hash, size_bytes, parts)) => {
            let mut rec = record(
                plan,
                done.id,
                key,
                content_hash,
                &input_hashes,
                size_bytes,
                wall_time_secs,
                done.cpu_secs,
            );
            rec.parts = parts;
            let recorded = store.put_record(&rec).map_err(Error::from).and_then(|()| {
                if plan.record_heads {
                    heads.update(&name, &rec)?;
                }
                Ok(())
            });
            if let Err(e) = recorded {
                let error = storage_failure(
                    &format!(
                        "cannot record the output of this build (key {})",
                        key.short()
                    ),
                    &e,
                    None,
                );
                return failed_report(name, key, error, wall_time_secs, done.cpu_secs);
            }
            InstanceReport {
                instance: name,
                key: Some(key),
                content_hash: Some(content_hash),
                outcome: Outcome::Built { reason },
                wall_time_secs,
                cpu_secs: done.cpu_secs,
            }
        }
        Err(e) => failed_report(name, key, e.to_string(), wall_time_secs, done.cpu_secs),
    }
}

/// The report of an instance that failed with `error`.
fn failed_report(
    instance: String,
    key: Hash,
    error: String,
    wall_time_secs: f64,
    cpu_secs: f64,
) -> InstanceReport {
    InstanceReport {
        instance,
        key: Some(key),
        content_hash: None,
        outcome: Outcome::Failed { error },
        wall_time_secs,
        cpu_secs,
    }
}

/// An instance's artifact in the store, or why it must be built.
pub(crate) enum Found {
    Present(Box<Record>),
    Build(String),
}

/// Looks up the artifact of instance `id` (named `name`) under `key`.
pub(crate) fn find(
    plan: &Plan,
    store: &Store,
    heads: &Heads,
    id: InstanceId,
    name: &str,
    key: &Hash,
    input_hashes: &[(String, Hash)],
) -> Result<Found> {
    Ok(Found::Build(match readable_record(store, key)? {
        Err(unreadable) => unreadable.to_string(),
        Ok(Some(rec)) => match record_state(store, &rec)? {
            (_, ObjectState::Present) => return Ok(Found::Present(Box::new(rec))),
            (hash, ObjectState::Missing) => Reason::ObjectMissing { hash }.to_string(),
            (hash, ObjectState::Damaged { .. }) => Reason::ObjectDamaged { hash }.to_string(),
        },
        Ok(None) => heads.reason_to_build(plan, id, name, input_hashes),
    }))
}

/// The report of an instance found in the store (`cut_off`: although an input was rebuilt).
pub(crate) fn cached_report(
    name: String,
    key: Hash,
    rec: &Record,
    cut_off: bool,
) -> InstanceReport {
    InstanceReport {
        instance: name,
        key: Some(key),
        content_hash: Some(rec.content_hash),
        outcome: if cut_off {
            Outcome::CutOff
        } else {
            Outcome::Cached
        },
        wall_time_secs: 0.0,
        cpu_secs: 0.0,
    }
}

/// An input that cannot be used as stored.
pub(crate) enum BadInput {
    /// Its object failed its hash check when loaded.
    Damaged { input: InstanceId, hash: Hash },
    /// Its bytes do not decode as its kind's output: a cached artifact whose layout changed
    /// without a schema bump.
    Stale {
        input: InstanceId,
        hash: Hash,
        tag: &'static str,
        reason: String,
    },
}

/// The state of a record's artifact: its object's, or the first part (shard) that is not
/// present, since a manifest is only as whole as its shards.
pub(crate) fn record_state(store: &Store, rec: &Record) -> Result<(Hash, ObjectState)> {
    for hash in std::iter::once(&rec.content_hash).chain(&rec.parts) {
        let state = store.object_state_cached(hash)?;
        if state != ObjectState::Present {
            return Ok((*hash, state));
        }
    }
    Ok((rec.content_hash, ObjectState::Present))
}

/// The store as a kind sees it: objects by hash, verified.
pub struct StoreObjects<'a>(pub &'a Store);
impl Objects for StoreObjects<'_> {
    fn get(&self, hash: &Hash) -> Result<Vec<u8>, StageError> {
        Ok(self.0.get(hash)?)
    }
    fn put(&self, bytes: &[u8]) -> Result<Hash, StageError> {
        self.0.put(bytes).map_err(|e| {
            storage_failure(
                "cannot store an item of this build",
                &e,
                Some(bytes.len() as u64),
            )
            .into()
        })
    }
}

/// Reads every input object, slot by slot (a gather slot's members in order). The shards of a
/// sharded input are read when the stage streams them.
pub(crate) fn load_inputs(
    plan: &Plan,
    store: &Store,
    inputs: &[InputInstance],
    input_hashes: &[(String, Hash)],
) -> Result<Result<BTreeMap<String, Vec<InputBytes>>, StageError>, BadInput> {
    let mut loaded: BTreeMap<String, Vec<InputBytes>> = BTreeMap::new();
    for (input, (_, hash)) in inputs.iter().zip(input_hashes) {
        let bytes = match store.get(hash) {
            Ok(bytes) => bytes,
            Err(osms_store::Error::Damaged { .. }) => {
                return Err(BadInput::Damaged {
                    input: input.id,
                    hash: *hash,
                });
            }
            Err(e) => {
                return Ok(Err(storage_failure(
                    &format!(
                        "cannot read input `{}` (the output of {}, object {})",
                        input.slot,
                        plan.display(input.id),
                        hash.short()
                    ),
                    &e,
                    None,
                )
                .into()));
            }
        };
        let producer = &plan.stages[input.id.stage];
        if let Err(e) = producer.kind.check_output(&bytes, &StoreObjects(store)) {
            return Err(BadInput::Stale {
                input: input.id,
                hash: *hash,
                tag: producer.info.output_tag,
                reason: e.to_string(),
            });
        }
        loaded
            .entry(input.slot.clone())
            .or_default()
            .push(InputBytes {
                member: input.id.member(),
                bytes: Arc::new(bytes),
                manifest: plan.stages[input.id.stage].info.itemised,
            });
    }
    Ok(Ok(loaded))
}

/// Runs `f` on the instance's kind with everything it needs: a panicking kind fails its own
/// stage only, not the whole make. rayon resumes a worker's panic in the caller of the
/// parallel op, so catching here covers item threads too. Nothing the stage left half-done is
/// observable: it wrote at most complete shards, and its record is only written after this
/// returns `Ok`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn with_env<R>(
    plan: &Plan,
    store: &Store,
    id: InstanceId,
    key: Hash,
    inputs: &BTreeMap<String, Vec<InputBytes>>,
    input_hashes: &[(String, Hash)],
    pool: &MeteredPool,
    progress: &dyn Progress,
    f: impl FnOnce(&dyn crate::kind::DynKind, &RunEnv<'_>) -> Result<R, StageError> + Send,
) -> Result<R, StageError>
where
    R: Send,
{
    let stage = &plan.stages[id.stage];
    let stream_name = plan.stream_name(id);
    let shards = StoreShards {
        plan,
        store,
        id,
        stage_key: key,
        input_hashes,
        shards: stage.shards,
        checkpoint_every: stage.checkpoint_every,
        pool,
        cpu_at_last_save: Mutex::new(pool.secs()),
        started: (Instant::now(), pool.secs()),
        resumed: Mutex::new((0.0, 0.0)),
    };
    let env = RunEnv {
        stage: &stream_name,
        seed: plan.effective_seed(id),
        fold: plan.fold(id),
        params: &stage.params,
        inputs,
        objects: &StoreObjects(store),
        progress,
        shards: &shards,
        checkpoints: &shards,
    };
    panic::catch_unwind(AssertUnwindSafe(|| {
        pool.pool.install(|| f(stage.kind.as_ref(), &env))
    }))
    .map_err(|payload| format!("stage panicked: {}", panic_message(payload.as_ref())))?
}

/// Builds an instance: runs its kind, checks the output's type and stores it.
#[allow(clippy::too_many_arguments)]
pub(crate) fn build(
    plan: &Plan,
    store: &Store,
    id: InstanceId,
    key: Hash,
    inputs: BTreeMap<String, Vec<InputBytes>>,
    input_hashes: &[(String, Hash)],
    pool: &MeteredPool,
    progress: &dyn Progress,
) -> BuildResult {
    let stage = &plan.stages[id.stage];
    let out = with_env(
        plan,
        store,
        id,
        key,
        &inputs,
        input_hashes,
        pool,
        progress,
        |kind, env| kind.run(env),
    )?;
    let bytes = out.bytes;
    let tag = read_header(&bytes)?.type_tag;
    if tag != stage.info.output_tag {
        return Err(format!(
            "kind `{}` produced a `{tag}`, not a `{}`",
            stage.info.name, stage.info.output_tag
        )
        .into());
    }
    let stored = store.put(&bytes).map_err(|e| {
        storage_failure(
            &format!(
                "cannot store the output of this build (key {})",
                key.short()
            ),
            &e,
            Some(bytes.len() as u64),
        )
    })?;
    Ok((stored, bytes.len() as u64, out.parts))
}

/// A store operation that failed for a stage, as its failure message: what could not be done,
/// the filesystem's error, and what to do about it.
pub(crate) fn storage_failure(
    what: &str,
    e: &(dyn std::error::Error + 'static),
    bytes: Option<u64>,
) -> String {
    format!("{what}: {e}\nhint: {}", storage_hint(e, bytes))
}

/// What to do about a failed store operation, by the filesystem's error in `e`'s chain (with
/// the bytes the operation needed, where known).
pub fn storage_hint(e: &(dyn std::error::Error + 'static), bytes: Option<u64>) -> String {
    let mut kind = None;
    let mut cause = Some(e);
    while let Some(c) = cause {
        if let Some(io) = c.downcast_ref::<std::io::Error>() {
            kind = Some(io.kind());
            break;
        }
        cause = c.source();
    }
    match kind {
        Some(std::io::ErrorKind::StorageFull | std::io::ErrorKind::QuotaExceeded) => format!(
            "no space left on the store's filesystem{}: free space and run `osms make` again; nothing built so far is lost",
            bytes
                .map(|b| format!(" (this output needs ≈ {})", osms_core::table::human_bytes(b)))
                .unwrap_or_default()
        ),
        Some(std::io::ErrorKind::ReadOnlyFilesystem) => {
            "the store's filesystem is read-only: remount it read-write, or build into another --store".to_string()
        }
        Some(_) => "the store's filesystem returned an error: check the disk (`dmesg`), then run `osms make` again; nothing built so far is lost, and `osms verify` checks what the store holds".to_string(),
        None => "run `osms make` again; `osms verify` checks what the store holds".to_string(),
    }
}

/// The record of `key`; an unreadable one is a reason to rebuild, as a missing one is.
///
/// A garbled index file (a disk error, a hand edit) must not stop every make and status that
/// needs its key: rebuilding replaces it atomically.
pub(crate) fn readable_record(store: &Store, key: &Hash) -> Result<Result<Option<Record>, Reason>> {
    match store.record(key) {
        Ok(rec) => Ok(Ok(rec)),
        Err(osms_store::Error::BadRecord { path, reason }) => {
            tracing::warn!("ignoring index record {}: {reason}", path.display());
            Ok(Err(Reason::RecordUnreadable { key: *key }))
        }
        Err(e) => Err(e.into()),
    }
}

fn panic_message(payload: &(dyn Any + Send)) -> &str {
    if let Some(s) = payload.downcast_ref::<&'static str>() {
        s
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s
    } else {
        "(no message)"
    }
}

#[allow(clippy::too_many_arguments)]
pub(crate) fn record(
    plan: &Plan,
    id: InstanceId,
    key: Hash,
    content_hash: Hash,
    input_hashes: &[(String, Hash)],
    size_bytes: u64,
    wall_time_secs: f64,
    cpu_secs: f64,
) -> Record {
    let stage = &plan.stages[id.stage];
    Record {
        key,
        content_hash,
        stage: stage.name.clone(),
        kind: stage.info.name.to_string(),
        code_version: stage.info.code_version,
        seed: plan.effective_seed(id),
        fold: id.fold,
        shard: None,
        parts: Vec::new(),
        params: stage.params.json.clone(),
        inputs: input_hashes.to_vec(),
        type_tag: stage.info.output_tag.to_string(),
        size_bytes,
        osms_version: OSMS_VERSION.to_string(),
        wall_time_secs,
        cpu_secs: Some(cpu_secs),
    }
}

/// Shards of an itemised stage, and the latest checkpoint of a long one, live in the store as
/// records of their own (kept by `gc` until the stage's own record exists), so a killed make
/// resumes from the last finished shard or checkpoint.
struct StoreShards<'a> {
    plan: &'a Plan,
    store: &'a Store,
    id: InstanceId,
    stage_key: Hash,
    input_hashes: &'a [(String, Hash)],
    shards: u32,
    checkpoint_every: Option<u32>,
    pool: &'a MeteredPool,
    /// The pool's CPU seconds when the previous shard was saved (or the build began): shards
    /// are computed one after another, so the difference is the shard's cost.
    cpu_at_last_save: Mutex<f64>,
    /// When the build began, and the pool's CPU seconds then.
    started: (Instant, f64),
    /// The wall and CPU seconds of the checkpoint this build resumed from: a checkpoint's
    /// record counts everything spent to reach it, over every attempt.
    resumed: Mutex<(f64, f64)>,
}

impl ShardIo for StoreShards<'_> {
    fn ranges(&self, n_items: usize) -> Vec<Range<usize>> {
        shard_ranges(n_items, self.shards)
    }

    fn load(&self, range: &Range<usize>) -> Option<Vec<u8>> {
        let key = shard_key(&self.stage_key, range.start as u64, range.end as u64);
        let rec = self.store.record(&key).ok()??;
        self.store.get(&rec.content_hash).ok()
    }

    fn save(
        &self,
        index: usize,
        range: &Range<usize>,
        bytes: Vec<u8>,
        items: Vec<Hash>,
        wall_secs: f64,
    ) -> Result<(), StageError> {
        let (start, end) = (range.start as u64, range.end as u64);
        let cpu_secs = {
            let now = self.pool.secs();
            let mut last = self
                .cpu_at_last_save
                .lock()
                .unwrap_or_else(PoisonError::into_inner);
            let used = now - *last;
            *last = now;
            used
        };
        let failed = |e: &osms_store::Error| {
            storage_failure(
                &format!("cannot store shard {index} (items {start}..{end}) of this build"),
                e,
                Some(bytes.len() as u64),
            )
        };
        let content_hash = self.store.put(&bytes).map_err(|e| failed(&e))?;
        let mut rec = record(
            self.plan,
            self.id,
            shard_key(&self.stage_key, start, end),
            content_hash,
            self.input_hashes,
            bytes.len() as u64,
            wall_secs,
            cpu_secs,
        );
        rec.shard = Some(ShardOf {
            stage_key: self.stage_key,
            start,
            end,
            index: Some(index as u32),
        });
        // The items' objects stay with the shard through a gc, for the resume.
        rec.parts = items;
        rec.type_tag = "shard".to_string();
        self.store.put_record(&rec).map_err(|e| failed(&e))?;
        Ok(())
    }
}

impl CheckpointIo for StoreShards<'_> {
    fn every(&self) -> Option<u32> {
        self.checkpoint_every
    }

    fn load(&self) -> Option<(u64, Vec<u8>)> {
        let rec = self.store.record(&checkpoint_key(&self.stage_key)).ok()??;
        let done = rec.shard?.end;
        let bytes = self.store.get(&rec.content_hash).ok()?;
        *self.resumed.lock().unwrap_or_else(PoisonError::into_inner) =
            (rec.wall_time_secs, rec.cpu_secs.unwrap_or(0.0));
        Some((done, bytes))
    }

    fn save(&self, done: u64, bytes: Vec<u8>) -> Result<(), StageError> {
        let failed = |e: &osms_store::Error| {
            storage_failure(
                &format!("cannot store this build's checkpoint after {done} steps"),
                e,
                Some(bytes.len() as u64),
            )
        };
        let (wall_before, cpu_before) =
            *self.resumed.lock().unwrap_or_else(PoisonError::into_inner);
        let content_hash = self.store.put(&bytes).map_err(|e| failed(&e))?;
        let mut rec = record(
            self.plan,
            self.id,
            checkpoint_key(&self.stage_key),
            content_hash,
            self.input_hashes,
            bytes.len() as u64,
            wall_before + self.started.0.elapsed().as_secs_f64(),
            cpu_before + (self.pool.secs() - self.started.1),
        );
        rec.shard = Some(ShardOf {
            stage_key: self.stage_key,
            start: 0,
            end: done,
            index: None,
        });
        rec.type_tag = CHECKPOINT_TAG.to_string();
        let previous = self.store.record(&rec.key).ok().flatten();
        self.store.put_record(&rec).map_err(|e| failed(&e))?;
        // A student's checkpoint is several times its output: the one it replaces goes now,
        // not at the next gc. Best effort: what stays, gc removes.
        if let Some(old) = previous.filter(|old| old.content_hash != content_hash)
            && let Err(e) = self.store.remove_if_unreferenced(&old.content_hash)
        {
            tracing::warn!("cannot remove the previous checkpoint: {e}");
        }
        Ok(())
    }
}
