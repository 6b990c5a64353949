//! Folds, gather inputs and typed input slots: instance naming, gathered members in a fixed
//! order, keys that cover every member, miswired pipelines refused before anything runs, and
//! a damaged or stale input rebuilt instead of failing its consumer.

use std::collections::BTreeMap;

use osms_core::{Artifact, decode};
use osms_make::{Outcome, State};
use osms_store::Hash;
use osms_tests::Project;
use osms_tests::artifacts::{Gathered, Numbers, Total};
use osms_tests::project::{hashes, outcomes};
use serde::Serialize;

const FOLDS: &str = r#"
[pipeline]
seed = 0

[stages.numbers]
kind = "numbers"
params = { n = 7, len = 3 }

[stages.total]
kind = "sum"
inputs = { values = "numbers" }

[stages.part]
kind = "fold_rows"
folds = 2
inputs = { values = "numbers" }

[stages.part_sum]
kind = "sum"
folds = 2
inputs = { values = "part" }

[stages.all]
kind = "gather_totals"
inputs = { totals = "part_sum#*@*" }

[stages.first_fold]
kind = "gather_totals"
inputs = { totals = "part_sum#0@*" }

[stages.per_seed]
kind = "gather_totals"
inputs = { totals = "total@*" }
"#;

fn read<A: Artifact>(p: &Project, hash: &Hash) -> A {
    decode(&p.open_store().get(hash).expect("object")).expect("decodes")
}

#[test]
fn folds_and_gathers_name_order_and_key_every_member() {
    let p = Project::new(FOLDS);
    let report = p.make(None, &[2, 0, 1], 2);
    assert!(report.failed().is_empty(), "{report:?}");
    let h = hashes(&report);
    let names: Vec<&str> = h.keys().map(String::as_str).collect();
    for name in [
        "numbers@0",
        "part#0@0",
        "part#1@2",
        "part_sum#1@1",
        "all",
        "first_fold",
        "per_seed",
    ] {
        assert!(names.contains(&name), "{name} missing from {names:?}");
    }

    // Each fold holds its own rows (row i in fold i mod 2), and the folds split the whole.
    let store = p.open_store();
    let all_rows: Numbers = osms_make::assemble(
        &store.get(&h["numbers@1"]).expect("object"),
        &osms_make::StoreObjects(&store),
    )
    .expect("assemble");
    let fold0: Numbers = read(&p, &h["part#0@1"]);
    let fold1: Numbers = read(&p, &h["part#1@1"]);
    assert_eq!(
        fold0.rows,
        vec![
            all_rows.rows[0].clone(),
            all_rows.rows[2].clone(),
            all_rows.rows[4].clone(),
            all_rows.rows[6].clone()
        ]
    );
    assert_eq!(
        fold1.rows,
        vec![
            all_rows.rows[1].clone(),
            all_rows.rows[3].clone(),
            all_rows.rows[5].clone()
        ]
    );

    // Members in (fold, seed) order, whatever order the seeds were given in.
    let all: Gathered = read(&p, &h["all"]);
    let order: Vec<&str> = all.members.iter().map(|(m, _)| m.as_str()).collect();
    assert_eq!(order, ["#0@0", "#0@1", "#0@2", "#1@0", "#1@1", "#1@2"]);
    let first: Gathered = read(&p, &h["first_fold"]);
    assert_eq!(first.members, all.members[..3]);
    // Independent truth: the two folds of a seed add up to that seed's total.
    let per_seed: Gathered = read(&p, &h["per_seed"]);
    assert_eq!(
        per_seed
            .members
            .iter()
            .map(|(m, _)| m.as_str())
            .collect::<Vec<_>>(),
        ["@0", "@1", "@2"]
    );
    for (i, (_, total)) in per_seed.members.iter().enumerate() {
        let folds = all.members[i].1 + all.members[3 + i].1;
        assert!(
            (folds - total).abs() < 1e-12,
            "seed {i}: {folds} != {total}"
        );
        let t: Total = read(&p, &h[&format!("total@{i}")]);
        assert_eq!(t.sum, *total);
    }

    // A smaller sweep: the per-seed work is cached, the gathers get new keys and rebuild.
    let again = p.make(None, &[0, 1], 1);
    let o = outcomes(&again);
    assert_eq!(o["part_sum#1@1"], "cached");
    for name in ["all", "first_fold", "per_seed"] {
        assert_eq!(o[name], "built", "{name}");
    }
    let k = |r: &osms_make::MakeReport, name: &str| {
        r.instances
            .iter()
            .find(|i| i.instance == name)
            .and_then(|i| i.key)
    };
    assert_ne!(k(&report, "all"), k(&again, "all"));
    let two: Gathered = read(&p, &hashes(&again)["all"]);
    assert_eq!(two.members.len(), 4);

    // The same sweep again: everything cached; status and why see the gathers' members.
    let third = p.make(None, &[0, 1, 2], 2);
    assert!(
        third.instances.iter().all(|r| r.outcome == Outcome::Cached),
        "{third:?}"
    );
    assert_eq!(hashes(&third), h);
    let plan = p.plan(None).expect("plan");
    let store = p.open_store();
    let status = osms_make::status(&plan, &store, &[], &[0, 1, 2]).expect("status");
    assert!(status.iter().all(|s| s.state == State::Cached));
    let lineage = osms_make::why(&plan, &store, "first_fold", &[0, 1, 2]).expect("why");
    let slots: Vec<String> = lineage
        .inputs
        .iter()
        .filter_map(|i| i.slot.clone())
        .collect();
    assert_eq!(slots, ["totals[#0@0]", "totals[#0@1]", "totals[#0@2]"]);
    assert_eq!(lineage.inputs[1].status.instance, "part_sum#0@1");

    // Targets name folds and seeds.
    let ids = plan
        .instances(&["part_sum#1@2".to_string()], &[0, 1, 2])
        .expect("instances");
    let shown: Vec<String> = ids.iter().map(|&id| plan.display(id)).collect();
    assert_eq!(shown, ["numbers@2", "part#1@2", "part_sum#1@2"]);
    let err = plan
        .instances(&["part_sum#2".to_string()], &[0])
        .expect_err("no fold 2");
    assert!(err.to_string().contains("has folds #0 to #1"), "{err}");
}

#[test]
fn folds_draw_from_streams_of_their_own() {
    let p = Project::new(
        "[stages.numbers]\nkind = \"numbers\"\nfolds = 2\nparams = { n = 2 }\n\
         [stages.both]\nkind = \"gather_totals\"\ninputs = { totals = \"sums#*\" }\n\
         [stages.sums]\nkind = \"sum\"\nfolds = 2\ninputs = { values = \"numbers\" }\n",
    );
    let report = p.make(None, &[0], 1);
    let h = hashes(&report);
    assert_ne!(h["numbers#0@0"], h["numbers#1@0"]);
    // A gather over folds only stays per seed.
    let both: Gathered = read(&p, &h["both@0"]);
    assert_eq!(
        both.members
            .iter()
            .map(|(m, _)| m.as_str())
            .collect::<Vec<_>>(),
        ["#0@0", "#1@0"]
    );
}

/// Plans `text`, which must be refused; returns the error text.
fn refused(text: &str) -> String {
    let p = Project::new(text);
    let err = p.plan(None).err().expect("the pipeline must be refused");
    let text = err.to_string();
    assert!(
        text.starts_with(&p.pipeline.display().to_string()),
        "not located: {text}"
    );
    text
}

#[test]
fn miswired_pipelines_are_refused_with_file_and_line() {
    let base = "[stages.numbers]\nkind = \"numbers\"\nparams = { n = 3 }\n\
                [stages.total]\nkind = \"sum\"\ninputs = { values = \"numbers\" }\n";

    // An artifact of the wrong type.
    let err = refused(&format!(
        "{base}[stages.wrong]\nkind = \"signs\"\ninputs = {{ values = \"total\" }}\n"
    ));
    assert!(err.contains(":9:"), "{err}");
    assert!(
        err.contains("input `values` = \"total\": the slot takes a `test.numbers` artifact, but stage `total` (kind `sum`) produces a `test.total`"),
        "{err}"
    );
    assert!(
        err.contains("hint: wire a stage whose kind produces `test.numbers` (`numbers`)"),
        "{err}"
    );

    // A gather reference in a slot that takes one artifact.
    let err = refused(&format!(
        "{base}[stages.wrong]\nkind = \"signs\"\ninputs = {{ values = \"numbers@*\" }}\n"
    ));
    assert!(
        err.contains("takes one artifact, but the reference names several"),
        "{err}"
    );

    // A folded upstream without a fold rule, into a stage without folds.
    let err = refused(&format!(
        "{base}[stages.part]\nkind = \"fold_rows\"\nfolds = 2\ninputs = {{ values = \"numbers\" }}\n\
         [stages.wrong]\nkind = \"sum\"\ninputs = {{ values = \"part\" }}\n"
    ));
    assert!(
        err.contains("stage `part` has 2 folds, and this stage has none"),
        "{err}"
    );
    assert!(err.contains("`part#*`"), "{err}");

    // Folds that do not exist, a fold of a stage without folds, a seed that is not `*`.
    let err = refused(&format!(
        "{base}[stages.part]\nkind = \"fold_rows\"\nfolds = 2\ninputs = {{ values = \"numbers\" }}\n\
         [stages.wrong]\nkind = \"sum\"\ninputs = {{ values = \"part#2\" }}\n"
    ));
    assert!(err.contains("has folds #0 to #1"), "{err}");
    let err = refused(&format!(
        "{base}[stages.wrong]\nkind = \"sum\"\ninputs = {{ values = \"numbers#0\" }}\n"
    ));
    assert!(err.contains("stage `numbers` has no folds"), "{err}");
    let err = refused(&format!(
        "{base}[stages.wrong]\nkind = \"gather_totals\"\ninputs = {{ totals = \"total@3\" }}\n"
    ));
    assert!(
        err.contains("`@3`: an input takes every run seed (`@*`)"),
        "{err}"
    );
    let err = refused(&format!(
        "{base}[stages.wrong]\nkind = \"fold_rows\"\nfolds = 0\ninputs = {{ values = \"numbers\" }}\n"
    ));
    assert!(err.contains("folds must be at least 1"), "{err}");

    // Roles: a slot that takes role `a` refuses `b` and role-less numbers.
    let err = refused(
        "[stages.b]\nkind = \"numbers\"\nparams = { n = 3, role = \"b\" }\n\
         [stages.wrong]\nkind = \"sum_of_a\"\ninputs = { values = \"b\" }\n",
    );
    assert!(
        err.contains("the slot takes role `a`, but stage `b` produces role `b`"),
        "{err}"
    );
    let err = refused(&format!(
        "{base}[stages.wrong]\nkind = \"sum_of_a\"\ninputs = {{ values = \"numbers\" }}\n"
    ));
    assert!(err.contains("produces an artifact without a role"), "{err}");
    let ok = Project::new(
        "[stages.a]\nkind = \"numbers\"\nparams = { n = 3, role = \"a\" }\n\
         [stages.fine]\nkind = \"sum_of_a\"\ninputs = { values = \"a\" }\n",
    );
    ok.plan(None).expect("role a is accepted");
}

#[test]
fn the_shipped_pipeline_refuses_an_artifact_of_the_wrong_type() {
    let shipped = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../pipeline.toml"))
        .expect("pipeline.toml");
    let miswired = shipped.replace(
        "inputs = { world = \"world\", conditions = \"heldout\", teacher = \"teacher\" }",
        "inputs = { world = \"world\", conditions = \"heldout\", teacher = \"eval_scripted\" }",
    );
    assert_ne!(miswired, shipped);
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("pipeline.toml");
    std::fs::write(&path, &miswired).expect("write");
    let pipeline = osms_make::Pipeline::load(&path, None).expect("parses");
    let err = osms_make::Plan::new(&pipeline, &osms_kinds::registry())
        .err()
        .expect("refused")
        .to_string();
    assert!(
        err.contains("the slot takes a `policy.teacher` artifact, but stage `eval_scripted` (kind `eval_scripted`) produces a `sim.evaluation`"),
        "{err}"
    );
}

/// The stat cache's on-disk form (osms-store's `statcache.rs`), to simulate bit rot: damage
/// that leaves the file metadata the cache remembers.
#[derive(Serialize, serde::Deserialize)]
struct StatCacheFile {
    entries: BTreeMap<Hash, StampFile>,
}
#[derive(Serialize, serde::Deserialize)]
struct StampFile {
    len: u64,
    ino: u64,
    mtime_ns: i128,
    ctime_ns: i128,
}

#[test]
fn a_damaged_input_is_rebuilt_rather_than_failing_its_consumer() {
    use std::os::unix::fs::MetadataExt;
    let text = |by: f64| {
        format!(
            "[stages.numbers]\nkind = \"numbers\"\nparams = {{ n = 4 }}\n\
             [stages.shifted]\nkind = \"shift\"\ninputs = {{ values = \"numbers\" }}\nparams = {{ by = {by:?} }}\n"
        )
    };
    let p = Project::new(&text(1.0));
    let first = p.make(None, &[0], 1);
    let numbers = hashes(&first)["numbers@0"];
    let store = p.open_store();
    let path = store.object_path(&numbers);
    let mut bytes = std::fs::read(&path).expect("object");
    let last = bytes.len() - 1;
    bytes[last] ^= 0x5a;
    std::fs::write(&path, &bytes).expect("damage");
    // Bit rot the stat cache cannot see: its entry matches the damaged file's metadata.
    let meta = std::fs::metadata(&path).expect("metadata");
    let cache_path = p.store.join("state").join("statcache");
    let mut cache: StatCacheFile = postcard::from_bytes(
        &std::fs::read(&cache_path).unwrap_or_default(),
    )
    .unwrap_or(StatCacheFile {
        entries: BTreeMap::new(),
    });
    cache.entries.insert(
        numbers,
        StampFile {
            len: meta.len(),
            ino: meta.ino(),
            mtime_ns: i128::from(meta.mtime()) * 1_000_000_000 + i128::from(meta.mtime_nsec()),
            ctime_ns: i128::from(meta.ctime()) * 1_000_000_000 + i128::from(meta.ctime_nsec()),
        },
    );
    std::fs::write(&cache_path, postcard::to_stdvec(&cache).expect("encode")).expect("write cache");

    p.write_pipeline(&text(2.0));
    let second = p.make(None, &[0], 1);
    assert!(second.failed().is_empty(), "{second:?}");
    let o = outcomes(&second);
    assert_eq!(o["numbers@0"], "built");
    assert_eq!(o["shifted@0"], "built");
    assert_eq!(
        second.instances.len(),
        2,
        "each instance reported once: {second:?}"
    );
    assert_eq!(
        hashes(&second)["numbers@0"],
        numbers,
        "the rebuild reproduces the bytes"
    );
    p.open_store()
        .get(&numbers)
        .expect("the object is whole again");
}

#[test]
fn a_scripted_evaluation_without_domain_randomisation_is_shared_by_a_sweep() {
    let shipped = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../pipeline.toml"))
        .expect("pipeline.toml");
    let plan_of = |text: &str| {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("pipeline.toml");
        std::fs::write(&path, text).expect("write");
        let pipeline = osms_make::Pipeline::load(&path, Some("tiny")).expect("parses");
        osms_make::Plan::new(&pipeline, &osms_kinds::registry()).expect("plans")
    };
    let names = |plan: &osms_make::Plan| -> Vec<String> {
        plan.instances(&["eval_scripted".to_string()], &[0, 1, 2])
            .expect("instances")
            .into_iter()
            .map(|id| plan.display(id))
            .filter(|n| n.starts_with("eval_scripted"))
            .collect()
    };
    // Shipped, it has a fixed seed: one build for every run seed.
    assert_eq!(names(&plan_of(&shipped)), ["eval_scripted"]);
    let fixed = "[stages.eval_scripted]\nkind = \"eval_scripted\"\nseed = 0\n";
    assert!(shipped.contains(fixed));
    let run_seeded = shipped.replace(fixed, "[stages.eval_scripted]\nkind = \"eval_scripted\"\n");
    assert_eq!(
        names(&plan_of(&run_seeded)),
        ["eval_scripted@0", "eval_scripted@1", "eval_scripted@2"]
    );
    let off = run_seeded.replace(
        "params = { rollout = { dr = \"paper\" } }",
        "params = { rollout = { dr = \"off\" } }",
    );
    assert_ne!(off, run_seeded);
    assert_eq!(names(&plan_of(&off)), ["eval_scripted"]);
}

#[test]
fn the_cli_names_folds_and_gathered_members() {
    let p = Project::new(FOLDS);
    let bin = std::path::Path::new(env!("CARGO_BIN_EXE_osms-test"));
    let run = |args: &[&str]| {
        let out = p.run(bin, args);
        let text = String::from_utf8_lossy(&out.stdout).into_owned()
            + &String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "osms {args:?} failed:\n{text}");
        text
    };
    run(&["make", "--seeds", "0,1", "-q"]);
    let status = run(&["status", "--seeds", "0,1", "--json"]);
    let status: serde_json::Value = serde_json::from_str(&status).expect("json");
    let names: Vec<&str> = status
        .as_array()
        .expect("a list")
        .iter()
        .filter_map(|s| s["instance"].as_str())
        .collect();
    for name in ["part#0@0", "part_sum#1@1", "all"] {
        assert!(names.contains(&name), "{name} not in {names:?}");
    }
    let why = run(&["why", "first_fold", "--seeds", "0,1"]);
    assert!(why.contains("totals[#0@1]: part_sum#0@1 [sum]"), "{why}");
    let show = run(&["show", "part#1@1", "--json"]);
    let shown: serde_json::Value = serde_json::from_str(&show).expect("json");
    assert_eq!(shown["fold"], 1, "{show}");
    // A sweep the gathers were not built for: they are not up to date; the rest is.
    let other = run(&["status", "--seeds", "0,1,2"]);
    assert!(
        other.contains("stale    all: input `part_sum#0@2` is not up to date"),
        "{other}"
    );
}

#[test]
fn an_optional_slot_may_be_left_unwired() {
    let text = "[stages.numbers]\nkind = \"numbers\"\nparams = { n = 3, len = 2 }\n\
                [stages.total]\nkind = \"sum\"\ninputs = { values = \"numbers\" }\n\
                [stages.plain]\nkind = \"offset\"\ninputs = { values = \"numbers\" }\n\
                [stages.shifted]\nkind = \"offset\"\ninputs = { values = \"numbers\", offset = \"total\" }\n";
    let p = Project::new(text);
    let report = p.make(None, &[0], 1);
    assert!(report.failed().is_empty(), "{report:?}");
    let h = hashes(&report);
    let store = p.open_store();
    let numbers: Numbers = osms_make::assemble(
        &store.get(&h["numbers@0"]).expect("object"),
        &osms_make::StoreObjects(&store),
    )
    .expect("assemble");
    let total: Total = read(&p, &h["total@0"]);
    let plain: Numbers = read(&p, &h["plain@0"]);
    let shifted: Numbers = read(&p, &h["shifted@0"]);
    assert_eq!(plain, numbers, "unwired: nothing added");
    for (s, n) in shifted
        .rows
        .iter()
        .flatten()
        .zip(numbers.rows.iter().flatten())
    {
        assert_eq!(*s, n + total.sum);
    }

    // A required slot is still required.
    let err = refused(
        "[stages.numbers]\nkind = \"numbers\"\nparams = { n = 3 }\n\
                       [stages.wrong]\nkind = \"offset\"\ninputs = { offset = \"numbers\" }\n",
    );
    assert!(err.contains("is missing input `values`"), "{err}");
}

/// Keeps the notes a make prints (the stale-artifact warning is one).
#[derive(Default)]
struct Notes(std::sync::Mutex<Vec<String>>);
impl osms_make::Observer for Notes {
    fn note(&self, text: &str) {
        self.0.lock().expect("notes").push(text.to_string());
    }
    fn started(&self, _: &str, _: &str) -> Box<dyn osms_make::Progress + '_> {
        Box::new(osms_make::NoProgress)
    }
    fn finished(&self, _: &osms_make::InstanceReport) {}
}

#[test]
fn a_stale_input_is_reported_once_and_rebuilt_rather_than_failing_its_consumers() {
    // `shifted` feeds two consumers; its cached artifact is made stale, then both must run.
    let text = |by: f64| {
        format!(
            "[stages.numbers]\nkind = \"numbers\"\nparams = {{ n = 4 }}\n\
             [stages.shifted]\nkind = \"shift\"\ninputs = {{ values = \"numbers\" }}\nparams = {{ by = 1.0 }}\n\
             [stages.a]\nkind = \"shift\"\ninputs = {{ values = \"shifted\" }}\nparams = {{ by = {by:?} }}\n\
             [stages.b]\nkind = \"shift\"\ninputs = {{ values = \"shifted\" }}\nparams = {{ by = {:?} }}\n",
            by + 10.0
        )
    };
    let clean = Project::new(&text(2.0));
    let clean = hashes(&clean.make(None, &[0], 1));
    let p = Project::new(&text(1.0));
    let first = p.make(None, &[0], 1);
    let shifted = first
        .instances
        .iter()
        .find(|r| r.instance == "shifted@0")
        .expect("shifted");

    // What an older osms would have stored under the same type tag and schema version, before
    // the type's layout changed: it does not decode as today's `Numbers`.
    #[derive(Serialize, serde::Deserialize)]
    struct OldNumbers {
        rows: u32,
    }
    impl Artifact for OldNumbers {
        const TYPE_TAG: &'static str = Numbers::TYPE_TAG;
        const SCHEMA_VERSION: u16 = Numbers::SCHEMA_VERSION;
    }
    let old = osms_core::encode(&OldNumbers { rows: 7 }).expect("encode");
    assert!(
        decode::<Numbers>(&old).is_err(),
        "the planted bytes must be stale"
    );
    let store = p.open_store();
    let planted = store.put(&old).expect("put");
    let mut record = store
        .record(&shifted.key.expect("key"))
        .expect("read")
        .expect("record");
    record.content_hash = planted;
    record.size_bytes = old.len() as u64;
    store.put_record(&record).expect("plant");

    p.write_pipeline(&text(2.0));
    let plan = p.plan(None).expect("plan");
    let notes = Notes::default();
    let opts = osms_make::MakeOptions {
        targets: vec![],
        seeds: vec![0],
        jobs: 1,
        stages: 1,
        dry_run: false,
    };
    let second = osms_make::make(&plan, &p.open_store(), &opts, &notes).expect("make");
    assert!(second.failed().is_empty(), "{second:?}");
    let notes = notes.0.into_inner().expect("notes");
    let stale: Vec<&String> = notes
        .iter()
        .filter(|n| n.contains("does not decode"))
        .collect();
    assert_eq!(stale.len(), 1, "reported once, not per consumer: {notes:?}");
    assert!(
        stale[0].contains("stage `shifted@0`")
            && stale[0].contains(&format!("`{}`", Numbers::TYPE_TAG))
            && stale[0].contains(&planted.short())
            && stale[0].contains("rebuilding it"),
        "{}",
        stale[0]
    );
    let o = outcomes(&second);
    assert_eq!(o["shifted@0"], "built");
    assert_eq!((o["a@0"], o["b@0"]), ("built", "built"));
    assert_eq!(
        second.instances.len(),
        4,
        "each instance reported once: {second:?}"
    );
    assert_eq!(hashes(&second), clean, "the same bytes as a clean build");
    let third = p.make(None, &[0], 1);
    assert!(
        outcomes(&third).values().all(|o| *o == "cached"),
        "{third:?}"
    );
}
