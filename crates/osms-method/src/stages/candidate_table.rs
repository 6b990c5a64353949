//! `candidate_table`: the four generators' candidate sets side by side.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};

use crate::artifacts::{CandidateSets, CandidateTable};
use crate::candidates::Generator;

/// The four generators' candidate sets side by side (`osms make candidates` builds them all).
pub struct CandidateTableStage;
impl Kind for CandidateTableStage {
    const KIND: &'static str = "candidate_table";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<CandidateSets>("geodesic"),
        Slot::one::<CandidateSets>("euclidean"),
        Slot::one::<CandidateSets>("unconditional"),
        Slot::one::<CandidateSets>("direct"),
    ];
    const DOC: &'static str =
        "the candidate generators side by side: sets, deviations, shrunk directions, matching";
    type Params = NoParams;
}

impl Stage for CandidateTableStage {
    type Output = CandidateTable;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<CandidateTable, StageError> {
        let mut rows = Vec::new();
        for (slot, generator) in [
            ("geodesic", Generator::Geodesic),
            ("euclidean", Generator::Euclidean),
            ("unconditional", Generator::Unconditional),
            ("direct", Generator::Direct),
        ] {
            let sets: CandidateSets = ctx.sharded(slot)?;
            if sets.params.generator != generator {
                return Err(format!(
                    "input `{slot}` holds `{}` candidate sets\nhint: wire the stage whose params say generator = \"{slot}\"",
                    sets.params.generator.name()
                )
                .into());
            }
            rows.push(sets.stats());
        }
        Ok(CandidateTable { rows })
    }
}
