//! Actions and their mapping to joint position targets, and domain randomisation.
//!
//! An action has 24 channels in [-1, 1]: 7 arm channels, then 17 hand channels in actuator order
//! (wrist; thumb cmc, abd, mcp, dip; index, middle, ring, pinky abd, mcp, pip).
//!
//! - **Arm channels** are read as the world's [`ArmAction`] says:
//!   - `increment` (the default): bounded delta targets, the servo target of arm joint i moves by
//!     `a_i · arm_max_delta_rad` per control step from its previous target, clamped to the
//!     joint's range. A zero arm action holds the current targets (no drift under gravity).
//!   - `absolute`: joint targets over the joint's range, as the hand's, reached at most
//!     `arm_max_delta_rad` per control step (the servo's rate limit, which a target increment
//!     has by construction).
//! - **Hand channels are absolute targets** over the joint's range: `lo + (a + 1) / 2 · (hi - lo)`.

use serde::{Deserialize, Serialize};

use crate::robot::{ARM, hand_ranges_rad};

pub const N_ARM: usize = 7;
pub const N_HAND: usize = 17;
pub const N_ACTION: usize = N_ARM + N_HAND;

pub type Action = [f64; N_ACTION];

/// How actions become servo targets. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ControlSpec {
    /// Largest change of an arm joint target per control step (rad). 0.15 rad at 50 Hz is
    /// 7.5 rad/s, more than twice the xArm7's rated 3.14 rad/s joint speed (joints reach about
    /// 7 rad/s in a follow-through): at the rated speed the palm cannot cover the paper's
    /// ℓ_max ≈ 0.42 m within Δt_eval = 0.2 s (docs/sim.md, "Deviation: a faster arm").
    pub arm_max_delta_rad: f64,
}

/// The default [`ControlSpec::arm_max_delta_rad`] (rad per control step).
pub const ARM_MAX_DELTA_RAD: f64 = 0.15;

impl Default for ControlSpec {
    fn default() -> Self {
        ControlSpec {
            arm_max_delta_rad: ARM_MAX_DELTA_RAD,
        }
    }
}

/// What an arm action channel means (issue 74): the paper says only "each action channel
/// normalized to [-1, 1]". A world option (`world.arm_action`), so every stage that rolls out in
/// a world reads its arm the same way.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ArmAction {
    /// A change of the joint's servo target: `a · arm_max_delta_rad` per control step.
    #[default]
    Increment,
    /// The joint's servo target over its range, `lo + (a + 1) / 2 · (hi - lo)`, followed at
    /// most `arm_max_delta_rad` per control step.
    Absolute,
}

impl ArmAction {
    pub const NAMES: [&'static str; 2] = ["increment", "absolute"];

    pub fn name(self) -> &'static str {
        match self {
            ArmAction::Increment => "increment",
            ArmAction::Absolute => "absolute",
        }
    }

    /// The factor on domain randomisation's actuation noise for arm joint `joint`'s channel:
    /// the noise is sized in the increment's units on both arms (one unit is
    /// `arm_max_delta_rad` of servo target), so a given noise is the same error of the servo
    /// target per control step whichever way the arm is commanded. On an absolute arm one unit
    /// is half the joint's range (π rad for joints 1, 3, 5, 7), and the paper DR's 0.02 would be
    /// a 0.06 rad jitter of the target.
    pub fn noise_scale(self, spec: &ControlSpec, joint: usize) -> f64 {
        match self {
            ArmAction::Increment => 1.0,
            ArmAction::Absolute => {
                let [lo, hi] = ARM[joint].range_rad;
                spec.arm_max_delta_rad / (0.5 * (hi - lo))
            }
        }
    }

    /// The arm action that asks for the servo targets `arm_rad`, one control step after the
    /// targets `from_rad`: the increment toward them (bounded by the rate limit) or the targets
    /// themselves.
    pub fn command(
        self,
        spec: &ControlSpec,
        from_rad: &[f64; N_ARM],
        arm_rad: &[f64; N_ARM],
    ) -> [f64; N_ARM] {
        std::array::from_fn(|i| {
            let [lo, hi] = ARM[i].range_rad;
            let a = match self {
                ArmAction::Increment => (arm_rad[i] - from_rad[i]) / spec.arm_max_delta_rad,
                ArmAction::Absolute => 2.0 * (arm_rad[i] - lo) / (hi - lo) - 1.0,
            };
            a.clamp(-1.0, 1.0)
        })
    }
}

impl ArmAction {
    /// The arm action in this world of a controller that moves by increments from the
    /// commanded targets `commanded_rad` ([`crate::policy::PolicyView::commanded_arm`]): the
    /// increments themselves on an increment arm, the targets they reach on an absolute one.
    pub fn from_increments(
        self,
        spec: &ControlSpec,
        commanded_rad: &[f64; N_ARM],
        increments: &[f64; N_ARM],
    ) -> [f64; N_ARM] {
        match self {
            ArmAction::Increment => *increments,
            ArmAction::Absolute => {
                let to: [f64; N_ARM] = std::array::from_fn(|i| {
                    let [lo, hi] = ARM[i].range_rad;
                    (commanded_rad[i] + increments[i].clamp(-1.0, 1.0) * spec.arm_max_delta_rad)
                        .clamp(lo, hi)
                });
                self.command(spec, commanded_rad, &to)
            }
        }
    }
}

/// Joint ranges in action order.
pub fn joint_ranges() -> [[f64; 2]; N_ACTION] {
    let mut r = [[0.0; 2]; N_ACTION];
    for (i, link) in ARM.iter().enumerate() {
        r[i] = link.range_rad;
    }
    r[N_ARM..].copy_from_slice(&hand_ranges_rad());
    r
}

/// New servo targets from the previous ones and an (already validated) action, its arm
/// channels read as `arm` says.
pub fn targets(
    spec: &ControlSpec,
    arm: ArmAction,
    previous: &[f64; N_ACTION],
    action: &Action,
) -> [f64; N_ACTION] {
    let ranges = joint_ranges();
    let mut out = [0.0; N_ACTION];
    let step = spec.arm_max_delta_rad;
    for i in 0..N_ACTION {
        let [lo, hi] = ranges[i];
        let absolute = lo + 0.5 * (action[i] + 1.0) * (hi - lo);
        out[i] = if i >= N_ARM {
            absolute
        } else {
            match arm {
                ArmAction::Increment => (previous[i] + action[i] * step).clamp(lo, hi),
                ArmAction::Absolute => absolute
                    .clamp(previous[i] - step, previous[i] + step)
                    .clamp(lo, hi),
            }
        };
    }
    out
}

/// The action that holds the arm at the servo targets `arm_rad` (where they already are) and
/// asks the hand for the posture `hand_rad`.
pub fn hold_action_at(arm: ArmAction, arm_rad: &[f64; N_ARM], hand_rad: &[f64; N_HAND]) -> Action {
    let mut a = hold_action(hand_rad);
    if arm == ArmAction::Absolute {
        let spec = ControlSpec::default();
        a[..N_ARM].copy_from_slice(&arm.command(&spec, arm_rad, arm_rad));
    }
    a
}

/// The action of an increment arm that holds the arm's targets and asks the hand for the
/// posture `hand_rad` ([`hold_action_at`] for either arm).
pub fn hold_action(hand_rad: &[f64; N_HAND]) -> Action {
    let ranges = joint_ranges();
    let mut a = [0.0; N_ACTION];
    for i in 0..N_HAND {
        let [lo, hi] = ranges[N_ARM + i];
        a[N_ARM + i] = (2.0 * (hand_rad[i] - lo) / (hi - lo) - 1.0).clamp(-1.0, 1.0);
    }
    a
}

/// Domain randomisation (paper 5, "Simulation"). Each effect is switched on by a non-zero size.
/// In pipeline.toml a `dr` is a preset name (`"off"`, `"paper"`) or a table of these fields
/// (missing fields are off). docs/sim.md gives each magnitude and where it comes from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default, remote = "Self")]
pub struct DrSpec {
    /// Standard deviation of the noise on the observed object position (m).
    pub object_position_noise_m: f64,
    /// Largest observation delay (control steps), drawn per rollout in 0..=max.
    pub max_observation_delay_steps: u32,
    /// Largest actuation delay (control steps), drawn per rollout in 0..=max.
    pub max_actuation_delay_steps: u32,
    /// Standard deviation of the noise added to every executed action channel.
    pub actuation_noise: f64,
    /// Servo gains are scaled per rollout by a factor uniform in [1 - g, 1 + g].
    pub gain_variation: f64,
    /// Probability that a control step lasts one physics step more or less than nominal.
    pub timing_jitter_prob: f64,
    /// Object friction and contact time constant are scaled per rollout by factors uniform in
    /// [1 - v, 1 + v].
    pub friction_variation: f64,
    pub contact_timeconst_variation: f64,
}

impl Default for DrSpec {
    /// Off: the world as specified. Pipelines switch effects on per stage.
    fn default() -> Self {
        DrSpec {
            object_position_noise_m: 0.0,
            max_observation_delay_steps: 0,
            max_actuation_delay_steps: 0,
            actuation_noise: 0.0,
            gain_variation: 0.0,
            timing_jitter_prob: 0.0,
            friction_variation: 0.0,
            contact_timeconst_variation: 0.0,
        }
    }
}

impl DrSpec {
    /// The names [`DrSpec::preset`] knows.
    pub const PRESETS: [&'static str; 2] = ["off", "paper"];

    /// A named setting: `off` (the world as specified) or `paper`.
    pub fn preset(name: &str) -> Option<Self> {
        match name {
            "off" => Some(DrSpec::default()),
            "paper" => Some(DrSpec::paper()),
            _ => None,
        }
    }

    pub fn is_off(&self) -> bool {
        *self == DrSpec::default()
    }

    /// The setting teachers are trained and every policy is evaluated under (paper 5: object
    /// position perturbations, observation and actuation delays, actuation noise and gain
    /// variation, control-timing jitter, contact-dynamics variation). The paper names the kinds
    /// but not their sizes; docs/sim.md says where each size comes from.
    pub fn paper() -> Self {
        DrSpec {
            object_position_noise_m: 0.005,
            max_observation_delay_steps: 1,
            max_actuation_delay_steps: 1,
            actuation_noise: 0.02,
            gain_variation: 0.1,
            timing_jitter_prob: 0.05,
            friction_variation: 0.2,
            contact_timeconst_variation: 0.3,
        }
    }
}

impl Serialize for DrSpec {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        DrSpec::serialize(self, s)
    }
}

impl<'de> Deserialize<'de> for DrSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use serde::de::{self, MapAccess, Visitor, value::MapAccessDeserializer};
        struct PresetOrTable;
        impl<'de> Visitor<'de> for PresetOrTable {
            type Value = DrSpec;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a preset name (\"off\" or \"paper\") or a table of DR sizes")
            }
            fn visit_str<E: de::Error>(self, name: &str) -> Result<DrSpec, E> {
                DrSpec::preset(name).ok_or_else(|| {
                    E::invalid_value(de::Unexpected::Str(name), &"\"off\" or \"paper\"")
                })
            }
            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<DrSpec, A::Error> {
                DrSpec::deserialize(MapAccessDeserializer::new(map))
            }
        }
        // Binary formats (the store's postcard) are not self-describing: always the table.
        if d.is_human_readable() {
            d.deserialize_any(PresetOrTable)
        } else {
            DrSpec::deserialize(d)
        }
    }
}

/// The per-rollout draws of domain randomisation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DrDraw {
    pub observation_delay_steps: u32,
    pub actuation_delay_steps: u32,
    pub gain_scale: f64,
    pub friction_scale: f64,
    pub contact_timeconst_scale: f64,
}

impl DrDraw {
    pub fn none() -> Self {
        DrDraw {
            observation_delay_steps: 0,
            actuation_delay_steps: 0,
            gain_scale: 1.0,
            friction_scale: 1.0,
            contact_timeconst_scale: 1.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_mapping_spans_the_range_and_hold_action_inverts_it() {
        let spec = ControlSpec::default();
        let ranges = joint_ranges();
        let prev = [0.0; N_ACTION];
        let lo = targets(&spec, ArmAction::Increment, &prev, &[-1.0; N_ACTION]);
        let hi = targets(&spec, ArmAction::Increment, &prev, &[1.0; N_ACTION]);
        for i in N_ARM..N_ACTION {
            assert!((lo[i] - ranges[i][0]).abs() < 1e-12 && (hi[i] - ranges[i][1]).abs() < 1e-12);
        }
        let hand: [f64; N_HAND] = std::array::from_fn(|i| 0.1 + 0.01 * i as f64);
        let t = targets(&spec, ArmAction::Increment, &prev, &hold_action(&hand));
        for i in 0..N_HAND {
            assert!((t[N_ARM + i] - hand[i]).abs() < 1e-12);
        }
        assert!(
            t[..N_ARM].iter().all(|x| *x == 0.0),
            "a hold action keeps the arm targets"
        );
    }

    #[test]
    fn dr_is_a_preset_name_or_a_table() {
        #[derive(Deserialize)]
        struct P {
            dr: DrSpec,
        }
        let parse = |s: &str| toml::from_str::<P>(s).map(|p| p.dr);
        assert_eq!(parse("dr = \"paper\"").expect("parses"), DrSpec::paper());
        assert_eq!(parse("dr = \"off\"").expect("parses"), DrSpec::default());
        let t = parse("dr = { actuation_noise = 0.1 }").expect("parses");
        assert_eq!(t.actuation_noise, 0.1);
        assert_eq!(t.gain_variation, 0.0);
        let e = parse("dr = \"papr\"").expect_err("an error").to_string();
        assert!(e.contains("papr") && e.contains("\"paper\""), "{e}");
        let e = parse("dr = { actuation_nois = 0.1 }")
            .expect_err("an error")
            .to_string();
        assert!(e.contains("actuation_nois"), "{e}");
        // The store's binary codec round-trips the table.
        let bytes = postcard::to_allocvec(&DrSpec::paper()).expect("encodes");
        assert_eq!(
            postcard::from_bytes::<DrSpec>(&bytes).expect("decodes"),
            DrSpec::paper()
        );
        let json = serde_json::to_string(&DrSpec::paper()).expect("encodes");
        assert_eq!(
            serde_json::from_str::<DrSpec>(&json).expect("decodes"),
            DrSpec::paper()
        );
    }

    #[test]
    fn arm_deltas_are_bounded_and_clamped_to_the_range() {
        let spec = ControlSpec::default();
        let ranges = joint_ranges();
        let mut prev = [0.0; N_ACTION];
        prev[3] = ranges[3][1] - 0.01;
        let t = targets(&spec, ArmAction::Increment, &prev, &[1.0; N_ACTION]);
        assert!((t[0] - spec.arm_max_delta_rad).abs() < 1e-12);
        assert_eq!(t[3], ranges[3][1]);
    }

    #[test]
    fn absolute_arm_targets_span_the_range_at_the_servos_rate() {
        let spec = ControlSpec::default();
        let ranges = joint_ranges();
        let step = spec.arm_max_delta_rad;
        // From the range's ends, a full-scale action reaches the other end one rate-limited
        // step at a time; from next to it, the end itself.
        let at_lo: [f64; N_ACTION] = std::array::from_fn(|i| ranges[i][0]);
        let t = targets(&spec, ArmAction::Absolute, &at_lo, &[1.0; N_ACTION]);
        let near_hi: [f64; N_ACTION] = std::array::from_fn(|i| ranges[i][1] - 0.5 * step);
        let u = targets(&spec, ArmAction::Absolute, &near_hi, &[1.0; N_ACTION]);
        for i in 0..N_ARM {
            assert!(
                (t[i] - (ranges[i][0] + step)).abs() < 1e-12,
                "joint {i}: {}",
                t[i]
            );
            assert!((u[i] - ranges[i][1]).abs() < 1e-12, "joint {i}: {}", u[i]);
        }
        // Within the rate, an absolute action designates the target whatever the previous one.
        let prev: [f64; N_ACTION] = std::array::from_fn(|i| 0.5 * (ranges[i][0] + ranges[i][1]));
        let want: [f64; N_ARM] = std::array::from_fn(|i| prev[i] + 0.1 - 0.03 * i as f64);
        let prev_arm: [f64; N_ARM] = std::array::from_fn(|i| prev[i]);
        let mut a = [0.0; N_ACTION];
        a[..N_ARM].copy_from_slice(&ArmAction::Absolute.command(&spec, &prev_arm, &want));
        let t = targets(&spec, ArmAction::Absolute, &prev, &a);
        for i in 0..N_ARM {
            assert!((t[i] - want[i]).abs() < 1e-12, "joint {i}");
        }
        // The same targets as an increment arm's command.
        a[..N_ARM].copy_from_slice(&ArmAction::Increment.command(&spec, &prev_arm, &want));
        let t = targets(&spec, ArmAction::Increment, &prev, &a);
        for i in 0..N_ARM {
            assert!((t[i] - want[i]).abs() < 1e-12, "joint {i}");
        }
    }

    #[test]
    fn a_hold_action_keeps_either_arms_targets() {
        let spec = ControlSpec::default();
        let ranges = joint_ranges();
        let hand = [0.2; N_HAND];
        let prev: [f64; N_ACTION] =
            std::array::from_fn(|i| ranges[i][0] + 0.3 * (ranges[i][1] - ranges[i][0]));
        let arm: [f64; N_ARM] = std::array::from_fn(|i| prev[i]);
        for mode in [ArmAction::Increment, ArmAction::Absolute] {
            let t = targets(&spec, mode, &prev, &hold_action_at(mode, &arm, &hand));
            for i in 0..N_ARM {
                assert!((t[i] - prev[i]).abs() < 1e-12, "{mode:?}, joint {i}");
            }
        }
        assert_eq!(
            hold_action_at(ArmAction::Increment, &arm, &hand),
            hold_action(&hand)
        );
    }

    #[test]
    fn actuation_noise_is_the_same_target_error_on_either_arm() {
        let spec = ControlSpec::default();
        for (j, joint) in ARM.iter().enumerate() {
            assert_eq!(ArmAction::Increment.noise_scale(&spec, j), 1.0);
            // One unit of noise moves an absolute arm's target by one increment's step.
            let [lo, hi] = joint.range_rad;
            let rad = ArmAction::Absolute.noise_scale(&spec, j) * 0.5 * (hi - lo);
            assert!((rad - spec.arm_max_delta_rad).abs() < 1e-12, "joint {j}");
        }
    }

    #[test]
    fn arm_action_names_parse() {
        #[derive(Deserialize)]
        struct P {
            arm_action: ArmAction,
        }
        for name in ArmAction::NAMES {
            let p: P = toml::from_str(&format!("arm_action = \"{name}\"")).expect("parses");
            assert_eq!(p.arm_action.name(), name);
        }
        assert!(toml::from_str::<P>("arm_action = \"delta\"").is_err());
    }
}
