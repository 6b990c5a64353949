//! Open-loop replay of a record: the rollout's model and initial state from ω and its DR draws,
//! then each control step's recorded servo targets for its recorded number of physics steps.
//! No policy, no hooks and no random stream take part, so a replay that reproduces a record
//! proves the record describes what the simulator did with those controls.

use mujoco_rs::mujoco_c::mjtState;
use mujoco_rs::prelude::*;
use osms_core::rng;
use serde::Serialize;

use crate::episode::{Episode, RolloutRecord, RolloutSpec};
use crate::metrics::Metrics;
use crate::policy::DEPLOYABLE_LEN;
use crate::world::World;

/// MuJoCo's full physical state (`mjSTATE_FULLPHYSICS`: time, qpos, qvel, act, history,
/// mocap poses, userdata, plugin state): what the robomimic export stores per step.
pub const FULL_PHYSICS: u32 = mjtState::mjSTATE_FULLPHYSICS as u32;

/// How far one recorded per-step array is from its replay.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Deviation {
    pub field: &'static str,
    /// Values compared (0 when the record kept none, e.g. privileged frames).
    pub values: usize,
    /// Values whose bits differ.
    pub differing: usize,
    /// Largest absolute difference.
    pub max_abs: f64,
}

/// What a replay found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReplayReport {
    pub steps: usize,
    pub replayed_steps: usize,
    /// Every physics-derived per-step array of the record, in record order.
    pub deviations: Vec<Deviation>,
    pub recorded: Metrics,
    pub replayed: Metrics,
    pub recorded_success: bool,
    pub replayed_success: bool,
    /// Whether every compared value, the metrics and the outcome are identical bits.
    pub bit_exact: bool,
}

impl ReplayReport {
    pub fn max_abs(&self) -> f64 {
        self.deviations
            .iter()
            .map(|d| d.max_abs)
            .fold(0.0, f64::max)
    }
}

/// Why a record cannot be replayed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ReplayError {
    #[error("the record's {field} hold {got} values for {steps} steps, expected {want}")]
    Malformed {
        field: &'static str,
        steps: usize,
        got: usize,
        want: usize,
    },
    #[error(
        "the record has no servo targets for replay ({targets} values, {physics} physics-step counts for {steps} steps); it was made before records kept them"
    )]
    NoControls {
        steps: usize,
        targets: usize,
        physics: usize,
    },
}

/// Replays `record` under `spec` (the spec it ran under: its success rule and whether it kept
/// privileged frames). `at_start(k, data)` sees the simulator at the start of control step k,
/// kinematics current, before its controls apply.
pub fn replay(
    world: &World,
    spec: &RolloutSpec,
    record: &RolloutRecord,
    at_start: &mut dyn FnMut(usize, &MjData<Box<MjModel>>),
) -> Result<(RolloutRecord, ReplayReport), ReplayError> {
    use crate::control::N_ACTION;
    if record.servo_targets.len() != record.steps * N_ACTION
        || record.physics_steps.len() != record.steps
    {
        return Err(ReplayError::NoControls {
            steps: record.steps,
            targets: record.servo_targets.len(),
            physics: record.physics_steps.len(),
        });
    }
    for (field, got, width) in [
        ("intended actions", record.intended.len(), N_ACTION),
        ("executed actions", record.executed.len(), N_ACTION),
        ("deployable frames", record.deployable.len(), DEPLOYABLE_LEN),
    ] {
        if got != record.steps * width {
            return Err(ReplayError::Malformed {
                field,
                steps: record.steps,
                got,
                want: record.steps * width,
            });
        }
    }
    // The stream is never read: replay draws no noise and takes the DR draws from the record.
    let unused = rng::stream(0, "replay", "unused", 0);
    let mut episode = Episode::with_draw(
        world,
        spec,
        record.condition.clone(),
        record.dr.clone(),
        unused,
    );
    for k in 0..record.steps {
        if !episode.replay_step(record, k, at_start) {
            break;
        }
    }
    let replayed = episode.finish();
    let report = compare(record, &replayed);
    Ok((replayed, report))
}

/// Every control step's full physical state at its start ([`FULL_PHYSICS`]), by replay.
pub fn states(
    world: &World,
    spec: &RolloutSpec,
    record: &RolloutRecord,
) -> Result<(Vec<Vec<f64>>, ReplayReport), ReplayError> {
    let mut states = Vec::with_capacity(record.steps);
    let (_, report) = replay(world, spec, record, &mut |_, data| {
        states.push(data.state(FULL_PHYSICS).into_vec());
    })?;
    Ok((states, report))
}

fn deviation<T: Copy + Into<f64> + PartialEq>(
    field: &'static str,
    recorded: &[T],
    replayed: &[T],
    bits: impl Fn(T) -> u64,
) -> Deviation {
    let n = recorded.len().min(replayed.len());
    let mut d = Deviation {
        field,
        values: recorded.len().max(replayed.len()),
        differing: recorded.len().abs_diff(replayed.len()),
        max_abs: if recorded.len() == replayed.len() {
            0.0
        } else {
            f64::INFINITY
        },
    };
    for (a, b) in recorded[..n].iter().zip(&replayed[..n]) {
        if bits(*a) != bits(*b) {
            d.differing += 1;
            let diff = ((*a).into() - (*b).into()).abs();
            d.max_abs = d
                .max_abs
                .max(if diff.is_nan() { f64::INFINITY } else { diff });
        }
    }
    d
}

fn compare(recorded: &RolloutRecord, replayed: &RolloutRecord) -> ReplayReport {
    let f32s =
        |field, a: &[f32], b: &[f32]| deviation(field, a, b, |x: f32| u64::from(x.to_bits()));
    // The deployable frame's physics part: robot q and q̇ (48 values) of every frame.
    let robot = |r: &RolloutRecord| -> Vec<f32> {
        r.deployable
            .chunks(DEPLOYABLE_LEN)
            .flat_map(|f| f[..48].iter().copied())
            .collect()
    };
    let deviations = vec![
        f32s("robot_state", &robot(recorded), &robot(replayed)),
        f32s("privileged", &recorded.privileged, &replayed.privileged),
        f32s("arm_targets", &recorded.arm_targets, &replayed.arm_targets),
        f32s("palm_pos", &recorded.palm_pos, &replayed.palm_pos),
        f32s("palm_vel", &recorded.palm_vel, &replayed.palm_vel),
        f32s("object_pos", &recorded.object_pos, &replayed.object_pos),
        f32s("object_vel", &recorded.object_vel, &replayed.object_vel),
        f32s(
            "normal_force",
            &recorded.normal_force,
            &replayed.normal_force,
        ),
        deviation("phase", &recorded.phase, &replayed.phase, u64::from),
        deviation(
            "servo_targets",
            &recorded.servo_targets,
            &replayed.servo_targets,
            f64::to_bits,
        ),
        deviation(
            "physics_steps",
            &recorded.physics_steps,
            &replayed.physics_steps,
            u64::from,
        ),
    ];
    let bit_exact = deviations.iter().all(|d| d.differing == 0)
        && recorded.metrics == replayed.metrics
        && recorded.outcome == replayed.outcome
        && recorded.steps == replayed.steps;
    ReplayReport {
        steps: recorded.steps,
        replayed_steps: replayed.steps,
        deviations,
        recorded: recorded.metrics.clone(),
        replayed: replayed.metrics.clone(),
        recorded_success: recorded.outcome.success(),
        replayed_success: replayed.outcome.success(),
        bit_exact,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::{Action, DrSpec, N_ARM, hold_action};
    use crate::policy::{NoHooks, Policy, PolicyView};
    use crate::{ConditionSpec, WorldSpec, conditions};
    use osms_core::rng;

    /// Moves the arm with a different increment every step, so the controls vary.
    struct Sweep(Action);
    impl Policy for Sweep {
        fn act(&mut self, view: &PolicyView<'_>) -> Action {
            let mut a = self.0;
            for (i, c) in a[..N_ARM].iter_mut().enumerate() {
                *c = 0.3 * ((view.step as f64 * 0.37 + i as f64).sin());
            }
            a
        }
    }

    fn setup(index: u64) -> (World, RolloutSpec, crate::TaskCondition) {
        let world = World::new(WorldSpec::default()).expect("world");
        let mut dr = DrSpec::paper();
        // Every source of randomness on, jitter often, so the replay must take the recorded
        // physics-step counts and the noisy executed actions rather than redraw them.
        dr.timing_jitter_prob = 0.3;
        let spec = RolloutSpec {
            dr,
            record_privileged: true,
            ..RolloutSpec::default()
        };
        let condition = conditions::sample(
            &ConditionSpec::default(),
            world.home_palm_pos,
            &mut rng::stream(0, "test", "omega", index),
        )
        .expect("ω");
        (world, spec, condition)
    }

    #[test]
    fn a_record_replays_bit_for_bit_and_a_changed_control_shows() {
        let (world, spec, condition) = setup(11);
        let mut policy = Sweep(hold_action(&world.spec.hand_home_rad));
        let record = Episode::new(&world, &spec, condition, rng::stream(0, "test", "roll", 11))
            .run(&mut policy, &mut NoHooks);
        assert!(record.steps > 10);
        assert!(
            record.physics_steps.iter().any(|&n| n != 10),
            "timing jitter should show in the counts: {:?}",
            record.physics_steps
        );
        let mut seen = Vec::new();
        let (replayed, report) =
            replay(&world, &spec, &record, &mut |k, _| seen.push(k)).expect("replay");
        assert!(report.bit_exact, "{report:#?}");
        assert_eq!(report.max_abs(), 0.0);
        assert_eq!(seen, (0..record.steps).collect::<Vec<_>>());
        // Everything but the deployable frames' noisy object positions, which the replay
        // copies, is recomputed; with them copied the records are equal.
        assert_eq!(replayed, record);

        let mut nudged = record.clone();
        nudged.servo_targets[3 * crate::N_ACTION] += 1e-3;
        let (_, report) = replay(&world, &spec, &nudged, &mut |_, _| {}).expect("replay");
        assert!(!report.bit_exact);
        let robot = &report.deviations[0];
        assert_eq!(robot.field, "robot_state");
        assert!(robot.differing > 0 && robot.max_abs > 0.0, "{robot:?}");
    }

    #[test]
    fn a_branched_record_replays_from_the_start() {
        let (world, spec, condition) = setup(12);
        let mut policy = Sweep(hold_action(&world.spec.hand_home_rad));
        let mut ep = Episode::new(&world, &spec, condition, rng::stream(0, "test", "roll", 12));
        for _ in 0..6 {
            ep.step(&mut policy, &mut NoHooks);
        }
        let snap = ep.snapshot();
        ep.step(&mut policy, &mut NoHooks);
        ep.restore(&snap);
        let mut other = Sweep(hold_action(&world.spec.hand_home_rad));
        other.0[0] = 0.5;
        let record = ep.run(&mut other, &mut NoHooks);
        let (_, report) = replay(&world, &spec, &record, &mut |_, _| {}).expect("replay");
        assert!(report.bit_exact, "{report:#?}");
        let (states, _) = states(&world, &spec, &record).expect("states");
        assert_eq!(states.len(), record.steps);
        assert!(states.iter().all(|s| s.len() == states[0].len()));
    }

    #[test]
    fn a_record_without_controls_is_refused() {
        let (world, spec, condition) = setup(13);
        let mut policy = Sweep(hold_action(&world.spec.hand_home_rad));
        let mut record = Episode::new(&world, &spec, condition, rng::stream(0, "test", "roll", 13))
            .run(&mut policy, &mut NoHooks);
        record.servo_targets.clear();
        let err = replay(&world, &spec, &record, &mut |_, _| {}).expect_err("no controls");
        assert!(matches!(err, ReplayError::NoControls { .. }), "{err}");
    }
}
