//! robomimic HDF5 layout (docs/export.md): one file, robomimic's dataset structure.
//!
//! ```text
//! data                 attrs total (i64), env_args (JSON)
//!   demo_<i>           attrs num_samples, variant, success, source, max_force_n, event_step
//!                      (-1: unknown) and, with physics, mass_kg, friction_scale,
//!                      contact_timeconst_scale, gain_scale, state_size
//!     actions          f32 [N, 24]
//!     rewards          f64 [N]   1 on the last frame of a successful episode
//!     dones            i64 [N]   1 on the last frame
//!     states           f64 [N, state_size]   mjSTATE_FULLPHYSICS (with physics only)
//!     obs/<key>        f32 [N, width]: arm_qpos, arm_qvel, hand_qpos, hand_qvel, object_pos
//!                      (observed: delayed and noisy), palm_touch (N, noisy), prev_action;
//!                      `privileged` only with `--privileged-obs`
//!     next_obs/<key>   obs/<key> of the next step; the last step repeats the last observation
//!     osms/            servo_targets f64 [N, 24] and physics_steps u8 [N] (with physics),
//!                      phase u8 [N], intended_actions f32 [N, 24], omega f32 [OMEGA_LEN],
//!                      privileged f32 [N, PRIVILEGED_LEN] when kept (and not in obs/)
//! mask/train, mask/valid   demo names as fixed-length byte strings; valid: i % 10 == 9
//! ```
//!
//! `env_args`' `type` is 0, which is none of robomimic's environment types: the file trains
//! robomimic's algorithms from `obs` and `next_obs` (`env_kwargs.deployable_obs_keys` lists
//! what a deployable policy may read), and replays through osms's own scripts from `states`,
//! the MJCF in `env_kwargs.mjcf` and the per-demo model edits, never through robomimic's env
//! wrappers.
//!
//! Strings (attributes) are UTF-8 variable-length strings, as h5py writes a Python `str`;
//! `success` is h5py's boolean enum. The bytes are a pure function of the [`ExportSet`].

#[path = "hdf5.rs"]
mod hdf5;

use std::borrow::Cow;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use osms_policy::osw::OMEGA_LEN;
use osms_sim::N_ACTION;
use osms_sim::policy::{DEPLOYABLE_LEN, PRIVILEGED_LEN};
use osms_sim::robot::{ARM_JOINTS, HAND_JOINTS};

use self::hdf5::{Attr, Data, Group};
use crate::{Error, ExportEpisode, ExportOptions, ExportSet};

/// `env_args.env_name`.
pub const ENV_NAME: &str = "osms-catch";

/// The deployable observation's keys and widths, in frame order.
pub const OBS_KEYS: [(&str, usize); 7] = [
    ("arm_qpos", ARM_JOINTS.len()),
    ("arm_qvel", ARM_JOINTS.len()),
    ("hand_qpos", HAND_JOINTS.len()),
    ("hand_qvel", HAND_JOINTS.len()),
    ("object_pos", 3),
    ("palm_touch", 1),
    ("prev_action", N_ACTION),
];

const _: () = {
    let mut sum = 0;
    let mut i = 0;
    while i < OBS_KEYS.len() {
        sum += OBS_KEYS[i].1;
        i += 1;
    }
    assert!(
        sum == DEPLOYABLE_LEN,
        "OBS_KEYS must cover the deployable frame"
    );
};

/// The privileged frame's dataset name, in `obs/` with `--privileged-obs`, else in `osms/`.
pub const PRIVILEGED: &str = "privileged";

/// Where the privileged frame goes under `options`, as a path in a demo group.
pub fn privileged_path(options: ExportOptions) -> String {
    let group = if options.privileged_obs {
        "obs"
    } else {
        "osms"
    };
    format!("{group}/{PRIVILEGED}")
}

/// Writes `set` as one robomimic HDF5 file at `path`. The privileged frame, where the set has
/// it, goes where `options` says ([`privileged_path`]).
pub fn write(set: &ExportSet, path: &Path, options: ExportOptions) -> Result<(), Error> {
    crate::validate(set)?;
    for (i, e) in set.episodes.iter().enumerate() {
        check_episode(i, e)?;
    }
    let env_args = env_args(set, options)?;
    let root = build(set, env_args, options);
    let plan = hdf5::plan(&root)?;
    let file = File::create(path).map_err(|e| Error::io(path, e))?;
    plan.write(BufWriter::with_capacity(1 << 20, file))
        .map_err(|e| Error::io(path, e))
}

/// The name of episode `i`'s group.
pub fn demo_name(i: usize) -> String {
    format!("demo_{i}")
}

/// Whether episode `i` goes to `mask/valid` (else `mask/train`).
pub fn is_valid(i: usize) -> bool {
    i % 10 == 9
}

/// Widths [`crate::validate`] leaves to the writers.
fn check_episode(i: usize, e: &ExportEpisode) -> Result<(), Error> {
    let bad = |what: &str, got: usize, want: usize| Error::Episode {
        episode: i,
        message: format!("{what} has {got} values, expected {want}"),
    };
    let n = e.frames;
    if let Some(a) = &e.intended_action
        && a.len() != n * N_ACTION
    {
        return Err(bad("intended_action", a.len(), n * N_ACTION));
    }
    if let Some(p) = &e.phase
        && p.len() != n
    {
        return Err(bad("phase", p.len(), n));
    }
    if e.omega.len() != OMEGA_LEN {
        return Err(bad("omega", e.omega.len(), OMEGA_LEN));
    }
    if let Some(p) = &e.physics {
        if p.servo_targets.len() != n * N_ACTION {
            return Err(bad("servo_targets", p.servo_targets.len(), n * N_ACTION));
        }
        if p.physics_steps.len() != n {
            return Err(bad("physics_steps", p.physics_steps.len(), n));
        }
    }
    Ok(())
}

#[derive(serde::Serialize)]
struct EnvArgs<'a> {
    env_name: &'static str,
    #[serde(rename = "type")]
    kind: u8,
    env_kwargs: EnvKwargs<'a>,
}

#[derive(serde::Serialize)]
struct EnvKwargs<'a> {
    #[serde(flatten)]
    provenance: &'a crate::Provenance,
    source_kind: &'static str,
    fps: u32,
    timestep_secs: f64,
    substeps: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    state: Option<&'static str>,
    /// The `obs/` keys a deployable policy may read.
    deployable_obs_keys: Vec<&'static str>,
    /// Where the privileged frame is, in each demo group (none: the set did not keep it).
    privileged_obs_key: Option<String>,
    /// Task `i`'s name; each demo's `task_index` attribute points here (the same in every
    /// export).
    tasks: Vec<String>,
    mjcf: Mjcf<'a>,
}

/// The variants' MJCF as a JSON object, in the set's order.
struct Mjcf<'a>(&'a [(String, String)]);

impl serde::Serialize for Mjcf<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(self.0.iter().map(|(k, v)| (k, v)))
    }
}

fn env_args(set: &ExportSet, options: ExportOptions) -> Result<String, Error> {
    for (i, (name, _)) in set.mjcf.iter().enumerate() {
        if set.mjcf[..i].iter().any(|(n, _)| n == name) {
            return Err(Error::Format(format!(
                "the MJCF of variant {name} is given twice"
            )));
        }
    }
    let args = EnvArgs {
        env_name: ENV_NAME,
        kind: 0,
        env_kwargs: EnvKwargs {
            provenance: &set.provenance,
            source_kind: set.source_kind,
            fps: set.fps,
            timestep_secs: set.timestep_secs,
            substeps: set.substeps,
            state: set
                .episodes
                .iter()
                .any(|e| e.physics.is_some())
                .then_some("mjSTATE_FULLPHYSICS"),
            deployable_obs_keys: OBS_KEYS.iter().map(|(k, _)| *k).collect(),
            privileged_obs_key: set
                .episodes
                .iter()
                .any(|e| e.environment_state.is_some())
                .then(|| privileged_path(options)),
            tasks: crate::task_names(),
            mjcf: Mjcf(&set.mjcf),
        },
    };
    serde_json::to_string(&args).map_err(|e| Error::Format(format!("env_args: {e}")))
}

fn build(set: &ExportSet, env_args: String, options: ExportOptions) -> Group<'_> {
    let mut data = Group::new();
    let total: usize = set.episodes.iter().map(|e| e.frames).sum();
    data.attr("total", Attr::I64(total as i64));
    data.attr("env_args", Attr::Str(env_args));
    for (i, e) in set.episodes.iter().enumerate() {
        data.group(&demo_name(i), demo(e, options));
    }
    let (valid, train): (Vec<usize>, Vec<usize>) =
        (0..set.episodes.len()).partition(|&i| is_valid(i));
    let mut mask = Group::new();
    for (name, demos) in [("train", train), ("valid", valid)] {
        let names: Vec<String> = demos.into_iter().map(demo_name).collect();
        mask.dataset(name, &[names.len()], Data::FixedStrings(names));
    }
    let mut root = Group::new();
    root.group("data", data);
    root.group("mask", mask);
    root
}

fn demo(e: &ExportEpisode, options: ExportOptions) -> Group<'_> {
    let n = e.frames;
    let mut g = Group::new();
    g.attr("num_samples", Attr::I64(n as i64));
    g.attr("variant", Attr::Str(e.variant.to_string()));
    g.attr("task_index", Attr::I64(crate::task_index(e.variant) as i64));
    g.attr("success", Attr::Bool(e.success));
    g.attr("source", Attr::Str(e.source.clone()));
    g.attr("max_force_n", Attr::F64(e.max_force_n));
    g.attr("event_step", Attr::I64(e.event_step.map_or(-1, i64::from)));
    if let Some(p) = &e.physics {
        g.attr("mass_kg", Attr::F64(p.mass_kg));
        g.attr("friction_scale", Attr::F64(p.friction_scale));
        g.attr(
            "contact_timeconst_scale",
            Attr::F64(p.contact_timeconst_scale),
        );
        g.attr("gain_scale", Attr::F64(p.gain_scale));
        g.attr("state_size", Attr::I64(p.state_size as i64));
    }

    g.dataset(
        "actions",
        &[n, N_ACTION],
        Data::F32(Cow::Borrowed(&e.action)),
    );
    let mut rewards = vec![0.0f64; n];
    let mut dones = vec![0i64; n];
    if let Some(last) = rewards.last_mut()
        && e.success
    {
        *last = 1.0;
    }
    if let Some(last) = dones.last_mut() {
        *last = 1;
    }
    g.dataset("rewards", &[n], Data::F64(Cow::Owned(rewards)));
    g.dataset("dones", &[n], Data::I64(dones));
    if let Some(p) = &e.physics {
        g.dataset(
            "states",
            &[n, p.state_size],
            Data::F64(Cow::Borrowed(&p.states)),
        );
    }

    // obs and next_obs: the same columns, next_obs one row on.
    for (group, next) in [("obs", false), ("next_obs", true)] {
        let mut obs = Group::new();
        let mut start = 0;
        for (key, width) in OBS_KEYS {
            obs.dataset(
                key,
                &[n, width],
                Data::F32Columns {
                    src: &e.state,
                    row: DEPLOYABLE_LEN,
                    start,
                    width,
                    next,
                },
            );
            start += width;
        }
        if let Some(p) = &e.environment_state
            && options.privileged_obs
        {
            obs.dataset(
                PRIVILEGED,
                &[n, PRIVILEGED_LEN],
                Data::F32Columns {
                    src: p,
                    row: PRIVILEGED_LEN,
                    start: 0,
                    width: PRIVILEGED_LEN,
                    next,
                },
            );
        }
        g.group(group, obs);
    }

    let mut osms = Group::new();
    if let Some(p) = &e.physics {
        osms.dataset(
            "servo_targets",
            &[n, N_ACTION],
            Data::F64(Cow::Borrowed(&p.servo_targets)),
        );
        osms.dataset(
            "physics_steps",
            &[n],
            Data::U8(Cow::Borrowed(&p.physics_steps)),
        );
    }
    if let Some(p) = &e.phase {
        osms.dataset("phase", &[n], Data::U8(Cow::Borrowed(p)));
    }
    if let Some(a) = &e.intended_action {
        osms.dataset(
            "intended_actions",
            &[n, N_ACTION],
            Data::F32(Cow::Borrowed(a)),
        );
    }
    osms.dataset("omega", &[OMEGA_LEN], Data::F32(Cow::Borrowed(&e.omega)));
    if let Some(p) = &e.environment_state
        && !options.privileged_obs
    {
        osms.dataset(
            PRIVILEGED,
            &[n, PRIVILEGED_LEN],
            Data::F32(Cow::Borrowed(p)),
        );
    }
    g.group("osms", osms);
    g
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{EpisodePhysics, Provenance};

    const STATE_SIZE: usize = 7;

    fn episode(i: usize, frames: usize, physics: bool, privileged: bool) -> ExportEpisode {
        let f = |k: usize, salt: usize| (i * 1000 + k * 7 + salt) as f32 * 0.001;
        ExportEpisode {
            variant: ["sphere-small", "box-large", "cylinder-small"][i % 3]
                .parse()
                .expect("a variant"),
            frames,
            state: (0..frames * DEPLOYABLE_LEN).map(|k| f(k, 1)).collect(),
            environment_state: privileged
                .then(|| (0..frames * PRIVILEGED_LEN).map(|k| f(k, 2)).collect()),
            action: (0..frames * N_ACTION).map(|k| f(k, 3) - 0.5).collect(),
            intended_action: physics.then(|| (0..frames * N_ACTION).map(|k| f(k, 4)).collect()),
            phase: physics.then(|| (0..frames).map(|k| (k * 5 / frames.max(1)) as u8).collect()),
            success: i.is_multiple_of(2),
            omega: (0..OMEGA_LEN).map(|k| f(k, 5)).collect(),
            event_step: (i % 3 != 1).then_some(i as u32 + 3),
            max_force_n: 1.5 * i as f64,
            source: format!("item {i} attempt 0 — é"),
            physics: physics.then(|| EpisodePhysics {
                states: (0..frames * STATE_SIZE)
                    .map(|k| (i * 100 + k) as f64 / 3.0)
                    .collect(),
                state_size: STATE_SIZE,
                servo_targets: (0..frames * N_ACTION).map(|k| k as f64 * 0.25).collect(),
                physics_steps: vec![10; frames],
                mass_kg: 0.1 + i as f64,
                friction_scale: 1.1,
                contact_timeconst_scale: 0.9,
                gain_scale: 1.05,
            }),
        }
    }

    fn set(n: usize) -> ExportSet {
        ExportSet {
            provenance: Provenance {
                stage: "d_r".into(),
                kind: "teacher_dataset".into(),
                key: "k".repeat(64),
                content_hash: "c".repeat(64),
                world_key: "w".repeat(64),
                world_content_hash: "h".repeat(64),
                profile: "small".into(),
            },
            source_kind: "rollouts",
            episodes: (0..n)
                .map(|i| episode(i, 3 + i % 5, i % 3 != 2, i % 2 == 0))
                .collect(),
            mjcf: vec![
                ("sphere-small".into(), "<mujoco model=\"a\"/>".into()),
                ("cube".into(), "<mujoco>".to_string() + &"x".repeat(100_000)),
            ],
            timestep_secs: 0.002,
            substeps: 10,
            fps: 50,
        }
    }

    /// A reader of exactly what the writer writes, checking every checksum.
    mod read {
        use std::collections::BTreeMap;

        use super::super::hdf5::lookup3;

        #[derive(Debug)]
        pub enum Obj {
            Group(BTreeMap<String, u64>, BTreeMap<String, Vec<u8>>),
            Dataset {
                shape: Vec<u64>,
                dtype: Vec<u8>,
                raw: Vec<u8>,
            },
        }

        fn u64_at(b: &[u8], at: usize) -> u64 {
            u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
        }

        pub fn root(file: &[u8]) -> u64 {
            assert_eq!(&file[..8], b"\x89HDF\r\n\x1a\n");
            assert_eq!(file[8], 2);
            assert_eq!(
                lookup3(&file[..44]).to_le_bytes(),
                file[44..48],
                "superblock checksum"
            );
            assert_eq!(u64_at(file, 28), file.len() as u64, "end of file address");
            u64_at(file, 36)
        }

        pub fn object(file: &[u8], addr: u64) -> Obj {
            let h = &file[addr as usize..];
            assert_eq!(&h[..4], b"OHDR");
            let width = 1usize << (h[5] & 3);
            let mut size = [0u8; 8];
            size[..width].copy_from_slice(&h[6..6 + width]);
            let end = 6 + width + u64::from_le_bytes(size) as usize;
            assert_eq!(
                lookup3(&h[..end]).to_le_bytes(),
                h[end..end + 4],
                "header checksum"
            );
            let (mut links, mut attrs) = (BTreeMap::new(), BTreeMap::new());
            let (mut shape, mut dtype, mut raw) = (None, None, None);
            let mut at = 6 + width;
            while at < end {
                let kind = h[at];
                let len = u16::from_le_bytes([h[at + 1], h[at + 2]]) as usize;
                let m = &h[at + 4..at + 4 + len];
                match kind {
                    0x01 => {
                        shape = Some((0..m[1] as usize).map(|d| u64_at(m, 4 + 8 * d)).collect())
                    }
                    0x03 => dtype = Some(m.to_vec()),
                    0x06 => {
                        let n = m[2] as usize;
                        let name = String::from_utf8(m[3..3 + n].to_vec()).expect("utf-8");
                        links.insert(name, u64_at(m, 3 + n));
                    }
                    0x08 => {
                        let (a, n) = (u64_at(m, 2), u64_at(m, 10) as usize);
                        raw = Some(if n == 0 {
                            Vec::new()
                        } else {
                            file[a as usize..a as usize + n].to_vec()
                        });
                    }
                    0x0C => {
                        let n = u16::from_le_bytes([m[2], m[3]]) as usize;
                        let name = String::from_utf8(m[9..9 + n - 1].to_vec()).expect("utf-8");
                        attrs.insert(name, m.to_vec());
                    }
                    _ => {}
                }
                at += 4 + len;
            }
            match (shape, dtype, raw) {
                (Some(shape), Some(dtype), Some(raw)) => Obj::Dataset { shape, dtype, raw },
                _ => Obj::Group(links, attrs),
            }
        }

        /// Every path in the file, with its object.
        pub fn walk(file: &[u8]) -> BTreeMap<String, Obj> {
            let mut out = BTreeMap::new();
            let mut todo = vec![(String::new(), root(file))];
            while let Some((path, addr)) = todo.pop() {
                let o = object(file, addr);
                if let Obj::Group(links, _) = &o {
                    for (name, a) in links {
                        todo.push((format!("{path}/{name}"), *a));
                    }
                }
                out.insert(if path.is_empty() { "/".into() } else { path }, o);
            }
            out
        }
    }

    fn f32s(raw: &[u8]) -> Vec<f32> {
        raw.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect()
    }

    #[test]
    fn writes_the_same_bytes_twice() {
        let dir = tempfile::tempdir().expect("tempdir");
        for n in [0, 1, 12] {
            let s = set(n);
            let (a, b) = (dir.path().join("a.hdf5"), dir.path().join("b.hdf5"));
            write(&s, &a, ExportOptions::default()).expect("write a");
            write(&s, &b, ExportOptions::default()).expect("write b");
            let (a, b) = (std::fs::read(a).expect("a"), std::fs::read(b).expect("b"));
            assert_eq!(a, b, "{n} episodes");
        }
    }

    #[test]
    fn lays_out_robomimic_groups_and_datasets() {
        for privileged_obs in [false, true] {
            lays_out(ExportOptions { privileged_obs });
        }
    }

    fn lays_out(options: ExportOptions) {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("set.hdf5");
        let s = set(12);
        write(&s, &path, options).expect("write");
        let file = std::fs::read(&path).expect("read");
        let objects = read::walk(&file);

        let read::Obj::Group(links, attrs) = &objects["/data"] else {
            panic!("data is a group")
        };
        assert_eq!(links.len(), 12);
        assert!(attrs.contains_key("total") && attrs.contains_key("env_args"));
        let total: usize = s.episodes.iter().map(|e| e.frames).sum();
        assert!(attrs["total"].ends_with(&(total as i64).to_le_bytes()));

        for (i, e) in s.episodes.iter().enumerate() {
            let d = format!("/data/demo_{i}");
            let read::Obj::Group(_, attrs) = &objects[&d] else {
                panic!("{d} is a group")
            };
            assert_eq!(attrs.contains_key("state_size"), e.physics.is_some());
            assert!(attrs["num_samples"].ends_with(&(e.frames as i64).to_le_bytes()));
            let read::Obj::Dataset { shape, raw, .. } = &objects[&format!("{d}/actions")] else {
                panic!("actions")
            };
            assert_eq!(shape, &[e.frames as u64, 24]);
            assert_eq!(f32s(raw), e.action);
            assert_eq!(
                objects.contains_key(&format!("{d}/states")),
                e.physics.is_some()
            );
            // The privileged frame is under obs/ only with the flag, else under osms/.
            let has = |path: &str| objects.contains_key(&format!("{d}/{path}"));
            let kept = e.environment_state.is_some();
            assert_eq!(has("obs/privileged"), kept && options.privileged_obs);
            assert_eq!(has("next_obs/privileged"), kept && options.privileged_obs);
            assert_eq!(has("osms/privileged"), kept && !options.privileged_obs);
            assert!(attrs["task_index"].ends_with(&(e.variant.index() as i64).to_le_bytes()));
            // next_obs[t] = obs[t + 1], the last step repeating the last observation.
            for (key, _) in OBS_KEYS.iter().chain(
                options
                    .privileged_obs
                    .then_some(&(PRIVILEGED, 0))
                    .filter(|_| kept),
            ) {
                let rows = |group: &str| -> Vec<Vec<f32>> {
                    let read::Obj::Dataset { shape, raw, .. } =
                        &objects[&format!("{d}/{group}/{key}")]
                    else {
                        panic!("{group}/{key}")
                    };
                    assert_eq!(shape[0], e.frames as u64);
                    f32s(raw)
                        .chunks_exact(shape[1] as usize)
                        .map(<[f32]>::to_vec)
                        .collect()
                };
                let (obs, next) = (rows("obs"), rows("next_obs"));
                let mut want = obs[1..].to_vec();
                want.push(obs[e.frames - 1].clone());
                assert_eq!(next, want, "{d} {key}");
            }
            let read::Obj::Dataset { shape, raw, .. } = &objects[&format!("{d}/obs/object_pos")]
            else {
                panic!("object_pos")
            };
            assert_eq!(shape, &[e.frames as u64, 3]);
            let want: Vec<f32> = e
                .state
                .chunks_exact(DEPLOYABLE_LEN)
                .flat_map(|r| r[48..51].to_vec())
                .collect();
            assert_eq!(f32s(raw), want);
            if let Some(p) = &e.physics {
                let read::Obj::Dataset { shape, raw, .. } = &objects[&format!("{d}/states")] else {
                    panic!("states")
                };
                assert_eq!(shape, &[e.frames as u64, p.state_size as u64]);
                let states: Vec<f64> = raw
                    .chunks_exact(8)
                    .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
                    .collect();
                assert_eq!(states, p.states);
            }
            let read::Obj::Dataset { raw, .. } = &objects[&format!("{d}/dones")] else {
                panic!("dones")
            };
            let mut dones = vec![0u8; 8 * e.frames];
            dones[8 * (e.frames - 1)] = 1;
            assert_eq!(raw, &dones);
        }
        let read::Obj::Dataset { shape, dtype, raw } = &objects["/mask/valid"] else {
            panic!("mask/valid")
        };
        assert_eq!(shape, &[1]);
        assert_eq!(dtype[0], 0x13, "a fixed-length string");
        assert_eq!(raw, b"demo_9");
        let read::Obj::Dataset { shape, .. } = &objects["/mask/train"] else {
            panic!("mask/train")
        };
        assert_eq!(shape, &[11]);
    }

    #[test]
    fn env_args_is_robomimic_metadata() {
        let s = set(2);
        let v: serde_json::Value =
            serde_json::from_str(&env_args(&s, ExportOptions::default()).expect("env_args"))
                .expect("JSON");
        assert_eq!(v["env_name"], "osms-catch");
        assert_eq!(v["type"], 0);
        let k = &v["env_kwargs"];
        assert_eq!(k["stage"], "d_r");
        assert_eq!(k["source_kind"], "rollouts");
        assert_eq!(k["fps"], 50);
        assert_eq!(k["substeps"], 10);
        assert_eq!(k["state"], "mjSTATE_FULLPHYSICS");
        assert_eq!(k["mjcf"]["sphere-small"], "<mujoco model=\"a\"/>");
        assert_eq!(
            k["deployable_obs_keys"],
            serde_json::json!([
                "arm_qpos",
                "arm_qvel",
                "hand_qpos",
                "hand_qvel",
                "object_pos",
                "palm_touch",
                "prev_action"
            ])
        );
        assert_eq!(k["privileged_obs_key"], "osms/privileged");
        assert_eq!(k["tasks"][3], "catch the sphere-small");
        let flagged: serde_json::Value = serde_json::from_str(
            &env_args(
                &s,
                ExportOptions {
                    privileged_obs: true,
                },
            )
            .expect("env_args"),
        )
        .expect("JSON");
        assert_eq!(
            flagged["env_kwargs"]["privileged_obs_key"],
            "obs/privileged"
        );
        let mut demos = set(2);
        demos.mjcf.clear();
        for e in &mut demos.episodes {
            e.physics = None;
        }
        let v: serde_json::Value =
            serde_json::from_str(&env_args(&demos, ExportOptions::default()).expect("env_args"))
                .expect("JSON");
        assert!(v["env_kwargs"].get("state").is_none());
        assert_eq!(v["env_kwargs"]["mjcf"], serde_json::json!({}));
    }

    #[test]
    fn rejects_episodes_of_the_wrong_widths() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("bad.hdf5");
        let mut s = set(3);
        s.episodes[1].phase = Some(vec![0; 1]);
        assert!(matches!(
            write(&s, &path, ExportOptions::default()),
            Err(Error::Episode { episode: 1, .. })
        ));
        let mut s = set(3);
        s.episodes[2].state.pop();
        assert!(matches!(
            write(&s, &path, ExportOptions::default()),
            Err(Error::Episode { episode: 2, .. })
        ));
        let missing = dir.path().join("no/such/dir/x.hdf5");
        assert!(matches!(
            write(&set(1), &missing, ExportOptions::default()),
            Err(Error::Io { .. })
        ));
    }
}
