//! Golden snapshots (files under `golden/`):
//! (a) the stage-definition DAG of the `tiny` profile, identical on every platform;
//! (b) the keys and content hashes of the `tiny` outputs, per platform class, checked where a
//!     snapshot for the running class exists (record one with `OSMS_RECORD_GOLDEN=1`).
//! A changed output hash whose stage kept its code version fails with its own message.

use std::path::{Path, PathBuf};

use osms_make::{Pipeline, Plan, Registry};
use osms_tests::Project;
use osms_tests::project::hashes;
use serde::{Deserialize, Serialize};

fn golden_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../golden")
}

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

fn settings() -> insta::Settings {
    let mut s = insta::Settings::clone_current();
    s.set_snapshot_path(golden_dir());
    s.set_prepend_module_to_snapshot(false);
    s.set_omit_expression(true);
    s
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

#[derive(Debug, Serialize, Deserialize, PartialEq)]
struct Output {
    instance: String,
    kind: String,
    code_version: u32,
    key: String,
    content_hash: String,
}

fn tiny_outputs() -> Vec<Output> {
    let p = Project::engine();
    let report = p.make(Some("tiny"), &[0], 2);
    let plan = p.plan(Some("tiny")).expect("plan");
    let h = hashes(&report);
    assert_eq!(
        h.len(),
        report.instances.len(),
        "every tiny stage must build"
    );
    report
        .instances
        .iter()
        .map(|r| {
            let stage = r.instance.split('@').next().unwrap_or(&r.instance);
            let info = &plan.stages[plan.stage_index(stage).expect("stage")].info;
            Output {
                instance: r.instance.clone(),
                kind: info.name.to_string(),
                code_version: info.code_version,
                key: r.key.map(|k| k.to_hex()).unwrap_or_default(),
                content_hash: h[&r.instance].to_hex(),
            }
        })
        .collect()
}

/// Reads the JSON body of an insta snapshot file.
fn snapshot_body(path: &Path) -> Option<Vec<Output>> {
    let text = std::fs::read_to_string(path).ok()?;
    let body = text.splitn(3, "---\n").nth(2)?;
    serde_json::from_str(body).ok()
}

#[test]
fn content_hashes_of_the_tiny_outputs_per_platform_class() {
    let class = osms::platform::class();
    let name = format!("outputs_engine_tiny@{class}");
    let path = golden_dir().join(format!("{name}.snap"));
    let outputs = tiny_outputs();
    let recording = std::env::var_os("OSMS_RECORD_GOLDEN").is_some();
    let Some(golden) = snapshot_body(&path) else {
        if !recording {
            eprintln!(
                "note: no golden content hashes for platform class {class} ({}); the identity tests still ran.\n\
                 Record them with: OSMS_RECORD_GOLDEN=1 INSTA_UPDATE=always cargo test -p osms-tests --test golden",
                path.display()
            );
            return;
        }
        settings().bind(|| insta::assert_json_snapshot!(name, outputs));
        return;
    };
    for now in &outputs {
        if let Some(before) = golden.iter().find(|g| g.instance == now.instance) {
            assert!(
                !(before.code_version == now.code_version
                    && before.kind == now.kind
                    && before.key == now.key
                    && before.content_hash != now.content_hash),
                "stage {} changed its output ({} -> {}) for the same key, but kind `{}` is still at code \
                 version {}: bump its CODE_VERSION, then re-record the golden hashes",
                now.instance,
                &before.content_hash[..12],
                &now.content_hash[..12],
                now.kind,
                now.code_version
            );
        }
    }
    settings().bind(|| insta::assert_json_snapshot!(name, outputs));
}
