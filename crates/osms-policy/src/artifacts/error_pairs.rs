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
        let all = eval.overall();
        serde_json::json!({
            "fold": self.fold.map(|(i, n)| format!("{i} of {n}")),
            "rollouts": self.rollouts.len(),
            "steps": self.rollouts.iter().map(PairRollout::steps).sum::<usize>(),
            "student_success_rate": all.success_rate,
            "student_completion_rate": all.completion_rate,
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

    /// `pairs.csv`: one row per step of every rollout (D_E item, step, phase, success of the
    /// rollout, then π̄'s 24 action channels `student_0..23` and the teacher's `teacher_0..23`),
    /// what Eq. 7 is fitted on, for analyses the summary does not make.
    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut csv = String::from("item,step,phase,success");
        for who in ["student", "teacher"] {
            for k in 0..N_ACTION {
                let _ = write!(csv, ",{who}_{k}");
            }
        }
        csv.push('\n');
        for r in &self.rollouts {
            for n in 0..r.steps() {
                let phase = Phase::ALL
                    .get(usize::from(r.phase[n]))
                    .map_or("unknown", |p| p.name());
                let _ = write!(csv, "{},{n},{phase},{}", r.item, r.eval.outcome.success());
                for v in r.student[n * N_ACTION..(n + 1) * N_ACTION]
                    .iter()
                    .chain(&r.teacher[n * N_ACTION..(n + 1) * N_ACTION])
                {
                    let _ = write!(csv, ",{v}");
                }
                csv.push('\n');
            }
        }
        vec![("pairs.csv".into(), csv.into_bytes())]
    }
}

#[cfg(test)]
mod tests {
    use osms_sim::control::DrDraw;
    use osms_sim::{Failure, Metrics, ObjectVariant, Outcome};

    use super::*;

    #[test]
    fn pairs_csv_has_one_row_per_step_with_both_actions() {
        let eval = EvalRow {
            variant: ObjectVariant::all()[0],
            lateral_offset_m: 0.0,
            dr: DrDraw::none(),
            steps: 2,
            metrics: Metrics {
                contact_time_secs: None,
                contact_speed_mps: None,
                max_force_n: 0.0,
                follow_through_m: 0.0,
                event_step: 0,
                closest_approach_m: 0.1,
            },
            outcome: Outcome {
                failures: vec![Failure::Drop],
            },
            trace: None,
        };
        let pairs = ErrorPairs {
            fold: Some((0, 2)),
            rollouts: vec![PairRollout {
                item: 7,
                student: (0..2 * N_ACTION).map(|i| i as f32).collect(),
                teacher: (0..2 * N_ACTION).map(|i| -(i as f32)).collect(),
                phase: vec![Phase::Approach as u8, Phase::Grasping as u8],
                eval,
            }],
        };
        let files = pairs.files();
        assert_eq!(files.len(), 1);
        assert_eq!(files[0].0, "pairs.csv");
        let text = String::from_utf8(files[0].1.clone()).expect("utf-8");
        let lines: Vec<Vec<&str>> = text.lines().map(|l| l.split(',').collect()).collect();
        assert_eq!(lines.len(), 3, "a header and one row per step");
        assert_eq!(lines[0].len(), 4 + 2 * N_ACTION);
        assert_eq!(lines[0][4], "student_0");
        assert_eq!(lines[0][4 + N_ACTION], "teacher_0");
        let second = &lines[2];
        assert_eq!(second.len(), lines[0].len());
        assert_eq!(&second[..4], &["7", "1", Phase::Grasping.name(), "false"]);
        assert_eq!(
            second[4],
            N_ACTION.to_string(),
            "π̄'s first channel at step 1"
        );
        assert_eq!(
            second[4 + N_ACTION],
            format!("-{N_ACTION}"),
            "the teacher's"
        );
    }
}
