//! The policy interface every crate's policies implement: what a policy sees at a control step
//! ([`PolicyView`], with the layouts of its deployable and privileged frames), what it
//! implements ([`Policy`]), and where the method changes a rollout from outside the policy
//! ([`Hooks`]).

use std::collections::VecDeque;

use mujoco_rs::prelude::*;

use crate::conditions::TaskCondition;
use crate::control::{Action, ControlSpec, N_ACTION, N_ARM};
use crate::flight::{FlightTracker, ObservedObject};
use crate::metrics::FirstContact;
use crate::world::World;

/// Length of a deployable observation frame: arm q, q̇ (7 + 7), hand q, q̇ (17 + 17), observed
/// object position (3), the palm's touch reading (1), previous executed action (24).
pub const DEPLOYABLE_LEN: usize = 7 + 7 + 17 + 17 + 3 + 1 + N_ACTION;
/// Length of a privileged frame: arm and hand q, q̇ (48), object position, quaternion, linear
/// and angular velocity (13, observed: delayed like the deployable frame's object position, the
/// position with its noise), palm position, normal and velocity (9), admissible normal force
/// and contact count (2), ω's mass and variant one-hot (11), time (1).
pub const PRIVILEGED_LEN: usize = 48 + 13 + 9 + 2 + 11 + 1;
/// Index of the observed object position (3) in a deployable frame.
pub const OBSERVED_OBJECT: usize = 7 + 7 + 17 + 17;
/// Index of the palm's touch reading in a deployable frame: the summed normal force of the
/// palm's contacts (N), as a touch sensor over the palm reads it, with [`TOUCH_NOISE_N`] of
/// sensor noise under domain randomisation (issue 54: a deployable contact signal).
pub const PALM_TOUCH: usize = OBSERVED_OBJECT + 3;
/// Standard deviation of the palm touch reading's noise (N) whenever domain randomisation is
/// on: about 1 % of a 20 N force-sensing pad's range, the noise floor of a resistive taxel or
/// of a servo's current reading converted to force (docs/sim.md).
pub const TOUCH_NOISE_N: f64 = 0.2;
/// Index of the palm's position in a privileged frame; its normal follows at + 3 and its
/// linear velocity at + 6 (3 each).
pub const PRIVILEGED_PALM: usize = 48 + 13;
/// Index of the admissible contact count in a privileged frame.
pub const PRIVILEGED_CONTACT_COUNT: usize = 48 + 13 + 9 + 1;

/// What a policy sees at a control step. Privileged policies may also read `data`, but not
/// for the object's state (see [`ObservedObject`]).
pub struct PolicyView<'a> {
    pub step: usize,
    pub time_secs: f64,
    pub deployable: &'a [f64],
    /// The last `history_steps` deployable frames, oldest first, ending with `deployable`.
    pub history: &'a VecDeque<Vec<f64>>,
    /// The observed object positions of every frame so far ([`PolicyView::tracked`]).
    pub tracker: &'a FlightTracker,
    pub privileged: &'a [f64],
    /// The object's observed position and velocity (the privileged frame's, delayed and noisy).
    pub object: ObservedObject,
    pub world: &'a World,
    pub condition: &'a TaskCondition,
    /// The first admissible hand–object contact, once it has happened (in an earlier control
    /// step): a controller can hand control back on it, and a follow-through moves along its
    /// incoming direction.
    pub first_contact: Option<&'a FirstContact>,
    /// The palm site's 6 × 7 Jacobian over the arm joints (linear rows, then angular), computed
    /// once per step for the palm velocity and shared by every controller that needs it.
    pub palm_jacobian: [[f64; N_ARM]; 6],
    /// The arm's servo targets at the step's start: the target the controller has accumulated
    /// from its commanded increments (a deployed controller knows its own command).
    pub arm_targets: [f64; N_ARM],
    /// The arm targets the commands so far designate, as the policy (or the snippet that
    /// replaced its arm channels) chose them: the intended actions run through the servo-target
    /// mapping from the home posture, without actuation noise, delay or perturbation. On an
    /// increment arm it is where the commanded increments add up to; a controller that acts
    /// on an absolute arm by increments moves from it (the scripted catcher does).
    pub commanded_arm: [f64; N_ARM],
    /// The simulator at the step's start: positions, velocities, kinematics, contacts and
    /// Jacobians are current; acceleration-stage fields only at steps with an admissible
    /// contact and only if the policy [reads the contact force](Policy::reads_contact_force)
    /// (elsewhere they are left from the last physics step and do not match the contacts).
    pub data: &'a MjData<Box<MjModel>>,
}

impl PolicyView<'_> {
    /// Turns `action`'s arm channels, increments of [`PolicyView::commanded_arm`], into the
    /// world's arm action ([`crate::control::ArmAction::from_increments`]); on an increment arm
    /// they stay as they are.
    pub fn arm_from_increments(&self, control: &ControlSpec, action: &mut Action) {
        let increments: [f64; N_ARM] = std::array::from_fn(|i| action[i]);
        let arm =
            self.world
                .spec
                .arm_action
                .from_increments(control, &self.commanded_arm, &increments);
        action[..N_ARM].copy_from_slice(&arm);
    }

    /// The deployable estimate of the object's flight now, from every observed position so far
    /// ([`crate::flight`]): computed on demand, so a policy that does not read it pays nothing.
    pub fn tracked(&self) -> ObservedObject {
        self.tracker.estimate(self.world.control_period_secs())
    }
}

pub trait Policy {
    fn act(&mut self, view: &PolicyView<'_>) -> Action;

    /// Whether `act` reads the admissible normal force of the privileged frame. Observing that
    /// force at a control step with hand–object contact costs a constraint solve beyond the
    /// physics steps; a policy that does not read it should say so, and then sees NaN in its
    /// place. (The acceleration-stage fields of `data` — `qacc`, `efc_force`, actuator forces,
    /// `mj_contactForce` — are current only where that solve ran; elsewhere they are the last
    /// physics step's.)
    fn reads_contact_force(&self) -> bool {
        true
    }
}

/// Points where the method changes a rollout from outside the policy.
pub trait Hooks {
    /// May replace the arm channels of the intended action (an OSW snippet ζ).
    fn override_arm(&mut self, _step: usize, _action: &mut Action) {}
    /// May perturb the action that is executed (modelled student action errors).
    fn perturb(&mut self, _step: usize, _action: &mut Action) {}
    /// Sees the simulator after every physics step (contacts and kinematics then describe the
    /// state before that step's integration).
    fn after_physics_step(&mut self, _data: &MjData<Box<MjModel>>) {}
}

/// No hooks.
pub struct NoHooks;
impl Hooks for NoHooks {}
