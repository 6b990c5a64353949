//! The robots' numbers (`../shared/reference/robot-facts.md`): the xArm7 chain and servos, and
//! the ORCA hand's joints, segment lengths and ranges. Names here are the names in the MJCF.

/// One xArm7 link: its offset from the parent frame, orientation, joint range, mass, servo.
///
/// Three kinds of number here are choices, not facts of the arm, and were changed so that the
/// paper's follow-through (ℓ_max ≈ 0.42 m within Δt_eval) fits the world (docs/sim.md,
/// "Deviation: a faster arm"): the masses are the lighter of robot-facts.md's two public
/// descriptions; the servos' velocity gain is kv = kp/20 and the joint damping a fifth of the
/// common MuJoCo servo's, which braked a 3 rad/s joint with most of its torque limit. Torque
/// limits, gains kp, ranges and the chain are robot-facts.md's.
pub struct ArmLink {
    pub name: &'static str,
    pub pos: [f64; 3],
    /// Quaternion (w x y z), not normalised (MuJoCo normalises).
    pub quat: Option<[f64; 4]>,
    pub range_rad: [f64; 2],
    pub mass_kg: f64,
    pub kp: f64,
    pub kv: f64,
    pub force_nm: f64,
    pub damping: f64,
}

/// Joints 1, 3, 5 and 7 turn ±2π on the real arm; a catching arm gets ±π, which keeps the
/// joint-limit failure meaningful and loses no reachable pose.
const HALF_TURN: f64 = std::f64::consts::PI;

// The published limits are decimal figures (e.g. j6's 3.14159), not approximations of π.
#[allow(clippy::approx_constant)]
pub const ARM: [ArmLink; 7] = [
    ArmLink {
        name: "arm_link1",
        pos: [0.0, 0.0, 0.267],
        quat: None,
        range_rad: [-HALF_TURN, HALF_TURN],
        mass_kg: 0.43,
        kp: 1500.0,
        kv: 75.0,
        force_nm: 50.0,
        damping: 2.0,
    },
    ArmLink {
        name: "arm_link2",
        pos: [0.0, 0.0, 0.0],
        quat: Some([1.0, -1.0, 0.0, 0.0]),
        range_rad: [-2.059, 2.0944],
        mass_kg: 0.56,
        kp: 1500.0,
        kv: 75.0,
        force_nm: 50.0,
        damping: 2.0,
    },
    ArmLink {
        name: "arm_link3",
        pos: [0.0, -0.293, 0.0],
        quat: Some([1.0, 1.0, 0.0, 0.0]),
        range_rad: [-HALF_TURN, HALF_TURN],
        mass_kg: 0.45,
        kp: 1000.0,
        kv: 50.0,
        force_nm: 30.0,
        damping: 1.0,
    },
    ArmLink {
        name: "arm_link4",
        pos: [0.0525, 0.0, 0.0],
        quat: Some([1.0, 1.0, 0.0, 0.0]),
        range_rad: [-0.19198, 3.927],
        mass_kg: 0.52,
        kp: 1000.0,
        kv: 50.0,
        force_nm: 30.0,
        damping: 1.0,
    },
    ArmLink {
        name: "arm_link5",
        pos: [0.0775, -0.3425, 0.0],
        quat: Some([1.0, 1.0, 0.0, 0.0]),
        range_rad: [-HALF_TURN, HALF_TURN],
        mass_kg: 0.19,
        kp: 1000.0,
        kv: 50.0,
        force_nm: 30.0,
        damping: 1.0,
    },
    ArmLink {
        name: "arm_link6",
        pos: [0.0, 0.0, 0.0],
        quat: Some([1.0, 1.0, 0.0, 0.0]),
        range_rad: [-1.69297, 3.14159],
        mass_kg: 0.31,
        kp: 800.0,
        kv: 40.0,
        force_nm: 20.0,
        damping: 0.4,
    },
    ArmLink {
        name: "arm_link7",
        pos: [0.076, 0.097, 0.0],
        quat: Some([1.0, -1.0, 0.0, 0.0]),
        range_rad: [-HALF_TURN, HALF_TURN],
        mass_kg: 0.32,
        kp: 800.0,
        kv: 40.0,
        force_nm: 20.0,
        damping: 0.4,
    },
];

pub const ARM_BASE_MASS_KG: f64 = 0.886;

/// Hand joint names in actuator (= action channel) order.
pub const HAND_JOINTS: [&str; 17] = [
    "hand_wrist",
    "hand_thumb_cmc",
    "hand_thumb_abd",
    "hand_thumb_mcp",
    "hand_thumb_dip",
    "hand_index_abd",
    "hand_index_mcp",
    "hand_index_pip",
    "hand_middle_abd",
    "hand_middle_mcp",
    "hand_middle_pip",
    "hand_ring_abd",
    "hand_ring_mcp",
    "hand_ring_pip",
    "hand_pinky_abd",
    "hand_pinky_mcp",
    "hand_pinky_pip",
];

pub const ARM_JOINTS: [&str; 7] = [
    "arm_j1", "arm_j2", "arm_j3", "arm_j4", "arm_j5", "arm_j6", "arm_j7",
];

fn deg(range: [f64; 2]) -> [f64; 2] {
    [range[0].to_radians(), range[1].to_radians()]
}

/// Hand joint ranges (rad), in [`HAND_JOINTS`] order.
pub fn hand_ranges_rad() -> [[f64; 2]; 17] {
    let finger = |abd: [f64; 2]| [deg(abd), deg([-25.0, 100.0]), deg([-15.0, 107.0])];
    let [ia, im, ip] = finger([-30.0, 25.0]);
    let [ma, mm, mp] = finger([-27.0, 27.0]);
    let [ra, rm, rp] = finger([-27.0, 27.0]);
    let [pa, pm, pp] = finger([-30.0, 30.0]);
    [
        deg([-65.0, 35.0]),
        deg([-45.0, 33.0]),
        deg([-18.0, 55.0]),
        deg([-25.0, 100.0]),
        deg([-15.0, 107.0]),
        ia,
        im,
        ip,
        ma,
        mm,
        mp,
        ra,
        rm,
        rp,
        pa,
        pm,
        pp,
    ]
}

/// A finger: abduction joint position in the palm frame, abduction-to-MCP and proximal lengths.
pub struct Finger {
    pub name: &'static str,
    pub abd_pos: [f64; 3],
    pub abd_to_mcp: f64,
    pub proximal: f64,
}

/// The distal segment is not published; fingertip sensors sit 0.018–0.022 m beyond the PIP axis.
pub const DISTAL: f64 = 0.02;

pub const FINGERS: [Finger; 4] = [
    Finger {
        name: "index",
        abd_pos: [-0.0272, -0.0022, 0.0694],
        abd_to_mcp: 0.0192,
        proximal: 0.037,
    },
    Finger {
        name: "middle",
        abd_pos: [-0.0057, -0.0040, 0.0785],
        abd_to_mcp: 0.0199,
        proximal: 0.040,
    },
    Finger {
        name: "ring",
        abd_pos: [0.0153, -0.0032, 0.0713],
        abd_to_mcp: 0.0199,
        proximal: 0.040,
    },
    Finger {
        name: "pinky",
        abd_pos: [0.0356, 0.0007, 0.0621],
        abd_to_mcp: 0.01775,
        proximal: 0.031,
    },
];

pub const THUMB_CMC_POS: [f64; 3] = [-0.0284, 0.0110, 0.0306];
/// cmc to abd, abd to mcp, mcp to dip, dip to tip (m).
pub const THUMB_SEGMENTS: [f64; 4] = [0.0089, 0.028, 0.032, 0.012];
