//! `learning_curves`: figure (f), the teachers' and the final students' learning curves.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use osms_policy::artifacts::{StudentArtifact, Teacher};

use crate::figures::learning_curves;
use crate::plot::Figure;

pub struct LearningCurvesStage;
impl Kind for LearningCurvesStage {
    const KIND: &'static str = "learning_curves";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Teacher>("teacher"),
        Slot::one::<Teacher>("catch_only"),
        Slot::gather::<StudentArtifact>("naive"),
        Slot::gather::<StudentArtifact>("normal"),
        Slot::gather::<StudentArtifact>("ours"),
    ];
    const DOC: &'static str = "figure (f): the teachers' and the final students' learning curves";
    type Params = NoParams;
}

impl Stage for LearningCurvesStage {
    type Output = Figure;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Figure, StageError> {
        let teacher: Teacher = ctx.input("teacher")?;
        let catch_only: Teacher = ctx.input("catch_only")?;
        let naive = students(ctx, "naive")?;
        let normal = students(ctx, "normal")?;
        let ours = students(ctx, "ours")?;
        Ok(learning_curves(
            [("RL teacher", &teacher), ("catching-only RL", &catch_only)],
            [
                ("Naive-IL", &naive),
                ("Normal-IL", &normal),
                ("Ours-IL", &ours),
            ],
        ))
    }
}

/// Per-seed students of a gather slot, in run-seed order.
fn students(ctx: &Ctx<'_, NoParams>, slot: &str) -> Result<Vec<StudentArtifact>, StageError> {
    Ok(ctx
        .gathered::<StudentArtifact>(slot)?
        .into_iter()
        .map(|(_, s)| s)
        .collect())
}
