//! `combine` (test kind): reads three inputs of three types.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};

use crate::artifacts::{Combined, Drops, Numbers, Total};

/// Reads three inputs of three types.
pub struct CombineKind;
impl Kind for CombineKind {
    const KIND: &'static str = "combine";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Total>("total"),
        Slot::one::<Drops>("drops"),
        Slot::one::<Numbers>("reference"),
    ];
    const DOC: &'static str = "a small report over three inputs (test kind)";
    type Params = NoParams;
}

impl Stage for CombineKind {
    type Output = Combined;
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Combined, StageError> {
        let total: Total = ctx.input("total")?;
        let drops: Drops = ctx.sharded("drops")?;
        let reference: Numbers = ctx.sharded("reference")?;
        Ok(Combined {
            total: total.sum,
            drops: drops.finals.len() as u64,
            reference_rows: reference.rows.len() as u64,
        })
    }
}
