//! The shipped `pipeline.toml` on the `tiny` profile with the shipped stage kinds: outputs that
//! do not depend on threads or shards, and content hashes per platform class
//! (`golden/outputs_pipeline_tiny@<class>.snap`, checked where the running class has one).

use std::collections::BTreeMap;
use std::path::Path;

use osms_make::{MakeOptions, Pipeline, Plan};
use osms_store::{Hash, Store};
use osms_tests::golden;
use osms_tests::project::{Silent, hashes};

fn shipped() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml"))
        .expect("pipeline.toml")
}

fn make(text: &str, jobs: usize) -> (BTreeMap<String, Hash>, Vec<golden::Output>) {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("pipeline.toml");
    std::fs::write(&path, text).expect("write");
    let plan = Plan::new(
        &Pipeline::load(&path, Some("tiny")).expect("load"),
        &osms::registry(),
    )
    .expect("plan");
    let store = Store::open(dir.path().join("store")).expect("store");
    let opts = MakeOptions {
        targets: vec![],
        seeds: vec![0],
        jobs,
        dry_run: false,
    };
    let report = osms_make::make(&plan, &store, &opts, &Silent).expect("make");
    assert!(report.failed().is_empty(), "{:?}", report.failed());
    (hashes(&report), golden::outputs(&plan, &report))
}

#[test]
fn tiny_outputs_do_not_depend_on_threads_or_shards_and_match_the_golden_hashes() {
    let text = shipped();
    let (reference, outputs) = make(&text, 1);
    assert_eq!(reference.len(), 3, "{reference:?}");
    assert_eq!(make(&text, 2).0, reference, "1 vs 2 threads");
    let reshard = text
        .replace(
            "params = { n = 40 }\nshards = 2",
            "params = { n = 40 }\nshards = 5",
        )
        .replace(
            "inputs = { world = \"world\", conditions = \"heldout\" }\nshards = 4",
            "inputs = { world = \"world\", conditions = \"heldout\" }\nshards = 3",
        );
    assert_eq!(
        reshard.matches("shards = 5").count() + reshard.matches("shards = 3").count(),
        2,
        "both overlays edited"
    );
    assert_eq!(make(&reshard, 2).0, reference, "other shard counts");
    golden::check("outputs_pipeline_tiny", outputs);
}
