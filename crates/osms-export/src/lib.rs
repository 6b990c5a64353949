//! Rollout datasets, demonstration sets and evaluations out of the store: LeRobot v3.0
//! (Parquet) and robomimic (HDF5) exports, with MuJoCo physics states from an open-loop replay,
//! and per-rollout evaluation results (CSV, Parquet).
//!
//! A rollout dataset (D_M, D_E, D_R) or a demonstration set (D_*, Naive, Normal) becomes an
//! [`ExportSet`], one neutral table of episodes, which the [`lerobot`] and [`robomimic`] writers
//! lay out in their formats (docs/export.md). An evaluation becomes one row per rollout
//! ([`rollouts`]), written by the small nullable-column [`table`] writer.
//!
//! Every export is a pure function of the artifact: the same artifact gives the same bytes.

pub mod lerobot;
mod parquet_file;
pub mod robomimic;
pub mod rollouts;
pub mod table;

use std::path::{Path, PathBuf};

use osms_policy::artifacts::Dataset;
use osms_policy::artifacts::DemoSet;
use osms_policy::osw::omega_features;
use osms_sim::episode::RolloutSpec;
use osms_sim::policy::{DEPLOYABLE_LEN, PRIVILEGED_LEN};
use osms_sim::replay::{self, ReplayReport};
use osms_sim::robot::{ARM_JOINTS, HAND_JOINTS};
use osms_sim::{N_ACTION, ObjectVariant, RolloutRecord, World};

/// What an export failed on.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("episode {episode}: {message}")]
    Episode { episode: usize, message: String },
    #[error("{0}")]
    Format(String),
    /// The robomimic file's HDF5 structure cannot be written (a name or a string HDF5 cannot
    /// hold).
    #[error("{0}")]
    Hdf5(String),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Error::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// Where the exported artifact came from, for the files' metadata.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Provenance {
    /// The stage instance (`d_r`, `student_ours@1`, ...).
    pub stage: String,
    /// Its kind (`teacher_dataset`, `dstar`, ...).
    pub kind: String,
    pub key: String,
    pub content_hash: String,
    /// The `world` stage's key and content hash.
    pub world_key: String,
    pub world_content_hash: String,
    pub profile: String,
}

/// What an export writes beyond what a deployable policy may read.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ExportOptions {
    /// Put the privileged frame among the policy inputs (LeRobot's
    /// `observation.environment_state`, robomimic's `obs/privileged`). Off by default: there
    /// a library's default input features would feed a student the true object state, mass
    /// and contact force, which no deployed policy has; the frame goes under osms's own keys
    /// (`osms.privileged`, `osms/privileged`) instead.
    pub privileged_obs: bool,
}

/// Every variant's task, in one fixed order: task index `i` is `ObjectVariant::all()[i]`'s,
/// the same in every export of every dataset, so exports merge without remapping.
pub fn task_names() -> Vec<String> {
    ObjectVariant::all().into_iter().map(task_name).collect()
}

/// A variant's task index (see [`task_names`]).
pub fn task_index(variant: ObjectVariant) -> usize {
    variant.index()
}

/// An episode's task: one per object variant.
pub fn task_name(variant: ObjectVariant) -> String {
    format!("catch the {variant}")
}

/// One exported episode: per-frame arrays flattened frame-major.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportEpisode {
    /// The object variant (LeRobot's task: "catch the sphere-small").
    pub variant: ObjectVariant,
    pub frames: usize,
    /// Deployable observation ([`STATE_NAMES`]), per frame.
    pub state: Vec<f32>,
    /// Privileged observation ([`ENVIRONMENT_STATE_NAMES`]), per frame, if the set kept it.
    pub environment_state: Option<Vec<f32>>,
    /// The action label, 24 per frame, in [-1, 1]: the executed action for rollout datasets,
    /// the commanded one for demonstration sets (what students train on).
    pub action: Vec<f32>,
    /// The commanded (intended) action, for rollout datasets.
    pub intended_action: Option<Vec<f32>>,
    /// Phase per frame (`Phase as u8`: approach 0, velocity matching 1, contact 2, follow
    /// through 3, grasping 4), for rollout datasets.
    pub phase: Option<Vec<u8>>,
    pub success: bool,
    /// ω's features (`osms_policy::osw::OMEGA_LEN`).
    pub omega: Vec<f32>,
    /// k_e: the event step (first contact, or closest approach), if known.
    pub event_step: Option<u32>,
    /// f_max (N).
    pub max_force_n: f64,
    /// Where the episode came from in the artifact (dataset item, or demo group and entry).
    pub source: String,
    /// What open-loop replay needs, for rollout datasets.
    pub physics: Option<EpisodePhysics>,
}

/// The MuJoCo side of a rollout: its per-step full physical states (from a replay that
/// reproduced the record bit for bit) and the controls that replay applied.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodePhysics {
    /// `mjSTATE_FULLPHYSICS` at each frame's start, `state_size` per frame.
    pub states: Vec<f64>,
    pub state_size: usize,
    /// Servo targets per frame (24), full precision.
    pub servo_targets: Vec<f64>,
    /// Physics steps per frame.
    pub physics_steps: Vec<u8>,
    /// The per-episode model edits and servo gain (docs/export.md, "Replay outside osms").
    pub mass_kg: f64,
    pub friction_scale: f64,
    pub contact_timeconst_scale: f64,
    pub gain_scale: f64,
}

/// A whole export: episodes plus what every format states once.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportSet {
    pub provenance: Provenance,
    /// `rollouts` (D_M, D_E, D_R) or `demonstrations` (D_*, Naive, Normal).
    pub source_kind: &'static str,
    pub episodes: Vec<ExportEpisode>,
    /// The world's MJCF per variant name, for replay outside osms (rollout datasets).
    pub mjcf: Vec<(String, String)>,
    /// Physics timestep (s) and physics steps per control step.
    pub timestep_secs: f64,
    pub substeps: u32,
    /// The control rate (Hz), 1 / (timestep · substeps): 50 with the world's defaults.
    pub fps: u32,
}

/// The world's control rate as whole frames per second, which both formats need.
pub fn control_fps(world: &World) -> Result<u32, Error> {
    let rate = 1.0 / (world.spec.timestep_secs * f64::from(world.spec.substeps));
    let fps = rate.round();
    if (rate - fps).abs() > 1e-6 * rate || fps < 1.0 {
        return Err(Error::Format(format!(
            "the world's control rate 1 / (timestep_secs {} × substeps {}) = {rate} Hz is not a whole number of frames per second, which LeRobot's fps needs; choose world params whose control period divides one second",
            world.spec.timestep_secs, world.spec.substeps
        )));
    }
    Ok(fps as u32)
}

/// The robot part both observations start with: arm q, arm q̇, hand q, hand q̇.
fn push_robot_names(n: &mut Vec<String>) {
    n.extend(ARM_JOINTS.iter().map(|j| format!("{j}.pos")));
    n.extend(ARM_JOINTS.iter().map(|j| format!("{j}.vel")));
    n.extend(HAND_JOINTS.iter().map(|j| format!("{j}.pos")));
    n.extend(HAND_JOINTS.iter().map(|j| format!("{j}.vel")));
}

/// Names of the deployable observation's channels ([`DEPLOYABLE_LEN`]).
pub fn state_names() -> Vec<String> {
    let mut n = Vec::with_capacity(DEPLOYABLE_LEN);
    push_robot_names(&mut n);
    n.extend(["object.x", "object.y", "object.z"].map(String::from));
    n.push("palm.touch".into());
    n.extend(
        action_names()
            .into_iter()
            .map(|a| format!("prev_action.{a}")),
    );
    n
}

/// Names of the privileged observation's channels ([`PRIVILEGED_LEN`]).
pub fn environment_state_names() -> Vec<String> {
    let mut n = Vec::with_capacity(PRIVILEGED_LEN);
    push_robot_names(&mut n);
    for (what, axes) in [
        ("object.pos", &["x", "y", "z"][..]),
        ("object.quat", &["w", "x", "y", "z"][..]),
        ("object.linvel", &["x", "y", "z"][..]),
        ("object.angvel", &["x", "y", "z"][..]),
        ("palm.pos", &["x", "y", "z"][..]),
        ("palm.normal", &["x", "y", "z"][..]),
        ("palm.vel", &["x", "y", "z"][..]),
    ] {
        n.extend(axes.iter().map(|a| format!("{what}.{a}")));
    }
    n.push("contact.admissible_force".into());
    n.push("contact.admissible_count".into());
    n.push("object.mass".into());
    n.extend(
        osms_sim::ObjectVariant::all()
            .iter()
            .map(|v| format!("variant.{v}")),
    );
    n.push("time".into());
    n
}

/// Names of the 24 action channels: 7 arm target increments, 17 hand targets.
pub fn action_names() -> Vec<String> {
    ARM_JOINTS
        .iter()
        .chain(HAND_JOINTS.iter())
        .map(|j| j.to_string())
        .collect()
}

/// A rollout dataset as an export, each episode replayed to recover its physical states
/// (episodes in parallel on the current rayon pool, results in item order). A replay that
/// does not reproduce its record bit for bit fails the export: the states would not be the
/// rollout's. `progress` is called with the number of episodes done.
pub fn from_dataset(
    provenance: Provenance,
    dataset: &Dataset,
    world: &World,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<ExportSet, Error> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    let spec = &dataset.task.rollout;
    let done = AtomicUsize::new(0);
    let episodes = dataset
        .items
        .par_iter()
        .enumerate()
        .map(|(i, item)| {
            let r = &item.rollout;
            let source = format!("item {} attempt {}", r.item, r.attempt);
            let episode = rollout_episode(world, spec, &r.record, source, i);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1);
            episode
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(ExportSet {
        provenance,
        source_kind: "rollouts",
        episodes,
        mjcf: osms_sim::ObjectVariant::all()
            .into_iter()
            .map(|v| (v.to_string(), world.xml(v).to_string()))
            .collect(),
        timestep_secs: world.spec.timestep_secs,
        substeps: world.spec.substeps,
        fps: control_fps(world)?,
    })
}

/// One rollout record as an episode, with its states from a bit-exact replay.
pub fn rollout_episode(
    world: &World,
    spec: &RolloutSpec,
    record: &RolloutRecord,
    source: String,
    index: usize,
) -> Result<ExportEpisode, Error> {
    let (states, report) = replay::states(world, spec, record).map_err(|e| Error::Episode {
        episode: index,
        message: e.to_string(),
    })?;
    check_replay(index, &report)?;
    let state_size = states.first().map_or(0, Vec::len);
    Ok(ExportEpisode {
        variant: record.condition.variant,
        frames: record.steps,
        state: record.deployable.clone(),
        environment_state: (!record.privileged.is_empty()).then(|| record.privileged.clone()),
        action: record.executed.clone(),
        intended_action: Some(record.intended.clone()),
        phase: Some(record.phase.clone()),
        success: record.outcome.success(),
        omega: omega_features(&record.condition),
        event_step: u32::try_from(record.metrics.event_step).ok(),
        max_force_n: record.metrics.max_force_n,
        source,
        physics: Some(EpisodePhysics {
            states: states.concat(),
            state_size,
            servo_targets: record.servo_targets.clone(),
            physics_steps: record.physics_steps.clone(),
            mass_kg: record.condition.mass_kg,
            friction_scale: record.dr.friction_scale,
            contact_timeconst_scale: record.dr.contact_timeconst_scale,
            gain_scale: record.dr.gain_scale,
        }),
    })
}

fn check_replay(index: usize, report: &ReplayReport) -> Result<(), Error> {
    if report.bit_exact {
        return Ok(());
    }
    let worst: Vec<String> = report
        .deviations
        .iter()
        .filter(|d| d.differing > 0)
        .map(|d| {
            format!(
                "{} ({} values, max |Δ| {:.3e})",
                d.field, d.differing, d.max_abs
            )
        })
        .collect();
    Err(Error::Episode {
        episode: index,
        message: format!(
            "the open-loop replay does not reproduce the record ({}); its physics states would not be the rollout's",
            if worst.is_empty() {
                "metrics or outcome differ".to_string()
            } else {
                worst.join(", ")
            }
        ),
    })
}

/// A demonstration set as an export: the student representation (deployable frames and
/// commanded labels), no physics (the set keeps no simulator state).
pub fn from_demo_set(
    provenance: Provenance,
    set: &DemoSet,
    world: &World,
) -> Result<ExportSet, Error> {
    let mut episodes = Vec::new();
    for (g, group) in set.used_groups().iter().enumerate() {
        for (e, entry) in group.demos.iter().enumerate() {
            let demo = &entry.demo;
            episodes.push(ExportEpisode {
                variant: group.condition.variant,
                frames: demo.steps,
                state: demo.deployable.clone(),
                environment_state: None,
                action: demo.actions.clone(),
                intended_action: None,
                phase: None,
                success: true,
                omega: omega_features(&group.condition),
                event_step: None,
                max_force_n: entry.max_force_n,
                source: format!(
                    "group {g} ({} item {} attempt {}, {}) demo {e} ({})",
                    if group.extension { "extension" } else { "data" },
                    group.item,
                    group.attempt,
                    group.origin.name(),
                    execution_name(entry.execution)
                ),
                physics: None,
            });
        }
    }
    Ok(ExportSet {
        provenance,
        source_kind: "demonstrations",
        episodes,
        mjcf: Vec::new(),
        timestep_secs: world.spec.timestep_secs,
        substeps: world.spec.substeps,
        fps: control_fps(world)?,
    })
}

fn execution_name(e: osms_policy::artifacts::Execution) -> String {
    use osms_policy::artifacts::Execution;
    match e {
        Execution::Original => "original".into(),
        Execution::Unperturbed => "unperturbed".into(),
        Execution::Perturbed { q } => format!("perturbed q={q}"),
        Execution::StudentVisited => "student visited".into(),
        Execution::Dart => "dart".into(),
    }
}

/// Checks the per-frame widths of every episode, so a writer can index without checks.
pub fn validate(set: &ExportSet) -> Result<(), Error> {
    for (i, e) in set.episodes.iter().enumerate() {
        let bad = |what: &str, got: usize, want: usize| Error::Episode {
            episode: i,
            message: format!("{what} has {got} values, expected {want}"),
        };
        if e.state.len() != e.frames * DEPLOYABLE_LEN {
            return Err(bad("state", e.state.len(), e.frames * DEPLOYABLE_LEN));
        }
        if e.action.len() != e.frames * N_ACTION {
            return Err(bad("action", e.action.len(), e.frames * N_ACTION));
        }
        if let Some(p) = &e.environment_state
            && p.len() != e.frames * PRIVILEGED_LEN
        {
            return Err(bad("environment_state", p.len(), e.frames * PRIVILEGED_LEN));
        }
        if let Some(p) = &e.physics
            && p.states.len() != e.frames * p.state_size
        {
            return Err(bad("states", p.states.len(), e.frames * p.state_size));
        }
    }
    Ok(())
}
