//! What a `show`, `export` or dataset command's target names: a stage instance of the plan
//! (its current build), or a key or content-hash prefix.

use anyhow::{Result, bail};
use osms_make::State;
use osms_store::{Record, Store};

use crate::cli::Selection;
use crate::context::Context;
use osms_make::describe;

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
                "stage `{}` has no current build under profile `{}` ({})\nhint: {} builds it",
                s.instance,
                plan.profile,
                describe(&s.reasons),
                ctx.make_command(target, &plan.profile)
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
