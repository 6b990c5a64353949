use std::process::ExitCode;

use anyhow::Result;
use osms_store::VerifyProblem;

use crate::EXIT_FAILURE;
use crate::commands::{human_bytes, print_json};
use crate::context::Context;

pub fn run(ctx: &Context, json: bool) -> Result<ExitCode> {
    let store = ctx.store()?;
    // Exclusive: a concurrent make could otherwise show as a missing object mid-write.
    let _lock = store
        .lock(|| eprintln!("waiting for another osms process to release the store lock..."))?;
    let report = store.verify()?;
    if json {
        print_json(&report)?;
    } else {
        for p in &report.problems {
            match p {
                VerifyProblem::DamagedObject { hash, actual, path } => {
                    println!(
                        "damaged  {} (its bytes hash to {}) at {}",
                        hash.short(),
                        actual.short(),
                        path.display()
                    )
                }
                VerifyProblem::ForeignObject { path, reason } => {
                    println!("foreign  {}: {reason}", path.display())
                }
                VerifyProblem::StrayFile { path } => println!("stray    {}", path.display()),
                VerifyProblem::MissingObject { key, stage, hash } => {
                    println!(
                        "missing  object {} of {stage} (key {})",
                        hash.short(),
                        key.short()
                    )
                }
                VerifyProblem::BadRecord { path, reason } => {
                    println!("bad      index record {}: {reason}", path.display())
                }
            }
        }
        let verdict = if report.problems.is_empty() {
            "ok".to_string()
        } else {
            format!("{} problem(s)", report.problems.len())
        };
        eprintln!(
            "osms verify: {} objects ({}) and {} records checked: {verdict}",
            report.objects_checked,
            human_bytes(report.bytes_checked),
            report.records_checked
        );
        if !report.problems.is_empty() {
            eprintln!(
                "hint: `osms make` rebuilds damaged or missing stage outputs; `osms gc` removes stray \
                 objects and the shards of finished stages"
            );
        }
    }
    Ok(if report.problems.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(EXIT_FAILURE)
    })
}
