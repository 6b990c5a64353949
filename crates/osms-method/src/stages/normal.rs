//! `normal`: the Normal baseline, unperturbed-only validation of the same candidate sets,
//! extended with mixed teacher rollouts through the same construction. Extension item j
//! draws its condition from ("item", n_R + j), its domain randomisation from ("attempt", j)
//! and its projection samples from ("projection", j).

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Scale, Slot, StageError};
use osms_policy::artifacts::{Dataset, DemoGroup, DemoSet, Teacher};
use osms_policy::catch::CatchTaskSpec;
use osms_sim::artifacts::WorldArtifact;

use super::{BaselineParams, demonstration_set_scale};
use crate::artifacts::{CandidateSets, ErrorModelArtifact, Validation};
use crate::candidates::{Generator, SearchParams};
use crate::construct::{Inputs, normal_extension, normal_group, used};
use crate::cvae::Cvae;
use crate::validate::{Construction, select_unperturbed};

/// What `normal` reads.
pub struct NormalInputs {
    inputs: Inputs,
    validation: Validation,
    manifold: Cvae,
    search: SearchParams,
    /// The task with privileged frames recorded (the extension's windows need ω̄).
    collect_task: CatchTaskSpec,
    target: Option<usize>,
    extension: usize,
}

/// The Normal set: unperturbed-only validation of D_R's candidate sets (read from the
/// validation, whose unperturbed outcomes are exactly these), extended with mixed teacher
/// rollouts on the stage's own conditions put through the same construction.
pub struct NormalStage;
impl Kind for NormalStage {
    const KIND: &'static str = "normal";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Teacher>("teacher"),
        Slot::one::<Dataset>("data").roles(&["d_r"]),
        Slot::one::<CandidateSets>("candidates"),
        Slot::one::<ErrorModelArtifact>("error_model"),
        Slot::one::<Validation>("validation"),
        Slot::one::<Cvae>("manifold"),
        Slot::one::<DemoSet>("target").optional(),
    ];
    const DOC: &'static str = "the Normal baseline: unperturbed-only validation of the same candidate sets, extended with mixed teacher rollouts through the same construction";
    type Params = BaselineParams;

    fn numerics() -> Vec<Numerics> {
        osms_policy::stages::numerics()
    }

    fn scale(_: &BaselineParams, inputs: &[(&str, f64)]) -> Scale {
        demonstration_set_scale(inputs)
    }
}

impl ItemStage for NormalStage {
    type Prepared = NormalInputs;
    type Item = DemoGroup;
    type Output = DemoSet;

    fn prepare(&self, ctx: &Ctx<'_, BaselineParams>) -> Result<NormalInputs, StageError> {
        ctx.params.check(ctx.has_input("target"))?;
        let validation: Validation = ctx.sharded("validation")?;
        if validation.params.construction != Construction::Both {
            return Err(format!(
                "input `validation` ran `{}`; the Normal baseline reads a validation that refines and repairs",
                validation.params.construction.name()
            )
            .into());
        }
        let inputs = super::load_inputs(ctx, &validation.params)?;
        inputs.check_validation(&validation.items, &validation.generator)?;
        let candidates: CandidateSets = ctx.head("candidates")?;
        // The extension searches the way the geodesic stage does; the ablation generators are
        // matched to a geodesic reference the extension's conditions do not have.
        if candidates.params.generator != Generator::Geodesic {
            return Err(format!(
                "input `candidates` holds `{}` sets; the Normal baseline takes the geodesic ones (its extension repeats their search)",
                candidates.params.generator.name()
            )
            .into());
        }
        let manifold: Cvae = ctx.input("manifold")?;
        if let Some(r) = inputs.rollouts.iter().find(|r| r.osw.complete)
            && r.osw.zeta_org.len() != manifold.h_os * osms_sim::N_ARM
        {
            return Err(format!(
                "input `manifold` has H_OS = {}, the D_R windows {}",
                manifold.h_os,
                r.osw.zeta_org.len() / osms_sim::N_ARM
            )
            .into());
        }
        // The D_R part's yield predicts how many extension conditions reach the target.
        let mut base = 0usize;
        for (v, r) in validation.items.iter().zip(&inputs.rollouts) {
            let j_org = validation
                .params
                .j_org(r.record.outcome.success(), r.record.metrics.max_force_n);
            if r.record.outcome.success() || select_unperturbed(j_org, &v.candidates).is_some() {
                base += 1;
            }
        }
        let (target, extra) = super::deficit(ctx, base)?;
        let yield_r = base as f64 / inputs.rollouts.len().max(1) as f64;
        let extension = if extra == 0 {
            0
        } else {
            ((extra as f64 / yield_r.max(0.05)) * ctx.params.margin).ceil() as usize
        };
        let mut collect_task = inputs.task.clone();
        collect_task.rollout.record_privileged = true;
        Ok(NormalInputs {
            search: candidates.params,
            inputs,
            validation,
            manifold,
            collect_task,
            target,
            extension,
        })
    }
    fn n_items(&self, _: &Ctx<'_, BaselineParams>, p: &NormalInputs) -> usize {
        p.inputs.rollouts.len() + p.extension
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, BaselineParams>,
        n: &NormalInputs,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<DemoGroup, StageError> {
        let vp = &n.validation.params;
        if let Some(r) = n.inputs.rollouts.get(index) {
            return Ok(normal_group(
                &n.inputs,
                vp,
                r,
                &n.inputs.sets[index],
                &n.validation.items[index].candidates,
                false,
            )?);
        }
        Ok(normal_extension(
            &n.inputs,
            vp,
            &n.collect_task,
            &n.manifold,
            &n.search,
            index,
            rng,
            ctx.stream_id("attempt", index as u64),
            &mut ctx.rng("projection", index as u64),
        )?)
    }
    fn merge(
        &self,
        _: &Ctx<'_, BaselineParams>,
        n: NormalInputs,
        groups: Vec<DemoGroup>,
    ) -> Result<DemoSet, StageError> {
        let set = DemoSet {
            construction: "normal".into(),
            target: n.target,
            used: used(&groups, n.target),
            groups,
        };
        if let Some(t) = set.target
            && set.len() < t
        {
            tracing::warn!(
                "normal: the extension's {} conditions gave {} of D_*'s {t} demonstrations; raise params.margin to close the gap",
                n.extension,
                set.len()
            );
        }
        Ok(set)
    }
}
