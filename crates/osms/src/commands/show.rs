//! `osms show`: an artifact's metadata and a summary of its contents.

use std::process::ExitCode;

use anyhow::Result;
use osms_core::read_header;
use osms_make::StoreObjects;
use osms_store::Record;
use serde::Serialize;

use super::resolve::{Resolved, resolve};
use crate::cli::ShowArgs;
use crate::commands::{human_bytes, print_json};
use crate::context::Context;

#[derive(Serialize)]
struct Shown<'a> {
    #[serde(flatten)]
    record: &'a Record,
    pub also_keys: Vec<String>,
    schema_version: u16,
    summary: serde_json::Value,
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
