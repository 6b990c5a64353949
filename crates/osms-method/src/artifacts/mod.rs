//! The method's artifact types, one file each, with what `osms show` and `osms export` print
//! of them. Types that are also the library's working values (the manifold [`Cvae`](crate::cvae::Cvae))
//! are stored as they are; their store and show impls live here.

mod calibration;
mod candidate_table;
mod candidates;
mod construction_table;
mod error_model;
mod ios_profile;
mod manifold;
mod validation;

pub use calibration::{Calibration, CalibrationItem, Folds, RunOutcome, RunSpec, RunSummary};
pub use candidate_table::CandidateTable;
pub use candidates::{CandidateItem, CandidateSets, CandidateStats};
pub use construction_table::{ConstructionRow, ConstructionTable, PAPER_TABLE2};
pub use error_model::{ErrorModelArtifact, FoldSearch, FoldStats, ScaleSearch, VariantFit};
pub use ios_profile::{IosProfile, IosRow};
pub use validation::{ErrorStreams, Validation, ValidationStats};
