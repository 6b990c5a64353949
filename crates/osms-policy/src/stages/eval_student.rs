//! `eval_student`: a student on a condition set.

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Slot, StageError};
use osms_sim::artifacts::{Conditions, EvalRow, Evaluation, WorldArtifact};
use osms_sim::{RolloutSpec, World};
use serde::{Deserialize, Serialize};

use super::Evaluates;
use crate::artifacts::StudentArtifact;
use crate::student::{ChunkExecution, ROLLOUT_BATCH, Student};

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalStudentParams {
    /// How the evaluation rollouts run (control, domain randomisation, success criteria); the
    /// history the student reads is its own.
    pub rollout: RolloutSpec,
    /// How the student's chunks are executed (issue 68, beyond the paper). The paper's, the
    /// default, is left out of the encoded params, so keys built before it stay valid.
    #[serde(skip_serializing_if = "ChunkExecution::is_paper")]
    pub execution: ChunkExecution,
}

/// A student on every condition of a set; rollout `i` draws its domain randomisation from
/// ("item", i) and the policy's noise from ("policy", i).
pub struct EvalStudentStage;
impl Kind for EvalStudentStage {
    const KIND: &'static str = "eval_student";
    /// 2: rows keep their DR draws.
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Conditions>("conditions"),
        Slot::one::<StudentArtifact>("student"),
    ];
    const DOC: &'static str = "a student evaluated on a condition set (table per family x size)";
    type Params = EvalStudentParams;

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }
}

impl ItemStage for EvalStudentStage {
    type Prepared = (World, Conditions, Student, RolloutSpec);
    type Item = EvalRow;
    type Output = Evaluation;

    fn prepare(&self, ctx: &Ctx<'_, EvalStudentParams>) -> Result<Self::Prepared, StageError> {
        let student = ctx.input::<StudentArtifact>("student")?.student;
        let protocol = Self::protocol(ctx.params, None)?;
        protocol.execution.check_for(&student.params)?;
        let spec = protocol.student_spec(&student);
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
        prepared: &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<EvalRow, StageError> {
        let mut rows = self.run_batch(ctx, prepared, index, vec![rng.clone()])?;
        Ok(rows.remove(0))
    }
    fn batch_len(&self, _: &Self::Prepared) -> usize {
        ROLLOUT_BATCH
    }
    fn run_batch(
        &self,
        ctx: &Ctx<'_, EvalStudentParams>,
        (world, conditions, student, spec): &Self::Prepared,
        first: usize,
        rngs: Vec<StreamRng>,
    ) -> Result<Vec<EvalRow>, StageError> {
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
        _: &Ctx<'_, EvalStudentParams>,
        _: Self::Prepared,
        rows: Vec<EvalRow>,
    ) -> Result<Evaluation, StageError> {
        Ok(Evaluation { rows })
    }
}
