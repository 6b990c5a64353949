//! The columns of a LeRobot dataset and their statistics: the tasks, each feature's values
//! per frame, the per-episode rows, and min / max / mean / std / count / quantiles as
//! LeRobot's `stats.json` and episodes table carry them.

use std::ops::Range;

use osms_policy::osw::OMEGA_LEN;
use osms_sim::N_ACTION;
use osms_sim::policy::{DEPLOYABLE_LEN, PRIVILEGED_LEN};
use osms_sim::robot::{ARM_JOINTS, HAND_JOINTS};

pub(super) use crate::parquet_file::{Column, Values};
use crate::{Error, ExportOptions, ExportSet};

/// The key of the privileged frame where a policy reads it (`--privileged-obs`) ...
pub const PRIVILEGED_OBS_KEY: &str = "observation.environment_state";
/// ... and where it does not: LeRobot's `dataset_to_policy_features` maps only `observation*`
/// and `action*` keys to policy inputs.
pub const PRIVILEGED_KEY: &str = "osms.privileged";
/// The keys a deployable policy may read (and `action`, its output).
pub const DEPLOYABLE_KEYS: [&str; 1] = ["observation.state"];

/// Where the privileged frame goes under `options`.
pub fn privileged_key(options: ExportOptions) -> &'static str {
    if options.privileged_obs {
        PRIVILEGED_OBS_KEY
    } else {
        PRIVILEGED_KEY
    }
}

/// The quantiles LeRobot's stats carry, by key.
pub(super) const QUANTILES: [(&str, f64); 5] = [
    ("q01", 0.01),
    ("q10", 0.10),
    ("q50", 0.50),
    ("q90", 0.90),
    ("q99", 0.99),
];

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

/// Every variant's task in the fixed order of [`crate::task_names`] (LeRobot reads an episode's
/// task by row position, so the table holds all ten, used or not), and each episode's index.
pub(super) struct Tasks {
    pub(super) names: Vec<String>,
    pub(super) of_episode: Vec<usize>,
}

impl Tasks {
    pub(super) fn of(set: &ExportSet) -> Tasks {
        Tasks {
            names: crate::task_names(),
            of_episode: set
                .episodes
                .iter()
                .map(|e| crate::task_index(e.variant))
                .collect(),
        }
    }
}

pub(super) fn to_i64(v: usize) -> i64 {
    // Frame and episode counts are far below 2^63.
    i64::try_from(v).unwrap_or(i64::MAX)
}

/// A feature's LeRobot dtype.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Dtype {
    Float32,
    Float64,
    Int64,
    Bool,
    String,
}

impl Dtype {
    pub(super) fn name(self) -> &'static str {
        match self {
            Dtype::Float32 => "float32",
            Dtype::Float64 => "float64",
            Dtype::Int64 => "int64",
            Dtype::Bool => "bool",
            Dtype::String => "string",
        }
    }
}

/// A data column with what `info.json` says of it.
pub(super) struct Feature {
    pub(super) column: Column,
    pub(super) dtype: Dtype,
    pub(super) width: usize,
    pub(super) names: Option<Vec<String>>,
}

impl Feature {
    pub(super) fn new(
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
        // LeRobot stores shape-[1] features as plain values, wider ones as lists.
        let column = if width == 1 {
            Column::scalar(name, values)
        } else {
            Column::list(name, values, (0..=rows).map(|r| r * width).collect())
        };
        Feature {
            column,
            dtype,
            width,
            names,
        }
    }

    /// Statistics over the frames `rows`, per channel; none for strings (as LeRobot).
    pub(super) fn stats(&self, rows: Range<usize>) -> Option<Stats> {
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
pub(super) struct Stats {
    pub(super) min: Vec<f64>,
    pub(super) max: Vec<f64>,
    pub(super) mean: Vec<f64>,
    pub(super) std: Vec<f64>,
    pub(super) count: usize,
    pub(super) quantiles: Vec<Vec<f64>>,
}

impl Stats {
    pub(super) fn of<T>(v: &[T], width: usize, rows: Range<usize>, f: impl Fn(&T) -> f64) -> Stats {
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
    pub(super) fn json(&self, dtype: Dtype) -> J {
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
pub(super) fn quantile(sorted: &[f64], q: f64) -> f64 {
    let Some(last) = sorted.len().checked_sub(1) else {
        return f64::NAN;
    };
    let pos = q * last as f64;
    let lo = (pos.floor() as usize).min(last);
    let hi = (lo + 1).min(last);
    let t = pos - lo as f64;
    sorted[lo] + (sorted[hi] - sorted[lo]) * t
}

pub(super) fn floats_json(v: &[f64]) -> J {
    J::Val(serde_json::Value::Array(
        v.iter().map(|&x| serde_json::Value::from(x)).collect(),
    ))
}

/// min and max keep the feature's type, as numpy's do.
pub(super) fn extreme_json(v: &[f64], dtype: Dtype) -> J {
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
pub(super) struct DataTable {
    pub(super) features: Vec<Feature>,
    pub(super) rows: usize,
    /// Each episode's global frame range.
    pub(super) episode_rows: Vec<Range<usize>>,
}

impl DataTable {
    pub(super) fn build(
        set: &ExportSet,
        tasks: &Tasks,
        options: ExportOptions,
    ) -> Result<DataTable, Error> {
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
                privileged_key(options),
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
                return Err(Error::Format(format!(
                    "{} has {len} values for {rows} frames of {}",
                    f.column.name, f.width
                )));
            }
            if let Some(names) = &f.names
                && names.len() != f.width
            {
                return Err(Error::Format(format!(
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
pub(super) fn episodes_table(set: &ExportSet, tasks: &Tasks, data: &DataTable) -> Vec<Column> {
    let n = set.episodes.len();
    let ints = |f: &dyn Fn(usize) -> i64| Values::I64((0..n).map(f).collect());
    let range = |i: usize| data.episode_rows.get(i).cloned().unwrap_or(0..0);
    let mut cols = vec![
        Column::scalar("episode_index", ints(&to_i64)),
        // A list of one task per episode.
        Column::list(
            "tasks",
            Values::Str(
                tasks
                    .of_episode
                    .iter()
                    .map(|&k| tasks.names.get(k).cloned().unwrap_or_default())
                    .collect(),
            ),
            (0..=n).collect(),
        ),
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
        let list = |stat: &str, values: Values, width: usize| {
            Column::list(&name(stat), values, (0..=n).map(|r| r * width).collect())
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
        Values::Str(eps.iter().map(|e| e.variant.to_string()).collect()),
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

/// JSON with its keys in the order given (serde_json's map would sort them).
pub(super) enum J {
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
