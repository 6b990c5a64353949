//! The cross-fitted IL students' rollouts paired with the teacher's actions (paper 4.3).

use std::fmt::Write;

use osms_core::Artifact;
use osms_core::table::{Cell, Column, Layout, Table, Unit};
use osms_make::Summarize;
use osms_sim::artifacts::{EvalRow, Evaluation};
use osms_sim::{N_ACTION, Phase};
use serde::{Deserialize, Serialize};

/// One IL-student rollout with the teacher's actions at the states it visited.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PairRollout {
    /// The D_E item whose condition ω this rollout ran on.
    pub item: u32,
    /// π̄'s actions (what it commanded), 24 per step.
    pub student: Vec<f32>,
    /// The frozen teacher's action at the same states, 24 per step.
    pub teacher: Vec<f32>,
    /// The phase known online at each step (the phase the previous step ended in).
    pub phase: Vec<u8>,
    /// The rollout's outcome and metrics.
    pub eval: EvalRow,
}

impl PairRollout {
    pub fn steps(&self) -> usize {
        self.phase.len()
    }
}

/// (π̄ action, teacher action, phase) sequences of one cross-fitted student on its held-out fold.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorPairs {
    pub fold: Option<(u32, u32)>,
    pub rollouts: Vec<PairRollout>,
}

impl Artifact for ErrorPairs {
    const TYPE_TAG: &'static str = "policy.error_pairs";
    /// 2: the rollouts' evaluation rows keep their impact trace; 3: and their DR draws.
    const SCHEMA_VERSION: u16 = 3;
}

impl osms_make::Sharded for ErrorPairs {
    type Item = PairRollout;
    fn take_items(&mut self) -> Vec<PairRollout> {
        std::mem::take(&mut self.rollouts)
    }
    fn set_items(&mut self, items: Vec<PairRollout>) {
        self.rollouts = items;
    }
}

/// Per-phase counts and mean absolute deviations of a set of pair rollouts.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PhaseDeviation {
    pub phase: &'static str,
    pub steps: usize,
    /// Mean |π̄ − teacher| over the phase's steps, arm channels and hand channels.
    pub arm_abs_deviation: Option<f64>,
    pub hand_abs_deviation: Option<f64>,
}

impl ErrorPairs {
    pub fn evaluation(&self) -> Evaluation {
        Evaluation {
            rows: self.rollouts.iter().map(|r| r.eval.clone()).collect(),
        }
    }

    pub fn phase_deviations(&self) -> Vec<PhaseDeviation> {
        Phase::ALL
            .iter()
            .map(|&p| {
                let (mut steps, mut arm, mut hand) = (0usize, 0.0f64, 0.0f64);
                for r in &self.rollouts {
                    for n in (0..r.steps()).filter(|&n| r.phase[n] == p as u8) {
                        steps += 1;
                        for k in 0..N_ACTION {
                            let d = f64::from(
                                (r.student[n * N_ACTION + k] - r.teacher[n * N_ACTION + k]).abs(),
                            );
                            if k < osms_sim::N_ARM {
                                arm += d;
                            } else {
                                hand += d;
                            }
                        }
                    }
                }
                let per = |sum: f64, channels: usize| {
                    (steps > 0).then(|| sum / (steps * channels) as f64)
                };
                PhaseDeviation {
                    phase: p.name(),
                    steps,
                    arm_abs_deviation: per(arm, osms_sim::N_ARM),
                    hand_abs_deviation: per(hand, N_ACTION - osms_sim::N_ARM),
                }
            })
            .collect()
    }
}

impl Summarize for ErrorPairs {
    fn summary(&self) -> serde_json::Value {
        let eval = self.evaluation();
        let all = eval.table().pop();
        serde_json::json!({
            "fold": self.fold.map(|(i, n)| format!("{i} of {n}")),
            "rollouts": self.rollouts.len(),
            "steps": self.rollouts.iter().map(PairRollout::steps).sum::<usize>(),
            "student_success_rate": all.as_ref().map(|l| l.success_rate),
            "student_completion_rate": all.as_ref().map(|l| l.completion_rate),
            "phases": self.phase_deviations(),
        })
    }

    fn text(&self) -> Option<String> {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "IL student on {} held-out conditions{}:\n",
            self.rollouts.len(),
            self.fold
                .map(|(i, n)| format!(" (fold {i} of {n})"))
                .unwrap_or_default()
        );
        out.push_str(&self.evaluation().text().unwrap_or_default());
        let _ = writeln!(
            out,
            "\nDeviations from the teacher queried at the same states:\n"
        );
        let mut t = Table::new(
            "deviations",
            "Deviations from the teacher",
            vec![
                Column::new("steps", Unit::Count),
                Column::new("mean abs arm", Unit::Number(4)),
                Column::new("mean abs hand", Unit::Number(4)),
            ],
        );
        for d in self.phase_deviations() {
            t.push(
                d.phase,
                vec![
                    Cell::one(d.steps as f64),
                    Cell::opt(d.arm_abs_deviation),
                    Cell::opt(d.hand_abs_deviation),
                ],
            );
        }
        out.push_str(&t.markdown_with(Layout::plain("phase")));
        Some(out)
    }
}
