//! `osms export` of an evaluation through the real command line: one row per rollout as
//! `rollouts.csv` and `rollouts.parquet`, in the condition set's order (pyarrow as an
//! independent reader), and a clear error for an evaluation stored in an older format.

use std::path::Path;
use std::process::{Command, Output};

use osms_make::{MakeOptions, Pipeline, Plan};
use osms_sim::artifacts::{Conditions, Evaluation};
use osms_store::{Hash, Store};
use osms_tests::project::{Silent, hashes};

/// The header `rollouts.csv` must have (docs/export.md).
const COLUMNS: [&str; 29] = [
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
    "v_rel_mps",
    "f_max_n",
    "l_max_m",
    "t_c_secs",
    "event_step",
    "closest_approach_m",
    "steps",
];

#[test]
fn an_evaluation_exports_one_row_per_condition_in_condition_order() {
    // The shipped pipeline on the tiny profile, only as far as the scripted catcher's
    // held-out evaluation (no training).
    let dir = tempfile::tempdir().expect("dir");
    let pipeline = dir.path().join("pipeline.toml");
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml"),
        &pipeline,
    )
    .expect("copy pipeline.toml");
    // Impact limits no catch of the scripted prior misses, so that the completed catches
    // succeed and the fixture has successes as well as failures of several kinds.
    let mut text = std::fs::read_to_string(&pipeline).expect("read");
    text.push_str(
        "\n[profiles.tiny.eval_scripted]\nparams = { rollout = { dr = \"paper\", success = { min_follow_through_m = 0.0, max_force_n = 100000.0, max_contact_speed_mps = 100.0 } } }\n",
    );
    std::fs::write(&pipeline, text).expect("write");
    let plan = Plan::new(
        &Pipeline::load(&pipeline, Some("tiny")).expect("load"),
        &osms_kinds::registry(),
    )
    .expect("plan");
    let store = Store::open(dir.path().join("store")).expect("store");
    let opts = MakeOptions {
        targets: vec!["eval_scripted".into()],
        seeds: vec![0],
        jobs: 2,
        stages: 1,
        dry_run: false,
    };
    let report = osms_make::make(&plan, &store, &opts, &Silent).expect("make");
    assert!(report.failed().is_empty(), "{:?}", report.failed());
    let built = hashes(&report);
    let objects = osms_make::StoreObjects(&store);
    let conditions: Conditions =
        osms_make::assemble(&store.get(&built["heldout"]).expect("heldout"), &objects)
            .expect("conditions");
    let evaluation: Evaluation = osms_make::assemble(
        &store.get(&built["eval_scripted"]).expect("eval_scripted"),
        &objects,
    )
    .expect("evaluation");
    let n = conditions.items.len();
    assert!(n > 1, "the tiny held-out set has {n} conditions");

    let osms = |args: &[&str]| -> Output {
        Command::new(env!("CARGO_BIN_EXE_osms-shipped"))
            .arg("--pipeline")
            .arg(&pipeline)
            .arg("--store")
            .arg(store.root())
            .args(args)
            .args(["--profile", "tiny"])
            .env("OSMS_NO_PROGRESS", "1")
            .output()
            .expect("run osms")
    };
    let out = dir.path().join("export");
    let out_arg = out.to_str().expect("utf-8 path");

    // Plain: the written paths, one a line, as the other exports print them.
    let o = osms(&["export", "eval_scripted", "--out", out_arg]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv_path = out.join("rollouts.csv");
    let parquet_path = out.join("rollouts.parquet");
    let p = |path: &Path| path.display().to_string();
    assert_eq!(
        String::from_utf8_lossy(&o.stdout),
        format!("{}\n{}\n", p(&csv_path), p(&parquet_path))
    );
    let first = (
        std::fs::read(&csv_path).expect("csv"),
        std::fs::read(&parquet_path).expect("parquet"),
    );
    // --json: the same paths as a list, the same bytes.
    let o = osms(&["export", "eval_scripted", "--out", out_arg, "--json"]);
    assert!(o.status.success());
    let listed: Vec<String> = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(listed, [p(&csv_path), p(&parquet_path)]);
    assert_eq!(
        (
            std::fs::read(&csv_path).expect("csv"),
            std::fs::read(&parquet_path).expect("parquet")
        ),
        first,
        "the same artifact gives the same bytes"
    );

    // The CSV: the header, one row per condition, in the condition set's order.
    let csv = String::from_utf8(first.0).expect("utf-8");
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    assert_eq!(header, COLUMNS);
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), n, "one row per condition");
    let col = |name: &str| COLUMNS.iter().position(|c| *c == name).expect("column");
    let float =
        |cell: &str| -> Option<f64> { (!cell.is_empty()).then(|| cell.parse().expect("a number")) };
    let mut drawn = 0;
    let mut outcomes = [0usize; 2];
    let mut successes = 0usize;
    let mut kinds = std::collections::BTreeSet::new();
    for (i, ((row, condition), eval)) in rows
        .iter()
        .zip(&conditions.items)
        .zip(&evaluation.rows)
        .enumerate()
    {
        assert_eq!(row.len(), COLUMNS.len(), "row {i}");
        assert_eq!(row[col("condition")], i.to_string());
        // Row i is the rollout on condition i: the condition set's own variant and offset.
        assert_eq!(
            row[col("variant")],
            condition.variant.to_string(),
            "row {i}"
        );
        assert_eq!(
            row[col("variant_index")],
            condition.variant.index().to_string()
        );
        assert_eq!(
            float(row[col("lateral_offset_m")]),
            Some(condition.lateral_offset_m),
            "row {i}"
        );
        // The stored rollout's DR draws and metrics, t_c empty without contact.
        assert_eq!(
            row[col("dr_observation_delay_steps")],
            eval.dr.observation_delay_steps.to_string()
        );
        assert_eq!(float(row[col("dr_gain_scale")]), Some(eval.dr.gain_scale));
        assert_eq!(
            float(row[col("dr_contact_timeconst_scale")]),
            Some(eval.dr.contact_timeconst_scale)
        );
        drawn += usize::from(eval.dr.gain_scale != 1.0);
        assert_eq!(
            float(row[col("t_c_secs")]),
            eval.metrics.contact_time_secs,
            "row {i}"
        );
        assert_eq!(
            float(row[col("v_rel_mps")]),
            eval.metrics.contact_speed_mps,
            "row {i}"
        );
        let contact = eval.metrics.contact_time_secs.is_some();
        assert_eq!(
            float(row[col("f_max_n")]),
            contact.then_some(eval.metrics.max_force_n)
        );
        assert_eq!(
            float(row[col("l_max_m")]),
            contact.then_some(eval.metrics.follow_through_m)
        );
        assert_eq!(row[col("success")], eval.outcome.success().to_string());
        assert_eq!(row[col("steps")], eval.steps.to_string());
        // The columns not checked above, every one against the stored row.
        assert_eq!(
            row[col("dr_actuation_delay_steps")],
            eval.dr.actuation_delay_steps.to_string(),
            "row {i}"
        );
        assert_eq!(
            float(row[col("dr_friction_scale")]),
            Some(eval.dr.friction_scale),
            "row {i}"
        );
        assert_eq!(
            row[col("completion")],
            eval.outcome.completion().to_string(),
            "row {i}"
        );
        for f in osms_sim::Failure::ALL {
            let kind = serde_json::to_value(f).expect("a failure kind");
            let name = format!("failure_{}", kind.as_str().expect("its snake_case name"));
            assert_eq!(
                row[col(&name)],
                eval.outcome.failures.contains(&f).to_string(),
                "row {i}, {name}"
            );
        }
        assert_eq!(
            row[col("event_step")],
            eval.metrics.event_step.to_string(),
            "row {i}"
        );
        assert_eq!(
            float(row[col("closest_approach_m")]),
            Some(eval.metrics.closest_approach_m).filter(|d| d.is_finite()),
            "row {i}"
        );
        outcomes[usize::from(eval.outcome.completion())] += 1;
        successes += usize::from(eval.outcome.success());
        kinds.extend(eval.outcome.failures.iter().copied());
    }
    // A fixture that can tell the columns apart: some catches succeed and some do not, some
    // complete and some do not, and the failures are of several kinds.
    assert!(
        outcomes[0] > 0 && outcomes[1] > 0,
        "incomplete / completed catches: {outcomes:?}"
    );
    assert!(
        successes > 0 && successes < n,
        "{successes} of {n} rollouts succeed"
    );
    assert!(kinds.len() >= 2, "failure kinds: {kinds:?}");
    assert!(
        drawn > 0,
        "the evaluation runs under DR: some gain draw differs from 1"
    );

    // An evaluation stored in the format before the DR draws (schema 3): a clear error.
    old_format_is_refused(&store, &osms, &dir.path().join("old"));

    // pyarrow reads the same table: columns, rows, nulls exactly where the CSV is empty.
    let Some(python) = osms_tests::python::interpreter("rollouts.parquet read back in Python")
    else {
        return;
    };
    let v = osms_tests::python::run_script(&python, "read-rollouts.py", &[&p(&parquet_path)]);
    assert_eq!(v["columns"], serde_json::json!(COLUMNS));
    assert_eq!(v["rows"], n);
    assert_eq!(v["types"]["variant"], "string");
    assert_eq!(v["types"]["success"], "bool");
    assert_eq!(v["types"]["condition"], "int64");
    assert_eq!(v["types"]["t_c_secs"], "double");
    assert_eq!(
        v["condition"],
        serde_json::json!((0..n).collect::<Vec<_>>())
    );
    let no_contact = rows
        .iter()
        .filter(|r| r[col("t_c_secs")].is_empty())
        .count();
    assert_eq!(v["nulls"]["t_c_secs"], no_contact);
    assert_eq!(v["nulls"]["f_max_n"], no_contact);
    assert_eq!(v["nulls"]["steps"], 0);
    for (i, eval) in evaluation.rows.iter().enumerate() {
        let t_c = v["t_c_secs"][i]
            .as_str()
            .map(|s| s.parse::<f64>().expect("a number"));
        assert_eq!(t_c, eval.metrics.contact_time_secs, "row {i}");
    }

    // scripts/split-rollouts.py groups the same rows by variant: every rollout in exactly one
    // group, each group's success and completion the CSV's (the scripted catcher completes
    // catches but never succeeds, so completion is the rate that can be wrong here).
    let groups = osms_tests::python::run_script(
        &python,
        "split-rollouts.py",
        &["variant", "--bins", "20", "--json", &p(&csv_path)],
    );
    let groups = groups.as_array().expect("a list of groups");
    let total: u64 = groups.iter().map(|g| g["n"].as_u64().expect("n")).sum();
    assert_eq!(total as usize, n);
    for g in groups {
        let name = g["group"].as_str().expect("group");
        let of: Vec<&Vec<&str>> = rows.iter().filter(|r| r[col("variant")] == name).collect();
        let successes = of.iter().filter(|r| r[col("success")] == "true").count();
        assert_eq!(g["n"].as_u64(), Some(of.len() as u64), "{name}");
        let completions = of.iter().filter(|r| r[col("completion")] == "true").count();
        for (key, count) in [("success", successes), ("completion", completions)] {
            let rate = g[key].as_f64().expect("a rate");
            assert!(
                (rate - count as f64 / of.len() as f64).abs() < 1e-12,
                "{name} {key}"
            );
        }
    }
    assert!(
        groups.iter().any(|g| g["completion"].as_f64() > Some(0.0)),
        "some catch is completed"
    );
}

/// The eval_scripted manifest with its header's schema version set back to 3, stored under a
/// record of its own: `osms export` of its hash exits 1, says to rebuild and writes nothing.
fn old_format_is_refused(store: &Store, osms: &dyn Fn(&[&str]) -> Output, out: &Path) {
    let (records, _) = store.records().expect("records");
    let record = records
        .iter()
        .find(|r| r.stage == "eval_scripted" && r.shard.is_none())
        .expect("eval_scripted record");
    let mut bytes = store.get(&record.content_hash).expect("manifest");
    // Magic (8 bytes), format version (u16), schema version (u16).
    assert_eq!(&bytes[10..12], &4u16.to_le_bytes(), "the current schema");
    bytes[10..12].copy_from_slice(&3u16.to_le_bytes());
    let mut old = record.clone();
    old.content_hash = store.put(&bytes).expect("put");
    old.key = Hash::of(b"an evaluation of an older osms");
    store.put_record(&old).expect("record");
    let prefix = old.content_hash.to_hex()[..12].to_string();
    let o = osms(&[
        "export",
        &prefix,
        "--out",
        out.to_str().expect("utf-8 path"),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("schema version 3, this osms reads version 4")
            && err.contains("rebuild it with `osms make`"),
        "{err}"
    );
    assert!(!out.exists());
}
