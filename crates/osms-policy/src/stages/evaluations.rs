//! The evaluation kinds and the protocol each one's params set ([`EvalProtocol`]): the one
//! place that says what an evaluation stage's rollouts are, read by the kinds themselves and by
//! the gym (which matches no kind names). A new evaluation kind implements [`Evaluates`] and
//! joins [`evaluation_kinds`].

use osms_make::ItemStage;
use osms_sim::stages::{EvalParams, EvalScriptedStage};

use super::{
    EvalStudentParams, EvalStudentStage, EvalTeacherParams, EvalTeacherStage, EvaluateParams,
    EvaluateStage,
};
use crate::catch::CatchTaskSpec;
use crate::protocol::{EvalProtocol, ScriptedSetup};

/// An evaluation kind: a stage whose item `i` rolls a policy out on condition `i` of its set.
pub trait Evaluates: ItemStage {
    /// Whether the protocol depends on the task of the teacher wired to the stage
    /// (`eval_teacher` runs its teacher's own task).
    const READS_TEACHER_TASK: bool = false;

    /// The protocol `params` set; `teacher` is the wired teacher's task when
    /// [`Evaluates::READS_TEACHER_TASK`].
    fn protocol(
        params: &Self::Params,
        teacher: Option<&CatchTaskSpec>,
    ) -> Result<EvalProtocol, String>;
}

impl Evaluates for EvalTeacherStage {
    const READS_TEACHER_TASK: bool = true;

    /// The teacher's training task, with `dr` if set.
    fn protocol(
        params: &EvalTeacherParams,
        teacher: Option<&CatchTaskSpec>,
    ) -> Result<EvalProtocol, String> {
        let task = teacher.ok_or("an `eval_teacher` protocol needs its teacher's task")?;
        Ok(EvalProtocol::on(task.with_dr(&params.dr).rollout))
    }
}

impl Evaluates for EvalStudentStage {
    fn protocol(
        params: &EvalStudentParams,
        _: Option<&CatchTaskSpec>,
    ) -> Result<EvalProtocol, String> {
        Ok(EvalProtocol {
            execution: params.execution,
            ..EvalProtocol::on(params.rollout.clone())
        })
    }
}

impl Evaluates for EvalScriptedStage {
    fn protocol(params: &EvalParams, _: Option<&CatchTaskSpec>) -> Result<EvalProtocol, String> {
        let mut protocol = EvalProtocol::on(params.rollout.clone());
        protocol.scripted.catcher = params.catcher.clone();
        Ok(protocol)
    }
}

impl Evaluates for EvaluateStage {
    /// The scripted catcher reads the world as its `prior_*` params say.
    fn protocol(
        params: &EvaluateParams,
        _: Option<&CatchTaskSpec>,
    ) -> Result<EvalProtocol, String> {
        Ok(EvalProtocol {
            rollout: params.rollout.clone(),
            scripted: ScriptedSetup {
                catcher: params.catcher.clone(),
                perception: params.prior_perception(),
                rollout: params.prior_rollout(),
            },
            execution: params.execution,
        })
    }
}

/// An evaluation kind by name, with how to read a protocol from its params as a pipeline
/// holds them (JSON).
pub struct EvaluationKind {
    pub kind: &'static str,
    /// As [`Evaluates::READS_TEACHER_TASK`].
    pub reads_teacher_task: bool,
    protocol: fn(&serde_json::Value, Option<&CatchTaskSpec>) -> Result<EvalProtocol, String>,
}

impl EvaluationKind {
    fn of<S: Evaluates>() -> Self {
        EvaluationKind {
            kind: S::KIND,
            reads_teacher_task: S::READS_TEACHER_TASK,
            protocol: |params, teacher| {
                let params: S::Params =
                    serde_json::from_value(params.clone()).map_err(|e| e.to_string())?;
                S::protocol(&params, teacher)
            },
        }
    }

    /// The protocol of a stage of this kind with `params` (its resolved params); `teacher` as
    /// [`Evaluates::protocol`] takes it.
    pub fn protocol(
        &self,
        params: &serde_json::Value,
        teacher: Option<&CatchTaskSpec>,
    ) -> Result<EvalProtocol, String> {
        (self.protocol)(params, teacher)
    }
}

/// The evaluation kinds osms ships.
pub fn evaluation_kinds() -> Vec<EvaluationKind> {
    vec![
        EvaluationKind::of::<EvalTeacherStage>(),
        EvaluationKind::of::<EvalStudentStage>(),
        EvaluationKind::of::<EvalScriptedStage>(),
        EvaluationKind::of::<EvaluateStage>(),
    ]
}
