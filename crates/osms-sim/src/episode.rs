//! One rollout: a per-rollout model copy (ω's mass, contact randomisation), the 50 Hz control
//! loop with domain randomisation, observations, the record, and exact snapshot/restore.
//!
//! Per control step: observe → the policy acts (privileged policies may read the simulator) →
//! hooks may replace the arm channels with an open-loop snippet and perturb the executed action →
//! actuation noise and delay → servo targets → 10 physics steps (±1 with timing jitter), each
//! evaluated by the [`Evaluator`].

use std::collections::VecDeque;

use mujoco_rs::mujoco_c::{mjtStage, mjtState};
use mujoco_rs::prelude::*;
use osms_core::rng::{self, StreamRng};
use serde::{Deserialize, Serialize};

use crate::conditions::TaskCondition;
use crate::control::{
    Action, ControlSpec, DrDraw, DrSpec, N_ACTION, N_ARM, N_HAND, hold_action_at, joint_ranges,
    targets,
};
use crate::flight::FlightTracker;
pub use crate::flight::ObservedObject;
use crate::metrics::{
    Evaluator, Failure, FirstContact, Metrics, Outcome, Phase, StepState, SuccessSpec, scan,
};
use crate::policy::{
    DEPLOYABLE_LEN, Hooks, OBSERVED_OBJECT, PALM_TOUCH, PRIVILEGED_LEN, Policy, PolicyView,
    TOUCH_NOISE_N,
};
use crate::world::{World, palm_normal};

/// Everything about how rollouts run, besides the world and ω.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RolloutSpec {
    pub control: ControlSpec,
    pub dr: DrSpec,
    pub success: SuccessSpec,
    /// Keep the privileged observation of every step in the record.
    pub record_privileged: bool,
    /// How many deployable frames (the current one included) a policy sees.
    pub history_steps: usize,
}

impl RolloutSpec {
    /// Whether a rollout under this spec draws from its random stream: only domain
    /// randomisation does, so with it off the record does not depend on the stream.
    pub fn draws_randomness(&self) -> bool {
        !self.dr.is_off()
    }
}

impl Default for RolloutSpec {
    fn default() -> Self {
        RolloutSpec {
            control: ControlSpec::default(),
            dr: DrSpec::default(),
            success: SuccessSpec::default(),
            record_privileged: false,
            history_steps: 4,
        }
    }
}

/// The ChaCha stream of a rollout's seed that the touch noise draws from: a stream of its own,
/// so reading the sensor leaves every other draw of the rollout where it was.
const TOUCH_STREAM: u64 = 1;

/// A finished rollout, compact: per-step arrays are `f32`, flattened with the stated widths.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RolloutRecord {
    pub condition: TaskCondition,
    pub dr: DrDraw,
    pub steps: usize,
    /// Intended actions (the policy's, after any arm override), 24 per step.
    pub intended: Vec<f32>,
    /// Executed actions (after perturbation, actuation noise and delay), 24 per step.
    pub executed: Vec<f32>,
    /// Deployable observation frames, [`DEPLOYABLE_LEN`] per step.
    pub deployable: Vec<f32>,
    /// Privileged frames, [`PRIVILEGED_LEN`] per step, if recorded.
    pub privileged: Vec<f32>,
    /// The arm's servo targets when each step starts (before its action), N_ARM per step.
    /// Arm actions are target increments, so an action snippet means a motion only together
    /// with the targets it starts from (ω̄ carries them).
    pub arm_targets: Vec<f32>,
    /// Palm and object position and velocity, 3 each per step.
    pub palm_pos: Vec<f32>,
    pub palm_vel: Vec<f32>,
    pub object_pos: Vec<f32>,
    pub object_vel: Vec<f32>,
    /// Largest summed admissible normal force within the step (N).
    pub normal_force: Vec<f32>,
    /// Each control step's phase (`Phase as u8`): contact for the one step during which the
    /// first admissible contact happened, otherwise the phase after the step's last physics
    /// step.
    pub phase: Vec<u8>,
    /// The servo targets every physics step of the control step tracked (after its action,
    /// noise and delay), N_ACTION per step at full precision: with ω, the DR draws and
    /// [`RolloutRecord::physics_steps`] they replay the rollout open loop, bit for bit.
    pub servo_targets: Vec<f64>,
    /// Physics steps each control step ran: the world's substeps, ±1 under timing jitter,
    /// fewer where the episode ended inside the step, 0 for an invalid action.
    pub physics_steps: Vec<u8>,
    pub metrics: Metrics,
    pub outcome: Outcome,
}

impl RolloutRecord {
    /// A record of no steps yet, with the metrics of an episode in which nothing happened.
    pub fn empty(condition: TaskCondition, dr: DrDraw) -> Self {
        RolloutRecord {
            condition,
            dr,
            steps: 0,
            intended: Vec::new(),
            executed: Vec::new(),
            deployable: Vec::new(),
            privileged: Vec::new(),
            arm_targets: Vec::new(),
            palm_pos: Vec::new(),
            palm_vel: Vec::new(),
            object_pos: Vec::new(),
            object_vel: Vec::new(),
            normal_force: Vec::new(),
            phase: Vec::new(),
            servo_targets: Vec::new(),
            physics_steps: Vec::new(),
            metrics: Evaluator::new(SuccessSpec::default()).finish().1,
            outcome: Outcome {
                failures: Vec::new(),
            },
        }
    }
}

/// Controller and randomisation state: with the MuJoCo state, all a resumed rollout needs.
#[derive(Debug, Clone, PartialEq)]
struct Controller {
    targets: [f64; N_ACTION],
    /// The arm targets the policy's commands designate ([`PolicyView::commanded_arm`]).
    commanded_arm: [f64; N_ARM],
    executed: Action,
    pending_actions: VecDeque<Action>,
    /// The object's position, quaternion and velocities (13) of the last steps, newest last:
    /// the observation delay's queue.
    pending_object: VecDeque<[f64; 13]>,
    history: VecDeque<Vec<f64>>,
    /// Every frame's observed object position, for the deployable flight estimate
    /// ([`PolicyView::tracked`]).
    tracker: FlightTracker,
    /// The touch sensor's noise ([`TOUCH_STREAM`] of the rollout's seed).
    touch_rng: StreamRng,
}

/// An exact copy of an episode's state at the start of a control step.
#[derive(Clone)]
pub struct Snapshot {
    mj_state: Box<[f64]>,
    /// MuJoCo's warning counters are not part of its state vector; without them one unstable
    /// branch would mark every later branch from the same snapshot unstable.
    warnings: Vec<(i32, i32)>,
    controller: Controller,
    rng: StreamRng,
    evaluator: Evaluator,
    record_steps: usize,
    step: usize,
}

pub struct Episode<'w> {
    world: &'w World,
    spec: &'w RolloutSpec,
    condition: TaskCondition,
    dr: DrDraw,
    data: MjData<Box<MjModel>>,
    controller: Controller,
    rng: StreamRng,
    evaluator: Evaluator,
    record: RolloutRecord,
    step: usize,
    /// Ranges of the arm joints and the wrist, for the joint-limit check.
    ranges: [[f64; 2]; N_ARM + 1],
    /// qvel before the current physics step (reused buffer).
    qvel_before: Vec<f64>,
    /// The observation ran `mj_step1` on the current state, so the next physics step is
    /// `mj_step2` alone: the control step's observation costs no extra forward pass.
    stepped1: bool,
}

const STATE: u32 = mjtState::mjSTATE_INTEGRATION as u32;

fn push3(v: &mut Vec<f32>, x: [f64; 3]) {
    v.extend(x.iter().map(|c| *c as f32));
}

/// A rollout's domain-randomisation draws: the first numbers of its stream, in this order.
fn draw_dr(dr_spec: &DrSpec, rng: &mut StreamRng) -> DrDraw {
    let observation_delay_steps = delay(rng, dr_spec.max_observation_delay_steps);
    let actuation_delay_steps = delay(rng, dr_spec.max_actuation_delay_steps);
    let mut scale = |v: f64| {
        if v > 0.0 {
            rng::uniform(rng, 1.0 - v, 1.0 + v)
        } else {
            1.0
        }
    };
    DrDraw {
        observation_delay_steps,
        actuation_delay_steps,
        gain_scale: scale(dr_spec.gain_variation),
        friction_scale: scale(dr_spec.friction_variation),
        contact_timeconst_scale: scale(dr_spec.contact_timeconst_variation),
    }
}

fn delay(rng: &mut StreamRng, max: u32) -> u32 {
    if max > 0 {
        rng::below(rng, u64::from(max) + 1) as u32
    } else {
        0
    }
}

/// The episode's model (ω's mass, the contact draws) and its state at the first control step's
/// start: the perturbed home posture at rest, the object at its launch position and velocity,
/// the servos holding the posture. Every step of this sequence is part of what a replay
/// outside osms must repeat (docs/export.md).
pub fn initial_data(world: &World, condition: &TaskCondition, dr: &DrDraw) -> MjData<Box<MjModel>> {
    let ids = &world.ids;
    let mut model = world.model(condition.variant).clone();
    let body = ids.object_body;
    let ratio = condition.mass_kg / model.body_mass()[body];
    model.body_mass_mut()[body] = condition.mass_kg;
    for c in &mut model.body_inertia_mut()[body] {
        *c *= ratio;
    }
    model.geom_friction_mut()[ids.object_geom][0] *= dr.friction_scale;
    model.geom_solref_mut()[ids.object_geom][0] *= dr.contact_timeconst_scale;

    let mut data = MjData::new(Box::new(model));
    // Mass-derived constants were computed at compile time; without this, gravity acts on
    // the new mass but the inertia stays the old one. It uses `data` as scratch, so it comes
    // before the initial state is set.
    data.set_const();
    let ranges = joint_ranges();
    let mut posture = [0.0; N_ACTION];
    for i in 0..N_ARM {
        posture[i] = (world.spec.arm_home_rad[i] + condition.arm_perturbation_rad[i])
            .clamp(ranges[i][0], ranges[i][1]);
    }
    for i in 0..N_HAND {
        posture[N_ARM + i] = (world.spec.hand_home_rad[i] + condition.hand_perturbation_rad[i])
            .clamp(ranges[N_ARM + i][0], ranges[N_ARM + i][1]);
    }
    {
        let qpos = data.qpos_mut();
        for i in 0..N_ARM {
            qpos[ids.arm_qpos[i]] = posture[i];
        }
        for i in 0..N_HAND {
            qpos[ids.hand_qpos[i]] = posture[N_ARM + i];
        }
        let o = ids.object_qpos;
        qpos[o..o + 3].copy_from_slice(&condition.launch_pos_m);
        qpos[o + 3..o + 7].copy_from_slice(&[1.0, 0.0, 0.0, 0.0]);
    }
    {
        let qvel = data.qvel_mut();
        qvel.fill(0.0);
        let d = ids.object_dof;
        qvel[d..d + 3].copy_from_slice(&condition.launch_vel_mps);
    }
    data.ctrl_mut().copy_from_slice(&posture);
    data.forward();
    data
}

impl<'w> Episode<'w> {
    /// Sets up a rollout of `condition`; `rng` is the rollout's own stream (DR draws and noise).
    pub fn new(
        world: &'w World,
        spec: &'w RolloutSpec,
        condition: TaskCondition,
        mut rng: StreamRng,
    ) -> Self {
        let dr = draw_dr(&spec.dr, &mut rng);
        Self::with_draw(world, spec, condition, dr, rng)
    }

    /// Sets up a rollout with given DR draws; `rng` continues the rollout's stream after them
    /// (actuation and observation noise, timing jitter).
    pub fn with_draw(
        world: &'w World,
        spec: &'w RolloutSpec,
        condition: TaskCondition,
        dr: DrDraw,
        rng: StreamRng,
    ) -> Self {
        let data = initial_data(world, &condition, &dr);
        let ranges = joint_ranges();
        let posture: [f64; N_ACTION] = std::array::from_fn(|i| data.ctrl()[i]);
        let nv = data.qvel().len();

        let hand_home: [f64; N_HAND] = std::array::from_fn(|i| posture[N_ARM + i]);
        let arm_home: [f64; N_ARM] = std::array::from_fn(|i| posture[i]);
        let hold = hold_action_at(world.spec.arm_action, &arm_home, &hand_home);
        let mut touch_rng = rng.clone();
        touch_rng.set_stream(TOUCH_STREAM);
        touch_rng.set_word_pos(0);
        let controller = Controller {
            targets: posture,
            commanded_arm: arm_home,
            executed: hold,
            pending_actions: VecDeque::from(vec![hold; dr.actuation_delay_steps as usize]),
            pending_object: VecDeque::new(),
            history: VecDeque::new(),
            tracker: FlightTracker::default(),
            touch_rng,
        };
        let record = RolloutRecord::empty(condition.clone(), dr.clone());
        Episode {
            world,
            spec,
            condition,
            dr,
            data,
            controller,
            rng,
            evaluator: Evaluator::new(spec.success.clone()),
            record,
            step: 0,
            ranges: std::array::from_fn(|i| ranges[i]),
            qvel_before: vec![0.0; nv],
            stepped1: false,
        }
    }

    pub fn is_done(&self) -> bool {
        self.evaluator.is_done()
    }

    pub fn step_index(&self) -> usize {
        self.step
    }

    /// Whether the rollout will fail however it continues (see
    /// [`Evaluator::failure_decided`]).
    pub fn failure_decided(&self) -> bool {
        self.evaluator.failure_decided()
    }

    pub fn data(&self) -> &MjData<Box<MjModel>> {
        &self.data
    }

    /// The first admissible hand–object contact, once it has happened.
    pub fn first_contact(&self) -> Option<&FirstContact> {
        self.evaluator.first_contact()
    }

    /// ℓ_max so far (m): the palm's largest progress along the incoming direction since t_c.
    pub fn follow_through_m(&self) -> f64 {
        self.evaluator.follow_through_m()
    }

    /// The record so far (its outcome and metrics are filled in by [`Episode::finish`]).
    pub fn record(&self) -> &RolloutRecord {
        &self.record
    }

    /// The control period (s): physics steps per control step times the timestep.
    pub fn control_period_secs(&self) -> f64 {
        self.world.control_period_secs()
    }

    /// The observation at the start of a control step. Kinematics are recomputed first
    /// (`mj_step` leaves them one physics step behind the state) by `mj_step1`, the first half
    /// of the next physics step, which leaves the integration state untouched, so a restored
    /// episode observes exactly what an uninterrupted one does. The admissible normal force is
    /// the constraint solve's at this state under the controls of the last physics step; it
    /// is solved for only where it can be non-zero and someone reads it (`forces`), else NaN.
    /// The palm's touch reading is the same solve's, wherever the palm has a contact (every
    /// policy reads it: it is part of the deployable frame).
    /// A replay (`noisy = false`) leaves out the observation noise: it reads no stream, and
    /// the recorded deployable frames keep the noisy values.
    fn observe(&mut self, noisy: bool, forces: bool) -> Frame {
        self.data.step1();
        self.stepped1 = true;
        let ids = &self.world.ids;
        let mut contacts = scan(&self.data, &ids.geom_class, false);
        let solve = contacts.palm_contacts > 0 || (forces && contacts.admissible_contacts > 0);
        if solve {
            // The acceleration stage under the last physics step's controls; the physics
            // step's `mj_step2` redoes it under the new ones, so the solve leaves the rollout's
            // bits alone.
            self.data.forward_skip(mjtStage::mjSTAGE_VEL, false);
            contacts = scan(&self.data, &ids.geom_class, true);
        } else if contacts.admissible_contacts > 0 {
            contacts.admissible_force_n = f64::NAN;
        }
        let mut touch = contacts.palm_force_n;
        if noisy && !self.spec.dr.is_off() {
            touch += TOUCH_NOISE_N * rng::normal(&mut self.controller.touch_rng);
        }
        let qpos = self.data.qpos();
        let qvel = self.data.qvel();
        let mut robot = Vec::with_capacity(DEPLOYABLE_LEN);
        robot.extend(ids.arm_qpos.iter().map(|&a| qpos[a]));
        robot.extend(ids.arm_dof.iter().map(|&a| qvel[a]));
        robot.extend(ids.hand_qpos.iter().map(|&a| qpos[a]));
        robot.extend(ids.hand_dof.iter().map(|&a| qvel[a]));
        let (o, d) = (ids.object_qpos, ids.object_dof);
        let object_pos = [qpos[o], qpos[o + 1], qpos[o + 2]];
        let object_vel = [qvel[d], qvel[d + 1], qvel[d + 2]];
        let site = ids.palm_site;
        let palm_pos = self.data.site_xpos()[site];
        let normal = palm_normal(&self.data.site_xmat()[site]);
        let (jacp, jacr) = self.data.jac_site(true, true, site);
        let palm_vel = jacobian_times(&jacp, qvel);
        let palm_jacobian = std::array::from_fn(|r| {
            let (rows, r) = if r < 3 { (&jacp, r) } else { (&jacr, r - 3) };
            ids.arm_dof.map(|dof| rows[r * qvel.len() + dof])
        });

        // The object as observed: delayed, the position noisy.
        let state: [f64; 13] =
            std::array::from_fn(|i| if i < 7 { qpos[o + i] } else { qvel[d + i - 7] });
        self.controller.pending_object.push_back(state);
        while self.controller.pending_object.len() > self.dr.observation_delay_steps as usize + 1 {
            self.controller.pending_object.pop_front();
        }
        let mut observed = self.controller.pending_object[0];
        let noise = self.spec.dr.object_position_noise_m;
        if noisy && noise > 0.0 {
            for c in &mut observed[..3] {
                *c += noise * rng::normal(&mut self.rng);
            }
        }
        let mut privileged = Vec::with_capacity(PRIVILEGED_LEN);
        privileged.extend_from_slice(&robot);
        privileged.extend(observed);
        privileged.extend(palm_pos);
        privileged.extend(normal);
        privileged.extend(palm_vel);
        privileged.push(contacts.admissible_force_n);
        privileged.push(contacts.admissible_contacts as f64);
        privileged.push(self.condition.mass_kg);
        privileged
            .extend((0..10).map(|v| f64::from(u8::from(v == self.condition.variant.index()))));
        privileged.push(self.data.time());

        // Deployable: the observed object's position only.
        let mut deployable = robot;
        deployable.extend(&observed[..3]);
        deployable.push(touch);
        deployable.extend(self.controller.executed);
        Frame {
            deployable,
            privileged,
            palm_pos,
            palm_vel,
            object_pos,
            object_vel,
            observed: ObservedObject {
                pos: [observed[0], observed[1], observed[2]],
                vel: [observed[7], observed[8], observed[9]],
            },
            arm_targets: std::array::from_fn(|i| self.controller.targets[i]),
            palm_jacobian,
        }
    }

    /// Runs one control step. Returns false once the episode is over.
    pub fn step(&mut self, policy: &mut dyn Policy, hooks: &mut dyn Hooks) -> bool {
        let Some(observed) = self.observe_step(policy.reads_contact_force()) else {
            return false;
        };
        let intended = policy.act(&self.view(&observed));
        self.act_step(observed, intended, hooks)
    }

    /// The first half of [`Episode::step`]: observes the state the next action is chosen in
    /// and pushes it onto the history; `None` once the episode is over. [`Episode::view`] shows
    /// it to a policy and [`Episode::act_step`] runs the chosen action. Split so many episodes
    /// can step in lockstep and their policy act on all of them at once; a step split this way
    /// is the same step, bit for bit.
    pub fn observe_step(&mut self, reads_contact_force: bool) -> Option<Observed> {
        if self.is_done() {
            return None;
        }
        let frame = self.observe(true, self.spec.record_privileged || reads_contact_force);
        // The evicted frame's buffer carries the new one: no allocation once the history is full.
        let mut kept = None;
        while self.controller.history.len() >= self.spec.history_steps.max(1) {
            kept = self.controller.history.pop_front();
        }
        let mut slot = kept.unwrap_or_default();
        slot.clone_from(&frame.deployable);
        self.controller.history.push_back(slot);
        let seen = &frame.deployable[OBSERVED_OBJECT..OBSERVED_OBJECT + 3];
        self.controller.tracker.push([seen[0], seen[1], seen[2]]);
        Some(Observed(frame))
    }

    /// What a policy sees of the step `observed` began.
    pub fn view<'a>(&'a self, observed: &'a Observed) -> PolicyView<'a> {
        let frame = &observed.0;
        PolicyView {
            step: self.step,
            time_secs: self.data.time(),
            deployable: &frame.deployable,
            history: &self.controller.history,
            tracker: &self.controller.tracker,
            privileged: &frame.privileged,
            object: frame.observed,
            world: self.world,
            condition: &self.condition,
            first_contact: self.evaluator.first_contact(),
            palm_jacobian: frame.palm_jacobian,
            arm_targets: frame.arm_targets,
            commanded_arm: self.controller.commanded_arm,
            data: &self.data,
        }
    }

    /// The second half of [`Episode::step`]: runs the policy's `intended` action on the step
    /// `observed` began. Returns false once the episode is over.
    pub fn act_step(
        &mut self,
        observed: Observed,
        mut intended: Action,
        hooks: &mut dyn Hooks,
    ) -> bool {
        let frame = observed.0;
        hooks.override_arm(self.step, &mut intended);
        let arm = self.world.spec.arm_action;
        if intended
            .iter()
            .all(|a| a.is_finite() && a.abs() <= 1.0 + 1e-9)
        {
            let mut previous = [0.0; N_ACTION];
            previous[..N_ARM].copy_from_slice(&self.controller.commanded_arm);
            let commanded = targets(&self.spec.control, arm, &previous, &intended);
            self.controller.commanded_arm = std::array::from_fn(|i| commanded[i]);
        }
        let mut executed = intended;
        hooks.perturb(self.step, &mut executed);
        if executed
            .iter()
            .any(|a| !a.is_finite() || a.abs() > 1.0 + 1e-9)
        {
            self.evaluator.abort(Failure::InvalidAction);
            let phase = self.evaluator.phase();
            self.push_record(&frame, &intended, &executed, 0.0, phase, 0);
            return false;
        }
        let noise = self.spec.dr.actuation_noise;
        if noise > 0.0 {
            for (i, a) in executed.iter_mut().enumerate() {
                let scale = if i < N_ARM {
                    arm.noise_scale(&self.spec.control, i)
                } else {
                    1.0
                };
                *a = (*a + noise * scale * rng::normal(&mut self.rng)).clamp(-1.0, 1.0);
            }
        }
        self.controller.pending_actions.push_back(executed);
        let applied = self
            .controller
            .pending_actions
            .pop_front()
            .unwrap_or(executed);
        self.controller.targets =
            targets(&self.spec.control, arm, &self.controller.targets, &applied);
        self.controller.executed = applied;

        let mut substeps = self.world.spec.substeps;
        let jitter = self.spec.dr.timing_jitter_prob;
        if jitter > 0.0 && rng::uniform01(&mut self.rng) < jitter {
            substeps = if rng::uniform01(&mut self.rng) < 0.5 {
                substeps - 1
            } else {
                substeps + 1
            }
            .max(1);
        }
        let (step_force, ran, phase) =
            self.physics_steps(substeps, &mut |d| hooks.after_physics_step(d));
        self.push_record(&frame, &intended, &applied, step_force, phase, ran);
        self.step += 1;
        !self.is_done()
    }

    /// Up to `n` evaluated physics steps toward the current servo targets, fewer if the
    /// episode ends: the step's largest summed admissible force, the physics steps run and the
    /// control step's phase.
    fn physics_steps(
        &mut self,
        n: u32,
        after: &mut dyn FnMut(&MjData<Box<MjModel>>),
    ) -> (f64, u8, Phase) {
        let touched_before = self.evaluator.first_contact().is_some();
        let mut step_force: f64 = 0.0;
        let mut ran = 0u8;
        for _ in 0..n {
            step_force = step_force.max(self.physics_step());
            ran += 1;
            after(&self.data);
            if self.is_done() {
                break;
            }
        }
        // The evaluator's contact phase lasts one physics step; at control rate the step that
        // contains t_c is the contact step.
        let phase = if !touched_before && self.evaluator.first_contact().is_some() {
            Phase::Contact
        } else {
            self.evaluator.phase()
        };
        (step_force, ran, phase)
    }

    /// Replays control step `k` of `record` open loop: its recorded servo targets for its
    /// recorded number of physics steps, evaluated as the original was. `at_start` sees the
    /// simulator at the step's start (kinematics current). Returns false once the episode is
    /// over.
    pub(crate) fn replay_step(
        &mut self,
        record: &RolloutRecord,
        k: usize,
        at_start: &mut dyn FnMut(usize, &MjData<Box<MjModel>>),
    ) -> bool {
        if self.is_done() {
            return false;
        }
        let mut frame = self.observe(false, self.spec.record_privileged);
        at_start(k, &self.data);
        let row = |v: &[f32], w: usize| -> [f64; N_ACTION] {
            std::array::from_fn(|c| f64::from(v[k * w + c]))
        };
        let intended = row(&record.intended, N_ACTION);
        let executed = row(&record.executed, N_ACTION);
        // The observed object position and the touch reading are the record's: they are
        // observations, not states, and drew from the stream. The deployable and privileged
        // frames share the position.
        let seen = OBSERVED_OBJECT..OBSERVED_OBJECT + 3;
        for c in seen.clone() {
            let v = f64::from(record.deployable[k * DEPLOYABLE_LEN + c]);
            frame.deployable[c] = v;
            frame.privileged[c] = v;
        }
        frame.deployable[PALM_TOUCH] =
            f64::from(record.deployable[k * DEPLOYABLE_LEN + PALM_TOUCH]);
        let n = record.physics_steps[k];
        if n == 0 {
            self.evaluator.abort(Failure::InvalidAction);
            let phase = self.evaluator.phase();
            self.push_record(&frame, &intended, &executed, 0.0, phase, 0);
            return false;
        }
        self.controller
            .targets
            .copy_from_slice(&record.servo_targets[k * N_ACTION..(k + 1) * N_ACTION]);
        self.controller.executed = executed;
        let (force, ran, phase) = self.physics_steps(u32::from(n), &mut |_| {});
        self.push_record(&frame, &intended, &executed, force, phase, ran);
        self.step += 1;
        !self.is_done()
    }

    fn push_record(
        &mut self,
        frame: &Frame,
        intended: &Action,
        executed: &Action,
        force: f64,
        phase: Phase,
        physics_steps: u8,
    ) {
        let r = &mut self.record;
        r.steps += 1;
        r.servo_targets.extend_from_slice(&self.controller.targets);
        r.physics_steps.push(physics_steps);
        r.intended.extend(intended.iter().map(|a| *a as f32));
        r.executed.extend(executed.iter().map(|a| *a as f32));
        r.deployable
            .extend(frame.deployable.iter().map(|a| *a as f32));
        if self.spec.record_privileged {
            r.privileged
                .extend(frame.privileged.iter().map(|a| *a as f32));
        }
        r.arm_targets
            .extend(frame.arm_targets.iter().map(|a| *a as f32));
        push3(&mut r.palm_pos, frame.palm_pos);
        push3(&mut r.palm_vel, frame.palm_vel);
        push3(&mut r.object_pos, frame.object_pos);
        push3(&mut r.object_vel, frame.object_vel);
        r.normal_force.push(force as f32);
        r.phase.push(phase as u8);
    }

    /// One physics step, evaluated; returns the summed admissible normal force.
    fn physics_step(&mut self) -> f64 {
        let ids = &self.world.ids;
        // Gain variation: a servo with gain g·kp toward target c acts like one with gain kp
        // toward q + g (c - q), recomputed every physics step.
        let g = self.dr.gain_scale;
        let qpos = self.data.qpos();
        let q: [f64; N_ACTION] = std::array::from_fn(|i| {
            qpos[if i < N_ARM {
                ids.arm_qpos[i]
            } else {
                ids.hand_qpos[i - N_ARM]
            }]
        });
        for ((c, q), t) in self
            .data
            .ctrl_mut()
            .iter_mut()
            .zip(q)
            .zip(self.controller.targets)
        {
            *c = q + g * (t - q);
        }
        self.qvel_before.copy_from_slice(self.data.qvel());
        let time = self.data.time();
        // mj_step is mj_step1 and mj_step2 (MuJoCo's engine_forward.c); the controls enter only
        // the second half.
        if std::mem::take(&mut self.stepped1) {
            self.data.step2();
        } else {
            self.data.step();
        }

        let unstable = self.data.warning().iter().any(|w| w.number > 0)
            || self
                .data
                .qpos()
                .iter()
                .chain(self.data.qvel().iter())
                .any(|v| !v.is_finite());
        if unstable {
            self.evaluator.abort(Failure::Instability);
            return 0.0;
        }
        // After mj_step, contacts and kinematics describe the state before integration.
        let contacts = scan(&self.data, &ids.geom_class, true);
        let site = ids.palm_site;
        let d = ids.object_dof;
        let qv = &self.qvel_before;
        let state = StepState {
            time_secs: time,
            control_step: self.step,
            object_pos: self.data.xpos()[ids.object_body],
            object_vel: [qv[d], qv[d + 1], qv[d + 2]],
            palm_pos: self.data.site_xpos()[site],
            palm_normal: palm_normal(&self.data.site_xmat()[site]),
        };
        let margin = self.spec.success.joint_limit_margin_rad;
        let q = self.data.qpos();
        // Arm joints and the wrist; fingers curling onto their limits around a small object
        // are part of a grasp.
        let joint_ok = ids
            .arm_qpos
            .iter()
            .chain(std::iter::once(&ids.hand_qpos[0]))
            .zip(&self.ranges)
            .all(|(&adr, [lo, hi])| q[adr] > lo + margin && q[adr] < hi - margin);
        let (data, world) = (&self.data, self.world);
        let mut palm_vel = || site_velocity(data, world.ids.palm_site, qv);
        self.evaluator
            .physics_step(&state, &contacts, joint_ok, &mut palm_vel);
        contacts.admissible_force_n
    }

    /// An exact copy of the state at the start of the next control step.
    pub fn snapshot(&self) -> Snapshot {
        Snapshot {
            mj_state: self.data.state(STATE),
            warnings: self
                .data
                .warning()
                .iter()
                .map(|w| (w.number, w.lastinfo))
                .collect(),
            controller: self.controller.clone(),
            rng: self.rng.clone(),
            evaluator: self.evaluator.clone(),
            record_steps: self.record.steps,
            step: self.step,
        }
    }

    /// Returns to `snapshot`, taken from this episode (same world, spec and ω).
    pub fn restore(&mut self, snapshot: &Snapshot) {
        self.data
            .set_state(&snapshot.mj_state, STATE)
            .expect("a snapshot of this model restores");
        for (w, &(number, lastinfo)) in self.data.warning_mut().iter_mut().zip(&snapshot.warnings) {
            w.number = number;
            w.lastinfo = lastinfo;
        }
        self.stepped1 = false;
        self.controller = snapshot.controller.clone();
        self.rng = snapshot.rng.clone();
        self.evaluator = snapshot.evaluator.clone();
        self.step = snapshot.step;
        let n = snapshot.record_steps;
        let r = &mut self.record;
        r.steps = n;
        r.intended.truncate(n * N_ACTION);
        r.executed.truncate(n * N_ACTION);
        r.deployable.truncate(n * DEPLOYABLE_LEN);
        r.privileged.truncate(if self.spec.record_privileged {
            n * PRIVILEGED_LEN
        } else {
            0
        });
        for v in [
            &mut r.palm_pos,
            &mut r.palm_vel,
            &mut r.object_pos,
            &mut r.object_vel,
        ] {
            v.truncate(n * 3);
        }
        r.arm_targets.truncate(n * N_ARM);
        r.normal_force.truncate(n);
        r.phase.truncate(n);
        r.servo_targets.truncate(n * N_ACTION);
        r.physics_steps.truncate(n);
    }

    /// Runs to the end and returns the record.
    pub fn run(mut self, policy: &mut dyn Policy, hooks: &mut dyn Hooks) -> RolloutRecord {
        while self.step(policy, hooks) {}
        self.finish()
    }

    /// The outcome and metrics as they stand (final once the episode is done).
    pub fn outcome(&self) -> (Outcome, Metrics) {
        self.evaluator.finish()
    }

    pub fn finish(mut self) -> RolloutRecord {
        let (outcome, metrics) = self.evaluator.finish();
        self.record.outcome = outcome;
        self.record.metrics = metrics;
        self.record
    }
}

/// The linear velocity of a site from its Jacobian and `qvel`.
fn site_velocity(data: &MjData<Box<MjModel>>, site: usize, qvel: &[f64]) -> [f64; 3] {
    jacobian_times(&data.jac_site(true, false, site).0, qvel)
}

/// A 3 × nv Jacobian times `qvel`.
fn jacobian_times(jacp: &[f64], qvel: &[f64]) -> [f64; 3] {
    let nv = qvel.len();
    std::array::from_fn(|r| (0..nv).map(|c| jacp[r * nv + c] * qvel[c]).sum())
}

/// A control step observed by [`Episode::observe_step`] and waiting for its action, on the
/// episode that observed it.
pub struct Observed(Frame);

/// One control step's observation and the state recorded with it.
struct Frame {
    deployable: Vec<f64>,
    privileged: Vec<f64>,
    palm_pos: [f64; 3],
    palm_vel: [f64; 3],
    object_pos: [f64; 3],
    object_vel: [f64; 3],
    observed: ObservedObject,
    /// The arm's servo targets in force when the step starts, before its action moves them.
    arm_targets: [f64; N_ARM],
    palm_jacobian: [[f64; N_ARM]; 6],
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::hold_action;
    use crate::policy::NoHooks;
    use crate::{ConditionSpec, WorldSpec, conditions};

    struct Hold(Action);
    impl Policy for Hold {
        fn act(&mut self, _: &PolicyView<'_>) -> Action {
            self.0
        }
    }

    #[test]
    fn an_unstable_branch_does_not_mark_later_branches_from_the_same_snapshot() {
        let world = World::new(WorldSpec::default()).expect("world");
        let spec = RolloutSpec {
            dr: DrSpec::paper(),
            ..RolloutSpec::default()
        };
        let condition = conditions::sample(
            &ConditionSpec::default(),
            world.home_palm_pos,
            &mut rng::stream(0, "test", "omega", 3),
        )
        .expect("ω");
        let mut hold = Hold(hold_action(&world.spec.hand_home_rad));
        let stream = || rng::stream(0, "test", "roll", 3);
        let full =
            Episode::new(&world, &spec, condition.clone(), stream()).run(&mut hold, &mut NoHooks);

        let mut ep = Episode::new(&world, &spec, condition, stream());
        for _ in 0..5 {
            ep.step(&mut hold, &mut NoHooks);
        }
        let snap = ep.snapshot();
        // What MuJoCo does when a branch blows up: it counts a warning.
        ep.data.warning_mut()[0].number += 1;
        assert!(!ep.step(&mut hold, &mut NoHooks));
        assert_eq!(ep.outcome().0.failures, [Failure::Instability]);

        ep.restore(&snap);
        assert!(ep.data.warning().iter().all(|w| w.number == 0));
        let resumed = ep.run(&mut hold, &mut NoHooks);
        assert_eq!(resumed, full);
    }

    /// ω̄ reads the recorded servo targets: they must be the ones the controller used, i.e.
    /// follow the target recurrence over the executed (applied) actions from the start posture.
    #[test]
    fn recorded_arm_targets_follow_the_executed_actions() {
        let world = World::new(WorldSpec::default()).expect("world");
        let spec = RolloutSpec {
            dr: DrSpec::paper(),
            ..RolloutSpec::default()
        };
        let condition = conditions::sample(
            &ConditionSpec::default(),
            world.home_palm_pos,
            &mut rng::stream(0, "test", "omega", 7),
        )
        .expect("ω");
        let mut action = hold_action(&world.spec.hand_home_rad);
        action[..N_ARM].copy_from_slice(&[0.3, -0.2, 0.1, 0.25, -0.1, 0.05, -0.3]);
        let record = Episode::new(&world, &spec, condition, rng::stream(0, "test", "roll", 7))
            .run(&mut Hold(action), &mut NoHooks);
        assert!(record.steps > 5);
        assert_eq!(record.arm_targets.len(), record.steps * N_ARM);
        let mut t = [0.0; N_ACTION];
        for (i, v) in record.arm_targets[..N_ARM].iter().enumerate() {
            t[i] = f64::from(*v);
        }
        for k in 0..record.steps - 1 {
            let executed: Action =
                std::array::from_fn(|c| f64::from(record.executed[k * N_ACTION + c]));
            t = targets(&spec.control, world.spec.arm_action, &t, &executed);
            let next = &record.arm_targets[(k + 1) * N_ARM..(k + 2) * N_ARM];
            for (c, (t, recorded)) in t.iter_mut().zip(next).enumerate() {
                let recorded = f64::from(*recorded);
                assert!(
                    (recorded - *t).abs() < 1e-5,
                    "step {k} channel {c}: recorded {recorded}, recurrence {t}"
                );
                *t = recorded;
            }
        }
    }

    /// The premise of sharing a DR-off evaluation across a seed sweep: with DR off the record
    /// does not depend on the rollout's stream; with it on it does.
    #[test]
    fn only_domain_randomisation_reads_the_stream() {
        let world = World::new(WorldSpec::default()).expect("world");
        let condition = conditions::sample(
            &ConditionSpec::default(),
            world.home_palm_pos,
            &mut rng::stream(0, "test", "omega", 5),
        )
        .expect("ω");
        let run = |spec: &RolloutSpec, seed: u64| {
            let mut hold = Hold(hold_action(&world.spec.hand_home_rad));
            Episode::new(
                &world,
                spec,
                condition.clone(),
                rng::stream(seed, "test", "roll", 5),
            )
            .run(&mut hold, &mut NoHooks)
        };
        let off = RolloutSpec::default();
        assert!(!off.draws_randomness());
        assert_eq!(run(&off, 1), run(&off, 2));
        let on = RolloutSpec {
            dr: DrSpec::paper(),
            ..RolloutSpec::default()
        };
        assert!(on.draws_randomness());
        assert_ne!(run(&on, 1), run(&on, 2));
    }
}
