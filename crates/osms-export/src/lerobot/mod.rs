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
//!
//! [`layout`] holds the paths and metadata, [`columns`] the columns and their statistics,
//! [`parquet_writer`] the Parquet files; [`write`] puts them together.

mod columns;
mod layout;

use std::fs;
use std::path::{Path, PathBuf};

use osms_policy::osw::OMEGA_LEN;
use osms_sim::N_ACTION;
use parquet::file::metadata::KeyValue;

use self::columns::{Column, DataTable, J, Tasks, Values, episodes_table, to_i64};
use self::layout::{
    DATA_PATH, EPISODES_PATH, INFO_PATH, STATS_PATH, TASKS_PATH, info_json, osms_metadata,
    pandas_tasks_metadata, write_json,
};
use crate::{Error, ExportOptions, ExportSet};

pub use self::columns::{
    DEPLOYABLE_KEYS, PRIVILEGED_KEY, PRIVILEGED_OBS_KEY, omega_names, privileged_key,
};
pub use self::layout::{CODEBASE_VERSION, ROBOT_TYPE};

/// Writes `set` in LeRobot v3.0 layout into the directory `out`, empty but for hidden files
/// (a writer's marker); returns the files written. The privileged frame, where the set has
/// it, goes where `options` says ([`privileged_key`]).
pub fn write(set: &ExportSet, out: &Path, options: ExportOptions) -> Result<Vec<PathBuf>, Error> {
    crate::validate(set)?;
    check(set)?;
    let mut entries = fs::read_dir(out).map_err(|e| Error::io(out, e))?;
    if entries.any(|e| e.map_or(true, |e| !e.file_name().to_string_lossy().starts_with('.'))) {
        return Err(Error::Format(format!(
            "{} is not empty: a LeRobot dataset is written into an empty directory",
            out.display()
        )));
    }

    let tasks = Tasks::of(set);
    let data = DataTable::build(set, &tasks, options)?;

    let mut written = Vec::new();
    for dir in ["meta/episodes/chunk-000", "data/chunk-000"] {
        let p = out.join(dir);
        fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
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
    write_json(&path, &info_json(set, &tasks, &data, options))?;
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
fn check(set: &ExportSet) -> Result<(), Error> {
    if set.episodes.is_empty() {
        return Err(Error::Format(
            "a LeRobot dataset needs at least one episode".into(),
        ));
    }
    for (i, e) in set.episodes.iter().enumerate() {
        let bad = |message: String| Error::Episode {
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

/// Writes `columns` as the Parquet file `path`, one row group per range in `groups`.
fn write_parquet(
    path: &Path,
    columns: &[&Column],
    groups: &[std::ops::Range<usize>],
    metadata: Vec<KeyValue>,
) -> Result<(), Error> {
    let file = fs::File::create(path).map_err(|e| Error::io(path, e))?;
    crate::parquet_file::write(file, columns, groups, Some(metadata))
        .map(drop)
        .map_err(|e| Error::io(path, std::io::Error::other(e)))
}

#[cfg(test)]
mod tests {
    use osms_sim::policy::{DEPLOYABLE_LEN, PRIVILEGED_LEN};
    use osms_sim::robot::ARM_JOINTS;

    use super::*;
    use crate::{ExportEpisode, Provenance};
    use parquet::file::reader::{FileReader, SerializedFileReader};

    fn episode(variant: &str, frames: usize, seed: f32, rollout: bool) -> ExportEpisode {
        let ramp = |n: usize, scale: f32| -> Vec<f32> {
            (0..n).map(|i| seed + scale * i as f32).collect()
        };
        ExportEpisode {
            variant: variant.parse().expect("a variant"),
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
            episode("box-large", 3, 1.0, false),
            episode("sphere-small", 4, 2.0, true),
        ])
    }

    fn rollouts() -> ExportSet {
        set(vec![
            episode("sphere-small", 6, 0.0, true),
            episode("capsule-small", 2, -1.0, true),
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
        let files = write(&mixed(), dir.path(), ExportOptions::default()).expect("write");
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
        assert_eq!(info["total_tasks"], 10, "every variant's task, used or not");
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
        assert_eq!(tasks.metadata().file_metadata().num_rows(), 10);
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
        write(&rollouts(), dir.path(), ExportOptions::default()).expect("write");
        let info = read_json(&dir.path().join(INFO_PATH));
        let f = &info["features"];
        assert_eq!(
            f["osms.intended_action"]["shape"],
            serde_json::json!([N_ACTION])
        );
        assert_eq!(f["osms.phase"]["dtype"], "int64");
        let data = parquet(&dir.path().join(DATA_PATH));
        assert!(column_names(&data).iter().any(|c| c == "osms.phase"));
    }

    /// The privileged frame is a policy input only when asked for: LeRobot feeds every
    /// `observation*` feature to a policy by default.
    #[test]
    fn the_privileged_frame_is_an_observation_only_with_the_flag() {
        for privileged_obs in [false, true] {
            let dir = tempfile::tempdir().expect("tempdir");
            let options = ExportOptions { privileged_obs };
            write(&rollouts(), dir.path(), options).expect("write");
            let info = read_json(&dir.path().join(INFO_PATH));
            let features = info["features"].as_object().expect("features");
            let mut observations: Vec<&str> = features
                .keys()
                .map(String::as_str)
                .filter(|k| k.starts_with("observation"))
                .collect();
            observations.sort_unstable();
            let key = if privileged_obs {
                assert_eq!(
                    observations,
                    ["observation.environment_state", "observation.state"]
                );
                PRIVILEGED_OBS_KEY
            } else {
                assert_eq!(observations, ["observation.state"]);
                PRIVILEGED_KEY
            };
            assert_eq!(features[key]["shape"], serde_json::json!([PRIVILEGED_LEN]));
            let data = parquet(&dir.path().join(DATA_PATH));
            let columns = column_names(&data);
            assert!(columns.iter().any(|c| c == key), "{columns:?}");
            let osms = &info["osms"];
            assert_eq!(
                osms["deployable_features"],
                serde_json::json!(["observation.state"])
            );
            assert_eq!(osms["privileged_feature"], key);
            assert_eq!(osms["privileged_is_policy_input"], privileged_obs);
            let stats = read_json(&dir.path().join(STATS_PATH));
            assert!(stats.get(key).is_some());
        }
        // A set without privileged frames says so.
        let dir = tempfile::tempdir().expect("tempdir");
        write(&mixed(), dir.path(), ExportOptions::default()).expect("write");
        let info = read_json(&dir.path().join(INFO_PATH));
        assert!(info["osms"]["privileged_feature"].is_null());
    }

    /// Two sets with the variants in different orders give every variant the same index.
    #[test]
    fn task_indices_are_the_same_in_every_export() {
        let read_tasks = |set: &ExportSet| {
            let dir = tempfile::tempdir().expect("tempdir");
            write(set, dir.path(), ExportOptions::default()).expect("write");
            let t = parquet(&dir.path().join(TASKS_PATH));
            let mut rows = Vec::new();
            for row in t.get_row_iter(None).expect("rows") {
                let row = row.expect("row");
                let cols: Vec<_> = row.get_column_iter().map(|(_, v)| v.to_string()).collect();
                rows.push(cols);
            }
            let d = parquet(&dir.path().join(DATA_PATH));
            let mut per_frame = Vec::new();
            for row in d.get_row_iter(None).expect("rows") {
                let row = row.expect("row");
                let (_, v) = row
                    .get_column_iter()
                    .find(|(n, _)| n.as_str() == "task_index")
                    .expect("task_index");
                per_frame.push(v.to_string());
            }
            (rows, per_frame)
        };
        let (a, a_frames) = read_tasks(&mixed());
        let (b, _) = read_tasks(&rollouts());
        assert_eq!(a, b);
        assert_eq!(a.len(), 10);
        for (i, variant) in osms_sim::ObjectVariant::all().into_iter().enumerate() {
            let name = crate::task_name(variant);
            assert_eq!(a[i], [i.to_string(), format!("\"{name}\"")]);
            assert_eq!(crate::task_index(variant), i);
        }
        // sphere-small (3) for 5 frames, box-large (0) for 3, sphere-small for 4.
        let want: Vec<String> = [(3, 5), (0, 3), (3, 4)]
            .iter()
            .flat_map(|&(k, n)| std::iter::repeat_n(k.to_string(), n))
            .collect();
        assert_eq!(a_frames, want);
    }

    #[test]
    fn same_set_same_bytes() {
        let a = tempfile::tempdir().expect("tempdir");
        let b = tempfile::tempdir().expect("tempdir");
        let fa = write(&mixed(), a.path(), ExportOptions::default()).expect("write");
        let fb = write(&mixed(), b.path(), ExportOptions::default()).expect("write");
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
            write(&mixed(), dir.path(), ExportOptions::default()),
            Err(Error::Format(_))
        ));

        let dir = tempfile::tempdir().expect("tempdir");
        let mut s = mixed();
        s.episodes[2].intended_action = Some(vec![0.0; 3]);
        assert!(matches!(
            write(&s, dir.path(), ExportOptions::default()),
            Err(Error::Episode { episode: 2, .. })
        ));

        let mut s = mixed();
        s.episodes[1].phase = Some(vec![0; 1]);
        assert!(matches!(
            write(&s, dir.path(), ExportOptions::default()),
            Err(Error::Episode { episode: 1, .. })
        ));

        let mut s = mixed();
        s.episodes[0].state.pop();
        assert!(matches!(
            write(&s, dir.path(), ExportOptions::default()),
            Err(Error::Episode { episode: 0, .. })
        ));

        assert!(matches!(
            write(&set(Vec::new()), dir.path(), ExportOptions::default()),
            Err(Error::Format(_))
        ));

        let missing = dir.path().join("missing");
        assert!(matches!(
            write(&mixed(), &missing, ExportOptions::default()),
            Err(Error::Io { .. })
        ));
    }
}
