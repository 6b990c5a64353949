//! The typed description of the world (`WorldSpec`, the `world` stage's params) and the ten
//! object variants. Every default lives here.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::control::ArmAction;

/// Object families (paper, section V-A).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectFamily {
    Box,
    Sphere,
    Ellipsoid,
    Cylinder,
    Capsule,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectSize {
    Large,
    Small,
}

/// One of the ten shape–size variants; each has a model of its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct ObjectVariant {
    pub family: ObjectFamily,
    pub size: ObjectSize,
}

impl ObjectFamily {
    pub const ALL: [ObjectFamily; 5] = [
        ObjectFamily::Box,
        ObjectFamily::Sphere,
        ObjectFamily::Ellipsoid,
        ObjectFamily::Cylinder,
        ObjectFamily::Capsule,
    ];

    pub fn name(self) -> &'static str {
        match self {
            ObjectFamily::Box => "box",
            ObjectFamily::Sphere => "sphere",
            ObjectFamily::Ellipsoid => "ellipsoid",
            ObjectFamily::Cylinder => "cylinder",
            ObjectFamily::Capsule => "capsule",
        }
    }
}

impl ObjectSize {
    pub const ALL: [ObjectSize; 2] = [ObjectSize::Large, ObjectSize::Small];

    pub fn name(self) -> &'static str {
        match self {
            ObjectSize::Large => "large",
            ObjectSize::Small => "small",
        }
    }
}

impl ObjectVariant {
    /// The ten variants in a fixed order (family-major); indices into world models use it.
    pub fn all() -> Vec<ObjectVariant> {
        ObjectFamily::ALL
            .iter()
            .flat_map(|&family| {
                ObjectSize::ALL
                    .iter()
                    .map(move |&size| ObjectVariant { family, size })
            })
            .collect()
    }

    pub fn index(self) -> usize {
        self.family as usize * 2 + self.size as usize
    }

    /// MuJoCo geom type and size (half-extents / radius / half-length, metres).
    pub fn geom(self) -> (&'static str, [f64; 3]) {
        let large = self.size == ObjectSize::Large;
        let pick = |l: [f64; 3], s: [f64; 3]| if large { l } else { s };
        match self.family {
            ObjectFamily::Box => ("box", pick([0.035, 0.030, 0.025], [0.025, 0.020, 0.018])),
            ObjectFamily::Sphere => ("sphere", pick([0.035, 0.0, 0.0], [0.025, 0.0, 0.0])),
            ObjectFamily::Ellipsoid => (
                "ellipsoid",
                pick([0.040, 0.030, 0.025], [0.030, 0.022, 0.018]),
            ),
            ObjectFamily::Cylinder => ("cylinder", pick([0.030, 0.040, 0.0], [0.022, 0.030, 0.0])),
            ObjectFamily::Capsule => ("capsule", pick([0.025, 0.035, 0.0], [0.018, 0.025, 0.0])),
        }
    }
}

impl fmt::Display for ObjectVariant {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}-{}", self.family.name(), self.size.name())
    }
}

impl FromStr for ObjectVariant {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        ObjectVariant::all()
            .into_iter()
            .find(|v| v.to_string() == s)
            .ok_or_else(|| {
                let names: Vec<String> = ObjectVariant::all()
                    .iter()
                    .map(ToString::to_string)
                    .collect();
                format!("unknown object `{s}`; objects are {}", names.join(", "))
            })
    }
}

/// The world's params: physics options, robot, objects and scene. The `world` stage's params
/// and the input of the MJCF builder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WorldSpec {
    /// Physics step (s).
    pub timestep_secs: f64,
    /// Physics steps per control step (10 × 2 ms = 50 Hz).
    pub substeps: u32,
    /// MuJoCo's impratio: a larger value makes frictional grasps stiffer.
    pub impratio: f64,
    /// Arm posture at rest before a throw (rad, joints 1–7). The default puts the palm centre at
    /// about (0.52, 0, 0.87) m facing up, fingers toward the thrower (+x), every joint at least
    /// 0.7 rad inside its range (a grid search over MuJoCo's forward kinematics). Palm up is the
    /// paper's setting: the lateral offset is measured where the object crosses the palm's
    /// horizontal plane.
    pub arm_home_rad: [f64; 7],
    /// Hand posture at rest (rad, in actuator order: wrist; thumb cmc, abd, mcp, dip; index,
    /// middle, ring, pinky abd, mcp, pip): a slightly curled open hand.
    pub hand_home_rad: [f64; 17],
    /// Sliding friction of every contact the object makes (its geom has contact priority).
    pub friction: f64,
    /// Contact time constant of every contact the object makes (s): softer contacts absorb
    /// impacts. 0.015 s is what the contacts had before the object's contact priority (the
    /// average of 0.01 s and the hand's 0.02 s); at 0.01 s the teacher lost 7–18 points on the
    /// development stream (docs/sim.md, "Contact parameters").
    pub contact_timeconst_secs: f64,
    /// What the arm's action channels command (issue 74): target increments (the default) or
    /// absolute targets over each joint's range. A world option, so every stage that acts in
    /// this world, teachers, datasets, students and their evaluations, reads the arm one way.
    pub arm_action: ArmAction,
}

impl Default for WorldSpec {
    fn default() -> Self {
        WorldSpec {
            timestep_secs: 0.002,
            substeps: 10,
            impratio: 10.0,
            arm_home_rad: [0.0, -0.45, 0.0, 1.225, 0.0, 0.123, -1.55],
            hand_home_rad: [
                0.0, // wrist
                0.0, 0.35, 0.2, 0.2, // thumb cmc, abd, mcp, dip
                0.0, 0.2, 0.2, // index abd, mcp, pip
                0.0, 0.2, 0.2, // middle
                0.0, 0.2, 0.2, // ring
                0.0, 0.2, 0.2, // pinky
            ],
            friction: 1.0,
            contact_timeconst_secs: 0.015,
            arm_action: ArmAction::Increment,
        }
    }
}

impl WorldSpec {
    pub fn control_dt_secs(&self) -> f64 {
        self.timestep_secs * f64::from(self.substeps)
    }
}

impl WorldSpec {
    /// Checks what serde cannot: positive times and masses, ordered ranges.
    pub fn validate(&self) -> Result<(), crate::SimError> {
        let bad = |what: &str| Err(crate::SimError::Spec(what.to_string()));
        if !(self.timestep_secs > 0.0 && self.timestep_secs <= 0.01) {
            return bad("timestep_secs must be in (0, 0.01]");
        }
        // Records count a control step's physics steps in a u8, with one more under jitter.
        if !(1..=254).contains(&self.substeps) {
            return bad("substeps must be in 1..=254");
        }
        if !(self.friction > 0.0 && self.contact_timeconst_secs > 0.0 && self.impratio >= 1.0) {
            return bad(
                "friction and contact_timeconst_secs must be positive and impratio at least 1",
            );
        }
        Ok(())
    }
}
