//! One file per verb (`exp` a folder of its subcommands), beside the helpers verbs share:
//! `resolve` (what a target names), `rollout_source` (the rollouts a dataset command reads),
//! `outdir` (replaceable output directories) and `report` (report directories).

mod doctor;
mod exp;
mod export;
mod export_dataset;
mod gc;
mod init;
mod kinds;
mod ls;
mod make;
mod outdir;
mod remote;
mod render;
mod replay;
mod report;
mod resolve;
mod rollout_source;
mod show;
mod status;
mod task;
mod verify;
mod why;
mod world;

use std::process::ExitCode;

use anyhow::{Context as _, Result};
use osms_make::Registry;

use crate::cli::{Cli, Command};
use crate::context::Context;

pub fn run(cli: Cli, registry: Registry) -> Result<ExitCode> {
    // init, doctor and kinds must work without a pipeline.toml.
    match &cli.command {
        Command::Init(args) => return init::run(&cli.global, args),
        Command::Doctor(args) => return doctor::run(&cli.global, &registry, args.json),
        Command::Kinds(args) => return kinds::kinds(&registry, args.json),
        _ => {}
    }
    let ctx = Context::new(&cli.global, registry)?;
    match cli.command {
        Command::Make(args) => make::run(&ctx, &args),
        Command::Status(args) => status::status(&ctx, &args),
        Command::Why(args) => why::why(&ctx, &args),
        Command::Show(args) => show::show(&ctx, &args),
        Command::Export(args) => export::export(&ctx, &args),
        Command::ExportDataset(args) => export_dataset::export_dataset(&ctx, &args),
        Command::Replay(args) => replay::replay(&ctx, &args),
        Command::Render(args) => render::render(&ctx, &args),
        Command::Ls(args) => ls::ls(&ctx, args.json),
        Command::Verify(args) => verify::run(&ctx, args.json),
        Command::Gc(args) => gc::run(&ctx, &args),
        Command::Push(args) => remote::push(&ctx, &args),
        Command::Pull(args) => remote::pull(&ctx, &args),
        Command::Exp(command) => exp::run(&ctx, command),
        Command::World(crate::cli::WorldCommand::Dump(args)) => world::dump(&ctx, &args),
        Command::RunTask(args) => task::run(&ctx, &args),
        Command::Init(_) | Command::Doctor(_) | Command::Kinds(_) => unreachable!("handled above"),
    }
}

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

/// Prints `value` as pretty JSON on stdout.
pub(crate) fn print_json(value: &impl serde::Serialize) -> Result<()> {
    outln!("{}", serde_json::to_string_pretty(value)?);
    Ok(())
}

pub(crate) use osms_core::table::human_bytes;
