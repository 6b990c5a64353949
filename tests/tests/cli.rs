//! The real command line over a temporary project: exit codes, stdout and stderr snapshotted
//! under `golden/cli/`, with only the temp path and timings filtered (never hashes).

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Output;

use osms_tests::Project;

// A new user's path from the wheel alone; here rather than in a test binary of its own, so that
// its single-threaded teacher build overlaps the other tests of this binary.
#[path = "cli/newcomer.rs"]
mod newcomer;

const BIN: &str = env!("CARGO_BIN_EXE_osms-test");

/// A pipeline of pure-Rust kinds only, so its hashes are the same on every platform.
const CLI_PIPELINE: &str = r#"[pipeline]
default_profile = "small"
seed = 0

[stages.numbers]
kind = "numbers"
shards = 2
params = { n = 4, len = 2 }

[stages.signs]
kind = "signs"
inputs = { values = "numbers" }

[stages.total]
kind = "sum"
inputs = { values = "signs" }

[stages.shifted]
kind = "shift"
inputs = { values = "numbers" }
params = { by = 0.5 }

[profiles.tiny.numbers]
params = { n = 2 }
[profiles.small]
[profiles.paper]
"#;

/// Replaces `<digits>.<digits>s` with `[T]s`.
fn filter_timings(text: &str) -> String {
    let chars: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < chars.len() {
        let start = i;
        let mut j = i;
        while j < chars.len() && chars[j].is_ascii_digit() {
            j += 1;
        }
        let boundary = start == 0 || !chars[start - 1].is_ascii_alphanumeric();
        if j > start && boundary && j < chars.len() && chars[j] == '.' {
            let mut k = j + 1;
            while k < chars.len() && chars[k].is_ascii_digit() {
                k += 1;
            }
            if k > j + 1
                && k < chars.len()
                && chars[k] == 's'
                && (k + 1 == chars.len() || !chars[k + 1].is_ascii_alphanumeric())
            {
                out.push_str("[T]s");
                i = k + 1;
                continue;
            }
        }
        out.push(chars[i]);
        i += 1;
    }
    out
}

fn transcript(p: &Project, args: &[&str]) -> (String, Output) {
    let out = p.run(Path::new(BIN), args);
    (shown(p, args, &out), out)
}

/// `make`'s line on how busy the cores were, whose numbers are the machine's.
fn filter_cost(text: &str) -> String {
    const COST: &str = "osms make: the builds used ";
    text.split_inclusive('\n')
        .map(|l| {
            if l.starts_with(COST) {
                format!("{COST}[COST]\n")
            } else {
                l.to_string()
            }
        })
        .collect()
}

/// The transcript of `out`, the output of `osms ARGS`, with the project's path, timings and
/// the cost line's numbers filtered.
fn shown(p: &Project, args: &[&str], out: &Output) -> String {
    let dir = p.dir.path().display().to_string();
    let clean = |b: &[u8]| {
        filter_cost(&filter_timings(
            &String::from_utf8_lossy(b).replace(&dir, "[PROJECT]"),
        ))
    };
    format!(
        "$ osms {}\nexit: {}\n--- stdout\n{}--- stderr\n{}",
        clean(args.join(" ").as_bytes()),
        out.status
            .code()
            .map(|c| c.to_string())
            .unwrap_or_else(|| "signal".into()),
        clean(&out.stdout),
        clean(&out.stderr)
    )
}

fn session(p: &Project, commands: &[&[&str]]) -> String {
    commands
        .iter()
        .map(|args| transcript(p, args).0)
        .collect::<Vec<_>>()
        .join("\n")
}

fn settings() -> insta::Settings {
    let mut s = insta::Settings::clone_current();
    s.set_snapshot_path(Path::new(env!("CARGO_MANIFEST_DIR")).join("../golden/cli"));
    s.set_prepend_module_to_snapshot(false);
    s.set_omit_expression(true);
    s
}

#[test]
fn make_status_why_ls_show() {
    let p = Project::new(CLI_PIPELINE);
    let mut text = session(
        &p,
        &[
            &["status"],
            &["make"],
            &["make", "-v"],
            &["status"],
            &["status", "-q"],
            &["why", "total"],
            &["ls"],
        ],
    );
    let (ls, _) = transcript(&p, &["ls", "--json"]);
    let json_start = ls.find('[').expect("ls --json prints an array");
    let json_end = ls.rfind(']').expect("array end");
    let records: serde_json::Value =
        serde_json::from_str(&ls[json_start..=json_end]).expect("ls --json");
    let total = records
        .as_array()
        .and_then(|r| r.iter().find(|r| r["stage"] == "total"))
        .and_then(|r| r["key"].as_str())
        .expect("total's key")
        .to_string();
    text.push('\n');
    text.push_str(&transcript(&p, &["show", &total[..10]]).0);
    let (by_name, out) = transcript(&p, &["show", "total"]);
    assert!(out.status.success(), "{by_name}");
    assert_eq!(
        by_name.lines().skip(1).collect::<Vec<_>>(),
        transcript(&p, &["show", &total[..10]])
            .0
            .lines()
            .skip(1)
            .collect::<Vec<_>>(),
        "a stage name shows its current build"
    );

    p.write_pipeline(&CLI_PIPELINE.replace("params = { by = 0.5 }", "params = { by = 1.5 }"));
    text.push('\n');
    text.push_str(&session(
        &p,
        &[
            &["status"],
            &["status", "-q"],
            &["make", "--dry-run"],
            &["make"],
            &["status"],
        ],
    ));
    settings().bind(|| insta::assert_snapshot!("make_status_why_ls_show", text));
}

#[test]
fn seed_sweep_and_profiles() {
    let p = Project::new(CLI_PIPELINE);
    let text = session(
        &p,
        &[
            &["make", "--seeds", "0,1,2", "-v"],
            &["status", "--seed", "1", "-v"],
            &["make", "--profile", "tiny"],
            &["status", "-p", "tiny"],
        ],
    );
    settings().bind(|| insta::assert_snapshot!("seed_sweep_and_profiles", text));
}

#[test]
fn gc_and_verify() {
    let p = Project::new(CLI_PIPELINE);
    transcript(&p, &["make"]);
    p.write_pipeline(&CLI_PIPELINE.replace("params = { by = 0.5 }", "params = { by = 2.5 }"));
    let text = session(
        &p,
        &[
            &["make"],
            &["gc", "--dry-run", "--profile", "small"],
            &["gc", "--profile", "small"],
            &["verify"],
            &["status"],
        ],
    );
    settings().bind(|| insta::assert_snapshot!("gc_and_verify", text));
}

#[test]
fn user_errors_exit_1_with_a_located_message() {
    let p = Project::new(CLI_PIPELINE);
    let mut text = session(
        &p,
        &[
            &["make", "--profile", "huge"],
            &["make", "totl"],
            &["why", "total@x"],
            &["show", "zz"],
            &["show", "abcdef"],
            &["show", "total"],
            &["export", "totl"],
        ],
    );
    transcript(&p, &["make"]);
    text.push('\n');
    text.push_str(&session(&p, &[&["export", "total"]]));
    p.write_pipeline(&CLI_PIPELINE.replace("params = { by = 0.5 }", "params = { by = \"half\" }"));
    text.push('\n');
    text.push_str(&session(&p, &[&["make"]]));
    p.write_pipeline(&CLI_PIPELINE.replace("kind = \"shift\"", "kind = \"shfit\""));
    text.push('\n');
    text.push_str(&session(&p, &[&["status"]]));
    p.write_pipeline("[stages.a\nkind = 1\n");
    text.push('\n');
    text.push_str(&session(&p, &[&["make"]]));

    // A mistyped --pipeline is named, is the user's to fix, and leaves no store beside it.
    let mistyped = p.dir.path().join("pipelines").join("pipeline.toml");
    let mistyped = mistyped.to_str().expect("UTF-8 temp path");
    for command in [&["status"][..], &["gc"], &["show", "total"]] {
        let args: Vec<&str> = ["--pipeline", mistyped]
            .iter()
            .chain(command)
            .copied()
            .collect();
        let out = std::process::Command::new(BIN)
            .args(&args)
            .env("OSMS_NO_PROGRESS", "1")
            .env_remove("OSMS_LOG")
            .env_remove("OSMS_STORE")
            .current_dir(p.dir.path())
            .output()
            .expect("run");
        text.push('\n');
        text.push_str(&shown(&p, &args, &out));
    }
    assert!(
        !p.dir.path().join("pipelines").exists(),
        "a store was created beside the mistyped pipeline"
    );
    settings().bind(|| insta::assert_snapshot!("user_errors", text));

    let out = std::process::Command::new(BIN)
        .arg("status")
        .current_dir(p.dir.path().parent().unwrap_or(Path::new("/")))
        .env_remove("OSMS_PIPELINE")
        .output()
        .expect("run");
    // The temp dir's parent has no pipeline.toml (and neither has /).
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no pipeline.toml in"));
}

/// `osms init DIR` as a newcomer runs it, outside any project.
fn init(dir: &Path, extra: &[&str]) -> Output {
    std::process::Command::new(BIN)
        .arg("init")
        .arg(dir)
        .args(extra)
        .current_dir(dir.parent().unwrap_or(Path::new("/")))
        .env("OSMS_NO_PROGRESS", "1")
        .env_remove("OSMS_PIPELINE")
        .env_remove("OSMS_STORE")
        .output()
        .expect("run")
}

#[test]
fn init_writes_the_shipped_pipeline_and_an_empty_store_and_never_over_a_project() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let project = tmp.path().join("new-project");
    let out = init(&project, &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert_eq!(
        std::fs::read_to_string(project.join("pipeline.toml")).expect("pipeline.toml"),
        osms_kinds::PIPELINE
    );
    assert!(project.join("store/OSMS_STORE").is_file(), "no store");
    assert!(
        stderr.contains("osms make teacher --profile tiny"),
        "{stderr}"
    );

    // A project is never overwritten: exit 1, the file as it was.
    std::fs::write(project.join("pipeline.toml"), "# mine\n").expect("write");
    let again = init(&project, &["--json"]);
    let stderr = String::from_utf8_lossy(&again.stderr);
    assert_eq!(again.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("is an osms project already"), "{stderr}");
    assert!(again.stdout.is_empty());
    assert_eq!(
        std::fs::read_to_string(project.join("pipeline.toml")).expect("read"),
        "# mine\n"
    );

    // A store directory that is not a store is refused before the pipeline is written.
    let other = tmp.path().join("other");
    std::fs::create_dir_all(other.join("store")).expect("mkdir");
    std::fs::write(other.join("store/notes.txt"), "mine").expect("write");
    let refused = init(&other, &[]);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("not an osms store"), "{stderr}");
    assert!(!other.join("pipeline.toml").exists());

    // --json names what was written.
    let json_project = tmp.path().join("json");
    let out = init(&json_project, &["--json"]);
    assert_eq!(out.status.code(), Some(0));
    let written = json_of(&out);
    assert_eq!(
        written["pipeline"],
        json_project.join("pipeline.toml").display().to_string()
    );
    assert_eq!(
        written["store"],
        json_project.join("store").display().to_string()
    );
}

#[test]
fn doctor_reports_mujoco_from_the_library_itself() {
    let p = Project::new(CLI_PIPELINE);
    let out = p.run(Path::new(BIN), &["doctor", "--json"]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("doctor --json");
    assert_eq!(report["mujoco_version"], "3.17.0");
    assert_eq!(report["setup_complete"], true);
    assert_eq!(report["platform_class"], osms::platform::class());
    assert!(report["mujoco_smoke_test"]["Ok"].is_string(), "{report}");
    assert_eq!(report["store"], p.store.display().to_string());
}

#[test]
fn make_json_reports_every_instance() {
    let p = Project::new(CLI_PIPELINE);
    let out = p.run(Path::new(BIN), &["make", "--json", "-q"]);
    assert_eq!(out.status.code(), Some(0));
    assert!(
        out.stderr.is_empty(),
        "-q prints nothing on stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("make --json");
    let instances = report["instances"].as_array().expect("instances");
    assert_eq!(instances.len(), 4);
    assert!(
        instances
            .iter()
            .all(|i| i["outcome"] == "built" && i["content_hash"].is_string())
    );
}

#[test]
fn a_panicking_stage_fails_with_exit_1_and_the_rest_is_built() {
    let p = Project::new(&format!(
        "{CLI_PIPELINE}\n[stages.boom]\nkind = \"panicky\"\nparams = {{ n = 4, panic_at_item = 2 }}\n\n\
         [stages.boom_total]\nkind = \"sum\"\ninputs = {{ values = \"boom\" }}\n"
    ));
    // Not snapshotted: the default panic hook's line names a source line of the test kinds.
    let (text, out) = transcript(&p, &["make", "-j", "2"]);
    assert_eq!(out.status.code(), Some(1), "{text}");
    assert!(
        text.contains("  FAILED boom: stage panicked: item 2 panicked on purpose (panic_at_item)"),
        "{text}"
    );
    assert!(
        text.contains("  skipped boom_total (input boom failed)"),
        "{text}"
    );
    assert!(text.contains("  built total@0 -> "), "{text}");
    assert!(
        text.contains("osms make: 4 built, 0 cached, 0 cut off, 1 failed, 1 skipped"),
        "{text}"
    );
}

/// A pipeline for experiments: seeded numbers, two shifts in a row and their total, and a
/// held-out set that an experiment should not read.
const EXP_PIPELINE: &str = r#"[pipeline]
default_profile = "small"
seed = 0
experiment_targets = ["total"]
held_out = ["heldout"]

[stages.numbers]
kind = "numbers"
shards = 2
params = { n = 4, len = 2 }

[stages.shifted]
kind = "shift"
inputs = { values = "numbers" }
params = { by = 0.5 }

[stages.again]
kind = "shift"
inputs = { values = "shifted" }
params = { by = 10.0 }

[stages.total]
kind = "sum"
inputs = { values = "again" }

[stages.heldout]
kind = "numbers"
seed = 9
params = { n = 3 }

[stages.peek]
kind = "sum"
inputs = { values = "heldout" }

[profiles.tiny.numbers]
params = { n = 2 }
[profiles.small]
"#;

/// Every file of the store with its bytes, to prove a command left it alone.
fn store_files(p: &Project) -> BTreeMap<String, Vec<u8>> {
    fn walk(dir: &Path, root: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let path = e.path();
            if path.is_dir() {
                walk(&path, root, out);
            } else {
                let name = path
                    .strip_prefix(root)
                    .unwrap_or(&path)
                    .display()
                    .to_string();
                // The lock file and the stat cache are bookkeeping, rewritten by any reader.
                if !name.ends_with(".lock") && !name.contains("stat-cache") {
                    out.insert(name, std::fs::read(&path).unwrap_or_default());
                }
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(&p.store, &p.store, &mut out);
    out
}

#[test]
fn bad_overrides_exit_1_naming_the_field_and_leave_the_store_alone() {
    let p = Project::new(EXP_PIPELINE);
    transcript(&p, &["make", "total"]);
    let before = store_files(&p);
    // Compared below: an empty "before" (a store looked for in the wrong place) would make
    // that comparison pass whatever the refused commands did.
    assert!(
        before.keys().any(|k| k.starts_with("objects"))
            && before.keys().any(|k| k.starts_with("index")),
        "the store after a make: {:?}",
        before.keys().collect::<Vec<_>>()
    );
    let text = session(
        &p,
        &[
            &["make", "--set", "nosuch.n=1"],
            &["make", "--set", "numbers.nn=1"],
            &["make", "--set", "numbers.n=many"],
            &["make", "--set", "numbers.n=-1"],
            &["make", "--set", "numbers.shards=0"],
            &["make", "--set", "numbers"],
            &["make", "--set", "numbers.n.deep=1"],
            &["make", "--set", "shifted.inputs.values=heldout"],
            &["status", "--set", "shifted.by=2", "total"],
            &["exp", "run", "bad", "--sweep", "shifted.by=1,x"],
            &["exp", "run", "bad", "--sweep", "shifted.by=1,1"],
            &["exp", "run", "bad/name"],
            &["exp", "show", "nope"],
            &["exp", "diff", "a", "b"],
            &["exp", "rm", "nope"],
        ],
    );
    assert_eq!(
        store_files(&p),
        before,
        "a refused command changed the store"
    );
    // A mistyped base value that the active profile overlays is still an error.
    p.write_pipeline(&EXP_PIPELINE.replace(
        "params = { n = 4, len = 2 }",
        "params = { n = \"many\", len = 2 }",
    ));
    let text = format!(
        "{text}\n{}",
        session(&p, &[&["make", "-p", "tiny", "total"]])
    );
    settings().bind(|| insta::assert_snapshot!("overrides", text));
}

fn json_of(out: &Output) -> serde_json::Value {
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON on stdout")
}

#[test]
fn a_sweep_builds_shared_work_once_and_exp_show_lists_every_point() {
    let p = Project::new(EXP_PIPELINE);
    let bin = Path::new(BIN);
    let run = json_of(&p.run(
        bin,
        &[
            "exp",
            "run",
            "sw",
            "--sweep",
            "shifted.by=0.5,1,2",
            "--sweep",
            "again.by=10,20",
            "--json",
            "-q",
        ],
    ));
    let mut built: BTreeMap<String, usize> = BTreeMap::new();
    for i in run["make"]["instances"].as_array().expect("instances") {
        if i["outcome"] == "built" {
            let name = i["instance"].as_str().expect("name");
            let stage = name.split(['~', '#', '@']).next().expect("stage");
            *built.entry(stage.to_string()).or_default() += 1;
        }
    }
    let expected: BTreeMap<String, usize> =
        [("numbers", 1), ("shifted", 3), ("again", 6), ("total", 6)]
            .map(|(s, n)| (s.to_string(), n))
            .into();
    assert_eq!(built, expected, "one graph: the shared numbers build once");
    assert_eq!(
        run["experiment"]["points"].as_array().map(Vec::len),
        Some(6)
    );

    let listed = json_of(&p.run(bin, &["exp", "ls", "--json"]));
    assert_eq!(listed[0]["name"], "sw");
    assert_eq!(listed[0]["points"], 6);
    assert_eq!(
        listed[0]["sweep"],
        serde_json::json!(["shifted.by", "again.by"])
    );
    let show = json_of(&p.run(bin, &["exp", "show", "--json", "--metrics", "sum,count"]));
    let rows = show["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 6);
    let mut seen = Vec::new();
    for (k, row) in rows.iter().enumerate() {
        assert_eq!(row["experiment"], "sw");
        assert_eq!(row["point"], k);
        let (a, b) = (
            row["params"]["shifted.by"].as_str().expect("shifted.by"),
            row["params"]["again.by"].as_str().expect("again.by"),
        );
        seen.push(format!("{a} {b}"));
        // The metric is the artifact's summary, the same that `osms show` prints for a make
        // with the same overrides; and that make finds everything built.
        let set_a = format!("shifted.by={a}");
        let set_b = format!("again.by={b}");
        let shown = json_of(&p.run(
            bin,
            &["show", "total", "--set", &set_a, "--set", &set_b, "--json"],
        ));
        for m in ["sum", "count"] {
            assert_eq!(
                row["metrics"][m][0].as_f64().expect("the row's metric"),
                shown["summary"][m].as_f64().expect("the summary's value"),
                "point {k}, {m}"
            );
        }
        let made = json_of(&p.run(
            bin,
            &[
                "make", "total", "--set", &set_a, "--set", &set_b, "--json", "-q",
            ],
        ));
        assert!(
            made["instances"]
                .as_array()
                .expect("instances")
                .iter()
                .all(|i| i["outcome"] == "cached"),
            "{made}"
        );
    }
    assert_eq!(seen, ["0.5 10", "0.5 20", "1 10", "1 20", "2 10", "2 20"]);

    let diff = json_of(&p.run(
        bin,
        &["exp", "diff", "sw/0", "sw/1", "--json", "--metrics", "sum"],
    ));
    assert_eq!(diff["params"]["again.by"], serde_json::json!(["10", "20"]));
    assert!(diff["params"].get("shifted.by").is_none(), "{diff}");
    assert_eq!(diff["shared_instances"], 2, "numbers and shifted: {diff}");
    let delta = diff["metrics"]["sum"]["delta"].as_f64().expect("delta");
    assert!(
        (delta - 10.0 * 8.0).abs() < 1e-9,
        "8 values shifted 10 further: {delta}"
    );

    // The name is taken; gc keeps what the experiment holds until it is forgotten.
    let again = p.run(bin, &["exp", "run", "sw"]);
    assert_eq!(again.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&again.stderr).contains("experiment `sw` exists"));
    let rebuilt = |p: &Project| {
        let made = json_of(&p.run(
            bin,
            &[
                "make",
                "total",
                "--set",
                "shifted.by=2",
                "--set",
                "again.by=20",
                "--json",
                "-q",
            ],
        ));
        made["instances"]
            .as_array()
            .expect("instances")
            .iter()
            .filter(|i| i["outcome"] == "built")
            .count()
    };
    json_of(&p.run(bin, &["gc", "--json"]));
    assert_eq!(rebuilt(&p), 0, "gc removed an experiment's artifacts");
    assert_eq!(
        json_of(&p.run(bin, &["exp", "show", "sw", "--json", "--metrics", "sum"]))["rows"]
            .as_array()
            .map(Vec::len),
        Some(6)
    );
    assert_eq!(p.run(bin, &["exp", "rm", "sw"]).status.code(), Some(0));
    json_of(&p.run(bin, &["gc", "--json"]));
    assert_eq!(
        rebuilt(&p),
        3,
        "shifted, again and total went with the experiment"
    );
    let shown = json_of(&p.run(bin, &["exp", "show", "--json"]));
    assert_eq!(shown["rows"], serde_json::json!([]));
}

#[test]
fn a_dry_run_estimates_a_new_point_from_a_recorded_experiments_builds() {
    let p = Project::new(EXP_PIPELINE);
    let bin = Path::new(BIN);
    let set = |a: &str, b: &str| {
        vec![
            "--set".to_string(),
            format!("shifted.by={a}"),
            "--set".to_string(),
            format!("again.by={b}"),
        ]
    };
    let mut first = vec!["exp", "run", "a", "-q"];
    let first_set = set("2", "20");
    first.extend(first_set.iter().map(String::as_str));
    assert_eq!(p.run(bin, &first).status.code(), Some(0));
    // The profile's own `shifted` and `again` were never built: only experiment `a` measures
    // them.
    let mut dry = vec!["exp", "run", "b", "--dry-run", "--json"];
    let dry_set = set("3", "30");
    dry.extend(dry_set.iter().map(String::as_str));
    let out = json_of(&p.run(bin, &dry));
    let estimate = &out["estimate"];
    let of = |name: &str| {
        estimate["instances"]
            .as_array()
            .expect("instances")
            .iter()
            .find(|i| i["instance"] == name)
            .unwrap_or_else(|| panic!("{name} in {estimate}"))
            .clone()
    };
    for stage in ["shifted", "again"] {
        let i = of(&format!("{stage}@0"));
        let m = &i["measured"];
        assert_eq!(m["profile"], "small, experiment a", "{stage}: {m}");
        assert_eq!(m["stage"], stage, "{stage}: {m}");
        assert!(i["core_hours"].as_f64().is_some_and(|h| h > 0.0), "{i}");
    }
    assert_eq!(estimate["unmeasured"], serde_json::json!([]), "{estimate}");
    assert!(
        store_files(&p).keys().all(|f| !f.contains("experiments/b")),
        "a dry run records nothing"
    );
    let mut dry_text = vec!["exp", "run", "b", "--dry-run"];
    dry_text.extend(dry_set.iter().map(String::as_str));
    let (text, _) = transcript(&p, &dry_text);
    assert!(
        text.contains("on small, experiment a:"),
        "the estimate says where it measured: {text}"
    );
}

#[test]
fn an_experiment_that_reads_held_out_stages_is_warned() {
    let p = Project::new(EXP_PIPELINE);
    let (text, out) = transcript(&p, &["exp", "run", "peeking", "peek"]);
    assert_eq!(out.status.code(), Some(0), "{text}");
    assert!(
        text.contains("warning: experiment `peeking` reads the held-out stage(s) heldout"),
        "{text}"
    );
    let (text, _) = transcript(&p, &["exp", "run", "clean", "--set", "again.by=3"]);
    assert!(!text.contains("warning"), "{text}");
    assert!(
        text.contains("osms exp run clean: 1 point(s), 4 built"),
        "{text}"
    );
}
