//! Golden content hashes per platform class (`osms::platform::class`, the arch and a
//! fingerprint of the loaded libm), with the code-version guard: an output whose hash changed
//! under the same key (kind, code version, params, inputs, seed) fails with a message asking for
//! a `CODE_VERSION` bump.
//!
//! A class without a snapshot is a visible skip, never a silent pass: [`check`] prints it,
//! appends a line to the file named by `OSMS_SKIP_LOG` (`scripts/test` counts and lists those
//! lines) and, under `CI`, fails unless `OSMS_ALLOW_MISSING_GOLDEN=1`. `OSMS_RECORD_GOLDEN=1`
//! (with `INSTA_UPDATE=always`) records the snapshot instead.

use std::io::Write;
use std::path::{Path, PathBuf};

use osms_make::{MakeReport, Plan};
use serde::{Deserialize, Serialize};

/// How to record the golden content hashes of the running class.
pub const RECORD_COMMAND: &str = "OSMS_RECORD_GOLDEN=1 INSTA_UPDATE=always cargo test -p osms-tests --test golden --test pipeline";

pub fn golden_dir() -> PathBuf {
    let tests = Path::new(env!("CARGO_MANIFEST_DIR"));
    tests.parent().unwrap_or(tests).join("golden")
}

pub fn settings() -> insta::Settings {
    settings_in(&golden_dir())
}

fn settings_in(dir: &Path) -> insta::Settings {
    let mut s = insta::Settings::clone_current();
    s.set_snapshot_path(dir);
    s.set_prepend_module_to_snapshot(false);
    s.set_omit_expression(true);
    s
}

/// One built output as the golden files record it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Output {
    pub instance: String,
    pub kind: String,
    pub code_version: u32,
    pub key: String,
    pub content_hash: String,
}

/// The outputs of a make, every instance required to have been built or found.
pub fn outputs(plan: &Plan, report: &MakeReport) -> Vec<Output> {
    report
        .instances
        .iter()
        .map(|r| {
            let stage = r.instance.split(['@', '#']).next().unwrap_or(&r.instance);
            let info = &plan.stages[plan.stage_index(stage).expect("stage")].info;
            Output {
                instance: r.instance.clone(),
                kind: info.name.to_string(),
                code_version: info.code_version,
                key: r.key.map(|k| k.to_hex()).unwrap_or_default(),
                content_hash: r
                    .content_hash
                    .unwrap_or_else(|| panic!("{} has no output", r.instance))
                    .to_hex(),
            }
        })
        .collect()
}

/// The environment's decisions for [`check_in`], read once by [`Mode::from_env`] so that tests
/// can pass their own without touching the process environment.
#[derive(Clone, Debug, Default)]
pub struct Mode {
    /// `OSMS_RECORD_GOLDEN`: record a missing snapshot (and let insta update an existing one).
    pub record: bool,
    /// `CI`: a missing snapshot fails ...
    pub ci: bool,
    /// ... unless `OSMS_ALLOW_MISSING_GOLDEN`.
    pub allow_missing: bool,
    /// `OSMS_SKIP_LOG`: a file that gets one line per skipped check.
    pub skip_log: Option<PathBuf>,
}

/// Set and not empty, `0` or `false`.
fn flag(value: Option<std::ffi::OsString>) -> bool {
    value.is_some_and(|v| !matches!(v.to_str(), Some("" | "0" | "false")))
}

impl Mode {
    pub fn from_env() -> Self {
        Mode {
            record: flag(std::env::var_os("OSMS_RECORD_GOLDEN")),
            ci: flag(std::env::var_os("CI")),
            allow_missing: flag(std::env::var_os("OSMS_ALLOW_MISSING_GOLDEN")),
            skip_log: std::env::var_os("OSMS_SKIP_LOG")
                .filter(|v| !v.is_empty())
                .map(PathBuf::from),
        }
    }
}

impl Mode {
    /// Appends `line` to the skip log, if any, so that `scripts/test` lists the check as skipped
    /// and counts it: no test that did not check what it names passes silently.
    pub fn log_skip(&self, line: &str) {
        let Some(log) = &self.skip_log else {
            return;
        };
        // One short write with O_APPEND: lines from parallel tests and binaries do not mix.
        let appended = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(log)
            .and_then(|mut f| f.write_all(format!("{line}\n").as_bytes()));
        if let Err(e) = appended {
            panic!("cannot append to OSMS_SKIP_LOG {}: {e}", log.display());
        }
    }
}

/// What [`check_in`] did (it panics on a mismatch or a forbidden skip).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// A snapshot existed: the code-version guard ran and the outputs matched it.
    Compared,
    /// No snapshot existed and `record` was set: insta wrote one.
    Recorded,
    /// No snapshot existed: reported, logged, nothing compared.
    Skipped,
}

fn snapshot_body(text: &str) -> Option<Vec<Output>> {
    let body = text.splitn(3, "---\n").nth(2)?;
    serde_json::from_str(body).ok()
}

/// Compares `outputs` with `golden/<name>@<class>.snap` for the running platform class; see
/// [`check_in`].
pub fn check(name: &str, outputs: Vec<Output>) -> Outcome {
    check_in(
        &golden_dir(),
        name,
        &osms::platform::class(),
        outputs,
        &Mode::from_env(),
    )
}

/// Compares `outputs` with `<dir>/<name>@<class>.snap`. Where the snapshot exists, the
/// code-version guard runs first, then insta compares (or, with `record` and
/// `INSTA_UPDATE=always`, updates). Where it does not: with `record`, insta records it;
/// otherwise the skip is printed and appended to `skip_log`, and under `ci` without
/// `allow_missing` the check fails.
pub fn check_in(dir: &Path, name: &str, class: &str, outputs: Vec<Output>, mode: &Mode) -> Outcome {
    let snap = format!("{name}@{class}");
    let path = dir.join(format!("{snap}.snap"));
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => Some(text),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => panic!("cannot read {}: {e}", path.display()),
    };
    let Some(text) = text else {
        if mode.record {
            settings_in(dir).bind(|| insta::assert_json_snapshot!(snap, outputs));
            return Outcome::Recorded;
        }
        skip(dir, name, class, &path, mode);
        return Outcome::Skipped;
    };
    match snapshot_body(&text) {
        Some(golden) => guard_code_versions(&golden, &outputs),
        None if mode.record => {}
        None => panic!(
            "{} is not a golden snapshot (a `---` header, then a JSON list of outputs); \
             re-record it with: {RECORD_COMMAND}",
            path.display()
        ),
    }
    settings_in(dir).bind(|| insta::assert_json_snapshot!(snap, outputs));
    Outcome::Compared
}

/// The code-version guard: the same key must give the same content hash.
fn guard_code_versions(golden: &[Output], outputs: &[Output]) {
    for now in outputs {
        if let Some(before) = golden.iter().find(|g| g.instance == now.instance) {
            assert!(
                !(before.code_version == now.code_version
                    && before.kind == now.kind
                    && before.key == now.key
                    && before.content_hash != now.content_hash),
                "stage {} changed its output ({} -> {}) for the same key, but kind `{}` is still at code \
                 version {}: bump its CODE_VERSION, then re-record the golden hashes",
                now.instance,
                &before.content_hash[..12.min(before.content_hash.len())],
                &now.content_hash[..12.min(now.content_hash.len())],
                now.kind,
                now.code_version
            );
        }
    }
}

/// Reports a missing snapshot: stderr always, the skip log if any, a failure under CI unless
/// allowed.
fn skip(dir: &Path, name: &str, class: &str, path: &Path, mode: &Mode) {
    let others = other_classes(dir, name);
    let others = if others.is_empty() {
        "no class has one".to_string()
    } else {
        format!("snapshots exist for {}", others.join(", "))
    };
    let line = format!(
        "golden {name}: no snapshot for platform class {class} ({}; {others}); content hashes not compared",
        path.display()
    );
    if mode.ci && !mode.allow_missing {
        panic!(
            "{line}.\nUnder CI a missing golden snapshot fails. `osms doctor` explains the class \
             (the arch and a fingerprint of the loaded libm). Record the snapshot on this class \
             with `{RECORD_COMMAND}` and commit {}, or set OSMS_ALLOW_MISSING_GOLDEN=1 to skip it.",
            path.display()
        );
    }
    eprintln!("SKIPPED {line}.\nRecord it with: {RECORD_COMMAND}");
    mode.log_skip(&line);
}

/// The classes that do have a snapshot named `name`.
fn other_classes(dir: &Path, name: &str) -> Vec<String> {
    let prefix = format!("{name}@");
    let mut classes: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter_map(|f| Some(f.strip_prefix(&prefix)?.strip_suffix(".snap")?.to_string()))
        .collect();
    classes.sort();
    classes
}
