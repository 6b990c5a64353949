//! Golden snapshots (files under `golden/`):
//! (a) the stage-definition DAG of the `tiny` profile, identical on every platform;
//! (b) the keys and content hashes of the `tiny` outputs, per platform class (the arch and a
//!     fingerprint of the loaded libm, `osms doctor`), checked where a snapshot for the running
//!     class exists, a visible skip where none does (a failure under `CI`); record one with
//!     `OSMS_RECORD_GOLDEN=1`.
//! A changed output hash whose stage kept its code version fails with its own message.

use std::path::Path;

use osms_make::{Pipeline, Plan, Registry};
use osms_tests::Project;
use osms_tests::golden::{self, Mode, Outcome, Output, settings};
use osms_tests::project::hashes;
use serde::Serialize;

#[derive(Serialize)]
struct DagStage {
    stage: String,
    kind: &'static str,
    code_version: u32,
    seeded: bool,
    fixed_seed: Option<u64>,
    seed_dependent: bool,
    shards: u32,
    folds: Option<u32>,
    role: Option<&'static str>,
    output: String,
    numerics: Vec<(&'static str, String)>,
    inputs: Vec<(String, String)>,
    params: serde_json::Value,
    definition: String,
}

fn dag(plan: &Plan) -> Vec<DagStage> {
    plan.stages
        .iter()
        .map(|s| DagStage {
            stage: s.name.clone(),
            kind: s.info.name,
            code_version: s.info.code_version,
            seeded: s.uses_rng,
            fixed_seed: s.fixed_seed,
            seed_dependent: s.seed_dependent,
            shards: s.shards,
            folds: s.folds,
            role: s.role,
            output: format!("{} v{}", s.info.output_tag, s.info.output_schema),
            numerics: s
                .info
                .numerics
                .iter()
                .map(|n| (n.name, n.version.clone()))
                .collect(),
            inputs: s
                .inputs
                .iter()
                .map(|i| (i.slot.clone(), i.reference.clone()))
                .collect(),
            params: s.params.json.clone(),
            definition: s.definition.to_hex(),
        })
        .collect()
}

#[test]
fn stage_dag_of_the_tiny_profile() {
    let engine = Project::engine();
    let plan = engine.plan(Some("tiny")).expect("engine plan");
    settings().bind(|| insta::assert_json_snapshot!("dag_engine_tiny", dag(&plan)));

    // The shipped pipeline with the shipped kinds.
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml");
    let pipeline = Pipeline::load(&shipped, Some("tiny")).expect("pipeline.toml parses");
    let registry: Registry = osms_kinds::registry();
    let plan = Plan::new(&pipeline, &registry).expect("pipeline.toml plans");
    settings().bind(|| insta::assert_json_snapshot!("dag_pipeline_tiny", dag(&plan)));
}

#[test]
fn content_hashes_of_the_tiny_outputs_per_platform_class() {
    let p = Project::engine();
    let report = p.make(Some("tiny"), &[0], 2);
    let plan = p.plan(Some("tiny")).expect("plan");
    assert_eq!(
        hashes(&report).len(),
        report.instances.len(),
        "every tiny stage must build"
    );
    golden::check("outputs_engine_tiny", golden::outputs(&plan, &report));
}

fn output(content_hash: &str) -> Output {
    Output {
        instance: "world".into(),
        kind: "world".into(),
        code_version: 2,
        key: "da8e17c34385341e4acb5181ae92f44faa2dd9c10e1bfccb9de99d3d1e1cd48e".into(),
        content_hash: content_hash.into(),
    }
}

const CLASS: &str = "x86_64-libm-0badc0de";

fn panic_message(result: std::thread::Result<Outcome>) -> String {
    let payload = result.expect_err("the check fails");
    payload
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_default()
}

#[test]
fn a_missing_snapshot_is_a_logged_skip_outside_ci() {
    let dir = tempfile::tempdir().expect("tempdir");
    let log = dir.path().join("skips");
    let mode = Mode {
        skip_log: Some(log.clone()),
        ..Mode::default()
    };
    let outcome = golden::check_in(dir.path(), "outputs_none", CLASS, vec![output("ab")], &mode);
    assert_eq!(outcome, Outcome::Skipped);
    // A second skip appends.
    golden::check_in(dir.path(), "outputs_other", CLASS, vec![], &mode);
    let text = std::fs::read_to_string(&log).expect("the skip log is written");
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 2, "{text}");
    assert!(lines[0].contains("outputs_none"), "{text}");
    assert!(lines[0].contains(CLASS), "{text}");
    assert!(
        lines[0].contains(&format!("outputs_none@{CLASS}.snap")),
        "{text}"
    );
    assert!(lines[1].contains("outputs_other"), "{text}");
    assert!(
        !dir.path()
            .join(format!("outputs_none@{CLASS}.snap"))
            .exists(),
        "a skip records nothing"
    );
}

#[test]
fn a_missing_snapshot_fails_under_ci_unless_allowed() {
    let dir = tempfile::tempdir().expect("tempdir");
    // Another class has one: the message names it.
    std::fs::write(
        dir.path().join("outputs_none@x86_64-libm-12345678.snap"),
        "---\nsource: x\n---\n[]\n",
    )
    .expect("write");
    let log = dir.path().join("skips");
    let ci = Mode {
        ci: true,
        skip_log: Some(log.clone()),
        ..Mode::default()
    };
    let message = panic_message(std::panic::catch_unwind(|| {
        golden::check_in(dir.path(), "outputs_none", CLASS, vec![output("ab")], &ci)
    }));
    for needle in [
        CLASS,
        &format!("outputs_none@{CLASS}.snap"),
        "x86_64-libm-12345678",
        "OSMS_RECORD_GOLDEN=1",
        "OSMS_ALLOW_MISSING_GOLDEN=1",
    ] {
        assert!(message.contains(needle), "`{needle}` in: {message}");
    }
    assert!(!log.exists(), "a failure is not counted as a skip");

    let allowed = Mode {
        allow_missing: true,
        ..ci
    };
    let outcome = golden::check_in(dir.path(), "outputs_none", CLASS, vec![], &allowed);
    assert_eq!(outcome, Outcome::Skipped);
    let text = std::fs::read_to_string(&log).expect("the allowed skip is logged");
    assert!(text.contains(CLASS), "{text}");
}

#[test]
fn an_existing_snapshot_is_compared_and_guards_the_code_version() {
    let dir = tempfile::tempdir().expect("tempdir");
    let golden_outputs = vec![output("f86a67037c112b6009ad069c4c101958")];
    let body = serde_json::to_string_pretty(&golden_outputs).expect("json");
    std::fs::write(
        dir.path().join(format!("outputs_some@{CLASS}.snap")),
        format!("---\nsource: tests/src/golden.rs\n---\n{body}\n"),
    )
    .expect("write");
    for ci in [false, true] {
        let mode = Mode {
            ci,
            ..Mode::default()
        };
        let same = golden::check_in(
            dir.path(),
            "outputs_some",
            CLASS,
            golden_outputs.clone(),
            &mode,
        );
        assert_eq!(same, Outcome::Compared);

        // Same key, other content: the guard asks for a CODE_VERSION bump, recording or not.
        for record in [false, true] {
            let mode = Mode {
                record,
                ..mode.clone()
            };
            let message = panic_message(std::panic::catch_unwind(|| {
                golden::check_in(
                    dir.path(),
                    "outputs_some",
                    CLASS,
                    vec![output("0000000000000000000000000000000")],
                    &mode,
                )
            }));
            assert!(message.contains("bump its CODE_VERSION"), "{message}");
        }
    }
}

#[test]
fn golden_output_files_are_named_by_a_platform_class() {
    // `<name>@<arch>-libm-<8 hex>.snap`: a file named by an older scheme would never be read.
    let mut seen = 0;
    for entry in std::fs::read_dir(golden::golden_dir()).expect("golden/") {
        let file = entry
            .expect("entry")
            .file_name()
            .into_string()
            .expect("utf-8");
        if !file.starts_with("outputs_") || !file.ends_with(".snap") {
            continue;
        }
        seen += 1;
        let class = file
            .trim_end_matches(".snap")
            .split_once('@')
            .map(|(_, class)| class)
            .unwrap_or_else(|| panic!("{file}: no @<class>"));
        let hex = class
            .split_once("-libm-")
            .map(|(_, hex)| hex)
            .unwrap_or_else(|| panic!("{file}: class `{class}` is not <arch>-libm-<hex>"));
        assert!(
            hex.len() == 8
                && hex
                    .bytes()
                    .all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase()),
            "{file}: class `{class}` is not <arch>-libm-<8 hex>"
        );
    }
    assert!(seen > 0, "golden/ holds output snapshots");
}

/// The class must separate glibc's FMA and plain libm variants, the axis measured to change
/// bits (`osms::platform`): a child process with the FMA variants masked reports another class.
#[test]
fn the_class_follows_the_libm_variant() {
    let report = osms::platform::report();
    let glibc = report.glibc_version.as_deref().and_then(|v| {
        let (major, minor) = v.split_once('.')?;
        Some((major.parse::<u32>().ok()?, minor.parse::<u32>().ok()?))
    });
    // `glibc.cpu.hwcaps` exists since glibc 2.26; without FMA and AVX2 there is nothing to mask.
    let fma_variants = report.cpu_fma == Some(true) && report.cpu_avx2 == Some(true);
    if !fma_variants || glibc.is_none_or(|v| v < (2, 26)) || report.glibc_tunables.is_some() {
        let line = format!(
            "golden the_class_follows_the_libm_variant: not applicable here (FMA {:?}, AVX2 {:?}, \
             glibc {:?}, GLIBC_TUNABLES {:?}); the class's libm axis not checked",
            report.cpu_fma, report.cpu_avx2, report.glibc_version, report.glibc_tunables
        );
        eprintln!("skipped: {line}");
        Mode::from_env().log_skip(&line);
        return;
    }
    let class_with = |tunables: Option<&str>| {
        let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_osms-test"));
        cmd.args(["doctor", "--json"]);
        if let Some(t) = tunables {
            cmd.env("GLIBC_TUNABLES", t);
        }
        let out = cmd.output().expect("run osms-test doctor");
        let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("doctor --json");
        json["platform_class"]
            .as_str()
            .expect("a class")
            .to_string()
    };
    let plain = class_with(Some("glibc.cpu.hwcaps=-AVX2,-FMA"));
    assert_eq!(class_with(None), report.class);
    assert_ne!(
        plain, report.class,
        "masking FMA/AVX2 from glibc must change the libm fingerprint"
    );
    assert_eq!(
        class_with(Some("glibc.cpu.hwcaps=-AVX2,-FMA,-AVX,-AVX512F")),
        plain,
        "masking AVX and AVX-512 as well changes nothing further"
    );
}

/// Where the libm axis cannot be checked (here: `GLIBC_TUNABLES` already set), the test says so
/// in the skip log that `scripts/test` lists and counts, instead of passing silently.
#[test]
fn the_libm_check_logs_its_skip() {
    let dir = tempfile::tempdir().expect("tempdir");
    let log = dir.path().join("skips");
    let out = std::process::Command::new(std::env::current_exe().expect("this test binary"))
        .args([
            "the_class_follows_the_libm_variant",
            "--exact",
            "--nocapture",
        ])
        .env("GLIBC_TUNABLES", "glibc.malloc.check=0")
        .env("OSMS_SKIP_LOG", &log)
        .output()
        .expect("run the libm test in a child");
    assert!(out.status.success(), "{out:?}");
    let text = std::fs::read_to_string(&log).unwrap_or_default();
    assert_eq!(text.lines().count(), 1, "one skip line: {text:?}");
    assert!(
        text.contains("the_class_follows_the_libm_variant") && text.contains("GLIBC_TUNABLES"),
        "{text}"
    );
}

/// `.ci/run` runs the test command with `CI` set (so every "fails under CI" holds on any
/// runner), and keeps a value the runner chose.
#[test]
fn ci_run_sets_ci() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the workspace root")
        .to_path_buf();
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::create_dir_all(dir.path().join(".ci")).expect("mkdir");
    std::fs::create_dir_all(dir.path().join("scripts")).expect("mkdir");
    std::fs::copy(root.join(".ci/run"), dir.path().join(".ci/run")).expect("copy .ci/run");
    let fake = dir.path().join("scripts/test");
    std::fs::write(
        &fake,
        "#!/usr/bin/env bash\nprintf 'CI=%s' \"${CI-unset}\"\n",
    )
    .expect("write");
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).expect("chmod");
    }
    let run = |ci: Option<&str>| {
        let mut cmd = std::process::Command::new("bash");
        cmd.arg(dir.path().join(".ci/run")).env_remove("CI");
        if let Some(v) = ci {
            cmd.env("CI", v);
        }
        let out = cmd.output().expect("run .ci/run");
        assert!(out.status.success(), "{out:?}");
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    assert_eq!(run(None), "CI=true");
    assert_eq!(run(Some("")), "CI=true");
    assert_eq!(run(Some("1")), "CI=1");
}
