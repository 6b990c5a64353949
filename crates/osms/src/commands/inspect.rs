use std::process::ExitCode;

use anyhow::{Context as _, Result, bail};
use osms_core::{Artifact, read_header};
use osms_make::Registry;
use osms_make::{State, StoreObjects};
use osms_store::{Record, Store};
use serde::Serialize;

use crate::cli::{ExportArgs, Selection, ShowArgs};
use crate::commands::{human_bytes, print_json};
use crate::context::Context;
use osms_make::describe;
use osms_sim::artifacts::Evaluation;

#[derive(Serialize)]
struct Shown<'a> {
    #[serde(flatten)]
    record: &'a Record,
    pub also_keys: Vec<String>,
    schema_version: u16,
    summary: serde_json::Value,
}

/// What a `show`/`export` target names, with the opened store and the plan's profile.
pub(super) struct Resolved {
    pub record: Record,
    /// Other keys with the same content (hash-prefix targets only).
    pub also_keys: Vec<String>,
    pub store: Store,
    pub profile: String,
}

/// The record a `show`/`export` target names: a stage instance of the plan (its current build)
/// or a key or content-hash prefix.
pub(super) fn resolve(ctx: &Context, target: &str, selection: &Selection) -> Result<Resolved> {
    // The plan first: a mistyped --pipeline must not leave a new store beside it.
    let plan = ctx.selected_plan(selection)?;
    let store = ctx.store()?;
    let (records, _) = store.records()?;
    let name = target.split(['@', '#']).next().unwrap_or(target);
    if plan.stage_index(name).is_some() {
        let seeds = Context::seeds(selection, &plan);
        let lineage = osms_make::why(&plan, &store, target, &seeds)?;
        let s = &lineage.status;
        let found = match (s.state, s.key) {
            (State::Cached, Some(key)) => records.iter().find(|r| r.key == key),
            _ => None,
        };
        let Some(record) = found else {
            bail!(
                "stage `{}` has no current build under profile `{}` ({})\nhint: `osms make {target}` builds it",
                s.instance,
                plan.profile,
                describe(&s.reasons)
            );
        };
        return Ok(Resolved {
            record: record.clone(),
            also_keys: Vec::new(),
            profile: plan.profile.clone(),
            store,
        });
    }
    let prefix = target.to_ascii_lowercase();
    if prefix.len() < 6 || !prefix.chars().all(|c| c.is_ascii_hexdigit()) {
        bail!(
            "`{target}` is neither a stage of {} nor a key or hash prefix\nhint: stages are {}; keys and hashes need at least 6 hexadecimal digits, as printed by `osms ls`",
            ctx.pipeline_path.display(),
            plan.stage_names().join(", ")
        );
    }
    let matches: Vec<&Record> = records
        .iter()
        .filter(|r| {
            r.key.to_hex().starts_with(&prefix) || r.content_hash.to_hex().starts_with(&prefix)
        })
        .collect();
    let Some(first) = matches.first() else {
        bail!(
            "no artifact in {} has a key or content hash starting with `{prefix}`\nhint: `osms ls` lists them",
            store.root().display()
        );
    };
    if matches.iter().any(|r| r.content_hash != first.content_hash) {
        let list: Vec<String> = matches
            .iter()
            .map(|r| {
                format!(
                    "  {} {} ({})",
                    r.key.short(),
                    r.content_hash.short(),
                    r.stage
                )
            })
            .collect();
        bail!(
            "`{prefix}` is ambiguous; it matches:\n{}\nhint: give more digits",
            list.join("\n")
        );
    }
    let also_keys = matches.iter().skip(1).map(|r| r.key.to_hex()).collect();
    Ok(Resolved {
        record: (*first).clone(),
        also_keys,
        profile: plan.profile.clone(),
        store,
    })
}

pub fn show(ctx: &Context, args: &ShowArgs) -> Result<ExitCode> {
    let Resolved {
        record,
        also_keys,
        store,
        ..
    } = resolve(ctx, &args.hash, &args.selection)?;
    let first = &record;
    let bytes = crate::commands::read_output(&store, first)?;
    let header = read_header(&bytes)?;
    let (summary, text) = match (ctx.registry.get(&first.kind), first.shard) {
        (_, Some(shard)) if first.type_tag == osms_make::CHECKPOINT_TAG => (
            serde_json::json!({ "checkpoint of": shard.stage_key, "steps done": shard.end }),
            None,
        ),
        (_, Some(shard)) => (
            serde_json::json!({ "shard of": shard.stage_key, "items": format!("{}..{}", shard.start, shard.end) }),
            None,
        ),
        (Some(kind), None) => {
            let objects = StoreObjects(&store);
            (
                kind.summarize(&bytes, &objects)
                    .map_err(|e| anyhow::anyhow!("{e}"))?,
                kind.text(&bytes, &objects)
                    .map_err(|e| anyhow::anyhow!("{e}"))?,
            )
        }
        (None, None) => (
            serde_json::json!(format!("kind `{}` is not known to this osms", first.kind)),
            None,
        ),
    };
    let shown = Shown {
        record: first,
        also_keys,
        schema_version: header.schema_version,
        summary,
    };
    if args.json {
        print_json(&shown)?;
        return Ok(ExitCode::SUCCESS);
    }
    let r = shown.record;
    let seed = r
        .seed
        .map(|s| s.to_string())
        .unwrap_or_else(|| "none (draws no random numbers)".into());
    outln!("key           {}", r.key);
    outln!("content hash  {}", r.content_hash);
    outln!(
        "stage         {} (kind {} v{})",
        r.stage,
        r.kind,
        r.code_version
    );
    outln!(
        "type          {} (schema {})",
        r.type_tag,
        header.schema_version
    );
    outln!("seed          {seed}");
    outln!("size          {}", human_bytes(r.size_bytes));
    outln!(
        "built by      osms {} in {:.3}s",
        r.osms_version,
        r.wall_time_secs
    );
    outln!("params        {}", r.params);
    for (slot, h) in &r.inputs {
        outln!("input         {slot} = {h}");
    }
    for k in &shown.also_keys {
        outln!("also key      {k}");
    }
    outln!("summary");
    match &shown.summary {
        serde_json::Value::Object(map) => {
            for (k, v) in map {
                outln!("  {k}: {v}");
            }
        }
        other => outln!("  {other}"),
    }
    if let Some(text) = text {
        outln!();
        out!("{text}");
    }
    Ok(ExitCode::SUCCESS)
}

pub fn ls(ctx: &Context, json: bool) -> Result<ExitCode> {
    let store = ctx.store()?;
    let (mut records, bad) = store.records()?;
    records.sort_by(|a, b| {
        (&a.stage, a.seed, a.shard.map(|s| s.start), a.key).cmp(&(
            &b.stage,
            b.seed,
            b.shard.map(|s| s.start),
            b.key,
        ))
    });
    if json {
        print_json(&records)?;
    } else {
        outln!(
            "{:<24} {:>6} {:<12} {:<12} {:>10}  type",
            "stage",
            "seed",
            "key",
            "hash",
            "size"
        );
        for r in &records {
            let stage = match r.shard {
                Some(s) if r.type_tag == osms_make::CHECKPOINT_TAG => {
                    format!("{}[after {}]", r.stage, s.end)
                }
                Some(s) => format!("{}[{}..{}]", r.stage, s.start, s.end),
                None => r.stage.clone(),
            };
            let seed = r.seed.map(|s| s.to_string()).unwrap_or_else(|| "-".into());
            outln!(
                "{stage:<24} {seed:>6} {:<12} {:<12} {:>10}  {}",
                r.key.short(),
                r.content_hash.short(),
                human_bytes(r.size_bytes),
                r.type_tag
            );
        }
        let total: u64 = records.iter().map(|r| r.size_bytes).sum();
        errln!("{} artifacts, {}", records.len(), human_bytes(total));
    }
    for (path, reason) in bad {
        errln!(
            "warning: unreadable index record {}: {reason}",
            path.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

pub fn kinds(registry: &Registry, json: bool) -> Result<ExitCode> {
    let infos = registry.infos();
    if json {
        print_json(&infos)?;
    } else if infos.is_empty() {
        outln!("no stage kinds are registered in this build of osms");
    } else {
        for k in infos {
            let shape = if k.itemised {
                ", itemised (shardable)"
            } else {
                ""
            };
            let rng = if k.uses_rng { ", seeded" } else { "" };
            outln!(
                "{} v{} -> {}{shape}{rng}",
                k.name,
                k.code_version,
                k.output_tag
            );
            outln!(
                "    inputs: {}",
                if k.inputs.is_empty() {
                    "none".to_string()
                } else {
                    k.inputs
                        .iter()
                        .map(|s| {
                            let mut text = format!("{}: {}", s.name, s.tag);
                            if !s.roles.is_empty() {
                                text.push_str(&format!(" ({})", s.roles.join(" | ")));
                            }
                            if s.gather {
                                text.push_str(" (gather)");
                            }
                            if s.optional {
                                text.push_str(" (optional)");
                            }
                            text
                        })
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            );
            outln!("    {}", k.doc);
        }
    }
    Ok(ExitCode::SUCCESS)
}

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
