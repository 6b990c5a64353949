//! `naive`: the Naive baseline, success-only filtering of D_R extended with successful
//! teacher rollouts to the target set's size. Extension item j draws its condition from
//! ("item", n_R + j) and its domain randomisation from ("attempt", …): the stage's name keeps
//! them apart from every other stage's draws.

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Scale, Slot, StageError};
use osms_policy::artifacts::{Dataset, DemoGroup, DemoSet, Teacher};
use osms_sim::artifacts::WorldArtifact;

use super::{BaselineParams, demonstration_set_scale};
use crate::construct::{naive_extension, naive_group, used};

/// The Naive set: D_R's successes, then successful teacher rollouts on the stage's own
/// conditions until D_*'s count.
pub struct NaiveStage;
impl Kind for NaiveStage {
    const KIND: &'static str = "naive";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Teacher>("teacher"),
        Slot::one::<Dataset>("data").roles(&["d_r"]),
        Slot::one::<DemoSet>("target").optional(),
    ];
    const DOC: &'static str = "the Naive baseline: success-only filtering of D_R, extended with successful teacher rollouts to the target set's size";
    type Params = BaselineParams;

    fn numerics() -> Vec<Numerics> {
        osms_policy::stages::numerics()
    }

    fn scale(params: &BaselineParams, inputs: &[(&str, f64)]) -> Scale {
        let d_r = demonstration_set_scale(inputs);
        // A set of a declared size (issue 74's data curve) is mostly its extension's teacher
        // rollouts, one per demonstration beyond D_R's successes: as many items as it holds.
        match params.demos {
            Some(n) => Scale::items(d_r.work.max(n as f64)),
            None => d_r,
        }
    }
}

impl ItemStage for NaiveStage {
    type Prepared = (osms_sim::World, Teacher, Dataset, Option<usize>, usize);
    type Item = DemoGroup;
    type Output = DemoSet;

    fn prepare(&self, ctx: &Ctx<'_, BaselineParams>) -> Result<Self::Prepared, StageError> {
        ctx.params.check(ctx.has_input("target"))?;
        let data: Dataset = ctx.sharded("data")?;
        let base = data
            .rollouts()
            .filter(|r| r.record.outcome.success())
            .count();
        let (target, extra) = super::deficit(ctx, base)?;
        let mut teacher: Teacher = ctx.input("teacher")?;
        teacher.task = data.task.clone();
        teacher.task.rollout.record_privileged = false;
        Ok((
            ctx.input::<WorldArtifact>("world")?.world()?,
            teacher,
            data,
            target,
            extra,
        ))
    }
    fn n_items(&self, _: &Ctx<'_, BaselineParams>, p: &Self::Prepared) -> usize {
        p.2.items.len() + p.4
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, BaselineParams>,
        (world, teacher, data, _, _): &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<DemoGroup, StageError> {
        if let Some(item) = data.items.get(index) {
            return Ok(naive_group(&item.rollout));
        }
        Ok(naive_extension(
            world,
            &teacher.task,
            &teacher.agent,
            index,
            ctx.params.max_attempts,
            rng,
            &|i| ctx.rng("attempt", i),
        )?)
    }
    fn merge(
        &self,
        _: &Ctx<'_, BaselineParams>,
        (.., target, _): Self::Prepared,
        groups: Vec<DemoGroup>,
    ) -> Result<DemoSet, StageError> {
        Ok(DemoSet {
            construction: "naive".into(),
            target,
            used: used(&groups, target),
            groups,
        })
    }
}
