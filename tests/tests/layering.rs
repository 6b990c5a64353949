//! `scripts/check-layering`: it passes on this workspace, and fails on what it exists to catch:
//! planted edges (an osms crate up a layer, MuJoCo under the engine, a network crate below the
//! command line), a crate table that misses a member or cannot be read, an import circle between
//! modules, and a crate whose one sentence differs between lib.rs, Cargo.toml and the table.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::{Value, json};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the workspace root")
        .to_path_buf()
}

fn check(args: &[&str]) -> Output {
    Command::new("python3")
        .arg(root().join("scripts/check-layering"))
        .args(args)
        .output()
        .expect("run scripts/check-layering with python3")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).to_string()
}

fn metadata() -> Value {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args(["metadata", "--format-version", "1", "--locked"])
        .current_dir(root())
        .output()
        .expect("cargo metadata");
    assert!(out.status.success(), "{}", stderr(&out));
    serde_json::from_slice(&out.stdout).expect("metadata JSON")
}

fn id_of(meta: &Value, name: &str) -> String {
    meta["packages"]
        .as_array()
        .expect("packages")
        .iter()
        .find(|p| p["name"] == name)
        .unwrap_or_else(|| panic!("package {name}"))["id"]
        .as_str()
        .expect("id")
        .to_string()
}

/// Adds a resolved normal dependency `from` -> `to` (package ids).
fn plant_resolved(meta: &mut Value, from: &str, to: &str, name: &str) {
    let node = meta["resolve"]["nodes"]
        .as_array_mut()
        .expect("nodes")
        .iter_mut()
        .find(|n| n["id"] == from)
        .expect("node");
    node["deps"].as_array_mut().expect("deps").push(json!({
        "name": name.replace('-', "_"),
        "pkg": to,
        "dep_kinds": [{"kind": null, "target": null}],
    }));
}

fn run_with(meta: &Value, args: &[&str]) -> Output {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("metadata.json");
    std::fs::write(&path, serde_json::to_vec(meta).expect("encode")).expect("write");
    let mut all = vec!["--metadata", path.to_str().expect("utf-8")];
    all.extend_from_slice(args);
    check(&all)
}

#[test]
fn passes_on_this_workspace() {
    let out = check(&[]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("edges, cycles, sentences, rooms, unsafe hold"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn a_planted_edge_up_a_layer_fails() {
    let mut meta = metadata();
    let nn = id_of(&meta, "osms-nn");
    let sim = id_of(&meta, "osms-sim");
    let pkg = meta["packages"]
        .as_array_mut()
        .expect("packages")
        .iter_mut()
        .find(|p| p["id"] == nn.as_str())
        .expect("osms-nn");
    pkg["dependencies"]
        .as_array_mut()
        .expect("dependencies")
        .push(json!({"name": "osms-sim", "kind": null}));
    plant_resolved(&mut meta, &nn, &sim, "osms-sim");
    let out = run_with(&meta, &["--only", "edges"]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let err = stderr(&out);
    assert!(
        err.contains("`osms-nn` -> `osms-sim` (normal dependency) is not in the crate table"),
        "{err}"
    );
    // Through osms-sim, osms-nn now reaches MuJoCo too, which its row forbids.
    assert!(
        err.contains("`osms-nn` must not reach MuJoCo: osms-nn -> osms-sim -> mujoco-rs"),
        "{err}"
    );

    // A dev-dependency up a layer is refused the same way.
    let mut meta = metadata();
    let sim_pkg = meta["packages"]
        .as_array_mut()
        .expect("packages")
        .iter_mut()
        .find(|p| p["name"] == "osms-sim")
        .expect("osms-sim");
    sim_pkg["dependencies"]
        .as_array_mut()
        .expect("dependencies")
        .push(json!({"name": "osms-policy", "kind": "dev"}));
    let out = run_with(&meta, &["--only", "edges"]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("`osms-sim` -> `osms-policy` (dev dependency)"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn mujoco_under_the_engine_and_a_network_crate_below_the_command_line_fail_with_their_chains() {
    let mut meta = metadata();
    let make = id_of(&meta, "osms-make");
    let mujoco = id_of(&meta, "mujoco-rs");
    plant_resolved(&mut meta, &make, &mujoco, "mujoco-rs");
    let report = id_of(&meta, "osms-report");
    let reqwest = "registry+https://github.com/rust-lang/crates.io-index#reqwest@0.12.0";
    meta["packages"]
        .as_array_mut()
        .expect("packages")
        .push(json!({"id": reqwest, "name": "reqwest", "dependencies": [], "manifest_path": "/nowhere/Cargo.toml"}));
    meta["resolve"]["nodes"]
        .as_array_mut()
        .expect("nodes")
        .push(json!({"id": reqwest, "deps": []}));
    plant_resolved(&mut meta, &report, reqwest, "reqwest");
    let out = run_with(&meta, &["--only", "edges"]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let err = stderr(&out);
    assert!(
        err.contains("`osms-make` must not reach MuJoCo: osms-make -> mujoco-rs"),
        "{err}"
    );
    // Everything above the engine reaches it through osms-make now; the store does not.
    assert!(!err.contains("`osms-store` must not reach MuJoCo"), "{err}");
    assert!(
        err.contains("`osms-report` reaches a network crate: osms-report -> reqwest"),
        "{err}"
    );
    assert!(
        err.contains("`osms-kinds` reaches a network crate: osms-kinds -> osms-report -> reqwest"),
        "{err}"
    );
    assert!(
        err.contains(
            "`osms-gym` reaches a network crate: osms-gym -> osms-kinds -> osms-report -> reqwest"
        ),
        "{err}"
    );
    // The command line and the remote crate may: their rows say so.
    assert!(!err.contains("`osms` reaches a network crate"), "{err}");
    assert!(!err.contains("`osms-remote` reaches"), "{err}");
}

#[test]
fn a_table_without_a_member_fails_and_one_that_cannot_be_read_is_unchecked() {
    let text = std::fs::read_to_string(root().join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let dir = tempfile::tempdir().expect("dir");
    let without = dir.path().join("without.md");
    let kept: Vec<&str> = text
        .lines()
        .filter(|l| !l.starts_with("| `osms-render` |"))
        .collect();
    assert_eq!(kept.len() + 1, text.lines().count(), "one row removed");
    std::fs::write(&without, kept.join("\n")).expect("write");
    let out = check(&[
        "--only",
        "edges",
        "--architecture",
        without.to_str().expect("utf-8"),
    ]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("workspace member `osms-render` has no row in the crate table"),
        "{}",
        stderr(&out)
    );

    let unreadable = dir.path().join("unreadable.md");
    std::fs::write(&unreadable, text.replace("## Crates", "## Crates we have")).expect("write");
    let out = check(&["--architecture", unreadable.to_str().expect("utf-8")]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("the layering is unchecked"),
        "{}",
        stderr(&out)
    );
}

/// A one-crate workspace on disk, with metadata and a crate table describing it.
struct Demo {
    dir: tempfile::TempDir,
}

impl Demo {
    fn new(files: &[(&str, &str)], description: &str, row: &str) -> Demo {
        let dir = tempfile::tempdir().expect("dir");
        let root = dir.path();
        for (path, text) in files {
            let p = root.join("crates/demo/src").join(path);
            std::fs::create_dir_all(p.parent().expect("parent")).expect("mkdir");
            std::fs::write(p, text).expect("write");
        }
        let meta = json!({
            "packages": [{
                "id": "demo 0.1.0",
                "name": "demo",
                "description": description,
                "dependencies": [],
                "manifest_path": root.join("crates/demo/Cargo.toml"),
            }],
            "workspace_members": ["demo 0.1.0"],
            "workspace_root": root,
            "resolve": {"nodes": [{"id": "demo 0.1.0", "deps": []}]},
        });
        std::fs::write(root.join("metadata.json"), meta.to_string()).expect("write");
        std::fs::write(
            root.join("ARCHITECTURE.md"),
            format!(
                "# Demo\n\n## Crates\n\n| crate | job | may depend on | MuJoCo | network |\n|---|---|---|---|---|\n| `demo` | {row} | — | no | no |\n"
            ),
        )
        .expect("write");
        Demo { dir }
    }

    fn check(&self, only: &str) -> Output {
        let root = self.dir.path();
        check(&[
            "--root",
            root.to_str().expect("utf-8"),
            "--metadata",
            root.join("metadata.json").to_str().expect("utf-8"),
            "--only",
            only,
        ])
    }

    /// Replaces the crate table file's "Unsafe code" section with `section`.
    fn set_unsafe_section(&self, section: &str) {
        let path = self.dir.path().join("ARCHITECTURE.md");
        let text = std::fs::read_to_string(&path).expect("read");
        let kept = text.split("\n## Unsafe code").next().expect("a first part");
        std::fs::write(&path, format!("{kept}{section}")).expect("write");
    }

    /// Rewrites one source file of the demo crate.
    fn write(&self, path: &str, text: &str) {
        std::fs::write(self.dir.path().join("crates/demo/src").join(path), text).expect("write");
    }
}

const SENTENCE: &str = "A demo crate: modules that import each other, or not.";

#[test]
fn an_import_circle_between_modules_fails_and_nested_modules_are_no_circle() {
    let lib = "//! A demo crate: modules that import each other, or not.\n\nmod a;\nmod b;\nmod c;\n\npub use b::Thing;\n";
    // a -> b through the root's re-export, b -> a by path, and a doc comment that names `crate::c`
    // without importing it.
    let circle = Demo::new(
        &[
            ("lib.rs", lib),
            ("a.rs", "use crate::Thing;\npub fn x() -> Thing { Thing }\n"),
            (
                "b.rs",
                "/// Unlike [`crate::c`].\npub struct Thing;\npub fn y() { crate::a::x(); }\n",
            ),
            ("c/mod.rs", "mod d;\n"),
            (
                "c/d.rs",
                "// super:: here is `c`, not the crate root.\nuse super::super::Thing;\npub fn z() -> Thing { Thing }\n",
            ),
        ],
        SENTENCE,
        SENTENCE,
    );
    let out = circle.check("cycles");
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("`demo`: modules a <-> b import each other"),
        "{}",
        stderr(&out)
    );
    assert!(!stderr(&out).contains("c <->"), "{}", stderr(&out));

    let fine = Demo::new(
        &[
            ("lib.rs", lib),
            ("a.rs", "use crate::Thing;\npub fn x() -> Thing { Thing }\n"),
            ("b.rs", "pub struct Thing;\n"),
            ("c/mod.rs", "mod d;\nuse super::a;\n"),
            (
                "c/d.rs",
                "use super::super::Thing;\npub fn z() -> Thing { Thing }\n",
            ),
        ],
        SENTENCE,
        SENTENCE,
    );
    let out = fine.check("cycles");
    assert!(out.status.success(), "{}", stderr(&out));
}

/// A library module of a crate with the three rooms must not import `stages` or `artifacts`; the
/// stages import the library, and a crate without both rooms (the test crate) has none to keep
/// apart.
#[test]
fn a_library_module_that_imports_the_stages_fails() {
    let lib = "//! A demo crate: modules that import each other, or not.\n\nmod stages;\nmod artifacts;\nmod fit;\n\npub use stages::FitParams;\n";
    let files = |fit: &'static str| {
        [
            ("lib.rs", lib),
            (
                "stages/mod.rs",
                "mod checks;\npub struct FitParams;\nuse crate::fit::run;\n",
            ),
            ("stages/checks.rs", "use super::FitParams;\n"),
            ("artifacts.rs", "use crate::fit::run;\n"),
            ("fit.rs", fit),
        ]
    };
    let fine = Demo::new(&files("pub fn run() {}\n"), SENTENCE, SENTENCE);
    let out = fine.check("rooms");
    assert!(out.status.success(), "{}", stderr(&out));

    // Through the root's re-export, as `checks.rs` did before it moved under `stages/`.
    let wrong = Demo::new(
        &files("use crate::FitParams;\npub fn run(_: FitParams) {}\n"),
        SENTENCE,
        SENTENCE,
    );
    let out = wrong.check("rooms");
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("rooms: `demo`: library module `fit` imports `stages`"),
        "{}",
        stderr(&out)
    );

    let no_rooms = Demo::new(
        &[
            (
                "lib.rs",
                "//! A demo crate: modules that import each other, or not.\n\nmod stages;\nmod fit;\n",
            ),
            ("stages.rs", "pub struct Kind;\n"),
            ("fit.rs", "use crate::stages::Kind;\n"),
        ],
        SENTENCE,
        SENTENCE,
    );
    let out = no_rooms.check("rooms");
    assert!(out.status.success(), "{}", stderr(&out));
}

#[test]
fn a_crate_must_say_one_sentence_everywhere() {
    let lib = format!("//! {SENTENCE}\n//!\n//! More.\n");
    let same = Demo::new(&[("lib.rs", &lib)], SENTENCE, &format!("`{SENTENCE}`"));
    let out = same.check("sentences");
    assert!(out.status.success(), "{}", stderr(&out));

    let differs = Demo::new(&[("lib.rs", &lib)], "Another sentence.", SENTENCE);
    let out = differs.check("sentences");
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("`demo` does not say one sentence everywhere"),
        "{}",
        stderr(&out)
    );
}

/// Every file that allows `unsafe_code` is in ARCHITECTURE.md's "Unsafe code" table, and every
/// file there allows it; a comment that names the attribute is no allowance, and a table
/// without the section leaves the check undone (exit 2).
#[test]
fn every_allowance_of_unsafe_code_is_listed_with_its_reason() {
    let lib = "//! A demo crate: modules that import each other, or not.\n\nmod ffi;\nmod gl;\n";
    let allows = "#![allow(unsafe_code)]\npub fn f() {}\n";
    let demo = Demo::new(
        &[("lib.rs", lib), ("ffi.rs", allows), ("gl.rs", allows)],
        SENTENCE,
        SENTENCE,
    );
    let out = demo.check("unsafe");
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("no `## Unsafe code` section"),
        "{}",
        stderr(&out)
    );

    let table = |files: &[&str]| {
        let rows: String = files
            .iter()
            .map(|f| format!("| `crates/demo/src/{f}` | a C call |\n"))
            .collect();
        format!("\n## Unsafe code\n\n| file | why |\n|---|---|\n{rows}")
    };
    demo.set_unsafe_section(&table(&["gl.rs"]));
    let out = demo.check("unsafe");
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("unsafe: `crates/demo/src/ffi.rs` allows unsafe_code but"),
        "{}",
        stderr(&out)
    );

    demo.set_unsafe_section(&table(&["gl.rs", "ffi.rs"]));
    let out = demo.check("unsafe");
    assert!(out.status.success(), "{}", stderr(&out));

    demo.write(
        "ffi.rs",
        "// Once had #[allow(unsafe_code)].\npub fn f() {}\n",
    );
    let out = demo.check("unsafe");
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("lists `crates/demo/src/ffi.rs`, which allows no unsafe_code"),
        "{}",
        stderr(&out)
    );
}
