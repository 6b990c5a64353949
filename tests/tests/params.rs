//! Nonsense params are refused at plan time (issue 55, item 6): every numeric param of every
//! stage of the shipped pipeline, set through an override (what `--set` parses) to NaN, ±inf,
//! −1, 0 and a huge value, is either refused by the planner with an error that names the stage,
//! the field and what is valid, or accepted, and then the stage builds with finite outputs.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use osms_make::overrides::Override;
use osms_make::{MakeOptions, Pipeline, Plan, Registry};
use osms_store::Store;
use osms_tests::project::Silent;

const VALUES: [&str; 6] = ["nan", "inf", "-inf", "-1", "0", "1e12"];

fn shipped() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml")
}

/// A numeric param: its dotted path inside the stage's params, and, for an element of a list,
/// the list's path, its index and the list (a list is set whole).
#[derive(Debug, Clone)]
struct Leaf {
    path: Vec<String>,
    list: Option<(Vec<String>, usize, Vec<serde_json::Value>)>,
}

fn leaves(value: &serde_json::Value, path: &mut Vec<String>, out: &mut Vec<Leaf>) {
    match value {
        serde_json::Value::Number(_) => out.push(Leaf {
            path: path.clone(),
            list: None,
        }),
        serde_json::Value::Object(m) => {
            for (k, v) in m {
                path.push(k.clone());
                leaves(v, path, out);
                path.pop();
            }
        }
        serde_json::Value::Array(a) => {
            for (i, v) in a.iter().enumerate() {
                if v.is_number() {
                    let mut p = path.clone();
                    p.push(i.to_string());
                    out.push(Leaf {
                        path: p,
                        list: Some((path.clone(), i, a.clone())),
                    });
                }
            }
        }
        _ => {}
    }
}

/// The override that sets `leaf` of `stage` to `value` (TOML text).
fn setting(stage: &str, leaf: &Leaf, value: &str) -> String {
    match &leaf.list {
        None => format!("{stage}.{}={value}", leaf.path.join(".")),
        Some((list, index, items)) => {
            let items: Vec<String> = items
                .iter()
                .enumerate()
                .map(|(i, v)| {
                    if i == *index {
                        value.to_string()
                    } else {
                        v.to_string()
                    }
                })
                .collect();
            format!("{stage}.{}=[{}]", list.join("."), items.join(", "))
        }
    }
}

/// The plan of `pipeline` with `setting` applied, or the error the CLI would print.
fn plan_with(pipeline: &Pipeline, registry: &Registry, setting: &str) -> Result<Plan, String> {
    let mut pipeline = pipeline.clone();
    let o: Override = setting.parse().map_err(|e| format!("{e}"))?;
    pipeline.apply(&[o]).map_err(|e| format!("{e}"))?;
    Plan::new(&pipeline, registry).map_err(|e| format!("{e}"))
}

/// One accepted setting per kind, param and value: the build half of the test.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
struct Accepted {
    kind: String,
    stage: String,
    param: String,
    value: &'static str,
    setting: String,
}

/// [`sweep_once`], run once for both tests of this file.
fn sweep() -> Vec<Accepted> {
    static SWEEP: std::sync::OnceLock<Vec<Accepted>> = std::sync::OnceLock::new();
    SWEEP.get_or_init(sweep_once).clone()
}

/// Sweeps every numeric param of every stage; returns the settings the planner accepted, one
/// per kind, param and value.
fn sweep_once() -> Vec<Accepted> {
    let pipeline = Pipeline::load(&shipped(), Some("tiny")).expect("load");
    let registry = osms_kinds::registry();
    let base = Plan::new(&pipeline, &registry).expect("the shipped pipeline plans");
    let mut accepted: BTreeMap<(String, String, &str), Accepted> = BTreeMap::new();
    let mut refused = 0;
    let mut tried = 0;
    for stage in &base.stages {
        let mut found = Vec::new();
        leaves(&stage.params.json, &mut Vec::new(), &mut found);
        for leaf in &found {
            let param = leaf.path.join(".");
            for value in VALUES {
                let key = (stage.info.name.to_string(), param.clone(), value);
                let s = setting(&stage.name, leaf, value);
                tried += 1;
                match plan_with(&pipeline, &registry, &s) {
                    Err(e) => {
                        refused += 1;
                        // The error says where and what: the setting (which names the stage
                        // and the field) and what would be valid.
                        assert!(
                            e.contains(&format!("`{}.", stage.name)) || e.contains(&stage.name),
                            "{s}: the error names the stage: {e}"
                        );
                        let field = leaf.list.as_ref().map_or(&leaf.path, |l| &l.0);
                        assert!(
                            e.contains(field.last().expect("a field")),
                            "{s}: the error names the field: {e}"
                        );
                        assert!(
                            ["expected", "finite", "not a table", "invalid", "must"]
                                .iter()
                                .any(|w| e.contains(w)),
                            "{s}: the error says what is valid: {e}"
                        );
                    }
                    Ok(_) => {
                        accepted.entry(key).or_insert(Accepted {
                            kind: stage.info.name.to_string(),
                            stage: stage.name.clone(),
                            param: param.clone(),
                            value,
                            setting: s,
                        });
                    }
                }
            }
        }
    }
    eprintln!(
        "{tried} settings: {refused} refused at plan time, {} distinct accepted",
        accepted.len()
    );
    assert!(
        tried > 1000,
        "the sweep reached every numeric param: {tried}"
    );
    accepted.into_values().collect()
}

/// Nothing non-finite or absurd gets past the planner: NaN and ±inf never, and a huge value
/// only where a param is a size that has no useful cap (none today).
#[test]
fn nonsense_params_are_refused_at_plan_time() {
    let accepted = sweep();
    for a in &accepted {
        assert!(
            ["-1", "0"].contains(&a.value),
            "`{}` was accepted at plan time",
            a.setting
        );
    }
    for a in &accepted {
        eprintln!("accepted: {} ({})", a.setting, a.kind);
    }
}

/// Paths inside a summary that hold `null` (a non-finite number serialises as `null`).
fn nulls(value: &serde_json::Value, path: &mut Vec<String>, out: &mut Vec<String>) {
    match value {
        serde_json::Value::Null => out.push(path.join(".")),
        serde_json::Value::Object(m) => {
            for (k, v) in m {
                path.push(k.clone());
                nulls(v, path, out);
                path.pop();
            }
        }
        serde_json::Value::Array(a) => {
            for (i, v) in a.iter().enumerate() {
                path.push(i.to_string());
                nulls(v, path, out);
                path.pop();
            }
        }
        _ => {}
    }
}

/// The summary and the export files of `stage`'s artifact, built in `store` with `settings`
/// (and its inputs).
fn build(
    store: &Store,
    settings: &[String],
    stage: &str,
) -> (serde_json::Value, Vec<(String, Vec<u8>)>) {
    let mut pipeline = Pipeline::load(&shipped(), Some("tiny")).expect("load");
    let overrides: Vec<Override> = settings
        .iter()
        .map(|s| s.parse().expect("override"))
        .collect();
    pipeline.apply(&overrides).expect("apply");
    let plan = Plan::new(&pipeline, &osms_kinds::registry()).expect("plan");
    let opts = MakeOptions {
        targets: vec![stage.to_string()],
        seeds: vec![0],
        jobs: 2,
        stages: 1,
        dry_run: false,
    };
    let report = osms_make::make(&plan, store, &opts, &Silent).expect("make");
    assert!(
        report.failed().is_empty(),
        "{settings:?}: the build failed: {:?}",
        report.failed()
    );
    let r = report
        .instances
        .iter()
        .find(|r| {
            r.instance
                .strip_prefix(stage)
                .is_some_and(|rest| rest.is_empty() || rest.starts_with(['@', '#']))
        })
        .unwrap_or_else(|| panic!("{stage} in the report"));
    let bytes = store.get(&r.content_hash.expect("built")).expect("object");
    let kind = &plan
        .stages
        .iter()
        .find(|s| s.name == stage)
        .expect("stage")
        .kind;
    let objects = osms_make::StoreObjects(store);
    (
        kind.summarize(&bytes, &objects).expect("summary"),
        kind.files(&bytes, &objects).expect("files"),
    )
}

/// Non-finite numbers written into an export file (`NaN`, `inf` as a field of CSV or JSON).
fn non_finite_in(files: &[(String, Vec<u8>)]) -> Vec<String> {
    let mut out = Vec::new();
    for (name, bytes) in files {
        let text = String::from_utf8_lossy(bytes);
        for field in text.split([',', '\n', ':', '[', ']', '|', ' ']) {
            let f = field.trim().trim_matches('"');
            if matches!(f, "NaN" | "nan" | "inf" | "-inf" | "Infinity" | "-Infinity") {
                out.push(format!("{name}: {f}"));
            }
        }
    }
    out
}

/// What the planner accepts builds, with finite outputs: one accepted setting per kind and
/// value (−1, 0), each built alone on a tiny store. Its export files hold no non-finite number,
/// and for the learned and fitted kinds (networks, error models, candidates: where a NaN means
/// broken weights) its summary has no `null` (a non-finite number) where the unchanged stage's
/// has a number. An evaluation's summary may: the mean force over no successes is empty.
#[test]
fn accepted_params_build_with_finite_outputs() {
    let accepted = sweep();
    let mut chosen: BTreeMap<(String, &str), Accepted> = BTreeMap::new();
    for a in accepted {
        chosen.entry((a.kind.clone(), a.value)).or_insert(a);
    }
    let dir = tempfile::tempdir().expect("dir");
    let store = Store::open(dir.path().join("store")).expect("store");
    let mut base: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for a in chosen.values() {
        let before = base.entry(a.stage.clone()).or_insert_with(|| {
            let mut out = Vec::new();
            nulls(&build(&store, &[], &a.stage).0, &mut Vec::new(), &mut out);
            out
        });
        let (summary, files) = build(&store, std::slice::from_ref(&a.setting), &a.stage);
        let bad = non_finite_in(&files);
        assert!(bad.is_empty(), "`{}`: {bad:?}", a.setting);
        if [
            "teacher",
            "student",
            "manifold",
            "error_model",
            "candidates",
        ]
        .contains(&a.kind.as_str())
        {
            let mut after = Vec::new();
            nulls(&summary, &mut Vec::new(), &mut after);
            after.retain(|p| !before.contains(p));
            assert!(
                after.is_empty(),
                "`{}`: non-finite numbers at {after:?}",
                a.setting
            );
        }
        eprintln!("built: {} ({})", a.setting, a.kind);
    }
    assert!(chosen.len() >= 10, "{} settings built", chosen.len());
}
