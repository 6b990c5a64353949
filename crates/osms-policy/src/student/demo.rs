//! Demonstrations and the features a student reads: a demo's frames and state, the current
//! step's features (the same from a demonstration's state and from a running rollout), and the
//! action normalisation.

use osms_sim::control::{ArmAction, ControlSpec, targets};
use osms_sim::flight::track_with;
use osms_sim::policy::{DEPLOYABLE_LEN, OBSERVED_OBJECT};
use osms_sim::{Action, N_ACTION, N_ARM, RolloutRecord};
use serde::{Deserialize, Serialize};

use super::params::StudentParams;
use crate::{Error, Result, RunningNorm};

/// The arm's largest target step per control step (rad) under the default control spec:
/// the scale between an arm action and its target increment, for `target_labels`.
pub const ARM_STEP_RAD: f64 = osms_sim::control::ARM_MAX_DELTA_RAD;

/// Values per step of [`Demo::state`].
pub const DEMO_STATE_LEN: usize = 9 + N_ARM;

/// One demonstration rollout as students read it: its deployable frames, the palm and object
/// state the optional features come from, and its action labels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Demo {
    pub steps: usize,
    /// [`DEPLOYABLE_LEN`] per step.
    pub deployable: Vec<f32>,
    /// [`DEMO_STATE_LEN`] per step, at the step's start: the palm's position and linear
    /// velocity, the object's true linear velocity, the arm's servo targets (the record's
    /// `palm_pos`, `palm_vel`, `object_vel`, `arm_targets`).
    pub state: Vec<f32>,
    /// The phase each step ended in (`Phase as u8`, the record's).
    pub phase: Vec<u8>,
    /// 24 per step: the action the demonstrating policy commanded at that step.
    pub actions: Vec<f32>,
}

impl Demo {
    /// A teacher rollout as a demonstration: its deployable frames and, as labels, its
    /// commanded actions (`record.intended`: the full 24-channel action the policy sent, before
    /// the environment's actuation noise and delay, which the student cannot command).
    pub fn from_record(record: &RolloutRecord) -> Demo {
        Demo::labelled(record, record.intended.clone())
    }

    /// A rollout's frames and state labelled with `actions` (24 per step).
    pub fn labelled(record: &RolloutRecord, actions: Vec<f32>) -> Demo {
        let state = (0..record.steps)
            .flat_map(|n| {
                let at = |v: &[f32]| {
                    let row: [f32; 3] = v[3 * n..3 * n + 3].try_into().expect("3 per step");
                    row
                };
                [
                    &at(&record.palm_pos)[..],
                    &at(&record.palm_vel),
                    &at(&record.object_vel),
                    &record.arm_targets[N_ARM * n..N_ARM * (n + 1)],
                ]
                .concat()
            })
            .collect();
        Demo {
            steps: record.steps,
            deployable: record.deployable.clone(),
            state,
            phase: record.phase.clone(),
            actions,
        }
    }

    /// The demonstration with its arm labels as the absolute servo target after each step:
    /// clamp(target at the step's start + [`ARM_STEP_RAD`] · increment) to the joint's range,
    /// as the controller integrates it (`osms_sim::control::targets`).
    pub fn with_target_labels(&self) -> Demo {
        let control = ControlSpec::default();
        let mut actions = self.actions.clone();
        for (n, row) in actions.chunks_exact_mut(N_ACTION).enumerate() {
            let start = &self.state[n * DEMO_STATE_LEN + 9..][..N_ARM];
            // Only the arm's targets are integrated; the hand channels are left as they are.
            let previous: [f64; N_ACTION] =
                std::array::from_fn(|i| start.get(i).map_or(0.0, |t| f64::from(*t)));
            let action: Action = std::array::from_fn(|i| f64::from(row[i]));
            let next = targets(&control, ArmAction::Increment, &previous, &action);
            for (a, t) in row[..N_ARM].iter_mut().zip(next) {
                *a = t as f32;
            }
        }
        Demo {
            actions,
            ..self.clone()
        }
    }

    pub(super) fn check(&self, index: usize) -> Result<()> {
        if self.deployable.len() != self.steps * DEPLOYABLE_LEN
            || self.state.len() != self.steps * DEMO_STATE_LEN
            || self.phase.len() != self.steps
            || self.phase.iter().any(|&p| usize::from(p) >= 5)
            || self.actions.len() != self.steps * N_ACTION
        {
            return Err(Error::Demo {
                index,
                why: format!(
                    "a demonstration of {} steps has {} deployable, {} state, {} phase and {} action values (expected {}, {}, {} phases below 5 and {})",
                    self.steps,
                    self.deployable.len(),
                    self.state.len(),
                    self.phase.len(),
                    self.actions.len(),
                    self.steps * DEPLOYABLE_LEN,
                    self.steps * DEMO_STATE_LEN,
                    self.steps,
                    self.steps * N_ACTION
                ),
            });
        }
        Ok(())
    }

    /// o_n: frames n − history + 1 … n, the oldest frame repeated before the rollout's start,
    /// then step n's features.
    pub fn observation(&self, n: usize, p: &StudentParams, out: &mut Vec<f32>) {
        let width = p.frame_len();
        let start = out.len();
        for h in 0..p.history {
            let k = (n + h + 1).saturating_sub(p.history);
            out.extend_from_slice(&self.deployable[k * DEPLOYABLE_LEN..k * DEPLOYABLE_LEN + width]);
        }
        let state = &self.state[n * DEMO_STATE_LEN..(n + 1) * DEMO_STATE_LEN];
        let object = &self.deployable[n * DEPLOYABLE_LEN + OBSERVED_OBJECT..][..3];
        let tracked = if p.tracked_object {
            let seen = |j: usize| {
                let at = j * DEPLOYABLE_LEN + OBSERVED_OBJECT;
                std::array::from_fn(|c| f64::from(self.deployable[at + c]))
            };
            tracked_features(track_with(n + 1, seen, NOMINAL_CONTROL_PERIOD_SECS))
        } else {
            [0.0; 6]
        };
        let now = Current {
            palm_pos: &state[0..3],
            palm_vel: &state[3..6],
            object,
            object_vel: &state[6..9],
            arm_targets: &state[9..9 + N_ARM],
            tracked: &tracked,
        };
        push_features(p, start, &now, out);
    }

    /// The label chunk at step n and its mask: steps past the end repeat the last action with
    /// mask 0.
    pub fn chunk(&self, n: usize, chunk: usize, labels: &mut Vec<f32>, mask: &mut Vec<f32>) {
        for j in 0..chunk {
            let k = (n + j).min(self.steps - 1);
            labels.extend_from_slice(&self.actions[k * N_ACTION..(k + 1) * N_ACTION]);
            let m = if n + j < self.steps { 1.0 } else { 0.0 };
            mask.extend(std::iter::repeat_n(m, N_ACTION));
        }
    }
}

/// Per-channel standardisation of actions: (a − mean) / std.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ActionNorm {
    pub mean: Vec<f32>,
    /// Floored at [`ActionNorm::MIN_STD`]: a channel the demonstrations barely move must not
    /// turn sampling noise into large actions.
    pub std: Vec<f32>,
}

impl ActionNorm {
    pub const MIN_STD: f64 = 0.01;

    pub(super) fn fit(demos: &[&Demo]) -> ActionNorm {
        let mut stats = RunningNorm::new(N_ACTION, f32::INFINITY);
        for d in demos {
            stats.update(&d.actions);
        }
        ActionNorm {
            mean: stats.mean.iter().map(|&m| m as f32).collect(),
            std: stats
                .var
                .iter()
                .map(|&v| v.sqrt().max(Self::MIN_STD) as f32)
                .collect(),
        }
    }
}

/// What the current step's features are computed from, as training (from a demonstration's
/// state) and acting (from the running rollout) both have it.
pub(super) struct Current<'a> {
    pub(super) palm_pos: &'a [f32],
    pub(super) palm_vel: &'a [f32],
    /// The observed object position.
    pub(super) object: &'a [f32],
    /// The object's true velocity (the oracle diagnostic only).
    pub(super) object_vel: &'a [f32],
    pub(super) arm_targets: &'a [f32],
    /// The flight estimate's position and velocity.
    pub(super) tracked: &'a [f32; 6],
}

/// The control period the students' flight-estimate input assumes: the default world's
/// (10 physics steps of 2 ms), in training and acting alike, so the two agree whatever world a
/// rollout runs in.
pub const NOMINAL_CONTROL_PERIOD_SECS: f64 = 0.02;

pub(super) fn tracked_features(o: osms_sim::episode::ObservedObject) -> [f32; 6] {
    std::array::from_fn(|i| if i < 3 { o.pos[i] } else { o.vel[i - 3] } as f32)
}

/// The current step's features (see the module's doc), in the order training and acting share.
/// The history's frames are already in `out`, from index `frames`.
pub(super) fn push_features(
    p: &StudentParams,
    frames: usize,
    now: &Current<'_>,
    out: &mut Vec<f32>,
) {
    let Current {
        palm_pos,
        palm_vel,
        object,
        object_vel,
        arm_targets,
        tracked,
    } = *now;
    if p.palm {
        out.extend_from_slice(&palm_pos[..3]);
        out.extend_from_slice(&palm_vel[..3]);
        out.extend((0..3).map(|c| object[c] - palm_pos[c]));
    }
    if p.object_differences {
        let w = p.frame_len();
        for h in 1..p.history {
            let at = |k: usize, c: usize| out[frames + k * w + OBSERVED_OBJECT + c];
            let change: [f32; 3] = std::array::from_fn(|c| at(h, c) - at(h - 1, c));
            out.extend(change);
        }
    }
    if p.oracle_object_velocity {
        out.extend_from_slice(&object_vel[..3]);
    }
    if p.arm_target {
        out.extend_from_slice(&arm_targets[..N_ARM]);
    }
    if p.tracked_object {
        out.extend_from_slice(tracked);
    }
}
