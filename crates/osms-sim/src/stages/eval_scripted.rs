//! `eval_scripted`: the scripted privileged catcher on a condition set.

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Slot, StageError};
use serde::{Deserialize, Serialize};

use crate::artifacts::{Conditions, EvalRow, Evaluation, WorldArtifact};
use crate::catcher::{CatcherSpec, ScriptedCatcher};
use crate::episode::{Episode, RolloutSpec};
use crate::policy::NoHooks;
use crate::world::World;

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalParams {
    pub rollout: RolloutSpec,
    pub catcher: CatcherSpec,
}

/// Rolls the scripted catcher out on every condition; rollout `i` draws from ("item", i).
pub struct EvalScriptedStage;
impl Kind for EvalScriptedStage {
    const KIND: &'static str = "eval_scripted";
    /// 5: rows keep their DR draws.
    const CODE_VERSION: u32 = 5;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Conditions>("conditions"),
    ];
    const DOC: &'static str =
        "the scripted privileged catcher evaluated on a condition set (table per family x size)";
    type Params = EvalParams;

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }
    /// Without domain randomisation a scripted rollout draws nothing: shared by a sweep.
    fn draws_randomness(params: &EvalParams) -> bool {
        params.rollout.draws_randomness()
    }
}

impl ItemStage for EvalScriptedStage {
    type Prepared = (World, Conditions);
    type Item = EvalRow;
    type Output = Evaluation;

    fn prepare(&self, ctx: &Ctx<'_, EvalParams>) -> Result<(World, Conditions), StageError> {
        ctx.params.catcher.validate()?;
        Ok((
            ctx.input::<WorldArtifact>("world")?.world()?,
            ctx.sharded("conditions")?,
        ))
    }
    fn n_items(&self, _: &Ctx<'_, EvalParams>, (_, conditions): &(World, Conditions)) -> usize {
        conditions.items.len()
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, EvalParams>,
        (world, conditions): &(World, Conditions),
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<EvalRow, StageError> {
        let p = ctx.params;
        let condition = conditions.items[index].clone();
        let mut catcher = ScriptedCatcher::new(p.catcher.clone(), p.rollout.control.clone());
        let record =
            Episode::new(world, &p.rollout, condition, rng.clone()).run(&mut catcher, &mut NoHooks);
        Ok(EvalRow::of(record))
    }
    fn merge(
        &self,
        _: &Ctx<'_, EvalParams>,
        _: (World, Conditions),
        rows: Vec<EvalRow>,
    ) -> Result<Evaluation, StageError> {
        Ok(Evaluation { rows })
    }
}
