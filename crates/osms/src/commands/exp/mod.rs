//! `osms exp`: named experiments, one file per subcommand. `run` plans every sweep point,
//! merges them into one graph (shared upstream work builds once), builds it and records each
//! point's instances; `show`, `diff` and `plot` read those records and the artifacts'
//! summaries (`rows`), never logs.

use std::process::ExitCode;

use anyhow::Result;
use osms_make::experiment::{self, Experiment};
use osms_store::Store;

use crate::cli::ExpCommand;
use crate::context::Context;

mod diff;
mod ls;
mod plot;
mod rm;
mod rows;
mod run;
mod show;

pub fn run(ctx: &Context, command: ExpCommand) -> Result<ExitCode> {
    match command {
        ExpCommand::Run(args) => run::exp_run(ctx, &args),
        ExpCommand::Ls(args) => ls::ls(ctx, args.json),
        ExpCommand::Show(args) => show::show(ctx, &args),
        ExpCommand::Diff(args) => diff::diff(ctx, &args),
        ExpCommand::Plot(args) => plot::plot(ctx, &args),
        ExpCommand::Rm(args) => rm::rm(ctx, &args),
    }
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
