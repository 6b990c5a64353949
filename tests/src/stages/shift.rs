//! `shift` (test kind): adds a constant.

use osms_core::check::{Check, Checked};
use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use serde::{Deserialize, Serialize};

use crate::artifacts::Numbers;

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShiftParams {
    pub by: f64,
}

/// Any value that parses: test kinds exercise the engine, not params' ranges.
impl Check for ShiftParams {
    fn check(&self) -> Checked {
        Ok(())
    }
}

/// Adds a constant.
pub struct ShiftKind;
impl Kind for ShiftKind {
    const KIND: &'static str = "shift";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Numbers>("values")];
    const DOC: &'static str = "every value plus a constant (test kind)";
    type Params = ShiftParams;
}

impl Stage for ShiftKind {
    type Output = Numbers;
    fn run(&self, ctx: &Ctx<'_, ShiftParams>) -> Result<Numbers, StageError> {
        let v: Numbers = ctx.sharded("values")?;
        Ok(Numbers {
            rows: v
                .rows
                .iter()
                .map(|r| r.iter().map(|x| x + ctx.params.by).collect())
                .collect(),
        })
    }
}
