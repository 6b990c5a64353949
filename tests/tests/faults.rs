//! Storage faults and closed pipes (issue 75), end to end on the real command line: each test
//! is a row of docs/store.md's fault table and says what a user sees.

use std::path::Path;
use std::process::{Output, Stdio};

use osms_tests::Project;

const BIN: &str = env!("CARGO_BIN_EXE_osms-test");

fn bin() -> &'static Path {
    Path::new(BIN)
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn no_panic(o: &Output) {
    let err = stderr(o);
    assert!(!err.contains("panicked"), "{err}");
    assert_ne!(o.status.code(), Some(101), "{err}");
}

/// `osms ARGS` on the project's pipeline with the store at `store` (a mount of the project's
/// own store, or one on a filesystem of the test's), checked for panics.
fn run_on(p: &Project, store: &Path, args: &[&str]) -> Output {
    let o = p.command_on(bin(), store, args).output().expect("run osms");
    no_panic(&o);
    o
}

/// `osms … | head -1`: the reader is gone before osms writes, so its first write to stdout
/// fails with EPIPE; osms ends quietly with 141, as a C tool killed by SIGPIPE.
#[test]
fn a_closed_stdout_ends_quietly_with_the_closed_pipe_status() {
    let p = Project::engine();
    assert!(p.run(bin(), &["make", "-q"]).status.success());
    for args in [&["kinds"][..], &["status", "--json"], &["ls"]] {
        let (reader, writer) = std::io::pipe().expect("pipe");
        drop(reader);
        let o = p
            .command(bin(), args)
            .stdout(writer)
            .stderr(Stdio::piped())
            .output()
            .expect("run osms");
        no_panic(&o);
        assert_eq!(o.status.code(), Some(141), "osms {args:?}: {}", stderr(&o));
        assert_eq!(stderr(&o), "", "osms {args:?}");
    }
}

/// stdout on a full disk is not a closed pipe: the user is told, exit 1.
#[test]
fn stdout_on_a_full_disk_is_an_error_that_says_so() {
    let p = Project::engine();
    let full = std::fs::File::create("/dev/full").expect("/dev/full");
    let o = p
        .command(bin(), &["kinds"])
        .stdout(full)
        .output()
        .expect("run osms");
    no_panic(&o);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("error: cannot write to standard output: No space left on device"),
        "{}",
        stderr(&o)
    );
}

/// stderr that cannot be written (a full disk here; EIO the same) drops the log lines, not the
/// command: the make builds everything, and a failing command still exits 1, not in a panic.
#[test]
fn a_failing_stderr_drops_the_lines_and_the_command_goes_on() {
    let p = Project::engine();
    let full = || std::fs::File::create("/dev/full").expect("/dev/full");
    let o = p
        .command(bin(), &["make", "-v"])
        .stderr(full())
        .output()
        .expect("run osms");
    no_panic(&o);
    assert!(o.status.success(), "{:?}", o.status);
    let again = p.run(bin(), &["status", "--json"]);
    let status: serde_json::Value = serde_json::from_slice(&again.stdout).expect("json");
    let items = status.as_array().expect("one item per instance");
    assert!(!items.is_empty());
    assert!(items.iter().all(|i| i["state"] == "cached"), "{status}");
    let o = p
        .command(bin(), &["show", "no_such_stage"])
        .stderr(full())
        .output()
        .expect("run osms");
    no_panic(&o);
    assert_eq!(o.status.code(), Some(1));
}

/// Logs written to a file (or any non-terminal) carry no ANSI colour codes.
#[test]
fn logs_in_a_file_carry_no_colour() {
    let p = Project::engine();
    let config = p.dir.path().join("config.toml");
    std::fs::write(
        &config,
        "[executor.slurm.stages.not_in_this_pipeline]\ncpus_per_task = 2\n",
    )
    .expect("write config");
    let o = p
        .command(bin(), &["-v", "make", "--dry-run"])
        .env("OSMS_CONFIG", &config)
        .output()
        .expect("run osms");
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("for stages this pipeline does not declare: not_in_this_pipeline"),
        "the debug log line: {err}"
    );
    assert!(!err.contains('\u{1b}'), "{err:?}");
}

/// A damaged object: `verify` names the stage whose output it is, and `make` rebuilds it.
#[test]
fn verify_names_the_stage_of_a_damaged_object_and_make_rebuilds_it() {
    let p = Project::engine();
    assert!(p.run(bin(), &["make", "-q"]).status.success());
    let store = p.open_store();
    let (records, _) = store.records().expect("records");
    let r = records
        .iter()
        .find(|r| r.shard.is_none() && r.parts.is_empty())
        .expect("a plain stage output");
    let path = store.object_path(&r.content_hash);
    let mut bytes = std::fs::read(&path).expect("read");
    let last = bytes.len() - 1;
    bytes[last] ^= 0x55;
    std::fs::write(&path, &bytes).expect("damage");
    let o = p.run(bin(), &["verify"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    let named = format!("output of {} (key {})", r.stage, r.key.short());
    assert!(out.contains(&named), "{out}");
    assert!(p.run(bin(), &["make", "-q"]).status.success());
    let o = p.run(bin(), &["verify"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));
}

/// Whether `strace` can trace here (installed, and ptrace allowed); otherwise the check is
/// logged as skipped (`scripts/test` lists it), never passed silently.
fn strace_usable(check: &str) -> bool {
    let ok = std::process::Command::new("strace")
        .args(["-qq", "-o", "/dev/null", "true"])
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        osms_tests::golden::Mode::from_env().log_skip(&format!(
            "tests/faults.rs {check}: strace cannot trace here"
        ));
    }
    ok
}

/// `osms ARGS` on the project run under `strace -f TRACE…` (the faults it injects), checked
/// for panics.
fn under_strace(p: &Project, trace: &[&str], args: &[&str]) -> Output {
    let o = std::process::Command::new("strace")
        .args(["-f", "-qq", "-o", "/dev/null"])
        .args(trace)
        .arg(BIN)
        .arg("--pipeline")
        .arg(&p.pipeline)
        .arg("--store")
        .arg(&p.store)
        .args(args)
        .env("OSMS_NO_PROGRESS", "1")
        .env("OSMS_STAGES", "1")
        .output()
        .expect("run strace");
    no_panic(&o);
    o
}

/// Field `name` of `instance` in `osms status --json`'s output.
fn status_field(status: &serde_json::Value, instance: &str, name: &str) -> String {
    status
        .as_array()
        .expect("items")
        .iter()
        .find(|i| i["instance"] == instance)
        .and_then(|i| i[name].as_str())
        .expect("a field")
        .to_string()
}

/// Garbles the index record of `key`, so its stage builds again.
fn garble_record(p: &Project, key: &str) {
    let path = p.open_store().record_path(&key.parse().expect("a key"));
    std::fs::write(path, "garbled").expect("garble");
}

/// A record that cannot be written (ENOSPC injected on its rename) fails its stage, not the
/// make: the stages that need it are skipped, the others build, `--json` still reports, exit 1;
/// the next make builds what is missing and nothing else.
#[test]
fn a_record_that_cannot_be_written_fails_its_stage_and_the_make_goes_on() {
    if !strace_usable("a_record_that_cannot_be_written_fails_its_stage_and_the_make_goes_on") {
        return;
    }
    let p = Project::engine();
    assert!(p.run(bin(), &["make", "-q"]).status.success());
    let status: serde_json::Value =
        serde_json::from_slice(&p.run(bin(), &["status", "--json"]).stdout).expect("json");
    let key = |instance: &str| status_field(&status, instance, "key");
    // Two records garbled, so both stages build again, their objects already stored: the
    // main thread's first rename is total@0's record, the one strace fails; sign_total@0's
    // comes after it.
    let (total, sign_total) = (key("total@0"), key("sign_total@0"));
    for k in [&total, &sign_total] {
        garble_record(&p, k);
    }
    let o = under_strace(
        &p,
        &[
            "-e",
            "trace=rename",
            "-e",
            "inject=rename:error=ENOSPC:when=1",
        ],
        &["make", "--json", "--jobs", "1"],
    );
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let short = &total[..12];
    assert!(
        err.contains(&format!(
            "FAILED total@0: cannot record the output of this build (key {short}): I/O error on"
        )),
        "{err}"
    );
    assert!(
        err.contains("hint: no space left on the store's filesystem: free space and run `osms make` again; nothing built so far is lost"),
        "{err}"
    );
    assert!(
        err.contains("skipped report@0 (input total@0 failed)"),
        "{err}"
    );
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).expect("--json report");
    let outcome = |instance: &str| {
        report["instances"]
            .as_array()
            .expect("instances")
            .iter()
            .find(|i| i["instance"] == instance)
            .map(|i| i["outcome"].clone())
            .expect("reported")
    };
    assert_eq!(outcome("total@0"), "failed", "{report}");
    assert_eq!(outcome("sign_total@0"), "built", "{report}");

    let o = p.run(bin(), &["make", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let again: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let built: Vec<&str> = again["instances"]
        .as_array()
        .expect("instances")
        .iter()
        .filter(|i| i["outcome"] == "built")
        .map(|i| i["instance"].as_str().expect("name"))
        .collect();
    assert_eq!(built, ["total@0"], "{again}");
}

/// An I/O error on reading a stored object: `show` and `export` name the artifact and say
/// what to do, `verify` goes on and names the stage whose output it is, and the stage that
/// needs it as an input fails, naming the input, its producer, the object and the
/// filesystem's error; once the disk reads again, the next make builds it.
#[test]
fn an_unreadable_input_fails_the_stage_that_reads_it_and_says_whose_it_is() {
    let check = "an_unreadable_input_fails_the_stage_that_reads_it_and_says_whose_it_is";
    if !strace_usable(check) {
        return;
    }
    let p = Project::engine();
    assert!(p.run(bin(), &["make", "-q"]).status.success());
    // Once the objects are older than the stat cache's racy window, a status vouches for them,
    // so the make reads reference's object only as report@0's input (a lookup that re-hashes
    // it fails reference itself, with the same hint).
    std::thread::sleep(std::time::Duration::from_millis(2_500));
    let status: serde_json::Value =
        serde_json::from_slice(&p.run(bin(), &["status", "--json"]).stdout).expect("json");
    let field = |instance: &str, name: &str| status_field(&status, instance, name);
    // report@0 builds again (its record garbled) and reads reference's object, which fails.
    garble_record(&p, &field("report@0", "key"));
    let hash = field("reference", "content_hash");
    let object = p.open_store().object_path(&hash.parse().expect("a hash"));
    let object = object.to_str().expect("utf-8 path");
    let unreadable = |args: &[&str]| {
        under_strace(
            &p,
            &[
                "-P",
                object,
                "-e",
                "trace=openat",
                "-e",
                "inject=openat:error=EIO",
            ],
            args,
        )
    };
    let o = unreadable(&["make", "--jobs", "1"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!(
            "FAILED report@0: cannot read input `reference` (the output of reference, object {}): I/O error on",
            &hash[..12]
        )),
        "{err}"
    );
    assert!(err.contains("Input/output error"), "{err}");
    assert!(
        err.contains("hint: the store's filesystem returned an error: check the disk"),
        "{err}"
    );
    // Reading it directly: the artifact named, the hint, exit 1 (not an internal error).
    for args in [
        &["show", "reference"][..],
        &["export", "reference", "--out", "x"],
    ] {
        let o = unreadable(args);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "osms {args:?}: {err}");
        assert!(
            err.contains(&format!(
                "cannot read the output of reference@7 (object {})",
                &hash[..12]
            )),
            "{err}"
        );
        assert!(
            err.contains("hint: the store's filesystem returned an error: check the disk"),
            "{err}"
        );
    }
    // verify goes on past it and says whose output it is (and the stat cache stops vouching
    // for it, so a make would now fail `reference` itself when it re-hashes it).
    let o = unreadable(&["verify"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        out.contains(&format!("unreadable {}", &hash[..12]))
            && out.contains("Input/output error")
            && out.contains(": output of reference (key"),
        "{out}"
    );
    assert!(
        stderr(&o).contains("check the disk (`dmesg`)"),
        "{}",
        stderr(&o)
    );
    let o = p.run(bin(), &["make", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// A filesystem mounted for a test, unmounted on drop. Its constructors return `None` (and log
/// the check as skipped) where this process cannot mount.
struct Mount(std::path::PathBuf);

/// Runs `mount ARGS`; whether it succeeded.
fn mount(args: &[&str]) -> bool {
    std::process::Command::new("mount")
        .args(args)
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

impl Mount {
    /// `store` bind-mounted read-only at `at`.
    fn read_only(store: &Path, at: &Path, check: &str) -> Option<Self> {
        std::fs::create_dir_all(at).expect("mount point");
        let (s, a) = (store.to_str().expect("utf-8"), at.to_str().expect("utf-8"));
        if !mount(&["--bind", s, a]) {
            osms_tests::golden::Mode::from_env()
                .log_skip(&format!("tests/faults.rs {check}: cannot bind-mount here"));
            return None;
        }
        let guard = Mount(at.to_path_buf());
        assert!(mount(&["-o", "remount,ro,bind", a]), "remount read-only");
        Some(guard)
    }

    /// A tmpfs of `size` at `at`.
    fn tmpfs(at: &Path, size: &str, check: &str) -> Option<Self> {
        std::fs::create_dir_all(at).expect("mount point");
        let a = at.to_str().expect("utf-8");
        if !mount(&["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs", a]) {
            osms_tests::golden::Mode::from_env().log_skip(&format!(
                "tests/faults.rs {check}: cannot mount a tmpfs here"
            ));
            return None;
        }
        Some(Mount(at.to_path_buf()))
    }
}

impl Drop for Mount {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount").arg(&self.0).status();
    }
}

/// Fills the filesystem holding `dir` to the last byte.
fn fill_disk(dir: &Path) {
    use std::io::Write;
    let mut fill = std::fs::File::create(dir.join("fill")).expect("fill");
    let block = vec![7u8; 1 << 16];
    while fill.write_all(&block).is_ok() {}
    while fill.write_all(&block[..1]).is_ok() {}
}

/// A store on a read-only mount (an archived or shared store) serves every read, verify and a
/// fully cached make, even with a stale stat cache; building into it fails with a clear error.
#[test]
fn a_read_only_store_serves_reads_and_refuses_builds_clearly() {
    let p = Project::engine();
    assert!(p.run(bin(), &["make", "-q"]).status.success());
    // Objects younger than the stat cache's racy window are never cached; once older, a status
    // records them, and removing the cache makes the read-only run re-hash and try to save it.
    std::thread::sleep(std::time::Duration::from_millis(2_500));
    assert!(p.run(bin(), &["status", "-q"]).status.success());
    let cache = p.store.join("state").join("statcache");
    assert!(cache.is_file(), "the stat cache was saved");
    std::fs::remove_file(&cache).expect("stale cache");
    let at = p.dir.path().join("ro");
    let check = "a_read_only_store_serves_reads_and_refuses_builds_clearly";
    let Some(_mount) = Mount::read_only(&p.store, &at, check) else {
        return;
    };
    let ro = at.to_str().expect("utf-8");
    let run = |args: &[&str]| run_on(&p, &at, args);
    for args in [
        &["status"][..],
        &["ls"],
        &["show", "total"],
        &["why", "total"],
        &["make", "--dry-run"],
        &["make"],
        &["verify"],
        &["gc", "--dry-run"],
    ] {
        let o = run(args);
        assert!(o.status.success(), "osms {args:?}: {}", stderr(&o));
    }
    assert!(!cache.exists(), "nothing was written");
    let o = run(&["make", "--set", "reference.params.n=6"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains(&format!(
            "FAILED reference: store {ro} is read-only: cannot build `reference` (params changed"
        )),
        "{}",
        stderr(&o)
    );
    let o = run(&["gc"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains(&format!(
            "store {ro} is read-only: gc cannot remove anything"
        )),
        "{}",
        stderr(&o)
    );
}

/// On a full disk, `status` and a make with everything cached still work (the stat cache is
/// saved only where it can be): nothing had to be written.
#[test]
fn a_full_disk_with_everything_cached_still_answers() {
    let p = Project::engine();
    let disk = p.dir.path().join("disk");
    let check = "a_full_disk_with_everything_cached_still_answers";
    let Some(_tmpfs) = Mount::tmpfs(&disk, "8m", check) else {
        return;
    };
    let store = disk.join("store");
    let run = |args: &[&str]| run_on(&p, &store, args);
    assert!(run(&["make", "-q"]).status.success());
    // Old enough for the stat cache, which is then gone: status re-hashes and tries to save.
    std::thread::sleep(std::time::Duration::from_millis(2_500));
    let _ = std::fs::remove_file(store.join("state").join("statcache"));
    fill_disk(&disk);
    for args in [&["status"][..], &["make"], &["verify"], &["ls"]] {
        let o = run(args);
        assert!(o.status.success(), "osms {args:?}: {}", stderr(&o));
    }
    assert!(!store.join("state").join("statcache").exists());
}

/// A pull onto a full disk fails with what to do, leaves nothing half-written (verify is clean),
/// and once space is freed the same pull finishes with every object and record.
#[test]
fn a_pull_onto_a_full_disk_says_so_and_resumes_once_there_is_space() {
    let p = Project::engine();
    let remote = p.dir.path().join("remote");
    let text = std::fs::read_to_string(&p.pipeline).expect("pipeline");
    p.write_pipeline(&format!(
        "{text}\n[remotes.shared]\nurl = \"file://{}\"\n",
        remote.display()
    ));
    assert!(p.run(bin(), &["make", "-q"]).status.success());
    assert!(
        p.run(bin(), &["push", "-q", "-r", "shared"])
            .status
            .success()
    );
    let disk = p.dir.path().join("disk");
    let check = "a_pull_onto_a_full_disk_says_so_and_resumes_once_there_is_space";
    let Some(_tmpfs) = Mount::tmpfs(&disk, "8m", check) else {
        return;
    };
    let store = disk.join("store");
    let run = |args: &[&str]| run_on(&p, &store, args);
    assert!(run(&["verify", "-q"]).status.success());
    fill_disk(&disk);
    let o = run(&["pull", "-r", "shared"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("No space left on device"), "{err}");
    assert!(
        err.contains(
            "hint: no space left on the store's filesystem: free space and run the pull again"
        ),
        "{err}"
    );
    std::fs::remove_file(disk.join("fill")).expect("free space");
    let v = run(&["verify", "--json"]);
    let report: serde_json::Value = serde_json::from_slice(&v.stdout).expect("verify --json");
    assert_eq!(report["problems"], serde_json::json!([]), "{report}");
    assert_eq!(
        report["records_checked"], 0,
        "a record before its objects: {report}"
    );
    let o = run(&["pull", "-r", "shared", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let pulled: serde_json::Value = serde_json::from_slice(&o.stdout).expect("pull --json");
    assert!(
        pulled["instances"]
            .as_array()
            .expect("instances")
            .iter()
            .all(|i| i["outcome"] == "pulled"),
        "{pulled}"
    );
    assert!(run(&["verify", "-q"]).status.success());
}

/// A make that will not fit: before it starts, a warning says how much space the stages it
/// builds took when last measured (here: the tiny profile's builds, scaled to `small`).
#[test]
fn a_make_that_will_not_fit_is_warned_about_before_it_starts() {
    let p = Project::engine();
    let disk = p.dir.path().join("disk");
    let check = "a_make_that_will_not_fit_is_warned_about_before_it_starts";
    let Some(_tmpfs) = Mount::tmpfs(&disk, "8m", check) else {
        return;
    };
    let store = disk.join("store");
    let run = |args: &[&str]| run_on(&p, &store, args);
    assert!(run(&["make", "-q", "-p", "tiny"]).status.success());
    let dry = run(&["make", "--dry-run"]);
    assert!(stderr(&dry).contains("to store)"), "{}", stderr(&dry));
    fill_disk(&disk);
    let o = run(&["make"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let warned = err
        .find("warning: the store's filesystem has 0 B free, and this make will store ≈ ")
        .unwrap_or_else(|| panic!("{err}"));
    assert!(warned < err.find("building").unwrap_or(usize::MAX), "{err}");
    assert!(
        err.contains("hint: free space or use another --store first"),
        "{err}"
    );
    // Then the first write fails its stage with what it could not store and what to do.
    assert!(err.contains(": cannot store "), "{err}");
    assert!(
        err.contains("hint: no space left on the store's filesystem"),
        "{err}"
    );
}

/// A teacher killed mid-training (as by a full disk's failed write, an OOM kill or a lost node)
/// resumes from its last checkpoint, not from iteration 0, and ends with the bytes of a
/// training that ran through; the checkpoint's record outlives the kill.
#[test]
fn a_killed_teacher_resumes_from_its_checkpoint_to_the_same_bytes() {
    let shipped = Path::new(env!("CARGO_BIN_EXE_osms-shipped"));
    let pipeline = Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml");
    let dir = tempfile::tempdir().expect("temp dir");
    let osms = |store: &str, args: &[&str]| {
        let mut c = std::process::Command::new(shipped);
        c.arg("--pipeline")
            .arg(&pipeline)
            .arg("--store")
            .arg(dir.path().join(store))
            .args([
                "make",
                "teacher",
                "-p",
                "tiny",
                "--set",
                "teacher.ppo.iterations=40",
                "--set",
                "teacher.checkpoint_every=1",
            ])
            .args(args)
            .env("OSMS_NO_PROGRESS", "1")
            .env_remove("OSMS_LOG")
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        c
    };
    let checkpoint = |store: &osms_store::Store| {
        store
            .records()
            .expect("records")
            .0
            .into_iter()
            .find(|r| r.type_tag == osms_make::CHECKPOINT_TAG && r.stage == "teacher")
    };
    let mut child = osms("killed", &[]).spawn().expect("start osms");
    let killed_after = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            panic!("the training ended ({status}) before a checkpoint was seen");
        }
        if let Ok(store) = osms_store::Store::open_existing(dir.path().join("killed"))
            && let Some(r) = checkpoint(&store)
        {
            child.kill().expect("kill -9");
            child.wait().expect("reap");
            break r.shard.expect("a checkpoint names its build").end;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    assert!((1..40).contains(&killed_after), "{killed_after}");
    let store = osms_store::Store::open_existing(dir.path().join("killed")).expect("store");
    let r = checkpoint(&store).expect("the checkpoint outlives the kill");
    let done = r.shard.expect("shard").end;
    assert!(done >= killed_after, "{done} < {killed_after}");
    let resumed = osms("killed", &["--json"]).output().expect("run osms");
    no_panic(&resumed);
    assert!(resumed.status.success(), "{}", stderr(&resumed));
    assert!(
        stderr(&resumed).contains(&format!(
            "teacher: resuming from its checkpoint after {done} steps"
        )),
        "{}",
        stderr(&resumed)
    );
    let through = osms("through", &["--json"]).output().expect("run osms");
    assert!(through.status.success(), "{}", stderr(&through));
    assert!(
        !stderr(&through).contains("resuming"),
        "{}",
        stderr(&through)
    );
    let teacher_hash = |o: &Output| {
        let report: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
        report["instances"]
            .as_array()
            .expect("instances")
            .iter()
            .find(|i| i["instance"] == "teacher")
            .and_then(|i| i["content_hash"].as_str())
            .expect("teacher's hash")
            .to_string()
    };
    assert_eq!(teacher_hash(&resumed), teacher_hash(&through));
}
