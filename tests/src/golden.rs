//! Golden content hashes per platform class, with the code-version guard: an output whose hash
//! changed under the same key (kind, code version, params, inputs, seed) fails with a message
//! asking for a `CODE_VERSION` bump.

use std::path::{Path, PathBuf};

use osms_make::{MakeReport, Plan};
use serde::{Deserialize, Serialize};

pub fn golden_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../golden")
}

pub fn settings() -> insta::Settings {
    let mut s = insta::Settings::clone_current();
    s.set_snapshot_path(golden_dir());
    s.set_prepend_module_to_snapshot(false);
    s.set_omit_expression(true);
    s
}

/// One built output as the golden files record it.
#[derive(Debug, Serialize, Deserialize, PartialEq)]
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
            let stage = r.instance.split('@').next().unwrap_or(&r.instance);
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

fn snapshot_body(path: &Path) -> Option<Vec<Output>> {
    let text = std::fs::read_to_string(path).ok()?;
    let body = text.splitn(3, "---\n").nth(2)?;
    serde_json::from_str(body).ok()
}

/// Compares `outputs` with `golden/<name>@<class>.snap` where the running platform class has
/// one (or records it with `OSMS_RECORD_GOLDEN=1`); notes the skip otherwise.
pub fn check(name: &str, outputs: Vec<Output>) {
    let class = osms::platform::class();
    let name = format!("{name}@{class}");
    let path = golden_dir().join(format!("{name}.snap"));
    let Some(golden) = snapshot_body(&path) else {
        if std::env::var_os("OSMS_RECORD_GOLDEN").is_none() {
            eprintln!(
                "note: no golden content hashes for platform class {class} ({}); the identity tests still ran.\n\
                 Record them with: OSMS_RECORD_GOLDEN=1 INSTA_UPDATE=always cargo test -p osms-tests",
                path.display()
            );
            return;
        }
        settings().bind(|| insta::assert_json_snapshot!(name, outputs));
        return;
    };
    for now in &outputs {
        if let Some(before) = golden.iter().find(|g| g.instance == now.instance) {
            assert!(
                !(before.code_version == now.code_version
                    && before.kind == now.kind
                    && before.key == now.key
                    && before.content_hash != now.content_hash),
                "stage {} changed its output ({} -> {}) for the same key, but kind `{}` is still at code \
                 version {}: bump its CODE_VERSION, then re-record the golden hashes",
                now.instance,
                &before.content_hash[..12],
                &now.content_hash[..12],
                now.kind,
                now.code_version
            );
        }
    }
    settings().bind(|| insta::assert_json_snapshot!(name, outputs));
}
