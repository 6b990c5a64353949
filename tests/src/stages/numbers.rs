//! `numbers` (test kind): normal random rows, one item per row (itemised, seeded, with roles).

use std::time::Duration;

use osms_core::check::{Check, Checked};
use osms_core::rng::{self, StreamRng};
use osms_make::{Ctx, ItemStage, Kind, Scale, Slot, StageError};
use serde::{Deserialize, Serialize};

use crate::artifacts::Numbers;

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NumbersParams {
    /// Number of rows (items).
    pub n: u32,
    /// Values per row.
    #[serde(default = "default_len")]
    pub len: u32,
    #[serde(default = "default_scale")]
    pub scale: f64,
    /// Sleep per item, so kill tests can interrupt a make mid-stage.
    #[serde(default)]
    pub sleep_ms: u64,
    /// Item index at which to fail (tests failure handling).
    #[serde(default)]
    pub fail_at: Option<u32>,
    /// A role for the typed-slot tests.
    #[serde(default)]
    pub role: Option<TestRole>,
}

/// Any value that parses: test kinds exercise the engine, not params' ranges.
impl Check for NumbersParams {
    fn check(&self) -> Checked {
        Ok(())
    }
}

/// Roles test numbers can play.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TestRole {
    A,
    B,
}
fn default_len() -> u32 {
    4
}
fn default_scale() -> f64 {
    1.0
}

/// Normal random rows, one item per row.
pub struct NumbersKind;
impl Kind for NumbersKind {
    const KIND: &'static str = "numbers";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[];
    const DOC: &'static str = "rows of scaled standard-normal numbers (test kind)";
    type Params = NumbersParams;

    fn scale(params: &NumbersParams, _: &[(&str, f64)]) -> Scale {
        Scale::items(f64::from(params.n))
    }

    fn output_role(params: &NumbersParams) -> Option<&'static str> {
        params.role.map(|r| match r {
            TestRole::A => "a",
            TestRole::B => "b",
        })
    }
}

impl ItemStage for NumbersKind {
    type Prepared = ();
    type Item = Vec<f64>;
    type Output = Numbers;

    fn prepare(&self, _: &Ctx<'_, NumbersParams>) -> Result<(), StageError> {
        Ok(())
    }
    fn n_items(&self, ctx: &Ctx<'_, NumbersParams>, _: &()) -> usize {
        ctx.params.n as usize
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, NumbersParams>,
        _: &(),
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<Vec<f64>, StageError> {
        let p = ctx.params;
        if p.fail_at == Some(index as u32) {
            return Err(format!("item {index} failed on purpose (fail_at)").into());
        }
        if p.sleep_ms > 0 {
            std::thread::sleep(Duration::from_millis(p.sleep_ms));
        }
        Ok((0..p.len).map(|_| p.scale * rng::normal(rng)).collect())
    }
    fn merge(
        &self,
        _: &Ctx<'_, NumbersParams>,
        _: (),
        items: Vec<Vec<f64>>,
    ) -> Result<Numbers, StageError> {
        Ok(Numbers { rows: items })
    }
}
