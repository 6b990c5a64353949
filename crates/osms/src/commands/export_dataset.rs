//! `osms export-dataset`: a rollout dataset or demonstration set as LeRobot v3.0 (Parquet) or
//! robomimic (HDF5).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context as _, Result};
use osms_export::ExportSet;

use super::outdir;
use super::print_json;
use super::rollout_source::{Contents, bar, load};
use crate::cli::{DatasetFormat, ExportDatasetArgs};
use crate::context::Context;

/// An export directory holds this marker: osms may replace it.
const MARKER: outdir::Marker = outdir::Marker {
    file: ".osms-export",
    what: "dataset export directory",
};

pub fn export_dataset(ctx: &Context, args: &ExportDatasetArgs) -> Result<ExitCode> {
    let source = load(ctx, &args.target, &args.selection)?;
    let instance = source.resolved.record.instance();
    let format = args.format.name();
    let dir = match &args.out {
        Some(d) => d.clone(),
        None => ctx
            .pipeline_path
            .parent()
            .unwrap_or_else(|| Path::new("."))
            .join("exports")
            .join(&source.resolved.profile)
            .join(format!("{}-{format}", source.resolved.record.stage)),
    };
    // Refuse before the replays, not after.
    outdir::check(&dir, MARKER)?;
    let world = source
        .world
        .world()
        .map_err(|e| anyhow::anyhow!("cannot compile the world of {instance}: {e}"))?;
    let set: ExportSet = match &source.contents {
        Contents::Rollouts(d) => {
            let bar = bar(ctx, d.items.len(), &format!("replaying {instance}"));
            let set = osms_export::from_dataset(source.provenance(), d, &world, &|n| {
                bar.set_position(n as u64)
            });
            bar.finish_and_clear();
            set.with_context(|| format!("cannot export {instance}"))?
        }
        Contents::Demos(s) => osms_export::from_demo_set(source.provenance(), s, &world)
            .with_context(|| format!("cannot export {instance}"))?,
    };
    let options = osms_export::ExportOptions {
        privileged_obs: args.privileged_obs,
    };
    let written = outdir::replace(&dir, MARKER, |partial| {
        let mut files = match args.format {
            DatasetFormat::Lerobot => osms_export::lerobot::write(&set, partial, options)?
                .into_iter()
                .map(|p| p.strip_prefix(partial).map(Path::to_path_buf).unwrap_or(p))
                .collect(),
            DatasetFormat::Robomimic => {
                let name = PathBuf::from(format!("{}.hdf5", source.resolved.record.stage));
                osms_export::robomimic::write(&set, &partial.join(&name), options)?;
                vec![name]
            }
        };
        files.sort();
        Ok(files)
    })?;
    let frames: usize = set.episodes.iter().map(|e| e.frames).sum();
    if args.json {
        print_json(&serde_json::json!({
            "stage": instance,
            "format": format,
            "dir": dir,
            "episodes": set.episodes.len(),
            "frames": frames,
            "physics_states": set.episodes.iter().all(|e| e.physics.is_some()),
            "privileged_obs": args.privileged_obs,
            "files": written,
        }))?;
    } else {
        outln!(
            "wrote {instance} as {format}: {} episodes, {frames} frames{} to {}",
            set.episodes.len(),
            if set.source_kind == "rollouts" {
                ", physics states from a bit-exact replay of every episode"
            } else {
                " (a demonstration set: no physics states)"
            },
            dir.display()
        );
        for w in &written {
            outln!("  {}", w.display());
        }
        if set.episodes.iter().any(|e| e.environment_state.is_some()) {
            let at = match args.format {
                DatasetFormat::Lerobot => osms_export::lerobot::privileged_key(options).to_string(),
                DatasetFormat::Robomimic => osms_export::robomimic::privileged_path(options),
            };
            outln!(
                "the privileged frame is in {at}{}",
                if options.privileged_obs {
                    ", among the policy inputs (--privileged-obs)"
                } else {
                    ", not a policy input (--privileged-obs puts it among them)"
                }
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
