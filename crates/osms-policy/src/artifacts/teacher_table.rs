//! Table I's analog: the scripted prior, the catching-only teacher and the teacher.

use osms_core::Artifact;
use osms_core::table::{self, Cell, Field, Layout, Sheet, Unit};
use osms_make::Summarize;
use osms_sim::artifacts::Evaluation;
use serde::{Deserialize, Serialize};

/// One row of the Table I analog.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TeacherTableRow {
    pub policy: String,
    pub rollouts: usize,
    pub completion_rate: f64,
    pub success_rate: f64,
    /// Means over catch completions, as in the paper.
    pub contact_speed_mps: Option<f64>,
    pub max_force_n: Option<f64>,
    pub follow_through_m: Option<f64>,
}

/// Table I analog: the scripted prior, the catching-only teacher and the teacher on the same
/// held-out conditions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TeacherTable {
    pub rows: Vec<TeacherTableRow>,
}

impl Artifact for TeacherTable {
    const TYPE_TAG: &'static str = "policy.teacher_table";
    const SCHEMA_VERSION: u16 = 1;
}

impl TeacherTable {
    /// The table once, headed as the paper's Table I and keyed by the row's fields.
    fn sheet(&self) -> Sheet {
        let mut t = Sheet::new(vec![
            Field::new("n", "rollouts", Unit::Count),
            Field::new("catch completion", "completion_rate", Unit::Percent),
            Field::new("task success", "success_rate", Unit::Percent),
            Field::new("v_rel (m/s)", "contact_speed_mps", Unit::Number(2)),
            Field::new("f_max (N)", "max_force_n", Unit::Number(1)),
            Field::new("l_max (m)", "follow_through_m", Unit::Number(3)),
        ]);
        for r in &self.rows {
            t.push(
                &r.policy,
                vec![
                    Cell::one(r.rollouts as f64),
                    Cell::one(r.completion_rate),
                    Cell::one(r.success_rate),
                    Cell::opt(r.contact_speed_mps),
                    Cell::opt(r.max_force_n),
                    Cell::opt(r.follow_through_m),
                ],
            );
        }
        t
    }

    pub fn markdown(&self) -> String {
        self.sheet()
            .with_note(
                "Impact metrics are means over catch completions. Paper (Table I): catching-only \
                 92.5% / 0.4% / 160 N; teacher 90.7% / 85.2% / 40.8 N.",
            )
            .markdown_with(Layout::plain("policy"))
    }

    pub fn csv(&self) -> String {
        self.sheet().wide_csv("policy")
    }
}

impl Summarize for TeacherTable {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(&self.rows).unwrap_or_default()
    }
    fn text(&self) -> Option<String> {
        Some(self.markdown())
    }
    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let json = serde_json::to_string_pretty(&self.rows).unwrap_or_default() + "\n";
        table::files("table1", self.markdown(), self.csv(), json.into_bytes())
    }
}

impl TeacherTableRow {
    /// The row of `policy` from its evaluation's summary.
    pub fn of(policy: &str, eval: &Evaluation) -> TeacherTableRow {
        let all = eval.overall();
        TeacherTableRow {
            policy: policy.to_string(),
            rollouts: all.rollouts,
            completion_rate: all.completion_rate,
            success_rate: all.success_rate,
            contact_speed_mps: all.contact_speed_mps,
            max_force_n: all.max_force_n,
            follow_through_m: all.follow_through_m,
        }
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;

    #[test]
    fn table1_files_agree_with_the_rows() {
        let table = TeacherTable {
            rows: vec![
                TeacherTableRow {
                    policy: "teacher".into(),
                    rollouts: 40,
                    completion_rate: 0.7,
                    success_rate: 0.475,
                    contact_speed_mps: Some(3.9),
                    max_force_n: Some(33.72),
                    follow_through_m: Some(0.215),
                },
                TeacherTableRow {
                    policy: "nothing caught".into(),
                    rollouts: 3,
                    completion_rate: 0.0,
                    success_rate: 0.0,
                    contact_speed_mps: None,
                    max_force_n: None,
                    follow_through_m: None,
                },
            ],
        };
        let files: BTreeMap<String, Vec<u8>> = table.files().into_iter().collect();
        let names: Vec<&str> = files.keys().map(String::as_str).collect();
        assert_eq!(names, ["table1.csv", "table1.json", "table1.md"]);
        let md = String::from_utf8_lossy(&files["table1.md"]).to_string();
        assert!(
            md.contains("| teacher | 40 | 70.0% | 47.5% | 3.90 | 33.7 | 0.215 |"),
            "{md}"
        );
        assert!(
            md.contains("| nothing caught | 3 | 0.0% | 0.0% | - | - | - |"),
            "{md}"
        );
        let csv = String::from_utf8_lossy(&files["table1.csv"]).to_string();
        assert_eq!(
            csv.lines().nth(1),
            Some("teacher,40,0.7,0.475,3.9,33.72,0.215")
        );
        assert_eq!(csv.lines().nth(2), Some("nothing caught,3,0,0,,,"));
        let back: Vec<TeacherTableRow> =
            serde_json::from_slice(&files["table1.json"]).expect("json");
        assert_eq!(back, table.rows);
    }
}
