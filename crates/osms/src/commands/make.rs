use std::process::ExitCode;
use std::time::Instant;

use anyhow::Result;
use osms_make::{MakeOptions, Outcome};

use crate::EXIT_FAILURE;
use crate::cli::MakeArgs;
use crate::commands::print_json;
use crate::context::Context;
use crate::progress::MakeObserver;

pub fn run(ctx: &Context, args: &MakeArgs) -> Result<ExitCode> {
    let started = Instant::now();
    let plan = ctx.plan(args.selection.profile.as_deref())?;
    let store = ctx.store()?;
    let seeds = Context::seeds(&args.selection, &plan);
    let jobs = args.jobs.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    let opts = MakeOptions {
        targets: args.targets.clone(),
        seeds: seeds.clone(),
        jobs,
        dry_run: args.dry_run,
    };
    let observer = MakeObserver {
        show_progress: ctx.progress,
        quiet: ctx.quiet,
        verbose: ctx.verbose,
    };
    let report = osms_make::make(&plan, &store, &opts, &observer)?;

    if args.json {
        print_json(&report)?;
    }
    let built = report.count(|o| matches!(o, Outcome::Built { .. }));
    let cached = report.count(|o| matches!(o, Outcome::Cached));
    let cut = report.count(|o| matches!(o, Outcome::CutOff));
    let failed = report.failed();
    if !ctx.quiet {
        let seeds_text = seeds
            .iter()
            .map(u64::to_string)
            .collect::<Vec<_>>()
            .join(",");
        let what = if args.dry_run {
            format!(
                "{} would be built",
                report.count(|o| matches!(o, Outcome::WouldBuild { .. }))
            )
        } else {
            format!("{built} built")
        };
        let failed_text = if failed.is_empty() {
            String::new()
        } else {
            format!(", {} failed", failed.len())
        };
        let skipped = report.count(|o| matches!(o, Outcome::Skipped { .. }));
        let skipped_text = if skipped == 0 {
            String::new()
        } else {
            format!(", {skipped} skipped")
        };
        eprintln!(
            "osms make: {what}, {cached} cached, {cut} cut off{failed_text}{skipped_text} (profile {}, seed {seeds_text}) in {:.2}s",
            plan.profile,
            started.elapsed().as_secs_f64()
        );
        if report.instances.is_empty() {
            eprintln!(
                "hint: {} declares no stages yet",
                ctx.pipeline_path.display()
            );
        }
    }
    if failed.is_empty() {
        Ok(ExitCode::SUCCESS)
    } else {
        eprintln!(
            "error: {} stage(s) failed: {}",
            failed.len(),
            failed.join(", ")
        );
        Ok(ExitCode::from(EXIT_FAILURE))
    }
}
