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
