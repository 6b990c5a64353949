//! `osms export`: the files an artifact renders.

use std::process::ExitCode;

use anyhow::{Context as _, Result, bail};
use osms_core::Artifact;
use osms_make::StoreObjects;

use super::resolve::{Resolved, resolve};
use crate::cli::ExportArgs;
use crate::commands::print_json;
use crate::context::Context;
use osms_sim::artifacts::Evaluation;

/// Writes the files an artifact renders (e.g. a table as Markdown, CSV and JSON; an
/// evaluation's rollouts as CSV and Parquet).
pub fn export(ctx: &Context, args: &ExportArgs) -> Result<ExitCode> {
    let Resolved {
        record,
        store,
        profile,
        ..
    } = resolve(ctx, &args.target, &args.selection)?;
    let Some(kind) = ctx.registry.get(&record.kind) else {
        bail!("kind `{}` is not known to this osms", record.kind);
    };
    let dir = match &args.out {
        Some(d) => d.clone(),
        None => {
            let instance = record.instance();
            ctx.pipeline_path
                .parent()
                .unwrap_or_else(|| std::path::Path::new("."))
                .join("reports")
                .join(&profile)
                .join(instance)
        }
    };
    // A report written by stage name carries its provenance, as `osms make` writes it.
    let by_name = args.target.split(['@', '#']).next() == Some(record.stage.as_str());
    if super::report::REPORT_KINDS.contains(&record.kind.as_str()) && by_name {
        let plan = ctx.selected_plan(&args.selection)?;
        let seeds = Context::seeds(&args.selection, &plan);
        let written = super::report::write(ctx, &plan, &store, &record.stage, &seeds, &dir)?;
        let written: Vec<String> = written.iter().map(|p| p.display().to_string()).collect();
        if args.json {
            print_json(&written)?;
        } else {
            for w in &written {
                outln!("{w}");
            }
        }
        return Ok(ExitCode::SUCCESS);
    }
    let bytes = crate::commands::read_output(&store, &record)?;
    let files = if record.shard.is_some() {
        Vec::new()
    } else if record.type_tag == Evaluation::TYPE_TAG {
        // One row per rollout (docs/export.md): written by osms-export, which the artifact's
        // own crate does not reach.
        let evaluation: Evaluation = osms_make::assemble(&bytes, &StoreObjects(&store))
            .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", record.instance()))?;
        osms_export::rollouts::files(&evaluation)?
    } else {
        kind.files(&bytes, &StoreObjects(&store))
            .map_err(|e| anyhow::anyhow!("{e}"))?
    };
    if files.is_empty() {
        bail!(
            "{} (kind `{}`) has no files to export\nhint: `osms show {}` prints its summary",
            record.stage,
            record.kind,
            args.target
        );
    }
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut written = Vec::new();
    for (name, content) in files {
        let path = dir.join(&name);
        // Write beside and rename, so an interrupted export leaves no half-written file.
        let tmp = dir.join(format!(".{name}.tmp"));
        std::fs::write(&tmp, &content)
            .with_context(|| format!("cannot write {}", tmp.display()))?;
        std::fs::rename(&tmp, &path).with_context(|| format!("cannot write {}", path.display()))?;
        written.push(path.display().to_string());
    }
    if args.json {
        print_json(&written)?;
    } else {
        for w in &written {
            outln!("{w}");
        }
    }
    Ok(ExitCode::SUCCESS)
}
