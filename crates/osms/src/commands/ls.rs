//! `osms ls`: the artifacts in the store.

use std::process::ExitCode;

use anyhow::Result;

use crate::commands::{human_bytes, print_json};
use crate::context::Context;

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
