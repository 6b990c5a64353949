//! The report's artifact types, one file each: a figure, the ablations, the baselines beyond
//! the paper and the report. Tables
//! II and III are `osms_core`'s one table model, stored as it is.

mod ablations;
mod baselines;
mod figure;
mod report;

pub use ablations::Ablations;
pub use baselines::Baselines;
pub use report::{Attached, Report};
