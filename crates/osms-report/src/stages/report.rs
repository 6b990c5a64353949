//! `report`: every table and figure of a run in one artifact.

use osms_core::NoParams;
use osms_core::table::Table;
use osms_make::{Ctx, Slot, Stage, StageError};
use osms_method::artifacts::{CandidateTable, ConstructionTable};
use osms_policy::artifacts::TeacherTable;

use crate::artifacts::{Attached, Report};
use crate::claims;
use crate::plot::Figure;

pub struct ReportStage;
impl Stage for ReportStage {
    const KIND: &'static str = "report";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<TeacherTable>("table1"),
        Slot::one::<Table>("table2"),
        Slot::one::<Table>("table3"),
        Slot::one::<ConstructionTable>("construction"),
        Slot::one::<CandidateTable>("candidates"),
        Slot::one::<Figure>("impact_profiles"),
        Slot::one::<Figure>("task_conditions"),
        Slot::one::<Figure>("candidate_selection"),
        Slot::one::<Figure>("ios"),
        Slot::one::<Figure>("learning_curves"),
    ];
    const DOC: &'static str =
        "the report: Tables I-III, construction and candidate tables, figures, claims check";
    type Params = NoParams;
    type Output = Report;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Report, StageError> {
        let table2: Table = ctx.input("table2")?;
        let table3: Table = ctx.input("table3")?;
        let claims = claims::check(&table2, &table3);
        let figures = [
            "impact_profiles",
            "task_conditions",
            "candidate_selection",
            "ios",
            "learning_curves",
        ]
        .iter()
        .map(|s| ctx.input::<Figure>(s))
        .collect::<Result<Vec<_>, _>>()?;
        Ok(Report {
            table1: Attached::of(
                "Table I: catching with and without impact mitigation",
                &ctx.input::<TeacherTable>("table1")?,
            ),
            construction: Attached::of(
                "Demonstration construction (Table II, left half, with counts)",
                &ctx.input::<ConstructionTable>("construction")?,
            ),
            candidates: Attached::of(
                "Candidate generators",
                &ctx.input::<CandidateTable>("candidates")?,
            ),
            tables: vec![table2, table3],
            figures,
            claims,
        })
    }
}
