//! Table II's left half: how Naive, Normal and ours constructed their demonstrations.

use osms_core::Artifact;
use osms_core::table::{self, Cell, Field, Layout, Sheet, Unit, Value};
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
    /// The table once: the Markdown shows the rates with the paper's values in parentheses,
    /// the CSV every count behind them and the paper's values as numbers.
    fn sheet(&self) -> Sheet {
        let pct = |v: f64| format!("{:.1}%", 100.0 * v);
        let count = |k: &str| Field::csv(k, Unit::Count);
        let mut t = Sheet::new(vec![
            Field::new("demos", "demonstrations", Unit::Count),
            count("conditions"),
            count("kept"),
            count("refined"),
            count("repaired"),
            count("dropped"),
            Field::new("coverage", "coverage", Unit::Percent),
            Field::new("repair rate", "repair_rate", Unit::Percent),
            Field::new("refinement rate", "refinement_rate", Unit::Percent),
            Field::new(
                "unperturbed f_max (N)",
                "unperturbed_max_force_n",
                Unit::Number(1),
            ),
            count("extension_conditions"),
            count("extension_demonstrations"),
            Field::csv("paper_coverage", Unit::Percent),
            Field::csv("paper_repair_rate", Unit::Percent),
            Field::csv("paper_refinement_rate", Unit::Percent),
            Field::csv("paper_unperturbed_max_force_n", Unit::Number(1)),
        ]);
        for r in &self.rows {
            let s = &r.stats;
            t.push(
                &r.construction,
                vec![
                    Cell::one(s.demonstrations as f64),
                    Cell::one(s.conditions as f64),
                    Cell::one(s.kept as f64),
                    Cell::one(s.refined as f64),
                    Cell::one(s.repaired as f64),
                    Cell::one(s.dropped as f64),
                    Cell::new(Value::One(s.coverage), Some(&pct(r.paper_coverage))),
                    Cell::new(Value::One(s.repair_rate), Some(&pct(r.paper_repair_rate))),
                    Cell::new(
                        Value::One(s.refinement_rate),
                        Some(&pct(r.paper_refinement_rate)),
                    ),
                    Cell::new(
                        Value::of(s.unperturbed_max_force_n),
                        Some(&format!("{:.1}", r.paper_unperturbed_max_force_n)),
                    ),
                    Cell::one(s.extension_conditions as f64),
                    Cell::one(s.extension_demonstrations as f64),
                    Cell::one(r.paper_coverage),
                    Cell::one(r.paper_repair_rate),
                    Cell::one(r.paper_refinement_rate),
                    Cell::one(r.paper_unperturbed_max_force_n),
                ],
            );
        }
        t.with_note(
            "In parentheses: the paper's Table II. Coverage, repair and refinement rates are over \
             the D_R conditions; demos count every demonstration, extension included.",
        )
    }

    pub fn markdown(&self) -> String {
        self.sheet().markdown_with(Layout::plain("construction"))
    }

    pub fn csv(&self) -> String {
        self.sheet().wide_csv("construction")
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
        table::files(
            "construction_table",
            self.markdown(),
            self.csv(),
            json.into_bytes(),
        )
    }
}
