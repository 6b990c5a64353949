//! Golden snapshots (files under `golden/`):
//! (a) the stage-definition DAG of the `tiny` profile, identical on every platform;
//! (b) the keys and content hashes of the `tiny` outputs, per platform class, checked where a
//!     snapshot for the running class exists (record one with `OSMS_RECORD_GOLDEN=1`).
//! A changed output hash whose stage kept its code version fails with its own message.

use std::path::Path;

use osms_make::{Pipeline, Plan, Registry};
use osms_tests::Project;
use osms_tests::golden::{self, settings};
use osms_tests::project::hashes;
use serde::Serialize;

#[derive(Serialize)]
struct DagStage {
    stage: String,
    kind: &'static str,
    code_version: u32,
    seeded: bool,
    fixed_seed: Option<u64>,
    seed_dependent: bool,
    shards: u32,
    inputs: Vec<(String, String)>,
    params: serde_json::Value,
    definition: String,
}

fn dag(plan: &Plan) -> Vec<DagStage> {
    plan.stages
        .iter()
        .map(|s| DagStage {
            stage: s.name.clone(),
            kind: s.info.name,
            code_version: s.info.code_version,
            seeded: s.info.uses_rng,
            fixed_seed: s.fixed_seed,
            seed_dependent: s.seed_dependent,
            shards: s.shards,
            inputs: s
                .inputs
                .iter()
                .map(|(slot, up)| (slot.clone(), plan.stages[*up].name.clone()))
                .collect(),
            params: s.params.json.clone(),
            definition: s.definition.to_hex(),
        })
        .collect()
}

#[test]
fn stage_dag_of_the_tiny_profile() {
    let engine = Project::engine();
    let plan = engine.plan(Some("tiny")).expect("engine plan");
    settings().bind(|| insta::assert_json_snapshot!("dag_engine_tiny", dag(&plan)));

    // The shipped pipeline with the shipped kinds.
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml");
    let pipeline = Pipeline::load(&shipped, Some("tiny")).expect("pipeline.toml parses");
    let registry: Registry = osms::registry();
    let plan = Plan::new(&pipeline, &registry).expect("pipeline.toml plans");
    settings().bind(|| insta::assert_json_snapshot!("dag_pipeline_tiny", dag(&plan)));
}

#[test]
fn content_hashes_of_the_tiny_outputs_per_platform_class() {
    let p = Project::engine();
    let report = p.make(Some("tiny"), &[0], 2);
    let plan = p.plan(Some("tiny")).expect("plan");
    assert_eq!(
        hashes(&report).len(),
        report.instances.len(),
        "every tiny stage must build"
    );
    golden::check("outputs_engine_tiny", golden::outputs(&plan, &report));
}
