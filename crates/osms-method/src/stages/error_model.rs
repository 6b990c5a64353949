//! `error_model`: the IL-student action-error model (Eq. 7) fitted on the cross-fitted
//! students' pairs, with the Table III comparison of all four variants and the fits beside them.

use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use osms_policy::artifacts::ErrorPairs;
use osms_sim::{N_ACTION, Phase};

use crate::artifacts::{ErrorModelArtifact, FoldStats, VariantFit};
use crate::error_model::{ErrorFitParams, ErrorVariant, PairSequence, fit, table3_metrics};

/// Eq. 7 on every (π̄, teacher, phase) sequence of the gathered pairs; the model of
/// `params.variant` is the one validation applies, and all four are fitted and scored for
/// Table III (model `i` simulates with stream ("table3", i)).
pub struct ErrorModelStage;
impl Kind for ErrorModelStage {
    const KIND: &'static str = "error_model";
    // v2: Σ_φ matched to the residuals' variances (`StationaryFit::Residual`); v3: the
    // unit-gain and orthogonal fits beside Table III's four.
    const CODE_VERSION: u32 = 3;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[Slot::gather::<ErrorPairs>("pairs")];
    const DOC: &'static str =
        "the IL-student action-error model (Eq. 7) and the Table III metrics of all four variants";
    type Params = ErrorFitParams;
}

impl Stage for ErrorModelStage {
    type Output = ErrorModelArtifact;

    fn run(&self, ctx: &Ctx<'_, ErrorFitParams>) -> Result<ErrorModelArtifact, StageError> {
        let gathered = ctx.gathered_sharded::<ErrorPairs>("pairs")?;
        let mut folds = Vec::with_capacity(gathered.len());
        let mut phase_steps = vec![0usize; Phase::ALL.len()];
        for (_, pairs) in &gathered {
            let eval = pairs.evaluation();
            let all = eval.overall();
            folds.push(FoldStats {
                fold: pairs.fold,
                rollouts: pairs.rollouts.len(),
                steps: pairs.rollouts.iter().map(|r| r.steps()).sum(),
                success_rate: all.success_rate,
                completion_rate: all.completion_rate,
            });
            for r in &pairs.rollouts {
                for &p in &r.phase {
                    if let Some(n) = phase_steps.get_mut(usize::from(p)) {
                        *n += 1;
                    }
                }
            }
        }
        let sequences: Vec<PairSequence<'_>> = gathered
            .iter()
            .flat_map(|(_, pairs)| &pairs.rollouts)
            .map(PairSequence::from)
            .collect();
        let mut variants = Vec::with_capacity(ErrorVariant::FITTED.len());
        for (i, &variant) in ErrorVariant::FITTED.iter().enumerate() {
            let params = ErrorFitParams {
                variant,
                ..ctx.params.clone()
            };
            let model = fit(&sequences, N_ACTION, &params).map_err(|e| {
                format!(
                    "input `pairs`: the {} model cannot be fitted: {e}\nhint: more D_E rollouts give the students more held-out conditions",
                    variant.name()
                )
            })?;
            let metrics = table3_metrics(&model, &sequences, &mut ctx.rng("table3", i as u64));
            variants.push(VariantFit { model, metrics });
        }
        let model = variants
            .iter()
            .find(|v| v.model.variant == ctx.params.variant)
            .map(|v| v.model.clone())
            .ok_or_else(|| {
                format!(
                    "params.variant = `{}` is not fitted on the pairs\nhint: one of {}; a calibrated model comes from a `calibrate_error_model` stage",
                    ctx.params.variant.name(),
                    ErrorVariant::FITTED.map(ErrorVariant::name).join(", ")
                )
            })?;
        Ok(ErrorModelArtifact {
            params: ctx.params.clone(),
            model,
            variants,
            folds,
            phase_steps,
            calibration: None,
        })
    }
}
