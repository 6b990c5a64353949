//! The student stage kinds: `student` (a flow-matching student trained on a dataset, cross-fitted
//! when the stage has folds), `eval_student` (a student on a condition set, the same table as
//! `eval_teacher`) and `error_pairs` (the cross-fitted IL students π̄ rolled out on the
//! conditions held out from them, with the frozen teacher queried at every visited state, paper
//! 4.3).

use std::collections::BTreeSet;
use std::fmt::Write;

use osms_core::Artifact;
use osms_core::rng::StreamRng;
use osms_make::{Ctx, Fold, ItemStage, Numerics, Scale, Slot, Stage, StageError, Summarize};
use osms_sim::artifacts::{Conditions, EvalRow, Evaluation, WorldArtifact};
use osms_sim::conditions::TaskCondition;
use osms_sim::control::DrSpec;
use osms_sim::{N_ACTION, Phase, RolloutSpec, World};
use serde::{Deserialize, Serialize};

use crate::dataset::Dataset;
use crate::demos::DemoSet;
use crate::stages::{Teacher, policy_numerics, with_dr};
use crate::student::{Demo, Student, StudentParams, paired_rollout, rollout};

/// Whether D_E item `item` belongs to fold `fold` (the conditions held out from π̄_fold).
pub fn in_fold(item: u32, fold: Fold) -> bool {
    item % fold.count == fold.index
}

/// A trained student and what it was trained on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StudentArtifact {
    pub student: Student,
    /// The fold this student is held out from (cross-fitted students), if any.
    pub fold: Option<(u32, u32)>,
    /// The dataset items (condition draws) the student trained on, held-out curve rollouts
    /// included, in order.
    pub items: Vec<u32>,
}

impl Artifact for StudentArtifact {
    const TYPE_TAG: &'static str = "policy.student_artifact";
    const SCHEMA_VERSION: u16 = 1;
}

impl Summarize for StudentArtifact {
    fn summary(&self) -> serde_json::Value {
        let s = &self.student;
        let last = s.curve.last();
        serde_json::json!({
            "fold": self.fold.map(|(i, n)| format!("{i} of {n}")),
            "items": self.items.len(),
            "train_rollouts": s.train_rollouts,
            "train_samples": s.train_samples,
            "heldout_rollouts": s.heldout_rollouts,
            "parameters": s.net.mlp.parameter_count(),
            "history": s.params.history,
            "chunk": s.params.chunk,
            "euler_steps": s.params.euler_steps,
            "steps": last.map(|c| c.step),
            "train_loss": last.map(|c| c.train_loss),
            "validation_loss": last.and_then(|c| c.validation_loss),
        })
    }

    fn text(&self) -> Option<String> {
        let s = &self.student;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "flow-matching student: {} frames of history, chunks of {} steps, {} Euler steps, hidden {:?} ({} parameters)",
            s.params.history,
            s.params.chunk,
            s.params.euler_steps,
            s.params.hidden,
            s.net.mlp.parameter_count()
        );
        let _ = writeln!(
            out,
            "trained on {} rollouts ({} steps), {} held out for the validation loss{}\n",
            s.train_rollouts,
            s.train_samples,
            s.heldout_rollouts,
            self.fold
                .map(|(i, n)| format!("; cross-fitted: fold {i} of {n} held out"))
                .unwrap_or_default()
        );
        let _ = writeln!(
            out,
            "Learning curve (flow-matching loss per element of the standardised chunk):\n"
        );
        let _ = writeln!(out, "| steps | train loss | validation loss | lr |");
        let _ = writeln!(out, "|---:|---:|---:|---:|");
        let stride = s.curve.len().div_ceil(20).max(1);
        for (i, c) in s.curve.iter().enumerate() {
            if i % stride != 0 && i + 1 != s.curve.len() {
                continue;
            }
            let _ = writeln!(
                out,
                "| {} | {:.4} | {} | {:.2e} |",
                c.step,
                c.train_loss,
                c.validation_loss
                    .map_or_else(|| "-".into(), |v| format!("{v:.4}")),
                c.lr
            );
        }
        Some(out)
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut csv = String::from("step,train_loss,validation_loss,lr\n");
        for c in &self.student.curve {
            let _ = writeln!(
                csv,
                "{},{},{},{}",
                c.step,
                c.train_loss,
                c.validation_loss.map(|v| v.to_string()).unwrap_or_default(),
                c.lr
            );
        }
        vec![("curve.csv".into(), csv.into_bytes())]
    }
}

/// A flow-matching student trained on a dataset's rollouts. With `folds = F` instance `#f`
/// trains on the items outside fold f (item index mod F ≠ f): the cross-fitted IL students π̄.
pub struct StudentStage;
impl Stage for StudentStage {
    const KIND: &'static str = "student";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Dataset>("data").optional(),
        Slot::one::<DemoSet>("demos").optional(),
        Slot::one::<DemoSet>("size_match").optional(),
    ];
    const DOC: &'static str = "a flow-matching student on a rollout dataset (`data`) or a constructed demonstration set (`demos`, optionally cut to the size of `size_match`); cross-fitted with folds";
    type Params = StudentParams;
    type Output = StudentArtifact;

    fn numerics() -> Vec<Numerics> {
        policy_numerics()
    }

    /// Training steps times batch size (the network's width is not counted).
    fn scale(params: &StudentParams, _: &[(&str, f64)]) -> Scale {
        Scale {
            work: f64::from(params.steps) * params.batch as f64,
            size: 1.0,
        }
    }

    fn run(&self, ctx: &Ctx<'_, StudentParams>) -> Result<StudentArtifact, StageError> {
        ctx.params.check()?;
        let fold = ctx.fold();
        let mut demos = Vec::new();
        let mut items = Vec::new();
        let slot = match (ctx.has_input("data"), ctx.has_input("demos")) {
            (true, false) => "data",
            (false, true) => "demos",
            _ => {
                return Err("a student trains on exactly one of `data` (a rollout dataset) and `demos` (a demonstration set)\nhint: wire one of them in the stage's inputs".into());
            }
        };
        if slot == "data" && ctx.has_input("size_match") {
            return Err("`size_match` cuts a demonstration set; it needs `demos`, not `data`\nhint: remove `size_match` or train on `demos`".into());
        }
        if slot == "data" {
            for item in ctx.items::<Dataset>("data")? {
                let r = item?.rollout;
                if fold.is_some_and(|f| in_fold(r.item, f)) {
                    continue;
                }
                items.push(r.item);
                demos.push(Demo::from_record(&r.record));
            }
        } else {
            let used = ctx.head::<DemoSet>("demos")?.used.unwrap_or(usize::MAX);
            // Matched dataset size (paper 6.4): the leading groups that hold at most the other
            // set's number of demonstrations.
            let cap = if ctx.has_input("size_match") {
                ctx.sharded::<DemoSet>("size_match")?.len()
            } else {
                usize::MAX
            };
            for group in ctx.items::<DemoSet>("demos")?.take(used) {
                let g = group?;
                if g.demos.is_empty() || fold.is_some_and(|f| in_fold(g.item, f)) {
                    continue;
                }
                if demos.len() + g.demos.len() > cap {
                    break;
                }
                items.push(g.item);
                demos.extend(g.demos.into_iter().map(|e| e.demo));
            }
        }
        let progress = ctx.progress();
        progress.set_total(u64::from(ctx.params.steps));
        let student = Student::train(
            &demos,
            ctx.params,
            (ctx.seed().unwrap_or_default(), ctx.stage()),
            &|| progress.inc(1),
        )
        .map_err(|e| format!("input `data`: {e}"))?;
        Ok(StudentArtifact {
            student,
            fold: fold.map(|f| (f.index, f.count)),
            items,
        })
    }
}

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalStudentParams {
    /// How the evaluation rollouts run (control, domain randomisation, success criteria); the
    /// history the student reads is its own.
    pub rollout: RolloutSpec,
}

/// A student on every condition of a set; rollout `i` draws its domain randomisation from
/// ("item", i) and the policy's noise from ("policy", i).
pub struct EvalStudentStage;
impl ItemStage for EvalStudentStage {
    const KIND: &'static str = "eval_student";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Conditions>("conditions"),
        Slot::one::<StudentArtifact>("student"),
    ];
    const DOC: &'static str = "a student evaluated on a condition set (table per family x size)";
    type Params = EvalStudentParams;
    type Prepared = (World, Conditions, Student, RolloutSpec);
    type Item = EvalRow;
    type Output = Evaluation;

    fn numerics() -> Vec<Numerics> {
        policy_numerics()
    }
    fn prepare(&self, ctx: &Ctx<'_, EvalStudentParams>) -> Result<Self::Prepared, StageError> {
        let student = ctx.input::<StudentArtifact>("student")?.student;
        let spec = student.rollout_spec(&ctx.params.rollout);
        Ok((
            ctx.input::<WorldArtifact>("world")?.world()?,
            ctx.sharded("conditions")?,
            student,
            spec,
        ))
    }
    fn n_items(&self, _: &Ctx<'_, EvalStudentParams>, p: &Self::Prepared) -> usize {
        p.1.items.len()
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, EvalStudentParams>,
        (world, conditions, student, spec): &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<EvalRow, StageError> {
        Ok(EvalRow::of(rollout(
            world,
            spec,
            student,
            conditions.items[index].clone(),
            rng.clone(),
            ctx.rng("policy", index as u64),
        )))
    }
    fn merge(
        &self,
        _: &Ctx<'_, EvalStudentParams>,
        _: Self::Prepared,
        rows: Vec<EvalRow>,
    ) -> Result<Evaluation, StageError> {
        Ok(Evaluation { rows })
    }
}

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
    /// 2: the rollouts' evaluation rows keep their impact trace.
    const SCHEMA_VERSION: u16 = 2;
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
        let _ = writeln!(out, "| phase | steps | mean abs arm | mean abs hand |");
        let _ = writeln!(out, "|---|---:|---:|---:|");
        let f = |v: Option<f64>| v.map_or_else(|| "-".into(), |v| format!("{v:.4}"));
        for d in self.phase_deviations() {
            let _ = writeln!(
                out,
                "| {} | {} | {} | {} |",
                d.phase,
                d.steps,
                f(d.arm_abs_deviation),
                f(d.hand_abs_deviation)
            );
        }
        Some(out)
    }
}

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ErrorPairsParams {
    /// Domain randomisation of the student's rollouts (a preset name or a table); absent: the
    /// teacher's training setting.
    pub dr: Option<DrSpec>,
}

/// What `error_pairs` builds once: the world, the teacher, the student, the rollout spec and
/// the conditions of the student's held-out fold (with their D_E items).
pub struct PairsPrepared {
    world: World,
    teacher: Teacher,
    student: Student,
    spec: RolloutSpec,
    conditions: Vec<(u32, TaskCondition)>,
}

/// The IL student π̄_f on the D_E conditions held out from it, the teacher queried at every
/// visited state (paper 4.3). Rollout `i` draws its domain randomisation from ("item", i) and
/// the policy's noise from ("policy", i).
pub struct ErrorPairsStage;
impl ItemStage for ErrorPairsStage {
    const KIND: &'static str = "error_pairs";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Dataset>("data").roles(&["d_e"]),
        Slot::one::<StudentArtifact>("student"),
        Slot::one::<Teacher>("teacher"),
    ];
    const DOC: &'static str =
        "cross-fitted IL students on their held-out D_E conditions, paired with teacher actions";
    type Params = ErrorPairsParams;
    type Prepared = PairsPrepared;
    type Item = PairRollout;
    type Output = ErrorPairs;

    fn numerics() -> Vec<Numerics> {
        policy_numerics()
    }
    fn prepare(&self, ctx: &Ctx<'_, ErrorPairsParams>) -> Result<PairsPrepared, StageError> {
        let student: StudentArtifact = ctx.input("student")?;
        let fold = ctx.fold();
        let own = fold.map(|f| (f.index, f.count));
        if student.fold != own {
            let name = |f: Option<(u32, u32)>| {
                f.map_or_else(|| "no fold".into(), |(i, n)| format!("fold {i} of {n}"))
            };
            return Err(format!(
                "input `student` is cross-fitted for {} but this stage is {}\nhint: declare both stages with the same `folds` and reference the student stage by name, so each fold takes its own student",
                name(student.fold),
                name(own)
            )
            .into());
        }
        let trained: BTreeSet<u32> = student.items.iter().copied().collect();
        let mut conditions = Vec::new();
        for item in ctx.items::<Dataset>("data")? {
            let r = item?.rollout;
            if fold.is_some_and(|f| !in_fold(r.item, f)) {
                continue;
            }
            // Holds by construction for students of this fold; a student trained elsewhere on
            // the same items would be scored on its own training conditions.
            if fold.is_some() && trained.contains(&r.item) {
                return Err(format!(
                    "input `student` trained on D_E item {} of the fold held out from it",
                    r.item
                )
                .into());
            }
            conditions.push((r.item, r.record.condition));
        }
        let mut teacher: Teacher = ctx.input("teacher")?;
        teacher.task = with_dr(&teacher.task, &ctx.params.dr);
        let spec = student.student.rollout_spec(&teacher.task.rollout);
        Ok(PairsPrepared {
            world: ctx.input::<WorldArtifact>("world")?.world()?,
            teacher,
            student: student.student,
            spec,
            conditions,
        })
    }
    fn n_items(&self, _: &Ctx<'_, ErrorPairsParams>, p: &PairsPrepared) -> usize {
        p.conditions.len()
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, ErrorPairsParams>,
        p: &PairsPrepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<PairRollout, StageError> {
        let (item, condition) = &p.conditions[index];
        let paired = paired_rollout(
            &p.world,
            &p.spec,
            &p.student,
            (&p.teacher.agent, &p.teacher.task),
            condition.clone(),
            rng.clone(),
            ctx.rng("policy", index as u64),
        );
        Ok(PairRollout {
            item: *item,
            student: paired.record.intended.clone(),
            teacher: paired.teacher,
            phase: paired.phase,
            eval: EvalRow::of(paired.record),
        })
    }
    fn merge(
        &self,
        ctx: &Ctx<'_, ErrorPairsParams>,
        _: PairsPrepared,
        rollouts: Vec<PairRollout>,
    ) -> Result<ErrorPairs, StageError> {
        Ok(ErrorPairs {
            fold: ctx.fold().map(|f| (f.index, f.count)),
            rollouts,
        })
    }
}

/// Registers the student stage kinds.
pub fn register(registry: &mut osms_make::Registry) {
    registry
        .register(StudentStage)
        .register_itemised(EvalStudentStage)
        .register_itemised(ErrorPairsStage);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folds_partition_the_items() {
        let count = 3;
        for item in 0..30u32 {
            let owners: Vec<u32> = (0..count)
                .filter(|&index| in_fold(item, Fold { index, count }))
                .collect();
            assert_eq!(owners, vec![item % count], "item {item}");
        }
    }
}
