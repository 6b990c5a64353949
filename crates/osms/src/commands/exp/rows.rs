//! An experiment's rows: each point's knobs, the metrics of its targets' summaries and build
//! records, and the table `exp show` prints (`exp diff` and `exp plot` read the same rows).

use std::collections::{BTreeMap, BTreeSet};

use anyhow::{Result, bail};
use osms_core::table::{Cell, Column, Table, Unit, Value};
use osms_make::StoreObjects;
use osms_make::experiment::{self, Experiment};
use osms_store::Store;
use serde::Serialize;

use super::unknown_experiment;
use crate::context::Context;

/// Kinds whose build time is training time: `train_secs` of a target is the build time of the
/// artifacts of these kinds it reads directly.
const TRAINING_KINDS: [&str; 3] = ["teacher", "student", "manifold"];

/// The metrics read from build records rather than summaries: `train_secs`, the training's
/// wall time, and `train_core_secs`, the CPU time of its threads (the same at any `--stages`
/// and whatever else ran beside it).
const TRAINING_TIMES: [&str; 2] = ["train_secs", "train_core_secs"];

/// One row of `exp show`: an experiment, or one point of a sweep.
#[derive(Debug, Clone, Serialize)]
pub(super) struct Row {
    pub experiment: String,
    /// The point's index in a sweep (`None` for an experiment of one point).
    pub point: Option<usize>,
    pub profile: String,
    pub seeds: Vec<u64>,
    /// Knob -> value for every override in force.
    pub params: BTreeMap<String, String>,
    /// Metric column -> its values (one per run seed and target instance).
    pub metrics: BTreeMap<String, Vec<f64>>,
    /// Summed build wall time of every instance of the point, shared upstream included.
    pub wall_secs: f64,
    /// Instances that failed: the metrics are partial.
    pub failed: Vec<String>,
    /// Target artifacts this osms cannot read (an older schema, say), with why: their metrics
    /// are missing.
    pub unreadable: Vec<String>,
    /// Rate metric column -> (successes, rollouts) pooled over the run seeds, for `--ci`.
    pub counts: BTreeMap<String, (u64, u64)>,
    /// Stage keys of the point's instances (for `diff`), not printed.
    #[serde(skip)]
    pub keys: BTreeSet<osms_store::Hash>,
}

impl Row {
    pub(super) fn label(&self) -> String {
        match self.point {
            Some(k) => format!("{}/{k}", self.experiment),
            None => self.experiment.clone(),
        }
    }
}

/// A summary field as a number: `success`, `completion` and `f_max` are short for the
/// evaluations' `success_rate`, `completion_rate` and `f_max_n`; a dotted name reaches into
/// nested fields (`last_tenth.success_rate`).
pub(super) fn summary_metric(summary: &serde_json::Value, metric: &str) -> Option<f64> {
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

pub(super) fn rows_of(
    ctx: &Context,
    store: &Store,
    exp: &Experiment,
    metrics: &[String],
) -> Result<Vec<Row>> {
    (0..exp.points.len())
        .map(|k| point_row(ctx, store, exp, k, metrics))
        .collect()
}

/// The row of point `k`: its knobs, the metrics of its targets' summaries and build records.
pub(super) fn point_row(
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

pub(super) fn unit_of(metric: &str) -> Unit {
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
pub(super) fn table(rows: &[Row], metrics: &[String], ci: bool) -> Table {
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

/// `NAME` or `NAME/k`: an experiment, or one point of it.
pub(super) fn point_spec(spec: &str) -> Result<(&str, Option<usize>)> {
    match spec.rsplit_once('/') {
        Some((n, k)) => match k.parse::<usize>() {
            Ok(k) => Ok((n, Some(k))),
            Err(_) => bail!("`{spec}`: `{k}` is not a point\nhint: write NAME/0, NAME/1, ..."),
        },
        None => Ok((spec, None)),
    }
}

pub(super) fn row_named(
    ctx: &Context,
    store: &Store,
    spec: &str,
    metrics: &[String],
) -> Result<Row> {
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

#[cfg(test)]
pub(super) mod tests {
    use osms_core::table::Layout;

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

    pub(in crate::commands::exp) fn row(
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
