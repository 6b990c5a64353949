//! `error_calibration` and `calibrate_error_model`: the error models against π̄ in closed loop
//! (issue 66). Both roll the frozen teacher out under a model on the D_E conditions each
//! cross-fitted π̄ was held out from (those `error_pairs` ran it on), and compare with π̄'s own
//! rollouts there, drawn with the same DR streams as the teacher's.

use std::collections::{BTreeMap, BTreeSet};

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Numerics, Scale, Slot, Stage, StageError};
use osms_policy::artifacts::{Dataset, ErrorPairs, PairRollout, StudentArtifact, Teacher};
use osms_policy::student::{Student, paired_rollout};
use osms_sim::artifacts::{EvalRow, WorldArtifact};
use osms_sim::conditions::TaskCondition;
use osms_sim::control::DrSpec;
use osms_sim::{N_ACTION, RolloutSpec, World};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::artifacts::{
    Calibration, CalibrationItem, ErrorModelArtifact, FoldSearch, RunOutcome, RunSpec, ScaleSearch,
    VariantFit,
};
use crate::calibrate::{DeviationStats, interpolate_scale, teacher_under};
use crate::error_model::{ErrorModel, ErrorVariant, PairSequence, table3_metrics};

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
            kappas: vec![1.0, 1.5],
            draws: 4,
            models: Vec::new(),
            dr: None,
        }
    }
}

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

/// What both kinds read: the world, the teacher under the rollouts' DR, every fold's π̄
/// rollouts (fold, pair) in fold order, the D_E conditions by item, the error models and each
/// fold's π̄ with its rollout spec.
pub struct Loaded {
    world: World,
    teacher: Teacher,
    pairs: Vec<(u32, PairRollout)>,
    conditions: BTreeMap<u32, TaskCondition>,
    errors: ErrorModelArtifact,
    students: BTreeMap<u32, (Student, RolloutSpec)>,
}

const INPUTS: &[Slot] = &[
    Slot::one::<WorldArtifact>("world"),
    Slot::one::<Teacher>("teacher"),
    Slot::one::<Dataset>("data").roles(&["d_e"]),
    Slot::gather::<ErrorPairs>("pairs"),
    Slot::one::<ErrorModelArtifact>("error_model"),
    Slot::gather::<StudentArtifact>("students"),
];

fn load<P>(ctx: &Ctx<'_, P>, dr: &Option<DrSpec>) -> Result<Loaded, StageError> {
    let mut teacher: Teacher = ctx.input("teacher")?;
    teacher.task = teacher.task.with_dr(dr);
    teacher.task.rollout.record_privileged = false;
    let mut conditions = BTreeMap::new();
    for item in ctx.items::<Dataset>("data")? {
        let r = item?.rollout;
        conditions.insert(r.item, r.record.condition);
    }
    let mut pairs = Vec::new();
    for (_, fold) in ctx.gathered_sharded::<ErrorPairs>("pairs")? {
        let f = fold.fold.map_or(0, |(i, _)| i);
        for p in fold.rollouts {
            if !conditions.contains_key(&p.item) {
                return Err(format!(
                    "input `pairs`: fold {f}'s rollouts ran on D_E item {}, which input `data` does not hold\nhint: wire `data` to the D_E dataset the `error_pairs` stages read",
                    p.item
                )
                .into());
            }
            pairs.push((f, p));
        }
    }
    if pairs.is_empty() {
        return Err("input `pairs`: no π̄ rollouts to compare with".into());
    }
    let errors: ErrorModelArtifact = ctx.input("error_model")?;
    let mut students = BTreeMap::new();
    for (_, s) in ctx.gathered::<StudentArtifact>("students")? {
        let Some((f, _)) = s.fold else {
            return Err("input `students`: a student that is not cross-fitted\nhint: wire `students` to the cross-fitted π̄ stage the `error_pairs` stages read (`student_il#*`)".into());
        };
        let trained: BTreeSet<u32> = s.items.iter().copied().collect();
        if let Some((_, p)) = pairs
            .iter()
            .find(|(g, p)| *g == f && trained.contains(&p.item))
        {
            return Err(format!(
                "input `students`: fold {f}'s student trained on D_E item {}, which fold {f}'s pairs hold out\nhint: wire `students` to the π̄ stage the `error_pairs` stages read",
                p.item
            )
            .into());
        }
        let spec = s.student.rollout_spec(&teacher.task.rollout);
        students.insert(f, (s.student, spec));
    }
    if let Some((f, _)) = pairs.iter().find(|(f, _)| !students.contains_key(f)) {
        return Err(format!(
            "input `students` has no student of fold {f}, whose pairs input `pairs` holds\nhint: wire `students` to the cross-fitted π̄ stage the `error_pairs` stages read (`student_il#*`)"
        )
        .into());
    }
    Ok(Loaded {
        world: ctx.input::<WorldArtifact>("world")?.world()?,
        teacher,
        pairs,
        conditions,
        errors,
        students,
    })
}

/// The DR and innovation streams of draw q on D_E item `item`: the same for every model, κ and
/// scale, and the DR stream the same for π̄ (common random numbers).
fn draw_streams<P>(ctx: &Ctx<'_, P>, item: u32, q: usize) -> (StreamRng, StreamRng) {
    (
        ctx.rng(&format!("dr-{q}"), u64::from(item)),
        ctx.rng(&format!("errors-{q}"), u64::from(item)),
    )
}

/// The teacher under `model` on draw q of D_E item `item` (from [`draw_streams`]).
fn teacher_draw<P>(
    ctx: &Ctx<'_, P>,
    l: &Loaded,
    condition: &TaskCondition,
    item: u32,
    q: usize,
    model: &ErrorModel,
) -> (EvalRow, DeviationStats) {
    let (dr, noise) = draw_streams(ctx, item, q);
    teacher_under(
        &l.world,
        &l.teacher.task,
        &l.teacher.agent,
        condition.clone(),
        dr,
        model,
        noise,
    )
}

/// π̄_f's own rollouts on D_E item `item`, `draws` of them: draw q with the DR stream of the
/// teacher's draw q and its policy noise from ("policy-q", item), the teacher queried at every
/// state π̄ reaches. Its rows (without the impact trace) and its arm deviation from the teacher.
fn student_draws<P>(
    ctx: &Ctx<'_, P>,
    l: &Loaded,
    fold: u32,
    item: u32,
    draws: usize,
) -> RunOutcome {
    let (student, spec) = &l.students[&fold];
    let condition = &l.conditions[&item];
    let mut rows = Vec::with_capacity(draws);
    let mut deviation = DeviationStats::default();
    for q in 0..draws {
        let (dr, _) = draw_streams(ctx, item, q);
        let paired = paired_rollout(
            &l.world,
            spec,
            student,
            (&l.teacher.agent, &l.teacher.task),
            condition.clone(),
            dr,
            ctx.rng(&format!("policy-{q}"), u64::from(item)),
        );
        deviation.push_rollout(&paired.record.intended, &paired.teacher, &paired.phase);
        let mut row = EvalRow::of(paired.record);
        row.trace = None;
        rows.push(row);
    }
    RunOutcome { rows, deviation }
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
impl ItemStage for CalibrationStage {
    const KIND: &'static str = "error_calibration";
    /// 2: π̄ is rolled out `draws` times per condition with the teacher's DR streams, instead
    /// of once (its `error_pairs` rollout, with DR draws of its own).
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = INPUTS;
    const DOC: &'static str = "closed-loop calibration of the error models: the teacher under each model against π̄ on π̄'s held-out D_E conditions";
    type Params = CalibrationParams;
    type Prepared = Prepared;
    type Item = CalibrationItem;
    type Output = Calibration;

    fn check_params(params: &Self::Params) -> osms_core::check::Checked {
        osms_core::check::Check::check(params)
    }

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
impl Stage for CalibrateErrorModelStage {
    const KIND: &'static str = "calibrate_error_model";
    /// 2: π̄'s success on the tuning fold is over `draws` rollouts per condition with the
    /// teacher's DR streams, not its one `error_pairs` rollout; the folds may be pooled.
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = INPUTS;
    const DOC: &'static str = "an error model's deviation scaled so the teacher under it succeeds as often as π̄ in closed loop (the `calibrated` model)";
    type Params = CalibrateParams;
    type Output = ErrorModelArtifact;

    fn check_params(params: &Self::Params) -> osms_core::check::Checked {
        osms_core::check::Check::check(params)
    }

    fn numerics() -> Vec<Numerics> {
        osms_policy::stages::numerics()
    }

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
            .map_or(1.5, |f| f.model.kappa);
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
