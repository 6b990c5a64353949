//! `sum` (test kind): sums the values in index order.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};

use crate::artifacts::{Numbers, Total};

/// Sums the values in index order.
pub struct SumKind;
impl Kind for SumKind {
    const KIND: &'static str = "sum";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Numbers>("values")];
    const DOC: &'static str = "count and sum of the values (test kind)";
    type Params = NoParams;
}

impl Stage for SumKind {
    type Output = Total;
    /// Streams the rows (shard by shard when the input is sharded).
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Total, StageError> {
        let mut values = Vec::new();
        for row in ctx.items::<Numbers>("values")? {
            values.extend(row?);
        }
        Ok(Total {
            count: values.len() as u64,
            sum: values.iter().sum(),
        })
    }
}
