//! The report's artifact types, one file each: a figure, the ablations and the report. Tables
//! II and III are `osms_core`'s one table model, stored as it is.

mod ablations;
mod figure;
mod report;

pub use ablations::Ablations;
pub use report::{Attached, Report};
