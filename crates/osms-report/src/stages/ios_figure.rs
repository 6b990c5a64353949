//! `ios_figure`: figure (e), the IOS profile.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use osms_method::artifacts::IosProfile;

use crate::figures::ios_figure;
use crate::plot::Figure;

pub struct IosFigureStage;
impl Kind for IosFigureStage {
    const KIND: &'static str = "ios_figure";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<IosProfile>("profile")];
    const DOC: &'static str = "figure (e): the IOS profile";
    type Params = NoParams;
}

impl Stage for IosFigureStage {
    type Output = Figure;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Figure, StageError> {
        Ok(ios_figure(&ctx.sharded("profile")?))
    }
}
