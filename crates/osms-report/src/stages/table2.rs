//! `table2`: Table II from the construction statistics and the evaluations over run seeds.

use osms_core::NoParams;
use osms_core::table::Table;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use osms_policy::artifacts::{ConstructionStats, DemoSet};
use osms_sim::artifacts::Evaluation;

use super::seed_evals;
use crate::tables::table2;

pub struct Table2Stage;
impl Kind for Table2Stage {
    const KIND: &'static str = "table2";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<DemoSet>("naive_demos"),
        Slot::one::<DemoSet>("normal_demos"),
        Slot::one::<DemoSet>("ours_demos"),
        Slot::one::<Evaluation>("teacher"),
        Slot::gather::<Evaluation>("naive"),
        Slot::gather::<Evaluation>("normal"),
        Slot::gather::<Evaluation>("ours"),
    ];
    const DOC: &'static str = "Table II: construction columns and the final students' closed-loop columns, mean ± sd over run seeds";
    type Params = NoParams;
}

impl Stage for Table2Stage {
    type Output = Table;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Table, StageError> {
        let stats: Vec<ConstructionStats> = ["naive_demos", "normal_demos", "ours_demos"]
            .iter()
            .map(|s| ctx.sharded::<DemoSet>(s).map(|d| d.stats()))
            .collect::<Result<_, _>>()?;
        let teacher: Evaluation = ctx.sharded("teacher")?;
        let naive = seed_evals(ctx, "naive")?;
        let normal = seed_evals(ctx, "normal")?;
        let ours = seed_evals(ctx, "ours")?;
        Ok(table2(
            [&stats[0], &stats[1], &stats[2]],
            &teacher,
            [&naive, &normal, &ours],
        ))
    }
}
