//! `dart`: the DART-IL baseline (Laskey et al. 2017; issue 68, beyond the paper). The teacher
//! collects demonstrations with noise injected into the actions it executes, and they are
//! labelled with the actions it intended, so a student sees the states its own errors lead to
//! with the teacher's answers there. DART sizes the noise to the trained student's error; here
//! that error is the fitted action-error model (Eq. 7, phase-wise correlated) at κ = 1, which
//! the closed-loop calibration matched to π̄'s success. Item `i` draws its conditions from
//! ("item", i), the domain randomisation of attempt `a` from ("attempt", i · max_attempts + a)
//! and the noise's innovations from ("noise", …) of the same index.

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Scale, Slot, StageError};
use osms_policy::artifacts::{Dataset, DemoEntry, DemoGroup, DemoSet, Execution, Origin, Teacher};
use osms_sim::World;
use osms_sim::artifacts::WorldArtifact;
use osms_sim::conditions::sample;
use serde::{Deserialize, Serialize};

use crate::artifacts::ErrorModelArtifact;
use crate::construct::used;
use crate::error_model::{ErrorModel, ErrorVariant, Perturber};
use crate::intervene::{Errors, execute};

use super::demonstration_set_scale;

/// DART-IL's collection. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DartParams {
    /// The noise's size against the modelled student error: Eq. 7's κ. 1, DART's rule, injects
    /// the error the model predicts for the trained student.
    pub kappa: f64,
    /// The fit of the error-model artifact that injects the noise (absent: its adopted model).
    pub error_model: Option<ErrorVariant>,
    /// Keep only the noisy rollouts that succeed, as Naive-IL keeps only the teacher's
    /// successes (false: every rollout, as DART's paper does).
    pub successes_only: bool,
    /// Attempts an item may take to find a success.
    pub max_attempts: u32,
}

impl Default for DartParams {
    fn default() -> Self {
        DartParams {
            kappa: 1.0,
            error_model: None,
            successes_only: true,
            max_attempts: 100,
        }
    }
}

/// What `dart` builds once.
pub struct DartPrepared {
    world: World,
    teacher: Teacher,
    model: ErrorModel,
    target: usize,
}

/// Noisy teacher rollouts on the stage's own conditions, as many as the target set has
/// demonstrations (size-matched to D_*).
pub struct DartStage;
impl Kind for DartStage {
    const KIND: &'static str = "dart";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Teacher>("teacher"),
        Slot::one::<Dataset>("data").roles(&["d_r"]),
        Slot::one::<ErrorModelArtifact>("error_model"),
        Slot::one::<DemoSet>("target"),
    ];
    const DOC: &'static str = "the DART-IL baseline: teacher rollouts under the action-error model's noise, labelled with the teacher's intended actions, as many as the target set's demonstrations";
    type Params = DartParams;

    fn numerics() -> Vec<Numerics> {
        osms_policy::stages::numerics()
    }

    fn scale(_: &DartParams, inputs: &[(&str, f64)]) -> Scale {
        demonstration_set_scale(inputs)
    }
}

impl ItemStage for DartStage {
    type Prepared = DartPrepared;
    type Item = DemoGroup;
    type Output = DemoSet;

    fn prepare(&self, ctx: &Ctx<'_, DartParams>) -> Result<DartPrepared, StageError> {
        let p = ctx.params;
        let model = super::fit_of(ctx.input("error_model")?, p.error_model)?.with_kappa(p.kappa);
        model
            .validate()
            .map_err(|e| format!("input `error_model`: {e}"))?;
        // The datasets' task: their domain randomisation, the rollouts' spec.
        let data: Dataset = ctx.head("data")?;
        let mut teacher: Teacher = ctx.input("teacher")?;
        teacher.task = data.task;
        teacher.task.rollout.record_privileged = false;
        let target = ctx.sharded::<DemoSet>("target")?.len();
        if target == 0 {
            return Err("input `target` holds no demonstrations: nothing to size-match\nhint: wire a built D_* (`dstar`)".into());
        }
        Ok(DartPrepared {
            world: ctx.input::<WorldArtifact>("world")?.world()?,
            teacher,
            model,
            target,
        })
    }

    fn n_items(&self, _: &Ctx<'_, DartParams>, p: &DartPrepared) -> usize {
        p.target
    }

    fn run_item(
        &self,
        ctx: &Ctx<'_, DartParams>,
        p: &DartPrepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<DemoGroup, StageError> {
        let max = ctx.params.max_attempts;
        for attempt in 0..max {
            let condition = sample(&p.teacher.task.conditions, p.world.home_palm_pos, rng)?;
            let stream = index as u64 * u64::from(max) + u64::from(attempt);
            let e = execute(
                &p.world,
                &p.teacher.task,
                &p.teacher.agent,
                condition,
                ctx.rng("attempt", stream),
                None,
                Some(Errors {
                    perturber: Perturber::new(&p.model),
                    rng: ctx.rng("noise", stream),
                }),
            );
            let success = e.record.outcome.success();
            if ctx.params.successes_only && !success {
                continue;
            }
            return Ok(DemoGroup {
                extension: true,
                item: index as u32,
                attempt,
                condition: e.record.condition.clone(),
                original_success: success,
                origin: Origin::Kept,
                demos: vec![DemoEntry::labelled(
                    Execution::Dart,
                    &e.record,
                    e.record.intended.clone(),
                )],
            });
        }
        Err(format!(
            "item {index}: the teacher failed {max} noisy attempts in a row\nhint: lower params.kappa or raise params.max_attempts"
        )
        .into())
    }

    fn merge(
        &self,
        _: &Ctx<'_, DartParams>,
        p: DartPrepared,
        groups: Vec<DemoGroup>,
    ) -> Result<DemoSet, StageError> {
        Ok(DemoSet {
            construction: "dart".into(),
            target: Some(p.target),
            used: used(&groups, Some(p.target)),
            groups,
        })
    }
}
