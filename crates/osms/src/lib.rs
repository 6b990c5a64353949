//! The osms command line: init, make (local or Slurm), status, why, show, ls, export, verify, gc,
//! push and pull (remote caches), exp (named experiments), doctor, kinds, export-dataset, replay,
//! render and world dump; it plans with the stage kinds of osms-kinds and writes report
//! directories with their provenance.
//!
//! [`main_with`] runs the command line with any [`Registry`], so end-to-end tests can drive the
//! same code with stage kinds of their own; `osms_kinds::registry` holds the kinds osms ships.

#[macro_use]
mod term;
mod cli;
mod commands;
mod context;
pub mod platform;
mod progress;

use std::process::ExitCode;

use clap::Parser;
use osms_make::Registry;

pub use context::Context;

/// Exit codes, as uv: 0 success, 1 the user's input or the pipeline failed, 2 internal error.
pub(crate) const EXIT_FAILURE: u8 = 1;
pub(crate) const EXIT_INTERNAL: u8 = 2;

/// Parses the command line and runs it with `registry`.
pub fn main_with(registry: Registry) -> ExitCode {
    osms_sim::ffi::route_mujoco_logs_at_startup();
    let cli = cli::Cli::parse();
    init_logging(&cli.global);
    match commands::run(cli, registry) {
        Ok(code) => code,
        Err(err) => {
            errln!("error: {}", render(&err));
            if let Some(hint) = storage_hint(&err) {
                errln!("hint: {hint}");
            }
            ExitCode::from(exit_code_of(&err))
        }
    }
}

fn init_logging(global: &cli::Global) {
    // MuJoCo's own messages (targets `mujoco`, `mujoco::<topic>`) include compile timings at
    // info level, and object_store logs each retry of a remote's request: show their warnings
    // and errors only, unless asked to be verbose (a failed transfer's error says it all).
    let default = if global.quiet {
        "error"
    } else if global.verbose {
        "debug"
    } else {
        "info,mujoco=warn,object_store=warn"
    };
    let filter = tracing_subscriber::EnvFilter::try_from_env("OSMS_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(|| term::LogWriter)
        .with_ansi(term::colour())
        .log_internal_errors(false)
        .without_time()
        .with_target(false)
        .try_init();
}

/// The error chain, outermost first, one cause per line.
fn render(err: &anyhow::Error) -> String {
    let mut text = err.to_string();
    for cause in err.chain().skip(1) {
        let c = cause.to_string();
        if !text.contains(&c) {
            text.push_str(&format!("\n  caused by: {c}"));
        }
    }
    text
}

fn exit_code_of(err: &anyhow::Error) -> u8 {
    for cause in err.chain() {
        if let Some(e) = cause.downcast_ref::<osms_make::Error>() {
            return if e.is_user_error() {
                EXIT_FAILURE
            } else {
                EXIT_INTERNAL
            };
        }
    }
    EXIT_FAILURE
}

/// What to do about a filesystem error under the store, if `err` holds one: a failing disk or
/// a full one is the machine's trouble, not osms's (exit 1, as uv reports a failing cache).
fn storage_hint(err: &anyhow::Error) -> Option<String> {
    err.chain().find_map(|c| {
        if matches!(
            c.downcast_ref::<osms_store::Error>(),
            Some(osms_store::Error::Io { .. })
        ) {
            return Some(osms_make::storage_hint(c, None));
        }
        // A pull's store error (the remote's error wraps it transparently, so the chain skips it).
        match c.downcast_ref::<osms_remote::Error>() {
            Some(osms_remote::Error::Store(osms_store::Error::Io { source, .. }))
                if matches!(
                    source.kind(),
                    std::io::ErrorKind::StorageFull | std::io::ErrorKind::QuotaExceeded
                ) =>
            {
                Some(
                    "no space left on the store's filesystem: free space and run the pull again; \
                     a failed pull leaves no object or record half-written"
                        .to_string(),
                )
            }
            Some(osms_remote::Error::Store(e @ osms_store::Error::Io { .. })) => {
                Some(osms_make::storage_hint(e, None))
            }
            _ => None,
        }
    })
}
