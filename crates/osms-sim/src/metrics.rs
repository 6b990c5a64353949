//! Contacts, the paper's catching metrics and success criteria (section III-A), the failure
//! taxonomy, the event step k_e, and the online phase detector.
//!
//! Everything is evaluated once per physics step on a consistent state S_t: MuJoCo's `mj_step`
//! detects contacts and computes kinematics at S_t before integrating, so the caller passes the
//! velocities it saved before the step together with the contacts and positions after it.

use mujoco_rs::prelude::*;
use mujoco_rs::wrappers::mj_model::traits::ModelType;
use serde::{Deserialize, Serialize};

use crate::vec3::{dot, norm, sub};
use crate::world::GeomClass;

/// Success thresholds and evaluation windows. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SuccessSpec {
    /// δ_v: largest object–palm relative speed just before t_c (m/s).
    pub max_contact_speed_mps: f64,
    /// δ_f: largest summed normal force within Δt_eval after t_c (N).
    pub max_force_n: f64,
    /// δ_ℓ: smallest palm follow-through along the incoming direction within Δt_eval (m).
    pub min_follow_through_m: f64,
    /// Δt_eval (s).
    pub eval_window_secs: f64,
    /// Δt_grasp (s): how long after t_c the object must still be held.
    pub grasp_secs: f64,
    /// An object farther than this from the palm centre after t_c has left the hand (m).
    pub release_distance_m: f64,
    /// An arm or wrist joint closer than this to a limit has hit it (rad).
    pub joint_limit_margin_rad: f64,
    /// Episodes end at the latest after this long (s).
    pub max_episode_secs: f64,
    /// Below this object–palm distance (m) the phase is velocity matching.
    pub matching_distance_m: f64,
    /// An object leaving the hand is a rebound when the component of its velocity (relative to
    /// the palm) along the palm normal is at least this fraction of its speed; otherwise it
    /// slid or fell out, a drop.
    pub rebound_normal_fraction: f64,
}

impl Default for SuccessSpec {
    fn default() -> Self {
        SuccessSpec {
            max_contact_speed_mps: 5.0,
            max_force_n: 80.0,
            min_follow_through_m: 0.2,
            eval_window_secs: 0.2,
            grasp_secs: 1.0,
            release_distance_m: 0.15,
            joint_limit_margin_rad: 0.005,
            max_episode_secs: 3.0,
            matching_distance_m: 0.3,
            rebound_normal_fraction: 0.5,
        }
    }
}

/// Why a rollout failed. A rollout can fail several impact criteria at once.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Failure {
    /// The object's first contact was with an arm link or the hand's mount.
    ForbiddenContactArm,
    /// The object's first contact was with the ground or the pedestal.
    ForbiddenContactGround,
    JointLimit,
    SelfCollision,
    Rebound,
    Drop,
    ContactSpeedExceeded,
    ForceExceeded,
    FollowThroughShort,
    /// MuJoCo raised a warning or the state became non-finite.
    Instability,
    /// An action channel was not finite or outside [-1, 1].
    InvalidAction,
}

impl Failure {
    pub const ALL: [Failure; 11] = [
        Failure::ForbiddenContactArm,
        Failure::ForbiddenContactGround,
        Failure::JointLimit,
        Failure::SelfCollision,
        Failure::Rebound,
        Failure::Drop,
        Failure::ContactSpeedExceeded,
        Failure::ForceExceeded,
        Failure::FollowThroughShort,
        Failure::Instability,
        Failure::InvalidAction,
    ];

    /// The three impact-mitigation criteria, which catch completion ignores.
    pub fn is_impact(self) -> bool {
        matches!(
            self,
            Failure::ContactSpeedExceeded | Failure::ForceExceeded | Failure::FollowThroughShort
        )
    }

    pub fn name(self) -> &'static str {
        match self {
            Failure::ForbiddenContactArm => "forbidden contact (arm)",
            Failure::ForbiddenContactGround => "forbidden contact (ground)",
            Failure::JointLimit => "joint limit",
            Failure::SelfCollision => "self-collision",
            Failure::Rebound => "rebound",
            Failure::Drop => "drop",
            Failure::ContactSpeedExceeded => "v_rel too high",
            Failure::ForceExceeded => "f_max too high",
            Failure::FollowThroughShort => "l_max too short",
            Failure::Instability => "instability",
            Failure::InvalidAction => "invalid action",
        }
    }
}

/// The outcome of a rollout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Outcome {
    pub failures: Vec<Failure>,
}

impl Outcome {
    pub fn success(&self) -> bool {
        self.failures.is_empty()
    }

    /// Success ignoring the three impact-mitigation criteria.
    pub fn completion(&self) -> bool {
        self.failures.iter().all(|f| f.is_impact())
    }
}

/// The paper's metrics of one rollout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    /// t_c: time of the first admissible hand–object contact (s).
    pub contact_time_secs: Option<f64>,
    /// v_rel(t_c): object–palm relative speed just before t_c (m/s).
    pub contact_speed_mps: Option<f64>,
    /// f_max: largest summed normal force over admissible contacts within Δt_eval (N).
    pub max_force_n: f64,
    /// ℓ_max: largest palm displacement along the pre-contact incoming direction (m).
    pub follow_through_m: f64,
    /// k_e: control step of the first object–robot contact, else of the closest approach.
    pub event_step: usize,
    pub closest_approach_m: f64,
}

/// Phases of a catch, detected online.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[repr(u8)]
pub enum Phase {
    Approach = 0,
    VelocityMatching = 1,
    Contact = 2,
    FollowThrough = 3,
    Grasping = 4,
}

impl Phase {
    pub const ALL: [Phase; 5] = [
        Phase::Approach,
        Phase::VelocityMatching,
        Phase::Contact,
        Phase::FollowThrough,
        Phase::Grasping,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Phase::Approach => "approach",
            Phase::VelocityMatching => "velocity matching",
            Phase::Contact => "contact",
            Phase::FollowThrough => "follow-through",
            Phase::Grasping => "grasping",
        }
    }
}

/// The contacts of one physics step, classified.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ContactScan {
    /// Classes of the geoms the object touches, one bit per `GeomClass as u8` (a set that
    /// needs no allocation at physics rate).
    object_touches: u8,
    /// Summed normal force over admissible (palm, finger) contacts with the object (N).
    pub admissible_force_n: f64,
    pub admissible_contacts: usize,
    /// Contacts on the palm, with anything: what a touch sensor over the palm feels.
    pub palm_contacts: usize,
    /// Summed normal force over the palm's contacts (N), with `forces`.
    pub palm_force_n: f64,
    /// An arm link touches the palm or a finger.
    pub self_collision: bool,
}

impl ContactScan {
    pub fn touches(&self, pred: impl Fn(GeomClass) -> bool) -> bool {
        GeomClass::ALL
            .into_iter()
            .any(|c| self.object_touches & (1 << c as u8) != 0 && pred(c))
    }
}

/// Classifies the contacts in `data` using `classes` (one per geom). With `forces` it also sums
/// the admissible normal forces, which needs the constraint solve of this state; without, the
/// sum stays 0.
pub fn scan<M: ModelType>(data: &MjData<M>, classes: &[GeomClass], forces: bool) -> ContactScan {
    let mut out = ContactScan::default();
    for (i, c) in data.contact().iter().enumerate() {
        let (a, b) = (classes[c.geom[0] as usize], classes[c.geom[1] as usize]);
        let palm = a == GeomClass::Palm || b == GeomClass::Palm;
        let other = match (a, b) {
            (GeomClass::Object, o) | (o, GeomClass::Object) => Some(o),
            _ => None,
        };
        let admissible = other.is_some_and(GeomClass::is_admissible);
        // The first component of the contact-frame force is the normal force; one solve of
        // it serves both sums (a palm–object contact is in each).
        let normal = if forces && (palm || admissible) {
            data.contact_force(i)[0]
        } else {
            0.0
        };
        if palm {
            out.palm_contacts += 1;
            out.palm_force_n += normal;
        }
        match other {
            Some(o) => {
                out.object_touches |= 1 << o as u8;
                if admissible {
                    out.admissible_contacts += 1;
                    out.admissible_force_n += normal;
                }
            }
            None => {
                let arm_vs_hand =
                    |x: GeomClass, y: GeomClass| x == GeomClass::Arm && y.is_admissible();
                if arm_vs_hand(a, b) || arm_vs_hand(b, a) {
                    out.self_collision = true;
                }
            }
        }
    }
    out
}

/// The state S_t the evaluator sees at one physics step. The palm's velocity costs a Jacobian,
/// so the evaluator asks for it only when it needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepState {
    pub time_secs: f64,
    pub control_step: usize,
    pub object_pos: [f64; 3],
    pub object_vel: [f64; 3],
    pub palm_pos: [f64; 3],
    pub palm_normal: [f64; 3],
}

/// The first admissible hand–object contact t_c, as the criteria see it: the event a controller
/// that hands control back (or a follow-through that must move along the incoming direction)
/// needs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FirstContact {
    /// t_c (s).
    pub time_secs: f64,
    /// The control step during which t_c fell.
    pub control_step: usize,
    /// v_rel(t_c): object–palm relative speed just before t_c (m/s).
    pub contact_speed_mps: f64,
    /// The object's pre-contact incoming direction (unit): ℓ_max is measured along it.
    pub incoming_dir: [f64; 3],
    /// The palm centre at t_c, where ℓ_max is measured from.
    pub palm_pos: [f64; 3],
}

/// Online evaluation of the success criteria. Cloneable, so it is part of an episode snapshot.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluator {
    spec: SuccessSpec,
    failures: Vec<Failure>,
    first_contact: Option<FirstContact>,
    max_force: f64,
    follow_through: f64,
    closest: (f64, usize),
    /// The first object–robot contact's control step.
    robot_contact_step: Option<usize>,
    done: bool,
    phase: Phase,
}

impl Evaluator {
    pub fn new(spec: SuccessSpec) -> Self {
        Evaluator {
            spec,
            failures: Vec::new(),
            first_contact: None,
            max_force: 0.0,
            follow_through: 0.0,
            closest: (f64::INFINITY, 0),
            robot_contact_step: None,
            done: false,
            phase: Phase::Approach,
        }
    }

    pub fn is_done(&self) -> bool {
        self.done
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// The first admissible contact, once it has happened.
    pub fn first_contact(&self) -> Option<&FirstContact> {
        self.first_contact.as_ref()
    }

    /// ℓ_max so far: the palm's largest progress along the incoming direction since t_c (m).
    pub fn follow_through_m(&self) -> f64 {
        self.follow_through
    }

    fn fail(&mut self, f: Failure) {
        if !self.failures.contains(&f) {
            self.failures.push(f);
        }
        self.done = true;
    }

    /// Whether the rollout has already failed, whatever happens next: a failure that ended it,
    /// or an impact criterion that can no longer be met (v_rel(t_c) is fixed at t_c, f_max
    /// only grows, and ℓ_max stops growing when Δt_eval closes). [`Evaluator::finish`] then
    /// reports a failure; validation stops such rollouts early.
    pub fn failure_decided(&self) -> bool {
        if !self.failures.is_empty() {
            return true;
        }
        let Some(c) = &self.first_contact else {
            return false;
        };
        c.contact_speed_mps > self.spec.max_contact_speed_mps
            || self.max_force > self.spec.max_force_n
            || (self.phase == Phase::Grasping
                && self.follow_through < self.spec.min_follow_through_m)
    }

    /// Ends the episode with a failure that is not about contacts (instability, invalid action).
    pub fn abort(&mut self, f: Failure) {
        self.fail(f);
    }

    /// Updates the criteria with one physics step; `joint_margin_ok` says whether every arm and
    /// wrist joint is inside its range by the margin; `palm_vel` computes the palm's velocity
    /// at S_t.
    pub fn physics_step(
        &mut self,
        s: &StepState,
        scan: &ContactScan,
        joint_margin_ok: bool,
        palm_vel: &mut dyn FnMut() -> [f64; 3],
    ) {
        if self.done {
            return;
        }
        let dist = norm(sub(s.object_pos, s.palm_pos));
        if dist < self.closest.0 {
            self.closest = (dist, s.control_step);
        }
        if self.robot_contact_step.is_none() && scan.touches(|c| c != GeomClass::World) {
            self.robot_contact_step = Some(s.control_step);
        }
        if scan.self_collision {
            self.fail(Failure::SelfCollision);
        }
        if !joint_margin_ok {
            self.fail(Failure::JointLimit);
        }
        match self.first_contact {
            None => {
                if scan.touches(|c| c.is_admissible()) {
                    // Contact forces act only in this step's integration, so the velocities of
                    // S_t are those immediately before t_c.
                    let rel = sub(s.object_vel, palm_vel());
                    let v = s.object_vel;
                    let n = norm(v).max(1e-12);
                    self.first_contact = Some(FirstContact {
                        time_secs: s.time_secs,
                        control_step: s.control_step,
                        contact_speed_mps: norm(rel),
                        incoming_dir: [v[0] / n, v[1] / n, v[2] / n],
                        palm_pos: s.palm_pos,
                    });
                    self.max_force = scan.admissible_force_n;
                    self.phase = Phase::Contact;
                } else if scan.touches(|c| matches!(c, GeomClass::Arm | GeomClass::Mount)) {
                    self.fail(Failure::ForbiddenContactArm);
                } else if scan.touches(|c| c == GeomClass::World) {
                    self.fail(Failure::ForbiddenContactGround);
                } else {
                    self.phase = if dist < self.spec.matching_distance_m {
                        Phase::VelocityMatching
                    } else {
                        Phase::Approach
                    };
                }
            }
            Some(FirstContact {
                time_secs: t_c,
                incoming_dir,
                palm_pos: palm0,
                ..
            }) => {
                let since = s.time_secs - t_c;
                if since <= self.spec.eval_window_secs {
                    self.max_force = self.max_force.max(scan.admissible_force_n);
                    let l = dot(sub(s.palm_pos, palm0), incoming_dir);
                    self.follow_through = self.follow_through.max(l);
                    self.phase = Phase::FollowThrough;
                } else {
                    self.phase = Phase::Grasping;
                }
                if scan.touches(|c| c == GeomClass::World) {
                    self.fail(Failure::Drop);
                } else if dist > self.spec.release_distance_m && scan.admissible_contacts == 0 {
                    let rel = sub(s.object_vel, palm_vel());
                    let away =
                        dot(rel, s.palm_normal) >= self.spec.rebound_normal_fraction * norm(rel);
                    self.fail(if away {
                        Failure::Rebound
                    } else {
                        Failure::Drop
                    });
                } else if since >= self.spec.grasp_secs {
                    if scan.admissible_contacts == 0 {
                        self.fail(Failure::Drop);
                    }
                    self.done = true;
                }
            }
        }
        if s.time_secs >= self.spec.max_episode_secs && !self.done {
            // Nothing decided the episode in time: the object was never caught.
            self.fail(Failure::Drop);
        }
    }

    /// The outcome and metrics once the episode is over.
    pub fn finish(&self) -> (Outcome, Metrics) {
        let mut failures = self.failures.clone();
        if let Some(c) = &self.first_contact {
            if c.contact_speed_mps > self.spec.max_contact_speed_mps {
                failures.push(Failure::ContactSpeedExceeded);
            }
            if self.max_force > self.spec.max_force_n {
                failures.push(Failure::ForceExceeded);
            }
            if self.follow_through < self.spec.min_follow_through_m {
                failures.push(Failure::FollowThroughShort);
            }
        }
        failures.sort();
        failures.dedup();
        let metrics = Metrics {
            contact_time_secs: self.first_contact.map(|c| c.time_secs),
            contact_speed_mps: self.first_contact.map(|c| c.contact_speed_mps),
            max_force_n: self.max_force,
            follow_through_m: self.follow_through,
            event_step: self.robot_contact_step.unwrap_or(self.closest.1),
            closest_approach_m: self.closest.0,
        };
        (Outcome { failures }, metrics)
    }
}
