//! The scripted privileged catcher: the prior the PPO teacher builds on. It predicts the
//! object's ballistic flight, picks the flight point closest to where the object's centre rests
//! on the palm at home, moves the palm under it (upward-facing, as at home) with
//! damped-least-squares IK on MuJoCo's site Jacobian, closes the fingers when the object
//! arrives and then holds the arm. The wrist's servo tower, which stands above the palm's base,
//! stops an object sliding across the palm. It makes no attempt to soften the impact: that is
//! what the teacher has to learn. It reads the object through the rollout's observation delay
//! and noise ([`crate::episode::ObservedObject`]); the contact count it closes on is exact.

use serde::{Deserialize, Serialize};

use crate::conditions::GRAVITY_MPS2;
use crate::control::{Action, ControlSpec, N_ACTION, N_ARM, N_HAND, hold_action};
use crate::episode::ObservedObject;
use crate::policy::{OBSERVED_OBJECT, Policy, PolicyView};
use crate::spec::ObjectVariant;
use crate::vec3::{cross, norm, sub, unit};
use crate::world::palm_normal;

/// The catcher's params. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CatcherSpec {
    /// Damping λ of the damped-least-squares IK.
    pub ik_damping: f64,
    /// Fraction of the palm pose error corrected per control step. 0.25: the lighter, less
    /// damped arm overshoots at 0.5 under a one-step actuation delay (catch completion under
    /// the paper's DR on the development stream: 61.0 % at 0.5, 71.6 % at 0.4, 80.0 % at 0.25,
    /// 80.2 % at 0.2; docs/sim.md).
    pub gain: f64,
    /// Largest palm position error acted on per step (m), so far targets do not saturate.
    pub max_step_error_m: f64,
    /// Close the fingers once the object is this close to the palm centre (m).
    pub close_distance_m: f64,
    /// Finger posture while waiting (rad, hand joint order).
    pub open_hand_rad: [f64; N_HAND],
    /// Finger posture when closing (rad).
    pub closed_hand_rad: [f64; N_HAND],
    /// Once closing, each hand joint's target (the wrist's too) leads the joint toward
    /// `closed_hand_rad` by at most this much (rad), so a finger stopped by the object pushes
    /// with at most kp × margin. Without a margin (`None`; in a pipeline, any margin wider
    /// than the hand's joint ranges, e.g. 4) the targets jump to the closed posture and the
    /// fingers close onto the object with the servos' full force: the squeeze's onset, ≈ 0.2 s
    /// after contact, was what exceeded f_max's δ_f = 80 N in most of the teacher's force
    /// failures. 0.1: over three teacher seeds on the development stream, f_max failures fall
    /// from 103 to 65 of 1,500 and the success stays (docs/policy.md, "Where f_max comes
    /// from").
    pub grip_margin_rad: Option<f64>,
    /// Horizon of the interception search (s).
    pub horizon_secs: f64,
    /// How far the palm turns from its home orientation toward facing the incoming object
    /// (0: keep the home orientation, 1: face the object).
    pub facing_blend: f64,
    /// Meet the object this far from the palm centre toward the fingertips (m): it lands on the
    /// palm rather than on the wrist's tower, then slides back against the tower.
    pub aim_toward_fingers_m: f64,
}

impl Default for CatcherSpec {
    fn default() -> Self {
        CatcherSpec {
            ik_damping: 0.1,
            gain: 0.25,
            max_step_error_m: 0.05,
            close_distance_m: 0.07,
            open_hand_rad: [
                0.0, 0.0, 0.4, 0.0, 0.0, 0.0, 0.1, 0.1, 0.0, 0.1, 0.1, 0.0, 0.1, 0.1, 0.0, 0.1, 0.1,
            ],
            // Fully flexed fingers and an opposed thumb: the servos squeeze with all the force
            // their position error allows.
            closed_hand_rad: [
                0.0, 0.5, 0.95, 1.7, 1.8, 0.0, 1.74, 1.86, 0.0, 1.74, 1.86, 0.0, 1.74, 1.86, 0.0,
                1.74, 1.86,
            ],
            grip_margin_rad: Some(0.1),
            horizon_secs: 1.0,
            facing_blend: 0.15,
            aim_toward_fingers_m: 0.01,
        }
    }
}

impl CatcherSpec {
    /// Checks what serde cannot.
    pub fn validate(&self) -> Result<(), crate::SimError> {
        if let Some(m) = self.grip_margin_rad
            && !(m > 0.0 && m.is_finite())
        {
            return Err(crate::SimError::Params(format!(
                "catcher.grip_margin_rad = {m}: must be a positive angle (rad), or absent for \
                 targets that jump to the closed posture"
            )));
        }
        Ok(())
    }
}

/// What the catcher reads of the world (issue 54's realisable teacher). The default is the
/// privileged catcher: the observed object's delayed velocity, ω's object radius and the
/// simulator's contact count. Each switch replaces one of them with what a deployed robot can
/// know, so a teacher built on the catcher acts on what its students see.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Perception {
    /// Aim with the mean radius of the object variants ([`nominal_radius_m`]) instead of ω's.
    pub nominal_radius: bool,
    /// Read the object's position and velocity from a least-squares ballistic fit to the
    /// observed positions of the newest this many frames of the history
    /// ([`estimate_object`]) instead of the observed (delayed, exact) velocity. A fixed window,
    /// so the catcher reads the same whatever history a rollout keeps.
    pub estimated_object: Option<usize>,
    /// Close the hand on the observed object's distance to the palm only, not on the
    /// simulator's contact count.
    pub close_on_distance_only: bool,
    /// Hold the arm still for the episode's first this many control steps, while a fitted
    /// flight still rests on one or two observations.
    pub hold_steps: usize,
    /// Read the object from the delay-aware flight estimate over every observation so far
    /// ([`crate::flight`], [`PolicyView::tracked`]) instead of `estimated_object`'s window.
    pub tracked: bool,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ScriptedCatcher {
    spec: CatcherSpec,
    control: ControlSpec,
    perception: Perception,
    closed: bool,
    /// The direction of flight when the hand began to close (unit vector), as the catcher saw
    /// it: a deployable stand-in for the first contact's incoming direction.
    closing_direction: Option<[f64; 3]>,
}

impl ScriptedCatcher {
    pub fn new(spec: CatcherSpec, control: ControlSpec) -> Self {
        Self::with_perception(spec, control, Perception::default())
    }

    pub fn with_perception(
        spec: CatcherSpec,
        control: ControlSpec,
        perception: Perception,
    ) -> Self {
        ScriptedCatcher {
            spec,
            control,
            perception,
            closed: false,
            closing_direction: None,
        }
    }

    /// How the catcher's increments become servo targets.
    pub fn control(&self) -> &ControlSpec {
        &self.control
    }

    /// The direction a follow-through moves the palm along: the pre-contact incoming
    /// direction that ℓ_max is measured along once there has been a contact (frozen with the
    /// first contact); for a catcher that does not read contacts, the direction of flight it
    /// saw when it began to close. Before either, the direction of flight as it reads it.
    pub fn follow_through_direction(&self, view: &PolicyView<'_>) -> [f64; 3] {
        let frozen = if self.perception.close_on_distance_only {
            self.closing_direction
        } else {
            view.first_contact.map(|c| c.incoming_dir)
        };
        frozen.unwrap_or_else(|| unit(self.object(view).vel))
    }

    /// The object as this catcher reads it at `view`.
    pub fn object(&self, view: &PolicyView<'_>) -> ObservedObject {
        if self.perception.tracked {
            return view.tracked();
        }
        let Some(window) = self.perception.estimated_object else {
            return view.object;
        };
        let frames: Vec<&[f64]> = view
            .history
            .range(fit_range(view.step, view.history.len(), window))
            .map(Vec::as_slice)
            .collect();
        estimate_object(&frames, view.world.control_period_secs())
    }
}

/// The frames a ballistic fit over `window` frames reads at control step `step`, as a range of
/// the `available` newest frames at hand (the last of them is step `step`'s): the newest
/// `window`, less the episode's first frame while it is among them. Under an observation delay
/// of d steps the first observation is seen d + 1 times (the delay line starts full of the
/// first state), which a fit would read as an object at rest. The students' fit input reads
/// the same frames of their record ([`estimate_object`]).
pub fn fit_range(step: usize, available: usize, window: usize) -> std::ops::Range<usize> {
    let n = window.min(available);
    let first_in_window = step < n && n > 2;
    available - n + usize::from(first_in_window)..available
}

/// The mean radius (first size) of the object variants: the radius a catcher that cannot tell
/// the objects apart aims with.
pub fn nominal_radius_m() -> f64 {
    let all = ObjectVariant::all();
    all.iter().map(|v| v.geom().1[0]).sum::<f64>() / all.len() as f64
}

/// The object's position and velocity at the newest of `history`'s frames (deployable frames,
/// oldest first, `dt` seconds apart), from a least-squares fit of a ballistic flight (gravity
/// known) to the observed positions: what a deployed robot can compute from its own
/// observations. The velocity's error falls with the number of frames (8 frames at 5 mm of
/// noise and 50 Hz: about 4 cm/s against 35 cm/s for one difference). With one frame the
/// velocity is 0.
pub fn estimate_object(history: &[&[f64]], dt: f64) -> ObservedObject {
    let n = history.len();
    let newest = n.saturating_sub(1);
    let t = |k: usize| (k as f64 - newest as f64) * dt;
    let mean_t = (0..n).map(t).sum::<f64>() / n.max(1) as f64;
    let s_tt: f64 = (0..n).map(|k| (t(k) - mean_t).powi(2)).sum();
    let mut pos = [0.0; 3];
    let mut vel = [0.0; 3];
    for c in 0..3 {
        // Gravity is known: remove it, then the flight is a line in t.
        let y = |k: usize| {
            let p = history[k][OBSERVED_OBJECT + c];
            if c == 2 {
                p + 0.5 * GRAVITY_MPS2 * t(k) * t(k)
            } else {
                p
            }
        };
        let mean_y = (0..n).map(y).sum::<f64>() / n.max(1) as f64;
        let slope = if s_tt > 0.0 {
            (0..n)
                .map(|k| (t(k) - mean_t) * (y(k) - mean_y))
                .sum::<f64>()
                / s_tt
        } else {
            0.0
        };
        vel[c] = slope;
        pos[c] = mean_y - slope * mean_t;
    }
    ObservedObject { pos, vel }
}

/// Solves `a x = b` for a small dense system by Gaussian elimination with partial pivoting
/// (fixed operation order, so the result is the same on every machine).
fn solve<const N: usize>(mut a: [[f64; N]; N], mut b: [f64; N]) -> [f64; N] {
    for col in 0..N {
        let pivot = (col..N)
            .max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))
            .unwrap_or(col);
        a.swap(col, pivot);
        b.swap(col, pivot);
        let d = a[col][col];
        if d.abs() < 1e-300 {
            continue;
        }
        let pivot_row = a[col];
        for row in col + 1..N {
            let f = a[row][col] / d;
            for (x, p) in a[row][col..].iter_mut().zip(&pivot_row[col..]) {
                *x -= f * p;
            }
            b[row] -= f * b[col];
        }
    }
    let mut x = [0.0; N];
    for row in (0..N).rev() {
        let mut s = b[row];
        for k in row + 1..N {
            s -= a[row][k] * x[k];
        }
        x[row] = if a[row][row].abs() < 1e-300 {
            0.0
        } else {
            s / a[row][row]
        };
    }
    x
}

/// Damped least squares: dq = Jᵀ (J Jᵀ + λ² I)⁻¹ e for a 6 × 7 Jacobian.
pub fn dls_step(jac: &[[f64; N_ARM]; 6], err: [f64; 6], damping: f64) -> [f64; N_ARM] {
    let mut jjt = [[0.0; 6]; 6];
    for (r, row) in jjt.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = (0..N_ARM).map(|k| jac[r][k] * jac[c][k]).sum::<f64>()
                + if r == c { damping * damping } else { 0.0 };
        }
    }
    let y = solve(jjt, err);
    std::array::from_fn(|k| (0..6).map(|r| jac[r][k] * y[r]).sum())
}

/// Damping of the damped-least-squares solve behind a follow-through (the teacher's
/// follow-through channel and [`crate::reach::FollowThroughProbe`]).
pub const PALM_MOTION_DAMPING: f64 = 0.05;

/// Arm action channels that move the palm along the unit vector `dir`, scaled so that the
/// largest channel has magnitude 1 (the fastest such motion one control step allows). The
/// angular rows of the Jacobian are weighted by `orientation_weight`: 1 holds the palm's
/// orientation as firmly as its position, smaller weights let it turn to gain speed.
pub fn palm_motion_channels(
    view: &PolicyView<'_>,
    dir: [f64; 3],
    orientation_weight: f64,
    damping: f64,
) -> [f64; N_ARM] {
    let mut jac = view.palm_jacobian;
    for row in &mut jac[3..] {
        for x in row.iter_mut() {
            *x *= orientation_weight;
        }
    }
    let dq = dls_step(&jac, [dir[0], dir[1], dir[2], 0.0, 0.0, 0.0], damping);
    let largest = dq.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if largest < 1e-12 {
        return [0.0; N_ARM];
    }
    dq.map(|x| x / largest)
}

impl Policy for ScriptedCatcher {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        let mut action = self.act_increments(view);
        view.arm_from_increments(&self.control, &mut action);
        action
    }

    /// It reads the privileged contact count, never the force.
    fn reads_contact_force(&self) -> bool {
        false
    }
}

impl ScriptedCatcher {
    /// The catcher's action with its arm channels as increments of the commanded targets,
    /// whatever the world's arm ([`PolicyView::arm_from_increments`] turns them into the
    /// world's): the form the residual teacher adds its residuals to.
    pub fn act_increments(&mut self, view: &PolicyView<'_>) -> Action {
        let data = view.data;
        let ids = &view.world.ids;
        // The object as observed (delayed, noisy), as the student sees it; the robot is exact.
        let object = self.object(view);
        let (p, v) = (object.pos, object.vel);
        let palm = data.site_xpos()[ids.palm_site];
        let normal = palm_normal(&data.site_xmat()[ids.palm_site]);

        // The desired palm normal: home, turned by `facing_blend` toward the incoming object.
        let home_normal = view.world.home_palm_normal;
        let radius = if self.perception.nominal_radius {
            nominal_radius_m()
        } else {
            view.condition.variant.geom().1[0]
        };
        // Interception: the predicted flight point closest to where the object's centre is when
        // it rests on the palm at home.
        let home = view.world.home_palm_pos;
        let fingers = {
            let m = data.site_xmat()[ids.palm_site];
            [m[2], m[5], m[8]]
        };
        let a = self.spec.aim_toward_fingers_m;
        let aim: [f64; 3] =
            std::array::from_fn(|k| home[k] + radius * home_normal[k] + a * fingers[k]);
        let at = |t: f64| {
            [
                p[0] + v[0] * t,
                p[1] + v[1] * t,
                p[2] + v[2] * t - 0.5 * GRAVITY_MPS2 * t * t,
            ]
        };
        let dt = 0.005;
        let steps = (self.spec.horizon_secs / dt) as usize;
        let t_star = (0..=steps)
            .map(|i| {
                let t = i as f64 * dt;
                (t, norm(sub(at(t), aim)))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(0.0, |(t, _)| t);
        let meet = at(t_star);
        let v_meet = [v[0], v[1], v[2] - GRAVITY_MPS2 * t_star];
        let speed = norm(v_meet).max(1e-9);
        let facing = [-v_meet[0] / speed, -v_meet[1] / speed, -v_meet[2] / speed];
        let b = self.spec.facing_blend;
        let blend: [f64; 3] = std::array::from_fn(|k| (1.0 - b) * home_normal[k] + b * facing[k]);
        let bn = norm(blend).max(1e-9);
        let want_normal = [blend[0] / bn, blend[1] / bn, blend[2] / bn];
        // The palm sits one radius behind the object's centre along its normal.
        let want: [f64; 3] =
            std::array::from_fn(|k| meet[k] - radius * want_normal[k] - a * fingers[k]);

        let mut e_pos = sub(want, palm);
        let size = norm(e_pos);
        if size > self.spec.max_step_error_m {
            let s = self.spec.max_step_error_m / size;
            e_pos = [e_pos[0] * s, e_pos[1] * s, e_pos[2] * s];
        }
        let e_rot = cross(normal, want_normal);
        let g = self.spec.gain;
        let err = [
            g * e_pos[0],
            g * e_pos[1],
            g * e_pos[2],
            g * e_rot[0],
            g * e_rot[1],
            g * e_rot[2],
        ];
        let dq = dls_step(&view.palm_jacobian, err, self.spec.ik_damping);

        let dist = norm(sub(p, palm));
        let touching = !self.perception.close_on_distance_only
            && view
                .privileged
                .get(crate::policy::PRIVILEGED_CONTACT_COUNT)
                .is_some_and(|n| *n > 0.0);
        if !self.closed && (dist < self.spec.close_distance_m || touching) {
            self.closed = true;
            self.closing_direction = Some(unit(v));
        }
        let hand = match (self.closed, self.spec.grip_margin_rad) {
            (false, _) => self.spec.open_hand_rad,
            (true, None) => self.spec.closed_hand_rad,
            (true, Some(m)) => {
                let q = data.qpos();
                std::array::from_fn(|i| {
                    let at = q[ids.hand_qpos[i]];
                    at + (self.spec.closed_hand_rad[i] - at).clamp(-m, m)
                })
            }
        };
        let mut action = hold_action(&hand);
        // Once closing, the arm holds still: re-aiming at the object's predicted fall would
        // pull the palm out from under it.
        if !self.closed && view.step >= self.perception.hold_steps {
            let max = self.control.arm_max_delta_rad;
            for k in 0..N_ARM {
                action[k] = (dq[k] / max).clamp(-1.0, 1.0);
            }
        }
        debug_assert_eq!(action.len(), N_ACTION);
        action
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames of a noiseless ballistic flight, `dt` apart, ending at `p` with velocity `v`.
    fn flight(n: usize, dt: f64, p: [f64; 3], v: [f64; 3]) -> Vec<Vec<f64>> {
        (0..n)
            .map(|k| {
                let t = (k as f64 - (n - 1) as f64) * dt;
                let mut frame = vec![0.0; OBSERVED_OBJECT + 3];
                for c in 0..3 {
                    let g = if c == 2 {
                        -0.5 * GRAVITY_MPS2 * t * t
                    } else {
                        0.0
                    };
                    frame[OBSERVED_OBJECT + c] = p[c] + v[c] * t + g;
                }
                frame
            })
            .collect()
    }

    fn frames(v: &[Vec<f64>]) -> Vec<&[f64]> {
        v.iter().map(Vec::as_slice).collect()
    }

    #[test]
    fn the_ballistic_fit_recovers_a_noiseless_flight_exactly() {
        let (p, v) = ([0.4, -0.1, 1.2], [-3.5, 0.6, 1.1]);
        for n in [2, 3, 8] {
            let got = estimate_object(&frames(&flight(n, 0.02, p, v)), 0.02);
            for c in 0..3 {
                assert!((got.pos[c] - p[c]).abs() < 1e-12, "{n} frames: pos {c}");
                assert!((got.vel[c] - v[c]).abs() < 1e-9, "{n} frames: vel {c}");
            }
        }
        let one = estimate_object(&frames(&flight(1, 0.02, p, v)), 0.02);
        assert_eq!(one.vel, [0.0; 3]);
        for (got, want) in one.pos.iter().zip(p) {
            assert!((got - want).abs() < 1e-12);
        }
    }

    /// Under independent position noise of sd σ the fitted velocity's sd is σ / (dt · √S_tt),
    /// S_tt the spread of the frame times: the least-squares slope's.
    #[test]
    fn the_ballistic_fits_velocity_error_is_the_least_squares_slopes() {
        let (n, dt, sigma) = (8usize, 0.02, 0.005);
        let mut r = osms_core::rng::stream(1, "test", "fit", 0);
        let draws = 4000;
        let mut sum_sq = 0.0;
        for _ in 0..draws {
            let mut flown = flight(n, dt, [0.0; 3], [1.0, 0.0, 0.0]);
            for f in &mut flown {
                f[OBSERVED_OBJECT] += sigma * osms_core::rng::normal(&mut r);
            }
            sum_sq += (estimate_object(&frames(&flown), dt).vel[0] - 1.0).powi(2);
        }
        let sd = (sum_sq / draws as f64).sqrt();
        let mean_t = -(n as f64 - 1.0) / 2.0 * dt;
        let s_tt: f64 = (0..n)
            .map(|k| ((k as f64 - (n - 1) as f64) * dt - mean_t).powi(2))
            .sum();
        let expected = sigma / s_tt.sqrt();
        // 4,000 draws: the sample sd is within about 2.2 % of the truth (1.96 · 1/√(2·4000)),
        // allowed 5 %.
        assert!(
            (sd / expected - 1.0).abs() < 0.05,
            "sd {sd} against {expected}"
        );
    }

    #[test]
    fn the_nominal_radius_is_the_variants_mean() {
        let r = nominal_radius_m();
        let all = ObjectVariant::all();
        let (lo, hi) = all
            .iter()
            .map(|v| v.geom().1[0])
            .fold((1.0f64, 0.0f64), |(lo, hi), x| (lo.min(x), hi.max(x)));
        assert!(lo < r && r < hi, "{lo} < {r} < {hi}");
    }

    #[test]
    fn dls_reduces_to_the_pseudo_inverse_for_an_invertible_square_block() {
        // J = [I6 | 0]: any e maps to dq = e / (1 + λ²) on the first six joints.
        let mut jac = [[0.0; N_ARM]; 6];
        for (i, row) in jac.iter_mut().enumerate() {
            row[i] = 1.0;
        }
        let e = [1.0, -2.0, 0.5, 0.0, 3.0, -1.0];
        let dq = dls_step(&jac, e, 0.1);
        for i in 0..6 {
            assert!((dq[i] - e[i] / 1.01).abs() < 1e-12);
        }
        assert_eq!(dq[6], 0.0);
    }

    #[test]
    fn solve_matches_a_known_system() {
        let a = [[4.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 4.0]];
        let x = [1.0, 2.0, 3.0];
        let b = std::array::from_fn(|r| (0..3).map(|c| a[r][c] * x[c]).sum());
        let got = solve(a, b);
        for i in 0..3 {
            assert!((got[i] - x[i]).abs() < 1e-12);
        }
    }
}
