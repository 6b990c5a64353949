//! `calibrate_error_model`: an error model's deviation scaled so the teacher under it succeeds
//! as often as π̄ in closed loop, the `calibrated` model validation applies (issue 66; what it
//! shares with `error_calibration` is in `closed_loop`).

use osms_make::{Ctx, Kind, Numerics, Slot, Stage, StageError};
use osms_policy::artifacts::PairRollout;
use osms_sim::control::DrSpec;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::artifacts::{ErrorModelArtifact, FoldSearch, ScaleSearch, VariantFit};
use crate::calibrate::interpolate_scale;
use crate::error_model::{ErrorModel, ErrorVariant, PAPER_KAPPA, PairSequence, table3_metrics};

use super::closed_loop::{INPUTS, load, student_draws, teacher_draw};

/// `calibrate_error_model`'s settings. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CalibrateParams {
    /// The fitted model whose deviation (bias and residual) is scaled.
    pub base: ErrorVariant,
    /// Deviation scales tried, increasing.
    pub scales: Vec<f64>,
    /// The fold on whose π̄'s held-out conditions the scale is chosen (the other folds then
    /// confirm it, in `error_calibration`); absent: every fold's conditions, each with its own
    /// π̄, pooled (as Eq. 7 is fitted on every fold's pairs). Either way the artifact keeps
    /// each fold's own search beside the one the model takes.
    pub fold: Option<u32>,
    /// Rollouts per condition and scale (common random numbers across scales).
    pub draws: usize,
    /// As [`CalibrationParams::dr`].
    pub dr: Option<DrSpec>,
}

impl Default for CalibrateParams {
    fn default() -> Self {
        CalibrateParams {
            base: ErrorVariant::UnitGain,
            scales: vec![0.6, 0.8, 1.0],
            fold: None,
            draws: 4,
            dr: None,
        }
    }
}

/// The base model's deviation (bias and residual) scaled so that the teacher under it at κ = 1
/// succeeds as often as π̄ on the tuning folds' held-out conditions (each fold's with its own
/// π̄): each scale of the grid, and π̄ itself, is rolled out `draws` times per condition (draw q
/// of D_E item i: DR from ("dr-q", i), innovations from ("errors-q", i), the same at every
/// scale and for π̄), and the scale is interpolated where the success rate crosses π̄'s. The
/// output is the input's models plus `calibrated`, which validation then applies at the base's
/// κ, and the search, pooled and per fold.
pub struct CalibrateErrorModelStage;

/// One tuning condition's fold, the teacher's successes under each scale of the grid over the
/// draws, and π̄'s.
type ConditionRow = (u32, Vec<usize>, usize);

/// Tuning conditions between checkpoints (pipeline.toml's `checkpoint_every` overrides it):
/// the default make's ≈ 500 take ≈ 10 minutes on 2 cores.
const CHECKPOINT_EVERY: u32 = 100;

impl Kind for CalibrateErrorModelStage {
    const KIND: &'static str = "calibrate_error_model";
    /// 2: π̄'s success on the tuning fold is over `draws` rollouts per condition with the
    /// teacher's DR streams, not its one `error_pairs` rollout; the folds may be pooled.
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = INPUTS;
    const DOC: &'static str = "an error model's deviation scaled so the teacher under it succeeds as often as π̄ in closed loop (the `calibrated` model)";
    type Params = CalibrateParams;

    fn numerics() -> Vec<Numerics> {
        osms_policy::stages::numerics()
    }
}

impl Stage for CalibrateErrorModelStage {
    type Output = ErrorModelArtifact;

    fn run(&self, ctx: &Ctx<'_, CalibrateParams>) -> Result<ErrorModelArtifact, StageError> {
        let p = ctx.params;
        let l = load(ctx, &p.dr)?;
        let base = l
            .errors
            .variants
            .iter()
            .find(|f| f.model.variant == p.base)
            .map(|f| f.model.with_kappa(1.0))
            .ok_or_else(|| {
                format!(
                    "params.base = `{}`: input `error_model` has no such model\nhint: an `error_model` stage fits {}",
                    p.base.name(),
                    ErrorVariant::FITTED.map(ErrorVariant::name).join(", ")
                )
            })?;
        let tune: Vec<(u32, &PairRollout)> = l
            .pairs
            .iter()
            .filter(|(f, _)| p.fold.is_none_or(|g| *f == g))
            .map(|(f, r)| (*f, r))
            .collect();
        if tune.is_empty() {
            let mut folds: Vec<String> = l.pairs.iter().map(|(f, _)| f.to_string()).collect();
            folds.dedup();
            return Err(format!(
                "params.fold = {}: input `pairs` has no rollouts of that fold\nhint: one of {}, or leave `fold` out to pool them",
                p.fold.map_or_else(|| "-".into(), |f| f.to_string()),
                folds.join(", ")
            )
            .into());
        }
        let models: Vec<ErrorModel> = p
            .scales
            .iter()
            .map(|&c| base.with_deviation_scale(c, ErrorVariant::Calibrated))
            .collect();
        let progress = ctx.progress();
        progress.set_total(tune.len() as u64);
        // Per condition: its fold, its successes at each scale over the draws, π̄'s; computed
        // in blocks of conditions, each block's rows checkpointed, so a killed build resumes
        // after the last block (the rows do not depend on the blocks).
        let mut successes: Vec<ConditionRow> = ctx
            .resume::<Vec<ConditionRow>>()
            .filter(|rows| rows.len() <= tune.len())
            .unwrap_or_default();
        progress.inc(successes.len() as u64);
        let block = ctx.checkpoint_every(CHECKPOINT_EVERY) as usize;
        while successes.len() < tune.len() {
            let end = (successes.len() + block).min(tune.len());
            let rows: Vec<ConditionRow> = tune[successes.len()..end]
                .par_iter()
                .map(|&(fold, pair)| {
                    let condition = &l.conditions[&pair.item];
                    let student = student_draws(ctx, &l, fold, pair.item, p.draws);
                    let own = student.rows.iter().filter(|r| r.outcome.success()).count();
                    let row = models
                        .iter()
                        .map(|model| {
                            (0..p.draws)
                                .filter(|&q| {
                                    teacher_draw(ctx, &l, condition, pair.item, q, model)
                                        .0
                                        .outcome
                                        .success()
                                })
                                .count()
                        })
                        .collect();
                    progress.inc(1);
                    (fold, row, own)
                })
                .collect();
            successes.extend(rows);
            if successes.len() < tune.len() {
                ctx.checkpoint(successes.len() as u64, &successes)?;
            }
        }
        let search = |of: &dyn Fn(u32) -> bool| -> Result<FoldSearch, StageError> {
            let rows: Vec<&ConditionRow> = successes.iter().filter(|r| of(r.0)).collect();
            let rollouts = (rows.len() * p.draws) as f64;
            let grid: Vec<(f64, f64)> = p
                .scales
                .iter()
                .enumerate()
                .map(|(s, &c)| {
                    (
                        c,
                        rows.iter().map(|r| r.1[s]).sum::<usize>() as f64 / rollouts,
                    )
                })
                .collect();
            let target = rows.iter().map(|r| r.2).sum::<usize>() as f64 / rollouts;
            let scale = interpolate_scale(&grid, target).ok_or("params.scales is empty")?;
            Ok(FoldSearch {
                conditions: rows.len(),
                target,
                grid,
                scale,
            })
        };
        let mut folds: Vec<u32> = tune.iter().map(|(f, _)| *f).collect();
        folds.dedup();
        let pooled = search(&|_| true)?;
        let by_fold = folds
            .iter()
            .map(|&f| Ok((f, search(&|g| g == f)?)))
            .collect::<Result<Vec<_>, StageError>>()?;
        let scale = pooled.scale;
        let kappa = l
            .errors
            .variants
            .iter()
            .find(|f| f.model.variant == p.base)
            .map_or(PAPER_KAPPA, |f| f.model.kappa);
        let model = base
            .with_deviation_scale(scale, ErrorVariant::Calibrated)
            .with_kappa(kappa);
        let sequences: Vec<PairSequence<'_>> =
            l.pairs.iter().map(|(_, r)| PairSequence::from(r)).collect();
        let metrics = table3_metrics(
            &model,
            &sequences,
            &mut ctx.rng("table3", l.errors.variants.len() as u64),
        );
        let mut errors = l.errors;
        errors
            .variants
            .retain(|v| v.model.variant != ErrorVariant::Calibrated);
        errors.variants.push(VariantFit {
            model: model.clone(),
            metrics,
        });
        errors.model = model;
        errors.calibration = Some(ScaleSearch {
            base: p.base,
            folds,
            draws: p.draws,
            pooled,
            by_fold,
        });
        Ok(errors)
    }
}
