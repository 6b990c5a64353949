//! Writing a `report` stage's directory: the artifact's files (index.md, tables, figures)
//! plus a provenance section that only this machine knows: every stage instance behind the
//! report with its key, content hash and wall time, the profile, the run seeds and the
//! platform class.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context as _, Result, bail};
use osms_core::table::{Cell, Column, Layout, Table, Unit};
use osms_make::{Plan, State, StoreObjects};
use osms_store::{Record, Store};

use super::outdir;
use crate::context::Context;

/// The kinds whose builds `osms make` writes out as a directory: the report, the ablations
/// and the baselines beyond the paper.
pub const REPORT_KINDS: [&str; 3] = ["report", "ablations", "baselines"];

/// A report directory holds this marker: osms may replace it.
const MARKER: outdir::Marker = outdir::Marker {
    file: ".osms-report",
    what: "report directory",
};

/// The directory `osms make` writes a report stage to: `<stage>/` beside pipeline.toml.
pub fn default_dir(ctx: &Context, stage: &str) -> PathBuf {
    ctx.pipeline_path
        .parent()
        .unwrap_or_else(|| Path::new("."))
        .join(stage)
}

/// Writes the current build of report stage `stage` to `dir`, replacing what was there only
/// once every file is written. Returns the written paths.
pub fn write(
    ctx: &Context,
    plan: &Plan,
    store: &Store,
    stage: &str,
    seeds: &[u64],
    dir: &Path,
) -> Result<Vec<PathBuf>> {
    let statuses = osms_make::status(plan, store, &[stage.to_string()], seeds)?;
    let Some(root) = statuses.last() else {
        bail!("stage `{stage}` has no instance");
    };
    let (Some(key), State::Cached) = (root.key, root.state) else {
        bail!(
            "stage `{stage}` has no current build under profile `{}`\nhint: {} builds it",
            plan.profile,
            ctx.make_command(stage, &plan.profile)
        );
    };
    let record = store
        .record(&key)?
        .with_context(|| format!("stage `{stage}`: no record for key {key}"))?;
    let Some(kind) = ctx.registry.get(&record.kind) else {
        bail!("kind `{}` is not known to this osms", record.kind);
    };
    let bytes = crate::commands::read_output(store, &record)?;
    let mut files = kind
        .files(&bytes, &StoreObjects(store))
        .map_err(|e| anyhow::anyhow!("{e}"))?;

    let mut lineage = Vec::new();
    for s in &statuses {
        let r = match s.key {
            Some(k) => store.record(&k)?,
            None => None,
        };
        lineage.push((s.instance.clone(), s.kind.clone(), r));
    }
    let provenance = provenance(plan, seeds, &lineage);
    match files.iter_mut().find(|(name, _)| name == "index.md") {
        Some((_, index)) => index.extend_from_slice(provenance.as_bytes()),
        None => files.push(("index.md".into(), provenance.into_bytes())),
    }

    outdir::replace(dir, MARKER, |partial| {
        let mut written = Vec::new();
        for (file, content) in &files {
            std::fs::write(partial.join(file), content)
                .with_context(|| format!("cannot write {}", partial.join(file).display()))?;
            written.push(PathBuf::from(file));
        }
        Ok(written)
    })
}

fn provenance(plan: &Plan, seeds: &[u64], lineage: &[(String, String, Option<Record>)]) -> String {
    let mut s = String::new();
    let seeds_text = seeds
        .iter()
        .map(u64::to_string)
        .collect::<Vec<_>>()
        .join(", ");
    let total: f64 = lineage
        .iter()
        .filter_map(|(_, _, r)| r.as_ref().map(|r| r.wall_time_secs))
        .sum();
    let total_cpu: f64 = lineage
        .iter()
        .filter_map(|(_, _, r)| r.as_ref().and_then(|r| r.cpu_secs))
        .sum();
    let _ = writeln!(
        s,
        "## Provenance\n\nProfile `{}`, run seeds {seeds_text}, platform class `{}`, osms {}. \
         Every stage instance behind this report, in build order, with its key (what it was \
         built from), the content hash of its artifact and the wall and CPU time of the build \
         that stored it; {} instances, {:.0} s and {:.0} core-s of builds in total (a stage \
         built once serves every later make; builds side by side each count their whole \
         wall time).\n",
        plan.profile,
        crate::platform::class(),
        env!("CARGO_PKG_VERSION"),
        lineage.len(),
        total,
        total_cpu
    );
    s.push_str(&cost_by_kind(lineage));
    let mut t = Table::new(
        "provenance",
        "Provenance",
        vec![
            Column::new("kind", Unit::Text),
            Column::new("key", Unit::Text),
            Column::new("content hash", Unit::Text),
            Column::new("wall time (s)", Unit::Number(1)),
            Column::new("CPU time (s)", Unit::Number(1)),
        ],
    );
    for (instance, kind, r) in lineage {
        let short = |h: &osms_store::Hash| Cell::text(format!("`{}`", &h.to_string()[..12]));
        let cells = match r {
            Some(r) => vec![
                Cell::text(kind),
                short(&r.key),
                short(&r.content_hash),
                Cell::one(r.wall_time_secs),
                Cell::opt(r.cpu_secs),
            ],
            None => vec![
                Cell::text(kind),
                Cell::opt(None),
                Cell::opt(None),
                Cell::opt(None),
                Cell::opt(None),
            ],
        };
        t.push(instance, cells);
    }
    s.push_str(&t.markdown_with(Layout::plain("instance")));
    s
}

/// The builds behind the report by stage kind: how many, their wall and CPU time, and how many
/// cores a build of the kind kept busy (CPU over wall), most expensive first. Records from
/// before osms measured CPU time count only in the wall column.
fn cost_by_kind(lineage: &[(String, String, Option<Record>)]) -> String {
    let kinds = osms_make::cost::KindCost::tally(lineage.iter().filter_map(|(_, kind, r)| {
        r.as_ref()
            .map(|r| (kind.clone(), r.wall_time_secs, r.cpu_secs))
    }));
    let mut t = Table::new(
        "cost",
        "Cost by stage kind",
        vec![
            Column::new("builds", Unit::Count),
            Column::new("wall time (s)", Unit::Number(0)),
            Column::new("CPU time (s)", Unit::Number(0)),
            Column::new("cores busy", Unit::Number(2)),
        ],
    );
    for k in kinds {
        t.push(
            k.kind,
            vec![
                Cell::one(k.builds as f64),
                Cell::one(k.wall_secs),
                Cell::one(k.cpu_secs),
                Cell::opt(k.cores_busy),
            ],
        );
    }
    format!("{}\n", t.markdown_with(Layout::plain("kind")))
}
