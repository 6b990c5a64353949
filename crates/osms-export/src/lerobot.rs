//! LeRobot v3.0 layout (docs/export.md).
//!
//! What LeRobot's `LeRobotDataset` (codebase version "v3.0") reads, written without LeRobot:
//!
//! - `meta/info.json`: codebase version, counts, chunking settings, fps, splits, path templates
//!   and the features (dtype, shape, names) that the data Parquet's columns must match.
//! - `meta/stats.json`: per feature min, max, mean, std, count and the q01 ... q99 quantiles
//!   (LeRobot's quantile normalisation needs q01 and q99).
//! - `meta/tasks.parquet`: a pandas frame indexed by the task string with a `task_index` column
//!   (the `pandas` schema metadata makes `pd.read_parquet` restore that index).
//! - `meta/episodes/chunk-000/file-000.parquet`: one row per episode: index, tasks, length,
//!   where its frames are (data file and global frame range), the per-episode
//!   `stats/<feature>/<stat>` columns LeRobot's dataset tools merge, and osms's own columns.
//! - `data/chunk-000/file-000.parquet`: one row per frame, one row group per episode.
//!
//! Every Parquet column is nullable, lists are the standard three-level `LIST` groups, pages
//! are Snappy-compressed (as LeRobot's own writer does): the bytes depend only on the
//! [`ExportSet`].

use std::fs;
use std::io;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use osms_policy::osw::OMEGA_LEN;
use osms_sim::N_ACTION;
use osms_sim::episode::{DEPLOYABLE_LEN, PRIVILEGED_LEN};
use osms_sim::robot::{ARM_JOINTS, HAND_JOINTS};
use parquet::basic::{Compression, LogicalType, Repetition, Type as PhysicalType};
use parquet::data_type::{BoolType, ByteArray, ByteArrayType, DoubleType, FloatType, Int64Type};
use parquet::errors::ParquetError;
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;
use parquet::file::writer::{SerializedColumnWriter, SerializedFileWriter};
use parquet::schema::types::Type;

use crate::{ExportError, ExportSet};

/// The LeRobot dataset format version written.
pub const CODEBASE_VERSION: &str = "v3.0";
/// `info.json`'s `robot_type`: the xArm7 arm with the ORCA hand.
pub const ROBOT_TYPE: &str = "xarm7_orca_hand";
/// LeRobot's defaults, stated in `info.json` (everything fits one chunk and one file here).
const CHUNKS_SIZE: u64 = 1000;
const DATA_FILES_SIZE_IN_MB: u64 = 100;
const VIDEO_FILES_SIZE_IN_MB: u64 = 200;

pub const INFO_PATH: &str = "meta/info.json";
pub const STATS_PATH: &str = "meta/stats.json";
pub const TASKS_PATH: &str = "meta/tasks.parquet";
pub const EPISODES_PATH: &str = "meta/episodes/chunk-000/file-000.parquet";
pub const DATA_PATH: &str = "data/chunk-000/file-000.parquet";
/// `info.json`'s `data_path` (a Python format string).
const DATA_PATH_TEMPLATE: &str = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet";

/// The quantiles LeRobot's stats carry, by key.
const QUANTILES: [(&str, f64); 5] = [
    ("q01", 0.01),
    ("q10", 0.10),
    ("q50", 0.50),
    ("q90", 0.90),
    ("q99", 0.99),
];

/// An episode's LeRobot task: one per object variant.
pub fn task_name(variant: &str) -> String {
    format!("catch the {variant}")
}

/// Names of ω's features (`osms_policy::osw::omega_features`'s order).
pub fn omega_names() -> Vec<String> {
    let mut n: Vec<String> = osms_sim::ObjectVariant::all()
        .iter()
        .map(|v| format!("variant.{v}"))
        .collect();
    n.push("mass_kg".into());
    n.extend(["x", "y", "z"].map(|a| format!("launch_pos.{a}")));
    n.extend(["x", "y", "z"].map(|a| format!("launch_vel.{a}")));
    n.push("lateral_offset".into());
    n.push("crossing_time".into());
    n.extend(ARM_JOINTS.iter().map(|j| format!("arm_perturbation.{j}")));
    n.extend(HAND_JOINTS.iter().map(|j| format!("hand_perturbation.{j}")));
    n
}

/// Writes `set` in LeRobot v3.0 layout into the directory `out`, empty but for hidden files
/// (a writer's marker); returns the files written.
pub fn write(set: &ExportSet, out: &Path) -> Result<Vec<PathBuf>, ExportError> {
    crate::validate(set)?;
    check(set)?;
    let mut entries = fs::read_dir(out).map_err(|e| ExportError::io(out, e))?;
    if entries.any(|e| e.map_or(true, |e| !e.file_name().to_string_lossy().starts_with('.'))) {
        return Err(ExportError::Format(format!(
            "{} is not empty: a LeRobot dataset is written into an empty directory",
            out.display()
        )));
    }

    let tasks = Tasks::of(set);
    let data = DataTable::build(set, &tasks)?;

    let mut written = Vec::new();
    for dir in ["meta/episodes/chunk-000", "data/chunk-000"] {
        let p = out.join(dir);
        fs::create_dir_all(&p).map_err(|e| ExportError::io(&p, e))?;
    }

    // Data: one row group per episode.
    let columns: Vec<&Column> = data.features.iter().map(|f| &f.column).collect();
    let path = out.join(DATA_PATH);
    write_parquet(
        &path,
        &columns,
        &data.episode_rows,
        vec![osms_metadata(set)],
    )?;
    written.push(path);

    // Episodes metadata.
    let episodes = episodes_table(set, &tasks, &data);
    let columns: Vec<&Column> = episodes.iter().collect();
    let path = out.join(EPISODES_PATH);
    let all = 0..set.episodes.len();
    write_parquet(
        &path,
        &columns,
        std::slice::from_ref(&all),
        vec![osms_metadata(set)],
    )?;
    written.push(path);

    // Tasks, as pandas writes a frame indexed by `task`.
    let task_index = Column::scalar(
        "task_index",
        Values::I64((0..tasks.names.len()).map(to_i64).collect()),
    );
    let task = Column::scalar("task", Values::Str(tasks.names.clone()));
    let path = out.join(TASKS_PATH);
    write_parquet(
        &path,
        &[&task_index, &task],
        std::slice::from_ref(&(0..tasks.names.len())),
        vec![KeyValue::new("pandas".into(), pandas_tasks_metadata())],
    )?;
    written.push(path);

    // info.json and stats.json.
    let path = out.join(INFO_PATH);
    write_json(&path, &info_json(set, &tasks, &data))?;
    written.push(path);
    let path = out.join(STATS_PATH);
    let stats = J::Obj(
        data.features
            .iter()
            .filter_map(|f| {
                let s = f.stats(0..data.rows)?;
                Some((f.column.name.clone(), s.json(f.dtype)))
            })
            .collect(),
    );
    write_json(&path, &stats)?;
    written.push(path);

    written.sort();
    Ok(written)
}

/// What [`crate::validate`] leaves to the writers: the widths of the optional per-frame arrays,
/// ω's length, and episodes with frames (LeRobot has no empty episodes).
fn check(set: &ExportSet) -> Result<(), ExportError> {
    if set.episodes.is_empty() {
        return Err(ExportError::Format(
            "a LeRobot dataset needs at least one episode".into(),
        ));
    }
    for (i, e) in set.episodes.iter().enumerate() {
        let bad = |message: String| ExportError::Episode {
            episode: i,
            message,
        };
        if e.frames == 0 {
            return Err(bad("has no frames".into()));
        }
        if let Some(a) = &e.intended_action
            && a.len() != e.frames * N_ACTION
        {
            return Err(bad(format!(
                "intended_action has {} values, expected {}",
                a.len(),
                e.frames * N_ACTION
            )));
        }
        if let Some(p) = &e.phase
            && p.len() != e.frames
        {
            return Err(bad(format!(
                "phase has {} values, expected {}",
                p.len(),
                e.frames
            )));
        }
        if e.omega.len() != OMEGA_LEN {
            return Err(bad(format!(
                "omega has {} values, expected {OMEGA_LEN}",
                e.omega.len()
            )));
        }
    }
    Ok(())
}

/// Tasks in order of first appearance, and each episode's task index.
struct Tasks {
    names: Vec<String>,
    of_episode: Vec<usize>,
}

impl Tasks {
    fn of(set: &ExportSet) -> Tasks {
        let mut names: Vec<String> = Vec::new();
        let mut of_episode = Vec::with_capacity(set.episodes.len());
        for e in &set.episodes {
            let name = task_name(&e.variant);
            let k = match names.iter().position(|n| *n == name) {
                Some(k) => k,
                None => {
                    names.push(name);
                    names.len() - 1
                }
            };
            of_episode.push(k);
        }
        Tasks { names, of_episode }
    }
}

fn to_i64(v: usize) -> i64 {
    // Frame and episode counts are far below 2^63.
    i64::try_from(v).unwrap_or(i64::MAX)
}

/// A feature's LeRobot dtype.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Dtype {
    Float32,
    Float64,
    Int64,
    Bool,
    String,
}

impl Dtype {
    fn name(self) -> &'static str {
        match self {
            Dtype::Float32 => "float32",
            Dtype::Float64 => "float64",
            Dtype::Int64 => "int64",
            Dtype::Bool => "bool",
            Dtype::String => "string",
        }
    }
}

/// A column's values, flattened row-major.
#[derive(Debug, Clone, PartialEq)]
enum Values {
    F32(Vec<f32>),
    F64(Vec<f64>),
    I64(Vec<i64>),
    Bool(Vec<bool>),
    Str(Vec<String>),
}

/// One Parquet column: a scalar per row, or a list per row (`offsets` has rows + 1 entries).
#[derive(Debug, Clone, PartialEq)]
struct Column {
    name: String,
    values: Values,
    offsets: Option<Vec<usize>>,
}

impl Column {
    fn scalar(name: &str, values: Values) -> Column {
        Column {
            name: name.into(),
            values,
            offsets: None,
        }
    }

    /// `width` values per row: a list column, or a scalar one for width 1 (LeRobot stores
    /// shape-[1] features as plain values).
    fn fixed(name: &str, values: Values, width: usize, rows: usize) -> Column {
        Column {
            name: name.into(),
            values,
            offsets: (width != 1).then(|| (0..=rows).map(|r| r * width).collect()),
        }
    }
}

/// A data column with what `info.json` says of it.
struct Feature {
    column: Column,
    dtype: Dtype,
    width: usize,
    names: Option<Vec<String>>,
}

impl Feature {
    fn new(
        name: &str,
        values: Values,
        width: usize,
        rows: usize,
        names: Option<Vec<String>>,
    ) -> Feature {
        let dtype = match values {
            Values::F32(_) => Dtype::Float32,
            Values::F64(_) => Dtype::Float64,
            Values::I64(_) => Dtype::Int64,
            Values::Bool(_) => Dtype::Bool,
            Values::Str(_) => Dtype::String,
        };
        Feature {
            column: Column::fixed(name, values, width, rows),
            dtype,
            width,
            names,
        }
    }

    /// Statistics over the frames `rows`, per channel; none for strings (as LeRobot).
    fn stats(&self, rows: Range<usize>) -> Option<Stats> {
        let w = self.width;
        Some(match &self.column.values {
            Values::F32(v) => Stats::of(v, w, rows, |x| f64::from(*x)),
            Values::F64(v) => Stats::of(v, w, rows, |x| *x),
            Values::I64(v) => Stats::of(v, w, rows, |x| *x as f64),
            Values::Bool(v) => Stats::of(v, w, rows, |x| if *x { 1.0 } else { 0.0 }),
            Values::Str(_) => return None,
        })
    }
}

/// min, max, mean, std (population), count and quantiles of one feature, per channel, in f64
/// with a fixed summation order (frame order).
struct Stats {
    min: Vec<f64>,
    max: Vec<f64>,
    mean: Vec<f64>,
    std: Vec<f64>,
    count: usize,
    quantiles: Vec<Vec<f64>>,
}

impl Stats {
    fn of<T>(v: &[T], width: usize, rows: Range<usize>, f: impl Fn(&T) -> f64) -> Stats {
        let count = rows.len();
        let mut s = Stats {
            min: Vec::with_capacity(width),
            max: Vec::with_capacity(width),
            mean: Vec::with_capacity(width),
            std: Vec::with_capacity(width),
            count,
            quantiles: vec![Vec::with_capacity(width); QUANTILES.len()],
        };
        let mut xs = Vec::with_capacity(count);
        for d in 0..width {
            xs.clear();
            xs.extend(rows.clone().filter_map(|r| v.get(r * width + d)).map(&f));
            let n = xs.len() as f64;
            let mean = xs.iter().sum::<f64>() / n;
            let var = xs.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
            xs.sort_by(f64::total_cmp);
            s.min.push(xs.first().copied().unwrap_or(f64::NAN));
            s.max.push(xs.last().copied().unwrap_or(f64::NAN));
            s.mean.push(mean);
            s.std.push(var.sqrt());
            for (k, (_, q)) in QUANTILES.iter().enumerate() {
                s.quantiles[k].push(quantile(&xs, *q));
            }
        }
        s
    }

    /// LeRobot's stats dictionary of one feature: every value an array (count's of one).
    fn json(&self, dtype: Dtype) -> J {
        let mut o = vec![
            ("min".to_string(), extreme_json(&self.min, dtype)),
            ("max".to_string(), extreme_json(&self.max, dtype)),
            ("mean".to_string(), floats_json(&self.mean)),
            ("std".to_string(), floats_json(&self.std)),
            (
                "count".to_string(),
                J::Val(serde_json::Value::from(vec![self.count as u64])),
            ),
        ];
        for ((key, _), q) in QUANTILES.iter().zip(&self.quantiles) {
            o.push((key.to_string(), floats_json(q)));
        }
        J::Obj(o)
    }
}

/// The `q` quantile of sorted values, interpolating linearly between closest ranks (numpy's
/// default method).
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let Some(last) = sorted.len().checked_sub(1) else {
        return f64::NAN;
    };
    let pos = q * last as f64;
    let lo = (pos.floor() as usize).min(last);
    let hi = (lo + 1).min(last);
    let t = pos - lo as f64;
    sorted[lo] + (sorted[hi] - sorted[lo]) * t
}

fn floats_json(v: &[f64]) -> J {
    J::Val(serde_json::Value::Array(
        v.iter().map(|&x| serde_json::Value::from(x)).collect(),
    ))
}

/// min and max keep the feature's type, as numpy's do.
fn extreme_json(v: &[f64], dtype: Dtype) -> J {
    match dtype {
        Dtype::Float32 | Dtype::Float64 | Dtype::String => floats_json(v),
        Dtype::Int64 => J::Val(serde_json::Value::Array(
            v.iter()
                .map(|&x| serde_json::Value::from(x as i64))
                .collect(),
        )),
        Dtype::Bool => J::Val(serde_json::Value::Array(
            v.iter()
                .map(|&x| serde_json::Value::from(x != 0.0))
                .collect(),
        )),
    }
}

/// The per-frame table, in `info.json`'s feature order.
struct DataTable {
    features: Vec<Feature>,
    rows: usize,
    /// Each episode's global frame range.
    episode_rows: Vec<Range<usize>>,
}

impl DataTable {
    fn build(set: &ExportSet, tasks: &Tasks) -> Result<DataTable, ExportError> {
        let eps = &set.episodes;
        let rows: usize = eps.iter().map(|e| e.frames).sum();
        let mut episode_rows = Vec::with_capacity(eps.len());
        let mut start = 0;
        for e in eps {
            episode_rows.push(start..start + e.frames);
            start += e.frames;
        }

        let concat = |part: &dyn Fn(&crate::ExportEpisode) -> &[f32]| -> Vec<f32> {
            let mut v = Vec::new();
            for e in eps {
                v.extend_from_slice(part(e));
            }
            v
        };
        // Per-episode values repeated on each of its frames.
        fn per_frame<T: Clone>(
            set: &ExportSet,
            value: impl Fn(usize, &crate::ExportEpisode) -> Vec<T>,
        ) -> Vec<T> {
            let mut v = Vec::new();
            for (i, e) in set.episodes.iter().enumerate() {
                let x = value(i, e);
                for _ in 0..e.frames {
                    v.extend_from_slice(&x);
                }
            }
            v
        }

        let mut features = vec![Feature::new(
            "observation.state",
            Values::F32(concat(&|e| &e.state)),
            DEPLOYABLE_LEN,
            rows,
            Some(crate::state_names()),
        )];
        if eps.iter().all(|e| e.environment_state.is_some()) {
            features.push(Feature::new(
                "observation.environment_state",
                Values::F32(concat(&|e| e.environment_state.as_deref().unwrap_or(&[]))),
                PRIVILEGED_LEN,
                rows,
                Some(crate::environment_state_names()),
            ));
        }
        features.push(Feature::new(
            "action",
            Values::F32(concat(&|e| &e.action)),
            N_ACTION,
            rows,
            Some(crate::action_names()),
        ));
        if eps.iter().all(|e| e.intended_action.is_some()) {
            features.push(Feature::new(
                "osms.intended_action",
                Values::F32(concat(&|e| e.intended_action.as_deref().unwrap_or(&[]))),
                N_ACTION,
                rows,
                Some(crate::action_names()),
            ));
        }
        if eps.iter().all(|e| e.phase.is_some()) {
            let mut v = Vec::with_capacity(rows);
            for e in eps {
                v.extend(e.phase.iter().flatten().map(|&p| i64::from(p)));
            }
            features.push(Feature::new("osms.phase", Values::I64(v), 1, rows, None));
        }
        features.push(Feature::new(
            "osms.success",
            Values::Bool(per_frame(set, |_, e| vec![e.success])),
            1,
            rows,
            None,
        ));
        features.push(Feature::new(
            "osms.omega",
            Values::F32(per_frame(set, |_, e| e.omega.clone())),
            OMEGA_LEN,
            rows,
            Some(omega_names()),
        ));
        features.push(Feature::new(
            "osms.event_step",
            Values::I64(per_frame(set, |_, e| {
                vec![e.event_step.map_or(-1, i64::from)]
            })),
            1,
            rows,
            None,
        ));
        // LeRobot's default features.
        let mut timestamp = Vec::with_capacity(rows);
        let mut frame_index = Vec::with_capacity(rows);
        for e in eps {
            for k in 0..e.frames {
                timestamp.push((k as f64 / f64::from(set.fps)) as f32);
                frame_index.push(to_i64(k));
            }
        }
        features.push(Feature::new(
            "timestamp",
            Values::F32(timestamp),
            1,
            rows,
            None,
        ));
        features.push(Feature::new(
            "frame_index",
            Values::I64(frame_index),
            1,
            rows,
            None,
        ));
        features.push(Feature::new(
            "episode_index",
            Values::I64(per_frame(set, |i, _| vec![to_i64(i)])),
            1,
            rows,
            None,
        ));
        features.push(Feature::new(
            "index",
            Values::I64((0..rows).map(to_i64).collect()),
            1,
            rows,
            None,
        ));
        features.push(Feature::new(
            "task_index",
            Values::I64(per_frame(set, |i, _| {
                vec![to_i64(tasks.of_episode.get(i).copied().unwrap_or(0))]
            })),
            1,
            rows,
            None,
        ));

        for f in &features {
            let len = match &f.column.values {
                Values::F32(v) => v.len(),
                Values::F64(v) => v.len(),
                Values::I64(v) => v.len(),
                Values::Bool(v) => v.len(),
                Values::Str(v) => v.len(),
            };
            if len != rows * f.width {
                return Err(ExportError::Format(format!(
                    "{} has {len} values for {rows} frames of {}",
                    f.column.name, f.width
                )));
            }
            if let Some(names) = &f.names
                && names.len() != f.width
            {
                return Err(ExportError::Format(format!(
                    "{} has {} channel names for {} channels",
                    f.column.name,
                    names.len(),
                    f.width
                )));
            }
        }
        Ok(DataTable {
            features,
            rows,
            episode_rows,
        })
    }
}

/// One row per episode: LeRobot's columns (with its per-episode stats), then osms's.
fn episodes_table(set: &ExportSet, tasks: &Tasks, data: &DataTable) -> Vec<Column> {
    let n = set.episodes.len();
    let ints = |f: &dyn Fn(usize) -> i64| Values::I64((0..n).map(f).collect());
    let range = |i: usize| data.episode_rows.get(i).cloned().unwrap_or(0..0);
    let mut cols = vec![
        Column::scalar("episode_index", ints(&to_i64)),
        // A list of one task per episode.
        Column {
            name: "tasks".into(),
            values: Values::Str(
                tasks
                    .of_episode
                    .iter()
                    .map(|&k| tasks.names.get(k).cloned().unwrap_or_default())
                    .collect(),
            ),
            offsets: Some((0..=n).collect()),
        },
        Column::scalar("length", ints(&|i| to_i64(range(i).len()))),
        Column::scalar("data/chunk_index", ints(&|_| 0)),
        Column::scalar("data/file_index", ints(&|_| 0)),
        Column::scalar("dataset_from_index", ints(&|i| to_i64(range(i).start))),
        Column::scalar("dataset_to_index", ints(&|i| to_i64(range(i).end))),
    ];

    for f in &data.features {
        let Some(per_episode) = (0..n)
            .map(|i| f.stats(range(i)))
            .collect::<Option<Vec<_>>>()
        else {
            continue;
        };
        let w = f.width;
        let name = |stat: &str| format!("stats/{}/{stat}", f.column.name);
        let extreme = |pick: &dyn Fn(&Stats) -> &Vec<f64>| -> Values {
            let all = per_episode.iter().flat_map(|s| pick(s).iter().copied());
            match f.dtype {
                Dtype::Float32 | Dtype::Float64 | Dtype::String => Values::F64(all.collect()),
                Dtype::Int64 => Values::I64(all.map(|x| x as i64).collect()),
                Dtype::Bool => Values::Bool(all.map(|x| x != 0.0).collect()),
            }
        };
        let floats = |pick: &dyn Fn(&Stats) -> &Vec<f64>| -> Values {
            Values::F64(
                per_episode
                    .iter()
                    .flat_map(|s| pick(s).iter().copied())
                    .collect(),
            )
        };
        let list = |stat: &str, values: Values, width: usize| Column {
            name: name(stat),
            values,
            offsets: Some((0..=n).map(|r| r * width).collect()),
        };
        cols.push(list("min", extreme(&|s| &s.min), w));
        cols.push(list("max", extreme(&|s| &s.max), w));
        cols.push(list("mean", floats(&|s| &s.mean), w));
        cols.push(list("std", floats(&|s| &s.std), w));
        cols.push(list(
            "count",
            Values::I64(per_episode.iter().map(|s| to_i64(s.count)).collect()),
            1,
        ));
        for (k, (key, _)) in QUANTILES.iter().enumerate() {
            cols.push(list(key, floats(&|s| &s.quantiles[k]), w));
        }
    }

    cols.push(Column::scalar("meta/episodes/chunk_index", ints(&|_| 0)));
    cols.push(Column::scalar("meta/episodes/file_index", ints(&|_| 0)));

    let eps = &set.episodes;
    cols.push(Column::scalar(
        "osms.variant",
        Values::Str(eps.iter().map(|e| e.variant.clone()).collect()),
    ));
    cols.push(Column::scalar(
        "osms.source",
        Values::Str(eps.iter().map(|e| e.source.clone()).collect()),
    ));
    cols.push(Column::scalar(
        "osms.success",
        Values::Bool(eps.iter().map(|e| e.success).collect()),
    ));
    cols.push(Column::scalar(
        "osms.event_step",
        Values::I64(
            eps.iter()
                .map(|e| e.event_step.map_or(-1, i64::from))
                .collect(),
        ),
    ));
    cols.push(Column::scalar(
        "osms.max_force_n",
        Values::F64(eps.iter().map(|e| e.max_force_n).collect()),
    ));
    cols
}

/// osms's provenance, in the Parquet footers (LeRobot warns of unknown `info.json` keys).
fn osms_metadata(set: &ExportSet) -> KeyValue {
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
fn pandas_tasks_metadata() -> String {
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

fn info_json(set: &ExportSet, tasks: &Tasks, data: &DataTable) -> J {
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
    ])
}

/// JSON with its keys in the order given (serde_json's map would sort them).
enum J {
    Val(serde_json::Value),
    Obj(Vec<(String, J)>),
}

impl serde::Serialize for J {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        match self {
            J::Val(v) => v.serialize(s),
            J::Obj(entries) => {
                let mut m = s.serialize_map(Some(entries.len()))?;
                for (k, v) in entries {
                    m.serialize_entry(k, v)?;
                }
                m.end()
            }
        }
    }
}

/// Pretty-printed with LeRobot's four-space indent.
fn write_json(path: &Path, value: &J) -> Result<(), ExportError> {
    let mut buf = Vec::new();
    let fmt = serde_json::ser::PrettyFormatter::with_indent(b"    ");
    let mut ser = serde_json::Serializer::with_formatter(&mut buf, fmt);
    serde::Serialize::serialize(value, &mut ser)
        .map_err(|e| ExportError::io(path, io::Error::other(e)))?;
    buf.push(b'\n');
    fs::write(path, buf).map_err(|e| ExportError::io(path, e))
}

/// The nullable Parquet field of a column: a primitive, or a three-level `LIST` group.
fn schema_field(col: &Column) -> Result<Type, ParquetError> {
    let (physical, logical) = match col.values {
        Values::F32(_) => (PhysicalType::FLOAT, None),
        Values::F64(_) => (PhysicalType::DOUBLE, None),
        Values::I64(_) => (PhysicalType::INT64, None),
        Values::Bool(_) => (PhysicalType::BOOLEAN, None),
        Values::Str(_) => (PhysicalType::BYTE_ARRAY, Some(LogicalType::String)),
    };
    let primitive = |name: &str| {
        Type::primitive_type_builder(name, physical)
            .with_repetition(Repetition::OPTIONAL)
            .with_logical_type(logical.clone())
            .build()
    };
    if col.offsets.is_none() {
        return primitive(&col.name);
    }
    let list = Type::group_type_builder("list")
        .with_repetition(Repetition::REPEATED)
        .with_fields(vec![Arc::new(primitive("element")?)])
        .build()?;
    Type::group_type_builder(&col.name)
        .with_repetition(Repetition::OPTIONAL)
        .with_logical_type(Some(LogicalType::List))
        .with_fields(vec![Arc::new(list)])
        .build()
}

/// Writes `columns` as one Parquet file, one row group per range of rows in `groups`.
fn write_parquet(
    path: &Path,
    columns: &[&Column],
    groups: &[Range<usize>],
    metadata: Vec<KeyValue>,
) -> Result<(), ExportError> {
    let err = |e: ParquetError| ExportError::io(path, io::Error::other(e));
    let fields = columns
        .iter()
        .map(|c| schema_field(c).map(Arc::new))
        .collect::<Result<Vec<_>, _>>()
        .map_err(err)?;
    let schema = Type::group_type_builder("schema")
        .with_fields(fields)
        .build()
        .map_err(err)?;
    let props = WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .set_key_value_metadata(Some(metadata))
        .build();
    let file = fs::File::create(path).map_err(|e| ExportError::io(path, e))?;
    let mut writer =
        SerializedFileWriter::new(file, Arc::new(schema), Arc::new(props)).map_err(err)?;
    for group in groups {
        let mut rg = writer.next_row_group().map_err(err)?;
        for col in columns {
            let Some(mut cw) = rg.next_column().map_err(err)? else {
                return Err(ExportError::Format(format!(
                    "{}: no Parquet column left for {}",
                    path.display(),
                    col.name
                )));
            };
            write_column(&mut cw, col, group.clone()).map_err(err)?;
            cw.close().map_err(err)?;
        }
        rg.close().map_err(err)?;
    }
    writer.close().map_err(err)?;
    Ok(())
}

/// Writes the rows `rows` of one column with its definition and repetition levels: a
/// scalar is defined at level 1; a list's values at level 3 (list, repeated group, element),
/// an empty list at level 1, each list starting at repetition level 0.
fn write_column(
    cw: &mut SerializedColumnWriter<'_>,
    col: &Column,
    rows: Range<usize>,
) -> Result<(), ParquetError> {
    let (values, def, rep) = match &col.offsets {
        None => (rows.clone(), vec![1i16; rows.len()], None),
        Some(off) => {
            let (Some(&a), Some(&b)) = (off.get(rows.start), off.get(rows.end)) else {
                return Err(ParquetError::General(format!(
                    "{}: rows {rows:?} out of range",
                    col.name
                )));
            };
            let mut def = Vec::with_capacity(b - a + rows.len());
            let mut rep = Vec::with_capacity(b - a + rows.len());
            for r in rows.clone() {
                let n = off[r + 1].saturating_sub(off[r]);
                if n == 0 {
                    def.push(1);
                    rep.push(0);
                }
                for k in 0..n {
                    def.push(3);
                    rep.push(i16::from(k > 0));
                }
            }
            (a..b, def, Some(rep))
        }
    };
    let rep = rep.as_deref();
    let out_of_range = || ParquetError::General(format!("{}: values out of range", col.name));
    match &col.values {
        Values::F32(v) => {
            let v = v.get(values).ok_or_else(out_of_range)?;
            cw.typed::<FloatType>().write_batch(v, Some(&def), rep)?;
        }
        Values::F64(v) => {
            let v = v.get(values).ok_or_else(out_of_range)?;
            cw.typed::<DoubleType>().write_batch(v, Some(&def), rep)?;
        }
        Values::I64(v) => {
            let v = v.get(values).ok_or_else(out_of_range)?;
            cw.typed::<Int64Type>().write_batch(v, Some(&def), rep)?;
        }
        Values::Bool(v) => {
            let v = v.get(values).ok_or_else(out_of_range)?;
            cw.typed::<BoolType>().write_batch(v, Some(&def), rep)?;
        }
        Values::Str(v) => {
            let v: Vec<ByteArray> = v
                .get(values)
                .ok_or_else(out_of_range)?
                .iter()
                .map(|s| ByteArray::from(s.as_str()))
                .collect();
            cw.typed::<ByteArrayType>()
                .write_batch(&v, Some(&def), rep)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ExportEpisode, Provenance};
    use parquet::file::reader::{FileReader, SerializedFileReader};

    fn episode(variant: &str, frames: usize, seed: f32, rollout: bool) -> ExportEpisode {
        let ramp = |n: usize, scale: f32| -> Vec<f32> {
            (0..n).map(|i| seed + scale * i as f32).collect()
        };
        ExportEpisode {
            variant: variant.into(),
            frames,
            state: ramp(frames * DEPLOYABLE_LEN, 0.001),
            environment_state: rollout.then(|| ramp(frames * PRIVILEGED_LEN, -0.002)),
            action: ramp(frames * N_ACTION, 0.01),
            intended_action: rollout.then(|| ramp(frames * N_ACTION, 0.02)),
            phase: rollout.then(|| (0..frames).map(|k| (k % 5) as u8).collect()),
            success: rollout,
            omega: ramp(OMEGA_LEN, 0.5),
            event_step: rollout.then_some(2),
            max_force_n: 3.5,
            source: format!("{variant} {frames}"),
            physics: None,
        }
    }

    fn set(episodes: Vec<ExportEpisode>) -> ExportSet {
        ExportSet {
            provenance: Provenance {
                stage: "d_r".into(),
                kind: "teacher_dataset".into(),
                key: "k".into(),
                content_hash: "h".into(),
                world_key: "wk".into(),
                world_content_hash: "wh".into(),
                profile: "tiny".into(),
            },
            source_kind: "rollouts",
            episodes,
            mjcf: Vec::new(),
            timestep_secs: 0.002,
            substeps: 10,
            fps: 50,
        }
    }

    fn mixed() -> ExportSet {
        set(vec![
            episode("sphere-small", 5, 0.0, true),
            episode("cube-large", 3, 1.0, false),
            episode("sphere-small", 4, 2.0, true),
        ])
    }

    fn rollouts() -> ExportSet {
        set(vec![
            episode("sphere-small", 6, 0.0, true),
            episode("mug", 2, -1.0, true),
        ])
    }

    fn read_json(path: &Path) -> serde_json::Value {
        let text = fs::read_to_string(path).expect("read json");
        serde_json::from_str(&text).expect("parse json")
    }

    fn parquet(path: &Path) -> SerializedFileReader<fs::File> {
        SerializedFileReader::new(fs::File::open(path).expect("open")).expect("parquet")
    }

    fn column_names(r: &SerializedFileReader<fs::File>) -> Vec<String> {
        let schema = r.metadata().file_metadata().schema_descr().root_schema();
        schema
            .get_fields()
            .iter()
            .map(|f| f.name().to_string())
            .collect()
    }

    #[test]
    fn omega_names_cover_omega() {
        assert_eq!(omega_names().len(), OMEGA_LEN);
    }

    #[test]
    fn writes_the_v3_layout() {
        let dir = tempfile::tempdir().expect("tempdir");
        let files = write(&mixed(), dir.path()).expect("write");
        let expected: Vec<PathBuf> = [DATA_PATH, EPISODES_PATH, INFO_PATH, STATS_PATH, TASKS_PATH]
            .iter()
            .map(|p| dir.path().join(p))
            .collect();
        let mut sorted = expected.clone();
        sorted.sort();
        assert_eq!(files, sorted);

        let info = read_json(&dir.path().join(INFO_PATH));
        assert_eq!(info["codebase_version"], "v3.0");
        assert_eq!(info["total_episodes"], 3);
        assert_eq!(info["total_frames"], 12);
        assert_eq!(info["total_tasks"], 2);
        assert_eq!(info["fps"], 50);
        assert_eq!(info["splits"]["train"], "0:3");
        assert!(info["video_path"].is_null());
        let features = info["features"].as_object().expect("features");
        // Episode 1 has no environment state, intended action or phase: no such columns.
        let mut keys: Vec<&str> = features.keys().map(String::as_str).collect();
        keys.sort_unstable();
        assert_eq!(
            keys,
            [
                "action",
                "episode_index",
                "frame_index",
                "index",
                "observation.state",
                "osms.event_step",
                "osms.omega",
                "osms.success",
                "task_index",
                "timestamp",
            ]
        );
        assert_eq!(
            features["observation.state"]["shape"],
            serde_json::json!([DEPLOYABLE_LEN])
        );
        assert_eq!(features["action"]["dtype"], "float32");
        assert_eq!(features["action"]["names"][0], ARM_JOINTS[0]);
        assert_eq!(features["index"]["shape"], serde_json::json!([1]));
        assert_eq!(features["osms.success"]["dtype"], "bool");

        // The data columns are the features, in order; one row group per episode.
        let data = parquet(&dir.path().join(DATA_PATH));
        let raw = fs::read_to_string(dir.path().join(INFO_PATH)).expect("info");
        let order: Vec<String> = column_names(&data);
        let mut positions: Vec<usize> = order
            .iter()
            .map(|c| raw.find(&format!("\"{c}\": {{")).expect("declared"))
            .collect();
        assert_eq!(order.len(), features.len());
        let before = positions.clone();
        positions.sort_unstable();
        assert_eq!(positions, before);
        assert_eq!(data.metadata().file_metadata().num_rows(), 12);
        assert_eq!(data.metadata().num_row_groups(), 3);
        let rows: Vec<i64> = data
            .metadata()
            .row_groups()
            .iter()
            .map(|g| g.num_rows())
            .collect();
        assert_eq!(rows, [5, 3, 4]);

        let episodes = parquet(&dir.path().join(EPISODES_PATH));
        assert_eq!(episodes.metadata().file_metadata().num_rows(), 3);
        let cols = column_names(&episodes);
        for c in [
            "episode_index",
            "tasks",
            "length",
            "data/chunk_index",
            "data/file_index",
            "dataset_from_index",
            "dataset_to_index",
            "stats/action/mean",
            "stats/index/count",
            "meta/episodes/chunk_index",
            "meta/episodes/file_index",
            "osms.source",
        ] {
            assert!(cols.iter().any(|x| x == c), "{c} missing from {cols:?}");
        }

        let tasks = parquet(&dir.path().join(TASKS_PATH));
        assert_eq!(tasks.metadata().file_metadata().num_rows(), 2);
        assert_eq!(column_names(&tasks), ["task_index", "task"]);
        let kv = tasks
            .metadata()
            .file_metadata()
            .key_value_metadata()
            .cloned()
            .unwrap_or_default();
        assert!(kv.iter().any(|k| k.key == "pandas"));

        let stats = read_json(&dir.path().join(STATS_PATH));
        assert_eq!(stats["index"]["min"], serde_json::json!([0]));
        assert_eq!(stats["index"]["max"], serde_json::json!([11]));
        assert_eq!(stats["index"]["mean"], serde_json::json!([5.5]));
        assert_eq!(stats["action"]["count"], serde_json::json!([12]));
        assert_eq!(stats["episode_index"]["q50"], serde_json::json!([1.0]));
        assert_eq!(
            stats["action"]["min"][0],
            serde_json::json!(0.0),
            "episode 0's first action"
        );
        assert_eq!(stats["osms.success"]["max"], serde_json::json!([true]));
    }

    #[test]
    fn rollout_columns_when_every_episode_has_them() {
        let dir = tempfile::tempdir().expect("tempdir");
        write(&rollouts(), dir.path()).expect("write");
        let info = read_json(&dir.path().join(INFO_PATH));
        let f = &info["features"];
        assert_eq!(
            f["observation.environment_state"]["shape"],
            serde_json::json!([PRIVILEGED_LEN])
        );
        assert_eq!(
            f["osms.intended_action"]["shape"],
            serde_json::json!([N_ACTION])
        );
        assert_eq!(f["osms.phase"]["dtype"], "int64");
        assert_eq!(info["total_tasks"], 2);
        let data = parquet(&dir.path().join(DATA_PATH));
        assert!(column_names(&data).iter().any(|c| c == "osms.phase"));
    }

    #[test]
    fn same_set_same_bytes() {
        let a = tempfile::tempdir().expect("tempdir");
        let b = tempfile::tempdir().expect("tempdir");
        let fa = write(&mixed(), a.path()).expect("write");
        let fb = write(&mixed(), b.path()).expect("write");
        assert_eq!(fa.len(), fb.len());
        for (x, y) in fa.iter().zip(&fb) {
            assert_eq!(x.strip_prefix(a.path()).ok(), y.strip_prefix(b.path()).ok());
            assert_eq!(
                fs::read(x).expect("a"),
                fs::read(y).expect("b"),
                "{}",
                x.display()
            );
        }
    }

    #[test]
    fn refuses_bad_input() {
        let dir = tempfile::tempdir().expect("tempdir");
        fs::write(dir.path().join("stale"), b"x").expect("stale");
        assert!(matches!(
            write(&mixed(), dir.path()),
            Err(ExportError::Format(_))
        ));

        let dir = tempfile::tempdir().expect("tempdir");
        let mut s = mixed();
        s.episodes[2].intended_action = Some(vec![0.0; 3]);
        assert!(matches!(
            write(&s, dir.path()),
            Err(ExportError::Episode { episode: 2, .. })
        ));

        let mut s = mixed();
        s.episodes[1].phase = Some(vec![0; 1]);
        assert!(matches!(
            write(&s, dir.path()),
            Err(ExportError::Episode { episode: 1, .. })
        ));

        let mut s = mixed();
        s.episodes[0].state.pop();
        assert!(matches!(
            write(&s, dir.path()),
            Err(ExportError::Episode { episode: 0, .. })
        ));

        assert!(matches!(
            write(&set(Vec::new()), dir.path()),
            Err(ExportError::Format(_))
        ));

        let missing = dir.path().join("missing");
        assert!(matches!(
            write(&mixed(), &missing),
            Err(ExportError::Io { .. })
        ));
    }
}
