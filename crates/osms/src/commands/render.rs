//! `osms render`: offscreen pictures of a rollout.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context as _, Result, bail};

use super::print_json;
use super::rollout_source::load;
use crate::cli::RenderArgs;
use crate::context::Context;

pub fn render(ctx: &Context, args: &RenderArgs) -> Result<ExitCode> {
    let source = load(ctx, &args.at.target, &args.at.selection)?;
    let dataset = source.rollouts("rendered")?;
    source.check_episode(args.at.episode)?;
    let instance = source.resolved.record.instance();
    let strip_path = args.out.clone();
    if strip_path.extension().and_then(|e| e.to_str()) != Some("png") {
        bail!(
            "--out {} must name a .png file (the strip; the GIF and the faded poses go beside it)",
            strip_path.display()
        );
    }
    let poses_path = strip_path.with_file_name(format!(
        "{}-poses.png",
        strip_path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    ));
    let gif_path = strip_path.with_extension("gif");
    let parent = match strip_path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    osms_render::osmesa_available()?;
    std::fs::create_dir_all(&parent)
        .with_context(|| format!("cannot create {}", parent.display()))?;
    let world = source
        .world
        .world()
        .map_err(|e| anyhow::anyhow!("cannot compile the world of {instance}: {e}"))?;
    let record = &dataset.items[args.at.episode].rollout.record;
    let opts = osms_render::RenderOptions {
        width: args.width,
        height: args.height,
        ..osms_render::RenderOptions::default()
    };
    let rendered = osms_render::render_rollout(&world, &dataset.task.rollout, record, &opts)
        .with_context(|| format!("cannot render {instance} episode {}", args.at.episode))?;
    if !rendered.replay.bit_exact {
        bail!(
            "{instance} episode {}: the replay does not reproduce the record (`osms replay` shows where), so the pictures would not show this rollout",
            args.at.episode
        );
    }
    let files = [
        (&strip_path, rendered.strip.to_png()),
        (&poses_path, rendered.composite.to_png()),
        (&gif_path, rendered.gif.clone()),
    ];
    // Each file beside its target first, so an interrupted render leaves no half-written one.
    for (path, bytes) in &files {
        let tmp = PathBuf::from(format!("{}.partial", path.display()));
        std::fs::write(&tmp, bytes).with_context(|| format!("cannot write {}", tmp.display()))?;
        std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))?;
    }
    let keys: Vec<serde_json::Value> = rendered
        .key_frames
        .iter()
        .map(|k| {
            serde_json::json!({
                "kind": k.kind.label(),
                "step": k.step,
                "time_secs": k.time_secs,
            })
        })
        .collect();
    if args.json {
        print_json(&serde_json::json!({
            "stage": instance,
            "episode": args.at.episode,
            "success": record.outcome.success(),
            "key_frames": keys,
            "gif_frames": rendered.gif_frames,
            "files": files.iter().map(|(p, _)| p.display().to_string()).collect::<Vec<_>>(),
        }))?;
    } else {
        outln!(
            "rendered {instance} episode {} ({}, {} steps):",
            args.at.episode,
            if record.outcome.success() {
                "a catch"
            } else {
                "a failed catch"
            },
            record.steps
        );
        for k in &rendered.key_frames {
            outln!(
                "  {:<15} step {:>3}, t = {:.2} s",
                k.kind.label(),
                k.step,
                k.time_secs
            );
        }
        for (path, _) in &files {
            outln!("  {}", path.display());
        }
    }
    Ok(ExitCode::SUCCESS)
}
