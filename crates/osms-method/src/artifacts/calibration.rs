//! The closed-loop calibration of the error models (issue 66): per held-out D_E condition, π̄'s
//! own rollouts beside the frozen teacher's rollouts under each model at each κ (draw q of
//! each with the same DR draws), and the report table "Does each model behave like π̄?".

use std::fmt::Write;

use osms_core::Artifact;
use osms_core::stats::{Difference, paired_difference};
use osms_core::table::{Cell, Column, Layout, Table, Unit, Value};
use osms_make::Summarize;
use osms_sim::artifacts::{EvalRow, EvalSummary};
use osms_sim::{N_ARM, Phase};
use serde::{Deserialize, Serialize};

use crate::calibrate::DeviationStats;
use crate::error_model::N_PHASES;

/// One model at one κ, as every item runs it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunSpec {
    /// The error model's variant name (`unperturbed`: the teacher's own rollout).
    pub model: String,
    /// κ_ε (1 for the unperturbed teacher).
    pub kappa: f64,
}

impl RunSpec {
    pub fn label(&self) -> String {
        if self.model == "unperturbed" {
            "teacher, unperturbed".into()
        } else {
            format!("{} at κ = {}", self.model, self.kappa)
        }
    }
}

/// What one run spec (or π̄) gave on one condition: its draws' rows and their pooled arm
/// deviation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunOutcome {
    pub rows: Vec<EvalRow>,
    pub deviation: DeviationStats,
}

impl RunOutcome {
    /// The share of the draws that succeeded (0 without draws).
    pub fn success_rate(&self) -> f64 {
        let n = self.rows.iter().filter(|r| r.outcome.success()).count();
        n as f64 / self.rows.len().max(1) as f64
    }
}

/// One held-out D_E condition of one fold.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationItem {
    /// The fold whose π̄ held this condition out.
    pub fold: u32,
    /// The D_E item.
    pub item: u32,
    /// π̄'s own rollouts (draw q with run draw q's DR stream) and its deviation from the
    /// teacher queried at the states it visited.
    pub student: RunOutcome,
    /// In [`Calibration::runs`] order.
    pub runs: Vec<RunOutcome>,
}

/// The calibration of every model on every fold's held-out conditions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// Draws per condition and run spec, and of π̄ (common random numbers: draw q of a
    /// condition has the same DR draws under every model and κ and for π̄, and the same
    /// innovations under every model and κ).
    pub draws: usize,
    pub runs: Vec<RunSpec>,
    pub items: Vec<CalibrationItem>,
}

impl Artifact for Calibration {
    const TYPE_TAG: &'static str = "method.calibration";
    /// 2: π̄'s side is `draws` rollouts per condition (a [`RunOutcome`]), not one row.
    const SCHEMA_VERSION: u16 = 2;
}

impl osms_make::Sharded for Calibration {
    type Item = CalibrationItem;
    fn take_items(&mut self) -> Vec<CalibrationItem> {
        std::mem::take(&mut self.items)
    }
    fn set_items(&mut self, items: Vec<CalibrationItem>) {
        self.items = items;
    }
}

/// A run spec (or π̄) on a set of conditions.
#[derive(Debug, Clone, PartialEq)]
pub struct RunSummary {
    pub label: String,
    pub rollouts: EvalSummary,
    /// Success minus π̄'s, paired by condition (the per-condition means over draws), with its
    /// 95 % interval; `None` for π̄ itself.
    pub calibration_error: Option<Difference>,
}

/// The failure kinds the table gives a column each.
const FAILURE_COLUMNS: [&str; 4] = [
    "drop",
    "f_max too high",
    "l_max too short",
    "v_rel too high",
];

/// Which conditions a summary covers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Folds {
    Both,
    One(u32),
}

impl Calibration {
    fn items_of(&self, folds: Folds) -> impl Iterator<Item = &CalibrationItem> {
        self.items.iter().filter(move |i| match folds {
            Folds::Both => true,
            Folds::One(f) => i.fold == f,
        })
    }

    /// The folds present, in order.
    pub fn folds(&self) -> Vec<u32> {
        let mut f: Vec<u32> = self.items.iter().map(|i| i.fold).collect();
        f.sort_unstable();
        f.dedup();
        f
    }

    /// π̄'s rollouts on `folds`' conditions.
    pub fn student_summary(&self, folds: Folds) -> RunSummary {
        RunSummary {
            label: "π̄ (its own rollouts)".into(),
            rollouts: EvalSummary::of(self.items_of(folds).flat_map(|i| &i.student.rows)),
            calibration_error: None,
        }
    }

    /// Run spec `r` on `folds`' conditions, with its calibration error against π̄.
    pub fn run_summary(&self, r: usize, folds: Folds) -> RunSummary {
        let items: Vec<&CalibrationItem> = self.items_of(folds).collect();
        let model: Vec<f64> = items.iter().map(|i| i.runs[r].success_rate()).collect();
        let student: Vec<f64> = items.iter().map(|i| i.student.success_rate()).collect();
        RunSummary {
            label: self.runs[r].label(),
            rollouts: EvalSummary::of(items.iter().flat_map(|i| &i.runs[r].rows)),
            calibration_error: paired_difference(&[model], &[student]),
        }
    }

    /// The pooled arm deviation of π̄ (`None`) or of run spec `r` on `folds`' conditions.
    pub fn deviation(&self, run: Option<usize>, folds: Folds) -> DeviationStats {
        let mut total = DeviationStats::default();
        for i in self.items_of(folds) {
            total.add(match run {
                None => &i.student.deviation,
                Some(r) => &i.runs[r].deviation,
            });
        }
        total
    }

    /// The run spec of `model` at `kappa`.
    pub fn run_index(&self, model: &str, kappa: f64) -> Option<usize> {
        self.runs
            .iter()
            .position(|r| r.model == model && (r.kappa == kappa || model == "unperturbed"))
    }

    /// "Does each model behave like π̄?": outcomes on both folds' conditions, and each run's
    /// calibration error (success minus π̄'s, paired by condition) on both and on each fold.
    pub fn table(&self) -> Table {
        let folds = self.folds();
        let mut columns = vec![
            Column::new("success", Unit::Percent),
            Column::new("− π̄ (95 % CI)", Unit::Text),
        ];
        for f in &folds {
            columns.push(Column::new(format!("− π̄, fold {f}"), Unit::Text));
        }
        columns.extend([
            Column::new("completion", Unit::Percent),
            Column::new("f_max (N)", Unit::Number(1)),
            Column::new("ℓ_max (m)", Unit::Number(3)),
            Column::new("v_rel (m/s)", Unit::Number(2)),
        ]);
        for f in FAILURE_COLUMNS {
            columns.push(Column::new(f, Unit::Percent));
        }
        columns.push(Column::new("rollouts", Unit::Count));
        let mut t = Table::new(
            "calibration",
            "Does each model behave like π̄? The frozen teacher under each error model, on π̄'s held-out D_E conditions",
            columns,
        );
        let ci = |d: &Option<Difference>| {
            Cell::text(d.as_ref().map_or_else(
                || "-".into(),
                |d| {
                    format!(
                        "{:+.1} [{:+.1}, {:+.1}]",
                        100.0 * d.estimate,
                        100.0 * d.low,
                        100.0 * d.high
                    )
                },
            ))
        };
        let push = |t: &mut Table, s: RunSummary, per_fold: Vec<Option<Difference>>| {
            let r = &s.rollouts;
            let mut cells = vec![Cell::one(r.success_rate), ci(&s.calibration_error)];
            cells.extend(per_fold.iter().map(ci));
            cells.extend([
                Cell::one(r.completion_rate),
                Cell::opt(r.max_force_n),
                Cell::opt(r.follow_through_m),
                Cell::opt(r.contact_speed_mps),
            ]);
            for f in FAILURE_COLUMNS {
                cells.push(Cell::one(r.failure_rate(f)));
            }
            cells.push(Cell::new(Value::One(r.rollouts as f64), None));
            t.push(s.label, cells);
        };
        push(
            &mut t,
            self.student_summary(Folds::Both),
            folds.iter().map(|_| None).collect(),
        );
        for r in 0..self.runs.len() {
            let per_fold = folds
                .iter()
                .map(|&f| self.run_summary(r, Folds::One(f)).calibration_error)
                .collect();
            push(&mut t, self.run_summary(r, Folds::Both), per_fold);
        }
        t.with_note(format!(
            "Each model's rollouts: the frozen teacher with Eq. 7 applied to every channel of every step (as validation's perturbed rollouts), {} draws per condition, and as many of π̄'s own, with common random numbers (draw q has the same DR draws for π̄ and under every model and κ). − π̄: success minus π̄'s on the same conditions, paired by condition (the per-condition means over the draws); a calibrated model has it near 0 at κ = 1. f_max, ℓ_max and v_rel are means over catch completions; failure columns are rates per rollout.",
            self.draws
        ))
    }

    /// The arm deviation a − ā per phase, as it occurs in closed loop, for π̄ and each run
    /// spec at κ = 1: mean over the seven arm channels of |mean|, sd and lag-1 correlation.
    pub fn deviation_table(&self) -> Table {
        let mut columns = Vec::new();
        for p in Phase::ALL.iter().take(N_PHASES) {
            columns.push(Column::new(format!("{} sd", p.name()), Unit::Number(3)));
            columns.push(Column::new(format!("{} ρ₁", p.name()), Unit::Number(2)));
        }
        let mut t = Table::new(
            "calibration_deviation",
            "The arm deviation a − ā in closed loop, per phase (mean over the arm channels)",
            columns,
        );
        let mut row = |label: String, d: DeviationStats| {
            let mut cells = Vec::new();
            for p in 0..N_PHASES {
                let s = d.phase_summary(p);
                cells.push(Cell::opt(s.sd));
                cells.push(Cell::opt(s.lag1));
            }
            t.push(label, cells);
        };
        row(
            "π̄ (its own rollouts)".into(),
            self.deviation(None, Folds::Both),
        );
        for (r, spec) in self.runs.iter().enumerate() {
            if spec.model != "unperturbed" && spec.kappa == 1.0 {
                row(spec.label(), self.deviation(Some(r), Folds::Both));
            }
        }
        t.with_note(format!(
            "ā is the teacher's command at the state reached; for π̄, a is its command and ā the teacher queried at π̄'s states (the error pairs). Sample sd and ρ₁ per (phase, arm channel) cell, averaged over the {N_ARM} arm channels; the phase is the one known online."
        ))
    }

    /// One line per condition and run spec, for `osms export`.
    pub fn csv(&self) -> String {
        let mut out = String::from(
            "fold,item,run,model,kappa,draws,successes,student_successes,student_completions\n",
        );
        for i in &self.items {
            for (r, spec) in self.runs.iter().enumerate() {
                let rows = &i.runs[r].rows;
                let _ = writeln!(
                    out,
                    "{},{},{},{},{},{},{},{},{}",
                    i.fold,
                    i.item,
                    r,
                    spec.model,
                    spec.kappa,
                    rows.len(),
                    rows.iter().filter(|x| x.outcome.success()).count(),
                    i.student
                        .rows
                        .iter()
                        .filter(|x| x.outcome.success())
                        .count(),
                    i.student
                        .rows
                        .iter()
                        .filter(|x| x.outcome.completion())
                        .count(),
                );
            }
        }
        out
    }
}

impl Summarize for Calibration {
    /// Per run spec: success, completion and the calibration error (estimate and 95 %
    /// interval, in points) on both folds and on each.
    fn summary(&self) -> serde_json::Value {
        let folds = self.folds();
        let error =
            |d: Option<Difference>| d.map(|d| serde_json::json!([d.estimate, d.low, d.high]));
        let student = self.student_summary(Folds::Both);
        let runs: Vec<serde_json::Value> = (0..self.runs.len())
            .map(|r| {
                let all = self.run_summary(r, Folds::Both);
                let per_fold: serde_json::Map<String, serde_json::Value> = folds
                    .iter()
                    .map(|&f| {
                        (
                            format!("fold_{f}"),
                            error(self.run_summary(r, Folds::One(f)).calibration_error)
                                .unwrap_or_default(),
                        )
                    })
                    .collect();
                serde_json::json!({
                    "model": self.runs[r].model,
                    "kappa": self.runs[r].kappa,
                    "success_rate": all.rollouts.success_rate,
                    "completion_rate": all.rollouts.completion_rate,
                    "calibration_error": error(all.calibration_error),
                    "calibration_error_by_fold": per_fold,
                })
            })
            .collect();
        serde_json::json!({
            "conditions": self.items.len(),
            "draws": self.draws,
            "student_success_rate": student.rollouts.success_rate,
            "student_completion_rate": student.rollouts.completion_rate,
            "runs": runs,
        })
    }

    fn text(&self) -> Option<String> {
        Some(format!(
            "{}\n\n{}\n\n{}\n\n{}",
            self.table().title,
            self.table().markdown_with(Layout::plain("rollouts of")),
            self.deviation_table().title,
            self.deviation_table()
                .markdown_with(Layout::plain("rollouts of")),
        ))
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut files = self.table().files();
        files.extend(self.deviation_table().files());
        files.push(("calibration.csv".into(), self.csv().into_bytes()));
        files
    }
}
