//! `osms why`: a stage's lineage, its inputs recursively with keys and content hashes.

use std::process::ExitCode;

use anyhow::Result;
use osms_make::{Lineage, State, describe};

use crate::cli::WhyArgs;
use crate::commands::print_json;
use crate::context::Context;

pub fn why(ctx: &Context, args: &WhyArgs) -> Result<ExitCode> {
    let plan = ctx.selected_plan(&args.selection)?;
    let store = ctx.store()?;
    let seeds = Context::seeds(&args.selection, &plan);
    let lineage = osms_make::why(&plan, &store, &args.target, &seeds)?;
    if args.json {
        print_json(&lineage)?;
    } else {
        let mut out = String::new();
        draw(&lineage, "", true, true, &mut out);
        out!("{out}");
    }
    Ok(ExitCode::SUCCESS)
}

fn draw(node: &Lineage, prefix: &str, last: bool, root: bool, out: &mut String) {
    let s = &node.status;
    let key = s.key.map(|h| h.short()).unwrap_or_else(|| "?".into());
    let hash = s
        .content_hash
        .map(|h| h.short())
        .unwrap_or_else(|| "-".into());
    let state = match s.state {
        State::Cached => "cached".to_string(),
        State::Stale => format!("stale: {}", describe(&s.reasons)),
        State::Missing => format!("missing: {}", describe(&s.reasons)),
    };
    let slot = node
        .slot
        .as_ref()
        .map(|sl| format!("{sl}: "))
        .unwrap_or_default();
    let branch = if root {
        ""
    } else if last {
        "└── "
    } else {
        "├── "
    };
    out.push_str(&format!(
        "{prefix}{branch}{slot}{} [{}] key {key} hash {hash} ({state})\n",
        s.instance, s.kind
    ));
    let child_prefix = if root {
        String::new()
    } else {
        format!("{prefix}{}", if last { "    " } else { "│   " })
    };
    for (i, child) in node.inputs.iter().enumerate() {
        draw(child, &child_prefix, i + 1 == node.inputs.len(), false, out);
    }
}
