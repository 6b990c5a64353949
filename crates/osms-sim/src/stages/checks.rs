//! The valid ranges of this crate's params (`osms_core::check`), in one place so that they are
//! read together. Caps are sanity bounds far above every profile's value. It lives with the
//! stages, which check params, so that no library module imports `stages`.

use osms_core::check::{Check, Checked, count, each, interval, nested, positive, unit, within};

use super::{ConditionsParams, EvalParams};
use crate::catcher::CatcherSpec;
use crate::conditions::ConditionSpec;
use crate::control::{ControlSpec, DrSpec};
use crate::episode::RolloutSpec;
use crate::metrics::SuccessSpec;
use crate::spec::WorldSpec;

/// Joint angles (rad): any posture of a revolute joint.
const ANGLE: f64 = 2.0 * std::f64::consts::PI;

impl Check for WorldSpec {
    fn check(&self) -> Checked {
        positive("timestep_secs", self.timestep_secs, 0.1)?;
        count("substeps", self.substeps, 1, 1000)?;
        positive("impratio", self.impratio, 1e4)?;
        each("arm_home_rad", &self.arm_home_rad, -ANGLE, ANGLE)?;
        each("hand_home_rad", &self.hand_home_rad, -ANGLE, ANGLE)?;
        positive("friction", self.friction, 100.0)?;
        positive("contact_timeconst_secs", self.contact_timeconst_secs, 10.0)
    }
}

impl Check for ConditionSpec {
    fn check(&self) -> Checked {
        interval("speed_mps", self.speed_mps, 0.1, 100.0)?;
        interval("launch_distance_m", self.launch_distance_m, 0.0, 100.0)?;
        interval("launch_height_m", self.launch_height_m, -10.0, 10.0)?;
        interval("launch_side_m", self.launch_side_m, -10.0, 10.0)?;
        within("max_lateral_offset_m", self.max_lateral_offset_m, 0.0, 1.0)?;
        within("arm_posture_std_rad", self.arm_posture_std_rad, 0.0, 1.0)?;
        within("hand_posture_std_rad", self.hand_posture_std_rad, 0.0, 1.0)?;
        interval("mass_kg", self.mass_kg, 1e-3, 100.0)
    }
}

impl Check for ConditionsParams {
    fn check(&self) -> Checked {
        count("n", self.n, 1, 10_000_000)?;
        nested("sampler", &self.sampler)
    }
}

impl Check for ControlSpec {
    fn check(&self) -> Checked {
        positive("arm_max_delta_rad", self.arm_max_delta_rad, ANGLE)
    }
}

impl Check for DrSpec {
    fn check(&self) -> Checked {
        within(
            "object_position_noise_m",
            self.object_position_noise_m,
            0.0,
            1.0,
        )?;
        count(
            "max_observation_delay_steps",
            self.max_observation_delay_steps,
            0,
            100,
        )?;
        count(
            "max_actuation_delay_steps",
            self.max_actuation_delay_steps,
            0,
            100,
        )?;
        within("actuation_noise", self.actuation_noise, 0.0, 10.0)?;
        // Gains and contact parameters scale by 1 ± v: v < 1 keeps them positive.
        within("gain_variation", self.gain_variation, 0.0, 0.99)?;
        unit("timing_jitter_prob", self.timing_jitter_prob)?;
        within("friction_variation", self.friction_variation, 0.0, 0.99)?;
        within(
            "contact_timeconst_variation",
            self.contact_timeconst_variation,
            0.0,
            0.99,
        )
    }
}

impl Check for SuccessSpec {
    fn check(&self) -> Checked {
        positive("max_contact_speed_mps", self.max_contact_speed_mps, 1e3)?;
        positive("max_force_n", self.max_force_n, 1e6)?;
        within("min_follow_through_m", self.min_follow_through_m, 0.0, 10.0)?;
        positive("eval_window_secs", self.eval_window_secs, 60.0)?;
        within("grasp_secs", self.grasp_secs, 0.0, 60.0)?;
        positive("release_distance_m", self.release_distance_m, 10.0)?;
        within(
            "joint_limit_margin_rad",
            self.joint_limit_margin_rad,
            0.0,
            1.0,
        )?;
        positive("max_episode_secs", self.max_episode_secs, 600.0)?;
        positive("matching_distance_m", self.matching_distance_m, 10.0)?;
        unit("rebound_normal_fraction", self.rebound_normal_fraction)
    }
}

impl Check for RolloutSpec {
    fn check(&self) -> Checked {
        nested("control", &self.control)?;
        nested("dr", &self.dr)?;
        nested("success", &self.success)?;
        count("history_steps", self.history_steps, 1, 1000)
    }
}

impl Check for CatcherSpec {
    fn check(&self) -> Checked {
        positive("ik_damping", self.ik_damping, 100.0)?;
        positive("gain", self.gain, 1.0)?;
        positive("max_step_error_m", self.max_step_error_m, 10.0)?;
        within("close_distance_m", self.close_distance_m, 0.0, 10.0)?;
        each("open_hand_rad", &self.open_hand_rad, -ANGLE, ANGLE)?;
        each("closed_hand_rad", &self.closed_hand_rad, -ANGLE, ANGLE)?;
        if let Some(m) = self.grip_margin_rad {
            positive("grip_margin_rad", m, 100.0)?;
        }
        positive("horizon_secs", self.horizon_secs, 60.0)?;
        unit("facing_blend", self.facing_blend)?;
        within("aim_toward_fingers_m", self.aim_toward_fingers_m, -1.0, 1.0)
    }
}

impl Check for EvalParams {
    fn check(&self) -> Checked {
        nested("rollout", &self.rollout)?;
        nested("catcher", &self.catcher)
    }
}
