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

struct Made {
    hashes: BTreeMap<String, Hash>,
    outputs: Vec<golden::Output>,
    plan: Plan,
    store: Store,
    _dir: tempfile::TempDir,
}

fn make(text: &str, jobs: usize) -> Made {
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
    Made {
        hashes: hashes(&report),
        outputs: golden::outputs(&plan, &report),
        plan,
        store,
        _dir: dir,
    }
}

fn load<A: osms_store::Artifact>(made: &Made, instance: &str) -> A {
    let hash = made
        .hashes
        .get(instance)
        .unwrap_or_else(|| panic!("{instance} built"));
    osms_store::decode(&made.store.get(hash).expect("object")).expect("decode")
}

#[test]
fn tiny_outputs_do_not_depend_on_threads_or_shards_and_match_the_golden_hashes() {
    let text = shipped();
    let first = make(&text, 1);
    let reference = first.hashes.clone();
    assert_eq!(reference.len(), 11, "{reference:?}");
    datasets_are_disjoint_successes_and_aligned(&first);
    a_damaged_dataset_shard_is_detected_and_rebuilt(&first);
    assert_eq!(make(&text, 2).hashes, reference, "1 vs 2 threads");
    let reshard = text
        .replace(
            "params = { n = 40 }\nshards = 2",
            "params = { n = 40 }\nshards = 5",
        )
        .replace(
            "inputs = { world = \"world\", conditions = \"heldout\" }\nshards = 4",
            "inputs = { world = \"world\", conditions = \"heldout\" }\nshards = 3",
        )
        .replace(
            "params = { n = 6 }\nshards = 2",
            "params = { n = 6 }\nshards = 4",
        );
    assert_eq!(
        (
            reshard.matches("shards = 5").count(),
            reshard.matches("shards = 3").count(),
            reshard.matches("params = { n = 6 }\nshards = 4").count()
        ),
        (1, 1, 2),
        "the overlays were edited"
    );
    assert_eq!(make(&reshard, 2).hashes, reference, "other shard counts");
    golden::check("outputs_pipeline_tiny", first.outputs);
}

/// D_M and D_E hold successes only; no ω is shared between D_M, D_E, D_R and the held-out set;
/// every OSW window is the teacher's arm actions of the H_OS steps before k_e.
fn datasets_are_disjoint_successes_and_aligned(made: &Made) {
    use osms_policy::dataset::Dataset;
    use osms_sim::N_ARM;
    use osms_sim::stages::Conditions;

    let heldout: Conditions = load(made, "heldout");
    let mut seen: Vec<(String, String)> = heldout
        .items
        .iter()
        .map(|c| ("heldout".to_string(), format!("{c:?}")))
        .collect();
    for name in ["d_m@0", "d_e@0", "d_r@0"] {
        let d: Dataset = load(made, name);
        let stats = d.stats();
        assert!(!d.items.is_empty(), "{name} is empty");
        if name != "d_r@0" {
            assert!(d.successes_only, "{name}");
            assert!(
                d.rollouts().all(|r| r.record.outcome.success()),
                "{name} holds a failure"
            );
            assert!(stats.attempts >= d.items.len() as u64);
        } else {
            assert_eq!(
                stats.attempts,
                d.items.len() as u64,
                "D_R keeps every attempt"
            );
        }
        for r in d.rollouts() {
            let c = format!("{:?}", r.record.condition);
            if let Some((other, _)) = seen.iter().find(|(_, s)| *s == c) {
                panic!("{name} item {} shares ω with {other}", r.item);
            }
            seen.push((name.to_string(), c));
            let w = &r.osw;
            assert_eq!(w.event_step, r.record.metrics.event_step);
            assert_eq!(w.complete, w.event_step >= d.osw.h_os);
            assert_eq!(w.zeta_org.len(), (w.event_step - w.start) * N_ARM);
            let k = w.start;
            if k < w.event_step {
                assert_eq!(
                    &w.zeta_org[..N_ARM],
                    &r.record.intended[k * osms_sim::N_ACTION..k * osms_sim::N_ACTION + N_ARM]
                );
            }
        }
    }
}

/// Damage one stored shard of D_M and the merged artifact: the next make detects both,
/// recomputes the shard and rebuilds D_M to the same bytes.
fn a_damaged_dataset_shard_is_detected_and_rebuilt(made: &Made) {
    let d_m = made.hashes["d_m@0"];
    let (records, _) = made.store.records().expect("records");
    let key = records
        .iter()
        .find(|r| r.content_hash == d_m && r.shard.is_none())
        .expect("d_m record")
        .key;
    let shard = records
        .iter()
        .find(|r| r.shard.as_ref().is_some_and(|s| s.stage_key == key))
        .expect("a stored shard of d_m");
    for hash in [shard.content_hash, d_m] {
        let path = made.store.object_path(&hash);
        let mut bytes = std::fs::read(&path).expect("read");
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x10;
        std::fs::write(&path, bytes).expect("write");
    }
    assert!(
        !made.store.verify().expect("verify").problems.is_empty(),
        "verify sees the damage"
    );
    let opts = MakeOptions {
        targets: vec!["d_m".into()],
        seeds: vec![0],
        jobs: 2,
        dry_run: false,
    };
    let report = osms_make::make(&made.plan, &made.store, &opts, &Silent).expect("make");
    assert!(report.failed().is_empty(), "{:?}", report.failed());
    assert_eq!(hashes(&report)["d_m@0"], d_m, "rebuilt to the same bytes");
    assert!(
        made.store.verify().expect("verify").problems.is_empty(),
        "shard and D_M repaired"
    );
}
