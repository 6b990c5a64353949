//! The engine through the library: identity under reruns, threads and shards; early cutoff;
//! seed sweeps; status reasons; failures; and every kind of bad pipeline declaration.

use osms_make::{ItemStage, Kind, MakeOptions, Reason, Registry, State};
use osms_tests::project::{ENGINE_PIPELINE, Silent, first_failure, hashes, outcomes};
use osms_tests::stages::{NumbersKind, NumbersParams};
use osms_tests::{Project, registry};

fn with_shards(numbers: u32, drops: u32) -> String {
    ENGINE_PIPELINE
        .replace(
            "[stages.numbers]\nkind = \"numbers\"\nshards = 3",
            &format!("[stages.numbers]\nkind = \"numbers\"\nshards = {numbers}"),
        )
        .replace(
            "[stages.drops]\nkind = \"drop\"\nshards = 2",
            &format!("[stages.drops]\nkind = \"drop\"\nshards = {drops}"),
        )
}

#[test]
fn outputs_do_not_depend_on_rerun_threads_or_shards() {
    let reference = Project::engine();
    let r1 = reference.make(Some("tiny"), &[0], 1);
    let h1 = hashes(&r1);
    assert_eq!(h1.len(), 7, "{h1:?}");

    let two_threads = Project::engine();
    assert_eq!(
        hashes(&two_threads.make(Some("tiny"), &[0], 2)),
        h1,
        "1 vs 2 threads"
    );

    let concurrent = Project::engine();
    assert_eq!(
        hashes(&concurrent.make_with_stages(Some("tiny"), &[0], 2, 2)),
        h1,
        "two stages at a time"
    );

    for (numbers, drops) in [(1, 1), (5, 4), (6, 3)] {
        let text = with_shards(numbers, drops);
        assert_ne!(text, ENGINE_PIPELINE);
        let p = Project::new(&text);
        assert_eq!(
            hashes(&p.make(Some("tiny"), &[0], 2)),
            h1,
            "{numbers} and {drops} shards"
        );
    }

    // A rerun into a fresh store rebuilds every byte identically, keys included.
    std::fs::remove_dir_all(&reference.store).expect("remove store");
    let r2 = reference.make(Some("tiny"), &[0], 2);
    assert!(outcomes(&r2).values().all(|o| *o == "built"));
    assert_eq!(hashes(&r2), h1);
    let keys = |r: &osms_make::MakeReport| {
        r.instances
            .iter()
            .map(|i| (i.instance.clone(), i.key))
            .collect::<Vec<_>>()
    };
    assert_eq!(keys(&r1), keys(&r2));
}

#[test]
fn a_second_make_finds_everything_cached() {
    let p = Project::engine();
    let first = p.make(Some("tiny"), &[0], 2);
    let second = p.make(Some("tiny"), &[0], 2);
    assert!(
        outcomes(&second).values().all(|o| *o == "cached"),
        "{:?}",
        outcomes(&second)
    );
    assert_eq!(hashes(&first), hashes(&second));
}

#[test]
fn changing_a_shard_count_rebuilds_nothing() {
    let p = Project::engine();
    let first = p.make(Some("tiny"), &[0], 2);
    p.write_pipeline(&with_shards(2, 1));
    let second = p.make(Some("tiny"), &[0], 2);
    assert!(
        outcomes(&second).values().all(|o| *o == "cached"),
        "{:?}",
        outcomes(&second)
    );
    assert_eq!(hashes(&first), hashes(&second));
}

#[test]
fn an_upstream_rebuild_with_identical_bytes_cuts_off_downstream() {
    let p = Project::engine();
    let before = p.make(Some("tiny"), &[0], 2);
    // Doubling the scale changes every value but no sign.
    p.write_pipeline(&ENGINE_PIPELINE.replace("scale = 1.0", "scale = 2.0"));
    let after = p.make(Some("tiny"), &[0], 2);
    let o = outcomes(&after);
    assert_eq!(o["numbers@0"], "built");
    assert_eq!(o["signs@0"], "built");
    assert_eq!(o["sign_total@0"], "cut off");
    assert_eq!(o["total@0"], "built");
    assert_eq!(o["drops@0"], "cached");
    assert_eq!(o["reference"], "cached");
    let (hb, ha) = (hashes(&before), hashes(&after));
    assert_eq!(hb["signs@0"], ha["signs@0"]);
    assert_ne!(hb["numbers@0"], ha["numbers@0"]);
}

#[test]
fn seed_sweeps_instantiate_the_seeded_part_once_per_seed_and_share_the_rest() {
    let p = Project::engine();
    let sweep = p.make(Some("tiny"), &[0, 1, 2], 2);
    let h = hashes(&sweep);
    // Six seed-dependent stages per seed, and `reference`, whose seed is fixed, once.
    assert_eq!(h.len(), 3 * 6 + 1, "{:?}", h.keys());
    assert!(h.contains_key("reference") && !h.contains_key("reference@0"));
    assert_ne!(h["numbers@0"], h["numbers@1"]);
    assert_ne!(h["numbers@1"], h["numbers@2"]);
    assert_ne!(h["drops@0"], h["drops@1"]);

    let single = p.make(Some("tiny"), &[1], 1);
    assert!(outcomes(&single).values().all(|o| *o == "cached"));
    let fresh = Project::engine();
    let alone = hashes(&fresh.make(Some("tiny"), &[2], 1));
    for (name, hash) in alone {
        assert_eq!(h[&name], hash, "{name} in a sweep vs alone");
    }
}

#[test]
fn a_target_with_a_seed_builds_that_instance_only() {
    let p = Project::engine();
    let plan = p.plan(Some("tiny")).expect("plan");
    let opts = MakeOptions {
        targets: vec!["total@2".into(), "reference".into()],
        seeds: vec![0, 1],
        jobs: 2,
        stages: 1,
        dry_run: false,
    };
    let report = osms_make::make(&plan, &p.open_store(), &opts, &Silent).expect("make");
    let names: Vec<&str> = report
        .instances
        .iter()
        .map(|r| r.instance.as_str())
        .collect();
    assert_eq!(names, ["numbers@2", "reference", "total@2"]);
    let opts = MakeOptions {
        targets: vec!["total@two".into()],
        seeds: vec![0],
        jobs: 1,
        stages: 1,
        dry_run: false,
    };
    let err = osms_make::make(&plan, &p.open_store(), &opts, &Silent).expect_err("bad seed");
    assert!(err.to_string().contains("`two` is not a seed"), "{err}");
}

#[test]
fn dry_run_builds_nothing_and_says_what_would_run() {
    let p = Project::engine();
    let plan = p.plan(Some("tiny")).expect("plan");
    let opts = MakeOptions {
        targets: vec!["total".into()],
        seeds: vec![0],
        jobs: 1,
        stages: 1,
        dry_run: true,
    };
    let report = osms_make::make(&plan, &p.open_store(), &opts, &Silent).expect("dry run");
    let o = outcomes(&report);
    assert_eq!(
        o.len(),
        2,
        "target `total` needs numbers and total only: {o:?}"
    );
    assert!(o.values().all(|v| *v == "would build"));
    assert!(p.open_store().records().expect("records").0.is_empty());
}

/// `numbers` at code version 2, to check that a bump is seen as one.
struct NumbersV2;
impl Kind for NumbersV2 {
    const KIND: &'static str = "numbers";
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = true;
    const INPUTS: &'static [osms_make::Slot] = &[];
    const DOC: &'static str = "numbers, bumped";
    type Params = NumbersParams;
}

impl ItemStage for NumbersV2 {
    type Prepared = ();
    type Item = Vec<f64>;
    type Output = osms_tests::artifacts::Numbers;
    fn prepare(
        &self,
        ctx: &osms_make::Ctx<'_, NumbersParams>,
    ) -> Result<(), osms_make::StageError> {
        NumbersKind.prepare(ctx)
    }
    fn n_items(&self, ctx: &osms_make::Ctx<'_, NumbersParams>, p: &()) -> usize {
        NumbersKind.n_items(ctx, p)
    }
    fn run_item(
        &self,
        ctx: &osms_make::Ctx<'_, NumbersParams>,
        p: &(),
        i: usize,
        rng: &mut osms_core::rng::StreamRng,
    ) -> Result<Vec<f64>, osms_make::StageError> {
        NumbersKind.run_item(ctx, p, i, rng)
    }
    fn merge(
        &self,
        ctx: &osms_make::Ctx<'_, NumbersParams>,
        p: (),
        items: Vec<Vec<f64>>,
    ) -> Result<osms_tests::artifacts::Numbers, osms_make::StageError> {
        NumbersKind.merge(ctx, p, items)
    }
}

#[test]
fn status_names_why_each_stage_would_run() {
    let mut p = Project::engine();
    let store = p.open_store();
    let status = |p: &Project| {
        let plan = p.plan(Some("tiny")).expect("plan");
        osms_make::status(&plan, &store, &[], &[0]).expect("status")
    };
    let fresh = status(&p);
    assert!(fresh.iter().all(|s| s.state == State::Missing));
    assert_eq!(
        fresh
            .iter()
            .find(|s| s.instance == "numbers@0")
            .map(|s| s.reasons.clone()),
        Some(vec![Reason::New])
    );

    p.make(Some("tiny"), &[0], 2);
    assert!(status(&p).iter().all(|s| s.state == State::Cached));

    p.write_pipeline(&ENGINE_PIPELINE.replace("params = { n = 6 }", "params = { n = 7 }"));
    let changed = status(&p);
    let numbers = changed
        .iter()
        .find(|s| s.instance == "numbers@0")
        .expect("numbers");
    assert_eq!(numbers.state, State::Stale);
    match &numbers.reasons[..] {
        [Reason::ParamsChanged { changes }] => {
            assert_eq!(changes.len(), 1);
            assert_eq!(changes[0].param, "n");
            assert_eq!(
                (changes[0].old.clone(), changes[0].new.clone()),
                (Some(6.into()), Some(7.into()))
            );
        }
        other => panic!("expected a param change, got {other:?}"),
    }
    let total = changed
        .iter()
        .find(|s| s.instance == "total@0")
        .expect("total");
    assert_eq!(
        total.reasons,
        vec![Reason::UpstreamNotUpToDate {
            input: "numbers@0".into()
        }]
    );
    assert_eq!(
        changed
            .iter()
            .find(|s| s.instance == "drops@0")
            .map(|s| s.state),
        Some(State::Cached)
    );

    p.write_pipeline(ENGINE_PIPELINE);
    // The test registry with `numbers` at version 2.
    p.registry = registry_with(NumbersV2);
    let after_bump = status(&p);
    let numbers = after_bump
        .iter()
        .find(|s| s.instance == "numbers@0")
        .expect("numbers");
    assert_eq!(
        numbers.reasons,
        vec![Reason::CodeVersionBumped { old: 1, new: 2 }]
    );
    // `reference` is also a `numbers` stage.
    assert_eq!(
        after_bump
            .iter()
            .find(|s| s.instance == "reference")
            .map(|s| s.state),
        Some(State::Stale)
    );
}

/// Counts the builds in flight (started, not yet finished) and the most at once.
#[derive(Default)]
struct InFlight {
    started: std::sync::Mutex<std::collections::BTreeSet<String>>,
    most: std::sync::atomic::AtomicUsize,
}
impl osms_make::Observer for InFlight {
    fn started(&self, instance: &str, _: &str) -> Box<dyn osms_make::Progress + '_> {
        let mut started = self.started.lock().expect("in flight");
        started.insert(instance.to_string());
        self.most
            .fetch_max(started.len(), std::sync::atomic::Ordering::SeqCst);
        Box::new(osms_make::NoProgress)
    }
    fn finished(&self, report: &osms_make::InstanceReport) {
        self.started
            .lock()
            .expect("in flight")
            .remove(&report.instance);
    }
}

#[test]
fn building_several_stages_at_once_changes_no_byte_and_no_outcome() {
    let seeds = [0, 1, 2];
    let one = Project::engine();
    let sequential = one.make(Some("tiny"), &seeds, 2);
    // Seven instances need no input (numbers, drops at three seeds, reference), so a make of
    // N ≤ 4 stages starts N of them before the first ends: N builds in flight at once.
    for (jobs, stages) in [(2, 2), (3, 3), (4, 4)] {
        let p = Project::engine();
        let observer = InFlight::default();
        let report = p.make_observed(Some("tiny"), &seeds, jobs, stages, &observer);
        assert_eq!(
            observer.most.load(std::sync::atomic::Ordering::SeqCst),
            stages,
            "{jobs} threads, {stages} stages: builds in flight at once"
        );
        assert_eq!(
            hashes(&report),
            hashes(&sequential),
            "{jobs} threads, {stages} stages"
        );
        assert_eq!(outcomes(&report), outcomes(&sequential));
        // Each instance exactly once, and after its inputs.
        let order: Vec<&str> = report
            .instances
            .iter()
            .map(|r| r.instance.as_str())
            .collect();
        assert_eq!(order.len(), sequential.instances.len(), "{order:?}");
        let position = |name: &str| order.iter().position(|n| *n == name).expect(name);
        for seed in seeds {
            assert!(position(&format!("numbers@{seed}")) < position(&format!("total@{seed}")));
            assert!(position(&format!("total@{seed}")) < position(&format!("report@{seed}")));
        }
        let again = p.make_with_stages(Some("tiny"), &seeds, jobs, stages);
        assert!(
            outcomes(&again).values().all(|o| *o == "cached"),
            "{again:?}"
        );
    }
}

/// Two stages of one definition have one key: at any number of stages one builds and the
/// other finds it cached (two builds at once would double the work and could race), and the
/// report lists instances in plan order however the builds interleave.
#[test]
fn instances_that_share_a_key_build_once_at_any_number_of_stages() {
    let pipeline = format!(
        "{ENGINE_PIPELINE}\n[stages.total_again]\nkind = \"sum\"\ninputs = {{ values = \"numbers\" }}\n"
    );
    for stages in [1, 2, 4] {
        let p = Project::new(&pipeline);
        let report = p.make_with_stages(Some("tiny"), &[0], 4, stages);
        let o = outcomes(&report);
        // The second finds the first's artifact: "cut off", as any cached instance whose
        // input this make built.
        let pair = [o["total@0"], o["total_again@0"]];
        assert!(
            pair == ["built", "cut off"] || pair == ["cut off", "built"],
            "{stages} stages: {pair:?}"
        );
        let keys: Vec<_> = ["total@0", "total_again@0"]
            .iter()
            .map(|n| {
                report
                    .instances
                    .iter()
                    .find(|r| r.instance == *n)
                    .and_then(|r| r.key)
            })
            .collect();
        assert_eq!(keys[0], keys[1], "one definition, one key");
        let plan = p.plan(Some("tiny")).expect("plan");
        let planned: Vec<String> = plan
            .instances(&[], &[0])
            .expect("instances")
            .into_iter()
            .map(|id| plan.display(id))
            .collect();
        let reported: Vec<String> = report
            .instances
            .iter()
            .map(|r| r.instance.clone())
            .collect();
        assert_eq!(reported, planned, "{stages} stages");
    }
}

/// A progress display whose drop panics.
struct PanickyDrop;
impl osms_make::Progress for PanickyDrop {
    fn set_total(&self, _: u64) {}
    fn inc(&self, _: u64) {}
}
impl Drop for PanickyDrop {
    fn drop(&mut self) {
        panic!("a progress display panicked on purpose in its drop");
    }
}

/// Shows every build on a [`PanickyDrop`].
struct PanickyObserver;
impl osms_make::Observer for PanickyObserver {
    fn started(&self, _: &str, _: &str) -> Box<dyn osms_make::Progress + '_> {
        Box::new(PanickyDrop)
    }
    fn finished(&self, _: &osms_make::InstanceReport) {}
}

/// A build whose thread panics outside its kind (here in its progress display's drop) is that
/// instance's failure: the make ends and reports it, at one stage and at several.
#[test]
fn a_build_thread_that_panics_fails_its_instance_and_the_make_ends() {
    for stages in [1, 2] {
        let p = Project::engine();
        let plan = p.plan(Some("tiny")).expect("plan");
        let store = p.open_store();
        let opts = MakeOptions {
            targets: vec!["numbers".into()],
            seeds: vec![0],
            jobs: 2,
            stages,
            dry_run: false,
        };
        // A hung make would hang the test: the make runs on a thread of its own, and the test
        // fails (leaving that thread behind) if no report comes.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(osms_make::make(&plan, &store, &opts, &PanickyObserver));
        });
        let report = rx
            .recv_timeout(std::time::Duration::from_secs(120))
            .expect("the make ended")
            .expect("the make reports");
        let o = outcomes(&report);
        assert_eq!(o["numbers@0"], "failed", "{stages} stages: {o:?}");
        let error = report.instances.iter().find_map(|r| match &r.outcome {
            osms_make::Outcome::Failed { error } => Some(error.clone()),
            _ => None,
        });
        assert!(
            error.is_some_and(|e| e.contains("panicked on purpose in its drop")),
            "{stages} stages: {report:?}"
        );
        drop(p);
    }
}

/// Makes the record of `blocked` unwritable (a directory where its file goes) the moment its
/// build starts: after the make looked for it, before it records it.
struct BlockRecord {
    blocked: String,
    path: std::path::PathBuf,
}
impl osms_make::Observer for BlockRecord {
    fn started(&self, instance: &str, _: &str) -> Box<dyn osms_make::Progress + '_> {
        if instance == self.blocked {
            std::fs::create_dir_all(&self.path).expect("block the record's path");
        }
        Box::new(osms_make::NoProgress)
    }
    fn finished(&self, _: &osms_make::InstanceReport) {}
}

/// A store error while recording one build fails that stage (issue 75: never the whole make),
/// and the build in flight beside it is recorded: its work is not thrown away.
#[test]
fn a_store_error_recording_one_build_fails_that_stage_and_keeps_the_build_beside_it() {
    // `numbers` sleeps (about 1.2 s); `reference` (no inputs, quick) starts beside it and its
    // record cannot be written.
    let p = Project::new(&ENGINE_PIPELINE.replace(
        "params = { n = 12, len = 4, scale = 1.0 }",
        "params = { n = 12, len = 4, scale = 1.0, sleep_ms = 100 }",
    ));
    let plan = p.plan(None).expect("plan");
    let ids = plan
        .instances(&["numbers".into(), "reference".into()], &[0])
        .expect("instances");
    let key_of = |name: &str| {
        let id = *ids
            .iter()
            .find(|id| plan.display(**id) == name)
            .expect(name);
        plan.key(id, &[])
    };
    let (numbers, reference) = (key_of("numbers@0"), key_of("reference"));
    let store = p.open_store();
    let hex = reference.to_hex();
    let observer = BlockRecord {
        blocked: "reference".into(),
        path: p
            .store
            .join("index")
            .join(&hex[..2])
            .join(format!("{hex}.json")),
    };
    let opts = MakeOptions {
        targets: vec!["numbers".into(), "reference".into()],
        seeds: vec![0],
        jobs: 2,
        stages: 2,
        dry_run: false,
    };
    let report = osms_make::make(&plan, &store, &opts, &observer).expect("a report");
    let o = outcomes(&report);
    assert_eq!(o["reference"], "failed");
    assert_eq!(o["numbers@0"], "built");
    let err = first_failure(&report).expect("the failure");
    assert!(
        err.contains(&format!(
            "cannot record the output of this build (key {})",
            reference.short()
        )),
        "{err}"
    );
    assert!(
        store.record(&numbers).expect("read").is_some(),
        "the build in flight beside the failed record was thrown away"
    );
}

#[test]
fn a_failing_stage_skips_its_dependents_and_the_rest_is_built() {
    for stages in [1, 2] {
        a_failing_stage_skips_its_dependents(stages);
    }
}

fn a_failing_stage_skips_its_dependents(stages: usize) {
    let p = Project::new(
        &ENGINE_PIPELINE.replace("params = { n = 6 }", "params = { n = 6, fail_at = 4 }"),
    );
    let report = p.make_with_stages(Some("tiny"), &[0], 2, stages);
    let o = outcomes(&report);
    assert_eq!(o["numbers@0"], "failed");
    for dependent in ["signs@0", "sign_total@0", "total@0", "report@0"] {
        assert_eq!(o[dependent], "skipped", "{dependent}");
    }
    assert_eq!(o["drops@0"], "built");
    assert_eq!(o["reference"], "built");
    let err = first_failure(&report);
    assert!(err.is_some_and(|e| e.contains("item 4 failed on purpose")));
}

/// The engine pipeline plus a `panicky` stage with `params` and a dependent of it.
fn with_panicky(params: &str) -> String {
    format!(
        "{ENGINE_PIPELINE}\n[stages.boom]\nkind = \"panicky\"\nshards = 2\nparams = {{ n = 6, {params} }}\n\n\
         [stages.boom_total]\nkind = \"sum\"\ninputs = {{ values = \"boom\" }}\n"
    )
}

#[test]
fn a_panicking_stage_fails_alone_and_leaves_no_record() {
    for (params, message) in [
        // On a rayon worker of the make's pool, mid-stage (after the first shard was stored).
        (
            "panic_at_item = 4",
            "item 4 panicked on purpose (panic_at_item)",
        ),
        ("panic_in_prepare = true", "prepare panicked on purpose"),
        ("panic_in_merge = true", "merge panicked on purpose"),
    ] {
        let p = Project::new(&with_panicky(params));
        let report = p.make(Some("tiny"), &[0], 2);
        let o = outcomes(&report);
        assert_eq!(o["boom"], "failed", "{params}");
        assert_eq!(o["boom_total"], "skipped", "{params}");
        for built in [
            "numbers@0",
            "signs@0",
            "total@0",
            "drops@0",
            "reference",
            "report@0",
        ] {
            assert_eq!(o[built], "built", "{params}: {built}");
        }
        let err = first_failure(&report).expect("a failure");
        assert!(
            err.starts_with("stage panicked: ") && err.contains(message),
            "{params}: {err}"
        );
        let (records, unreadable) = p.open_store().records().expect("records");
        assert!(unreadable.is_empty());
        assert!(
            !records
                .iter()
                .any(|r| r.stage == "boom" && r.shard.is_none()),
            "{params}: a panicked stage has a record"
        );
    }
}

#[test]
fn an_unreadable_index_record_is_rebuilt_not_fatal() {
    let p = Project::engine();
    let first = p.make(Some("tiny"), &[0], 2);
    let total = first
        .instances
        .iter()
        .find(|r| r.instance == "total@0")
        .and_then(|r| r.key)
        .expect("total's key");
    let hex = total.to_hex();
    let record = p
        .store
        .join("index")
        .join(&hex[..2])
        .join(format!("{hex}.json"));
    assert!(record.is_file(), "{}", record.display());
    // A record cut short mid-write by something other than osms.
    std::fs::write(&record, b"{\"key\": \"").expect("garble the record");

    let plan = p.plan(Some("tiny")).expect("plan");
    let statuses = osms_make::status(&plan, &p.open_store(), &[], &[0]).expect("status");
    let st = statuses
        .iter()
        .find(|s| s.instance == "total@0")
        .expect("total");
    assert_eq!(st.state, State::Missing);
    assert_eq!(st.reasons, [Reason::RecordUnreadable { key: total }]);
    // Its dependents cannot know their key until it is rebuilt.
    let report = statuses
        .iter()
        .find(|s| s.instance == "report@0")
        .expect("report");
    assert_eq!(report.state, State::Stale);

    let second = p.make(Some("tiny"), &[0], 2);
    let o = outcomes(&second);
    assert_eq!(o["total@0"], "built");
    assert_eq!(o["report@0"], "cut off");
    assert_eq!(o["numbers@0"], "cached");
    assert_eq!(hashes(&second), hashes(&first));
    let plan = p.plan(Some("tiny")).expect("plan");
    let after = osms_make::status(&plan, &p.open_store(), &[], &[0]).expect("status");
    assert!(after.iter().all(|s| s.state == State::Cached));
}

fn plan_error(text: &str) -> String {
    let p = Project::new(text);
    match p.plan(Some("small")) {
        Ok(_) => panic!("the pipeline was accepted:\n{text}"),
        Err(e) => e
            .to_string()
            .replace(&p.pipeline.display().to_string(), "pipeline.toml"),
    }
}

#[test]
fn malformed_toml_is_reported_with_line_and_column() {
    let err = plan_error("[stages.a]\nkind = \"numbers\"\nparams = { n = 3,, }\n");
    assert!(err.starts_with("pipeline.toml:3:"), "{err}");
}

#[test]
fn unknown_stage_kind_names_the_stage_and_the_known_kinds() {
    let err = plan_error("[stages.gen]\nkind = \"numbres\"\nparams = { n = 3 }\n");
    assert_eq!(
        err,
        "pipeline.toml:2:1: stage `gen` has unknown kind `numbres`\nhint: known kinds are `combine`, `drop`, `fold_rows`, `gather_totals`, `numbers`, `offset`, `panicky`, `shift`, `signs`, `spin`, `sum`, `sum_of_a`"
    );
}

#[test]
fn unknown_param_names_the_field_and_lists_the_valid_ones() {
    let err =
        plan_error("[stages.gen]\nkind = \"numbers\"\n\n[stages.gen.params]\nn = 3\nscael = 2.0\n");
    assert!(
        err.starts_with("pipeline.toml:6:1: stage `gen` (kind `numbers`), param"),
        "{err}"
    );
    assert!(err.contains("unknown field `scael`"), "{err}");
    assert!(
        err.contains("expected one of `n`, `len`, `scale`, `sleep_ms`, `fail_at`"),
        "{err}"
    );
}

#[test]
fn unknown_param_in_a_profile_overlay_points_at_the_overlay() {
    let err = plan_error(
        "[stages.gen]\nkind = \"numbers\"\nparams = { n = 3 }\n\n[profiles.small.gen.params]\nlne = 2\n",
    );
    assert!(err.starts_with("pipeline.toml:6:1:"), "{err}");
    assert!(err.contains("unknown field `lne`"), "{err}");
}

#[test]
fn mistyped_param_names_the_field_and_the_expected_type() {
    let err = plan_error("[stages.gen]\nkind = \"numbers\"\nparams = { n = \"ten\" }\n");
    assert!(err.starts_with("pipeline.toml:3:12: stage `gen` (kind `numbers`), param `n`: invalid type: string \"ten\", expected u32"), "{err}");
    let err = plan_error("[stages.gen]\nkind = \"numbers\"\nparams = { len = 2 }\n");
    assert!(err.contains("missing field `n`"), "{err}");
}

#[test]
fn missing_input_names_the_stage_and_the_slot() {
    let err = plan_error("[stages.total]\nkind = \"sum\"\n");
    assert_eq!(
        err,
        "pipeline.toml:1:9: stage `total` (kind `sum`) is missing input `values`\nhint: add `inputs = { values = \"<stage>\" }` to it"
    );
}

#[test]
fn input_from_an_undeclared_stage_or_an_unknown_slot_is_named() {
    let err = plan_error("[stages.total]\nkind = \"sum\"\ninputs = { values = \"numbrs\" }\n");
    assert!(err.starts_with("pipeline.toml:3:12: stage `total`: input `values` refers to stage `numbrs`, which is not declared"), "{err}");
    let err = plan_error(
        "[stages.n]\nkind = \"numbers\"\nparams = { n = 1 }\n[stages.total]\nkind = \"sum\"\ninputs = { values = \"n\", extra = \"n\" }\n",
    );
    assert!(err.contains("stage `total` (kind `sum`) has no input slot `extra`\nhint: its input slots are `values`"), "{err}");
}

#[test]
fn a_cycle_is_named() {
    let err = plan_error(
        "[stages.a]\nkind = \"signs\"\ninputs = { values = \"b\" }\n[stages.b]\nkind = \"shift\"\nparams = { by = 1.0 }\ninputs = { values = \"a\" }\n",
    );
    assert!(
        err.contains("stage `a` depends on itself: a -> b -> a"),
        "{err}"
    );
    assert!(err.starts_with("pipeline.toml:3:1:"), "{err}");
}

#[test]
fn sharding_a_plain_kind_or_fixing_the_seed_of_a_deterministic_one_is_refused() {
    let base = "[stages.n]\nkind = \"numbers\"\nparams = { n = 1 }\n";
    let err = plan_error(&format!(
        "{base}[stages.s]\nkind = \"signs\"\nshards = 2\ninputs = {{ values = \"n\" }}\n"
    ));
    assert!(
        err.contains("kind `signs` computes one artifact and cannot be sharded"),
        "{err}"
    );
    let err = plan_error(&format!(
        "{base}[stages.s]\nkind = \"signs\"\nseed = 3\ninputs = {{ values = \"n\" }}\n"
    ));
    assert!(err.contains("draws no random numbers"), "{err}");
}

/// `numbers`, same kind and version, computing items in batches of `BATCH` (each batch in
/// reverse order, to show the order inside a batch does not matter), optionally returning one
/// item too few.
struct NumbersBatched {
    short: bool,
}
const BATCH: usize = 4;
impl Kind for NumbersBatched {
    const KIND: &'static str = "numbers";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [osms_make::Slot] = &[];
    const DOC: &'static str = "numbers, in batches";
    type Params = NumbersParams;
}

impl ItemStage for NumbersBatched {
    type Prepared = ();
    type Item = Vec<f64>;
    type Output = osms_tests::artifacts::Numbers;
    fn prepare(
        &self,
        ctx: &osms_make::Ctx<'_, NumbersParams>,
    ) -> Result<(), osms_make::StageError> {
        NumbersKind.prepare(ctx)
    }
    fn n_items(&self, ctx: &osms_make::Ctx<'_, NumbersParams>, p: &()) -> usize {
        NumbersKind.n_items(ctx, p)
    }
    fn run_item(
        &self,
        _: &osms_make::Ctx<'_, NumbersParams>,
        _: &(),
        _: usize,
        _: &mut osms_core::rng::StreamRng,
    ) -> Result<Vec<f64>, osms_make::StageError> {
        Err("a batched kind's items come from run_batch".into())
    }
    fn batch_len(&self, _: &()) -> usize {
        BATCH
    }
    fn run_batch(
        &self,
        ctx: &osms_make::Ctx<'_, NumbersParams>,
        p: &(),
        first: usize,
        rngs: Vec<osms_core::rng::StreamRng>,
    ) -> Result<Vec<Vec<f64>>, osms_make::StageError> {
        assert!(rngs.len() <= BATCH);
        let mut items = rngs
            .into_iter()
            .enumerate()
            .rev()
            .map(|(k, mut rng)| NumbersKind.run_item(ctx, p, first + k, &mut rng))
            .collect::<Result<Vec<_>, _>>()?;
        items.reverse();
        if self.short {
            items.pop();
        }
        Ok(items)
    }
    fn merge(
        &self,
        ctx: &osms_make::Ctx<'_, NumbersParams>,
        p: (),
        items: Vec<Vec<f64>>,
    ) -> Result<osms_tests::artifacts::Numbers, osms_make::StageError> {
        NumbersKind.merge(ctx, p, items)
    }
}

/// The test registry with its `numbers` kind replaced by `numbers`.
fn registry_with(numbers: impl ItemStage) -> Registry {
    let mut r = Registry::new();
    r.register_itemised(numbers)
        .register_itemised(osms_tests::stages::DropKind)
        .register(osms_tests::stages::SignsKind)
        .register(osms_tests::stages::ShiftKind)
        .register(osms_tests::stages::OffsetKind)
        .register(osms_tests::stages::SumKind)
        .register(osms_tests::stages::CombineKind)
        .register_itemised(osms_tests::stages::PanicKind)
        .register(osms_tests::stages::FoldRowsKind)
        .register(osms_tests::stages::GatherKind)
        .register(osms_tests::stages::SumOfAKind)
        .register(osms_tests::stages::SpinKind);
    assert_eq!(r.names(), registry().names());
    r
}

#[test]
fn batched_items_are_the_items_one_by_one() {
    let reference = hashes(&Project::engine().make(Some("tiny"), &[0], 1));
    // 6 items: one full batch and a ragged one; shards cut batches shorter still.
    for (shards, jobs) in [(1, 1), (1, 2), (5, 2)] {
        let mut p = Project::new(&with_shards(shards, 2));
        p.registry = registry_with(NumbersBatched { short: false });
        assert_eq!(
            hashes(&p.make(Some("tiny"), &[0], jobs)),
            reference,
            "{shards} shards, {jobs} threads"
        );
    }
    // A batch that comes back short fails its stage with its item range (whichever batch
    // a thread met first), and nothing else.
    let mut p = Project::new(&with_shards(1, 2));
    p.registry = registry_with(NumbersBatched { short: true });
    let report = p.make(Some("tiny"), &[0], 2);
    assert_eq!(outcomes(&report)["numbers@0"], "failed");
    let err = first_failure(&report);
    assert!(
        err.as_deref().is_some_and(|e| {
            e.contains("items 0..4 came back as 3 items")
                || e.contains("items 4..6 came back as 1 items")
        }),
        "{err:?}"
    );
}

/// A record's core-seconds are the CPU time of the build's own threads: a build that uses
/// 0.3 s of CPU on one of two threads records ≈ 0.3 s alone and beside another build, not its
/// wall time times the threads over the builds in flight (0.6 s alone, under the old rule).
#[test]
fn core_seconds_are_the_builds_cpu_time_at_any_number_of_stages() {
    let pipeline = "[stages.spin_a]\nkind = \"spin\"\nparams = { cpu_ms = 300 }\n\
                    [stages.spin_b]\nkind = \"spin\"\nparams = { cpu_ms = 301 }\n";
    for stages in [1, 2] {
        let p = Project::new(pipeline);
        let report = p.make_with_stages(None, &[0], 2, stages);
        let store = p.open_store();
        for r in &report.instances {
            let key = r.key.expect("built");
            let rec = store.record(&key).expect("read").expect("a record");
            let cpu = rec.cpu_secs.expect("cpu_secs");
            let used = if r.instance == "spin_a" { 0.300 } else { 0.301 };
            assert!(
                (used..used + 0.15).contains(&cpu),
                "{stages} stages: `{}` used {used} s of CPU and records {cpu} s (wall {} s)",
                r.instance,
                rec.wall_time_secs
            );
        }
    }
}
