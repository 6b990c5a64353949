//! Overrides and the development stream through the library: an override rebuilds exactly
//! what it reaches, reverting it builds nothing, and the shipped development stream shares no
//! condition with the held-out set.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use osms_make::overrides::Override;
use osms_make::{MakeOptions, MakeReport, Outcome, Pipeline, Plan};
use osms_sim::artifacts::Conditions;
use osms_store::Store;
use osms_tests::Project;
use osms_tests::project::{Silent, outcomes};

fn make_with(p: &Project, overrides: &[&str]) -> MakeReport {
    let mut pipeline = Pipeline::load(&p.pipeline, None).expect("load");
    let overrides: Vec<Override> = overrides
        .iter()
        .map(|o| o.parse().expect("override"))
        .collect();
    pipeline.apply(&overrides).expect("apply");
    let plan = Plan::new(&pipeline, &p.registry).expect("plan");
    let opts = MakeOptions {
        targets: vec![],
        seeds: vec![0],
        jobs: 2,
        stages: 1,
        dry_run: false,
    };
    osms_make::make(&plan, &p.open_store(), &opts, &Silent).expect("make")
}

#[test]
fn an_override_rebuilds_exactly_what_it_reaches_and_reverting_it_builds_nothing() {
    let p = Project::engine();
    let first = make_with(&p, &[]);
    assert!(first.failed().is_empty());
    let scaled = outcomes(&make_with(&p, &["numbers.scale=2.0"]));
    let expected: BTreeMap<String, &str> = [
        // numbers changes; signs sees new input bytes, so it runs, and gives the same signs;
        // so sign_total is cut off. total and report read the new numbers.
        ("numbers@0", "built"),
        ("signs@0", "built"),
        ("sign_total@0", "cut off"),
        ("total@0", "built"),
        ("report@0", "built"),
        // Not downstream of numbers: untouched.
        ("reference", "cached"),
        ("drops@0", "cached"),
    ]
    .map(|(k, v)| (k.to_string(), v))
    .into();
    assert_eq!(scaled, expected);
    // A param of the shared `drops` only: its consumer rebuilds, nothing upstream does.
    let drops = outcomes(&make_with(&p, &["drops.steps=350"]));
    let rebuilt: BTreeSet<&str> = drops
        .iter()
        .filter(|(_, o)| **o == "built")
        .map(|(i, _)| i.as_str())
        .collect();
    assert_eq!(rebuilt, BTreeSet::from(["drops@0", "report@0"]));
    // Reverting is a no-op make: every variant's artifacts are still in the store.
    let reverted = make_with(&p, &[]);
    assert!(
        reverted
            .instances
            .iter()
            .all(|i| matches!(i.outcome, Outcome::Cached)),
        "{:?}",
        outcomes(&reverted)
    );
}

fn shipped_plan(profile: &str) -> (Plan, tempfile::TempDir, Store) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml");
    let plan = Plan::new(
        &Pipeline::load(&path, Some(profile)).expect("load"),
        &osms_kinds::registry(),
    )
    .expect("plan");
    let dir = tempfile::tempdir().expect("dir");
    let store = Store::open(dir.path().join("store")).expect("store");
    (plan, dir, store)
}

fn build(plan: &Plan, store: &Store, targets: &[&str]) -> BTreeMap<String, osms_store::Hash> {
    let opts = MakeOptions {
        targets: targets.iter().map(|t| t.to_string()).collect(),
        seeds: vec![0],
        jobs: 2,
        stages: 1,
        dry_run: false,
    };
    let report = osms_make::make(plan, store, &opts, &Silent).expect("make");
    assert!(report.failed().is_empty(), "{:?}", report.failed());
    osms_tests::project::hashes(&report)
}

/// The shipped pipeline under `profile`.
fn shipped_pipeline(profile: &str) -> Pipeline {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml");
    Pipeline::load(&path, Some(profile)).expect("load")
}

/// What decides a stage's builds, stage by stage.
fn stage_spec(p: &Pipeline) -> Vec<String> {
    p.stages
        .values()
        .map(|s| {
            format!(
                "{} {} {:?} {:?} {} {:?} {:?}",
                s.name, s.kind, s.inputs, s.params, s.shards, s.folds, s.fixed_seed
            )
        })
        .collect()
}

#[test]
fn the_decide_profile_is_small_with_twenty_six_run_seeds() {
    // Same stages, params and seeds as small, so its first three run seeds are small's builds.
    let (small, decide) = (shipped_pipeline("small"), shipped_pipeline("decide"));
    assert_eq!(stage_spec(&small), stage_spec(&decide));
    assert_eq!(small.default_seeds, [0, 1, 2]);
    assert_eq!(decide.default_seeds, (0..26).collect::<Vec<u64>>());
}

#[test]
fn the_de4k_profile_is_small_at_the_data_curves_four_thousand_point() {
    // The profile and `curve-pibar-4k` (scripts/issue74-experiments) must set the same params,
    // so the profile's π̄ builds are the curve point's, and everything else is small's.
    let de4k = shipped_pipeline("de4k");
    let mut curve = shipped_pipeline("small");
    let overrides: Vec<Override> = ["d_e.n=8000", "student_il.steps=60000"]
        .iter()
        .map(|o| o.parse().expect("override"))
        .collect();
    curve.apply(&overrides).expect("apply");
    assert_eq!(stage_spec(&de4k), stage_spec(&curve));
    assert_ne!(stage_spec(&de4k), stage_spec(&shipped_pipeline("small")));
    assert_eq!(de4k.default_seeds, [0, 1, 2]);
    let script = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/issue74-experiments"),
    )
    .expect("script");
    assert!(
        script.contains("curve-pibar-4k --set d_e.n=8000 --set student_il.steps=60000 "),
        "curve-pibar-4k's settings changed: change [profiles.de4k] with them"
    );
}

#[test]
fn the_development_stream_shares_no_condition_with_the_held_out_set() {
    // The paper profile's sizes: all 3,000 held-out conditions against all 500 of the stream.
    let (plan, _dir, store) = shipped_plan("paper");
    let hashes = build(&plan, &store, &["heldout", "dev"]);
    let load = |name: &str| -> Conditions {
        let objects = osms_make::StoreObjects(&store);
        osms_make::assemble(&store.get(&hashes[name]).expect("object"), &objects)
            .expect("conditions")
    };
    let (heldout, dev) = (load("heldout"), load("dev"));
    assert_eq!((heldout.items.len(), dev.items.len()), (3000, 500));
    let bytes = |c: &osms_sim::TaskCondition| postcard::to_stdvec(c).expect("encode");
    let held: BTreeSet<Vec<u8>> = heldout.items.iter().map(bytes).collect();
    assert_eq!(held.len(), 3000, "the held-out set repeats a condition");
    let shared = dev
        .items
        .iter()
        .filter(|c| held.contains(&bytes(c)))
        .count();
    assert_eq!(shared, 0, "{shared} development conditions are held out");
    // Not even one ω component (the launch, say) coincides.
    let launches: BTreeSet<String> = heldout
        .items
        .iter()
        .map(|c| format!("{:?}", c.launch_vel_mps))
        .collect();
    assert!(
        dev.items
            .iter()
            .all(|c| !launches.contains(&format!("{:?}", c.launch_vel_mps)))
    );
}

#[test]
fn evaluate_rolls_out_the_scripted_catcher_as_eval_scripted_does() {
    // The same params, seed and stage name under the two kinds give the same rows.
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml"))
            .expect("pipeline.toml");
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("pipeline.toml");
    let store = Store::open(dir.path().join("store")).expect("store");
    let mut made = Vec::new();
    for kind in ["evaluate", "eval_scripted"] {
        let variant = text.replacen(
            "[stages.dev_scripted]\nkind = \"evaluate\"",
            &format!("[stages.dev_scripted]\nkind = \"{kind}\""),
            1,
        );
        assert_ne!(kind == "eval_scripted", variant == text);
        std::fs::write(&path, variant).expect("write");
        let plan = Plan::new(
            &Pipeline::load(&path, Some("tiny")).expect("load"),
            &osms_kinds::registry(),
        )
        .expect("plan");
        made.push(build(&plan, &store, &["dev_scripted"])["dev_scripted"]);
    }
    assert_eq!(made[0], made[1]);
}
