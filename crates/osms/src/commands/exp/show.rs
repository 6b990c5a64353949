//! `osms exp show`: one row per experiment (per sweep point), from the records and the
//! artifacts' summaries, never logs.

use std::process::ExitCode;

use anyhow::Result;
use osms_core::table::Layout;

use super::load_named;
use super::rows::{rows_of, table};
use crate::cli::ExpShowArgs;
use crate::commands::print_json;
use crate::context::Context;

pub(super) fn show(ctx: &Context, args: &ExpShowArgs) -> Result<ExitCode> {
    let store = ctx.store()?;
    let exps = load_named(&store, &args.names)?;
    let mut rows = Vec::new();
    for e in &exps {
        rows.extend(rows_of(ctx, &store, e, &args.metrics)?);
    }
    for r in &rows {
        for why in &r.unreadable {
            say!(ctx, "warning: {}: {why}", r.label());
        }
    }
    if args.json {
        print_json(&serde_json::json!({ "rows": rows }))?;
    } else if args.csv {
        out!(
            "{}",
            table(&rows, &args.metrics, args.ci).wide_csv("experiment")
        );
    } else if rows.is_empty() {
        say!(
            ctx,
            "no experiments yet; `osms exp run NAME --set STAGE.PATH=VALUE` records one"
        );
    } else {
        out!(
            "{}",
            table(&rows, &args.metrics, args.ci).markdown_with(Layout::plain("experiment"))
        );
    }
    Ok(ExitCode::SUCCESS)
}
