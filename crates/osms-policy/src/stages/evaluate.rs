//! `evaluate`: any policy on a condition set, for tuning on a development stream: the scripted
//! catcher, a teacher or a student, whichever is wired.

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Slot, StageError, items_one_by_one};
use osms_sim::artifacts::{Conditions, EvalRow, Evaluation, WorldArtifact};
use osms_sim::catcher::{CatcherSpec, ScriptedCatcher};
use osms_sim::{Episode, NoHooks, RolloutSpec, World};
use serde::{Deserialize, Serialize};

use super::Evaluates;
use crate::artifacts::{StudentArtifact, Teacher};
use crate::catch::ActorInputs;
use crate::protocol::EvalProtocol;
use crate::student::{ChunkExecution, ROLLOUT_BATCH, Student};

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvaluateParams {
    /// How the rollouts run. The scripted catcher and a student run this spec (a student
    /// with its own history length); a teacher runs its training task with this spec's
    /// domain randomisation, as `eval_teacher` with `dr` set does.
    pub rollout: RolloutSpec,
    /// The scripted catcher's gains (used when neither a teacher nor a student is wired).
    pub catcher: CatcherSpec,
    /// The scripted catcher reads the world as the prior of this rung of the teacher's
    /// actor-input ladder does (issue 54): the prior a realisable teacher builds on. The
    /// default, `privileged`, is left out of the encoded params, so keys built before it stay
    /// valid.
    #[serde(skip_serializing_if = "ActorInputs::is_privileged")]
    pub prior_inputs: ActorInputs,
    /// The scripted catcher's ballistic fit reads this many frames instead of its rung's (a
    /// probe of the fit's window for issue 66's `tracked` rung; needs a rung that fits the
    /// flight, `observed_velocity` or later). Absent: the rung's own window; left out of the
    /// encoded params then, so keys built before it stay valid.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prior_fit_frames: Option<usize>,
    /// The scripted catcher holds the arm still for the first this many control steps (a
    /// probe for issue 66). Absent: its rung's own; left out of the encoded params then.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prior_hold_steps: Option<usize>,
    /// The scripted catcher reads the object from the delay-aware flight estimate
    /// (`osms_sim::flight`) whatever its rung (a probe for issue 66). Left out of the encoded
    /// params when false.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub prior_tracked: bool,
    /// How a wired student's chunks are executed (issue 68, beyond the paper). The paper's,
    /// the default, is left out of the encoded params, so keys built before it stay valid.
    #[serde(skip_serializing_if = "ChunkExecution::is_paper")]
    pub execution: ChunkExecution,
}

impl EvaluateParams {
    /// How the scripted catcher reads the world: its rung's perception, with the fit's window
    /// replaced by `prior_fit_frames`.
    pub fn prior_perception(&self) -> osms_sim::catcher::Perception {
        let mut perception = self.prior_inputs.perception();
        if let Some(frames) = self.prior_fit_frames {
            perception.estimated_object = Some(frames);
        }
        if let Some(steps) = self.prior_hold_steps {
            perception.hold_steps = steps;
        }
        if self.prior_tracked {
            perception.tracked = true;
        }
        perception
    }

    /// The scripted catcher's rollout spec: `rollout`, keeping the frames its fit reads.
    pub fn prior_rollout(&self) -> RolloutSpec {
        let mut spec = self.prior_inputs.rollout(&self.rollout);
        if let Some(frames) = self.prior_fit_frames {
            spec.history_steps = spec.history_steps.max(frames);
        }
        spec
    }
}

/// The policy an `evaluate` stage rolls out.
pub enum Evaluated {
    /// The scripted catcher, as the stage's protocol sets it up.
    Scripted(Box<EvalProtocol>),
    Teacher(Box<Teacher>),
    Student(Box<Student>, RolloutSpec),
}

/// One policy on every condition of a set; rollout `i` draws its domain randomisation from
/// ("item", i) and a student's noise from ("policy", i), as the `eval_*` kinds do: under the
/// same stage name and seed its rows are theirs (tests/tests/experiments.rs checks the scripted
/// catcher's).
pub struct EvaluateStage;
impl Kind for EvaluateStage {
    const KIND: &'static str = "evaluate";
    /// 2: rows keep their DR draws.
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Conditions>("conditions"),
        Slot::one::<Teacher>("teacher").optional(),
        Slot::one::<StudentArtifact>("student").optional(),
    ];
    const DOC: &'static str =
        "any policy (scripted catcher, teacher or student, as wired) evaluated on a condition set";
    type Params = EvaluateParams;

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }
}

impl ItemStage for EvaluateStage {
    type Prepared = (World, Conditions, Evaluated);
    type Item = EvalRow;
    type Output = Evaluation;

    fn prepare(&self, ctx: &Ctx<'_, EvaluateParams>) -> Result<Self::Prepared, StageError> {
        let p = ctx.params;
        if !p.execution.is_paper() && !ctx.has_input("student") {
            return Err("params.execution: chunk execution applies to a student, and no `student` is wired\nhint: wire `student` or leave `execution` out".into());
        }
        let protocol = Self::protocol(p, None)?;
        let policy = match (ctx.has_input("teacher"), ctx.has_input("student")) {
            (true, true) => {
                return Err(
                    "`evaluate` rolls out one policy: wire `teacher` or `student`, not both".into(),
                );
            }
            (true, false) => {
                let mut teacher: Teacher = ctx.input("teacher")?;
                teacher.task = protocol.teacher_task(&teacher.task);
                Evaluated::Teacher(Box::new(teacher))
            }
            (false, true) => {
                let student = ctx.input::<StudentArtifact>("student")?.student;
                protocol.execution.check_for(&student.params)?;
                let spec = protocol.student_spec(&student);
                Evaluated::Student(Box::new(student), spec)
            }
            (false, false) => {
                p.catcher.validate()?;
                Evaluated::Scripted(Box::new(protocol))
            }
        };
        Ok((
            ctx.input::<WorldArtifact>("world")?.world()?,
            ctx.sharded("conditions")?,
            policy,
        ))
    }
    fn n_items(&self, _: &Ctx<'_, EvaluateParams>, p: &Self::Prepared) -> usize {
        p.1.items.len()
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, EvaluateParams>,
        prepared: &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<EvalRow, StageError> {
        let (world, conditions, policy) = prepared;
        let condition = conditions.items[index].clone();
        let record = match policy {
            Evaluated::Scripted(protocol) => {
                let s = &protocol.scripted;
                let mut catcher = ScriptedCatcher::with_perception(
                    s.catcher.clone(),
                    protocol.rollout.control.clone(),
                    s.perception,
                );
                Episode::new(world, &s.rollout, condition, rng.clone())
                    .run(&mut catcher, &mut NoHooks)
            }
            Evaluated::Teacher(t) => {
                crate::catch::rollout(world, &t.task, &t.agent, condition, rng.clone())
            }
            Evaluated::Student(..) => {
                let mut rows = self.run_batch(ctx, prepared, index, vec![rng.clone()])?;
                return Ok(rows.remove(0));
            }
        };
        Ok(EvalRow::of(record))
    }
    fn batch_len(&self, (_, _, policy): &Self::Prepared) -> usize {
        match policy {
            Evaluated::Student(..) => ROLLOUT_BATCH,
            _ => 1,
        }
    }
    /// A student's rollouts step in lockstep ([`rollouts`]); the other policies one by one.
    fn run_batch(
        &self,
        ctx: &Ctx<'_, EvaluateParams>,
        prepared: &Self::Prepared,
        first: usize,
        rngs: Vec<StreamRng>,
    ) -> Result<Vec<EvalRow>, StageError> {
        let (world, conditions, policy) = prepared;
        let Evaluated::Student(student, spec) = policy else {
            return items_one_by_one(self, ctx, prepared, first, rngs);
        };
        Ok(super::student_rows(
            ctx,
            (world, conditions),
            (student, ctx.params.execution, spec),
            first,
            rngs,
        ))
    }
    fn merge(
        &self,
        _: &Ctx<'_, EvaluateParams>,
        _: Self::Prepared,
        rows: Vec<EvalRow>,
    ) -> Result<Evaluation, StageError> {
        Ok(Evaluation { rows })
    }
}
