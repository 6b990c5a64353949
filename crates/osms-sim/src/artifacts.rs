//! The simulator's artifact types: the world, a condition set and an evaluation, with what
//! `osms show` and `osms export` print of each.

use osms_core::Artifact;
use osms_core::table::{Cell, Column, Layout, Table, Unit};
use osms_make::{Sharded, Summarize};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

use crate::Result;
use crate::conditions::TaskCondition;
use crate::control::DrDraw;
use crate::episode::RolloutRecord;
use crate::metrics::{Failure, Metrics, Outcome};
use crate::spec::{ObjectVariant, WorldSpec};
use crate::world::World;

/// The world: its spec and the exact MJCF of every object variant.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorldArtifact {
    pub spec: WorldSpec,
    /// MJCF per variant, in [`ObjectVariant::all`] order.
    pub xml: Vec<String>,
    pub home_palm_pos: [f64; 3],
    pub home_palm_normal: [f64; 3],
}

impl Artifact for WorldArtifact {
    const TYPE_TAG: &'static str = "sim.world";
    /// 2: the spec has the arm's action (issue 74).
    const SCHEMA_VERSION: u16 = 2;
}

impl Summarize for WorldArtifact {
    fn summary(&self) -> serde_json::Value {
        serde_json::json!({
            "variants": ObjectVariant::all().iter().map(ToString::to_string).collect::<Vec<_>>(),
            "timestep_secs": self.spec.timestep_secs,
            "control_hz": 1.0 / self.spec.control_dt_secs(),
            "arm_action": self.spec.arm_action.name(),
            "home_palm_pos_m": self.home_palm_pos,
            "home_palm_normal": self.home_palm_normal,
            "mjcf_bytes": self.xml.iter().map(String::len).sum::<usize>(),
        })
    }
}

impl WorldArtifact {
    /// The world this artifact describes, compiled by MuJoCo from its stored MJCF.
    pub fn world(&self) -> Result<World> {
        World::from_xml(self.spec.clone(), self.xml.clone())
    }
}

/// A list of task conditions ω.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Conditions {
    pub items: Vec<TaskCondition>,
}

impl Artifact for Conditions {
    const TYPE_TAG: &'static str = "sim.conditions";
    /// 2: stored as a manifest of its shards.
    const SCHEMA_VERSION: u16 = 2;
}

impl Sharded for Conditions {
    type Item = TaskCondition;
    fn take_items(&mut self) -> Vec<TaskCondition> {
        std::mem::take(&mut self.items)
    }
    fn set_items(&mut self, items: Vec<TaskCondition>) {
        self.items = items;
    }
}

impl Summarize for Conditions {
    fn summary(&self) -> serde_json::Value {
        let n = self.items.len().max(1) as f64;
        let mut per_variant: BTreeMap<String, usize> = BTreeMap::new();
        for c in &self.items {
            *per_variant.entry(c.variant.to_string()).or_default() += 1;
        }
        serde_json::json!({
            "conditions": self.items.len(),
            "mean_speed_mps": self.items.iter().map(TaskCondition::speed_mps).sum::<f64>() / n,
            "mean_abs_lateral_offset_m": self.items.iter().map(|c| c.lateral_offset_m.abs()).sum::<f64>() / n,
            "per_variant": per_variant,
        })
    }
}

/// What an evaluation keeps of one rollout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalRow {
    pub variant: ObjectVariant,
    pub lateral_offset_m: f64,
    /// The rollout's domain-randomisation draws (delays, gain, friction, contact stiffness).
    pub dr: DrDraw,
    pub steps: u32,
    pub metrics: Metrics,
    pub outcome: Outcome,
    /// The signals around t_c, if the hand touched the object.
    pub trace: Option<ImpactTrace>,
}

impl EvalRow {
    /// What an evaluation keeps of a finished rollout.
    pub fn of(record: RolloutRecord) -> Self {
        EvalRow {
            variant: record.condition.variant,
            lateral_offset_m: record.condition.lateral_offset_m,
            steps: record.steps as u32,
            trace: ImpactTrace::of(&record),
            dr: record.dr,
            metrics: record.metrics,
            outcome: record.outcome,
        }
    }
}

/// Per-control-step signals of a rollout around its contact step k_c (the step holding t_c),
/// for impact profiles aligned at t_c: sample j is control step k_c + `from` + j.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImpactTrace {
    pub from: i32,
    /// Largest summed admissible normal force within the step (N).
    pub normal_force_n: Vec<f32>,
    /// Object–palm relative speed at the step's start (m/s).
    pub relative_speed_mps: Vec<f32>,
    /// Object velocity along its pre-contact incoming direction at the step's start (m/s):
    /// how much of the incoming motion is left.
    pub incoming_velocity_mps: Vec<f32>,
}

impl ImpactTrace {
    /// Control steps kept before and after the contact step.
    pub const BEFORE: usize = 10;
    pub const AFTER: usize = 25;

    /// The trace of a record, `None` without an admissible contact.
    pub fn of(record: &RolloutRecord) -> Option<Self> {
        let contact = crate::metrics::Phase::Contact as u8;
        let k_c = record.phase.iter().position(|&p| p == contact)?;
        let v3 = |v: &[f32], k: usize| [v[3 * k], v[3 * k + 1], v[3 * k + 2]];
        // The object's velocity at the start of the contact step is still the incoming one.
        let v_in = v3(&record.object_vel, k_c);
        let n = v_in.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-9);
        let dir = v_in.map(|x| x / n);
        let start = k_c.saturating_sub(Self::BEFORE);
        let end = (k_c + Self::AFTER + 1).min(record.steps);
        let mut t = ImpactTrace {
            from: start as i32 - k_c as i32,
            normal_force_n: Vec::with_capacity(end - start),
            relative_speed_mps: Vec::with_capacity(end - start),
            incoming_velocity_mps: Vec::with_capacity(end - start),
        };
        for k in start..end {
            let o = v3(&record.object_vel, k);
            let p = v3(&record.palm_vel, k);
            let rel = [o[0] - p[0], o[1] - p[1], o[2] - p[2]];
            t.normal_force_n.push(record.normal_force[k]);
            t.relative_speed_mps
                .push(rel.iter().map(|x| x * x).sum::<f32>().sqrt());
            t.incoming_velocity_mps
                .push(o[0] * dir[0] + o[1] * dir[1] + o[2] * dir[2]);
        }
        Some(t)
    }

    /// The sample at `offset` control steps from the contact step, if kept.
    pub fn at(&self, offset: i32) -> Option<(f32, f32, f32)> {
        let j = usize::try_from(offset - self.from).ok()?;
        Some((
            *self.normal_force_n.get(j)?,
            *self.relative_speed_mps.get(j)?,
            *self.incoming_velocity_mps.get(j)?,
        ))
    }
}

/// Per-rollout rows and the table over family × size.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Evaluation {
    /// One row per condition, in the condition set's order: row `i` is the rollout on
    /// condition `i`, whatever the shards. Every evaluation kind rolls out item `i` on
    /// condition `i`, and the engine hands `merge` the items in index order (shards are
    /// consecutive ranges, each collected in order), so two evaluations on the same condition
    /// set pair up row by row.
    pub rows: Vec<EvalRow>,
}

impl Artifact for Evaluation {
    const TYPE_TAG: &'static str = "sim.evaluation";
    /// 2: stored as a manifest of its shards; 3: rows keep their impact trace; 4: rows keep
    /// their DR draws.
    const SCHEMA_VERSION: u16 = 4;
}

impl Sharded for Evaluation {
    type Item = EvalRow;
    fn take_items(&mut self) -> Vec<EvalRow> {
        std::mem::take(&mut self.rows)
    }
    fn set_items(&mut self, items: Vec<EvalRow>) {
        self.rows = items;
    }
}

/// What a set of rollouts came to: the one summary row every evaluation table and summary
/// reads (Table I's rows, Table II's policy columns, the calibration's runs).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EvalSummary {
    pub rollouts: usize,
    pub success_rate: f64,
    pub completion_rate: f64,
    /// Means over catch completions only, as in the paper.
    pub contact_speed_mps: Option<f64>,
    pub max_force_n: Option<f64>,
    pub follow_through_m: Option<f64>,
    /// Rollouts failing each way (a rollout can fail several ways).
    pub failures: BTreeMap<String, usize>,
}

impl EvalSummary {
    /// The summary of `rows` (rates are 0 for none).
    pub fn of<'a>(rows: impl IntoIterator<Item = &'a EvalRow>) -> EvalSummary {
        let rows: Vec<&EvalRow> = rows.into_iter().collect();
        let n = rows.len().max(1) as f64;
        let completions: Vec<&&EvalRow> = rows.iter().filter(|r| r.outcome.completion()).collect();
        let mean = |f: &dyn Fn(&EvalRow) -> Option<f64>| {
            let v: Vec<f64> = completions.iter().filter_map(|r| f(r)).collect();
            (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
        };
        let mut failures = BTreeMap::new();
        for r in &rows {
            for f in &r.outcome.failures {
                *failures.entry(f.name().to_string()).or_default() += 1;
            }
        }
        EvalSummary {
            rollouts: rows.len(),
            success_rate: rows.iter().filter(|r| r.outcome.success()).count() as f64 / n,
            completion_rate: completions.len() as f64 / n,
            contact_speed_mps: mean(&|r| r.metrics.contact_speed_mps),
            max_force_n: mean(&|r| Some(r.metrics.max_force_n)),
            follow_through_m: mean(&|r| Some(r.metrics.follow_through_m)),
            failures,
        }
    }

    /// Rollouts failing as `failure` (a [`Failure::name`]) per rollout.
    pub fn failure_rate(&self, failure: &str) -> f64 {
        self.failures
            .get(failure)
            .map_or(0.0, |&k| k as f64 / self.rollouts.max(1) as f64)
    }
}

impl Evaluation {
    /// The summary of every rollout.
    pub fn overall(&self) -> EvalSummary {
        EvalSummary::of(&self.rows)
    }

    /// The summary per object variant, then `all`.
    pub fn table(&self) -> Vec<(String, EvalSummary)> {
        let mut groups: BTreeMap<ObjectVariant, Vec<&EvalRow>> = BTreeMap::new();
        for r in &self.rows {
            groups.entry(r.variant).or_default().push(r);
        }
        let mut lines: Vec<(String, EvalSummary)> = groups
            .into_iter()
            .map(|(v, rows)| (v.to_string(), EvalSummary::of(rows)))
            .collect();
        lines.push(("all".into(), self.overall()));
        lines
    }
}

impl Summarize for Evaluation {
    fn summary(&self) -> serde_json::Value {
        let all = self.overall();
        serde_json::json!({
            "rollouts": self.rows.len(),
            "success_rate": all.success_rate,
            "completion_rate": all.completion_rate,
            "f_max_n": all.max_force_n,
            "follow_through_m": all.follow_through_m,
            // Rollouts failing each way (`osms exp show --metrics failures.drop`).
            "failures": all.failures,
        })
    }

    fn text(&self) -> Option<String> {
        let lines = self.table();
        let mut objects = Table::new(
            "evaluation",
            "Evaluation per object",
            vec![
                Column::new("n", Unit::Count),
                Column::new("success", Unit::Percent),
                Column::new("completion", Unit::Percent),
                Column::new("v_rel (m/s)", Unit::Number(2)),
                Column::new("f_max (N)", Unit::Number(1)),
                Column::new("l_max (m)", Unit::Number(3)),
            ],
        );
        for (group, l) in &lines {
            objects.push(
                group,
                vec![
                    Cell::one(l.rollouts as f64),
                    Cell::one(l.success_rate),
                    Cell::one(l.completion_rate),
                    Cell::opt(l.contact_speed_mps),
                    Cell::opt(l.max_force_n),
                    Cell::opt(l.follow_through_m),
                ],
            );
        }
        let mut failures = Table::new(
            "failures",
            "Failures",
            vec![Column::new("all", Unit::Count)],
        );
        if let Some((_, all)) = lines.last() {
            for f in Failure::ALL {
                let n = all.failures.get(f.name()).copied().unwrap_or(0);
                failures.push(f.name(), vec![Cell::one(n as f64)]);
            }
        }
        Some(format!(
            "{}\nFailures (a rollout can fail several impact criteria):\n\n{}",
            objects.markdown_with(Layout::plain("object")),
            failures.markdown_with(Layout::plain("failure"))
        ))
    }
}
