//! `offset` (test kind): adds the sum of the optional `offset` input, if wired (an optional slot).

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};

use crate::artifacts::{Numbers, Total};

/// Adds the sum of the optional `offset` input, if wired (an optional slot).
pub struct OffsetKind;
impl Kind for OffsetKind {
    const KIND: &'static str = "offset";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Numbers>("values"),
        Slot::one::<Total>("offset").optional(),
    ];
    const DOC: &'static str = "every value plus an optional total's sum (test kind)";
    type Params = NoParams;
}

impl Stage for OffsetKind {
    type Output = Numbers;
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Numbers, StageError> {
        let v: Numbers = ctx.sharded("values")?;
        let by = if ctx.has_input("offset") {
            ctx.input::<Total>("offset")?.sum
        } else {
            0.0
        };
        Ok(Numbers {
            rows: v
                .rows
                .iter()
                .map(|r| r.iter().map(|x| x + by).collect())
                .collect(),
        })
    }
}
