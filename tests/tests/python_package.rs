//! The Python package `osms` (crates/osms-py) against osms's own evaluations: the store's
//! teacher, student and scripted catcher evaluated from Python give `osms export`'s rows bit
//! for bit at 1, 3 and 16 rollouts at once; a NumPy policy's rows do not depend on batching
//! and match the gymnasium environment's; gymnasium's checker passes; bad actions raise an
//! error naming the condition and step and leave the store alone (crates/osms-py/tests/
//! check_package.py does the Python side; scripts/test builds the package into the test venv).

use std::path::Path;
use std::process::Command;

use osms_make::{MakeOptions, Pipeline, Plan};
use osms_sim::artifacts::Evaluation;
use osms_store::Store;
use osms_tests::project::{Silent, hashes};

#[test]
fn the_python_package_reproduces_osms_evaluations() {
    let Some(python) = osms_tests::python::interpreter("the Python package's checks") else {
        return;
    };
    let dir = tempfile::tempdir().expect("dir");
    let pipeline = dir.path().join("pipeline.toml");
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml"),
        &pipeline,
    )
    .expect("copy pipeline.toml");
    let plan = Plan::new(
        &Pipeline::load(&pipeline, Some("tiny")).expect("load"),
        &osms::registry(),
    )
    .expect("plan");
    let store = Store::open(dir.path().join("store")).expect("store");
    let protocols = ["eval_teacher", "eval_student_il", "eval_scripted"];
    let opts = MakeOptions {
        targets: protocols.iter().map(|s| s.to_string()).collect(),
        seeds: vec![0],
        jobs: 2,
        stages: 1,
        dry_run: false,
    };
    let report = osms_make::make(&plan, &store, &opts, &Silent).expect("make");
    assert!(report.failed().is_empty(), "{:?}", report.failed());
    let built = hashes(&report);
    // The reference rows: each evaluation's rollouts.csv as `osms export` writes it.
    let reference = dir.path().join("reference");
    std::fs::create_dir_all(&reference).expect("reference dir");
    let objects = osms_make::StoreObjects(&store);
    for stage in protocols {
        let evaluation: Evaluation =
            osms_make::assemble(&store.get(&built[stage]).expect("evaluation"), &objects)
                .expect("decode");
        let files = osms_export::rollouts::files(&evaluation).expect("files");
        let (_, csv) = files
            .iter()
            .find(|(name, _)| name == osms_export::rollouts::CSV_FILE)
            .expect("a csv");
        std::fs::write(reference.join(format!("{stage}.csv")), csv).expect("write csv");
    }
    drop(store);

    let script =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../crates/osms-py/tests/check_package.py");
    let out = Command::new(&python)
        .arg(&script)
        .arg(&pipeline)
        .arg(&reference)
        .env("OSMS_NO_PROGRESS", "1")
        .output()
        .expect("run python");
    assert!(
        out.status.success(),
        "check_package.py failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "check_package.py printed no JSON ({e}):\n{}",
            String::from_utf8_lossy(&out.stdout)
        )
    });
    // Nine identity checks (three policies × three batch sizes), each over the whole set.
    let conditions = std::fs::read_to_string(reference.join("eval_teacher.csv"))
        .expect("csv")
        .lines()
        .count()
        - 1;
    let identity = summary["identity"].as_object().expect("identity");
    assert_eq!(identity.len(), 9, "{summary}");
    assert!(
        identity
            .values()
            .all(|n| n.as_u64() == Some(conditions as u64)),
        "{summary}"
    );
    assert_eq!(summary["store_unchanged"], true);
    assert_eq!(summary["reset_keyed"], true);
    assert_eq!(summary["python_policy"]["env_rows_match"], true);
    assert_eq!(summary["render"], serde_json::json!([480, 480, 3]));
    let warnings = summary["check_env_warnings"].as_array().expect("warnings");
    assert!(
        warnings.is_empty(),
        "gymnasium's checker warned: {warnings:?}"
    );
}
