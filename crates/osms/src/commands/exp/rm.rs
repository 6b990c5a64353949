//! `osms exp rm`: forget named experiments (their artifacts stay until `osms gc`).

use std::process::ExitCode;

use anyhow::Result;
use osms_make::Observer;
use osms_make::experiment::{self};

use super::unknown_experiment;
use crate::cli::ExpRmArgs;
use crate::context::Context;
use crate::progress::MakeObserver;

pub(super) fn rm(ctx: &Context, args: &ExpRmArgs) -> Result<ExitCode> {
    let store = ctx.store()?;
    for name in &args.names {
        if experiment::load(&store, name)?.is_none() {
            return Err(unknown_experiment(&store, name));
        }
    }
    let _lock = store.lock(|| MakeObserver::of(ctx).waiting_for_lock())?;
    for name in &args.names {
        experiment::remove(&store, name)?;
        say!(
            ctx,
            "osms exp rm: forgot `{name}`; `osms gc` removes what only it kept"
        );
    }
    Ok(ExitCode::SUCCESS)
}
