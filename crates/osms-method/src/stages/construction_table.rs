//! `construction_table`: Table II's construction columns from the three demonstration sets.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use osms_policy::artifacts::DemoSet;

use crate::artifacts::{ConstructionRow, ConstructionTable, PAPER_TABLE2};

/// Table II's construction columns from the three demonstration sets.
pub struct ConstructionTableStage;
impl Kind for ConstructionTableStage {
    const KIND: &'static str = "construction_table";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<DemoSet>("naive"),
        Slot::one::<DemoSet>("normal"),
        Slot::one::<DemoSet>("ours"),
    ];
    const DOC: &'static str = "Table II's demonstration-construction columns for Naive, Normal and ours, with the paper's values";
    type Params = NoParams;
}

impl Stage for ConstructionTableStage {
    type Output = ConstructionTable;

    fn run(&self, ctx: &Ctx<'_, Self::Params>) -> Result<ConstructionTable, StageError> {
        let mut rows = Vec::new();
        for (slot, paper) in ["naive", "normal", "ours"].iter().zip(PAPER_TABLE2) {
            let set: DemoSet = ctx.sharded(slot)?;
            rows.push(ConstructionRow {
                construction: (*slot).to_string(),
                stats: set.stats(),
                paper_coverage: paper.1,
                paper_repair_rate: paper.2,
                paper_refinement_rate: paper.3,
                paper_unperturbed_max_force_n: paper.4,
            });
        }
        Ok(ConstructionTable { rows })
    }
}
