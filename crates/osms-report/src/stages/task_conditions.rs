//! `task_conditions`: figures (b, c), success per object and by lateral offset.

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};
use osms_sim::artifacts::Evaluation;

use super::seed_evals;
use crate::figures::task_conditions;
use crate::plot::Figure;

pub struct TaskConditionsStage;
impl Kind for TaskConditionsStage {
    const KIND: &'static str = "task_conditions";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Evaluation>("teacher"),
        Slot::gather::<Evaluation>("naive"),
        Slot::gather::<Evaluation>("normal"),
        Slot::gather::<Evaluation>("ours"),
    ];
    const DOC: &'static str = "figures (b, c): success per object family x size, Ours-IL's gain, success vs lateral offset";
    type Params = NoParams;
}

impl Stage for TaskConditionsStage {
    type Output = Figure;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Figure, StageError> {
        let teacher: Evaluation = ctx.sharded("teacher")?;
        let naive = seed_evals(ctx, "naive")?;
        let normal = seed_evals(ctx, "normal")?;
        let ours = seed_evals(ctx, "ours")?;
        Ok(task_conditions(&teacher, [&naive, &normal, &ours]))
    }
}
