//! A new user's path from the wheel alone (issue 77): the wheel installed into a fresh venv
//! (scripts/test makes it), a working directory outside the checkout, no MuJoCo on the library
//! path and no osms variables set. The user runs the README's Python snippet before there is a
//! project, follows each hint the errors print by running it as printed, and ends with the
//! snippet running verbatim.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The README's Python snippet (the first ```python block of "Use your own policy (Python)").
fn readme_snippet() -> String {
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md"))
            .expect("README.md");
    let section = readme
        .split("## Use your own policy (Python)")
        .nth(1)
        .expect("the README's Python section");
    let block = section
        .split("```python\n")
        .nth(1)
        .and_then(|rest| rest.split("```").next())
        .expect("a python block in that section");
    block.to_string()
}

/// The command the last `hint:` line of `stderr` names (between its first pair of backticks).
fn hinted_command(stderr: &str) -> String {
    let line = stderr
        .lines()
        .rev()
        .find(|l| l.starts_with("hint:") && l.contains('`'))
        .unwrap_or_else(|| panic!("no hint naming a command in:\n{stderr}"));
    line.split('`')
        .nth(1)
        .expect("a command in backticks")
        .to_string()
}

struct Newcomer {
    bin: PathBuf,
}

impl Newcomer {
    /// `program` (found on the venv's PATH first) in `dir`, as a user's shell would run it.
    fn run(&self, dir: &Path, shell_line: &str, profile: Option<&str>) -> Output {
        let path = format!(
            "{}:{}",
            self.bin.display(),
            std::env::var("PATH").unwrap_or_default()
        );
        let mut cmd = Command::new("sh");
        cmd.arg("-c")
            .arg(shell_line)
            .current_dir(dir)
            .env("PATH", path)
            .env_remove("LD_LIBRARY_PATH")
            .env_remove("OSMS_PIPELINE")
            .env_remove("OSMS_STORE")
            .env_remove("OSMS_PROFILE")
            .env_remove("PYTHONPATH")
            .env("OSMS_NO_PROGRESS", "1");
        if let Some(p) = profile {
            cmd.env("OSMS_PROFILE", p);
        }
        cmd.output().expect("run a shell")
    }
}

fn text(out: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn a_new_user_follows_the_readme_and_each_hint_from_the_wheel_alone() {
    let Some(python) = osms_tests::python::wheel_interpreter("the newcomer's path") else {
        return;
    };
    let bin = python.parent().expect("the venv's bin").to_path_buf();
    assert!(
        bin.join("osms").is_file(),
        "the wheel installed no `osms` command into {}",
        bin.display()
    );
    let user = Newcomer { bin };
    let home =
        tempfile::tempdir_in(std::env::temp_dir()).expect("a directory outside the checkout");
    let snippet = home.path().join("mine.py");
    std::fs::write(&snippet, readme_snippet()).expect("write the snippet");

    // No project yet: the error says how to make one.
    let out = user.run(home.path(), "python mine.py", Some("tiny"));
    let (_, stderr) = text(&out);
    assert!(
        !out.status.success(),
        "the snippet ran without a project:\n{stderr}"
    );
    assert!(stderr.contains("osms.OsmsError"), "{stderr}");
    let init = hinted_command(&stderr);
    assert!(init.starts_with("osms init"), "{stderr}");
    let out = user.run(home.path(), &init.replace("DIR", "catching"), None);
    let (stdout, stderr) = text(&out);
    assert!(out.status.success(), "`{init}`: {stdout}\n{stderr}");
    let project = home.path().join("catching");
    assert!(project.join("pipeline.toml").is_file() && project.join("store").is_dir());
    std::fs::rename(&snippet, project.join("mine.py")).expect("move the snippet");

    // A project without a teacher: the snippet gets as far as loading it, and the error names
    // the command that builds it into this project's store.
    let out = user.run(&project, "python mine.py", Some("tiny"));
    let (stdout, stderr) = text(&out);
    assert!(
        !out.status.success(),
        "the snippet ran without a teacher:\n{stdout}"
    );
    assert!(
        stdout.contains("completion"),
        "the snippet's first evaluation printed no summary before the teacher:\n{stdout}\n{stderr}"
    );
    let make = hinted_command(&stderr);
    let store = project.join("store").canonicalize().expect("store");
    assert!(
        make.starts_with("osms make teacher --profile tiny")
            && make.contains(&format!("--store {}", store.display())),
        "{stderr}"
    );
    // Run from elsewhere, as printed: it builds into the project's store all the same.
    let out = user.run(home.path(), &make, None);
    let (stdout, stderr) = text(&out);
    assert!(out.status.success(), "`{make}`: {stdout}\n{stderr}");

    // The snippet verbatim, to the end.
    let out = user.run(&project, "python mine.py", Some("tiny"));
    let (stdout, stderr) = text(&out);
    assert!(
        out.status.success(),
        "the README's snippet failed:\n{stdout}\n{stderr}"
    );
    assert_eq!(
        stdout.matches("success").count(),
        2,
        "two evaluations printed:\n{stdout}"
    );
    assert!(project.join("out/mine/rollouts.csv").is_file());
    assert!(project.join("out/mine/eval_info.json").is_file());
}
