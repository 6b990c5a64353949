//! `osms init [DIR]`: a new project, the pipeline osms ships and an empty store, so the
//! commands work wherever a user is, the wheel alone included.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context as _, Result, bail};
use serde::Serialize;

use crate::cli::{Global, InitArgs};
use crate::commands::print_json;
use crate::term::Printer;

#[derive(Serialize)]
struct Written {
    pipeline: PathBuf,
    store: PathBuf,
}

pub fn run(global: &Global, args: &InitArgs) -> Result<ExitCode> {
    let dir = args.dir.clone().unwrap_or_else(|| PathBuf::from("."));
    let pipeline = dir.join("pipeline.toml");
    if pipeline.exists() {
        bail!(
            "{} exists: {} is an osms project already\nhint: run osms there, or `osms init NEW_DIR` for another project",
            pipeline.display(),
            dir.display()
        );
    }
    let store = global.store.clone().unwrap_or_else(|| dir.join("store"));
    fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    // The store first: a directory that is not one is refused before anything is written.
    osms_store::Store::open(&store)
        .with_context(|| format!("cannot create the store at {}", store.display()))?;
    write_new(&pipeline, osms_kinds::PIPELINE.as_bytes())?;
    if args.json {
        print_json(&Written { pipeline, store })?;
    } else {
        let printer = Printer::new(global);
        printer.say(format_args!(
            "wrote {} (the pipeline of osms {}) and an empty store at {}\n\
             next: `osms make teacher --profile tiny` in {} builds a small teacher in minutes; \
             `osms make` builds the default profile's report (≈ 2 h on 2 cores)\n",
            pipeline.display(),
            env!("CARGO_PKG_VERSION"),
            store.display(),
            dir.display()
        ));
    }
    Ok(ExitCode::SUCCESS)
}

/// Writes `bytes` to `path` through a temporary file beside it, so an interrupted init leaves
/// no half-written pipeline, and never over a file that appeared meanwhile.
fn write_new(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("toml.tmp");
    fs::write(&tmp, bytes).with_context(|| format!("cannot write {}", tmp.display()))?;
    let linked = fs::hard_link(&tmp, path);
    let _ = fs::remove_file(&tmp);
    linked.with_context(|| format!("cannot write {}", path.display()))
}
