//! Crash safety and store integrity through the real command line: `kill -9` at arbitrary
//! points, concurrent makers, damaged, truncated and deleted objects, and files that do not
//! belong in a store.
//!
//! Every test drives `osms-test` (the `osms` CLI with the test kinds registered) as a separate
//! process. Nothing here asserts on durations: delays only choose where a kill lands, and every
//! assertion about the store holds wherever it lands. Only the `kill -9` test's count of kills
//! that landed mid-build rests on timing, with bounds explained there.

use std::collections::{BTreeMap, BTreeSet};
use std::io::{BufRead, BufReader};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant, SystemTime};

use osms_store::Hash;
use osms_tests::Project;
use osms_tests::project::ENGINE_PIPELINE;
use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_osms-test");

const WAITING: &str = "waiting for another osms process";

// ---------------------------------------------------------------------------------------------
// Running the binary

/// `osms-test --pipeline P --store S --no-progress ARGS`, with no osms variables inherited from
/// the environment the tests run in.
fn command_with_store(pipeline: &Path, store: &Path, args: &[&str]) -> Command {
    let mut c = Command::new(BIN);
    c.arg("--pipeline")
        .arg(pipeline)
        .arg("--store")
        .arg(store)
        .arg("--no-progress")
        .args(args)
        .env_remove("OSMS_NO_PROGRESS")
        .env_remove("OSMS_LOG")
        .env_remove("OSMS_PIPELINE")
        .env_remove("OSMS_STORE")
        .current_dir(pipeline.parent().expect("pipeline.toml has a parent"));
    c
}

fn command(p: &Project, args: &[&str]) -> Command {
    command_with_store(&p.pipeline, &p.store, args)
}

/// Runs to completion, as `Project::run` does; built on [`command`] so that the same flags serve
/// processes that are spawned, killed or pointed at another store.
fn run(p: &Project, args: &[&str]) -> Output {
    command(p, args).output().expect("run osms-test")
}

fn shown(args: &[&str], out: &Output) -> String {
    format!(
        "osms-test {}\nexit: {:?}\n--- stdout\n{}--- stderr\n{}",
        args.join(" "),
        out.status.code(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Runs and asserts the exit code.
fn run_expect(p: &Project, args: &[&str], code: i32) -> Output {
    let out = run(p, args);
    assert_eq!(
        out.status.code(),
        Some(code),
        "expected exit code {code}:\n{}",
        shown(args, &out)
    );
    out
}

fn run_ok(p: &Project, args: &[&str]) -> Output {
    run_expect(p, args, 0)
}

fn stdout(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn json(out: &Output) -> Value {
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("stdout is not JSON ({e}):\n{}", stdout(out)))
}

// ---------------------------------------------------------------------------------------------
// Reading `make --json`, `status --json` and `ls --json`

/// One entry of a `make --json` report.
#[derive(Debug, Clone)]
struct Inst {
    outcome: String,
    reason: Option<String>,
    content_hash: Option<String>,
}

fn report(out: &Output) -> BTreeMap<String, Inst> {
    let v = json(out);
    let instances = v["instances"]
        .as_array()
        .unwrap_or_else(|| panic!("no `instances` in the make report:\n{}", stdout(out)));
    let mut map = BTreeMap::new();
    for i in instances {
        let name = i["instance"].as_str().expect("instance name").to_string();
        let inst = Inst {
            outcome: i["outcome"].as_str().expect("outcome").to_string(),
            reason: i["reason"].as_str().map(str::to_string),
            content_hash: i["content_hash"].as_str().map(str::to_string),
        };
        assert!(
            map.insert(name.clone(), inst).is_none(),
            "{name} twice in a report"
        );
    }
    map
}

/// Instance -> content hash, every instance of the report required to have one.
fn report_hashes(r: &BTreeMap<String, Inst>) -> BTreeMap<String, String> {
    r.iter()
        .map(|(name, i)| {
            let hash = i
                .content_hash
                .clone()
                .unwrap_or_else(|| panic!("{name} has no content hash: {i:?}"));
            (name.clone(), hash)
        })
        .collect()
}

fn outcome_counts(r: &BTreeMap<String, Inst>) -> BTreeMap<String, usize> {
    let mut counts = BTreeMap::new();
    for i in r.values() {
        *counts.entry(i.outcome.clone()).or_insert(0) += 1;
    }
    counts
}

/// Stage key -> (stage, content hash) of every record in the store, shards included.
fn records(p: &Project) -> BTreeMap<String, (String, String)> {
    let out = run_ok(p, &["ls", "--json"]);
    json(&out)
        .as_array()
        .expect("ls --json prints an array")
        .iter()
        .map(|r| {
            let s = |f: &str| {
                r[f].as_str()
                    .unwrap_or_else(|| panic!("record without {f}: {r}"))
            };
            (
                s("key").to_string(),
                (s("stage").to_string(), s("content_hash").to_string()),
            )
        })
        .collect()
}

fn object_path(store: &Path, hex: &str) -> PathBuf {
    store.join("objects").join(&hex[..2]).join(hex)
}

fn dir_entries(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .expect("read dir")
        .map(|e| {
            e.expect("dir entry")
                .file_name()
                .to_string_lossy()
                .into_owned()
        })
        .collect();
    names.sort();
    names
}

/// Seeded stages take `sleep_ms` per item, so a make lasts long enough to be killed mid-stage.
/// `numbers_n` items in `numbers_shards` shards; `reference` (a fixed seed, shared by every run
/// seed) sleeps too.
fn sleepy_pipeline(numbers_n: u32, numbers_shards: u32, sleep_ms: u32) -> String {
    format!(
        r#"# Crash tests: the engine pipeline's shape with items that sleep.
[pipeline]
seed = 0

[stages.numbers]
kind = "numbers"
shards = {numbers_shards}
params = {{ n = {numbers_n}, len = 4, scale = 1.0, sleep_ms = {sleep_ms} }}

[stages.signs]
kind = "signs"
inputs = {{ values = "numbers" }}

[stages.sign_total]
kind = "sum"
inputs = {{ values = "signs" }}

[stages.total]
kind = "sum"
inputs = {{ values = "numbers" }}

[stages.reference]
kind = "numbers"
seed = 7
shards = 4
params = {{ n = 12, len = 2, sleep_ms = {sleep_ms} }}

[stages.drops]
kind = "drop"
shards = 2
params = {{ n = 4, steps = 300 }}

[stages.report]
kind = "combine"
inputs = {{ total = "total", drops = "drops", reference = "reference" }}
"#
    )
}

/// How many index records the store holds (shards included), read straight from its layout so
/// that counting costs no process while a make runs.
fn index_len(store: &Path) -> usize {
    let index = store.join("index");
    if !index.exists() {
        return 0;
    }
    dir_entries(&index)
        .iter()
        .map(|sub| {
            dir_entries(&index.join(sub))
                .iter()
                .filter(|f| f.ends_with(".json"))
                .count()
        })
        .sum()
}

/// The index record of one shard, and the identity of its file.
#[derive(Debug, Clone, PartialEq)]
struct ShardFile {
    stage_key: String,
    start: u64,
    /// Inode and mtime: every write of a record renames a new file into place, so a record
    /// written again (its shard computed again) has another identity, even with the same bytes.
    identity: (u64, SystemTime),
}

/// Record key -> shard record, of every shard of `stage` in the store, read straight from its
/// layout so that polling while a make runs costs no process.
fn shard_files(store: &Path, stage: &str) -> BTreeMap<String, ShardFile> {
    let index = store.join("index");
    let mut shards = BTreeMap::new();
    if !index.exists() {
        return shards;
    }
    for sub in dir_entries(&index) {
        for name in dir_entries(&index.join(&sub)) {
            let Some(key) = name.strip_suffix(".json") else {
                continue;
            };
            let path = index.join(&sub).join(&name);
            let record: Value = serde_json::from_slice(&std::fs::read(&path).expect("read record"))
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            if record["stage"] != stage || record["shard"].is_null() {
                continue;
            }
            let meta = std::fs::metadata(&path).expect("stat record");
            let shard = ShardFile {
                stage_key: record["shard"]["stage_key"]
                    .as_str()
                    .expect("stage key of a shard")
                    .to_string(),
                start: record["shard"]["start"].as_u64().expect("start of a shard"),
                identity: (meta.ino(), meta.modified().expect("mtime")),
            };
            shards.insert(key.to_string(), shard);
        }
    }
    shards
}

fn kill_and_wait(child: &mut Child) -> ExitStatus {
    // SIGKILL on Unix; Ok if the child has exited already.
    child.kill().expect("kill osms-test");
    child.wait().expect("wait for osms-test")
}

// ---------------------------------------------------------------------------------------------
// 1. kill -9

#[test]
fn kill_nine_at_random_points_leaves_a_clean_store_and_resumes_to_the_same_hashes() {
    kill_storm("1");
}

/// The storm with two builds in flight at every kill's make and at the resume: records and
/// hashes as an uninterrupted one-at-a-time make's.
#[test]
fn kill_nine_at_two_stages_leaves_a_clean_store_and_resumes_to_the_same_hashes() {
    kill_storm("2");
}

/// 24 makes of `--stages stages` killed at seeded random points, then a resume, against an
/// uninterrupted make at one stage.
fn kill_storm(stages: &str) {
    const KILLS: u64 = 24;
    // Two attempts per run seed: the second resumes what the first left (and may be killed in
    // turn), and every run seed brings new work, so later kills still land mid-build.
    let seed_of = |i: u64| i / 2;
    let seeds: Vec<String> = (0..KILLS.div_ceil(2)).map(|s| s.to_string()).collect();
    let seeds_arg = seeds.join(",");
    let pipeline = sleepy_pipeline(64, 8, 20);

    let reference = Project::new(&pipeline);
    let ref_args = ["make", "--jobs", "2", "--json", "--seeds", &seeds_arg];
    let ref_out = run_ok(&reference, &ref_args);
    let ref_report = report(&ref_out);
    assert!(
        ref_report.values().all(|i| i.outcome == "built"),
        "{ref_report:?}"
    );
    let ref_hashes = report_hashes(&ref_report);
    // Six seeded stages per run seed and `reference` once.
    assert_eq!(
        ref_hashes.len(),
        6 * seeds.len() + 1,
        "{:?}",
        ref_hashes.keys()
    );

    let p = Project::new(&pipeline);
    // The store exists before the first kill: killing its creation is tested on its own in
    // `a_store_being_created_is_never_taken_for_a_foreign_directory`.
    run_ok(&p, &["verify"]);

    let mut killed = 0;
    let mut mid_build = 0;
    for i in 0..KILLS {
        let mut rng = osms_core::rng::stream(0, "crash test", "kill delay", i);
        let delay = osms_core::rng::uniform(&mut rng, 0.0, 1.2);
        let seed = seed_of(i).to_string();
        let records_before = index_len(&p.store);
        let mut child = command(
            &p,
            &["make", "--jobs", "2", "--stages", stages, "--seed", &seed],
        )
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn osms-test make");
        std::thread::sleep(Duration::from_secs_f64(delay));
        let status = kill_and_wait(&mut child);
        // Killed, or finished (successfully) before the kill: nothing else.
        let what = match status.code() {
            // Records written and then a kill: the make was interrupted between two of its
            // artifacts, which is what the resume below must cope with.
            None if index_len(&p.store) > records_before => {
                killed += 1;
                mid_build += 1;
                "killed mid-build"
            }
            None => {
                killed += 1;
                "killed before its first record"
            }
            Some(0) => "finished",
            Some(c) => panic!("make --seed {seed} exited with {c} before it was killed"),
        };
        let verify = run(&p, &["verify"]);
        assert_eq!(
            verify.status.code(),
            Some(0),
            "verify after kill {i} (seed {seed}, {:.0} ms, {what}):\n{}",
            delay * 1000.0,
            shown(&["verify"], &verify)
        );
        eprintln!(
            "kill {i:2}: seed {seed:>2}, after {:4.0} ms: {what:30} -> verify ok, {}",
            delay * 1000.0,
            stderr(&verify).trim()
        );
    }
    eprintln!(
        "{killed} of {KILLS} makes were killed before they finished, {mid_build} of them after \
         writing records"
    );
    // Load only makes a make slower, so more kills land, never fewer. The delays are fixed (a
    // seeded stream): 7 of the 12 first attempts at a seed are killed within 13 to 506 ms, but
    // their `numbers` alone sleeps 640 ms (64 items of 20 ms on 2 threads), so they are killed
    // however fast the machine; a quarter (6) leaves one for a test thread that oversleeps.
    // Five of those 7 come 123 ms or more after the spawn, and a make writes its first record
    // (a `drops` shard) within about 50 ms on an idle machine; asking for 3 of them to have
    // written something leaves room for a machine several times slower.
    assert!(
        killed >= KILLS / 4,
        "only {killed} of {KILLS} makes were killed before they finished"
    );
    assert!(
        mid_build >= KILLS / 8,
        "only {mid_build} of {KILLS} makes were killed after writing records"
    );

    let args = [
        "make", "--jobs", "2", "--stages", stages, "--json", "--seeds", &seeds_arg,
    ];
    let out = run_ok(&p, &args);
    let resumed = report(&out);
    eprintln!("resuming make: {:?}", outcome_counts(&resumed));
    assert!(
        resumed
            .values()
            .all(|i| i.outcome == "built" || i.outcome == "cached" || i.outcome == "cut_off"),
        "{}",
        shown(&args, &out)
    );
    assert_eq!(
        report_hashes(&resumed),
        ref_hashes,
        "resumed vs uninterrupted"
    );
    // Every record, shards included, names the same content under the same key.
    assert_eq!(
        records(&p),
        records(&reference),
        "index after kills vs uninterrupted"
    );
    run_ok(&p, &["verify"]);
    let status = json(&run_ok(&p, &["status", "--json", "--seeds", &seeds_arg]));
    for s in status.as_array().expect("status array") {
        assert_eq!(s["state"], "cached", "{s}");
    }
}

/// `gc` between a make killed mid-stage and the make that resumes it keeps the shards finished
/// before the kill: the resume computes only the others and ends where an uninterrupted build
/// ends.
#[test]
fn gc_after_a_kill_mid_stage_keeps_the_finished_shards_for_the_resume() {
    // 16 shards of 4 items of 50 ms: about 100 ms a shard on 2 threads, 1.6 s for the stage.
    const SHARDS: usize = 16;
    let pipeline = sleepy_pipeline(64, SHARDS as u32, 50);
    let reference = Project::new(&pipeline);
    let ref_hashes = report_hashes(&report(&run_ok(
        &reference,
        &["make", "--jobs", "2", "--json"],
    )));

    let p = Project::new(&pipeline);
    let mut child = command(&p, &["make", "numbers", "--jobs", "2"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn osms-test make");
    // Killed once 3 shards are stored: the other 13 sleep at least 1.3 s, far longer than a poll
    // of 10 ms, so the kill lands mid-stage.
    let deadline = Instant::now() + Duration::from_secs(120);
    while shard_files(&p.store, "numbers").len() < 3 {
        assert!(
            child.try_wait().expect("poll make").is_none(),
            "make numbers exited before 3 of its shards were stored"
        );
        assert!(
            Instant::now() < deadline,
            "make numbers did not store 3 shards within 2 minutes"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let status = kill_and_wait(&mut child);
    assert_eq!(status.code(), None, "make numbers finished before its kill");
    let finished = shard_files(&p.store, "numbers");
    let stage_keys: BTreeSet<&str> = finished.values().map(|s| s.stage_key.as_str()).collect();
    let [stage_key] = stage_keys.into_iter().collect::<Vec<_>>()[..] else {
        panic!("shards of more than one stage key: {finished:?}");
    };
    assert!(finished.len() < SHARDS, "{finished:?}");
    assert!(
        !records(&p).contains_key(stage_key),
        "numbers@0 has its own record: the kill came after the stage was complete"
    );
    // The shards belong to the build the plan asks for now, which is what gc keeps them for.
    let status = json(&run_ok(&p, &["status", "--json"]));
    let numbers = status
        .as_array()
        .expect("status array")
        .iter()
        .find(|s| s["instance"] == "numbers@0")
        .expect("numbers@0 in status")
        .clone();
    assert_eq!(numbers["key"], stage_key, "{numbers}");
    assert_eq!(numbers["state"], "missing", "{numbers}");

    let gc = run_ok(&p, &["gc"]);
    eprintln!("{}", stderr(&gc).trim());
    assert_eq!(
        shard_files(&p.store, "numbers"),
        finished,
        "gc removed or rewrote shards of the interrupted stage:\n{}",
        shown(&["gc"], &gc)
    );
    // Their objects too: verify reports a record whose object is gone.
    run_ok(&p, &["verify"]);

    let args = ["make", "--jobs", "2", "--json"];
    let out = run_ok(&p, &args);
    let resumed = report(&out);
    assert_eq!(
        resumed["numbers@0"].outcome,
        "built",
        "{}",
        shown(&args, &out)
    );
    let after = shard_files(&p.store, "numbers");
    assert_eq!(after.len(), SHARDS, "{after:?}");
    assert!(
        after.values().all(|s| s.stage_key == stage_key),
        "{after:?}"
    );
    // A computed shard's record is written anew; an unchanged one was loaded.
    let (loaded, computed): (Vec<_>, Vec<_>) = after
        .iter()
        .partition(|(key, s)| finished.get(*key) == Some(*s));
    let starts = |shards: &[(&String, &ShardFile)]| -> BTreeSet<u64> {
        shards.iter().map(|(_, s)| s.start).collect()
    };
    let finished_starts: BTreeSet<u64> = finished.values().map(|s| s.start).collect();
    eprintln!(
        "shards finished before the kill (first items): {finished_starts:?}; the resume loaded \
         {} and computed {}",
        loaded.len(),
        computed.len()
    );
    assert_eq!(
        starts(&loaded),
        finished_starts,
        "the resume must load every shard finished before the kill and compute only the rest \
         (first items of the shards it computed: {:?})",
        starts(&computed)
    );
    assert_eq!(computed.len(), SHARDS - finished.len());
    assert_eq!(
        report_hashes(&resumed),
        ref_hashes,
        "resumed vs uninterrupted"
    );
    assert_eq!(
        records(&p),
        records(&reference),
        "index after kill, gc and resume vs uninterrupted"
    );
    run_ok(&p, &["verify"]);
}

/// A make killed while it creates its store, or two processes creating one store at once, must
/// leave a directory that is an osms store (or nothing), never one every later command refuses
/// as foreign.
#[test]
fn a_store_being_created_is_never_taken_for_a_foreign_directory() {
    let p = Project::new(&sleepy_pipeline(4, 2, 0));
    // `args` on `store` exit 0; `state` says what the store held, for the message.
    let succeeds = |store: &Path, args: &[&str], state: &str| {
        let out = command_with_store(&p.pipeline, store, args)
            .output()
            .expect("run osms-test");
        assert_eq!(
            out.status.code(),
            Some(0),
            "{} of {state}:\n{}",
            args[0],
            shown(args, &out)
        );
    };

    // Kill points 0, 0.5, 1, ... 20 ms after the start cover the creation of the store in any
    // start-up time of the binary; the first make that gets further builds on it. Where each
    // kill landed: before the store's directory existed, during its creation (the directory
    // without the marker or without every subdirectory), or after it.
    let mut landed = [0usize; 3];
    // Then 25 to 200 ms: after the creation even on a loaded machine.
    let delays = (0..=40u64)
        .map(|step| 500 * step)
        .chain([25_000, 50_000, 100_000, 200_000]);
    for (step, micros) in delays.enumerate() {
        let store = p.dir.path().join(format!("killed-{step}"));
        let mut child = command_with_store(&p.pipeline, &store, &["make", "--jobs", "1"])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("spawn osms-test make");
        std::thread::sleep(Duration::from_micros(micros));
        kill_and_wait(&mut child);
        let left = if store.exists() {
            dir_entries(&store)
        } else {
            vec![]
        };
        let complete = ["OSMS_STORE", "objects", "index", "state", "tmp"]
            .iter()
            .all(|e| store.join(e).exists());
        landed[if !store.exists() {
            0
        } else if complete {
            2
        } else {
            1
        }] += 1;
        succeeds(
            &store,
            &["verify"],
            &format!("a store whose creation was killed after {micros} us (it holds {left:?})"),
        );
    }
    eprintln!(
        "store-creation kills: {} before the directory, {} during its creation, {} after",
        landed[0], landed[1], landed[2]
    );
    // The kill points straddle the creation: some kills land before the store is complete
    // (before its directory exists, or during its creation) and some after it; the states in
    // between are made below. Load can delay the parent's kill as much as the child's work
    // (seen beside a make: no kill before the directory, 10 during, 35 after), so the earliest
    // kills need not find the directory missing; the last one is 200 ms in.
    assert!(
        landed[0] + landed[1] > 0 && landed[2] > 0,
        "the kills did not straddle the store's creation: {landed:?}"
    );

    // A kill inside the creation's microseconds is luck, so every state it can leave is made
    // here, in the order the creation passes through them: the directory alone, the marker's
    // dot-file half written, the marker without the subdirectories, the marker with some of
    // them. Each is taken for a store being created, never for a foreign directory: `verify`
    // passes and a make builds in it.
    let subdirs = ["objects", "index", "state", "tmp"];
    for k in 0..=subdirs.len() + 2 {
        let store = p.dir.path().join(format!("during-{k}"));
        std::fs::create_dir_all(&store).expect("mkdir");
        match k {
            0 => {}
            1 => std::fs::write(store.join(".OSMS_STORE.tmp-1-0"), b"osms st").expect("write"),
            _ => {
                // The marker's text, as `Store::open` writes it.
                std::fs::write(store.join("OSMS_STORE"), "osms store, layout 1\n").expect("write");
                for d in &subdirs[..k - 2] {
                    std::fs::create_dir(store.join(d)).expect("mkdir");
                }
            }
        }
        let state = format!(
            "a creation stopped at state {k} ({:?})",
            dir_entries(&store)
        );
        succeeds(&store, &["verify"], &state);
        succeeds(&store, &["make", "--jobs", "1"], &state);
    }

    // Two processes opening a store that does not exist yet.
    for round in 0..10 {
        let store = p.dir.path().join(format!("concurrent-{round}"));
        let spawn = || {
            command_with_store(&p.pipeline, &store, &["status"])
                .stdin(Stdio::null())
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .expect("spawn osms-test status")
        };
        let (a, b) = (spawn(), spawn());
        for child in [a, b] {
            let out = child.wait_with_output().expect("wait");
            assert_eq!(
                out.status.code(),
                Some(0),
                "round {round}: two processes creating {} at once:\n{}",
                store.display(),
                shown(&["status"], &out)
            );
        }
    }
}

// ---------------------------------------------------------------------------------------------
// 2. Concurrent makers

/// Spawns `make --jobs 1 --json` with stdout and stderr piped; a thread forwards stderr lines
/// to `events` as `(who, Some(line))` and ends with `(who, None)`, returning them all.
fn spawn_maker(
    p: &Project,
    who: usize,
    events: mpsc::Sender<(usize, Option<String>)>,
) -> (Child, std::thread::JoinHandle<Vec<String>>) {
    spawn_osms(p, who, &["make", "--jobs", "1", "--json"], events)
}

/// Spawns `osms-test ARGS` as [`spawn_maker`] does.
fn spawn_osms(
    p: &Project,
    who: usize,
    args: &[&str],
    events: mpsc::Sender<(usize, Option<String>)>,
) -> (Child, std::thread::JoinHandle<Vec<String>>) {
    let mut child = command(p, args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn osms-test make");
    let err = child.stderr.take().expect("piped stderr");
    let reader = std::thread::spawn(move || {
        let mut lines = Vec::new();
        for line in BufReader::new(err).lines() {
            let line = line.expect("read stderr");
            let _ = events.send((who, Some(line.clone())));
            lines.push(line);
        }
        let _ = events.send((who, None));
        lines
    });
    (child, reader)
}

/// Both makers' reports and stderr, after both exited 0.
fn finish_makers(
    makers: Vec<(Child, std::thread::JoinHandle<Vec<String>>)>,
) -> Vec<(BTreeMap<String, Inst>, String)> {
    makers
        .into_iter()
        .enumerate()
        .map(|(who, (child, reader))| {
            let out = child.wait_with_output().expect("wait for make");
            let err = reader.join().expect("stderr reader").join("\n");
            assert_eq!(
                out.status.code(),
                Some(0),
                "maker {who}:\nstdout:\n{}\nstderr:\n{err}",
                stdout(&out)
            );
            (report(&out), err)
        })
        .collect()
}

/// One maker built every instance, the other found every instance cached, and the hashes agree
/// with each other and with `expected`.
fn check_makers_agree(
    results: &[(BTreeMap<String, Inst>, String)],
    expected: &BTreeMap<String, String>,
) -> usize {
    assert_eq!(results.len(), 2);
    let all = |r: &BTreeMap<String, Inst>, o: &str| r.values().all(|i| i.outcome == o);
    let builder = match (all(&results[0].0, "built"), all(&results[1].0, "built")) {
        (true, false) => 0,
        (false, true) => 1,
        _ => panic!(
            "exactly one maker must build everything:\n{:?}\n{:?}\nstderr 0:\n{}\nstderr 1:\n{}",
            results[0].0, results[1].0, results[0].1, results[1].1
        ),
    };
    let other = &results[1 - builder];
    assert!(
        all(&other.0, "cached"),
        "the maker that did not build must find everything cached: {:?}\nstderr:\n{}",
        other.0,
        other.1
    );
    assert_eq!(&report_hashes(&results[0].0), expected, "maker 0");
    assert_eq!(&report_hashes(&results[1].0), expected, "maker 1");
    builder
}

fn check_store_complete(p: &Project) {
    let status = json(&run_ok(p, &["status", "--json"]));
    let status = status.as_array().expect("status array");
    assert_eq!(status.len(), 7);
    for s in status {
        assert_eq!(s["state"], "cached", "{s}");
    }
    run_ok(p, &["verify"]);
}

#[test]
fn two_concurrent_makers_serialise_and_agree() {
    // About 0.5 s with one thread: 24 items of 20 ms.
    let pipeline = sleepy_pipeline(24, 4, 20);
    let reference = Project::new(&pipeline);
    let expected = report_hashes(&report(&run_ok(
        &reference,
        &["make", "--jobs", "1", "--json"],
    )));
    assert_eq!(expected.len(), 7);

    // (a) Started together: whichever takes the lock first builds, the other waits for it (or,
    // started late, finds everything cached without waiting).
    let p = Project::new(&pipeline);
    // Created first: two processes creating one store is the subject of
    // `a_store_being_created_is_never_taken_for_a_foreign_directory`.
    run_ok(&p, &["verify"]);
    let (tx, rx) = mpsc::channel();
    let makers = vec![spawn_maker(&p, 0, tx.clone()), spawn_maker(&p, 1, tx)];
    drop(rx);
    let results = finish_makers(makers);
    let builder = check_makers_agree(&results, &expected);
    eprintln!(
        "racing makers: maker {builder} built; the other {}",
        if results[1 - builder].1.contains(WAITING) {
            "waited for the lock, then found everything cached"
        } else {
            "found everything cached without waiting"
        }
    );
    assert!(
        !results[builder].1.contains(WAITING),
        "the builder never waits: the store was unlocked until one of them took it:\n{}",
        results[builder].1
    );
    check_store_complete(&p);

    // (b) Contention made certain: the test holds the lock until both makers say they wait, so
    // both are blocked on it when it is released.
    let p = Project::new(&pipeline);
    let store = p.open_store();
    let lock = store.lock(|| {}).expect("take the store lock");
    let (tx, rx) = mpsc::channel();
    let makers = vec![spawn_maker(&p, 0, tx.clone()), spawn_maker(&p, 1, tx)];
    let mut waiting = [false; 2];
    let mut seen = [Vec::new(), Vec::new()];
    while waiting != [true, true] {
        let (who, line) = rx.recv().expect("both stderr readers report");
        match line {
            Some(line) => {
                waiting[who] |= line.contains(WAITING);
                seen[who].push(line);
            }
            None => panic!(
                "maker {who} ended without waiting for the lock the test holds:\n{}",
                seen[who].join("\n")
            ),
        }
    }
    drop(lock);
    let results = finish_makers(makers);
    for (who, (_, err)) in results.iter().enumerate() {
        assert!(err.contains(WAITING), "maker {who}:\n{err}");
    }
    let builder = check_makers_agree(&results, &expected);
    eprintln!(
        "blocked makers: maker {builder} built, the other waited and found everything cached"
    );
    check_store_complete(&p);
}

/// Waits until process `who` writes a stderr line containing `text`; panics if it ends first.
fn wait_for_line(rx: &mpsc::Receiver<(usize, Option<String>)>, who: usize, text: &str) {
    let mut seen = Vec::new();
    loop {
        let (from, line) = rx.recv().expect("the stderr readers report");
        if from != who {
            continue;
        }
        match line {
            Some(line) if line.contains(text) => return,
            Some(line) => seen.push(line),
            None => panic!(
                "process {who} ended without writing `{text}`:\n{}",
                seen.join("\n")
            ),
        }
    }
}

/// Waits for a process of [`spawn_osms`]: its exit code and stderr.
fn finish(process: (Child, std::thread::JoinHandle<Vec<String>>)) -> (Option<i32>, String) {
    let (child, reader) = process;
    let out = child.wait_with_output().expect("wait for osms-test");
    (
        out.status.code(),
        reader.join().expect("stderr reader").join("\n"),
    )
}

/// Starts `first`, waits until it builds (it holds the store lock then, for seconds), starts
/// `second` and waits until it waits for the lock; returns both, still running. The events of
/// the two stay in `rx` for the caller to drain.
#[allow(clippy::type_complexity)]
fn second_waits_for_first(
    p: &Project,
    first: &[&str],
    second: &[&str],
) -> [(Child, std::thread::JoinHandle<Vec<String>>); 2] {
    let (tx, rx) = mpsc::channel();
    let a = spawn_osms(p, 0, first, tx.clone());
    wait_for_line(&rx, 0, "building");
    let b = spawn_osms(p, 1, second, tx);
    wait_for_line(&rx, 1, WAITING);
    // The readers keep sending; a dropped receiver only makes their sends fail, which they
    // ignore.
    drop(rx);
    [a, b]
}

/// `gc` decides what to keep after it holds the lock: a `make --seeds 9` that held the lock
/// when gc started, before any `@9` artifact existed, and finished while gc waited keeps
/// every `@9` artifact.
#[test]
fn a_gc_that_waited_for_a_make_keeps_the_seeds_that_make_built() {
    // About 2.4 s with one thread: 24 items of 100 ms, so gc starts long before the first
    // instance is done.
    let p = Project::new(&sleepy_pipeline(24, 4, 100));
    run_ok(&p, &["make", "--jobs", "1"]);
    let [make, gc] = second_waits_for_first(&p, &["make", "--jobs", "1", "--seeds", "9"], &["gc"]);
    let (make_code, make_err) = finish(make);
    let (gc_code, gc_err) = finish(gc);
    assert_eq!(make_code, Some(0), "make:\n{make_err}");
    assert_eq!(gc_code, Some(0), "gc:\n{gc_err}");
    assert!(
        gc_err.contains("[0, 9]"),
        "gc keeps seeds 0 and 9:\n{gc_err}"
    );
    let status = json(&run_ok(&p, &["status", "--seeds", "9", "--json"]));
    for s in status.as_array().expect("status array") {
        assert_eq!(s["state"], "cached", "{s}");
    }
    run_ok(&p, &["verify"]);
}

/// `exp run` holds the lock from its make through saving its record: a `gc` that waited for
/// the make finds the experiment and keeps what it names (instances no profile makes current),
/// and `verify` checks that.
#[test]
fn a_gc_that_waited_for_an_experiment_keeps_what_the_experiment_records() {
    let p = Project::new(&sleepy_pipeline(24, 4, 100));
    let run = [
        "exp",
        "run",
        "scaled",
        "--jobs",
        "1",
        "--set",
        "numbers.scale=3.0",
        "total",
    ];
    let [exp, gc] = second_waits_for_first(&p, &run, &["gc"]);
    let (exp_code, exp_err) = finish(exp);
    let (gc_code, gc_err) = finish(gc);
    assert_eq!(exp_code, Some(0), "exp run:\n{exp_err}");
    assert_eq!(gc_code, Some(0), "gc:\n{gc_err}");
    assert!(
        gc_err.contains("only named experiments hold"),
        "gc kept the experiment's instances:\n{gc_err}"
    );
    run_ok(&p, &["verify"]);
    // verify fails once an experiment names an object the store lost.
    let store = p.open_store();
    let record = osms_make::experiment::load(&store, "scaled")
        .expect("read the record")
        .expect("the experiment is recorded");
    let hash = record.points[0]
        .instances
        .iter()
        .find(|i| i.stage == "total")
        .expect("a `total` instance")
        .content_hash;
    std::fs::remove_file(store.object_path(&hash)).expect("remove the object");
    let out = run_expect(&p, &["verify"], 1);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("of experiment `scaled` (total"),
        "{}",
        shown(&["verify"], &out)
    );
}

/// Two `exp run`s of one name at once: one records it, the other (which waited for the lock)
/// fails and names the other process, unless `--force`.
#[test]
fn of_two_experiments_of_one_name_at_once_one_is_recorded_and_the_other_refused() {
    let p = Project::new(&sleepy_pipeline(24, 4, 100));
    let run = [
        "exp",
        "run",
        "twice",
        "--jobs",
        "1",
        "--set",
        "numbers.scale=3.0",
        "total",
    ];
    let [first, second] = second_waits_for_first(&p, &run, &run);
    let (first_code, first_err) = finish(first);
    let (second_code, second_err) = finish(second);
    assert_eq!(first_code, Some(0), "first:\n{first_err}");
    assert_eq!(second_code, Some(1), "second:\n{second_err}");
    assert!(
        second_err.contains("was recorded by another osms process"),
        "{second_err}"
    );
    let forced: Vec<&str> = run.iter().copied().chain(["--force"]).collect();
    run_ok(&p, &forced);
    run_ok(&p, &["verify"]);
}

/// `status` takes no lock, but may save what it learnt about objects; a command taking the lock
/// meanwhile (and clearing `tmp/`, where writes are in flight) must not make it fail.
#[test]
fn status_alongside_locking_commands_always_succeeds() {
    const ROUNDS: u64 = 20;
    let p = Project::new(&sleepy_pipeline(4, 2, 0));
    let seeds: Vec<String> = (0..ROUNDS).map(|s| s.to_string()).collect();
    run_ok(&p, &["make", "--jobs", "2", "--seeds", &seeds.join(",")]);
    // Old objects are the ones a status may remember as verified (and so save something).
    std::thread::sleep(Duration::from_secs(3));
    for round in 0..ROUNDS {
        let seed = round.to_string();
        let args = ["status", "--seed", &seed];
        let status = command(&p, &args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn osms-test status");
        for _ in 0..3 {
            run_ok(&p, &["verify"]);
        }
        let out = status.wait_with_output().expect("wait for status");
        assert_eq!(
            out.status.code(),
            Some(0),
            "round {round}: status while verify takes the lock:\n{}",
            shown(&args, &out)
        );
        assert!(
            stdout(&out).contains("up to date"),
            "{}",
            shown(&args, &out)
        );
    }
    run_ok(&p, &["verify"]);
}

// ---------------------------------------------------------------------------------------------
// 3. Damaged, truncated and deleted objects

#[test]
fn damaged_and_truncated_objects_are_detected_reported_and_rebuilt() {
    let p = Project::new(ENGINE_PIPELINE);
    let make = ["make", "--profile", "tiny", "--jobs", "2", "--json"];
    let first = report(&run_ok(&p, &make));
    let hashes = report_hashes(&first);
    assert_eq!(hashes.len(), 7, "{hashes:?}");
    let target = "numbers@0";
    let hex = hashes[target].clone();
    let short = &hex[..12];
    let path = object_path(&p.store, &hex);
    let original = std::fs::read(&path).expect("read the object of numbers@0");
    assert_eq!(Hash::of(&original).to_hex(), hex);
    assert!(original.len() > 16, "{} bytes", original.len());
    // Let the objects age, then read them all again, so that anything remembering verified
    // objects by their file metadata (and distrusting files changed moments before) trusts
    // them when they are damaged: damage must be found all the same.
    std::thread::sleep(Duration::from_secs(3));
    let cached = report(&run_ok(&p, &make));
    assert!(cached.values().all(|i| i.outcome == "cached"), "{cached:?}");
    run_ok(&p, &["status", "--profile", "tiny"]);
    run_ok(&p, &["verify"]);

    type Harm = fn(&Path, &[u8]);
    let harms: [(&str, Harm, &str); 3] = [
        (
            "one bit flipped",
            |path, bytes| {
                let mut b = bytes.to_vec();
                let mid = b.len() / 2;
                b[mid] ^= 0x08;
                std::fs::write(path, b).expect("write");
            },
            "damaged",
        ),
        (
            "truncated to half",
            |path, bytes| std::fs::write(path, &bytes[..bytes.len() / 2]).expect("write"),
            "damaged",
        ),
        (
            "deleted",
            |path, _| std::fs::remove_file(path).expect("remove"),
            "missing",
        ),
    ];

    for (what, harm, word) in harms {
        harm(&path, &original);

        let verify = run_expect(&p, &["verify"], 1);
        let text = stdout(&verify);
        assert!(
            text.contains(short) && text.contains(word),
            "{what}: verify must name {short} as {word}:\n{}",
            shown(&["verify"], &verify)
        );
        let vj = json(&run_expect(&p, &["verify", "--json"], 1));
        let problems = vj["problems"].as_array().expect("problems");
        assert_eq!(problems.len(), 1, "{what}: {vj}");
        let tag = if word == "damaged" {
            "damaged_object"
        } else {
            "missing_object"
        };
        assert_eq!(problems[0]["problem"], tag, "{what}: {vj}");
        assert_eq!(problems[0]["hash"], hex.as_str(), "{what}: {vj}");

        let args = ["status", "--profile", "tiny"];
        let status = run_ok(&p, &args);
        let line = stdout(&status)
            .lines()
            .find(|l| l.contains(target))
            .map(str::to_string)
            .unwrap_or_else(|| {
                panic!(
                    "{what}: status does not list {target}:\n{}",
                    shown(&args, &status)
                )
            });
        assert!(
            line.starts_with("missing")
                && line.contains(short)
                && line.contains(&format!("is {word}")),
            "{what}: {line}"
        );
        let sj = json(&run_ok(&p, &["status", "--profile", "tiny", "--json"]));
        let st = sj
            .as_array()
            .expect("status array")
            .iter()
            .find(|s| s["instance"] == target)
            .expect("numbers@0 in status")
            .clone();
        assert_eq!(st["state"], "missing", "{what}: {st}");
        assert_eq!(
            st["reasons"][0]["reason"],
            format!("object_{word}"),
            "{what}: {st}"
        );

        let out = run_ok(&p, &make);
        let again = report(&out);
        let inst = &again[target];
        assert_eq!(inst.outcome, "built", "{what}: {inst:?}");
        let reason = inst.reason.clone().unwrap_or_default();
        assert!(reason.contains(word), "{what}: reason `{reason}`");
        for (name, i) in &again {
            if name != target {
                assert!(
                    i.outcome == "cached" || i.outcome == "cut_off",
                    "{what}: only {target} is rebuilt, but {name} is {i:?}"
                );
            }
        }
        assert_eq!(report_hashes(&again), hashes, "{what}: rebuilt hashes");
        let repaired = std::fs::read(&path).expect("read the rebuilt object");
        assert_eq!(Hash::of(&repaired).to_hex(), hex, "{what}");
        assert_eq!(repaired, original, "{what}");
        run_ok(&p, &["verify"]);
    }
}

// ---------------------------------------------------------------------------------------------
// 4. Files that are not osms's

#[test]
fn foreign_file_in_store_is_refused() {
    let p = Project::new(ENGINE_PIPELINE);

    // (a) A directory of someone else's is not taken for a store, whatever the command.
    let theirs = p.dir.path().join("my-documents");
    std::fs::create_dir(&theirs).expect("mkdir");
    let notes = theirs.join("notes.txt");
    let content = "shopping: milk, bread\n";
    std::fs::write(&notes, content).expect("write notes");
    for args in [
        &["make", "--profile", "tiny"][..],
        &["verify"],
        &["gc"],
        &["status"],
    ] {
        let out = command_with_store(&p.pipeline, &theirs, args)
            .output()
            .expect("run osms-test");
        assert_eq!(out.status.code(), Some(1), "{}", shown(args, &out));
        assert!(
            stderr(&out).contains("not an osms store"),
            "{}",
            shown(args, &out)
        );
        assert_eq!(dir_entries(&theirs), ["notes.txt"], "{args:?}");
        assert_eq!(
            std::fs::read_to_string(&notes).expect("read notes"),
            content
        );
    }

    // (b) Inside a real store: a file named by its own hash that is no artifact, and a file whose
    // name is no hash at all.
    run_ok(&p, &["make", "--profile", "tiny"]);
    run_ok(&p, &["verify"]);
    let junk = b"these bytes were never an osms artifact\n";
    let hex = Hash::of(junk).to_hex();
    let foreign = object_path(&p.store, &hex);
    std::fs::create_dir_all(foreign.parent().expect("parent")).expect("mkdir");
    std::fs::write(&foreign, junk).expect("write foreign object");
    let stray = p.store.join("objects").join("ab").join("README");
    std::fs::create_dir_all(stray.parent().expect("parent")).expect("mkdir");
    std::fs::write(&stray, "not an object\n").expect("write README");

    let out = run_expect(&p, &["verify"], 1);
    let text = stdout(&out);
    let line_with = |word: &str| {
        text.lines()
            .find(|l| l.starts_with(word))
            .map(str::to_string)
    };
    let foreign_line =
        line_with("foreign").unwrap_or_else(|| panic!("{}", shown(&["verify"], &out)));
    assert!(foreign_line.contains(&hex), "{foreign_line}");
    let stray_line = line_with("stray").unwrap_or_else(|| panic!("{}", shown(&["verify"], &out)));
    assert!(stray_line.contains("README"), "{stray_line}");
    assert!(
        stderr(&out).contains("2 problem(s)"),
        "{}",
        shown(&["verify"], &out)
    );

    let vj = json(&run_expect(&p, &["verify", "--json"], 1));
    let mut tags: Vec<&str> = vj["problems"]
        .as_array()
        .expect("problems")
        .iter()
        .map(|pr| pr["problem"].as_str().expect("problem tag"))
        .collect();
    tags.sort_unstable();
    assert_eq!(tags, ["foreign_object", "stray_file"], "{vj}");

    // Neither file is read as an artifact nor touched by make.
    let again = report(&run_ok(&p, &["make", "--profile", "tiny", "--json"]));
    assert!(again.values().all(|i| i.outcome == "cached"), "{again:?}");
    assert_eq!(std::fs::read(&foreign).expect("read foreign"), junk);
    assert!(stray.is_file());
}
