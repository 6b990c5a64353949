//! The report's stage kinds, one file each: Tables II and III, the figures, the ablations, the
//! baselines beyond the paper and the report.

mod ablations;
mod baselines;
mod candidate_selection;
mod impact_profiles;
mod ios_figure;
mod learning_curves;
mod report;
mod table2;
mod table3;
mod task_conditions;

pub use ablations::AblationsStage;
pub use baselines::BaselinesStage;
pub use candidate_selection::CandidateSelectionStage;
pub use impact_profiles::ImpactProfilesStage;
pub use ios_figure::IosFigureStage;
pub use learning_curves::LearningCurvesStage;
pub use report::ReportStage;
pub use table2::Table2Stage;
pub use table3::Table3Stage;
pub use task_conditions::TaskConditionsStage;

use osms_core::NoParams;
use osms_make::{Ctx, StageError};
use osms_sim::artifacts::Evaluation;

/// Per-seed evaluations of a gather slot, in run-seed order (the tables and figures read the
/// order, not the seeds).
pub fn seed_evals(ctx: &Ctx<'_, NoParams>, slot: &str) -> Result<Vec<Evaluation>, StageError> {
    let evals = ctx.gathered_sharded::<Evaluation>(slot)?;
    if evals.is_empty() {
        return Err(format!(
            "input `{slot}` gathered no evaluation\nhint: wire `{slot} = \"<eval stage>@*\"`"
        )
        .into());
    }
    Ok(evals.into_iter().map(|(_, e)| e).collect())
}

/// Registers the report's stage kinds.
pub fn register(registry: &mut osms_make::Registry) {
    registry
        .register(Table2Stage)
        .register(Table3Stage)
        .register(ImpactProfilesStage)
        .register(TaskConditionsStage)
        .register(IosFigureStage)
        .register(CandidateSelectionStage)
        .register(LearningCurvesStage)
        .register(ReportStage)
        .register(AblationsStage)
        .register(BaselinesStage);
}
