//! The policy crate's artifact types, one file each, with what `osms show` and `osms export`
//! print of them.

mod dataset;
mod demo_set;
mod error_pairs;
mod osw_set;
mod student;
mod teacher;
mod teacher_table;

pub use dataset::{Dataset, DatasetItem, DatasetStats, DemoRollout};
pub use demo_set::{ConstructionStats, DemoEntry, DemoGroup, DemoSet, Execution, Origin};
pub use error_pairs::{ErrorPairs, PairRollout, PhaseDeviation};
pub use osw_set::{OswSample, OswSet};
pub use student::StudentArtifact;
pub use teacher::Teacher;
pub use teacher_table::{TeacherTable, TeacherTableRow};
