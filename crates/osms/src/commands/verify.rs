use std::process::ExitCode;

use anyhow::Result;
use osms_store::VerifyProblem;
use serde::Serialize;

use crate::EXIT_FAILURE;
use crate::commands::{human_bytes, print_json};
use crate::context::Context;

pub fn run(ctx: &Context, json: bool) -> Result<ExitCode> {
    let store = ctx.store()?;
    // Exclusive: a concurrent make could otherwise show as a missing object mid-write.
    let _lock =
        store.lock(|| errln!("waiting for another osms process to release the store lock..."))?;
    let report = store.verify()?;
    let experiments = experiment_problems(&store)?;
    let problems = report.problems.len() + experiments.len();
    if json {
        let mut value = serde_json::to_value(&report)?;
        value["experiment_problems"] = serde_json::to_value(&experiments)?;
        print_json(&value)?;
    } else {
        let by = |used_by: &[(String, osms_store::Hash)]| {
            if used_by.is_empty() {
                "no stage's output (`osms gc` removes it)".to_string()
            } else {
                used_by
                    .iter()
                    .map(|(stage, key)| format!("{stage} (key {})", key.short()))
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        };
        for p in &report.problems {
            match p {
                VerifyProblem::DamagedObject {
                    hash,
                    actual,
                    path,
                    used_by,
                } => outln!(
                    "damaged  {} (its bytes hash to {}) at {}: output of {}",
                    hash.short(),
                    actual.short(),
                    path.display(),
                    by(used_by)
                ),
                VerifyProblem::UnreadableObject {
                    hash,
                    path,
                    error,
                    used_by,
                } => outln!(
                    "unreadable {} at {} ({error}): output of {}",
                    hash.short(),
                    path.display(),
                    by(used_by)
                ),
                VerifyProblem::ForeignObject { path, reason } => {
                    outln!("foreign  {}: {reason}", path.display())
                }
                VerifyProblem::StrayFile { path } => outln!("stray    {}", path.display()),
                VerifyProblem::MissingObject { key, stage, hash } => {
                    outln!(
                        "missing  object {} of {stage} (key {})",
                        hash.short(),
                        key.short()
                    )
                }
                VerifyProblem::BadRecord { path, reason } => {
                    outln!("bad      index record {}: {reason}", path.display())
                }
            }
        }
        for p in &experiments {
            outln!(
                "missing  {} {} of experiment `{}` ({}): {}",
                p.what,
                p.hash.short(),
                p.experiment,
                p.instance,
                p.why
            );
        }
        let verdict = if problems == 0 {
            "ok".to_string()
        } else {
            format!("{problems} problem(s)")
        };
        errln!(
            "osms verify: {} objects ({}) and {} records checked: {verdict}",
            report.objects_checked,
            human_bytes(report.bytes_checked),
            report.records_checked
        );
        if !experiments.is_empty() {
            errln!(
                "hint: an experiment names instances the store no longer holds; `osms exp run NAME --force ...` records it again"
            );
        }
        if report
            .problems
            .iter()
            .any(|p| matches!(p, VerifyProblem::UnreadableObject { .. }))
        {
            errln!(
                "hint: the store's filesystem would not read some objects: check the disk (`dmesg`); once it reads again, `osms verify` checks them, and `osms make` rebuilds what is damaged"
            );
        }
        if !report.problems.is_empty() {
            errln!(
                "hint: `osms make` rebuilds damaged or missing stage outputs; `osms gc` removes stray \
                 objects and the shards of finished stages"
            );
        }
    }
    Ok(if problems == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(EXIT_FAILURE)
    })
}

/// An instance a named experiment records whose record or object the store does not hold.
#[derive(Debug, Serialize)]
struct ExperimentProblem {
    experiment: String,
    instance: String,
    /// `record` (no index record for the key) or `object` (no object for the content hash).
    what: &'static str,
    hash: osms_store::Hash,
    why: String,
}

fn experiment_problems(store: &osms_store::Store) -> Result<Vec<ExperimentProblem>> {
    let mut out = Vec::new();
    for e in osms_make::experiment::load_all(store)? {
        for point in &e.points {
            for i in &point.instances {
                let problem = |what, hash, why: String| ExperimentProblem {
                    experiment: e.name.clone(),
                    instance: i.instance.clone(),
                    what,
                    hash,
                    why,
                };
                if store.record(&i.key)?.is_none() {
                    out.push(problem(
                        "record",
                        i.key,
                        format!("no index record for the key of {}", i.stage),
                    ));
                } else if !store.object_path(&i.content_hash).exists() {
                    out.push(problem(
                        "object",
                        i.content_hash,
                        format!("the output of {} is not in the store", i.stage),
                    ));
                }
            }
        }
    }
    Ok(out)
}
