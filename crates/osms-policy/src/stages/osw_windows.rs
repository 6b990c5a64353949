//! `osw_windows`: the OSW windows ζ_org and conditioning ω̄ of a dataset.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};

use crate::artifacts::{Dataset, OswSample, OswSet};

/// A projection: streams a dataset shard by shard and keeps each rollout's OSW window and
/// ω̄, so later stages never decode full records.
pub struct OswWindowsStage;
impl Kind for OswWindowsStage {
    const KIND: &'static str = "osw_windows";
    /// 2: ω̄ carries the arm's servo targets.
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Dataset>("data")];
    const DOC: &'static str = "the OSW windows ζ_org and conditioning ω̄ of a dataset (projection)";
    type Params = NoParams;
}

impl Stage for OswWindowsStage {
    type Output = OswSet;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<OswSet, StageError> {
        let head: Dataset = ctx.head("data")?;
        let mut windows = Vec::new();
        for item in ctx.items::<Dataset>("data")? {
            let r = item?.rollout;
            windows.push(OswSample {
                item: r.item,
                attempt: r.attempt,
                variant: r.record.condition.variant.to_string(),
                success: r.record.outcome.success(),
                complete: r.osw.complete,
                zeta_org: r.osw.zeta_org,
                omega_bar: r.osw.omega_bar,
            });
        }
        Ok(OswSet {
            osw: head.osw,
            windows,
        })
    }
}
