//! `impact_profiles`: figure (a), impact profiles aligned at t_c.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use osms_sim::artifacts::Evaluation;

use super::seed_evals;
use crate::figures::impact_profiles;
use crate::plot::Figure;

pub struct ImpactProfilesStage;
impl Kind for ImpactProfilesStage {
    const KIND: &'static str = "impact_profiles";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Evaluation>("catch_only"),
        Slot::one::<Evaluation>("teacher"),
        Slot::gather::<Evaluation>("naive"),
        Slot::gather::<Evaluation>("normal"),
        Slot::gather::<Evaluation>("ours"),
    ];
    const DOC: &'static str = "figure (a): impact profiles aligned at t_c, catching-only vs teacher and teacher vs the final students";
    type Params = NoParams;
}

impl Stage for ImpactProfilesStage {
    type Output = Figure;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Figure, StageError> {
        let catch_only: Evaluation = ctx.sharded("catch_only")?;
        let teacher: Evaluation = ctx.sharded("teacher")?;
        let naive = seed_evals(ctx, "naive")?;
        let normal = seed_evals(ctx, "normal")?;
        let ours = seed_evals(ctx, "ours")?;
        Ok(impact_profiles(
            &catch_only,
            &teacher,
            [&naive, &normal, &ours],
        ))
    }
}
