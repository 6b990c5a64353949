//! `WorldSpec` + object variant → MJCF text. The text is the world: the `world` artifact stores
//! it, `osms world dump` prints it, and every rollout compiles exactly it.
//!
//! Frames: world z up, the arm's base at the origin, the thrower on the +x side. The hand's
//! palm frame has z along the fingers (continuing the flange's z axis), x across the palm (index
//! at -x, pinky at +x) and y along the palm normal: the palm faces +y and fingers flex toward it.
//!
//! Every robot body has `gravcomp="1"`: like the xArm's own controller, the servos act on top of
//! gravity compensation, so the home posture is an equilibrium and a held palm does not sag.
//!
//! Contact bitmasks make the classes of `contacts.rs` separable and keep pointless pairs out of
//! the collision pipeline: the world collides with the object only; arm links with the object
//! and with the palm and fingers (self-collision); the hand's mount (adapter and servo tower)
//! with the object only; palm and fingers with the object and the arm; the object with
//! everything.

use std::fmt::Write;

use crate::robot::{
    ARM, ARM_BASE_MASS_KG, ARM_JOINTS, DISTAL, FINGERS, HAND_JOINTS, THUMB_CMC_POS, THUMB_SEGMENTS,
    hand_ranges_rad,
};
use crate::spec::{ObjectVariant, WorldSpec};

pub const BIT_WORLD: u32 = 1;
pub const BIT_ARM: u32 = 2;
pub const BIT_HAND: u32 = 4;
pub const BIT_OBJECT: u32 = 8;
pub const BIT_MOUNT: u32 = 16;

/// Body and site names that the rest of the crate looks up.
pub const OBJECT_BODY: &str = "object";
pub const PALM_BODY: &str = "hand_palm";
pub const PALM_SITE: &str = "palm_center";

fn v3(v: [f64; 3]) -> String {
    format!("{} {} {}", v[0], v[1], v[2])
}

struct Xml {
    out: String,
    depth: usize,
}

impl Xml {
    fn line(&mut self, text: &str) {
        let _ = writeln!(self.out, "{}{text}", "  ".repeat(self.depth));
    }
    fn open(&mut self, text: &str) {
        self.line(text);
        self.depth += 1;
    }
    fn close(&mut self, tag: &str) {
        self.depth -= 1;
        self.line(&format!("</{tag}>"));
    }
}

const ARM_CONTACT: &str = "contype=\"2\" conaffinity=\"12\"";
const HAND_CONTACT: &str = "contype=\"4\" conaffinity=\"10\"";
const MOUNT_CONTACT: &str = "contype=\"16\" conaffinity=\"8\"";

/// The MJCF of the world with object `variant`.
pub fn world_xml(spec: &WorldSpec, variant: ObjectVariant) -> String {
    let mut x = Xml {
        out: String::new(),
        depth: 0,
    };
    x.open(&format!("<mujoco model=\"osms-catch-{variant}\">"));
    x.line("<compiler angle=\"radian\" autolimits=\"true\"/>");
    x.line(&format!(
        "<option timestep=\"{}\" integrator=\"implicitfast\" cone=\"elliptic\" impratio=\"{}\"/>",
        spec.timestep_secs, spec.impratio
    ));
    x.line("<size memory=\"4M\"/>");
    x.open("<default>");
    x.line("<geom friction=\"1 0.005 0.001\" condim=\"3\"/>");
    x.close("default");

    x.open("<worldbody>");
    x.line("<light pos=\"0 0 3\" dir=\"0 0 -1\" directional=\"true\"/>");
    x.line("<geom name=\"ground\" type=\"plane\" size=\"5 5 0.1\" contype=\"1\" conaffinity=\"8\" rgba=\"0.8 0.8 0.8 1\"/>");
    x.line("<geom name=\"pedestal\" type=\"cylinder\" pos=\"0 0 0.06\" size=\"0.06 0.06\" contype=\"1\" conaffinity=\"8\" rgba=\"0.3 0.3 0.3 1\"/>");
    arm_and_hand(&mut x, spec);
    object(&mut x, spec, variant);
    x.close("worldbody");

    actuators(&mut x);
    x.open("<keyframe>");
    let mut qpos: Vec<f64> = spec.arm_home_rad.to_vec();
    qpos.extend(spec.hand_home_rad);
    qpos.extend([1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0]);
    let ctrl: Vec<f64> = spec
        .arm_home_rad
        .iter()
        .chain(spec.hand_home_rad.iter())
        .copied()
        .collect();
    let join = |v: &[f64]| {
        v.iter()
            .map(|f| f.to_string())
            .collect::<Vec<_>>()
            .join(" ")
    };
    x.line(&format!(
        "<key name=\"home\" qpos=\"{}\" ctrl=\"{}\"/>",
        join(&qpos),
        join(&ctrl)
    ));
    x.close("keyframe");
    x.close("mujoco");
    x.out
}

fn arm_and_hand(x: &mut Xml, spec: &WorldSpec) {
    let _ = spec;
    x.open("<body name=\"arm_base\" pos=\"0 0 0.12\">");
    x.line(&format!(
        "<geom name=\"arm_base_geom\" type=\"cylinder\" fromto=\"0 0 0 0 0 0.2\" size=\"0.06\" mass=\"{ARM_BASE_MASS_KG}\" {ARM_CONTACT} rgba=\"0.9 0.9 0.9 1\"/>"
    ));
    // Each link's geom spans from its origin to the next link's origin.
    for (i, link) in ARM.iter().enumerate() {
        let quat = link
            .quat
            .map(|q| format!(" quat=\"{} {} {} {}\"", q[0], q[1], q[2], q[3]))
            .unwrap_or_default();
        x.open(&format!(
            "<body name=\"{}\" pos=\"{}\"{quat} gravcomp=\"1\">",
            link.name,
            v3(link.pos)
        ));
        x.line(&format!(
            "<joint name=\"{}\" type=\"hinge\" axis=\"0 0 1\" range=\"{} {}\" damping=\"{}\" armature=\"0.1\" frictionloss=\"1\"/>",
            ARM_JOINTS[i], link.range_rad[0], link.range_rad[1], link.damping
        ));
        let geom_name = format!("{}_geom", link.name);
        match ARM.get(i + 1) {
            Some(next) if next.pos.iter().any(|c| *c != 0.0) => x.line(&format!(
                "<geom name=\"{geom_name}\" type=\"capsule\" fromto=\"0 0 0 {}\" size=\"0.045\" mass=\"{}\" {ARM_CONTACT} rgba=\"0.9 0.9 0.9 1\"/>",
                v3(next.pos),
                link.mass_kg
            )),
            Some(_) => x.line(&format!(
                "<geom name=\"{geom_name}\" type=\"sphere\" size=\"0.05\" mass=\"{}\" {ARM_CONTACT} rgba=\"0.9 0.9 0.9 1\"/>",
                link.mass_kg
            )),
            // The flange: a disc whose +z face is the mounting surface.
            None => x.line(&format!(
                "<geom name=\"{geom_name}\" type=\"cylinder\" fromto=\"0 0 -0.02 0 0 0\" size=\"0.04\" mass=\"{}\" {ARM_CONTACT} rgba=\"0.7 0.7 0.7 1\"/>",
                link.mass_kg
            )),
        }
    }
    hand(x);
    for _ in ARM {
        x.close("body");
    }
    x.close("body");
}

/// The hand on a flange adapter: a 20 mm adapter disc, the 0.9 kg servo tower (100 mm from the
/// tower's origin to the wrist axis), the wrist, the palm and the five fingers. The tower's box
/// sits toward the palm side (as the servos and tendons of a tendon-driven hand do), so its face
/// stands 39 mm above the palm surface and stops an object sliding across the palm toward the
/// wrist.
fn hand(x: &mut Xml) {
    let ranges = hand_ranges_rad();
    let range = |name: &str| {
        let i = HAND_JOINTS
            .iter()
            .position(|j| *j == name)
            .expect("a hand joint");
        format!("range=\"{} {}\"", ranges[i][0], ranges[i][1])
    };
    let joint = |name: &str, axis: &str| {
        format!(
            "<joint name=\"{name}\" type=\"hinge\" axis=\"{axis}\" {} damping=\"0.1\" armature=\"0.001\" frictionloss=\"0.001\"/>",
            range(name)
        )
    };
    let flex = "-1 0 0";
    x.line(&format!(
        "<geom name=\"hand_adapter\" type=\"cylinder\" fromto=\"0 0 0 0 0 0.02\" size=\"0.04\" mass=\"0.05\" {MOUNT_CONTACT} rgba=\"0.2 0.2 0.2 1\"/>"
    ));
    x.open("<body name=\"hand_tower\" pos=\"0 0 0.02\" gravcomp=\"1\">");
    x.line(&format!(
        "<geom name=\"hand_tower_geom\" type=\"box\" pos=\"0 0.02 0.045\" size=\"0.035 0.03 0.045\" mass=\"0.9\" {MOUNT_CONTACT} rgba=\"0.2 0.2 0.2 1\"/>"
    ));
    x.open("<body name=\"hand_palm\" pos=\"0 0 0.1\" gravcomp=\"1\">");
    x.line(&joint("hand_wrist", "1 0 0").replace("damping=\"0.1\"", "damping=\"0.5\""));
    x.line(&format!(
        "<geom name=\"hand_palm_geom\" type=\"box\" pos=\"0.004 0 0.042\" size=\"0.044 0.011 0.042\" mass=\"0.05\" {HAND_CONTACT} friction=\"1 0.005 0.001\" rgba=\"0.95 0.6 0.4 1\"/>"
    ));
    x.line(&format!(
        "<site name=\"{PALM_SITE}\" pos=\"0.004 0.011 0.045\" size=\"0.005\"/>"
    ));
    for f in &FINGERS {
        let n = f.name;
        x.open(&format!(
            "<body name=\"hand_{n}_base\" pos=\"{}\" gravcomp=\"1\">",
            v3(f.abd_pos)
        ));
        x.line(&joint(&format!("hand_{n}_abd"), "0 1 0"));
        x.line(&format!(
            "<geom name=\"hand_{n}_base_geom\" type=\"capsule\" fromto=\"0 0 0 0 0 {}\" size=\"0.009\" mass=\"0.005\" {HAND_CONTACT} rgba=\"0.95 0.6 0.4 1\"/>",
            f.abd_to_mcp
        ));
        x.open(&format!(
            "<body name=\"hand_{n}_proximal\" pos=\"0 0 {}\" gravcomp=\"1\">",
            f.abd_to_mcp
        ));
        x.line(&joint(&format!("hand_{n}_mcp"), flex));
        x.line(&format!(
            "<geom name=\"hand_{n}_proximal_geom\" type=\"capsule\" fromto=\"0 0 0 0 0 {}\" size=\"0.009\" mass=\"0.015\" {HAND_CONTACT} rgba=\"0.95 0.6 0.4 1\"/>",
            f.proximal
        ));
        x.open(&format!(
            "<body name=\"hand_{n}_distal\" pos=\"0 0 {}\" gravcomp=\"1\">",
            f.proximal
        ));
        x.line(&joint(&format!("hand_{n}_pip"), flex));
        x.line(&format!(
            "<geom name=\"hand_{n}_distal_geom\" type=\"capsule\" fromto=\"0 0 0 0 0 {DISTAL}\" size=\"0.008\" mass=\"0.008\" {HAND_CONTACT} rgba=\"0.95 0.6 0.4 1\"/>"
        ));
        x.close("body");
        x.close("body");
        x.close("body");
    }
    // The thumb leaves the palm toward -x and +z (rotated -50° about y) and flexes toward +y.
    let [cmc_to_abd, abd_to_mcp, mcp_to_dip, dip_to_tip] = THUMB_SEGMENTS;
    x.open(&format!(
        "<body name=\"hand_thumb_base\" pos=\"{}\" euler=\"0 -0.8727 0\" gravcomp=\"1\">",
        v3(THUMB_CMC_POS)
    ));
    x.line(&joint("hand_thumb_cmc", "0 0 1"));
    x.line(&format!(
        "<geom name=\"hand_thumb_base_geom\" type=\"sphere\" size=\"0.01\" mass=\"0.005\" {HAND_CONTACT} rgba=\"0.95 0.6 0.4 1\"/>"
    ));
    x.open(&format!(
        "<body name=\"hand_thumb_abd_link\" pos=\"0 0 {cmc_to_abd}\" gravcomp=\"1\">"
    ));
    x.line(&joint("hand_thumb_abd", "0 1 0"));
    x.line(&format!(
        "<geom name=\"hand_thumb_abd_geom\" type=\"capsule\" fromto=\"0 0 0 0 0 {abd_to_mcp}\" size=\"0.009\" mass=\"0.012\" {HAND_CONTACT} rgba=\"0.95 0.6 0.4 1\"/>"
    ));
    x.open(&format!(
        "<body name=\"hand_thumb_proximal\" pos=\"0 0 {abd_to_mcp}\" gravcomp=\"1\">"
    ));
    x.line(&joint("hand_thumb_mcp", flex));
    x.line(&format!(
        "<geom name=\"hand_thumb_proximal_geom\" type=\"capsule\" fromto=\"0 0 0 0 0 {mcp_to_dip}\" size=\"0.009\" mass=\"0.012\" {HAND_CONTACT} rgba=\"0.95 0.6 0.4 1\"/>"
    ));
    x.open(&format!(
        "<body name=\"hand_thumb_distal\" pos=\"0 0 {mcp_to_dip}\" gravcomp=\"1\">"
    ));
    x.line(&joint("hand_thumb_dip", flex));
    x.line(&format!(
        "<geom name=\"hand_thumb_distal_geom\" type=\"capsule\" fromto=\"0 0 0 0 0 {dip_to_tip}\" size=\"0.009\" mass=\"0.008\" {HAND_CONTACT} rgba=\"0.95 0.6 0.4 1\"/>"
    ));
    for _ in 0..4 {
        x.close("body");
    }
    x.close("body");
    x.close("body");
}

fn object(x: &mut Xml, spec: &WorldSpec, variant: ObjectVariant) {
    let (kind, size) = variant.geom();
    let size_text = match kind {
        "sphere" => format!("{}", size[0]),
        "cylinder" | "capsule" => format!("{} {}", size[0], size[1]),
        _ => v3(size),
    };
    // A nominal mass; every rollout sets ω's mass (and scales the inertia with it).
    let mass = 0.05;
    x.open(&format!(
        "<body name=\"{}\" pos=\"1 0 1\">",
        crate::mjcf::OBJECT_BODY
    ));
    x.line("<freejoint name=\"object_free\"/>");
    // Priority 1: every contact the object makes takes the object's friction, solref and
    // condim. Without it MuJoCo takes the larger friction and averages the time constants, so
    // the hand's defaults (friction 1, 0.02 s) swallowed the world's values and their DR.
    x.line(&format!(
        "<geom name=\"object_geom\" type=\"{kind}\" size=\"{size_text}\" mass=\"{mass}\" priority=\"1\" friction=\"{} 0.005 0.0001\" condim=\"4\" solref=\"{} 1\" contype=\"8\" conaffinity=\"7\" rgba=\"0.2 0.5 0.9 1\"/>",
        spec.friction, spec.contact_timeconst_secs
    ));
    x.close("body");
}

/// 7 arm servos (xArm7 gains, affine-bias position control) then 17 hand position servos, in
/// action channel order. The wrist carries the palm and fingers, so it gets a stronger servo
/// than the finger joints.
fn actuators(x: &mut Xml) {
    x.open("<actuator>");
    for (i, link) in ARM.iter().enumerate() {
        x.line(&format!(
            "<general name=\"{j}\" joint=\"{j}\" gaintype=\"fixed\" biastype=\"affine\" gainprm=\"{kp}\" biasprm=\"0 {nkp} {nkv}\" forcerange=\"{nf} {f}\" ctrlrange=\"{lo} {hi}\"/>",
            j = ARM_JOINTS[i],
            kp = link.kp,
            nkp = -link.kp,
            nkv = -link.kv,
            nf = -link.force_nm,
            f = link.force_nm,
            lo = link.range_rad[0],
            hi = link.range_rad[1],
        ));
    }
    let ranges = hand_ranges_rad();
    for (i, j) in HAND_JOINTS.iter().enumerate() {
        let (kp, force) = if *j == "hand_wrist" {
            (10.0, 5.0)
        } else {
            (2.0, 1.0)
        };
        x.line(&format!(
            "<position name=\"{j}\" joint=\"{j}\" kp=\"{kp}\" forcerange=\"{} {force}\" ctrlrange=\"{} {}\"/>",
            -force, ranges[i][0], ranges[i][1]
        ));
    }
    x.close("actuator");
}
