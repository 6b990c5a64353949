//! `panic` (test kind): rows `[i]`, or a panic where asked: a panicking kind fails its own stage only.

use osms_core::check::{Check, Checked};
use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Slot, StageError};
use serde::{Deserialize, Serialize};

use crate::artifacts::Numbers;

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PanicParams {
    /// Number of rows (items).
    pub n: u32,
    /// Item index whose `run_item` panics.
    #[serde(default)]
    pub panic_at_item: Option<u32>,
    #[serde(default)]
    pub panic_in_prepare: bool,
    #[serde(default)]
    pub panic_in_merge: bool,
}

/// Any value that parses: test kinds exercise the engine, not params' ranges.
impl Check for PanicParams {
    fn check(&self) -> Checked {
        Ok(())
    }
}

/// Rows `[i]` for every item `i`, or a panic where asked: tests that a panicking kind fails its
/// own stage only. A kind of its own, so the keys of the other kinds' golden outputs stay put.
pub struct PanicKind;
impl Kind for PanicKind {
    const KIND: &'static str = "panicky";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[];
    const DOC: &'static str = "one row per item, or a panic on demand (test kind)";
    type Params = PanicParams;
}

impl ItemStage for PanicKind {
    type Prepared = ();
    type Item = Vec<f64>;
    type Output = Numbers;

    fn prepare(&self, ctx: &Ctx<'_, PanicParams>) -> Result<(), StageError> {
        if ctx.params.panic_in_prepare {
            panic!("prepare panicked on purpose (panic_in_prepare)");
        }
        Ok(())
    }
    fn n_items(&self, ctx: &Ctx<'_, PanicParams>, _: &()) -> usize {
        ctx.params.n as usize
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, PanicParams>,
        _: &(),
        index: usize,
        _: &mut StreamRng,
    ) -> Result<Vec<f64>, StageError> {
        if ctx.params.panic_at_item == Some(index as u32) {
            panic!("item {index} panicked on purpose (panic_at_item)");
        }
        Ok(vec![index as f64])
    }
    fn merge(
        &self,
        ctx: &Ctx<'_, PanicParams>,
        _: (),
        items: Vec<Vec<f64>>,
    ) -> Result<Numbers, StageError> {
        if ctx.params.panic_in_merge {
            panic!("merge panicked on purpose (panic_in_merge)");
        }
        Ok(Numbers { rows: items })
    }
}
