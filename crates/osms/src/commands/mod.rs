//! One file per verb.

mod data;
mod doctor;
mod exp;
mod gc;
mod inspect;
mod make;
mod outdir;
mod report;
mod status;
mod task;
mod verify;
mod world;

use std::process::ExitCode;

use anyhow::{Context as _, Result};
use osms_make::Registry;

use crate::cli::{Cli, Command};
use crate::context::Context;

pub fn run(cli: Cli, registry: Registry) -> Result<ExitCode> {
    // doctor and kinds must work without a pipeline.toml.
    match &cli.command {
        Command::Doctor(args) => return doctor::run(&cli.global, &registry, args.json),
        Command::Kinds(args) => return inspect::kinds(&registry, args.json),
        _ => {}
    }
    let ctx = Context::new(&cli.global, registry)?;
    match cli.command {
        Command::Make(args) => make::run(&ctx, &args),
        Command::Status(args) => status::status(&ctx, &args),
        Command::Why(args) => status::why(&ctx, &args),
        Command::Show(args) => inspect::show(&ctx, &args),
        Command::Export(args) => inspect::export(&ctx, &args),
        Command::ExportDataset(args) => data::export_dataset(&ctx, &args),
        Command::Replay(args) => data::replay(&ctx, &args),
        Command::Render(args) => data::render(&ctx, &args),
        Command::Ls(args) => inspect::ls(&ctx, args.json),
        Command::Verify(args) => verify::run(&ctx, args.json),
        Command::Gc(args) => gc::run(&ctx, &args),
        Command::Exp(command) => exp::run(&ctx, command),
        Command::World(crate::cli::WorldCommand::Dump(args)) => world::dump(&ctx, &args),
        Command::RunTask(args) => task::run(&ctx, &args),
        Command::Doctor(_) | Command::Kinds(_) => unreachable!("handled above"),
    }
}

/// Prints `value` as pretty JSON on stdout.
/// The bytes of `record`'s output; a store that cannot read them names the artifact.
pub(crate) fn read_output(
    store: &osms_store::Store,
    record: &osms_store::Record,
) -> Result<Vec<u8>> {
    store.get(&record.content_hash).with_context(|| {
        format!(
            "cannot read the output of {} (object {})",
            record.instance(),
            record.content_hash.short()
        )
    })
}

pub(crate) fn print_json(value: &impl serde::Serialize) -> Result<()> {
    outln!("{}", serde_json::to_string_pretty(value)?);
    Ok(())
}

pub(crate) use osms_core::table::human_bytes;
