//! `osms world dump` prints MJCF that MuJoCo's own file parser loads, for every object.

use std::path::Path;
use std::process::Command;

use mujoco_rs::prelude::MjModel;

const BIN: &str = env!("CARGO_BIN_EXE_osms");

fn pipeline() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../pipeline.toml")
}

#[test]
fn every_object_dumps_to_a_loadable_file() {
    let dir = tempfile::tempdir().expect("dir");
    for v in osms_sim::ObjectVariant::all() {
        let out = Command::new(BIN)
            .args(["--store"])
            .arg(dir.path().join("store"))
            .arg("--pipeline")
            .arg(pipeline())
            .args([
                "world",
                "dump",
                "--profile",
                "tiny",
                "--object",
                &v.to_string(),
            ])
            .output()
            .expect("run osms");
        assert_eq!(
            out.status.code(),
            Some(0),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let path = dir.path().join(format!("{v}.xml"));
        std::fs::write(&path, &out.stdout).expect("write");
        let model = MjModel::from_xml(&path).unwrap_or_else(|e| panic!("{v}: {e}"));
        assert_eq!(model.ffi().nu, 24);
    }
}

#[test]
fn an_unknown_object_is_refused_with_the_valid_names() {
    let out = Command::new(BIN)
        .arg("--pipeline")
        .arg(pipeline())
        .args(["world", "dump", "--object", "cube"])
        .output()
        .expect("run osms");
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("unknown object `cube`") && err.contains("sphere-small"),
        "{err}"
    );
}
