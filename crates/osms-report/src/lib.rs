//! The report of a run: Table II and Table III (mean ± sample sd over the run seeds) and the
//! ablation tables, each with the paper's values beside ours; the paper's figures; the
//! claims check; and the `report` stage that bundles them with Table I, the construction
//! table, the candidate table and the IOS profile. `docs/report.md` explains how to read it.

pub mod ablations;
pub mod claims;
pub mod figure;
pub mod figures;
pub mod report;
pub mod tables;

/// Registers the report's stage kinds.
pub fn register(registry: &mut osms_make::Registry) {
    registry
        .register(tables::Table2Stage)
        .register(tables::Table3Stage)
        .register(figures::ImpactProfilesStage)
        .register(figures::TaskConditionsStage)
        .register(figures::IosFigureStage)
        .register(figures::CandidateSelectionStage)
        .register(figures::LearningCurvesStage)
        .register(report::ReportStage)
        .register(ablations::AblationsStage);
}
