//! `osms exp run`: plans every sweep point, merges them into one graph (shared upstream work
//! builds once), builds it and records each point's instances.

use std::collections::BTreeSet;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Result, bail};
use osms_make::experiment::{self, Axis, RunSpec, Sweep};
use osms_make::{MakeOptions, Outcome, Pipeline, Plan};

use crate::cli::ExpRunArgs;
use crate::commands::make::{failure_exit, foreign_mujoco, print_estimate};
use crate::commands::print_json;
use crate::context::{Context, parse_overrides};
use crate::progress::MakeObserver;

pub(super) fn exp_run(ctx: &Context, args: &ExpRunArgs) -> Result<ExitCode> {
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
    if !args.dry_run {
        experiment::check_free(&store, &args.name, args.force)?;
    }
    let (plan, maps) = Plan::merge(plans)?;
    if let Some(problem) = foreign_mujoco(&plan, osms_sim::MUJOCO_PINNED) {
        bail!("{problem}");
    }
    let sweep = Sweep::new(plan, maps, &targets, &seeds)?;
    if !sweep.reads_held_out.is_empty() {
        say!(
            ctx,
            "warning: experiment `{}` reads the held-out stage(s) {}: choosing a knob on them leaks the final tables' conditions\nhint: target a development stream (`[pipeline] experiment_targets`: {})",
            args.name,
            sweep.reads_held_out.join(", "),
            if sweep.plan.experiment_targets.is_empty() {
                "none declared".to_string()
            } else {
                sweep.plan.experiment_targets.join(", ")
            }
        );
    }
    if points.len() > 1 {
        for (k, p) in points.iter().enumerate() {
            let shown: Vec<String> = p.iter().map(|o| o.to_string()).collect();
            say!(ctx, "point {k}: {}", shown.join(" "));
        }
    }

    let jobs = Context::jobs(args.jobs);
    let opts = MakeOptions {
        targets: sweep.all_targets(),
        seeds: seeds.clone(),
        jobs,
        stages: crate::cli::Stages::resolve(args.stages, jobs),
        dry_run: args.dry_run,
    };
    let observer = MakeObserver::of(ctx);
    if args.dry_run {
        let report = osms_make::make(&sweep.plan, &store, &opts, &observer)?;
        let cached = report.count(|o| matches!(o, Outcome::Cached | Outcome::CutOff));
        let would = report.count(|o| matches!(o, Outcome::WouldBuild { .. }));
        let estimate = estimate(ctx, &sweep.plan, &store, &report, &seeds)?;
        say!(
            ctx,
            "osms exp run {}: {} point(s); {would} instance(s) would be built, {cached} cached (nothing recorded)",
            args.name,
            points.len()
        );
        if args.json {
            print_json(&serde_json::json!({ "make": report, "estimate": estimate }))?;
        } else if ctx.printer.says() {
            print_estimate(&estimate);
        }
        return Ok(ExitCode::SUCCESS);
    }
    let spec = RunSpec {
        name: &args.name,
        profile: profile_name,
        targets,
        seeds,
        set: &set,
        axes: &axes,
        points: &points,
        force: args.force,
    };
    let (exp, report) = experiment::run(&store, &sweep, spec, &opts, &observer)?;
    let built = report.count(|o| matches!(o, Outcome::Built { .. }));
    let cached = report.count(|o| matches!(o, Outcome::Cached | Outcome::CutOff));
    let failed = report.failed();
    if args.json {
        print_json(&serde_json::json!({ "experiment": exp, "make": report }))?;
    }
    say!(
        ctx,
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
    Ok(failure_exit(&failed))
}

/// The core-hours a dry run's builds would take, scaled from the builds of every profile and of
/// every recorded experiment's points (a sweep's new point is measured by its siblings'
/// builds). A record whose overrides no longer plan (the pipeline changed) measures nothing.
fn estimate(
    ctx: &Context,
    plan: &Plan,
    store: &osms_store::Store,
    report: &osms_make::MakeReport,
    seeds: &[u64],
) -> Result<osms_make::Estimate> {
    let mut recorded = Vec::new();
    for exp in experiment::load_all(store)? {
        let Ok(pipeline) = Pipeline::load(&ctx.pipeline_path, Some(&exp.profile)) else {
            continue;
        };
        for point in &exp.points {
            let Ok(overrides) = parse_overrides(&point.overrides) else {
                continue;
            };
            if let Ok(mut p) = ctx.plan_of(pipeline.clone(), &overrides) {
                p.profile = format!("{}, experiment {}", exp.profile, exp.name);
                recorded.push(p);
            }
        }
    }
    crate::commands::make::estimate(ctx, plan, store, report, seeds, recorded)
}
