//! `report`: every table and figure of a run in one artifact.

use osms_core::NoParams;
use osms_core::table::Table;
use osms_make::{Ctx, Slot, Stage, StageError};
use osms_method::artifacts::{CandidateTable, ConstructionTable};
use osms_policy::artifacts::TeacherTable;
use osms_sim::artifacts::Evaluation;

use super::seed_evals;
use crate::artifacts::{Attached, Report};
use crate::claims::{self, ClaimData};
use crate::plot::Figure;

pub struct ReportStage;
impl Stage for ReportStage {
    const KIND: &'static str = "report";
    /// 2: the claims check decides by confidence intervals on the evaluations. 3: the
    /// claims encoded at report schema 2.
    const CODE_VERSION: u32 = 3;
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
        Slot::one::<Evaluation>("teacher"),
        Slot::gather::<Evaluation>("naive"),
        Slot::gather::<Evaluation>("normal"),
        Slot::gather::<Evaluation>("ours"),
        Slot::gather::<Evaluation>("global_iid"),
        Slot::gather::<Evaluation>("phase_independent"),
    ];
    const DOC: &'static str =
        "the report: Tables I-III, construction and candidate tables, figures, claims check";
    type Params = NoParams;
    type Output = Report;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Report, StageError> {
        let table2: Table = ctx.input("table2")?;
        let table3: Table = ctx.input("table3")?;
        let construction: ConstructionTable = ctx.input("construction")?;
        let stats = |name: &str| {
            construction
                .rows
                .iter()
                .find(|r| r.construction == name)
                .map(|r| &r.stats)
                .ok_or_else(|| {
                    StageError::from(format!(
                        "input `construction` has no `{name}` row\nhint: wire it to a \
                         `construction_table` stage"
                    ))
                })
        };
        let teacher: Evaluation = ctx.sharded("teacher")?;
        let evals = ["naive", "normal", "ours", "global_iid", "phase_independent"]
            .iter()
            .map(|s| seed_evals(ctx, s))
            .collect::<Result<Vec<_>, _>>()?;
        let claims = claims::check(&ClaimData {
            teacher: &teacher,
            naive: &evals[0],
            normal: &evals[1],
            ours: &evals[2],
            global_iid: &evals[3],
            phase_independent: &evals[4],
            stats: [stats("naive")?, stats("normal")?, stats("ours")?],
            table3: &table3,
        });
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
                &construction,
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
