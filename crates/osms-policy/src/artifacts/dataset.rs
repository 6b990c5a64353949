//! Teacher rollout datasets (paper section 4: D_M, D_E, D_R), each rollout with its
//! outcome-sensitive window.

use std::collections::BTreeMap;
use std::fmt::Write;

use osms_core::rng::StreamId;
use osms_core::table::{Cell, Column, Layout, Table, Unit};
use osms_sim::control::ArmAction;
use osms_sim::{Phase, RolloutRecord};
use serde::{Deserialize, Serialize};

use crate::catch::CatchTaskSpec;
use crate::osw::{OswSpec, OswWindow};

/// One teacher rollout of a dataset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoRollout {
    /// Which draw of the dataset's condition stream ω came from: (item, attempt).
    pub item: u32,
    pub attempt: u32,
    /// The stream the rollout's domain randomisation drew from (its DR draws, then actuation
    /// and observation noise): with `Dataset::task` and ω it repeats the rollout exactly.
    pub dr_stream: StreamId,
    /// The per-step record: ω, intended (teacher) and executed actions, deployable and
    /// privileged frames, palm and object states, forces, phases, metrics and outcome.
    pub record: RolloutRecord,
    pub osw: OswWindow,
}

/// What one dataset item holds: the kept rollout and what the discarded attempts failed by.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DatasetItem {
    pub rollout: DemoRollout,
    /// Attempts this item took (1 for mixed datasets).
    pub attempts: u32,
    /// Failure counts of the discarded attempts (success-only datasets).
    pub discarded_failures: BTreeMap<String, u32>,
}

/// D_M, D_E (successes only) or D_R (mixed).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Dataset {
    pub successes_only: bool,
    pub osw: OswSpec,
    /// The teacher's task as the rollouts ran it: its rollout spec with the dataset's domain
    /// randomisation, so later stages branch from these rollouts under the same setting.
    pub task: CatchTaskSpec,
    /// What the world's arm channels command (`world.arm_action`), so a reader of the actions
    /// without the world knows.
    pub arm_action: ArmAction,
    pub items: Vec<DatasetItem>,
}

impl osms_core::Artifact for Dataset {
    const TYPE_TAG: &'static str = "policy.dataset";
    /// 3: stored as a manifest of its shards (the rollouts are stored once); 4: records keep
    /// the arm's servo targets and ω̄ ends with them; 5: each rollout names its DR stream and
    /// the dataset keeps the task spec it ran; 6: records keep their servo targets and
    /// physics-step counts (open-loop replay).
    /// 7: the task has the actor-input rung and the smoothness weight (issue 54).
    /// 8: deployable frames carry the palm's touch reading (issue 54, item 2).
    /// 9: the world's arm action (issue 74).
    const SCHEMA_VERSION: u16 = 9;
}

impl osms_make::Sharded for Dataset {
    type Item = DatasetItem;
    fn take_items(&mut self) -> Vec<DatasetItem> {
        std::mem::take(&mut self.items)
    }
    fn set_items(&mut self, items: Vec<DatasetItem>) {
        self.items = items;
    }
}

/// Counts behind `osms show` on a dataset.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DatasetStats {
    pub rollouts: usize,
    pub attempts: u64,
    /// Successes over attempts: the teacher's success rate on this dataset's stream.
    pub teacher_success_rate: f64,
    /// Successes among the kept rollouts.
    pub kept_success_rate: f64,
    pub kept_completion_rate: f64,
    /// Failures of the kept rollouts and, for success-only datasets, of the discarded attempts.
    pub failures: BTreeMap<String, u64>,
    pub per_family: BTreeMap<String, usize>,
    pub per_variant: BTreeMap<String, usize>,
    pub complete_windows: usize,
    pub mean_steps: f64,
    /// Mean control steps per phase over the kept rollouts, in phase order.
    pub phase_steps: Vec<(String, f64)>,
    /// Kept rollouts whose record shows all five phases.
    pub all_phases: usize,
}

impl Dataset {
    pub fn rollouts(&self) -> impl Iterator<Item = &DemoRollout> {
        self.items.iter().map(|i| &i.rollout)
    }

    pub fn stats(&self) -> DatasetStats {
        let n = self.items.len();
        let attempts: u64 = self.items.iter().map(|i| u64::from(i.attempts)).sum();
        let successes = self
            .rollouts()
            .filter(|r| r.record.outcome.success())
            .count();
        let mut failures: BTreeMap<String, u64> = BTreeMap::new();
        let mut per_variant: BTreeMap<String, usize> = BTreeMap::new();
        let mut per_family: BTreeMap<String, usize> = BTreeMap::new();
        for item in &self.items {
            *per_family
                .entry(
                    item.rollout
                        .record
                        .condition
                        .variant
                        .family
                        .name()
                        .to_string(),
                )
                .or_default() += 1;
            for f in &item.rollout.record.outcome.failures {
                *failures.entry(f.name().to_string()).or_default() += 1;
            }
            for (f, c) in &item.discarded_failures {
                *failures.entry(f.clone()).or_default() += u64::from(*c);
            }
            *per_variant
                .entry(item.rollout.record.condition.variant.to_string())
                .or_default() += 1;
        }
        let per = |x: usize| x as f64 / n.max(1) as f64;
        DatasetStats {
            rollouts: n,
            attempts,
            teacher_success_rate: successes as f64 / attempts.max(1) as f64,
            kept_success_rate: per(successes),
            kept_completion_rate: per(self
                .rollouts()
                .filter(|r| r.record.outcome.completion())
                .count()),
            failures,
            per_family,
            per_variant,
            complete_windows: self.rollouts().filter(|r| r.osw.complete).count(),
            mean_steps: self.rollouts().map(|r| r.record.steps as f64).sum::<f64>()
                / n.max(1) as f64,
            phase_steps: Phase::ALL
                .iter()
                .map(|&p| {
                    let steps = self
                        .rollouts()
                        .map(|r| r.record.phase.iter().filter(|&&x| x == p as u8).count())
                        .sum::<usize>();
                    (p.name().to_string(), per(steps))
                })
                .collect(),
            all_phases: self
                .rollouts()
                .filter(|r| {
                    Phase::ALL
                        .iter()
                        .all(|&p| r.record.phase.contains(&(p as u8)))
                })
                .count(),
        }
    }
}

impl osms_make::Summarize for Dataset {
    fn summary(&self) -> serde_json::Value {
        let mut v = serde_json::to_value(self.stats()).unwrap_or_default();
        if let Some(o) = v.as_object_mut() {
            o.insert("successes_only".into(), self.successes_only.into());
            o.insert("h_os".into(), self.osw.h_os.into());
        }
        v
    }

    fn text(&self) -> Option<String> {
        let s = self.stats();
        let mut out = String::new();
        let kind = if self.successes_only {
            "successes only (collected until N successes)"
        } else {
            "mixed (one rollout per condition)"
        };
        let _ = writeln!(out, "{} rollouts, {kind}", s.rollouts);
        let _ = writeln!(
            out,
            "attempts {}, teacher success rate {:.1}% (successes / attempts)",
            s.attempts,
            100.0 * s.teacher_success_rate
        );
        let _ = writeln!(
            out,
            "kept: success {:.1}%, catch completion {:.1}%, mean length {:.1} steps",
            100.0 * s.kept_success_rate,
            100.0 * s.kept_completion_rate,
            s.mean_steps
        );
        let _ = writeln!(
            out,
            "OSW (H_OS = {}): {} of {} windows complete (k_e ≥ H_OS)\n",
            self.osw.h_os, s.complete_windows, s.rollouts
        );
        let _ = writeln!(
            out,
            "Phases (mean control steps per rollout; {} of {} rollouts show all five):\n",
            s.all_phases, s.rollouts
        );
        let counts = |label: &str, column: &str, unit: Unit, rows: Vec<(String, f64)>| {
            let mut t = Table::new(column, column, vec![Column::new(column, unit)]);
            for (name, v) in rows {
                t.push(name, vec![Cell::one(v)]);
            }
            t.markdown_with(Layout::plain(label))
        };
        out.push_str(&counts(
            "phase",
            "steps",
            Unit::Number(2),
            s.phase_steps.clone(),
        ));
        out.push('\n');
        out.push_str(&counts(
            "failure",
            "count",
            Unit::Count,
            osms_sim::Failure::ALL
                .iter()
                .filter_map(|f| Some((f.name().to_string(), *s.failures.get(f.name())? as f64)))
                .collect(),
        ));
        out.push('\n');
        out.push_str(&counts(
            "family",
            "rollouts",
            Unit::Count,
            s.per_family
                .iter()
                .map(|(f, c)| (f.clone(), *c as f64))
                .collect(),
        ));
        out.push('\n');
        out.push_str(&counts(
            "object",
            "rollouts",
            Unit::Count,
            s.per_variant
                .iter()
                .map(|(v, c)| (v.clone(), *c as f64))
                .collect(),
        ));
        Some(out)
    }
}
