//! The cost model behind `osms make --dry-run`: each instance's core-hours, scaled from the
//! measured core-seconds of the same stage built under another (smaller) profile.
//!
//! A build's core-seconds are in its record (`cpu_secs`: the CPU time its threads used, summed
//! over the jobs of a cluster build). Every kind says how large a build is ([`Scale`]): a dataset
//! its rollouts, a teacher its PPO episodes, a student its steps times batch, most others as
//! large as their largest input. Sizes flow down the graph, so a validation of a 20,000-rollout
//! D_R is 20 times one of 1,000. The estimate of an instance is a measured build's core-seconds
//! times target work over measured work, from the measuring profile with the most work (the
//! least dominated by fixed costs); where several builds did that work, their median (a build
//! resumed from a checkpoint records only its last part). Fixed costs (model set-up, loading
//! inputs) are scaled too, which overestimates; network width is not in the teacher's or
//! student's work.
//!
//! A stage whose inputs changed since its last build (stale) still has that build's record:
//! where its params are the profile's, its core-seconds measure the same work on other input
//! bytes, and the estimate uses it when no up-to-date build of the stage exists.
//!
//! A stage no profile has built (an ablation's validation, say) is scaled from another stage of
//! the same kind, its largest build, and says so ([`Measured::stage`]): the same code per unit
//! of work, other params, so a rougher figure than a build of the stage itself.

use std::collections::BTreeMap;

use osms_store::{Hash, Store};
use serde::Serialize;

use crate::error::Result;
use crate::heads::Heads;
use crate::kind::Scale;
use crate::plan::{InstanceId, Plan};
use crate::status::{State, status};

/// The planned [`Scale`] of every instance needed for `targets`, from params alone.
pub fn scales(
    plan: &Plan,
    targets: &[String],
    seeds: &[u64],
) -> Result<BTreeMap<InstanceId, Scale>> {
    let mut out: BTreeMap<InstanceId, Scale> = BTreeMap::new();
    for id in plan.instances(targets, seeds)? {
        let stage = &plan.stages[id.stage];
        let inputs: Vec<(String, f64)> = plan
            .input_instances(id, seeds)
            .into_iter()
            .map(|i| (i.slot, out.get(&i.id).map(|s| s.size).unwrap_or(1.0)))
            .collect();
        let refs: Vec<(&str, f64)> = inputs.iter().map(|(s, v)| (s.as_str(), *v)).collect();
        out.insert(id, stage.kind.scale(&stage.params, &refs));
    }
    Ok(out)
}

/// A measured build an estimate scales.
#[derive(Debug, Clone, Serialize)]
pub struct Measured {
    pub profile: String,
    /// The stage that was built: the estimated one, or another of its kind when no profile
    /// has built the estimated one.
    pub stage: String,
    pub key: Hash,
    pub core_secs: f64,
    pub work: f64,
    /// Core-seconds per unit of work.
    pub core_secs_per_unit: f64,
    /// The record predates `cpu_secs`: its wall time was multiplied by an assumed thread count.
    pub threads_assumed: bool,
    /// The instance's last build, from inputs that have changed since (same params).
    pub stale: bool,
    /// Bytes the build stored: its output's object and its parts' (items, shards), as they
    /// are on disk now (parts shared with other builds counted here too).
    pub bytes: u64,
}

#[derive(Debug, Clone, Serialize)]
pub struct InstanceEstimate {
    pub instance: String,
    pub kind: String,
    pub work: f64,
    /// `None`: no profile has a build of this stage to scale.
    pub core_hours: Option<f64>,
    /// Bytes it will store, scaled the same way (`None` with `core_hours`).
    pub bytes: Option<f64>,
    pub measured: Option<Measured>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Estimate {
    pub profile: String,
    pub total_core_hours: f64,
    /// What the measured instances will store: an upper bound where objects are shared.
    pub total_bytes: f64,
    pub instances: Vec<InstanceEstimate>,
    /// Instances no profile has measured (not in the total).
    pub unmeasured: Vec<String>,
}

/// Estimates the core-hours of `instances` of `target` from the builds in `store` of the same
/// stages under `references` (other profiles of the same pipeline, an experiment's recorded
/// points). Records without `cpu_secs` count `assumed_threads` threads.
pub fn estimate(
    target: &Plan,
    references: &[Plan],
    store: &Store,
    seeds: &[u64],
    instances: &[String],
    assumed_threads: usize,
) -> Result<Estimate> {
    let all_targets: Vec<String> = Vec::new();
    let planned = scales(target, &all_targets, seeds)?;
    // Every measured build, by instance name, with its stage's kind.
    let mut measured: BTreeMap<String, Vec<(&'static str, Measured)>> = BTreeMap::new();
    let heads = Heads::load(store)?;
    for plan in references {
        let sizes = scales(plan, &all_targets, seeds)?;
        for st in status(plan, store, &all_targets, seeds)? {
            let stage = &plan.stages[st.id.stage];
            let (key, stale) = match (st.state, st.key) {
                (State::Cached, Some(key)) => (key, false),
                (State::Stale, _) => match heads.get(&st.instance)? {
                    Some(h) if h.kind == stage.info.name && h.params == stage.params.json => {
                        (h.key, true)
                    }
                    _ => continue,
                },
                _ => continue,
            };
            let Some(rec) = store.record(&key)? else {
                continue;
            };
            let (core_secs, threads_assumed) = match rec.cpu_secs {
                Some(c) => (c, false),
                None => (rec.wall_time_secs * assumed_threads as f64, true),
            };
            let work = sizes.get(&st.id).map(|s| s.work).unwrap_or(1.0);
            // A build of no work (`n = 0`) says nothing about the cost of one unit.
            if core_secs <= 0.0 || work <= 0.0 {
                continue;
            }
            let bytes = std::iter::once(&rec.content_hash)
                .chain(&rec.parts)
                .filter_map(|h| std::fs::metadata(store.object_path(h)).ok())
                .map(|m| m.len())
                .sum();
            measured.entry(st.instance.clone()).or_default().push((
                stage.info.name,
                Measured {
                    profile: plan.profile.clone(),
                    stage: stage.name.clone(),
                    key,
                    core_secs,
                    work,
                    core_secs_per_unit: core_secs / work,
                    threads_assumed,
                    stale,
                    bytes,
                },
            ));
        }
    }
    let mut out = Estimate {
        profile: target.profile.clone(),
        total_core_hours: 0.0,
        total_bytes: 0.0,
        instances: Vec::new(),
        unmeasured: Vec::new(),
    };
    for (id, scale) in &planned {
        let name = target.display(*id);
        if !instances.contains(&name) {
            continue;
        }
        // The builds of the largest work of any instance of the stage (its seeds and folds do
        // the same work), up-to-date ones before stale; failing both, the same of its kind.
        // Of those, the median core-seconds: a build resumed from a checkpoint recorded only
        // its last part, and one build seen by several plans counts once.
        let stage = &target.stages[id.stage];
        let largest = |of_stage: bool| {
            let mut builds: Vec<&Measured> = measured
                .values()
                .flatten()
                .filter(|(kind, m)| {
                    *kind == stage.info.name && (!of_stage || m.stage == stage.name)
                })
                .map(|(_, m)| m)
                .collect();
            builds.sort_by_key(|m| (m.key, m.stale));
            builds.dedup_by_key(|m| m.key);
            let first = builds
                .iter()
                .map(|m| (!m.stale, m.work))
                .max_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)))?;
            builds.retain(|m| (!m.stale, m.work) == first);
            builds.sort_by(|a, b| {
                a.core_secs
                    .total_cmp(&b.core_secs)
                    .then(a.stage.cmp(&b.stage))
                    .then(a.key.cmp(&b.key))
            });
            let median = builds.len().checked_sub(1)? / 2;
            Some(builds[median].clone())
        };
        let best = largest(true).or_else(|| largest(false));
        let core_hours = best
            .as_ref()
            .map(|m| m.core_secs * scale.work / m.work / 3600.0);
        let bytes = best.as_ref().map(|m| m.bytes as f64 * scale.work / m.work);
        match core_hours {
            Some(h) => out.total_core_hours += h,
            None => out.unmeasured.push(name.clone()),
        }
        out.total_bytes += bytes.unwrap_or(0.0);
        out.instances.push(InstanceEstimate {
            instance: name,
            kind: stage.info.name.to_string(),
            work: scale.work,
            core_hours,
            bytes,
            measured: best,
        });
    }
    Ok(out)
}
