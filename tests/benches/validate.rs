//! Candidate validation, fast against exhaustive, on the same D_R rollouts in one run: wall
//! time, rollouts and control steps simulated, and the speed-up, with the two results checked
//! to be identical item by item. Reads the inputs from the project's store (building them if
//! they are missing: on `small` that is the pipeline up to the error model, about 20 minutes).
//!
//! `OSMS_BENCH_PROFILE` (default `small`), `OSMS_BENCH_ITEMS` (default 24: the first D_R
//! rollouts), `OSMS_STORE` (default the repository's `store/`). Prints figures; asserts only
//! that both evaluations agree.

use std::path::Path;
use std::time::Instant;

use osms_make::{MakeOptions, Pipeline, Plan};
use osms_method::artifacts::CandidateSets;
use osms_method::artifacts::ErrorModelArtifact;
use osms_method::artifacts::ErrorStreams;
use osms_method::validate::{Case, Cost, ValidateParams, validate};
use osms_policy::artifacts::Dataset;
use osms_policy::artifacts::Teacher;
use osms_sim::artifacts::WorldArtifact;
use osms_store::Store;
use osms_tests::project::{Silent, hashes};

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let profile = std::env::var("OSMS_BENCH_PROFILE").unwrap_or_else(|_| "small".into());
    let n: usize = std::env::var("OSMS_BENCH_ITEMS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(24);
    let store_dir = std::env::var("OSMS_STORE")
        .map(Into::into)
        .unwrap_or_else(|_| root.join("store"));
    let plan = Plan::new(
        &Pipeline::load(&root.join("pipeline.toml"), Some(&profile)).expect("pipeline"),
        &osms_kinds::registry(),
    )
    .expect("plan");
    let store = Store::open(&store_dir).expect("store");
    let targets = [
        "world",
        "teacher",
        "d_r",
        "candidates_geodesic",
        "error_model",
    ];
    println!(
        "inputs: `osms make {}` on profile {profile} (cached if built)",
        targets.join(" ")
    );
    let report = osms_make::make(
        &plan,
        &store,
        &MakeOptions {
            targets: targets.iter().map(|t| t.to_string()).collect(),
            seeds: vec![0],
            jobs: 1,
            stages: 1,
            dry_run: false,
        },
        &Silent,
    )
    .expect("make");
    assert!(report.failed().is_empty(), "{:?}", report.failed());
    let h = hashes(&report);
    let bytes = |name: &str| store.get(&h[name]).expect("object");
    let sharded = |name: &str| bytes(name);
    let world = osms_core::decode::<WorldArtifact>(&bytes("world"))
        .expect("world")
        .world()
        .expect("world");
    let teacher: Teacher = osms_core::decode(&bytes("teacher@0")).expect("teacher");
    let d_r: Dataset =
        osms_make::assemble(&sharded("d_r@0"), &osms_make::StoreObjects(&store)).expect("D_R");
    let sets: CandidateSets = osms_make::assemble(
        &sharded("candidates_geodesic@0"),
        &osms_make::StoreObjects(&store),
    )
    .expect("candidates");
    let model = osms_core::decode::<ErrorModelArtifact>(&bytes("error_model@0"))
        .expect("error model")
        .model;
    let mut task = d_r.task.clone();
    task.rollout.record_privileged = false;
    let streams = ErrorStreams {
        seed: 0,
        stage: "bench".into(),
    };
    let n = n.min(d_r.items.len());
    let (mut fast, mut slow) = ((0.0, Cost::default()), (0.0, Cost::default()));
    let params = ValidateParams::default();
    for i in 0..n {
        let rollout = &d_r.items[i].rollout;
        let candidates = sets.items[i]
            .set
            .as_ref()
            .map(|s| s.candidates.clone())
            .unwrap_or_default();
        let item = rollout.item;
        let errors = |q| streams.rng(item, q);
        let case = Case {
            world: &world,
            task: &task,
            agent: &teacher.agent,
            rollout,
            candidates: &candidates,
            model: &model,
            errors: &errors,
        };
        let mut results = Vec::new();
        for (exhaustive, acc) in [(false, &mut fast), (true, &mut slow)] {
            let p = ValidateParams {
                exhaustive,
                ..params.clone()
            };
            let t = Instant::now();
            let (v, cost) = validate(&case, &p).expect("validate");
            acc.0 += t.elapsed().as_secs_f64();
            acc.1 += cost;
            results.push(v);
        }
        assert_eq!(
            results[0], results[1],
            "D_R item {item}: fast and exhaustive differ"
        );
    }
    let steps_per_rollout = slow.1.steps as f64 / slow.1.rollouts.max(1) as f64;
    println!(
        "validation of {n} D_R rollouts (|η| = 9, Q = {}), one thread, same results:",
        params.q
    );
    for (name, (t, c)) in [("exhaustive", slow), ("fast", fast)] {
        println!(
            "  {name:<10} {t:>8.2} s  {:>6} rollouts  {:>8} control steps  {:>7.0} steps/s  {:>6.1} full-rollout equivalents/s",
            c.rollouts,
            c.steps,
            c.steps as f64 / t,
            c.steps as f64 / steps_per_rollout / t
        );
    }
    println!(
        "  speed-up of fast over exhaustive: {:.2}x wall time ({:.2}x fewer control steps)",
        slow.0 / fast.0,
        slow.1.steps as f64 / fast.1.steps.max(1) as f64
    );
}
