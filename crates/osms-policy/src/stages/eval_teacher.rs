//! `eval_teacher`: a frozen teacher on a condition set.

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Slot, StageError};
use osms_sim::World;
use osms_sim::artifacts::{Conditions, EvalRow, Evaluation, WorldArtifact};
use osms_sim::control::DrSpec;
use serde::{Deserialize, Serialize};

use super::Evaluates;
use crate::artifacts::Teacher;
use crate::catch::rollout;

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalTeacherParams {
    /// Domain randomisation of the evaluation rollouts (a preset name or a table); absent:
    /// the teacher's training setting.
    pub dr: Option<DrSpec>,
}

/// The frozen teacher (deterministic actions) on every condition of a set; rollout `i` draws
/// its domain randomisation from ("item", i).
pub struct EvalTeacherStage;
impl Kind for EvalTeacherStage {
    const KIND: &'static str = "eval_teacher";
    /// 3: rows keep their DR draws.
    const CODE_VERSION: u32 = 3;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Conditions>("conditions"),
        Slot::one::<Teacher>("teacher"),
    ];
    const DOC: &'static str =
        "a frozen teacher evaluated on a condition set (table per family x size)";
    type Params = EvalTeacherParams;

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }
}

impl ItemStage for EvalTeacherStage {
    type Prepared = (World, Conditions, Teacher);
    type Item = EvalRow;
    type Output = Evaluation;

    fn prepare(&self, ctx: &Ctx<'_, EvalTeacherParams>) -> Result<Self::Prepared, StageError> {
        let mut teacher: Teacher = ctx.input("teacher")?;
        teacher.task = Self::protocol(ctx.params, Some(&teacher.task))?.teacher_task(&teacher.task);
        Ok((
            ctx.input::<WorldArtifact>("world")?.world()?,
            ctx.sharded("conditions")?,
            teacher,
        ))
    }
    fn n_items(&self, _: &Ctx<'_, EvalTeacherParams>, p: &Self::Prepared) -> usize {
        p.1.items.len()
    }
    fn run_item(
        &self,
        _: &Ctx<'_, EvalTeacherParams>,
        (world, conditions, teacher): &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<EvalRow, StageError> {
        Ok(EvalRow::of(rollout(
            world,
            &teacher.task,
            &teacher.agent,
            conditions.items[index].clone(),
            rng.clone(),
        )))
    }
    fn merge(
        &self,
        _: &Ctx<'_, EvalTeacherParams>,
        _: Self::Prepared,
        rows: Vec<EvalRow>,
    ) -> Result<Evaluation, StageError> {
        Ok(Evaluation { rows })
    }
}
