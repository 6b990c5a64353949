//! `error_calibration`: does each error model behave like π̄? The frozen teacher under every
//! model at every κ on π̄'s held-out D_E conditions, beside π̄'s own rollouts there (issue 66;
//! what it shares with `calibrate_error_model` is in `closed_loop`).

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Scale, Slot, StageError};
use osms_sim::N_ACTION;
use osms_sim::control::DrSpec;
use serde::{Deserialize, Serialize};

use crate::artifacts::{Calibration, CalibrationItem, RunOutcome, RunSpec, VariantFit};
use crate::calibrate::DeviationStats;
use crate::error_model::{ErrorModel, ErrorVariant, PAPER_KAPPA};

use super::closed_loop::{INPUTS, Loaded, load, student_draws, teacher_draw};

/// `error_calibration`'s settings. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CalibrationParams {
    /// κ_ε each perturbed model runs at: 1 (the model as fitted, what calibration is judged
    /// at) and validation's 1.5.
    pub kappas: Vec<f64>,
    /// Rollouts per condition and run (common random numbers across models and κ).
    pub draws: usize,
    /// The models run; empty: every model of the input, in its order.
    pub models: Vec<ErrorVariant>,
    /// Domain randomisation of the teacher's and π̄'s rollouts; absent: the teacher's
    /// training setting. Set it as `error_pairs`' (`"paper"`), so π̄ is compared where its
    /// error pairs were recorded.
    pub dr: Option<DrSpec>,
}

impl Default for CalibrationParams {
    fn default() -> Self {
        CalibrationParams {
            kappas: vec![1.0, PAPER_KAPPA],
            draws: 4,
            models: Vec::new(),
            dr: None,
        }
    }
}

/// The prepared runs of `error_calibration`: each run spec with its model.
pub struct Prepared {
    loaded: Loaded,
    runs: Vec<(RunSpec, ErrorModel)>,
}

/// The frozen teacher under every model at every κ on each held-out D_E condition of every
/// fold, beside π̄'s own rollouts there. Draw q of D_E item i takes its DR from stream
/// ("dr-q", i) and its innovations from ("errors-q", i); π̄'s draw q the same DR stream.
pub struct CalibrationStage;

impl Kind for CalibrationStage {
    const KIND: &'static str = "error_calibration";
    /// 2: π̄ is rolled out `draws` times per condition with the teacher's DR streams, instead
    /// of once (its `error_pairs` rollout, with DR draws of its own).
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = INPUTS;
    const DOC: &'static str = "closed-loop calibration of the error models: the teacher under each model against π̄ on π̄'s held-out D_E conditions";
    type Params = CalibrationParams;

    fn numerics() -> Vec<Numerics> {
        osms_policy::stages::numerics()
    }

    /// The pairs' rollouts, each run `draws` times per model and κ and by π̄ (the models not
    /// counted).
    fn scale(params: &CalibrationParams, inputs: &[(&str, f64)]) -> Scale {
        let n = Scale::input(inputs, "pairs");
        Scale {
            work: n * (params.draws * (params.kappas.len() + 1)) as f64,
            size: n,
        }
    }
}

impl ItemStage for CalibrationStage {
    type Prepared = Prepared;
    type Item = CalibrationItem;
    type Output = Calibration;

    fn prepare(&self, ctx: &Ctx<'_, CalibrationParams>) -> Result<Prepared, StageError> {
        let p = ctx.params;
        let loaded = load(ctx, &p.dr)?;
        let fits: Vec<&VariantFit> = if p.models.is_empty() {
            loaded.errors.variants.iter().collect()
        } else {
            p.models
                .iter()
                .map(|v| {
                    loaded
                        .errors
                        .variants
                        .iter()
                        .find(|f| f.model.variant == *v)
                        .ok_or_else(|| {
                            format!(
                                "params.models: input `error_model` has no `{}` model\nhint: it has {}",
                                v.name(),
                                loaded
                                    .errors
                                    .variants
                                    .iter()
                                    .map(|f| f.model.variant.name())
                                    .collect::<Vec<_>>()
                                    .join(", ")
                            )
                        })
                })
                .collect::<Result<_, _>>()?
        };
        let mut runs = Vec::new();
        for fit in fits {
            let name = fit.model.variant.name().to_string();
            if fit.model.variant == ErrorVariant::Unperturbed {
                runs.push((
                    RunSpec {
                        model: name,
                        kappa: 1.0,
                    },
                    fit.model.clone(),
                ));
                continue;
            }
            for &kappa in &p.kappas {
                runs.push((
                    RunSpec {
                        model: name.clone(),
                        kappa,
                    },
                    fit.model.with_kappa(kappa),
                ));
            }
        }
        for (spec, model) in &runs {
            model
                .validate()
                .map_err(|e| format!("input `error_model`, model `{}`: {e}", spec.model))?;
            if model.channels != N_ACTION && model.variant != ErrorVariant::Unperturbed {
                return Err(format!(
                    "input `error_model`: model `{}` has {} channels, the teacher acts on {N_ACTION}",
                    spec.model, model.channels
                )
                .into());
            }
        }
        Ok(Prepared { loaded, runs })
    }

    fn n_items(&self, _: &Ctx<'_, CalibrationParams>, p: &Prepared) -> usize {
        p.loaded.pairs.len()
    }

    fn run_item(
        &self,
        ctx: &Ctx<'_, CalibrationParams>,
        p: &Prepared,
        index: usize,
        _: &mut StreamRng,
    ) -> Result<CalibrationItem, StageError> {
        let l = &p.loaded;
        let (fold, pair) = &l.pairs[index];
        let condition = &l.conditions[&pair.item];
        let student = student_draws(ctx, l, *fold, pair.item, ctx.params.draws);
        let runs = p
            .runs
            .iter()
            .map(|(_, model)| {
                let mut rows = Vec::with_capacity(ctx.params.draws);
                let mut deviation = DeviationStats::default();
                for q in 0..ctx.params.draws {
                    let (row, d) = teacher_draw(ctx, l, condition, pair.item, q, model);
                    rows.push(row);
                    deviation.add(&d);
                }
                RunOutcome { rows, deviation }
            })
            .collect();
        Ok(CalibrationItem {
            fold: *fold,
            item: pair.item,
            student,
            runs,
        })
    }

    fn merge(
        &self,
        ctx: &Ctx<'_, CalibrationParams>,
        p: Prepared,
        items: Vec<CalibrationItem>,
    ) -> Result<Calibration, StageError> {
        Ok(Calibration {
            draws: ctx.params.draws,
            runs: p.runs.into_iter().map(|(s, _)| s).collect(),
            items,
        })
    }
}
