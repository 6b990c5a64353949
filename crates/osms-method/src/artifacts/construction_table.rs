//! Table II's left half: how Naive, Normal and ours constructed their demonstrations.

use osms_core::Artifact;
use osms_make::Summarize;
use osms_policy::artifacts::ConstructionStats;
use serde::{Deserialize, Serialize};

/// The paper's construction columns of Table II: coverage, repair rate, refinement rate,
/// unperturbed f_max (N).
pub const PAPER_TABLE2: [(&str, f64, f64, f64, f64); 3] = [
    ("naive", 0.852, 0.0, 0.0, 40.6),
    ("normal", 0.949, 0.655, 0.842, 35.9),
    ("ours", 0.918, 0.443, 0.598, 36.5),
];

/// One row of the construction table with the paper's values beside ours.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConstructionRow {
    pub construction: String,
    pub stats: ConstructionStats,
    pub paper_coverage: f64,
    pub paper_repair_rate: f64,
    pub paper_refinement_rate: f64,
    pub paper_unperturbed_max_force_n: f64,
}

/// Table II's left half (demonstration construction) for Naive, Normal and ours.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConstructionTable {
    pub rows: Vec<ConstructionRow>,
}

impl Artifact for ConstructionTable {
    const TYPE_TAG: &'static str = "method.construction_table";
    const SCHEMA_VERSION: u16 = 1;
}

impl ConstructionTable {
    pub fn markdown(&self) -> String {
        use std::fmt::Write;
        let mut out = String::from(
            "| construction | demos | coverage | repair rate | refinement rate | unperturbed f_max (N) |\n|---|---:|---:|---:|---:|---:|\n",
        );
        let pct = |v: f64| format!("{:.1}%", 100.0 * v);
        for r in &self.rows {
            let s = &r.stats;
            let _ = writeln!(
                out,
                "| {} | {} | {} ({}) | {} ({}) | {} ({}) | {} ({:.1}) |",
                r.construction,
                s.demonstrations,
                pct(s.coverage),
                pct(r.paper_coverage),
                pct(s.repair_rate),
                pct(r.paper_repair_rate),
                pct(s.refinement_rate),
                pct(r.paper_refinement_rate),
                s.unperturbed_max_force_n
                    .map_or_else(|| "-".into(), |f| format!("{f:.1}")),
                r.paper_unperturbed_max_force_n
            );
        }
        out.push_str("\nIn parentheses: the paper's Table II. Coverage, repair and refinement rates are over the D_R conditions; demos count every demonstration, extension included.\n");
        out
    }

    pub fn csv(&self) -> String {
        use std::fmt::Write;
        let mut out = String::from(
            "construction,demonstrations,conditions,kept,refined,repaired,dropped,coverage,repair_rate,refinement_rate,unperturbed_max_force_n,extension_conditions,extension_demonstrations,paper_coverage,paper_repair_rate,paper_refinement_rate,paper_unperturbed_max_force_n\n",
        );
        for r in &self.rows {
            let s = &r.stats;
            let _ = writeln!(
                out,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                r.construction,
                s.demonstrations,
                s.conditions,
                s.kept,
                s.refined,
                s.repaired,
                s.dropped,
                s.coverage,
                s.repair_rate,
                s.refinement_rate,
                s.unperturbed_max_force_n
                    .map(|f| f.to_string())
                    .unwrap_or_default(),
                s.extension_conditions,
                s.extension_demonstrations,
                r.paper_coverage,
                r.paper_repair_rate,
                r.paper_refinement_rate,
                r.paper_unperturbed_max_force_n
            );
        }
        out
    }
}

impl Summarize for ConstructionTable {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(&self.rows).unwrap_or_default()
    }
    fn text(&self) -> Option<String> {
        Some(self.markdown())
    }
    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let json = serde_json::to_string_pretty(&self.rows).unwrap_or_default() + "\n";
        vec![
            ("construction_table.md".into(), self.markdown().into_bytes()),
            ("construction_table.csv".into(), self.csv().into_bytes()),
            ("construction_table.json".into(), json.into_bytes()),
        ]
    }
}
