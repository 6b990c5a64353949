//! `validate`: every D_R rollout's candidates validated under the action-error model, and the
//! refine / repair decision (paper 4.4, Eqs. 8–9, Alg. 1 steps 3–4).

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Scale, Slot, StageError};
use osms_policy::artifacts::{Dataset, Teacher};
use osms_sim::artifacts::WorldArtifact;

use crate::artifacts::{CandidateSets, ErrorModelArtifact, ErrorStreams, Validation};
use crate::construct::Inputs;
use crate::validate::{Cost, ValidateParams, ValidationItem, validate};

/// Alg. 1 steps 3–4 for every D_R rollout: one unperturbed and Q perturbed rollouts per
/// candidate and for ζ_org, common random numbers per condition (perturbed rollout q of item i
/// draws from stream ("errors-q", i)), and the decision.
pub struct ValidateStage;
impl Kind for ValidateStage {
    const KIND: &'static str = "validate";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Teacher>("teacher"),
        Slot::one::<Dataset>("data").roles(&["d_r"]),
        Slot::one::<CandidateSets>("candidates"),
        Slot::one::<ErrorModelArtifact>("error_model"),
    ];
    const DOC: &'static str = "candidate validation under the action-error model (paper 4.4, Eqs. 8-9): SR, J and the refine / repair decision per D_R rollout";
    type Params = ValidateParams;

    fn numerics() -> Vec<Numerics> {
        osms_policy::stages::numerics()
    }

    /// The D_R rollouts validated (`rollouts`, 0: all of `data`).
    fn scale(params: &ValidateParams, inputs: &[(&str, f64)]) -> Scale {
        let data = Scale::input(inputs, "data");
        Scale::items(match params.rollouts {
            0 => data,
            n => data.min(n as f64),
        })
    }
}

impl ItemStage for ValidateStage {
    type Prepared = Inputs;
    type Item = ValidationItem;
    type Output = Validation;

    fn prepare(&self, ctx: &Ctx<'_, ValidateParams>) -> Result<Inputs, StageError> {
        super::load_inputs(ctx, ctx.params)
    }
    fn n_items(&self, _: &Ctx<'_, ValidateParams>, p: &Inputs) -> usize {
        p.rollouts.len()
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, ValidateParams>,
        inputs: &Inputs,
        index: usize,
        _: &mut StreamRng,
    ) -> Result<ValidationItem, StageError> {
        let (item, cost) = validate_with_cost(ctx, inputs, index)?;
        tracing::debug!(
            index,
            rollouts = cost.rollouts,
            steps = cost.steps,
            "validated"
        );
        Ok(item)
    }
    fn merge(
        &self,
        ctx: &Ctx<'_, ValidateParams>,
        inputs: Inputs,
        items: Vec<ValidationItem>,
    ) -> Result<Validation, StageError> {
        Ok(Validation {
            // Both evaluations give the same artifact; the flag is not part of it.
            params: ValidateParams {
                exhaustive: false,
                ..ctx.params.clone()
            },
            error_model: inputs.model.variant.name().to_string(),
            generator: inputs.generator,
            streams: streams(ctx),
            items,
        })
    }
}

fn streams(ctx: &Ctx<'_, ValidateParams>) -> ErrorStreams {
    ErrorStreams {
        seed: ctx.seed().unwrap_or_default(),
        stage: ctx.stage().to_string(),
    }
}

/// One D_R rollout's validation and what it simulated (the benchmark's measure).
fn validate_with_cost(
    ctx: &Ctx<'_, ValidateParams>,
    inputs: &Inputs,
    index: usize,
) -> crate::Result<(ValidationItem, Cost)> {
    let streams = streams(ctx);
    let item = inputs.rollouts[index].item;
    let errors = move |q| streams.rng(item, q);
    validate(&inputs.case(index, &errors), ctx.params)
}
