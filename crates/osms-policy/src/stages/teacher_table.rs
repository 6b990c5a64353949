//! `teacher_table`: Table I's analog from the three held-out evaluations.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use osms_sim::artifacts::Evaluation;

use crate::artifacts::{TeacherTable, TeacherTableRow};

/// Table I's analog: the scripted prior, the catching-only teacher and the teacher on the
/// same held-out conditions, and (wired as `privileged`) a teacher whose actor reads the
/// privileged frame: what a realisable teacher costs (issue 66).
pub struct TeacherTableStage;
impl Kind for TeacherTableStage {
    const KIND: &'static str = "teacher_table";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Evaluation>("scripted"),
        Slot::one::<Evaluation>("catch_only"),
        Slot::one::<Evaluation>("teacher"),
        Slot::one::<Evaluation>("privileged").optional(),
    ];
    const DOC: &'static str =
        "Table I analog: scripted prior, catching-only teacher and teacher on held-out conditions";
    type Params = NoParams;
}

impl Stage for TeacherTableStage {
    type Output = TeacherTable;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<TeacherTable, StageError> {
        let scripted: Evaluation = ctx.sharded("scripted")?;
        let catch_only: Evaluation = ctx.sharded("catch_only")?;
        let teacher: Evaluation = ctx.sharded("teacher")?;
        let mut rows = vec![
            TeacherTableRow::of("scripted prior", &scripted),
            TeacherTableRow::of("catching-only teacher", &catch_only),
            TeacherTableRow::of("teacher", &teacher),
        ];
        if ctx.has_input("privileged") {
            rows.push(TeacherTableRow::of(
                "privileged teacher (actor on the privileged frame)",
                &ctx.sharded::<Evaluation>("privileged")?,
            ));
        }
        Ok(TeacherTable { rows })
    }
}
