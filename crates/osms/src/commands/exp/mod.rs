//! `osms exp`: named experiments. `run` plans every sweep point, merges them into one graph
//! (shared upstream work builds once), builds it and records each point's instances; `show`
//! and `diff` read those records and the artifacts' summaries, never logs.

use std::collections::{BTreeMap, BTreeSet};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Result, bail};
use osms_core::stats::MeanSd;
use osms_core::table::{Cell, Column, Layout, Table, Unit, Value};
use osms_make::experiment::{self, Axis, Experiment, RECORD_VERSION};
use osms_make::{MakeOptions, Observer, Outcome, Pipeline, Plan, StoreObjects};
use osms_store::Store;
use serde::Serialize;

use crate::cli::{ExpCommand, ExpDiffArgs, ExpRmArgs, ExpRunArgs, ExpShowArgs};
use crate::commands::make::{failure_exit, foreign_mujoco};
use crate::commands::print_json;
use crate::context::{Context, parse_overrides};
use crate::progress::MakeObserver;

mod plot;

/// Kinds whose build time is training time: `train_secs` of a target is the build time of the
/// artifacts of these kinds it reads directly.
const TRAINING_KINDS: [&str; 3] = ["teacher", "student", "manifold"];

/// The metrics read from build records rather than summaries: `train_secs`, the training's
/// wall time, and `train_core_secs`, the CPU time of its threads (the same at any `--stages`
/// and whatever else ran beside it).
const TRAINING_TIMES: [&str; 2] = ["train_secs", "train_core_secs"];

pub fn run(ctx: &Context, command: ExpCommand) -> Result<ExitCode> {
    match command {
        ExpCommand::Run(args) => exp_run(ctx, &args),
        ExpCommand::Ls(args) => ls(ctx, args.json),
        ExpCommand::Show(args) => show(ctx, &args),
        ExpCommand::Diff(args) => diff(ctx, &args),
        ExpCommand::Plot(args) => plot::plot(ctx, &args),
        ExpCommand::Rm(args) => rm(ctx, &args),
    }
}

fn exp_run(ctx: &Context, args: &ExpRunArgs) -> Result<ExitCode> {
    let started = Instant::now();
    experiment::check_name(&args.name)?;
    let set = parse_overrides(&args.selection.set)?;
    let axes: Vec<Axis> = args
        .sweep
        .iter()
        .map(|a| a.parse::<Axis>())
        .collect::<std::result::Result<_, _>>()?;
    let mut knobs = BTreeSet::new();
    for a in &axes {
        if !knobs.insert(a.knob.clone()) {
            bail!(
                "--sweep names `{}` twice\nhint: list every value of a knob in one --sweep",
                a.knob
            );
        }
    }
    // Every point is planned before anything runs: a bad value fails here, naming its --sweep.
    let points = experiment::points(&axes);
    let pipeline = Pipeline::load(&ctx.pipeline_path, args.selection.profile.as_deref())?;
    let plans = points
        .iter()
        .map(|p| {
            let mut all = set.clone();
            all.extend(p.iter().cloned());
            ctx.plan_of(pipeline.clone(), &all)
        })
        .collect::<Result<Vec<Plan>>>()?;
    let targets = if args.targets.is_empty() {
        plans[0].experiment_targets.clone()
    } else {
        args.targets.clone()
    };
    if targets.is_empty() {
        bail!(
            "no targets: name the stages to build, or set `experiment_targets` under [pipeline] in {}\nhint: a development stream's evaluation, e.g. `osms exp run {} dev_teacher`",
            ctx.pipeline_path.display(),
            args.name
        );
    }
    let seeds = Context::seeds(&args.selection, &plans[0]);
    let profile_name = plans[0].profile.clone();
    let store = ctx.store()?;
    if !args.force && !args.dry_run && experiment::load(&store, &args.name)?.is_some() {
        bail!(
            "experiment `{}` exists\nhint: `osms exp run {} --force ...` replaces it, `osms exp rm {}` forgets it",
            args.name,
            args.name,
            args.name
        );
    }
    let (plan, maps) = Plan::merge(plans)?;
    if let Some(problem) = foreign_mujoco(&plan, osms_sim::MUJOCO_PINNED) {
        bail!("{problem}");
    }
    let point_targets: Vec<Vec<String>> = maps
        .iter()
        .map(|m| targets.iter().map(|t| plan.point_target(m, t)).collect())
        .collect();
    let all_targets: Vec<String> = point_targets.iter().flatten().cloned().collect();
    let needed = plan.instances(&all_targets, &seeds)?;
    let read: BTreeSet<&str> = needed
        .iter()
        .map(|id| plan.stages[id.stage].name.as_str())
        .collect();
    let reads_held_out: Vec<String> = plan
        .held_out
        .iter()
        .filter(|h| read.contains(h.as_str()))
        .cloned()
        .collect();
    if !reads_held_out.is_empty() && !ctx.quiet {
        errln!(
            "warning: experiment `{}` reads the held-out stage(s) {}: choosing a knob on them leaks the final tables' conditions\nhint: target a development stream (`[pipeline] experiment_targets`: {})",
            args.name,
            reads_held_out.join(", "),
            if plan.experiment_targets.is_empty() {
                "none declared".to_string()
            } else {
                plan.experiment_targets.join(", ")
            }
        );
    }
    if !ctx.quiet && points.len() > 1 {
        for (k, p) in points.iter().enumerate() {
            let shown: Vec<String> = p.iter().map(|o| o.to_string()).collect();
            errln!("point {k}: {}", shown.join(" "));
        }
    }

    let jobs = Context::jobs(args.jobs);
    let opts = MakeOptions {
        targets: all_targets,
        seeds: seeds.clone(),
        jobs,
        stages: crate::cli::Stages::resolve(args.stages, jobs),
        dry_run: args.dry_run,
    };
    let observer = MakeObserver::of(ctx);
    // The lock is held from the make through saving the record: a `gc` waiting for it would
    // otherwise run in between and remove the instances the record is about to name.
    let lock = if args.dry_run {
        None
    } else {
        let lock = store.lock(|| observer.waiting_for_lock())?;
        // Checked again under the lock: two runs of one name started together both passed
        // the check above.
        if !args.force && experiment::load(&store, &args.name)?.is_some() {
            bail!(
                "experiment `{}` was recorded by another osms process while this one waited for the store lock\nhint: `osms exp run {} --force ...` replaces it, or choose another name",
                args.name,
                args.name
            );
        }
        Some(lock)
    };
    let report = match &lock {
        Some(held) => osms_make::make_holding(&plan, &store, held, &opts, &observer)?,
        None => osms_make::make(&plan, &store, &opts, &observer)?,
    };
    let built = report.count(|o| matches!(o, Outcome::Built { .. }));
    let cached = report.count(|o| matches!(o, Outcome::Cached | Outcome::CutOff));
    let would = report.count(|o| matches!(o, Outcome::WouldBuild { .. }));
    let failed = report.failed();
    if args.dry_run {
        if !ctx.quiet {
            errln!(
                "osms exp run {}: {} point(s); {would} instance(s) would be built, {cached} cached (nothing recorded)",
                args.name,
                points.len()
            );
        }
        if args.json {
            print_json(&serde_json::json!({ "make": report }))?;
        }
        return Ok(ExitCode::SUCCESS);
    }

    let set_texts: Vec<String> = set.iter().map(|o| o.to_string()).collect();
    let mut recorded = Vec::with_capacity(points.len());
    for (k, point) in points.iter().enumerate() {
        let target_stages: Vec<usize> = targets
            .iter()
            .filter_map(|t| {
                maps[k]
                    .get(t.split(['#', '@']).next().unwrap_or(t))
                    .copied()
            })
            .collect();
        let mut overrides = set_texts.clone();
        overrides.extend(point.iter().map(|o| o.to_string()));
        recorded.push(experiment::point_record(
            &plan,
            &report,
            &point_targets[k],
            &seeds,
            &target_stages,
            point.iter().map(|o| o.value_text()).collect(),
            overrides,
        )?);
    }
    let exp = Experiment {
        version: RECORD_VERSION,
        name: args.name.clone(),
        profile: profile_name,
        targets,
        seeds,
        set: set_texts,
        axes: axes.iter().map(|a| a.knob.clone()).collect(),
        points: recorded,
        reads_held_out,
    };
    experiment::save(&store, &exp)?;
    drop(lock);
    if args.json {
        print_json(&serde_json::json!({ "experiment": exp, "make": report }))?;
    }
    if !ctx.quiet {
        errln!(
            "osms exp run {}: {} point(s), {built} built, {cached} cached{} in {:.2}s; `osms exp show {}` compares",
            args.name,
            exp.points.len(),
            if failed.is_empty() {
                String::new()
            } else {
                format!(", {} failed", failed.len())
            },
            started.elapsed().as_secs_f64(),
            args.name
        );
    }
    Ok(failure_exit(&failed))
}

fn ls(ctx: &Context, json: bool) -> Result<ExitCode> {
    let store = ctx.store()?;
    let exps = experiment::load_all(&store)?;
    if json {
        let listed: Vec<serde_json::Value> = exps
            .iter()
            .map(|e| {
                serde_json::json!({
                    "name": e.name,
                    "profile": e.profile,
                    "points": e.points.len(),
                    "seeds": e.seeds,
                    "targets": e.targets,
                    "set": e.set,
                    "sweep": e.axes,
                    "complete": e.points.iter().all(|p| p.failed.is_empty()),
                })
            })
            .collect();
        print_json(&listed)?;
        return Ok(ExitCode::SUCCESS);
    }
    let mut t = Table::new(
        "experiments",
        "Experiments",
        vec![
            Column::new("profile", Unit::Text),
            Column::new("points", Unit::Count),
            Column::new("seeds", Unit::Text),
            Column::new("targets", Unit::Text),
            Column::new("knobs", Unit::Text),
        ],
    );
    for e in &exps {
        let seeds: Vec<String> = e.seeds.iter().map(u64::to_string).collect();
        let mut knobs = e.set.clone();
        knobs.extend(e.axes.iter().map(|a| format!("{a}=(sweep)")));
        t.push(
            &e.name,
            vec![
                Cell::text(&e.profile),
                Cell::one(e.points.len() as f64),
                Cell::text(seeds.join(",")),
                Cell::text(e.targets.join(" ")),
                Cell::text(knobs.join(" ")),
            ],
        );
    }
    if exps.is_empty() {
        if !ctx.quiet {
            errln!("no experiments yet; `osms exp run NAME --set STAGE.PATH=VALUE` records one");
        }
    } else {
        out!("{}", t.markdown_with(Layout::plain("experiment")));
    }
    Ok(ExitCode::SUCCESS)
}

/// One row of `exp show`: an experiment, or one point of a sweep.
#[derive(Debug, Clone, Serialize)]
struct Row {
    experiment: String,
    /// The point's index in a sweep (`None` for an experiment of one point).
    point: Option<usize>,
    profile: String,
    seeds: Vec<u64>,
    /// Knob -> value for every override in force.
    params: BTreeMap<String, String>,
    /// Metric column -> its values (one per run seed and target instance).
    metrics: BTreeMap<String, Vec<f64>>,
    /// Summed build wall time of every instance of the point, shared upstream included.
    wall_secs: f64,
    /// Instances that failed: the metrics are partial.
    failed: Vec<String>,
    /// Target artifacts this osms cannot read (an older schema, say), with why: their metrics
    /// are missing.
    unreadable: Vec<String>,
    /// Rate metric column -> (successes, rollouts) pooled over the run seeds, for `--ci`.
    counts: BTreeMap<String, (u64, u64)>,
    /// Stage keys of the point's instances (for `diff`), not printed.
    #[serde(skip)]
    keys: BTreeSet<osms_store::Hash>,
}

impl Row {
    fn label(&self) -> String {
        match self.point {
            Some(k) => format!("{}/{k}", self.experiment),
            None => self.experiment.clone(),
        }
    }
}

/// A summary field as a number: `success`, `completion` and `f_max` are short for the
/// evaluations' `success_rate`, `completion_rate` and `f_max_n`; a dotted name reaches into
/// nested fields (`last_tenth.success_rate`).
fn summary_metric(summary: &serde_json::Value, metric: &str) -> Option<f64> {
    let long = match metric {
        "success" => "success_rate",
        "completion" => "completion_rate",
        "f_max" => "f_max_n",
        other => other,
    };
    [metric, long].iter().find_map(|name| {
        name.split('.')
            .try_fold(summary, |v, k| v.get(k))
            .and_then(serde_json::Value::as_f64)
    })
}

fn rows_of(ctx: &Context, store: &Store, exp: &Experiment, metrics: &[String]) -> Result<Vec<Row>> {
    (0..exp.points.len())
        .map(|k| point_row(ctx, store, exp, k, metrics))
        .collect()
}

/// The row of point `k`: its knobs, the metrics of its targets' summaries and build records.
fn point_row(
    ctx: &Context,
    store: &Store,
    exp: &Experiment,
    k: usize,
    metrics: &[String],
) -> Result<Row> {
    let objects = StoreObjects(store);
    let point = &exp.points[k];
    let wanted: Vec<&String> = metrics
        .iter()
        .filter(|m| !TRAINING_TIMES.contains(&m.as_str()))
        .collect();
    let target_stages: BTreeSet<&str> = point
        .instances
        .iter()
        .filter(|i| i.target)
        .map(|i| i.stage.as_str())
        .collect();
    let column = |metric: &str, stage: &str| {
        if target_stages.len() == 1 {
            metric.to_string()
        } else {
            format!("{metric} ({stage})")
        }
    };
    let mut values: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut wall_secs = 0.0;
    // Build time of every trained artifact of the point, by content hash: `train_secs` of a
    // target is that of the networks it reads directly (the student it evaluates).
    // (wall seconds, core-seconds) of each.
    let mut trained: BTreeMap<osms_store::Hash, (f64, f64)> = BTreeMap::new();
    let mut records = Vec::with_capacity(point.instances.len());
    let mut unreadable = Vec::new();
    let mut counts: BTreeMap<String, (u64, u64)> = BTreeMap::new();
    for i in &point.instances {
        let record = store.record(&i.key)?;
        let secs = record.as_ref().map_or(0.0, |r| r.wall_time_secs);
        wall_secs += secs;
        if TRAINING_KINDS.contains(&i.kind.as_str()) {
            let core = record.as_ref().and_then(|r| r.cpu_secs).unwrap_or(f64::NAN);
            trained.insert(i.content_hash, (secs, core));
        }
        records.push(record);
    }
    for (i, record) in point.instances.iter().zip(&records) {
        if !i.target {
            continue;
        }
        for (metric, core) in [("train_secs", false), ("train_core_secs", true)] {
            if !metrics.iter().any(|m| m == metric) {
                continue;
            }
            let secs: Vec<f64> = record
                .iter()
                .flat_map(|r| r.inputs.iter())
                .filter_map(|(_, h)| trained.get(h))
                .map(|&(wall, cpu)| if core { cpu } else { wall })
                .collect();
            // A record from before core-seconds were measured has none to show.
            if !secs.is_empty() && secs.iter().all(|s| s.is_finite()) {
                values
                    .entry(column(metric, &i.stage))
                    .or_default()
                    .push(secs.iter().sum());
            }
        }
        if wanted.is_empty() {
            continue;
        }
        let Some(kind) = ctx.registry.get(&i.kind) else {
            continue;
        };
        let bytes = store.get(&i.content_hash).map_err(|e| {
                anyhow::anyhow!(
                    "experiment `{}`: the artifact of `{}` is not readable ({e})\nhint: `osms exp run {} --force ...` builds it again",
                    exp.name,
                    i.instance,
                    exp.name
                )
            })?;
        // An artifact of an older schema (the code changed since the experiment ran) leaves
        // its metrics out of the row instead of failing every experiment's table.
        let summary = match kind.summarize(&bytes, &objects) {
            Ok(s) => s,
            Err(e) => {
                unreadable.push(format!("{}: {e}", i.instance));
                continue;
            }
        };
        let rollouts = summary_metric(&summary, "rollouts");
        for m in &wanted {
            if let Some(v) = summary_metric(&summary, m) {
                values.entry(column(m, &i.stage)).or_default().push(v);
                if let (Some(n), Unit::Percent) = (rollouts, unit_of(m)) {
                    let c = counts.entry(column(m, &i.stage)).or_default();
                    c.0 += (v * n).round() as u64;
                    c.1 += n as u64;
                }
            }
        }
    }
    Ok(Row {
        experiment: exp.name.clone(),
        point: (exp.points.len() > 1).then_some(k),
        profile: exp.profile.clone(),
        seeds: exp.seeds.clone(),
        params: point.knobs().into_iter().collect(),
        metrics: values,
        wall_secs,
        failed: point.failed.clone(),
        unreadable,
        counts,
        keys: point.instances.iter().map(|i| i.key).collect(),
    })
}

fn load_named(store: &Store, names: &[String]) -> Result<Vec<Experiment>> {
    if names.is_empty() {
        return Ok(experiment::load_all(store)?);
    }
    names
        .iter()
        .map(|n| experiment::load(store, n)?.ok_or_else(|| unknown_experiment(store, n)))
        .collect()
}

fn unknown_experiment(store: &Store, name: &str) -> anyhow::Error {
    let known = experiment::names(store).unwrap_or_default();
    anyhow::anyhow!(
        "no experiment `{name}` in {}\nhint: {}",
        store.root().display(),
        if known.is_empty() {
            "there are none yet; `osms exp run NAME ...` records one".to_string()
        } else {
            format!("experiments are {}", known.join(", "))
        }
    )
}

fn unit_of(metric: &str) -> Unit {
    let base = metric.split(" (").next().unwrap_or(metric);
    match base {
        "success" | "completion" => Unit::Percent,
        m if m.ends_with("_rate") => Unit::Percent,
        m if m.ends_with("_secs") => Unit::Number(2),
        "f_max" => Unit::Number(1),
        m if m.starts_with("failures.") => Unit::Number(0),
        _ => Unit::Number(3),
    }
}

/// The rows as one table: a column per knob that any row sets, then the metrics (with `ci`,
/// each rate followed by its 95 % Wilson interval and n over the pooled rollouts), then the
/// wall time.
fn table(rows: &[Row], metrics: &[String], ci: bool) -> Table {
    let mut knobs: Vec<&String> = Vec::new();
    for r in rows {
        for k in r.params.keys() {
            if !knobs.contains(&k) {
                knobs.push(k);
            }
        }
    }
    let mut metric_columns: Vec<&String> = Vec::new();
    for m in metrics {
        for r in rows {
            for c in r.metrics.keys() {
                let matches = c == m || c.starts_with(&format!("{m} ("));
                if matches && !metric_columns.contains(&c) {
                    metric_columns.push(c);
                }
            }
        }
    }
    let mut columns: Vec<Column> = knobs.iter().map(|k| Column::new(*k, Unit::Text)).collect();
    let interval = |m: &str| ci && rows.iter().any(|r| r.counts.contains_key(m));
    for m in &metric_columns {
        columns.push(Column::new(*m, unit_of(m)));
        if interval(m) {
            columns.push(Column::new(format!("{m} 95% CI (n)"), Unit::Text));
        }
    }
    columns.push(Column::new("wall_secs", Unit::Number(1)));
    let mut t = Table::new("experiments", "Experiments", columns);
    for r in rows {
        let mut cells: Vec<Cell> = knobs
            .iter()
            .map(|k| Cell::text(r.params.get(*k).cloned().unwrap_or_else(|| "-".into())))
            .collect();
        for m in &metric_columns {
            cells.push(Cell::ours(match r.metrics.get(*m) {
                None => Value::Missing,
                // One value of a several-seed row is shown as such ("(1 seed)").
                Some(v) if v.len() == 1 && r.seeds.len() == 1 => Value::One(v[0]),
                Some(v) => Value::Seeds(v.clone()),
            }));
            if interval(m) {
                cells.push(Cell::text(match r.counts.get(*m) {
                    Some(&(x, n)) if n > 0 => {
                        let z = osms_core::stats::normal_quantile(0.975);
                        let (lo, hi) = osms_core::stats::wilson(x as usize, n as usize, z);
                        format!("{:.1}–{:.1}% ({n})", 100.0 * lo, 100.0 * hi)
                    }
                    _ => "-".into(),
                }));
            }
        }
        cells.push(Cell::one(r.wall_secs));
        let label = if !r.failed.is_empty() {
            format!("{} (incomplete)", r.label())
        } else if !r.unreadable.is_empty() {
            format!("{} (stale)", r.label())
        } else {
            r.label()
        };
        t.push(label, cells);
    }
    t.with_note(
        "`-` under a knob: the pipeline's value; under a metric: none (no catch completed, say, so no f_max). Metrics over several run seeds read mean ± sd; a 95% CI is a Wilson interval over the rollouts pooled over the run seeds (rollout noise only: the seed spread is in the sd); `(stale)`: a target this osms cannot read any more, its metrics left out (`osms exp run NAME --force` rebuilds them); wall_secs sums the build time of every instance of the row, shared upstream included.",
    )
}

fn show(ctx: &Context, args: &ExpShowArgs) -> Result<ExitCode> {
    let store = ctx.store()?;
    let exps = load_named(&store, &args.names)?;
    let mut rows = Vec::new();
    for e in &exps {
        rows.extend(rows_of(ctx, &store, e, &args.metrics)?);
    }
    if !ctx.quiet {
        for r in &rows {
            for why in &r.unreadable {
                errln!("warning: {}: {why}", r.label());
            }
        }
    }
    if args.json {
        print_json(&serde_json::json!({ "rows": rows }))?;
    } else if args.csv {
        out!(
            "{}",
            table(&rows, &args.metrics, args.ci).wide_csv("experiment")
        );
    } else if rows.is_empty() {
        if !ctx.quiet {
            errln!("no experiments yet; `osms exp run NAME --set STAGE.PATH=VALUE` records one");
        }
    } else {
        out!(
            "{}",
            table(&rows, &args.metrics, args.ci).markdown_with(Layout::plain("experiment"))
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// `NAME` (an experiment of one point) or `NAME/k`.
/// `NAME` or `NAME/k`: an experiment, or one point of it.
fn point_spec(spec: &str) -> Result<(&str, Option<usize>)> {
    match spec.rsplit_once('/') {
        Some((n, k)) => match k.parse::<usize>() {
            Ok(k) => Ok((n, Some(k))),
            Err(_) => bail!("`{spec}`: `{k}` is not a point\nhint: write NAME/0, NAME/1, ..."),
        },
        None => Ok((spec, None)),
    }
}

fn row_named(ctx: &Context, store: &Store, spec: &str, metrics: &[String]) -> Result<Row> {
    let (name, point) = point_spec(spec)?;
    let exp = experiment::load(store, name)?.ok_or_else(|| unknown_experiment(store, name))?;
    let n = exp.points.len();
    match (point, n) {
        (None, 1) => point_row(ctx, store, &exp, 0, metrics),
        (None, _) => bail!(
            "experiment `{name}` has {n} points\nhint: name one: {name}/0 .. {name}/{}",
            n - 1
        ),
        (Some(k), _) if k < n => point_row(ctx, store, &exp, k, metrics),
        (Some(k), _) => bail!(
            "experiment `{name}` has points 0 to {}, not {k}",
            n.saturating_sub(1)
        ),
    }
}

/// One metric in two rows: the means and b - a.
#[derive(Debug, Serialize)]
struct Delta {
    a: Option<f64>,
    b: Option<f64>,
    delta: Option<f64>,
}

#[derive(Debug, Serialize)]
struct Diff {
    a: String,
    b: String,
    /// Knob -> (value in a, value in b), for the knobs whose values differ (`None`: the
    /// pipeline's value).
    params: BTreeMap<String, (Option<String>, Option<String>)>,
    metrics: BTreeMap<String, Delta>,
    shared_instances: usize,
    instances: (usize, usize),
}

fn diff(ctx: &Context, args: &ExpDiffArgs) -> Result<ExitCode> {
    let store = ctx.store()?;
    if let Some(stage) = &args.paired {
        return paired(&store, args, stage);
    }
    let a = row_named(ctx, &store, &args.a, &args.metrics)?;
    let b = row_named(ctx, &store, &args.b, &args.metrics)?;
    let knobs: BTreeSet<&String> = a.params.keys().chain(b.params.keys()).collect();
    let params = knobs
        .into_iter()
        .filter(|k| a.params.get(*k) != b.params.get(*k))
        .map(|k| {
            (
                k.clone(),
                (a.params.get(k).cloned(), b.params.get(k).cloned()),
            )
        })
        .collect();
    let mean = |v: Option<&Vec<f64>>| v.and_then(|v| MeanSd::of(v)).map(|s| s.mean);
    let columns: BTreeSet<&String> = a.metrics.keys().chain(b.metrics.keys()).collect();
    let metrics = columns
        .into_iter()
        .map(|m| {
            let (x, y) = (mean(a.metrics.get(m)), mean(b.metrics.get(m)));
            let delta = x.zip(y).map(|(x, y)| y - x);
            (m.clone(), Delta { a: x, b: y, delta })
        })
        .collect();
    let d = Diff {
        a: a.label(),
        b: b.label(),
        params,
        metrics,
        shared_instances: a.keys.intersection(&b.keys).count(),
        instances: (a.keys.len(), b.keys.len()),
    };
    if args.json {
        print_json(&d)?;
        return Ok(ExitCode::SUCCESS);
    }
    let mut knobs = Table::new(
        "params",
        "Knobs that differ",
        vec![Column::new(&d.a, Unit::Text), Column::new(&d.b, Unit::Text)],
    );
    let shown = |v: &Option<String>| Cell::text(v.clone().unwrap_or_else(|| "-".into()));
    for (k, (x, y)) in &d.params {
        knobs.push(k, vec![shown(x), shown(y)]);
    }
    let mut deltas = Table::new(
        "metrics",
        "Metrics",
        vec![
            Column::new(&d.a, Unit::Number(4)),
            Column::new(&d.b, Unit::Number(4)),
            Column::new("b - a", Unit::Number(4)),
        ],
    );
    for (m, v) in &d.metrics {
        deltas.push(m, vec![Cell::opt(v.a), Cell::opt(v.b), Cell::opt(v.delta)]);
    }
    if d.params.is_empty() {
        outln!("the same knobs\n");
    } else {
        outln!("{}", knobs.markdown_with(Layout::plain("knob")));
    }
    outln!("{}", deltas.markdown_with(Layout::plain("metric")));
    outln!(
        "shared instances: {} ({} in {}, {} in {})",
        d.shared_instances,
        d.instances.0,
        d.a,
        d.instances.1,
        d.b
    );
    Ok(ExitCode::SUCCESS)
}

/// `exp diff --paired`: B − A in STAGE's success, paired by condition.
#[derive(Debug, Serialize)]
struct Paired {
    stage: String,
    a: PairedSide,
    b: PairedSide,
    /// The conditions' content hash every evaluation rolled out on.
    conditions: String,
    difference: osms_core::stats::Difference,
}

#[derive(Debug, Serialize)]
struct PairedSide {
    label: String,
    /// `point: instance` of each evaluation, one per seed.
    evaluations: Vec<String>,
    /// Success of each, in the same order.
    success: Vec<f64>,
}

fn paired(store: &Store, args: &ExpDiffArgs, stages: &str) -> Result<ExitCode> {
    // `A_STAGE:B_STAGE` pairs two stages (Ours-IL against Naive-IL, within one experiment too).
    let (stage_a, stage_b) = match stages.split_once(':') {
        Some((a, b)) if !a.is_empty() && !b.is_empty() => (a, b),
        Some(_) => bail!(
            "--paired `{stages}`: write STAGE, or A_STAGE:B_STAGE to compare two stages (e.g. `dev_student_naive:dev_student`)"
        ),
        None => (stages, stages),
    };
    let mut conditions: Option<osms_store::Hash> = None;
    let mut side = |spec: &str, stage: &str| -> Result<(PairedSide, Vec<Vec<f64>>)> {
        let (name, only) = point_spec(spec)?;
        let exp = experiment::load(store, name)?.ok_or_else(|| unknown_experiment(store, name))?;
        if let Some(k) = only.filter(|&k| k >= exp.points.len()) {
            bail!("experiment `{name}` has no point {k}");
        }
        let mut evaluations = Vec::new();
        let mut values = Vec::new();
        // An instance the sweep does not change is shared by every point: one seed, not several.
        let mut seen = BTreeSet::new();
        for (k, point) in exp.points.iter().enumerate() {
            if only.is_some_and(|o| o != k) {
                continue;
            }
            for i in point
                .instances
                .iter()
                .filter(|i| i.stage == stage && seen.insert(i.key))
            {
                let record = store.record(&i.key)?.ok_or_else(|| {
                    anyhow::anyhow!(
                        "{name}/{k}: `{}` has no build record\nhint: rerun `osms exp run {name}`",
                        i.instance
                    )
                })?;
                let Some(&(_, on)) = record.inputs.iter().find(|(n, _)| n == "conditions") else {
                    bail!(
                        "`{stage}` ({}) has no `conditions` input: only evaluations pair by condition",
                        i.kind
                    );
                };
                match conditions {
                    None => conditions = Some(on),
                    Some(c) if c != on => bail!(
                        "{name}/{k}: `{}` rolled out on other conditions ({}) than the first evaluation ({})\nhint: pair evaluations of one condition set",
                        i.instance,
                        on.short(),
                        c.short()
                    ),
                    Some(_) => {}
                }
                let eval: osms_sim::artifacts::Evaluation =
                    osms_make::assemble(&store.get(&i.content_hash)?, &StoreObjects(store))
                        .map_err(|e| anyhow::anyhow!("{name}/{k}: `{}`: {e}", i.instance))?;
                let s: Vec<f64> = eval
                    .rows
                    .iter()
                    .map(|r| f64::from(u8::from(r.outcome.success())))
                    .collect();
                evaluations.push(format!("{k}: {}", i.instance));
                values.push(s);
            }
        }
        if values.is_empty() {
            bail!(
                "`{spec}` has no instance of `{stage}`\nhint: `osms exp show {name}` lists its targets"
            );
        }
        let success = values
            .iter()
            .map(|v| v.iter().sum::<f64>() / v.len().max(1) as f64)
            .collect();
        Ok((
            PairedSide {
                label: spec.to_string(),
                evaluations,
                success,
            },
            values,
        ))
    };
    let (a, va) = side(&args.a, stage_a)?;
    let (b, vb) = side(&args.b, stage_b)?;
    let Some(difference) = osms_core::stats::paired_difference(&vb, &va) else {
        bail!("`{stages}`: fewer than two conditions to pair");
    };
    let d = Paired {
        stage: stages.to_string(),
        a,
        b,
        conditions: conditions.map(|c| c.to_string()).unwrap_or_default(),
        difference,
    };
    if args.json {
        print_json(&d)?;
        return Ok(ExitCode::SUCCESS);
    }
    let pct = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{:.1} %", 100.0 * x))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mean = |v: &[f64]| 100.0 * v.iter().sum::<f64>() / v.len().max(1) as f64;
    for (s, stage) in [(&d.a, stage_a), (&d.b, stage_b)] {
        outln!(
            "{}: {} evaluation(s) of {stage}: {} (mean {:.1} %)",
            s.label,
            s.evaluations.len(),
            pct(&s.success),
            mean(&s.success)
        );
    }
    let x = &d.difference;
    outln!(
        "b - a: {:+.1} points, 95 % [{:+.1}, {:+.1}] (paired on {} conditions; seeds {} and {})",
        100.0 * x.estimate,
        100.0 * x.low,
        100.0 * x.high,
        x.n[0],
        x.seeds[1],
        x.seeds[0]
    );
    Ok(ExitCode::SUCCESS)
}

fn rm(ctx: &Context, args: &ExpRmArgs) -> Result<ExitCode> {
    let store = ctx.store()?;
    for name in &args.names {
        if experiment::load(&store, name)?.is_none() {
            return Err(unknown_experiment(&store, name));
        }
    }
    let _lock = store.lock(|| MakeObserver::of(ctx).waiting_for_lock())?;
    for name in &args.names {
        experiment::remove(&store, name)?;
        if !ctx.quiet {
            errln!("osms exp rm: forgot `{name}`; `osms gc` removes what only it kept");
        }
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_metric_names_reach_the_summaries_fields() {
        let s = serde_json::json!({
            "success_rate": 0.5, "completion_rate": 0.25, "f_max_n": 12.0,
            "last_tenth": { "return": 3.0 }, "rollouts": 40
        });
        assert_eq!(summary_metric(&s, "success"), Some(0.5));
        assert_eq!(summary_metric(&s, "completion"), Some(0.25));
        assert_eq!(summary_metric(&s, "f_max"), Some(12.0));
        assert_eq!(summary_metric(&s, "rollouts"), Some(40.0));
        assert_eq!(summary_metric(&s, "last_tenth.return"), Some(3.0));
        assert_eq!(summary_metric(&s, "missing"), None);
        assert_eq!(unit_of("success (eval)"), Unit::Percent);
        assert_eq!(unit_of("train_secs"), Unit::Number(2));
        assert_eq!(unit_of("f_max"), Unit::Number(1));
    }

    pub(super) fn row(
        point: Option<usize>,
        params: &[(&str, &str)],
        metrics: &[(&str, &[f64])],
    ) -> Row {
        Row {
            experiment: "e".into(),
            point,
            profile: "tiny".into(),
            seeds: vec![0, 1],
            params: params
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect(),
            metrics: metrics
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_vec()))
                .collect(),
            wall_secs: 2.0,
            failed: vec![],
            unreadable: vec![],
            counts: BTreeMap::new(),
            keys: BTreeSet::new(),
        }
    }

    #[test]
    fn the_table_has_a_column_per_knob_and_metric_and_reads_mean_sd_over_seeds() {
        let rows = [
            row(Some(0), &[("s.steps", "10")], &[("success", &[0.5, 0.7])]),
            row(
                Some(1),
                &[("s.steps", "20"), ("t.lr", "0.1")],
                &[("success", &[0.9])],
            ),
        ];
        let t = table(&rows, &["success".into()], false);
        let md = t.markdown_with(Layout::plain("experiment"));
        assert!(
            md.starts_with("| experiment | s.steps | t.lr | success | wall_secs |"),
            "{md}"
        );
        assert!(
            md.contains("| e/0 | 10 | - | 60.0% ± 14.1% | 2.0 |"),
            "{md}"
        );
        assert!(
            md.contains("| e/1 | 20 | 0.1 | 90.0% (1 seed) | 2.0 |"),
            "{md}"
        );
    }

    /// `--ci`: the Wilson interval of the pooled counts (Newcombe 1998's example: 81 of 263,
    /// 25.5–36.6 %), and a stale row is labelled as such.
    #[test]
    fn intervals_pool_the_rollouts_and_stale_rows_say_so() {
        let mut a = row(None, &[], &[("success", &[0.308])]);
        a.counts.insert("success".into(), (81, 263));
        let mut b = row(None, &[], &[]);
        b.experiment = "old".into();
        b.unreadable.push("dev_student: schema 3".into());
        let md =
            table(&[a, b], &["success".into()], true).markdown_with(Layout::plain("experiment"));
        assert!(md.contains("| success | success 95% CI (n) |"), "{md}");
        assert!(md.contains("| 25.5–36.6% (263) |"), "{md}");
        assert!(md.contains("| old (stale) |"), "{md}");
    }
}
