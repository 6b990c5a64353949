//! Every D_R rollout's validation: its candidates' reports and the decision.

use std::collections::BTreeMap;
use std::fmt::Write;

use osms_core::Artifact;
use osms_core::rng::StreamRng;
use osms_core::table::{Cell, Column, Layout, Table, Unit};
use osms_make::Summarize;
use serde::{Deserialize, Serialize};

use crate::validate::{Robustness, Unperturbed, ValidateParams, ValidationItem};

/// Every D_R rollout's validation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Validation {
    pub params: ValidateParams,
    /// The error model validated under.
    pub error_model: String,
    /// The candidate generator of the sets validated.
    pub generator: String,
    /// Where the perturbed rollouts' innovations came from, so D_* repeats them.
    pub streams: ErrorStreams,
    pub items: Vec<ValidationItem>,
}

/// The innovations of perturbed rollout q of D_R item i: stream ("errors-q", i) of the
/// validation stage, the same for every candidate of the item (common random numbers).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorStreams {
    pub seed: u64,
    pub stage: String,
}

impl ErrorStreams {
    pub fn rng(&self, item: u32, q: usize) -> StreamRng {
        osms_core::rng::stream(
            self.seed,
            &self.stage,
            &format!("errors-{q}"),
            u64::from(item),
        )
    }
}

impl Artifact for Validation {
    const TYPE_TAG: &'static str = "method.validation";
    /// 2: its params name the D_R subset (`rollouts`). 3: and κ and the deviation's scale
    /// (issue 74).
    const SCHEMA_VERSION: u16 = 3;
}

impl osms_make::Sharded for Validation {
    type Item = ValidationItem;
    fn take_items(&mut self) -> Vec<ValidationItem> {
        std::mem::take(&mut self.items)
    }
    fn set_items(&mut self, items: Vec<ValidationItem>) {
        self.items = items;
    }
}

/// Counts behind `osms show` on a validation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValidationStats {
    pub rollouts: usize,
    pub validated: usize,
    pub original_successes: usize,
    pub decisions: BTreeMap<String, usize>,
    pub candidates: usize,
    pub unperturbed_successes: usize,
    /// Candidates that got perturbed rollouts, and of those how many reached the threshold.
    pub perturbed: usize,
    pub qualified: usize,
    /// Mean SR_org over the originals whose SR was needed.
    pub mean_sr_org: Option<f64>,
    /// Mean SR of the selected candidates.
    pub mean_sr_selected: Option<f64>,
}

impl Validation {
    pub fn stats(&self) -> ValidationStats {
        let q = self.params.q;
        let mut decisions = BTreeMap::new();
        for i in &self.items {
            *decisions.entry(i.decision.name().to_string()).or_default() += 1;
        }
        let cands = || self.items.iter().flat_map(|i| &i.candidates);
        let mean = |v: Vec<f64>| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        ValidationStats {
            rollouts: self.items.len(),
            validated: self.items.iter().filter(|i| i.validated).count(),
            original_successes: self.items.iter().filter(|i| i.original.success).count(),
            decisions,
            candidates: cands().count(),
            unperturbed_successes: cands().filter(|c| c.unperturbed.success()).count(),
            perturbed: cands()
                .filter(|c| c.robustness != Robustness::NotRun)
                .count(),
            qualified: cands()
                .filter(|c| matches!(c.robustness, Robustness::Full { .. }))
                .count(),
            mean_sr_org: mean(
                self.items
                    .iter()
                    .filter_map(|i| i.original.robustness.sr(q))
                    .collect(),
            ),
            mean_sr_selected: mean(
                self.items
                    .iter()
                    .filter_map(|i| {
                        i.decision
                            .selected()
                            .and_then(|k| i.candidates[k].robustness.sr(q))
                    })
                    .collect(),
            ),
        }
    }
}

impl Summarize for Validation {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(self.stats()).unwrap_or_default()
    }

    fn text(&self) -> Option<String> {
        let s = self.stats();
        let p = &self.params;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "validation of {} candidate sets under the {} error model: Q = {}, δ_SR = {}, λ_f = {}, λ_d = {}, {}{}",
            self.generator,
            self.error_model,
            p.q,
            p.delta_sr,
            p.lambda_f,
            p.lambda_d,
            p.construction.name(),
            if p.exhaustive { ", exhaustive" } else { "" }
        );
        let _ = writeln!(
            out,
            "{} D_R rollouts ({} teacher successes), {} validated; {} candidates, {} succeed unperturbed, {} got perturbed rollouts, {} reached the threshold",
            s.rollouts,
            s.original_successes,
            s.validated,
            s.candidates,
            s.unperturbed_successes,
            s.perturbed,
            s.qualified
        );
        let fmt = |v: Option<f64>| v.map_or_else(|| "-".into(), |v| format!("{v:.3}"));
        let _ = writeln!(
            out,
            "mean SR_org {} (where needed), mean SR of the selected {}",
            fmt(s.mean_sr_org),
            fmt(s.mean_sr_selected)
        );
        let mut decisions = Table::new(
            "decisions",
            "Decisions",
            vec![Column::new("rollouts", Unit::Count)],
        );
        for (d, n) in &s.decisions {
            decisions.push(d, vec![Cell::one(*n as f64)]);
        }
        out.push('\n');
        out.push_str(&decisions.markdown_with(Layout::plain("decision")));
        Some(out)
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut csv = String::from(
            "item,attempt,variant,original_success,original_max_force_n,original_sr,candidate,unperturbed_success,max_force_n,j,deviation,distance,robustness,successes,evaluated,selected\n",
        );
        let q = self.params.q;
        for i in &self.items {
            let org_sr = i
                .original
                .robustness
                .sr(q)
                .map(|v| v.to_string())
                .unwrap_or_default();
            for (k, c) in i.candidates.iter().enumerate() {
                let (f, j) = match c.unperturbed {
                    Unperturbed::Succeeded { max_force_n, j } => {
                        (max_force_n.to_string(), j.to_string())
                    }
                    Unperturbed::Failed => (String::new(), String::new()),
                };
                let (kind, s, e) = match c.robustness {
                    Robustness::NotRun => ("not_run", String::new(), String::new()),
                    Robustness::Insufficient {
                        successes,
                        evaluated,
                    } => ("insufficient", successes.to_string(), evaluated.to_string()),
                    Robustness::Full { successes } => {
                        ("full", successes.to_string(), q.to_string())
                    }
                };
                let _ = writeln!(
                    csv,
                    "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                    i.item,
                    i.attempt,
                    i.variant,
                    i.original.success,
                    i.original.max_force_n,
                    org_sr,
                    k,
                    c.unperturbed.success(),
                    f,
                    j,
                    c.deviation,
                    c.distance,
                    kind,
                    s,
                    e,
                    i.decision.selected() == Some(k)
                );
            }
        }
        vec![("validation.csv".into(), csv.into_bytes())]
    }
}
