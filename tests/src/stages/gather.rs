//! `gather` (test kind): lists the totals of a gather slot (`stage@*`, `stage#*`).

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};

use crate::artifacts::{Gathered, Total};

/// Lists the totals of a gather slot (test kind for `stage@*` and `stage#*`).
pub struct GatherKind;
impl Kind for GatherKind {
    const KIND: &'static str = "gather_totals";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::gather::<Total>("totals")];
    const DOC: &'static str = "every total of a gather slot, in order (test kind)";
    type Params = NoParams;
}

impl Stage for GatherKind {
    type Output = Gathered;
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Gathered, StageError> {
        Ok(Gathered {
            members: ctx
                .gathered::<Total>("totals")?
                .into_iter()
                .map(|(m, t)| (m.suffix(), t.sum))
                .collect(),
        })
    }
}
