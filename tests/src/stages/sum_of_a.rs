//! `sum_of_a` (test kind): the sum of numbers of role `a` only (typed slots with roles).

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};

use crate::artifacts::{Numbers, Total};

/// The sum of numbers of role `a` only (test kind for typed slots with roles).
pub struct SumOfAKind;
impl Kind for SumOfAKind {
    const KIND: &'static str = "sum_of_a";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Numbers>("values").roles(&["a"])];
    const DOC: &'static str = "count and sum of numbers of role a (test kind)";
    type Params = NoParams;
}

impl Stage for SumOfAKind {
    type Output = Total;
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Total, StageError> {
        super::SumKind.run(ctx)
    }
}
