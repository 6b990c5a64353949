//! The rollouts a dataset command (`export-dataset`, `replay`, `render`) names: a rollout
//! dataset or a demonstration set out of the store, decoded, with the world it ran in.

use std::collections::BTreeSet;

use anyhow::{Context as _, Result, bail};
use osms_export::Provenance;
use osms_make::StoreObjects;
use osms_policy::artifacts::Dataset;
use osms_policy::artifacts::DemoSet;
use osms_sim::artifacts::WorldArtifact;
use osms_store::{Record, Store};

use super::resolve::{Resolved, resolve};
use crate::cli::Selection;
use crate::context::Context;

const DATASET_TAG: &str = "policy.dataset";
const DEMO_SET_TAG: &str = "policy.demo_set";

/// The artifact a dataset command names, decoded, with its world.
pub(super) struct Source {
    pub resolved: Resolved,
    pub contents: Contents,
    pub world_record: Record,
    pub world: WorldArtifact,
}

impl Source {
    pub(super) fn provenance(&self) -> Provenance {
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

    pub(super) fn episodes(&self) -> usize {
        match &self.contents {
            Contents::Rollouts(d) => d.items.len(),
            Contents::Demos(s) => s.demos().count(),
        }
    }

    /// The rollout dataset, or an error saying why a demonstration set has no rollouts.
    pub(super) fn rollouts(&self, verb: &str) -> Result<&Dataset> {
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

    pub(super) fn check_episode(&self, episode: usize) -> Result<()> {
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

pub(super) enum Contents {
    Rollouts(Box<Dataset>),
    Demos(DemoSet),
}

const DATASET_HINT: &str = "stages of kind `collect`: d_m, d_e, d_r in the shipped pipeline";

pub(super) fn load(ctx: &Context, target: &str, selection: &Selection) -> Result<Source> {
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

pub(super) fn bar(ctx: &Context, len: usize, what: &str) -> indicatif::ProgressBar {
    let target = if ctx.printer.progress {
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
