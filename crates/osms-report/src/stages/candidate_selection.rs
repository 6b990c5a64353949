//! `candidate_selection`: figure (d), J against SR of the validated candidates.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use osms_method::artifacts::Validation;

use crate::figures::candidate_selection;
use crate::plot::Figure;

pub struct CandidateSelectionStage;
impl Kind for CandidateSelectionStage {
    const KIND: &'static str = "candidate_selection";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Validation>("validation")];
    const DOC: &'static str =
        "figure (d): J vs SR of the validated candidates, selected ones marked";
    type Params = NoParams;
}

impl Stage for CandidateSelectionStage {
    type Output = Figure;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Figure, StageError> {
        Ok(candidate_selection(&ctx.sharded("validation")?))
    }
}
