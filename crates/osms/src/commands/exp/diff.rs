//! `osms exp diff`: two experiments (or points) side by side, or one stage's success paired by
//! condition (`--paired`).

use std::collections::{BTreeMap, BTreeSet};
use std::process::ExitCode;

use anyhow::{Result, bail};
use osms_core::stats::MeanSd;
use osms_core::table::{Cell, Column, Layout, Table, Unit};
use osms_make::StoreObjects;
use osms_make::experiment::{self};
use osms_store::Store;
use serde::Serialize;

use super::rows::{point_spec, row_named};
use super::unknown_experiment;
use crate::cli::ExpDiffArgs;
use crate::commands::print_json;
use crate::context::Context;

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

pub(super) fn diff(ctx: &Context, args: &ExpDiffArgs) -> Result<ExitCode> {
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
