//! `osms push`, `osms pull` and the remote side of `osms make --remote`.

use std::collections::BTreeMap;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, bail};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use osms_make::executor::{load_user_remotes, user_config_path};
use osms_make::{Fetch, InstanceId, Plan, RemoteSpec, State};
use osms_remote::{Progress, Remote};
use osms_store::{Hash, ObjectState, Record, Store};
use serde::Serialize;

use crate::EXIT_FAILURE;
use crate::cli::TransferArgs;
use crate::commands::{human_bytes, print_json};
use crate::context::Context;

/// The remote a command names (`--remote`), else the pipeline's default, opened and asked for
/// its listing, so that a bad URL, server or credential fails here with the remote named.
pub(crate) fn open(ctx: &Context, plan: &Plan, name: Option<&str>, jobs: usize) -> Result<Remote> {
    let mut remotes: BTreeMap<String, (RemoteSpec, String)> = plan
        .remotes
        .iter()
        .map(|(n, s)| {
            (
                n.clone(),
                (s.clone(), ctx.pipeline_path.display().to_string()),
            )
        })
        .collect();
    if let Some(path) = user_config_path() {
        for (n, s) in load_user_remotes(&path)? {
            remotes.insert(n, (s, path.display().to_string()));
        }
    }
    let Some(name) = name.or(plan.default_remote.as_deref()) else {
        bail!(
            "no remote named\nhint: pass --remote NAME{}, or set `remote = \"NAME\"` under [pipeline] in {}",
            declared(&remotes),
            ctx.pipeline_path.display()
        );
    };
    let Some((spec, source)) = remotes.get(name) else {
        bail!(
            "no remote `{name}` is declared\nhint: add `[remotes.{name}]` with `url = \"s3://BUCKET/PREFIX\"` to {} or to the user config ({}){}",
            ctx.pipeline_path.display(),
            user_config_path().map_or_else(
                || "$XDG_CONFIG_HOME/osms/config.toml".to_string(),
                |p| p.display().to_string()
            ),
            declared(&remotes)
        );
    };
    let remote = Remote::open(name, &spec.url)
        .with_context(|| format!("remote `{name}` is declared in {source}"))?
        .with_jobs(jobs);
    remote.check()?;
    Ok(remote)
}

fn declared(remotes: &BTreeMap<String, (RemoteSpec, String)>) -> String {
    if remotes.is_empty() {
        String::new()
    } else {
        format!(
            " (declared: {})",
            remotes.keys().cloned().collect::<Vec<_>>().join(", ")
        )
    }
}

/// A transfer's progress bar: bytes, rate and time left (nothing when bars are off).
pub(crate) struct Bar {
    bar: ProgressBar,
    prefix: String,
}

impl Bar {
    pub(crate) fn new(ctx: &Context, prefix: &str) -> Bar {
        let bar = ProgressBar::with_draw_target(
            None,
            if ctx.printer.progress {
                ProgressDrawTarget::stderr()
            } else {
                ProgressDrawTarget::hidden()
            },
        );
        Bar {
            bar,
            prefix: prefix.to_string(),
        }
    }
}

impl Progress for Bar {
    fn begin(&self, what: &str, objects: u64, bytes: u64) {
        if objects == 0 {
            return;
        }
        // Styled before anything else, or the first draws show indicatif's default bar.
        self.bar.set_style(
            ProgressStyle::with_template(
                "{spinner} {prefix:.bold} [{bar:30}] {bytes}/{total_bytes} {bytes_per_sec} (eta {eta})",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        self.bar
            .set_prefix(format!("{} {objects} {what}", self.prefix));
        self.bar.reset();
        self.bar.set_length(bytes);
        self.bar.enable_steady_tick(Duration::from_millis(120));
    }
    fn advance(&self, bytes: u64) {
        self.bar.inc(bytes);
    }
    fn end(&self) {
        self.bar.finish_and_clear();
    }
}

/// What push and pull both start from: the plan, the store under its lock (so `osms gc` waits
/// for the transfer), the run seeds, the targets and the opened remote.
struct Transfer {
    started: Instant,
    plan: Plan,
    store: Store,
    seeds: Vec<u64>,
    targets: Vec<String>,
    remote: Remote,
    _lock: osms_store::StoreLock,
}

impl Transfer {
    fn begin(ctx: &Context, args: &TransferArgs) -> Result<Transfer> {
        let started = Instant::now();
        let plan = ctx.selected_plan(&args.selection)?;
        let store = ctx.store()?;
        let seeds = Context::seeds(&args.selection, &plan);
        let targets = if args.targets.is_empty() {
            plan.default_targets.clone()
        } else {
            args.targets.clone()
        };
        let remote = open(ctx, &plan, args.remote.as_deref(), args.transfers)?;
        let lock = store
            .lock(|| errln!("waiting for another osms process to release the store lock..."))?;
        Ok(Transfer {
            started,
            plan,
            store,
            seeds,
            targets,
            remote,
            _lock: lock,
        })
    }
}

#[derive(Serialize)]
struct PushJson<'a> {
    remote: &'a str,
    url: &'a str,
    #[serde(flatten)]
    report: &'a osms_remote::PushReport,
    secs: f64,
}

pub fn push(ctx: &Context, args: &TransferArgs) -> Result<ExitCode> {
    let Transfer {
        started,
        plan,
        store,
        seeds,
        targets,
        remote,
        _lock,
    } = Transfer::begin(ctx, args)?;
    let statuses = osms_make::status(&plan, &store, &targets, &seeds)?;
    let unbuilt: Vec<&str> = statuses
        .iter()
        .filter(|s| s.state != State::Cached)
        .map(|s| s.instance.as_str())
        .collect();
    if !unbuilt.is_empty() {
        bail!(
            "nothing was pushed: {} of the targets' {} instances have no current build in {} ({})\nhint: {} builds them",
            unbuilt.len(),
            statuses.len(),
            store.root().display(),
            unbuilt.join(", "),
            ctx.make_command(&targets.join(" "), &plan.profile)
        );
    }
    let mut records = Vec::with_capacity(statuses.len());
    for s in &statuses {
        let key = s.key.context("internal: a cached instance without a key")?;
        let record = store
            .record(&key)?
            .with_context(|| format!("internal: `{}` has no record", s.instance))?;
        records.push(record);
    }
    let report = remote.push(&store, &records, &Bar::new(ctx, "pushing"))?;
    let secs = started.elapsed().as_secs_f64();
    if args.json {
        print_json(&PushJson {
            remote: remote.name(),
            url: remote.url(),
            report: &report,
            secs,
        })?;
    }
    say!(
        ctx,
        "osms push: {} objects sent ({}), {} already on `{}`, {} records, in {secs:.2}s",
        report.objects_sent,
        human_bytes(report.bytes_sent),
        report.objects_present,
        remote.name(),
        report.records
    );
    Ok(ExitCode::SUCCESS)
}

/// What `osms pull` did to one instance.
#[derive(Debug, Serialize)]
#[serde(tag = "outcome", rename_all = "snake_case")]
enum PullOutcome {
    /// Its artifact was in the store already.
    Present,
    /// Its record and objects came from the remote.
    Pulled,
    /// The remote has no build of its key.
    NotOnRemote,
    /// An input is neither here nor on the remote, so its key is unknown.
    Blocked { input: String },
}

#[derive(Serialize)]
struct PullRow {
    instance: String,
    key: Option<Hash>,
    #[serde(flatten)]
    outcome: PullOutcome,
}

pub fn pull(ctx: &Context, args: &TransferArgs) -> Result<ExitCode> {
    let Transfer {
        started,
        plan,
        store,
        seeds,
        targets,
        remote,
        _lock,
    } = Transfer::begin(ctx, args)?;
    if store.is_read_only() {
        bail!(
            "store {} is read-only: nothing can be pulled into it\nhint: pull into a store that can be written (--store DIR)",
            store.root().display()
        );
    }
    let (rows, received, _) = pull_closure(
        &plan,
        &store,
        &seeds,
        &targets,
        &remote,
        &Bar::new(ctx, "pulling"),
    )?;
    let secs = started.elapsed().as_secs_f64();
    if args.json {
        print_json(&serde_json::json!({
            "remote": remote.name(),
            "url": remote.url(),
            "instances": rows,
            "objects_received": received.objects,
            "bytes_received": received.bytes,
            "secs": secs,
        }))?;
    }
    let pulled = rows
        .iter()
        .filter(|r| matches!(r.outcome, PullOutcome::Pulled))
        .count();
    let present = rows
        .iter()
        .filter(|r| matches!(r.outcome, PullOutcome::Present))
        .count();
    let lacking: Vec<&str> = rows
        .iter()
        .filter(|r| matches!(r.outcome, PullOutcome::NotOnRemote))
        .map(|r| r.instance.as_str())
        .collect();
    let blocked = rows
        .iter()
        .filter(|r| matches!(r.outcome, PullOutcome::Blocked { .. }))
        .count();
    say!(
        ctx,
        "osms pull: {pulled} pulled ({} objects, {}), {present} already here, {} not on `{}`{} (profile {}) in {secs:.2}s",
        received.objects,
        human_bytes(received.bytes),
        lacking.len(),
        remote.name(),
        if blocked > 0 {
            format!(", {blocked} downstream of those")
        } else {
            String::new()
        },
        plan.profile
    );
    if lacking.is_empty() {
        return Ok(ExitCode::SUCCESS);
    }
    errln!(
        "error: remote `{}` has no build of {}\nhint: {} builds them here (or `osms push` them from the store that built them)",
        remote.name(),
        lacking.join(", "),
        ctx.make_command(&targets.join(" "), &plan.profile)
    );
    Ok(ExitCode::from(EXIT_FAILURE))
}

/// Walks `targets`' instances from the first stage down, reading the remote's record of each
/// key the store lacks, then downloads every object those records name (at once) and writes the
/// records, which it returns with the rows. Callers hold the store's lock.
fn pull_closure(
    plan: &Plan,
    store: &Store,
    seeds: &[u64],
    targets: &[String],
    remote: &Remote,
    bar: &Bar,
) -> Result<(Vec<PullRow>, osms_remote::Received, Vec<Record>)> {
    let mut wanted: Vec<Record> = Vec::new();
    // Keys follow content: an instance's key is known once each input's content hash is, from
    // the store or from the remote's record.
    let mut known: BTreeMap<InstanceId, Hash> = BTreeMap::new();
    let mut rows = Vec::new();
    for id in plan.instances(targets, seeds)? {
        let instance = plan.display(id);
        let mut hashes = Vec::new();
        let mut blocked = None;
        for input in plan.input_instances(id, seeds) {
            match known.get(&input.id) {
                Some(h) => hashes.push((input.label, *h)),
                None => {
                    blocked = Some(plan.display(input.id));
                    break;
                }
            }
        }
        if let Some(input) = blocked {
            rows.push(PullRow {
                instance,
                key: None,
                outcome: PullOutcome::Blocked { input },
            });
            continue;
        }
        let key = plan.key(id, &hashes);
        if let Some(record) = intact(store, &key)? {
            known.insert(id, record.content_hash);
            rows.push(PullRow {
                instance,
                key: Some(key),
                outcome: PullOutcome::Present,
            });
            continue;
        }
        let outcome = match remote.record(&key)? {
            Some(record) => {
                known.insert(id, record.content_hash);
                wanted.push(record);
                PullOutcome::Pulled
            }
            None => PullOutcome::NotOnRemote,
        };
        rows.push(PullRow {
            instance,
            key: Some(key),
            outcome,
        });
    }
    // Every object at once (a walk needs only the records: keys follow content hashes), then
    // the records; a pull killed before the end leaves objects no record names yet, which the
    // next pull skips.
    let received = remote.download(store, &wanted, bar)?;
    Ok((rows, received, wanted))
}

/// For `osms make --executor slurm --remote NAME`: pulls what the remote holds of `targets`
/// (from the first stage down, as `osms pull` does, without failing on what it lacks) under
/// the store's lock, released before the cluster make takes it. The instances pulled, with
/// their bytes.
pub(crate) fn pull_before_cluster_make(
    ctx: &Context,
    plan: &Plan,
    store: &Store,
    seeds: &[u64],
    targets: &[String],
    remote: &Remote,
) -> Result<BTreeMap<String, u64>> {
    let _lock =
        store.lock(|| errln!("waiting for another osms process to release the store lock..."))?;
    let (rows, _, records) = pull_closure(
        plan,
        store,
        seeds,
        targets,
        remote,
        &Bar::new(ctx, "pulling"),
    )?;
    let sizes: BTreeMap<Hash, u64> = records.iter().map(|r| (r.key, r.size_bytes)).collect();
    Ok(rows
        .into_iter()
        .filter_map(|row| match (row.outcome, row.key) {
            (PullOutcome::Pulled, Some(key)) => Some((row.instance, sizes[&key])),
            _ => None,
        })
        .collect())
}

/// The record of `key` if the store holds it with every object intact.
fn intact(store: &Store, key: &Hash) -> Result<Option<Record>> {
    let Ok(Some(record)) = store.record(key) else {
        return Ok(None);
    };
    for hash in std::iter::once(&record.content_hash).chain(&record.parts) {
        if store.object_state_cached(hash)? != ObjectState::Present {
            return Ok(None);
        }
    }
    Ok(Some(record))
}

/// `osms make --remote`: the make's [`Fetch`], with one progress bar for all downloads.
pub(crate) struct MakeFetch {
    pub remote: Remote,
    pub bar: Bar,
}

impl Fetch for MakeFetch {
    fn fetch(&self, store: &Store, key: &Hash) -> Result<Option<(Record, u64)>, String> {
        match self.remote.fetch(store, key, &self.bar) {
            Ok(found) => Ok(found.map(|f| (f.record, f.bytes_received))),
            Err(e) => Err(e.to_string()),
        }
    }
}
