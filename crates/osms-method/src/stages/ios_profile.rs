//! `ios_profile`: the interventional outcome sensitivity profile (Eq. 1) around the event
//! step k_e.

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Scale, Slot, StageError};
use osms_policy::artifacts::{Dataset, Teacher};
use osms_sim::World;
use osms_sim::artifacts::WorldArtifact;

use crate::artifacts::IosProfile;
use crate::ios::{IosItem, IosParams, profile};

/// The IOS profile of the first `rollouts` D_R rollouts; rollout i draws its Δζ from stream
/// ("item", i).
pub struct IosProfileStage;
impl Kind for IosProfileStage {
    const KIND: &'static str = "ios_profile";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Teacher>("teacher"),
        Slot::one::<Dataset>("data"),
    ];
    const DOC: &'static str =
        "the interventional outcome sensitivity profile (Eq. 1) around the event step k_e";
    type Params = IosParams;

    /// `rollouts` D_R rollouts profiled, each `draws` times.
    fn scale(params: &IosParams, inputs: &[(&str, f64)]) -> Scale {
        let n = Scale::input(inputs, "data").min(params.rollouts as f64);
        Scale {
            work: n * params.draws.max(1) as f64,
            size: n,
        }
    }

    fn numerics() -> Vec<Numerics> {
        osms_policy::stages::numerics()
    }
}

impl ItemStage for IosProfileStage {
    type Prepared = (World, Teacher, Dataset);
    type Item = IosItem;
    type Output = IosProfile;

    fn prepare(&self, ctx: &Ctx<'_, IosParams>) -> Result<Self::Prepared, StageError> {
        ctx.params.check()?;
        let data: Dataset = ctx.sharded("data")?;
        let mut teacher: Teacher = ctx.input("teacher")?;
        teacher.task = data.task.clone();
        teacher.task.rollout.record_privileged = false;
        Ok((ctx.input::<WorldArtifact>("world")?.world()?, teacher, data))
    }
    fn n_items(&self, ctx: &Ctx<'_, IosParams>, p: &Self::Prepared) -> usize {
        ctx.params.rollouts.min(p.2.items.len())
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, IosParams>,
        (world, teacher, data): &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<IosItem, StageError> {
        Ok(profile(
            world,
            &teacher.task,
            &teacher.agent,
            &data.items[index].rollout,
            ctx.params,
            rng,
        )?)
    }
    fn merge(
        &self,
        ctx: &Ctx<'_, IosParams>,
        (_, teacher, _): Self::Prepared,
        items: Vec<IosItem>,
    ) -> Result<IosProfile, StageError> {
        Ok(IosProfile {
            params: ctx.params.clone(),
            force_scale_n: teacher.task.rollout.success.max_force_n,
            items,
        })
    }
}
