//! Datasets out of the store: `export-dataset` (LeRobot v3.0, robomimic), `replay` (a
//! rollout's recorded controls, open loop, against its record) and `render` (offscreen
//! pictures of a rollout).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context as _, Result, bail};
use osms_export::{ExportSet, Provenance};
use osms_make::StoreObjects;
use osms_policy::artifacts::Dataset;
use osms_policy::artifacts::DemoSet;
use osms_sim::artifacts::WorldArtifact;
use osms_store::{Record, Store};

use super::inspect::{Resolved, resolve};
use super::outdir;
use super::print_json;
use crate::cli::{DatasetFormat, ExportDatasetArgs, RenderArgs, ReplayArgs, Selection};
use crate::context::Context;

const DATASET_TAG: &str = "policy.dataset";
const DEMO_SET_TAG: &str = "policy.demo_set";

/// An export directory holds this marker: osms may replace it.
const MARKER: outdir::Marker = outdir::Marker {
    file: ".osms-export",
    what: "dataset export directory",
};

/// The artifact a dataset command names, decoded, with its world.
struct Source {
    resolved: Resolved,
    contents: Contents,
    world_record: Record,
    world: WorldArtifact,
}

enum Contents {
    Rollouts(Box<Dataset>),
    Demos(DemoSet),
}

impl Source {
    fn provenance(&self) -> Provenance {
        let r = &self.resolved.record;
        Provenance {
            stage: r.instance(),
            kind: r.kind.clone(),
            key: r.key.to_hex(),
            content_hash: r.content_hash.to_hex(),
            world_key: self.world_record.key.to_hex(),
            world_content_hash: self.world_record.content_hash.to_hex(),
            profile: self.resolved.profile.clone(),
        }
    }

    fn episodes(&self) -> usize {
        match &self.contents {
            Contents::Rollouts(d) => d.items.len(),
            Contents::Demos(s) => s.demos().count(),
        }
    }

    /// The rollout dataset, or an error saying why a demonstration set has no rollouts.
    fn rollouts(&self, verb: &str) -> Result<&Dataset> {
        match &self.contents {
            Contents::Rollouts(d) => Ok(d),
            Contents::Demos(_) => bail!(
                "{} (kind `{}`) is a demonstration set: it keeps the student's observations and action labels, no simulator state, so it cannot be {verb}\nhint: {verb} a rollout dataset ({})",
                self.resolved.record.instance(),
                self.resolved.record.kind,
                DATASET_HINT
            ),
        }
    }

    fn check_episode(&self, episode: usize) -> Result<()> {
        let n = self.episodes();
        if episode >= n {
            bail!(
                "episode {episode} is out of range: {} has {n} episodes{}",
                self.resolved.record.instance(),
                if n == 0 {
                    String::new()
                } else {
                    format!(" (0 to {})", n - 1)
                }
            );
        }
        Ok(())
    }
}

const DATASET_HINT: &str = "stages of kind `collect`: d_m, d_e, d_r in the shipped pipeline";

fn load(ctx: &Context, target: &str, selection: &Selection) -> Result<Source> {
    let resolved = resolve(ctx, target, selection)?;
    let record = &resolved.record;
    let store = &resolved.store;
    if record.shard.is_some() {
        bail!(
            "{target} names one shard of {}; name the stage instead",
            record.instance()
        );
    }
    let bytes = crate::commands::read_output(store, record)?;
    let objects = StoreObjects(store);
    let contents = match record.type_tag.as_str() {
        DATASET_TAG => Contents::Rollouts(Box::new(
            osms_make::assemble::<Dataset>(&bytes, &objects)
                .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", record.instance()))?,
        )),
        DEMO_SET_TAG => Contents::Demos(
            osms_make::assemble::<DemoSet>(&bytes, &objects)
                .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", record.instance()))?,
        ),
        other => bail!(
            "{} (kind `{}`, artifact type `{other}`) is not a dataset\nhint: give a rollout dataset ({DATASET_HINT}) or a demonstration set (kinds `dstar`, `naive`, `normal`)",
            record.instance(),
            record.kind
        ),
    };
    let world_record = world_of(store, record)?;
    let world: WorldArtifact = osms_core::decode(&store.get(&world_record.content_hash)?)
        .with_context(|| format!("cannot read the world of {}", record.instance()))?;
    Ok(Source {
        resolved,
        contents,
        world_record,
        world,
    })
}

/// The `world` artifact a record was built from, found through its inputs.
fn world_of(store: &Store, record: &Record) -> Result<Record> {
    let (records, _) = store.records()?;
    let mut seen = BTreeSet::new();
    let mut queue: Vec<_> = record.inputs.iter().map(|(_, h)| *h).collect();
    while let Some(hash) = queue.pop() {
        if !seen.insert(hash) {
            continue;
        }
        let Some(r) = records
            .iter()
            .find(|r| r.content_hash == hash && r.shard.is_none())
        else {
            continue;
        };
        if r.type_tag == "sim.world" {
            return Ok(r.clone());
        }
        queue.extend(r.inputs.iter().map(|(_, h)| *h));
    }
    bail!(
        "the store holds no world among the inputs of {}\nhint: `osms make {}` rebuilds its lineage",
        record.instance(),
        record.stage
    )
}

fn bar(ctx: &Context, len: usize, what: &str) -> indicatif::ProgressBar {
    let target = if ctx.progress {
        indicatif::ProgressDrawTarget::stderr()
    } else {
        indicatif::ProgressDrawTarget::hidden()
    };
    let bar = indicatif::ProgressBar::with_draw_target(Some(len as u64), target);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{prefix:.bold} [{bar:30}] {pos}/{len} episodes, {elapsed} (eta {eta})",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_prefix(what.to_string());
    bar
}

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

pub fn replay(ctx: &Context, args: &ReplayArgs) -> Result<ExitCode> {
    let source = load(ctx, &args.at.target, &args.at.selection)?;
    let dataset = source.rollouts("replayed")?;
    source.check_episode(args.at.episode)?;
    let instance = source.resolved.record.instance();
    let world = source
        .world
        .world()
        .map_err(|e| anyhow::anyhow!("cannot compile the world of {instance}: {e}"))?;
    let rollout = &dataset.items[args.at.episode].rollout;
    let (_, report) = osms_sim::replay::replay(
        &world,
        &dataset.task.rollout,
        &rollout.record,
        &mut |_, _| {},
    )
    .with_context(|| format!("{instance} episode {}", args.at.episode))?;
    if args.json {
        print_json(&serde_json::json!({
            "stage": instance,
            "episode": args.at.episode,
            "item": rollout.item,
            "attempt": rollout.attempt,
            "report": report,
        }))?;
    } else {
        out!("{}", describe(&instance, args.at.episode, &report));
    }
    Ok(if report.bit_exact {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

fn describe(instance: &str, episode: usize, r: &osms_sim::replay::ReplayReport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{instance} episode {episode}: {} of {} control steps replayed from the recorded servo targets: {}",
        r.replayed_steps,
        r.steps,
        if r.bit_exact {
            "the record is reproduced bit for bit"
        } else {
            "the replay DEVIATES from the record"
        }
    );
    let _ = writeln!(
        s,
        "  {:<14} {:>8} {:>10} {:>12}",
        "field", "values", "differing", "max |Δ|"
    );
    for d in &r.deviations {
        let _ = writeln!(
            s,
            "  {:<14} {:>8} {:>10} {:>12.3e}",
            d.field, d.values, d.differing, d.max_abs
        );
    }
    let opt = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.4}"));
    let _ = writeln!(
        s,
        "  {:<14} {:>14} {:>14}",
        "metric", "recorded", "replayed"
    );
    let _ = writeln!(
        s,
        "  {:<14} {:>14} {:>14}",
        "success", r.recorded_success, r.replayed_success
    );
    let _ = writeln!(
        s,
        "  {:<14} {:>14.4} {:>14.4}",
        "f_max (N)", r.recorded.max_force_n, r.replayed.max_force_n
    );
    let _ = writeln!(
        s,
        "  {:<14} {:>14} {:>14}",
        "t_c (s)",
        opt(r.recorded.contact_time_secs),
        opt(r.replayed.contact_time_secs)
    );
    let _ = writeln!(
        s,
        "  {:<14} {:>14} {:>14}",
        "k_e", r.recorded.event_step, r.replayed.event_step
    );
    s
}

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
