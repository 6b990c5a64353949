//! `signs` (test kind): the signs of the values: many inputs map to one output, so early cutoff shows.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};

use crate::artifacts::Numbers;

/// Signs of the values: many inputs map to one output, which makes early cutoff observable.
pub struct SignsKind;
impl Kind for SignsKind {
    const KIND: &'static str = "signs";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Numbers>("values")];
    const DOC: &'static str = "the sign of every value (test kind)";
    type Params = NoParams;
}

impl Stage for SignsKind {
    type Output = Numbers;
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Numbers, StageError> {
        let v: Numbers = ctx.sharded("values")?;
        Ok(Numbers {
            rows: v
                .rows
                .iter()
                .map(|r| r.iter().map(|x| x.signum()).collect())
                .collect(),
        })
    }
}
