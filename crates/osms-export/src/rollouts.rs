//! Per-rollout results of an evaluation (`sim.evaluation`): one row per rollout, as
//! `rollouts.csv` and `rollouts.parquet` (docs/export.md, "Per-rollout results of an
//! evaluation").
//!
//! Row `i` is the rollout on condition `i` of the evaluated condition set (an evaluation keeps
//! its rows in condition order, whatever its shards: [`Evaluation::rows`]), so the `condition`
//! column pairs the rows of policies evaluated on the same set.

use osms_sim::Failure;
use osms_sim::artifacts::{EvalRow, Evaluation};

use crate::Error;
use crate::table::{Cells, Column, Table};

/// The file names `osms export` writes for an evaluation.
pub const CSV_FILE: &str = "rollouts.csv";
pub const PARQUET_FILE: &str = "rollouts.parquet";

/// A failure kind's stored name (`force_exceeded`).
pub fn failure_key(f: Failure) -> String {
    serde_json::to_value(f)
        .ok()
        .and_then(|v| v.as_str().map(String::from))
        .expect("a failure kind serialises as its snake_case name")
}

/// A failure kind's column: `failure_` and its stored name (`failure_force_exceeded`).
pub fn failure_column(f: Failure) -> String {
    format!("failure_{}", failure_key(f))
}

/// The table of an evaluation's rows, one per rollout, in row (= condition) order.
pub fn table(rows: &[EvalRow]) -> Table {
    table_on(rows, &(0..rows.len()).collect::<Vec<_>>())
}

/// The table of rollouts on some conditions of a set: row `k` ran condition `conditions[k]`
/// (an evaluation of a subset, from Python's `osms.eval.evaluate`).
pub fn table_on(rows: &[EvalRow], conditions: &[usize]) -> Table {
    assert_eq!(rows.len(), conditions.len(), "one condition per row");
    let ints = |f: &dyn Fn(usize, &EvalRow) -> i64| {
        Cells::Int(
            rows.iter()
                .enumerate()
                .map(|(i, r)| Some(f(i, r)))
                .collect(),
        )
    };
    let floats = |f: &dyn Fn(&EvalRow) -> Option<f64>| Cells::Float(rows.iter().map(f).collect());
    let bools =
        |f: &dyn Fn(&EvalRow) -> bool| Cells::Bool(rows.iter().map(|r| Some(f(r))).collect());
    let mut columns = vec![
        Column::new("condition", ints(&|i, _| conditions[i] as i64)),
        Column::new(
            "variant",
            Cells::Text(rows.iter().map(|r| Some(r.variant.to_string())).collect()),
        ),
        Column::new("variant_index", ints(&|_, r| r.variant.index() as i64)),
        Column::new("lateral_offset_m", floats(&|r| Some(r.lateral_offset_m))),
        Column::new(
            "dr_observation_delay_steps",
            ints(&|_, r| i64::from(r.dr.observation_delay_steps)),
        ),
        Column::new(
            "dr_actuation_delay_steps",
            ints(&|_, r| i64::from(r.dr.actuation_delay_steps)),
        ),
        Column::new("dr_gain_scale", floats(&|r| Some(r.dr.gain_scale))),
        Column::new("dr_friction_scale", floats(&|r| Some(r.dr.friction_scale))),
        Column::new(
            "dr_contact_timeconst_scale",
            floats(&|r| Some(r.dr.contact_timeconst_scale)),
        ),
        Column::new("success", bools(&|r| r.outcome.success())),
        Column::new("completion", bools(&|r| r.outcome.completion())),
    ];
    for f in Failure::ALL {
        columns.push(Column::new(
            &failure_column(f),
            bools(&|r| r.outcome.failures.contains(&f)),
        ));
    }
    columns.extend([
        Column::new("v_rel_mps", floats(&|r| r.metrics.contact_speed_mps)),
        // Measured over Δt_eval from t_c: undefined without a contact (stored as 0).
        Column::new(
            "f_max_n",
            floats(&|r| r.metrics.contact_time_secs.map(|_| r.metrics.max_force_n)),
        ),
        Column::new(
            "l_max_m",
            floats(&|r| {
                r.metrics
                    .contact_time_secs
                    .map(|_| r.metrics.follow_through_m)
            }),
        ),
        Column::new("t_c_secs", floats(&|r| r.metrics.contact_time_secs)),
        Column::new("event_step", ints(&|_, r| r.metrics.event_step as i64)),
        // Infinite only for a rollout that ran no step.
        Column::new(
            "closest_approach_m",
            floats(&|r| Some(r.metrics.closest_approach_m).filter(|d| d.is_finite())),
        ),
        Column::new("steps", ints(&|_, r| i64::from(r.steps))),
    ]);
    Table { columns }
}

/// The column names, in order.
pub fn column_names() -> Vec<String> {
    table(&[]).columns.into_iter().map(|c| c.name).collect()
}

/// The column names with their cell types (`int`, `float`, `bool`, `text`), in order: how a
/// reader of `rollouts.csv` parses each column.
pub fn column_types() -> Vec<(String, &'static str)> {
    table(&[])
        .columns
        .into_iter()
        .map(|c| {
            let kind = match c.cells {
                Cells::Int(_) => "int",
                Cells::Float(_) => "float",
                Cells::Bool(_) => "bool",
                Cells::Text(_) => "text",
            };
            (c.name, kind)
        })
        .collect()
}

/// `rollouts.csv` and `rollouts.parquet` of an evaluation.
pub fn files(evaluation: &Evaluation) -> Result<Vec<(String, Vec<u8>)>, Error> {
    let t = table(&evaluation.rows);
    Ok(vec![
        (CSV_FILE.to_string(), t.csv()?.into_bytes()),
        (PARQUET_FILE.to_string(), t.parquet()?),
    ])
}

#[cfg(test)]
mod tests {
    use osms_sim::ObjectVariant;
    use osms_sim::control::DrDraw;
    use osms_sim::metrics::{Metrics, Outcome};
    use parquet::file::reader::{FileReader, SerializedFileReader};
    use parquet::record::Field;

    use super::*;

    /// A synthetic row. `DrDraw` and `Metrics` are written out field by field (here and in
    /// [`rows`]), so a new DR draw or metric stops this test compiling until the table has a
    /// column for it.
    fn row(
        variant: &str,
        offset: f64,
        dr: DrDraw,
        contact: Option<(f64, f64)>,
        failures: Vec<Failure>,
    ) -> EvalRow {
        EvalRow {
            variant: variant.parse::<ObjectVariant>().expect("variant"),
            lateral_offset_m: offset,
            dr,
            steps: 75,
            metrics: Metrics {
                contact_time_secs: contact.map(|c| c.0),
                contact_speed_mps: contact.map(|c| c.1),
                max_force_n: if contact.is_some() { 41.5 } else { 0.0 },
                follow_through_m: 0.25,
                event_step: 31,
                closest_approach_m: if contact.is_some() { 0.0 } else { 0.125 },
            },
            outcome: Outcome { failures },
            trace: None,
        }
    }

    /// A catch, a drop that never touched the hand, and a completion that failed two impact
    /// criteria.
    fn rows() -> Vec<EvalRow> {
        vec![
            row(
                "sphere-small",
                0.05,
                DrDraw::none(),
                Some((0.62, 0.8)),
                vec![],
            ),
            row(
                "box-large",
                -0.1,
                DrDraw {
                    observation_delay_steps: 1,
                    actuation_delay_steps: 0,
                    gain_scale: 0.95,
                    friction_scale: 1.125,
                    contact_timeconst_scale: 0.75,
                },
                None,
                vec![Failure::Drop],
            ),
            row(
                "capsule-small",
                0.0,
                DrDraw {
                    observation_delay_steps: 0,
                    actuation_delay_steps: 1,
                    gain_scale: 1.0,
                    friction_scale: 1.0,
                    contact_timeconst_scale: 1.25,
                },
                Some((0.5, 2.5)),
                vec![Failure::ContactSpeedExceeded, Failure::ForceExceeded],
            ),
        ]
    }

    const FAILURES: [&str; 11] = [
        "failure_forbidden_contact_arm",
        "failure_forbidden_contact_ground",
        "failure_joint_limit",
        "failure_self_collision",
        "failure_rebound",
        "failure_drop",
        "failure_contact_speed_exceeded",
        "failure_force_exceeded",
        "failure_follow_through_short",
        "failure_instability",
        "failure_invalid_action",
    ];

    fn expected_names() -> Vec<String> {
        let head = [
            "condition",
            "variant",
            "variant_index",
            "lateral_offset_m",
            "dr_observation_delay_steps",
            "dr_actuation_delay_steps",
            "dr_gain_scale",
            "dr_friction_scale",
            "dr_contact_timeconst_scale",
            "success",
            "completion",
        ];
        let tail = [
            "v_rel_mps",
            "f_max_n",
            "l_max_m",
            "t_c_secs",
            "event_step",
            "closest_approach_m",
            "steps",
        ];
        head.iter()
            .chain(FAILURES.iter())
            .chain(tail.iter())
            .map(|s| s.to_string())
            .collect()
    }

    #[test]
    fn csv_has_one_line_per_rollout_and_empty_cells_where_undefined() {
        assert_eq!(column_names(), expected_names());
        let csv = table(&rows()).csv().expect("csv");
        let lines: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
        assert_eq!(lines.len(), 4, "{csv}");
        assert_eq!(lines[0], expected_names());
        let cell = |r: usize, name: &str| {
            let c = expected_names()
                .iter()
                .position(|n| n == name)
                .expect("column");
            lines[r + 1][c]
        };
        assert_eq!(
            (0..3).map(|r| cell(r, "condition")).collect::<Vec<_>>(),
            ["0", "1", "2"]
        );
        assert_eq!(cell(0, "variant"), "sphere-small");
        assert_eq!(cell(0, "variant_index"), "3");
        assert_eq!(cell(1, "variant_index"), "0");
        assert_eq!(cell(2, "variant_index"), "9");
        assert_eq!(cell(1, "lateral_offset_m"), "-0.1");
        assert_eq!(cell(1, "dr_observation_delay_steps"), "1");
        assert_eq!(cell(2, "dr_actuation_delay_steps"), "1");
        assert_eq!(cell(1, "dr_gain_scale"), "0.95");
        assert_eq!(cell(1, "dr_friction_scale"), "1.125");
        assert_eq!(cell(1, "dr_contact_timeconst_scale"), "0.75");
        assert_eq!(cell(0, "dr_gain_scale"), "1");
        assert_eq!(
            [cell(0, "success"), cell(1, "success"), cell(2, "success")],
            ["true", "false", "false"]
        );
        assert_eq!(
            [
                cell(0, "completion"),
                cell(1, "completion"),
                cell(2, "completion")
            ],
            ["true", "false", "true"]
        );
        assert_eq!(cell(1, "failure_drop"), "true");
        assert_eq!(cell(2, "failure_drop"), "false");
        assert_eq!(cell(2, "failure_contact_speed_exceeded"), "true");
        assert_eq!(cell(2, "failure_force_exceeded"), "true");
        assert_eq!(cell(2, "failure_follow_through_short"), "false");
        // No contact: no t_c, v_rel, f_max or l_max, empty cells; k_e and the closest approach
        // are numbers.
        assert_eq!(
            ["t_c_secs", "v_rel_mps", "f_max_n", "l_max_m"].map(|c| cell(1, c)),
            ["", "", "", ""]
        );
        assert_eq!([cell(0, "t_c_secs"), cell(0, "v_rel_mps")], ["0.62", "0.8"]);
        assert_eq!(cell(0, "f_max_n"), "41.5");
        assert_eq!(cell(1, "event_step"), "31");
        assert_eq!(cell(1, "closest_approach_m"), "0.125");
        assert_eq!(cell(0, "l_max_m"), "0.25");
        assert_eq!(cell(0, "event_step"), "31");
        assert_eq!(cell(2, "steps"), "75");
    }

    #[test]
    fn parquet_reads_back_with_the_same_columns_values_and_nulls() {
        let bytes = table(&rows()).parquet().expect("parquet");
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join(PARQUET_FILE);
        std::fs::write(&path, &bytes).expect("write");
        let reader =
            SerializedFileReader::new(std::fs::File::open(&path).expect("open")).expect("read");
        let names: Vec<String> = reader
            .metadata()
            .file_metadata()
            .schema_descr()
            .root_schema()
            .get_fields()
            .iter()
            .map(|f| f.name().to_string())
            .collect();
        assert_eq!(names, expected_names());
        let rows: Vec<Vec<(String, Field)>> = reader
            .get_row_iter(None)
            .expect("rows")
            .map(|r| {
                r.expect("row")
                    .get_column_iter()
                    .map(|(n, f)| (n.clone(), f.clone()))
                    .collect()
            })
            .collect();
        assert_eq!(rows.len(), 3);
        let get = |r: usize, name: &str| -> Field {
            rows[r]
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, f)| f.clone())
                .expect("column")
        };
        assert_eq!(get(2, "condition"), Field::Long(2));
        assert_eq!(get(2, "variant"), Field::Str("capsule-small".into()));
        assert_eq!(get(2, "variant_index"), Field::Long(9));
        assert_eq!(get(1, "lateral_offset_m"), Field::Double(-0.1));
        assert_eq!(get(1, "dr_observation_delay_steps"), Field::Long(1));
        assert_eq!(get(1, "dr_contact_timeconst_scale"), Field::Double(0.75));
        assert_eq!(get(0, "success"), Field::Bool(true));
        assert_eq!(get(2, "completion"), Field::Bool(true));
        assert_eq!(get(2, "failure_force_exceeded"), Field::Bool(true));
        assert_eq!(get(0, "failure_force_exceeded"), Field::Bool(false));
        assert_eq!(get(1, "t_c_secs"), Field::Null);
        assert_eq!(get(1, "v_rel_mps"), Field::Null);
        assert_eq!(get(0, "t_c_secs"), Field::Double(0.62));
        assert_eq!(get(2, "v_rel_mps"), Field::Double(2.5));
        assert_eq!(get(1, "f_max_n"), Field::Null);
        assert_eq!(get(1, "l_max_m"), Field::Null);
        assert_eq!(get(1, "closest_approach_m"), Field::Double(0.125));
        assert_eq!(get(0, "f_max_n"), Field::Double(41.5));
        assert_eq!(get(0, "event_step"), Field::Long(31));
        assert_eq!(get(0, "steps"), Field::Long(75));
        // The same rows give the same bytes.
        assert_eq!(table(&self::rows()).parquet().expect("parquet"), bytes);
    }

    #[test]
    fn an_empty_evaluation_gives_a_header_and_an_empty_parquet_file() {
        let files = files(&Evaluation { rows: vec![] }).expect("files");
        assert_eq!(files[0].0, CSV_FILE);
        assert_eq!(
            String::from_utf8(files[0].1.clone()).expect("utf-8"),
            format!("{}\n", expected_names().join(","))
        );
        assert_eq!(files[1].0, PARQUET_FILE);
        assert!(files[1].1.starts_with(b"PAR1"));
    }
}
