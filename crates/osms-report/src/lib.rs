//! The report of a run: Table II and Table III (mean ± sample sd over the run seeds) and the
//! ablation tables, each with the paper's values beside ours; the paper's figures; the
//! claims check; and the `report` stage that bundles them with Table I, the construction
//! table, the candidate table and the IOS profile. `docs/report.md` explains how to read it.

pub mod ablations;
pub mod artifacts;
pub mod claims;
mod error;
pub mod figures;
pub mod plot;
pub mod stages;
pub mod tables;

pub use error::{Error, Result};
pub use stages::register;
