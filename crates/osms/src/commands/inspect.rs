use std::process::ExitCode;

use anyhow::{Result, bail};
use osms_make::Registry;
use osms_store::{Record, read_header};
use serde::Serialize;

use crate::cli::ShowArgs;
use crate::commands::{human_bytes, print_json};
use crate::context::Context;

#[derive(Serialize)]
struct Shown<'a> {
    #[serde(flatten)]
    record: &'a Record,
    also_keys: Vec<String>,
    schema_version: u16,
    summary: serde_json::Value,
}

pub fn show(ctx: &Context, args: &ShowArgs) -> Result<ExitCode> {
    let prefix = args.hash.to_ascii_lowercase();
    if prefix.len() < 6 || !prefix.chars().all(|c| c.is_ascii_hexdigit()) {
        bail!(
            "`{}` is not a key or hash prefix\nhint: give at least 6 hexadecimal digits, as printed by `osms ls`",
            args.hash
        );
    }
    let store = ctx.store()?;
    let (records, _) = store.records()?;
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
    let bytes = store.get(&first.content_hash)?;
    let header = read_header(&bytes)?;
    let (summary, text) = match (ctx.registry.get(&first.kind), first.shard) {
        (_, Some(shard)) => (
            serde_json::json!({ "shard of": shard.stage_key, "items": format!("{}..{}", shard.start, shard.end) }),
            None,
        ),
        (Some(kind), None) => (kind.summarize(&bytes)?, kind.text(&bytes)?),
        (None, None) => (
            serde_json::json!(format!("kind `{}` is not known to this osms", first.kind)),
            None,
        ),
    };
    let shown = Shown {
        record: first,
        also_keys: matches.iter().skip(1).map(|r| r.key.to_hex()).collect(),
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
    println!("key           {}", r.key);
    println!("content hash  {}", r.content_hash);
    println!(
        "stage         {} (kind {} v{})",
        r.stage, r.kind, r.code_version
    );
    println!(
        "type          {} (schema {})",
        r.type_tag, header.schema_version
    );
    println!("seed          {seed}");
    println!("size          {}", human_bytes(r.size_bytes));
    println!(
        "built by      osms {} in {:.3}s",
        r.osms_version, r.wall_time_secs
    );
    println!("params        {}", r.params);
    for (slot, h) in &r.inputs {
        println!("input         {slot} = {h}");
    }
    for k in &shown.also_keys {
        println!("also key      {k}");
    }
    println!("summary");
    match &shown.summary {
        serde_json::Value::Object(map) => {
            for (k, v) in map {
                println!("  {k}: {v}");
            }
        }
        other => println!("  {other}"),
    }
    if let Some(text) = text {
        println!();
        print!("{text}");
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
        println!(
            "{:<24} {:>6} {:<12} {:<12} {:>10}  type",
            "stage", "seed", "key", "hash", "size"
        );
        for r in &records {
            let stage = match r.shard {
                Some(s) => format!("{}[{}..{}]", r.stage, s.start, s.end),
                None => r.stage.clone(),
            };
            let seed = r.seed.map(|s| s.to_string()).unwrap_or_else(|| "-".into());
            println!(
                "{stage:<24} {seed:>6} {:<12} {:<12} {:>10}  {}",
                r.key.short(),
                r.content_hash.short(),
                human_bytes(r.size_bytes),
                r.type_tag
            );
        }
        let total: u64 = records.iter().map(|r| r.size_bytes).sum();
        eprintln!("{} artifacts, {}", records.len(), human_bytes(total));
    }
    for (path, reason) in bad {
        eprintln!(
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
        println!("no stage kinds are registered in this build of osms");
    } else {
        for k in infos {
            let shape = if k.itemised {
                ", itemised (shardable)"
            } else {
                ""
            };
            let rng = if k.uses_rng { ", seeded" } else { "" };
            println!(
                "{} v{} -> {}{shape}{rng}",
                k.name, k.code_version, k.output_tag
            );
            println!(
                "    inputs: {}",
                if k.inputs.is_empty() {
                    "none".to_string()
                } else {
                    k.inputs.join(", ")
                }
            );
            println!("    {}", k.doc);
        }
    }
    Ok(ExitCode::SUCCESS)
}
