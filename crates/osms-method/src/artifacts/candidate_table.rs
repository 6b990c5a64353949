//! The candidate generators side by side (paper 6.4).

use std::fmt::Write;

use osms_core::Artifact;
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

const TABLE_COLUMNS: &str = "generator,sets,refine,repair,skipped_incomplete,candidates,mean_projection_residual,mean_deviation,mean_max_deviation,mean_geodesic_length,directions_shrunk,unmatched,mean_scale";

impl CandidateTable {
    fn markdown(&self) -> String {
        let opt = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.3}"));
        let mut s = String::from(
            "| generator | sets | refine / repair | projection residual | mean deviation | largest deviation | geodesic length | shrunk directions | unmatched sets | scale |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        );
        for r in &self.rows {
            let _ = writeln!(
                s,
                "| {} | {} | {} / {} | {} | {:.3} | {:.3} | {} | {} | {} | {:.3} |",
                r.generator,
                r.sets,
                r.refine,
                r.repair,
                opt(r.mean_projection_residual),
                r.mean_deviation,
                r.mean_max_deviation,
                opt(r.mean_geodesic_length),
                r.directions_shrunk,
                r.unmatched,
                r.mean_scale
            );
        }
        s
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
        let opt = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
        let mut csv = format!("{TABLE_COLUMNS}\n");
        for r in &self.rows {
            let _ = writeln!(
                csv,
                "{},{},{},{},{},{},{},{},{},{},{},{},{}",
                r.generator,
                r.sets,
                r.refine,
                r.repair,
                r.skipped_incomplete,
                r.candidates,
                opt(r.mean_projection_residual),
                r.mean_deviation,
                r.mean_max_deviation,
                opt(r.mean_geodesic_length),
                r.directions_shrunk,
                r.unmatched,
                r.mean_scale
            );
        }
        vec![
            ("candidates.md".into(), self.markdown().into_bytes()),
            ("candidates.csv".into(), csv.into_bytes()),
            (
                "candidates.json".into(),
                serde_json::to_vec_pretty(&self.rows).unwrap_or_default(),
            ),
        ]
    }
}
