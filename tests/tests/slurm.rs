//! The Slurm driver (`make_slurm`) and `osms run-task`, with the engine test pipeline, against
//! a scheduler that runs each submitted batch script at once with the environment Slurm would
//! give it. This checks the driver's bookkeeping and the real tasks (the `osms-test` binary)
//! on every CI run; `scripts/slurm-test` runs the same code against a real slurmctld.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::process::Command;

use osms_make::executor::ExecutorConfig;
use osms_make::slurm::cmd::{Ended, JobRequest, Queued, Scheduler};
use osms_make::slurm::{Launch, make_slurm};
use osms_make::{MakeOptions, MakeReport, Outcome};
use osms_store::Hash;
use osms_tests::Project;
use osms_tests::project::{Silent, hashes, outcomes};

const BIN: &str = env!("CARGO_BIN_EXE_osms-test");

/// Runs every job when it is submitted: each array task in index order, then a job that
/// depends on an array only if all of the array's tasks exited 0 (`--kill-on-invalid-dep`).
/// `drop` names array tasks (by job name and index) to treat as cancelled: never run.
#[derive(Default)]
struct Inline {
    next_id: RefCell<u64>,
    /// Job id -> whether every task of it succeeded.
    ok: RefCell<BTreeMap<u64, bool>>,
    submitted: RefCell<Vec<JobRequest>>,
    drop: RefCell<Vec<(String, u32)>>,
}

impl Inline {
    fn run(&self, job: &JobRequest, id: u64, task: Option<u32>) -> bool {
        if let Some(t) = task
            && self.drop.borrow().contains(&(job.name.clone(), t))
        {
            return false;
        }
        let mut cmd = Command::new("sh");
        cmd.arg("-c")
            .arg(&job.script)
            .current_dir(&job.workdir)
            .env_remove("OSMS_LOG")
            .env("OSMS_NO_PROGRESS", "1");
        match task {
            Some(t) => {
                cmd.env("SLURM_ARRAY_JOB_ID", id.to_string())
                    .env("SLURM_ARRAY_TASK_ID", t.to_string())
                    .env("SLURM_JOB_ID", (id * 1000 + u64::from(t)).to_string());
            }
            None => {
                cmd.env("SLURM_JOB_ID", id.to_string());
            }
        }
        let out = cmd.output().expect("run the batch script");
        assert!(
            out.status.success(),
            "{} failed: {}",
            job.name,
            String::from_utf8_lossy(&out.stderr)
        );
        out.status.success()
    }
}

impl Scheduler for Inline {
    fn submit(&self, job: &JobRequest) -> osms_make::Result<u64> {
        let id = {
            let mut n = self.next_id.borrow_mut();
            *n += 1;
            *n
        };
        self.submitted.borrow_mut().push(job.clone());
        let deps_ok = job
            .after_ok
            .is_none_or(|dep| self.ok.borrow().get(&dep).copied().unwrap_or(false));
        let ok = deps_ok
            && match &job.array {
                Some(tasks) => tasks.iter().all(|t| self.run(job, id, Some(*t))),
                None => self.run(job, id, None),
            };
        self.ok.borrow_mut().insert(id, ok);
        Ok(id)
    }
    fn queue_all(&self) -> osms_make::Result<Vec<Queued>> {
        Ok(Vec::new())
    }
    fn ended(&self, _: &[u64]) -> Option<Vec<Ended>> {
        None
    }
    fn cancel(&self, _: &[u64]) -> osms_make::Result<()> {
        Ok(())
    }
}

fn config() -> ExecutorConfig {
    let mut c = ExecutorConfig::default();
    c.slurm.poll_secs = Some(0.01);
    c.slurm.cpus_per_task = Some(2);
    c
}

fn slurm_make(p: &Project, sched: &Inline) -> MakeReport {
    let plan = p.plan(None).expect("plan");
    let store = p.open_store();
    let opts = MakeOptions {
        targets: vec![],
        seeds: vec![0],
        jobs: 1,
        stages: 1,
        dry_run: false,
    };
    let launch = Launch {
        binary: BIN.into(),
        pipeline: p.pipeline.clone(),
        store: p.store.clone(),
        workdir: p.dir.path().to_path_buf(),
        platform: osms::platform::class(),
    };
    make_slurm(&plan, &store, &opts, &config(), sched, &launch, &Silent).expect("slurm make")
}

#[test]
fn a_cluster_build_has_the_local_build_s_keys_and_bytes_and_resumes_only_missing_shards() {
    let local = Project::engine();
    let local_report = local.make(None, &[0], 2);

    let p = Project::engine();
    let sched = Inline::default();
    // Shard 1 of `drops` is "cancelled": its task never runs.
    sched.drop.borrow_mut().push(("osms-drops@0".into(), 1));
    let first = slurm_make(&p, &sched);
    let o = outcomes(&first);
    assert_eq!(o["drops@0"], "failed", "{o:?}");
    assert_eq!(o["report@0"], "skipped", "{o:?}");
    assert_eq!(o["numbers@0"], "built", "{o:?}");
    let Outcome::Failed { error } = &first
        .instances
        .iter()
        .find(|r| r.instance == "drops@0")
        .expect("drops@0")
        .outcome
    else {
        unreachable!()
    };
    assert!(
        error.contains("shard 1") && error.contains("resubmits"),
        "{error}"
    );
    // The array of `numbers` ran 3 tasks, then its merge, as jobs of the stage's name.
    let submitted = sched.submitted.borrow().clone();
    let numbers: Vec<&JobRequest> = submitted
        .iter()
        .filter(|j| j.name == "osms-numbers@0")
        .collect();
    assert_eq!(numbers.len(), 2);
    assert_eq!(numbers[0].array, Some(vec![0, 1, 2]));
    assert!(numbers[0].flags.contains(&"--cpus-per-task=2".to_string()));
    assert!(numbers[1].after_ok.is_some() && numbers[1].array.is_none());
    // Nothing half-written, no temp directories left behind.
    let store = p.open_store();
    assert!(store.verify().expect("verify").problems.is_empty());
    assert!(store.task_dirs().expect("task dirs").is_empty());

    sched.drop.borrow_mut().clear();
    sched.submitted.borrow_mut().clear();
    let second = slurm_make(&p, &sched);
    let o = outcomes(&second);
    assert_eq!(o["drops@0"], "built", "{o:?}");
    assert_eq!(o["numbers@0"], "cached", "{o:?}");
    let again = sched.submitted.borrow().clone();
    let drops: Vec<&JobRequest> = again.iter().filter(|j| j.name == "osms-drops@0").collect();
    assert_eq!(
        drops[0].array,
        Some(vec![1]),
        "only the missing shard runs again"
    );

    let mut all = hashes(&first);
    all.extend(hashes(&second));
    let expected: BTreeMap<String, Hash> = hashes(&local_report);
    assert_eq!(all, expected, "the same content hashes as the local build");
    let keys = |r: &MakeReport| -> BTreeMap<String, Option<Hash>> {
        r.instances
            .iter()
            .map(|i| (i.instance.clone(), i.key))
            .collect()
    };
    let mut cluster_keys = keys(&first);
    cluster_keys.extend(keys(&second).into_iter().filter(|(_, k)| k.is_some()));
    assert_eq!(cluster_keys, keys(&local_report), "the same keys");

    // A third make finds everything.
    sched.submitted.borrow_mut().clear();
    let third = slurm_make(&p, &sched);
    assert!(outcomes(&third).values().all(|o| *o == "cached"));
    assert!(sched.submitted.borrow().is_empty());
}

#[test]
fn a_task_refuses_a_store_it_cannot_see_and_a_pipeline_changed_since_submission() {
    let p = Project::engine();
    // No store at all where the task looks: it must not create one.
    let out = p.run(std::path::Path::new(BIN), &["run-task", &"ab".repeat(32)]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("shared by the submit host"), "{err}");
    assert!(!p.store.exists());

    // A submitted task whose pipeline changed before it ran.
    let sched = Inline::default();
    sched.drop.borrow_mut().push(("osms-drops@0".into(), 0));
    slurm_make(&p, &sched);
    let drops = sched
        .submitted
        .borrow()
        .iter()
        .find(|j| j.name == "osms-drops@0")
        .cloned()
        .expect("drops submitted");
    let key = drops
        .script
        .split_whitespace()
        .find(|w| w.len() == 64)
        .expect("the key in the script")
        .to_string();
    // A task on a node of another platform class refuses before computing anything.
    let store = p.open_store();
    let hash: Hash = key.parse().expect("key");
    let mut spec = osms_make::slurm::ledger::read_task(&store, &hash)
        .expect("read")
        .expect("spec");
    spec.platform = "x86_64-elsewhere".into();
    let lock = store.lock(|| {}).expect("lock");
    osms_make::slurm::ledger::write_task(&store, &spec).expect("write");
    let out = p.run(
        std::path::Path::new(BIN),
        &["run-task", &key, "--shard", "0"],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("platform class") && err.contains("x86_64-elsewhere"),
        "{err}"
    );
    spec.platform = osms::platform::class();
    osms_make::slurm::ledger::write_task(&store, &spec).expect("write");
    drop(lock);

    p.write_pipeline(&osms_tests::project::ENGINE_PIPELINE.replace("steps = 400", "steps = 401"));
    let out = p.run(
        std::path::Path::new(BIN),
        &["run-task", &key, "--shard", "0"],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("changed between submission and this task"),
        "{err}"
    );
}

/// Builds of the same work (one per run seed) measure a stage by their median core-seconds: a
/// build resumed from a checkpoint records only its last part, and must not set the estimate.
#[test]
fn the_cost_model_takes_the_median_of_builds_of_equal_work() {
    let p = Project::engine();
    let seeds = [0, 1, 2];
    p.make(Some("small"), &seeds, 2);
    let store = p.open_store();
    let (paper, small) = (
        p.plan(Some("paper")).expect("paper plan"),
        p.plan(Some("small")).expect("small plan"),
    );
    let names = vec!["numbers@0".to_string()];
    let mut secs: Vec<f64> = osms_make::status(&small, &store, &[], &seeds)
        .expect("status")
        .into_iter()
        .filter(|st| st.instance.starts_with("numbers@"))
        .map(|st| {
            let key = st.key.expect("built");
            store
                .record(&key)
                .expect("read")
                .and_then(|r| r.cpu_secs)
                .expect("cpu_secs")
        })
        .collect();
    assert_eq!(secs.len(), 3);
    secs.sort_by(f64::total_cmp);
    // Seen through two plans (an experiment's points share builds), still their median.
    let twice = [small, p.plan(Some("small")).expect("small plan")];
    let e = osms_make::estimate(&paper, &twice, &store, &seeds, &names, 1).expect("estimate");
    let m = e.instances[0].measured.as_ref().expect("measured");
    assert_eq!(m.core_secs, secs[1], "{secs:?}");
}

#[test]
fn the_cost_model_scales_measured_core_seconds_by_planned_work() {
    let p = Project::engine();
    p.make(Some("small"), &[0], 2);
    let store = p.open_store();
    let paper = p.plan(Some("paper")).expect("paper plan");
    let small = p.plan(Some("small")).expect("small plan");
    let names: Vec<String> = paper
        .instances(&[], &[0])
        .expect("instances")
        .into_iter()
        .map(|id| paper.display(id))
        .collect();
    let e = osms_make::estimate(&paper, &[small], &store, &[0], &names, 1).expect("estimate");
    assert!(e.unmeasured.is_empty(), "{:?}", e.unmeasured);
    let get = |n: &str| {
        e.instances
            .iter()
            .find(|i| i.instance == n)
            .expect(n)
            .clone()
    };
    // `numbers`: 12 items measured, 1000 planned; `total` follows its input.
    let numbers = get("numbers@0");
    let m = numbers.measured.clone().expect("measured");
    assert_eq!((m.work, numbers.work), (12.0, 1000.0));
    let rec = store.record(&m.key).expect("read").expect("record");
    assert_eq!(Some(m.core_secs), rec.cpu_secs);
    let expected = m.core_secs * 1000.0 / 12.0 / 3600.0;
    assert!((numbers.core_hours.expect("hours") - expected).abs() <= 1e-12 * expected.max(1e-300));
    assert_eq!(get("total@0").work, 1000.0);
    assert_eq!(get("drops@0").work, 200.0);
    let sum: f64 = e.instances.iter().filter_map(|i| i.core_hours).sum();
    assert!((e.total_core_hours - sum).abs() <= 1e-12 * sum.max(1e-300));
    assert!(
        e.instances
            .iter()
            .all(|i| !i.measured.as_ref().expect("m").stale)
    );
    // A stage with a build of its own is scaled from it, never from another of its kind.
    for i in &e.instances {
        let stage = i.instance.split(['#', '@']).next().expect("a stage");
        assert_eq!(i.measured.as_ref().expect("m").stage, stage, "{i:?}");
    }

    // New numbers: every build is stale. Those whose params are the profile's still measure
    // their stage (their last build's record); `numbers` itself, whose params changed, does not
    // measure its own.
    p.write_pipeline(&osms_tests::project::ENGINE_PIPELINE.replace(
        "params = { n = 12, len = 4, scale = 1.0 }",
        "params = { n = 12, len = 4, scale = 2.0 }",
    ));
    let (paper, small) = (
        p.plan(Some("paper")).expect("plan"),
        p.plan(Some("small")).expect("plan"),
    );
    let e = osms_make::estimate(&paper, &[small], &store, &[0], &names, 1).expect("estimate");
    let total = e
        .instances
        .iter()
        .find(|i| i.instance == "total@0")
        .expect("total");
    let m = total
        .measured
        .as_ref()
        .expect("the stale build measures `total`");
    assert!(m.stale);
    assert_eq!((m.work, total.work), (12.0, 1000.0));
    let old = get("total@0").measured.expect("measured");
    assert_eq!((m.key, m.core_secs), (old.key, old.core_secs));
    // `numbers`, whose own build no longer measures it, is scaled from the other stage of its
    // kind, `reference`, and says so.
    let numbers = e
        .instances
        .iter()
        .find(|i| i.instance == "numbers@0")
        .expect("numbers");
    let by_kind = numbers.measured.as_ref().expect("measured by its kind");
    assert_eq!(by_kind.stage, "reference");
    assert_eq!(numbers.work, 1000.0);
    let expected = by_kind.core_secs * 1000.0 / by_kind.work / 3600.0;
    assert!(
        (numbers.core_hours.expect("hours") - expected).abs() <= 1e-12 * expected.max(1e-300),
        "{numbers:?}"
    );
    assert!(e.unmeasured.is_empty(), "{:?}", e.unmeasured);
    assert!(
        e.instances
            .iter()
            .find(|i| i.instance == "drops@0")
            .and_then(|i| i.measured.as_ref())
            .is_some_and(|m| !m.stale),
        "drops does not read numbers: up to date"
    );
    // Nothing measured, nothing estimated: an empty store leaves every instance unmeasured.
    let empty = Project::engine();
    let e = osms_make::estimate(
        &paper,
        &[empty.plan(Some("small")).expect("plan")],
        &empty.open_store(),
        &[0],
        &names,
        1,
    )
    .expect("estimate");
    assert_eq!(e.unmeasured.len(), names.len());
    assert_eq!(e.total_core_hours, 0.0);
}
