//! `conditions`: a set of task conditions ω (e.g. the held-out evaluation set).

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Scale, Slot, StageError};
use serde::{Deserialize, Serialize};

use crate::artifacts::{Conditions, WorldArtifact};
use crate::conditions::{ConditionSpec, TaskCondition, sample};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConditionsParams {
    /// How many conditions.
    pub n: u32,
    #[serde(default)]
    pub sampler: ConditionSpec,
}

/// Samples task conditions; condition `i` draws from stream ("item", i).
pub struct ConditionsStage;
impl Kind for ConditionsStage {
    const KIND: &'static str = "conditions";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[Slot::one::<WorldArtifact>("world")];
    const DOC: &'static str = "task conditions ω (object, mass, launch, posture perturbation)";
    type Params = ConditionsParams;

    fn numerics() -> Vec<Numerics> {
        vec![Numerics {
            name: "osms-sim",
            version: crate::NUMERICS_VERSION.to_string(),
        }]
    }

    /// `n` conditions.
    fn scale(params: &ConditionsParams, _: &[(&str, f64)]) -> Scale {
        Scale::items(params.n as f64)
    }
}

impl ItemStage for ConditionsStage {
    type Prepared = [f64; 3];
    type Item = TaskCondition;
    type Output = Conditions;

    fn prepare(&self, ctx: &Ctx<'_, ConditionsParams>) -> Result<[f64; 3], StageError> {
        Ok(ctx.input::<WorldArtifact>("world")?.home_palm_pos)
    }
    fn n_items(&self, ctx: &Ctx<'_, ConditionsParams>, _: &[f64; 3]) -> usize {
        ctx.params.n as usize
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, ConditionsParams>,
        palm: &[f64; 3],
        _: usize,
        rng: &mut StreamRng,
    ) -> Result<TaskCondition, StageError> {
        Ok(sample(&ctx.params.sampler, *palm, rng)?)
    }
    fn merge(
        &self,
        _: &Ctx<'_, ConditionsParams>,
        _: [f64; 3],
        items: Vec<TaskCondition>,
    ) -> Result<Conditions, StageError> {
        Ok(Conditions { items })
    }
}
