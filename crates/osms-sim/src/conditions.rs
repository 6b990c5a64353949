//! Task conditions ω (paper, section III-A and V-A): object variant and mass, launch state, and
//! the initial posture perturbation. The sampler aims every throw so that the object crosses the
//! palm's horizontal plane, descending, within a configured lateral offset of the palm centre.

use osms_core::rng::{self, StreamRng};
use serde::{Deserialize, Serialize};

use crate::error::{Result, SimError};
use crate::spec::ObjectVariant;
use crate::vec3::norm;

/// Standard gravity used by MuJoCo's default model (m/s²).
pub const GRAVITY_MPS2: f64 = 9.81;

/// The sampler's params. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConditionSpec {
    /// Launch speed range (m/s).
    pub speed_mps: [f64; 2],
    /// Launch point, relative to the home palm centre: distance toward the thrower (+x),
    /// height, and sideways (y) ranges (m).
    pub launch_distance_m: [f64; 2],
    pub launch_height_m: [f64; 2],
    pub launch_side_m: [f64; 2],
    /// Largest absolute lateral offset (m) of the crossing point of the palm's horizontal plane
    /// from the palm centre, measured across the throw.
    pub max_lateral_offset_m: f64,
    /// Standard deviations of the initial posture perturbation (rad).
    pub arm_posture_std_rad: f64,
    pub hand_posture_std_rad: f64,
    /// Object mass range (kg).
    pub mass_kg: [f64; 2],
}

impl Default for ConditionSpec {
    fn default() -> Self {
        ConditionSpec {
            speed_mps: [2.8, 5.0],
            launch_distance_m: [0.9, 1.6],
            launch_height_m: [-0.1, 0.5],
            launch_side_m: [-0.3, 0.3],
            max_lateral_offset_m: 0.06,
            arm_posture_std_rad: 0.03,
            hand_posture_std_rad: 0.05,
            mass_kg: [0.04, 0.06],
        }
    }
}

/// One task condition ω.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TaskCondition {
    pub variant: ObjectVariant,
    pub mass_kg: f64,
    pub launch_pos_m: [f64; 3],
    pub launch_vel_mps: [f64; 3],
    /// Signed distance across the throw between the palm centre and the point where the object
    /// crosses the palm's horizontal plane (m); recorded for the figures.
    pub lateral_offset_m: f64,
    /// Flight time from launch to that crossing (s).
    pub crossing_time_secs: f64,
    pub arm_perturbation_rad: [f64; 7],
    pub hand_perturbation_rad: [f64; 17],
}

impl TaskCondition {
    pub fn speed_mps(&self) -> f64 {
        norm(self.launch_vel_mps)
    }
}

/// The launch velocity that takes a ballistic object from `from` to `to` in `t` seconds.
pub fn launch_velocity(from: [f64; 3], to: [f64; 3], t: f64) -> [f64; 3] {
    [
        (to[0] - from[0]) / t,
        (to[1] - from[1]) / t,
        (to[2] - from[2] + 0.5 * GRAVITY_MPS2 * t * t) / t,
    ]
}

/// The shortest flight time in which a throw at `speed` from `from` reaches `to`, if any. The
/// needed speed falls with flight time and then rises again (gravity), so the flat solution
/// lies before the minimum: find the minimum, then bisect on the falling side.
pub fn flat_flight_time(from: [f64; 3], to: [f64; 3], speed: f64) -> Option<f64> {
    let need = |t: f64| norm(launch_velocity(from, to, t));
    let (mut lo, mut hi) = (1e-3, 5.0);
    // Golden-section search for the minimum of the (unimodal) needed speed.
    let phi = 0.5 * (libm::sqrt(5.0) - 1.0);
    for _ in 0..100 {
        let a = hi - phi * (hi - lo);
        let b = lo + phi * (hi - lo);
        if need(a) < need(b) {
            hi = b;
        } else {
            lo = a;
        }
    }
    let t_min = 0.5 * (lo + hi);
    if need(t_min) > speed {
        return None;
    }
    let (mut a, mut b) = (1e-3, t_min);
    for _ in 0..100 {
        let m = 0.5 * (a + b);
        if need(m) > speed {
            a = m;
        } else {
            b = m;
        }
    }
    Some(0.5 * (a + b))
}

/// Draws ω from `rng`. `palm` is the home palm centre; `mass_kg` comes from the world.
pub fn sample(spec: &ConditionSpec, palm: [f64; 3], rng: &mut StreamRng) -> Result<TaskCondition> {
    let variants = ObjectVariant::all();
    let variant = variants[rng::below(rng, variants.len() as u64) as usize];
    let mass_kg = rng::uniform(rng, spec.mass_kg[0], spec.mass_kg[1]);
    let mut arm_perturbation_rad = [0.0; 7];
    for p in &mut arm_perturbation_rad {
        *p = spec.arm_posture_std_rad * rng::normal(rng);
    }
    let mut hand_perturbation_rad = [0.0; 17];
    for p in &mut hand_perturbation_rad {
        *p = spec.hand_posture_std_rad * rng::normal(rng);
    }
    const ATTEMPTS: u32 = 1000;
    for _ in 0..ATTEMPTS {
        let launch_pos_m = [
            palm[0] + rng::uniform(rng, spec.launch_distance_m[0], spec.launch_distance_m[1]),
            palm[1] + rng::uniform(rng, spec.launch_side_m[0], spec.launch_side_m[1]),
            palm[2] + rng::uniform(rng, spec.launch_height_m[0], spec.launch_height_m[1]),
        ];
        let offset = rng::uniform(rng, -spec.max_lateral_offset_m, spec.max_lateral_offset_m);
        let speed = rng::uniform(rng, spec.speed_mps[0], spec.speed_mps[1]);
        // The crossing point: the palm centre moved `offset` across the horizontal throw line.
        let (dx, dy) = (palm[0] - launch_pos_m[0], palm[1] - launch_pos_m[1]);
        let h = libm::sqrt(dx * dx + dy * dy);
        let across = [-dy / h, dx / h];
        let target = [
            palm[0] + offset * across[0],
            palm[1] + offset * across[1],
            palm[2],
        ];
        let Some(t) = flat_flight_time(launch_pos_m, target, speed) else {
            continue;
        };
        let launch_vel_mps = launch_velocity(launch_pos_m, target, t);
        // Catch descending objects only.
        if launch_vel_mps[2] - GRAVITY_MPS2 * t >= 0.0 {
            continue;
        }
        return Ok(TaskCondition {
            variant,
            mass_kg,
            launch_pos_m,
            launch_vel_mps,
            lateral_offset_m: offset,
            crossing_time_secs: t,
            arm_perturbation_rad,
            hand_perturbation_rad,
        });
    }
    Err(SimError::NoFeasibleLaunch { attempts: ATTEMPTS })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampled_throws_hit_their_target_at_their_speed_descending() {
        let spec = ConditionSpec::default();
        let palm = [0.58, 0.0, 0.93];
        let mut seen = std::collections::BTreeSet::new();
        for i in 0..300 {
            let mut r = rng::stream(0, "test", "omega", i);
            let w = sample(&spec, palm, &mut r).expect("feasible");
            seen.insert(w.variant);
            let s = w.speed_mps();
            assert!(
                (spec.speed_mps[0] - 1e-6..=spec.speed_mps[1] + 1e-6).contains(&s),
                "speed {s}"
            );
            // Independent check: integrate the closed-form parabola to the crossing time.
            let t = w.crossing_time_secs;
            let p: Vec<f64> = (0..3)
                .map(|k| {
                    w.launch_pos_m[k] + w.launch_vel_mps[k] * t
                        - if k == 2 {
                            0.5 * GRAVITY_MPS2 * t * t
                        } else {
                            0.0
                        }
                })
                .collect();
            assert!((p[2] - palm[2]).abs() < 1e-9, "crosses at z = {}", p[2]);
            let lateral = libm::sqrt((p[0] - palm[0]).powi(2) + (p[1] - palm[1]).powi(2));
            assert!((lateral - w.lateral_offset_m.abs()).abs() < 1e-9);
            assert!(w.lateral_offset_m.abs() <= spec.max_lateral_offset_m);
            assert!(w.launch_vel_mps[2] - GRAVITY_MPS2 * t < 0.0, "descending");
            assert!((spec.mass_kg[0]..spec.mass_kg[1]).contains(&w.mass_kg));
        }
        assert_eq!(seen.len(), 10, "all ten variants drawn");
    }

    #[test]
    fn sampling_is_reproducible_per_stream() {
        let spec = ConditionSpec::default();
        let draw = |i| {
            sample(
                &spec,
                [0.58, 0.0, 0.93],
                &mut rng::stream(3, "conditions", "omega", i),
            )
            .expect("ω")
        };
        assert_eq!(draw(5), draw(5));
        assert_ne!(draw(5), draw(6));
    }

    #[test]
    fn impossible_ranges_are_reported() {
        let spec = ConditionSpec {
            speed_mps: [0.5, 0.6],
            ..ConditionSpec::default()
        };
        let err = sample(&spec, [0.58, 0.0, 0.93], &mut rng::stream(0, "t", "x", 0))
            .expect_err("too slow");
        assert!(err.to_string().contains("no launch reaches the palm"));
    }
}
