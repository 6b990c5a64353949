//! Constructed demonstration sets (paper 4.4 and 6, "Baselines"): D_* and the Naive and Normal
//! sets, in the representation students train on ([`Demo`]: deployable frames and commanded
//! action labels, nothing privileged), grouped by the task condition they came from.

use std::fmt::Write;

use osms_sim::conditions::TaskCondition;
use serde::{Deserialize, Serialize};

use crate::student::Demo;

/// What the construction did with a condition.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Origin {
    /// The teacher's successful original, kept.
    Kept,
    /// A successful original replaced by a validated candidate.
    Refined,
    /// A failed original replaced by a validated candidate.
    Repaired,
    /// A failed original with no replacement: no demonstration.
    Dropped,
}

impl Origin {
    pub fn name(self) -> &'static str {
        match self {
            Origin::Kept => "kept",
            Origin::Refined => "refined",
            Origin::Repaired => "repaired",
            Origin::Dropped => "dropped",
        }
    }
}

/// Which rollout of a condition a demonstration is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Execution {
    /// The teacher's own rollout.
    Original,
    /// The selected candidate, unperturbed.
    Unperturbed,
    /// The selected candidate under the action-error model, perturbed rollout q (its labels
    /// include the modelled perturbation).
    Perturbed { q: u32 },
    /// A student's own rollout, labelled with the teacher's actions at the states it visited
    /// (the `dagger` diagnostic and the DAgger-IL baseline).
    StudentVisited,
    /// The teacher's rollout under injected action noise, labelled with the actions it
    /// intended (the DART-IL baseline).
    Dart,
}

/// One successful rollout kept as a demonstration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoEntry {
    pub execution: Execution,
    /// Its f_max (N).
    pub max_force_n: f64,
    pub demo: Demo,
}

impl DemoEntry {
    /// A demonstration of one executed rollout: its deployable frames labelled with `actions`
    /// (what the policy commanded, or what the teacher would have), and its f_max.
    pub fn labelled(
        execution: Execution,
        record: &osms_sim::RolloutRecord,
        actions: Vec<f32>,
    ) -> DemoEntry {
        DemoEntry {
            execution,
            max_force_n: record.metrics.max_force_n,
            demo: Demo::labelled(record, actions),
        }
    }
}

/// The demonstrations of one task condition.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoGroup {
    /// The condition's dataset and draw: `data` (the D_R rollouts) or `extension` (the
    /// baseline's own stream), with (item, attempt).
    pub extension: bool,
    pub item: u32,
    pub attempt: u32,
    /// ω (its draw is the group's provenance: extensions never share one with another set).
    pub condition: TaskCondition,
    /// Whether the teacher's original rollout succeeded.
    pub original_success: bool,
    pub origin: Origin,
    pub demos: Vec<DemoEntry>,
}

/// A constructed demonstration set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoSet {
    /// `ours`, `naive` or `normal` (and ablation variants).
    pub construction: String,
    /// The demonstration count an extension aimed at (D_*'s, for the baselines).
    pub target: Option<usize>,
    /// How many leading groups form the set (`None`: all). An extension that ran more
    /// conditions than it needed keeps the rest, unused, so its items stay the shards' items.
    pub used: Option<usize>,
    pub groups: Vec<DemoGroup>,
}

impl osms_core::Artifact for DemoSet {
    const TYPE_TAG: &'static str = "policy.demo_set";
    /// 3: a demonstration's state holds the arm's servo targets (issue 54).
    const SCHEMA_VERSION: u16 = 3;
}

impl osms_make::Sharded for DemoSet {
    type Item = DemoGroup;
    fn take_items(&mut self) -> Vec<DemoGroup> {
        std::mem::take(&mut self.groups)
    }
    fn set_items(&mut self, items: Vec<DemoGroup>) {
        self.groups = items;
    }
}

/// Table II's construction columns and the counts behind them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConstructionStats {
    pub construction: String,
    /// D_R conditions (the target conditions).
    pub conditions: usize,
    pub original_successes: usize,
    pub kept: usize,
    pub refined: usize,
    pub repaired: usize,
    pub dropped: usize,
    /// Fraction of target conditions with a successful unperturbed rollout among the
    /// demonstrations.
    pub coverage: f64,
    /// Repaired over failed originals.
    pub repair_rate: f64,
    /// Refined over successful originals.
    pub refinement_rate: f64,
    /// Mean f_max (N) of the retained unperturbed rollouts (originals and selected
    /// candidates) of the target conditions.
    pub unperturbed_max_force_n: Option<f64>,
    /// All demonstrations, extension included.
    pub demonstrations: usize,
    pub extension_conditions: usize,
    pub extension_demonstrations: usize,
    pub target: Option<usize>,
    /// Extension conditions run beyond the target and left out.
    pub unused_conditions: usize,
    pub steps: usize,
}

impl DemoSet {
    /// The groups that form the set.
    pub fn used_groups(&self) -> &[DemoGroup] {
        let n = self
            .used
            .unwrap_or(self.groups.len())
            .min(self.groups.len());
        &self.groups[..n]
    }

    /// Every demonstration, in order.
    pub fn demos(&self) -> impl Iterator<Item = &Demo> {
        self.used_groups()
            .iter()
            .flat_map(|g| g.demos.iter().map(|e| &e.demo))
    }

    pub fn len(&self) -> usize {
        self.used_groups().iter().map(|g| g.demos.len()).sum()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn stats(&self) -> ConstructionStats {
        let target: Vec<&DemoGroup> = self.used_groups().iter().filter(|g| !g.extension).collect();
        let count = |o: Origin| target.iter().filter(|g| g.origin == o).count();
        let successes = target.iter().filter(|g| g.original_success).count();
        let failures = target.len() - successes;
        let (kept, refined, repaired, dropped) = (
            count(Origin::Kept),
            count(Origin::Refined),
            count(Origin::Repaired),
            count(Origin::Dropped),
        );
        let forces: Vec<f64> = target
            .iter()
            .flat_map(|g| {
                g.demos
                    .iter()
                    .filter(|e| matches!(e.execution, Execution::Original | Execution::Unperturbed))
                    .map(|e| e.max_force_n)
            })
            .collect();
        let ratio = |a: usize, b: usize| if b == 0 { 0.0 } else { a as f64 / b as f64 };
        let extension: Vec<&DemoGroup> =
            self.used_groups().iter().filter(|g| g.extension).collect();
        ConstructionStats {
            construction: self.construction.clone(),
            conditions: target.len(),
            original_successes: successes,
            kept,
            refined,
            repaired,
            dropped,
            coverage: ratio(kept + refined + repaired, target.len()),
            repair_rate: ratio(repaired, failures),
            refinement_rate: ratio(refined, successes),
            unperturbed_max_force_n: (!forces.is_empty())
                .then(|| forces.iter().sum::<f64>() / forces.len() as f64),
            demonstrations: self.len(),
            extension_conditions: extension.len(),
            extension_demonstrations: extension.iter().map(|g| g.demos.len()).sum(),
            target: self.target,
            unused_conditions: self.groups.len() - self.used_groups().len(),
            steps: self.demos().map(|d| d.steps).sum(),
        }
    }
}

impl osms_make::Summarize for DemoSet {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(self.stats()).unwrap_or_default()
    }

    fn text(&self) -> Option<String> {
        let s = self.stats();
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{}: {} demonstrations ({} control steps) from {} target conditions and {} extension conditions",
            s.construction, s.demonstrations, s.steps, s.conditions, s.extension_conditions
        );
        let _ = writeln!(
            out,
            "target conditions: {} kept, {} refined, {} repaired, {} dropped ({} teacher successes)",
            s.kept, s.refined, s.repaired, s.dropped, s.original_successes
        );
        let _ = writeln!(
            out,
            "coverage {:.1}%, repair rate {:.1}%, refinement rate {:.1}%, unperturbed f_max {}",
            100.0 * s.coverage,
            100.0 * s.repair_rate,
            100.0 * s.refinement_rate,
            s.unperturbed_max_force_n
                .map_or_else(|| "-".into(), |f| format!("{f:.1} N"))
        );
        Some(out)
    }
}
