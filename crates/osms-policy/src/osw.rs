//! The outcome-sensitive window (paper 3.2, 5.2): W_OS cut out of a rollout record, ζ_org,
//! and its conditioning ω̄ (ω's features, the DR draws, the privileged state at the window's
//! start).

use osms_sim::control::DrDraw;
use osms_sim::{N_ACTION, N_ARM, RolloutRecord, conditions::TaskCondition, spec::ObjectVariant};
use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// How the outcome-sensitive window is cut. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OswSpec {
    /// H_OS: control steps immediately before the event step k_e.
    pub h_os: usize,
}

impl Default for OswSpec {
    fn default() -> Self {
        OswSpec { h_os: 8 }
    }
}

/// Length of the task-condition features ω: object variant one-hot, mass, launch position and
/// velocity, lateral offset, crossing time, arm and hand posture perturbations.
pub const OMEGA_LEN: usize = 10 + 1 + 3 + 3 + 1 + 1 + 7 + 17;

/// ω as a feature vector (the order of [`OMEGA_LEN`]'s doc).
pub fn omega_features(c: &TaskCondition) -> Vec<f32> {
    let mut out = vec![0.0f32; ObjectVariant::all().len()];
    out[c.variant.index()] = 1.0;
    out.push(c.mass_kg as f32);
    out.extend(c.launch_pos_m.iter().map(|&v| v as f32));
    out.extend(c.launch_vel_mps.iter().map(|&v| v as f32));
    out.push(c.lateral_offset_m as f32);
    out.push(c.crossing_time_secs as f32);
    out.extend(c.arm_perturbation_rad.iter().map(|&v| v as f32));
    out.extend(c.hand_perturbation_rad.iter().map(|&v| v as f32));
    out
}

/// Length of the domain-randomisation features: a rollout's DR draws belong to its condition
/// (paper 3.1: ω specifies the environment parameters too).
pub const DR_FEATURES_LEN: usize = 5;

/// A rollout's DR draws as features: observation and actuation delay (control steps), gain,
/// friction and contact time-constant scales.
pub fn dr_features(dr: &DrDraw) -> [f32; DR_FEATURES_LEN] {
    [
        dr.observation_delay_steps as f32,
        dr.actuation_delay_steps as f32,
        dr.gain_scale as f32,
        dr.friction_scale as f32,
        dr.contact_timeconst_scale as f32,
    ]
}

/// A rollout aligned to its outcome-sensitive window W_OS = {k_e − H_OS, …, k_e − 1}.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OswWindow {
    /// k_e: the first object–robot contact's control step, or the closest approach's.
    pub event_step: usize,
    /// The window's first step, max(k_e − H_OS, 0).
    pub start: usize,
    /// Whether the window has all H_OS steps (k_e ≥ H_OS); search skips incomplete windows.
    pub complete: bool,
    /// ζ_org: the teacher's arm actions over the window, step-major (`[step][channel]`,
    /// N_ARM channels), k_e − start steps.
    pub zeta_org: Vec<f32>,
    /// ω̄: ω's features, the rollout's DR draws ([`dr_features`]), the privileged state at
    /// the window's first step and the arm's servo targets then ([`OMEGA_BAR_LEN`] values).
    pub omega_bar: Vec<f32>,
}

/// Length of ω̄: ω, the DR draws, a privileged frame and the arm's servo targets.
pub const OMEGA_BAR_LEN: usize =
    OMEGA_LEN + DR_FEATURES_LEN + osms_sim::policy::PRIVILEGED_LEN + N_ARM;

impl OswWindow {
    /// Cuts the window out of a record that kept its privileged frames. Fails if the record
    /// has none or is shorter than its event step says.
    pub fn extract(record: &RolloutRecord, spec: &OswSpec) -> Result<OswWindow> {
        let k_e = record.metrics.event_step;
        if k_e > record.steps {
            return Err(Error::EventPastEnd {
                event_step: k_e,
                steps: record.steps,
            });
        }
        if record.steps == 0 || record.privileged.is_empty() {
            return Err(Error::NoPrivilegedFrames);
        }
        let frame = record.privileged.len() / record.steps;
        let start = k_e.saturating_sub(spec.h_os);
        let mut zeta_org = Vec::with_capacity((k_e - start) * N_ARM);
        for k in start..k_e {
            zeta_org.extend_from_slice(&record.intended[k * N_ACTION..k * N_ACTION + N_ARM]);
        }
        // A contact at step 0 has no frame before it; ω̄ then uses the first frame.
        let at = start.min(record.steps - 1);
        let mut omega_bar = omega_features(&record.condition);
        omega_bar.extend(dr_features(&record.dr));
        omega_bar.extend_from_slice(&record.privileged[at * frame..(at + 1) * frame]);
        // Arm actions are target increments: without the targets they start from, one ζ would
        // stand for different motions.
        if record.arm_targets.len() != record.steps * N_ARM {
            return Err(Error::NoArmTargets);
        }
        omega_bar.extend_from_slice(&record.arm_targets[at * N_ARM..(at + 1) * N_ARM]);
        Ok(OswWindow {
            event_step: k_e,
            start,
            complete: k_e >= spec.h_os,
            zeta_org,
            omega_bar,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn condition() -> TaskCondition {
        TaskCondition {
            variant: ObjectVariant::all()[3],
            mass_kg: 0.05,
            launch_pos_m: [1.0, 2.0, 3.0],
            launch_vel_mps: [-3.0, 0.0, 1.0],
            lateral_offset_m: 0.01,
            crossing_time_secs: 0.6,
            arm_perturbation_rad: [0.0; 7],
            hand_perturbation_rad: [0.0; 17],
        }
    }

    /// A record whose intended action at step k, channel c is 100·k + c, whose privileged
    /// frame at step k is [k, k + 0.5] and whose arm target c at step k is −k − c.
    fn record(steps: usize, event_step: usize) -> RolloutRecord {
        let dr = DrDraw {
            observation_delay_steps: 1,
            actuation_delay_steps: 0,
            gain_scale: 1.05,
            friction_scale: 0.9,
            contact_timeconst_scale: 1.25,
        };
        let mut r = RolloutRecord::empty(condition(), dr);
        r.steps = steps;
        r.intended = (0..steps)
            .flat_map(|k| (0..N_ACTION).map(move |c| (100 * k + c) as f32))
            .collect();
        r.privileged = (0..steps)
            .flat_map(|k| [k as f32, k as f32 + 0.5])
            .collect();
        r.arm_targets = (0..steps)
            .flat_map(|k| (0..N_ARM).map(move |c| -((k + c) as f32)))
            .collect();
        r.metrics.event_step = event_step;
        r
    }

    #[test]
    fn window_holds_the_arm_actions_of_the_h_steps_before_the_event() {
        let w = OswWindow::extract(&record(30, 20), &OswSpec::default()).expect("window");
        assert!(w.complete);
        assert_eq!((w.start, w.event_step), (12, 20));
        assert_eq!(w.zeta_org.len(), 8 * N_ARM);
        for j in 0..8 {
            for c in 0..N_ARM {
                assert_eq!(w.zeta_org[j * N_ARM + c], (100 * (12 + j) + c) as f32);
            }
        }
        assert_eq!(w.omega_bar.len(), OMEGA_LEN + DR_FEATURES_LEN + 2 + N_ARM);
        assert_eq!(
            &w.omega_bar[OMEGA_LEN..OMEGA_LEN + DR_FEATURES_LEN],
            &[1.0, 0.0, 1.05, 0.9, 1.25],
            "DR draws"
        );
        let state = &w.omega_bar[OMEGA_LEN + DR_FEATURES_LEN..];
        assert_eq!(
            &state[..2],
            &[12.0, 12.5],
            "privileged frame at the window start"
        );
        assert_eq!(
            &state[2..],
            &[-12.0, -13.0, -14.0, -15.0, -16.0, -17.0, -18.0],
            "arm servo targets at the window start"
        );
        assert_eq!(w.omega_bar[3], 1.0, "variant one-hot");
        assert_eq!(&w.omega_bar[11..14], &[1.0, 2.0, 3.0], "launch position");
    }

    #[test]
    fn early_events_give_incomplete_windows_and_bad_records_are_errors() {
        let spec = OswSpec::default();
        let w = OswWindow::extract(&record(30, 8), &spec).expect("window");
        assert!(w.complete, "k_e = H_OS is exactly complete");
        let w = OswWindow::extract(&record(30, 5), &spec).expect("window");
        assert!(!w.complete);
        assert_eq!((w.start, w.zeta_org.len()), (0, 5 * N_ARM));
        let w = OswWindow::extract(&record(30, 0), &spec).expect("window");
        assert!(!w.complete && w.zeta_org.is_empty());
        assert_eq!(
            &w.omega_bar[OMEGA_LEN + DR_FEATURES_LEN..OMEGA_LEN + DR_FEATURES_LEN + 2],
            &[0.0, 0.5]
        );
        assert!(OswWindow::extract(&record(10, 11), &spec).is_err());
        let mut r = record(30, 20);
        r.privileged.clear();
        assert!(OswWindow::extract(&r, &spec).is_err());
        let mut r = record(30, 20);
        r.arm_targets.clear();
        assert!(OswWindow::extract(&r, &spec).is_err());
    }
}
