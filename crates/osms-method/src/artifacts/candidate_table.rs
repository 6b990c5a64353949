//! The candidate generators side by side (paper 6.4).

use osms_core::Artifact;
use osms_core::table::{self, Cell, Column, Layout, Table, Unit};
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
    fn markdown(&self) -> String {
        let mut t = Table::new(
            "candidates",
            "Candidate generators",
            vec![
                Column::new("sets", Unit::Count),
                Column::new("refine / repair", Unit::Count),
                Column::new("projection residual", Unit::Number(3)),
                Column::new("mean deviation", Unit::Number(3)),
                Column::new("largest deviation", Unit::Number(3)),
                Column::new("geodesic length", Unit::Number(3)),
                Column::new("shrunk directions", Unit::Count),
                Column::new("unmatched sets", Unit::Count),
                Column::new("scale", Unit::Number(3)),
            ],
        );
        for r in &self.rows {
            t.push(
                &r.generator,
                vec![
                    Cell::one(r.sets as f64),
                    Cell::text(format!("{} / {}", r.refine, r.repair)),
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
        t.markdown_with(Layout::plain("generator"))
    }

    /// Every statistic of every generator, one line each, for programs.
    fn csv(&self) -> String {
        let count = |n: &str| Column::new(n, Unit::Count);
        let number = |n: &str| Column::new(n, Unit::Number(3));
        let mut t = Table::new(
            "candidates",
            "Candidate generators",
            vec![
                count("sets"),
                count("refine"),
                count("repair"),
                count("skipped_incomplete"),
                count("candidates"),
                number("mean_projection_residual"),
                number("mean_deviation"),
                number("mean_max_deviation"),
                number("mean_geodesic_length"),
                count("directions_shrunk"),
                count("unmatched"),
                number("mean_scale"),
            ],
        );
        for r in &self.rows {
            t.push(
                &r.generator,
                vec![
                    Cell::one(r.sets as f64),
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
        t.wide_csv("generator")
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
