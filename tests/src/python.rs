//! The Python readers the export tests use as independent checks (scripts/setup-python sets up
//! the venv; scripts/test passes its interpreter in `OSMS_TEST_PYTHON`).

use std::path::{Path, PathBuf};
use std::process::Command;

/// The test interpreter, or `None` after logging a visible skip. Under `CI` a missing
/// interpreter fails the test: the test command always sets one up there.
pub fn interpreter(check: &str) -> Option<PathBuf> {
    from_env(
        "OSMS_TEST_PYTHON",
        check,
        "scripts/test sets it from scripts/setup-python",
    )
}

/// The interpreter of a fresh venv holding the Python package as a wheel (scripts/test installs
/// it there: `OSMS_TEST_WHEEL_PYTHON`), or `None` after logging a visible skip; under `CI` a
/// missing one fails the test.
pub fn wheel_interpreter(check: &str) -> Option<PathBuf> {
    from_env(
        "OSMS_TEST_WHEEL_PYTHON",
        check,
        "scripts/test installs the wheel",
    )
}

/// The interpreter the environment variable `var` names; else a logged skip, or under `CI` a
/// failure saying where it comes from (`set_by`).
fn from_env(var: &str, check: &str, set_by: &str) -> Option<PathBuf> {
    if let Some(p) = std::env::var_os(var).filter(|v| !v.is_empty()) {
        return Some(PathBuf::from(p));
    }
    let mode = crate::golden::Mode::from_env();
    assert!(!mode.ci, "{check} needs {var} under CI ({set_by})");
    let line = format!("{check}: {var} is not set (run scripts/test)");
    eprintln!("skipped: {line}");
    mode.log_skip(&line);
    None
}

/// Runs `scripts/<script>` with `args` and parses the one JSON object it prints.
pub fn run_script(python: &Path, script: &str, args: &[&str]) -> serde_json::Value {
    run_file(
        python,
        &Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../scripts")
            .join(script),
        args,
    )
}

/// Runs the Python file `path` with `args` and parses the one JSON object it prints.
pub fn run_file(python: &Path, path: &Path, args: &[&str]) -> serde_json::Value {
    let script = path.display();
    // `python -O` (PYTHONOPTIMIZE) would skip any `assert` a script still carries.
    let out = Command::new(python)
        .arg(path)
        .args(args)
        .env_remove("PYTHONOPTIMIZE")
        .output()
        .unwrap_or_else(|e| panic!("run {script}: {e}"));
    assert!(
        out.status.success(),
        "{script} {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "{script} printed no JSON ({e}):\n{}",
            String::from_utf8_lossy(&out.stdout)
        )
    })
}
