//! The candidate generators side by side (paper 6.4).

use osms_core::Artifact;
use osms_core::table::{self, Cell, Field, Layout, Sheet, Unit};
use osms_make::Summarize;
use serde::{Deserialize, Serialize};

use super::CandidateStats;

/// The generators side by side: what each proposed, matched or not.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CandidateTable {
    pub rows: Vec<CandidateStats>,
}

impl Artifact for CandidateTable {
    const TYPE_TAG: &'static str = "method.candidate_table";
    const SCHEMA_VERSION: u16 = 1;
}

impl CandidateTable {
    /// The table once: the Markdown reads refine / repair as one column, the CSV has every
    /// statistic of every generator.
    fn sheet(&self) -> Sheet {
        let both = |label: &str, key: &str, unit| Field::new(label, key, unit);
        let mut t = Sheet::new(vec![
            both("sets", "sets", Unit::Count),
            Field::markdown("refine / repair", Unit::Count),
            Field::csv("refine", Unit::Count),
            Field::csv("repair", Unit::Count),
            Field::csv("skipped_incomplete", Unit::Count),
            Field::csv("candidates", Unit::Count),
            both(
                "projection residual",
                "mean_projection_residual",
                Unit::Number(3),
            ),
            both("mean deviation", "mean_deviation", Unit::Number(3)),
            both("largest deviation", "mean_max_deviation", Unit::Number(3)),
            both("geodesic length", "mean_geodesic_length", Unit::Number(3)),
            both("shrunk directions", "directions_shrunk", Unit::Count),
            both("unmatched sets", "unmatched", Unit::Count),
            both("scale", "mean_scale", Unit::Number(3)),
        ]);
        for r in &self.rows {
            t.push(
                &r.generator,
                vec![
                    Cell::one(r.sets as f64),
                    Cell::text(format!("{} / {}", r.refine, r.repair)),
                    Cell::one(r.refine as f64),
                    Cell::one(r.repair as f64),
                    Cell::one(r.skipped_incomplete as f64),
                    Cell::one(r.candidates as f64),
                    Cell::opt(r.mean_projection_residual),
                    Cell::one(r.mean_deviation),
                    Cell::one(r.mean_max_deviation),
                    Cell::opt(r.mean_geodesic_length),
                    Cell::one(r.directions_shrunk as f64),
                    Cell::one(r.unmatched as f64),
                    Cell::one(r.mean_scale),
                ],
            );
        }
        t
    }

    fn markdown(&self) -> String {
        self.sheet().markdown_with(Layout::plain("generator"))
    }

    /// Every statistic of every generator, one line each, for programs.
    fn csv(&self) -> String {
        self.sheet().wide_csv("generator")
    }
}

impl Summarize for CandidateTable {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(&self.rows).unwrap_or_default()
    }

    fn text(&self) -> Option<String> {
        Some(format!(
            "candidate generators (paper 6.4), deviations ‖ζ − ζ_org‖_W_a; the ablations are scaled to the geodesic set's largest deviation per rollout\n\n{}",
            self.markdown()
        ))
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        table::files(
            "candidates",
            self.markdown(),
            self.csv(),
            serde_json::to_vec_pretty(&self.rows).unwrap_or_default(),
        )
    }
}
