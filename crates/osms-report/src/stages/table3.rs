//! `table3`: Table III from the error models' fits, their demonstration sets and students.

use osms_core::NoParams;
use osms_core::table::Table;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use osms_method::artifacts::ErrorModelArtifact;
use osms_policy::artifacts::DemoSet;
use osms_sim::artifacts::Evaluation;

use super::seed_evals;
use crate::tables::table3;

pub struct Table3Stage;
impl Kind for Table3Stage {
    const KIND: &'static str = "table3";
    /// 2: the phase-wise correlated row is the model validation applies, the paper's
    /// least-squares fit a row of its own where they differ (issue 66).
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<ErrorModelArtifact>("error_model"),
        Slot::one::<DemoSet>("unperturbed_demos"),
        Slot::one::<DemoSet>("global_iid_demos"),
        Slot::one::<DemoSet>("phase_independent_demos"),
        Slot::one::<DemoSet>("phase_correlated_demos"),
        Slot::gather::<Evaluation>("unperturbed"),
        Slot::gather::<Evaluation>("global_iid"),
        Slot::gather::<Evaluation>("phase_independent"),
        Slot::gather::<Evaluation>("phase_correlated"),
    ];
    const DOC: &'static str = "Table III: the four validation models' fit metrics, repair rates and students' success, mean ± sd over run seeds";
    type Params = NoParams;
}

impl Stage for Table3Stage {
    type Output = Table;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Table, StageError> {
        let model: ErrorModelArtifact = ctx.input("error_model")?;
        let names = [
            "unperturbed",
            "global_iid",
            "phase_independent",
            "phase_correlated",
        ];
        let mut stats = Vec::new();
        let mut evals = Vec::new();
        for n in names {
            stats.push(ctx.sharded::<DemoSet>(&format!("{n}_demos"))?.stats());
            evals.push(seed_evals(ctx, n)?);
        }
        Ok(table3(
            &model,
            [&stats[0], &stats[1], &stats[2], &stats[3]],
            [&evals[0], &evals[1], &evals[2], &evals[3]],
        ))
    }
}
