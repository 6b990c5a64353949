//! Where a LeRobot v3.0 dataset's files go and the metadata they carry: the format and path
//! constants, `meta/info.json`, the tasks frame's pandas metadata and the provenance every
//! Parquet file keeps.

use std::fs;
use std::io;
use std::path::Path;

use parquet::file::metadata::KeyValue;

use super::columns::{DEPLOYABLE_KEYS, DataTable, J, Tasks, privileged_key};
use crate::{Error, ExportOptions, ExportSet};

/// The LeRobot dataset format version written.
pub const CODEBASE_VERSION: &str = "v3.0";
/// `info.json`'s `robot_type`: the xArm7 arm with the ORCA hand.
pub const ROBOT_TYPE: &str = "xarm7_orca_hand";
/// LeRobot's defaults, stated in `info.json` (everything fits one chunk and one file here).
pub(super) const CHUNKS_SIZE: u64 = 1000;
pub(super) const DATA_FILES_SIZE_IN_MB: u64 = 100;
pub(super) const VIDEO_FILES_SIZE_IN_MB: u64 = 200;

pub const INFO_PATH: &str = "meta/info.json";
pub const STATS_PATH: &str = "meta/stats.json";
pub const TASKS_PATH: &str = "meta/tasks.parquet";
pub const EPISODES_PATH: &str = "meta/episodes/chunk-000/file-000.parquet";
pub const DATA_PATH: &str = "data/chunk-000/file-000.parquet";
/// `info.json`'s `data_path` (a Python format string).
pub(super) const DATA_PATH_TEMPLATE: &str =
    "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet";

/// osms's provenance, in the Parquet footers.
pub(super) fn osms_metadata(set: &ExportSet) -> KeyValue {
    let v = serde_json::json!({
        "provenance": set.provenance,
        "source_kind": set.source_kind,
        "fps": set.fps,
        "timestep_secs": set.timestep_secs,
        "substeps": set.substeps,
    });
    KeyValue::new("osms".into(), v.to_string())
}

/// The `pandas` schema metadata pyarrow writes for a frame indexed by a string `task` with
/// one int64 column `task_index`: `pd.read_parquet` restores the index from it.
pub(super) fn pandas_tasks_metadata() -> String {
    let column = |name: &str, pandas_type: &str, numpy_type: &str| {
        serde_json::json!({
            "name": name,
            "field_name": name,
            "pandas_type": pandas_type,
            "numpy_type": numpy_type,
            "metadata": null,
        })
    };
    let meta = J::Obj(vec![
        ("index_columns".into(), J::Val(serde_json::json!(["task"]))),
        (
            "column_indexes".into(),
            J::Val(serde_json::json!([{
                "name": null,
                "field_name": null,
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": {"encoding": "UTF-8"},
            }])),
        ),
        (
            "columns".into(),
            J::Val(serde_json::Value::Array(vec![
                column("task_index", "int64", "int64"),
                column("task", "unicode", "object"),
            ])),
        ),
        (
            "creator".into(),
            J::Val(serde_json::json!({"library": "osms", "version": env!("CARGO_PKG_VERSION")})),
        ),
        ("pandas_version".into(), J::Val(serde_json::json!("2.2.3"))),
    ]);
    serde_json::to_string(&meta).unwrap_or_default()
}

pub(super) fn info_json(
    set: &ExportSet,
    tasks: &Tasks,
    data: &DataTable,
    options: ExportOptions,
) -> J {
    let v = |x: serde_json::Value| J::Val(x);
    let features = data
        .features
        .iter()
        .map(|f| {
            (
                f.column.name.clone(),
                J::Obj(vec![
                    ("dtype".into(), v(f.dtype.name().into())),
                    ("shape".into(), v(serde_json::json!([f.width]))),
                    ("names".into(), v(serde_json::json!(f.names))),
                ]),
            )
        })
        .collect();
    let n = set.episodes.len();
    J::Obj(vec![
        ("codebase_version".into(), v(CODEBASE_VERSION.into())),
        ("robot_type".into(), v(ROBOT_TYPE.into())),
        ("total_episodes".into(), v(n.into())),
        ("total_frames".into(), v(data.rows.into())),
        ("total_tasks".into(), v(tasks.names.len().into())),
        ("chunks_size".into(), v(CHUNKS_SIZE.into())),
        (
            "data_files_size_in_mb".into(),
            v(DATA_FILES_SIZE_IN_MB.into()),
        ),
        (
            "video_files_size_in_mb".into(),
            v(VIDEO_FILES_SIZE_IN_MB.into()),
        ),
        ("fps".into(), v(set.fps.into())),
        (
            "splits".into(),
            v(serde_json::json!({"train": format!("0:{n}")})),
        ),
        ("data_path".into(), v(DATA_PATH_TEMPLATE.into())),
        ("video_path".into(), v(serde_json::Value::Null)),
        ("features".into(), J::Obj(features)),
        ("osms".into(), osms_info(data, options)),
    ])
}

/// What a reader of the files must know that LeRobot's own keys cannot say: which features a
/// deployable policy may read, and where the privileged frame is (LeRobot's loader keeps
/// `info.json` as a plain dictionary, so the extra key rides along).
fn osms_info(data: &DataTable, options: ExportOptions) -> J {
    let v = |x: serde_json::Value| J::Val(x);
    let privileged = privileged_key(options);
    let has = |key: &str| data.features.iter().any(|f| f.column.name == key);
    J::Obj(vec![
        (
            "deployable_features".into(),
            v(serde_json::json!(DEPLOYABLE_KEYS)),
        ),
        ("action_feature".into(), v("action".into())),
        (
            "privileged_feature".into(),
            v(if has(privileged) {
                privileged.into()
            } else {
                serde_json::Value::Null
            }),
        ),
        (
            "privileged_is_policy_input".into(),
            v(serde_json::Value::Bool(
                has(privileged) && options.privileged_obs,
            )),
        ),
        (
            "task_index".into(),
            v(serde_json::json!(
                "fixed: catch the <variant>, in osms's variant order; the same in every osms export"
            )),
        ),
    ])
}

/// Pretty-printed with LeRobot's four-space indent.
pub(super) fn write_json(path: &Path, value: &J) -> Result<(), Error> {
    let mut buf = Vec::new();
    let fmt = serde_json::ser::PrettyFormatter::with_indent(b"    ");
    let mut ser = serde_json::Serializer::with_formatter(&mut buf, fmt);
    serde::Serialize::serialize(value, &mut ser)
        .map_err(|e| Error::io(path, io::Error::other(e)))?;
    buf.push(b'\n');
    fs::write(path, buf).map_err(|e| Error::io(path, e))
}
