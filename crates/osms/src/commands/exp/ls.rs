//! `osms exp ls`: the named experiments in the store.

use std::process::ExitCode;

use anyhow::Result;
use osms_core::table::{Cell, Column, Layout, Table, Unit};
use osms_make::experiment::{self};

use crate::commands::print_json;
use crate::context::Context;

pub(super) fn ls(ctx: &Context, json: bool) -> Result<ExitCode> {
    let store = ctx.store()?;
    let exps = experiment::load_all(&store)?;
    if json {
        let listed: Vec<serde_json::Value> = exps
            .iter()
            .map(|e| {
                serde_json::json!({
                    "name": e.name,
                    "profile": e.profile,
                    "points": e.points.len(),
                    "seeds": e.seeds,
                    "targets": e.targets,
                    "set": e.set,
                    "sweep": e.axes,
                    "complete": e.points.iter().all(|p| p.failed.is_empty()),
                })
            })
            .collect();
        print_json(&listed)?;
        return Ok(ExitCode::SUCCESS);
    }
    let mut t = Table::new(
        "experiments",
        "Experiments",
        vec![
            Column::new("profile", Unit::Text),
            Column::new("points", Unit::Count),
            Column::new("seeds", Unit::Text),
            Column::new("targets", Unit::Text),
            Column::new("knobs", Unit::Text),
        ],
    );
    for e in &exps {
        let seeds: Vec<String> = e.seeds.iter().map(u64::to_string).collect();
        let mut knobs = e.set.clone();
        knobs.extend(e.axes.iter().map(|a| format!("{a}=(sweep)")));
        t.push(
            &e.name,
            vec![
                Cell::text(&e.profile),
                Cell::one(e.points.len() as f64),
                Cell::text(seeds.join(",")),
                Cell::text(e.targets.join(" ")),
                Cell::text(knobs.join(" ")),
            ],
        );
    }
    if exps.is_empty() {
        say!(
            ctx,
            "no experiments yet; `osms exp run NAME --set STAGE.PATH=VALUE` records one"
        );
    } else {
        out!("{}", t.markdown_with(Layout::plain("experiment")));
    }
    Ok(ExitCode::SUCCESS)
}
