//! The report: Tables II and III and the ablation tables over run seeds, the paper's figures (SVG,
//! PNG, CSV), the claims check, and the report stage that bundles them with Table I and the
//! construction and candidate tables.
//!
//! Rooms: [`tables`], [`figures`], [`ablations`] and [`claims`] build the tables, figures and
//! claims from artifacts of the other crates without the engine; [`plot`] is the figure model
//! and its SVG/PNG rendering; the one table model is `osms_core::table`; [`artifacts`] holds
//! the stored figure, ablations and report; [`stages`] one adapter per stage kind.
//! `docs/report.md` explains how to read the report.

pub mod ablations;
pub mod artifacts;
pub mod baselines;
pub mod claims;
mod error;
pub mod figures;
mod glyphs;
pub mod plot;
pub mod stages;
pub mod tables;

pub use error::{Error, Result};
pub use stages::register;
