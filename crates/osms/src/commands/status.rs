//! `osms status`: which stages are cached, stale (and why) or missing, and what a cluster is
//! doing for them.

use std::process::ExitCode;

use anyhow::Result;
use osms_make::slurm::ClusterStatus;
use osms_make::slurm::cmd::SlurmCli;
use osms_make::{State, describe};

use crate::EXIT_FAILURE;
use crate::cli::StatusArgs;
use crate::commands::print_json;
use crate::context::Context;

pub fn status(ctx: &Context, args: &StatusArgs) -> Result<ExitCode> {
    let plan = ctx.selected_plan(&args.selection)?;
    let store = ctx.store()?;
    let seeds = Context::seeds(&args.selection, &plan);
    let statuses = osms_make::status(&plan, &store, &args.targets, &seeds)?;
    let not_up_to_date = statuses.iter().filter(|s| s.state != State::Cached).count();
    let cluster = cluster(&store);
    if args.json {
        // Each instance with jobs on a cluster gains a `cluster` object.
        let mut value = serde_json::to_value(&statuses)?;
        if let (Some(items), Ok(cluster)) = (value.as_array_mut(), &cluster) {
            for item in items {
                let key = item.get("key").and_then(|k| k.as_str()).map(str::to_string);
                if let Some(c) = cluster.iter().find(|c| Some(c.key.to_hex()) == key) {
                    item["cluster"] = serde_json::to_value(c)?;
                }
            }
        }
        print_json(&value)?;
    } else if ctx.printer.says() {
        if not_up_to_date == 0 {
            outln!(
                "Everything is up to date ({} stages, profile {}).",
                statuses.len(),
                plan.profile
            );
        } else {
            for s in &statuses {
                let hash = s
                    .content_hash
                    .map(|h| h.short())
                    .unwrap_or_else(|| "-".into());
                match s.state {
                    State::Cached => {
                        if ctx.printer.verbose {
                            outln!("{:<8} {} {hash}", "cached", s.instance);
                        }
                    }
                    State::Stale | State::Missing => {
                        let state = if s.state == State::Stale {
                            "stale"
                        } else {
                            "missing"
                        };
                        outln!("{state:<8} {}: {}", s.instance, describe(&s.reasons));
                    }
                }
            }
            match &cluster {
                Ok(cluster) => {
                    for c in cluster {
                        outln!("{:<8} {}", "slurm", describe_cluster(c));
                    }
                }
                Err(e) => outln!("{:<8} cannot ask Slurm: {e}", "slurm"),
            }
            let cached = statuses.len() - not_up_to_date;
            outln!(
                "{not_up_to_date} of {} stages not up to date, {cached} cached (profile {}).",
                statuses.len(),
                plan.profile
            );
        }
    }
    // As `dvc status -q`: the exit code says whether anything would run.
    if !ctx.printer.says() && not_up_to_date > 0 {
        Ok(ExitCode::from(EXIT_FAILURE))
    } else {
        Ok(ExitCode::SUCCESS)
    }
}

/// What the cluster is doing for the instances with jobs on record (nothing, and no call to
/// Slurm, when there are none).
fn cluster(store: &osms_store::Store) -> Result<Vec<ClusterStatus>, osms_make::Error> {
    osms_make::slurm::cluster_status(store, &SlurmCli)
}

fn describe_cluster(c: &ClusterStatus) -> String {
    let mut text = format!("{}: ", c.instance);
    if let Some(array) = c.array_job {
        text.push_str(&format!(
            "shards {}/{} done, {} running, {} submitted",
            c.shards_done, c.shards, c.shards_running, c.shards_submitted
        ));
        if !c.shards_failed.is_empty() {
            let failed: Vec<String> = c.shards_failed.iter().map(u32::to_string).collect();
            text.push_str(&format!(", failed {}", failed.join(",")));
        }
        text.push_str(&format!(" (array job {array}); "));
    }
    text.push_str(&format!("job {} {}", c.job, c.job_state.to_lowercase()));
    if !c.reason.is_empty() && c.reason != "None" {
        text.push_str(&format!(" ({})", c.reason));
    }
    text
}
