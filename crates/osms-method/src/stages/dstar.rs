//! `dstar`: D_* built from the validation's decisions as student demonstrations (Alg. 1
//! step 4).

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Scale, Slot, StageError};
use osms_policy::artifacts::{Dataset, DemoGroup, DemoSet, Teacher};
use osms_sim::artifacts::WorldArtifact;
use serde::{Deserialize, Serialize};

use crate::artifacts::{CandidateSets, ErrorModelArtifact, Validation};
use crate::construct::{Inputs, PerturbedLabels, dstar_group};

use super::demonstration_set_scale;

/// D_* (Alg. 1 step 4): for a refined or repaired rollout the selected ζ*'s unperturbed
/// rollout and every successful perturbed one (labels: the commanded actions, modelled
/// perturbations included, unless `perturbed_labels` says otherwise); a kept original as it
/// ran; nothing for a dropped one. The rollouts are re-run with the validation's streams and
/// checked against its outcomes.
pub struct DstarStage;
impl Kind for DstarStage {
    const KIND: &'static str = "dstar";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Teacher>("teacher"),
        Slot::one::<Dataset>("data").roles(&["d_r"]),
        Slot::one::<CandidateSets>("candidates"),
        Slot::one::<ErrorModelArtifact>("error_model"),
        Slot::one::<Validation>("validation"),
    ];
    const DOC: &'static str = "D_*: the selected candidates' successful unperturbed and perturbed rollouts and the kept originals, as student demonstrations";
    type Params = DstarParams;

    fn numerics() -> Vec<Numerics> {
        osms_policy::stages::numerics()
    }

    fn scale(_: &DstarParams, inputs: &[(&str, f64)]) -> Scale {
        demonstration_set_scale(inputs)
    }
}

impl ItemStage for DstarStage {
    type Prepared = (Inputs, Validation);
    type Item = DemoGroup;
    type Output = DemoSet;

    fn prepare(&self, ctx: &Ctx<'_, DstarParams>) -> Result<Self::Prepared, StageError> {
        let validation: Validation = ctx.sharded("validation")?;
        let inputs = super::load_inputs(ctx, &validation.params)?;
        inputs.check_validation(&validation.items, &validation.generator)?;
        if inputs.model.variant.name() != validation.error_model {
            return Err(format!(
                "input `validation` ran under the {} error model, but `error_model` gives {}",
                validation.error_model,
                inputs.model.variant.name()
            )
            .into());
        }
        Ok((inputs, validation))
    }
    fn n_items(&self, _: &Ctx<'_, DstarParams>, p: &Self::Prepared) -> usize {
        p.0.rollouts.len()
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, DstarParams>,
        (inputs, validation): &Self::Prepared,
        index: usize,
        _: &mut StreamRng,
    ) -> Result<DemoGroup, StageError> {
        let item = inputs.rollouts[index].item;
        Ok(dstar_group(
            inputs,
            index,
            &validation.items[index],
            validation.params.q,
            ctx.params.perturbed_labels,
            &|q| validation.streams.rng(item, q),
        )?)
    }
    fn merge(
        &self,
        _: &Ctx<'_, DstarParams>,
        _: Self::Prepared,
        groups: Vec<DemoGroup>,
    ) -> Result<DemoSet, StageError> {
        Ok(DemoSet {
            construction: "ours".into(),
            target: None,
            used: None,
            groups,
        })
    }
}

/// D_*'s own setting; everything else is the validation's.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DstarParams {
    /// How the selected candidates' successful perturbed rollouts enter D_* (an ablation
    /// knob). The default, `executed`, is left out of the encoded params, so keys built before
    /// the knob existed stay valid.
    #[serde(default, skip_serializing_if = "is_executed")]
    pub perturbed_labels: PerturbedLabels,
}

fn is_executed(labels: &PerturbedLabels) -> bool {
    *labels == PerturbedLabels::Executed
}
