//! A deployable estimate of the object's flight from the observed positions alone (issue 66):
//! what a deployed robot's perception can compute from its own camera stream, for the
//! `tracked` teacher rung, its prior and the students.
//!
//! The observed position is the state of d control steps ago plus noise, d the rollout's
//! observation delay; the delay line starts full of the first state, so the first d + 1
//! frames all show the object where it was released. The tracker reads d off that stall (the
//! first frame that has moved more than [`STILL_M`] from the first one is frame d + 1), dates
//! frame j at max(j − d, 0) control steps, fits a ballistic flight (gravity known) to the
//! newest [`TRACKER_WINDOW`] frames by least squares (a Kalman filter on the ballistic model
//! without process noise gives the same estimate) and extrapolates it by d steps to the
//! present. Until a frame has moved it reports the object at rest where it was seen.

use crate::conditions::GRAVITY_MPS2;

/// The object as a policy observes it: the state of `observation_delay_steps` control steps
/// ago, the position with the observation noise. Privileged policies read the object through
/// this, not through `data`, so the teacher's inputs carry the student's delay and noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObservedObject {
    pub pos: [f64; 3],
    pub vel: [f64; 3],
}

/// Frames the fit reads: the newest this many (a throw lasts 10–25 control steps before
/// contact, so this is the whole flight; after contact the estimate no longer describes a free
/// flight).
pub const TRACKER_WINDOW: usize = 32;

/// A frame that lies within this distance of the first one still shows the released object
/// (m): six standard deviations of the difference of two observations under the paper DR's
/// 5 mm noise per axis (docs/sim.md), while a throw (2.8–5 m/s) moves 5.6 cm or more per
/// control step.
pub const STILL_M: f64 = 0.03;

/// Leading frames longer than this are not read as a delay: an object at rest.
pub const MAX_DELAY_STEPS: usize = 4;

/// The observed positions of a rollout so far, as records keep them (f32), so that an
/// estimate from a rollout's record equals the one its policy saw.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FlightTracker {
    seen: Vec<[f64; 3]>,
}

impl FlightTracker {
    /// The observed position of the next frame.
    pub fn push(&mut self, observed: [f64; 3]) {
        self.seen.push(observed.map(|v| f64::from(v as f32)));
    }

    /// The estimate at the newest frame ([`track`]).
    pub fn estimate(&self, dt: f64) -> ObservedObject {
        track(&self.seen, dt)
    }
}

/// The observation delay the leading frames of `seen` show (see the module's doc), or `None`
/// while no frame has moved from the first.
pub fn stall(seen: &[[f64; 3]]) -> Option<usize> {
    stall_with(seen.len(), |j| seen[j])
}

fn stall_with(frames: usize, seen: impl Fn(usize) -> [f64; 3]) -> Option<usize> {
    if frames == 0 {
        return None;
    }
    let first = seen(0);
    (0..frames.min(MAX_DELAY_STEPS + 2))
        .find(|&j| distance(&seen(j), &first) > STILL_M)
        .map(|moved| moved - 1)
}

/// The object's position and velocity now, from the observed positions of frames 0 … k
/// (`seen`, oldest first, `dt` seconds apart): see the module's doc.
pub fn track(seen: &[[f64; 3]], dt: f64) -> ObservedObject {
    track_with(seen.len(), |j| seen[j], dt)
}

/// [`track`] over `frames` frames read through `seen(j)`, which is asked only for the leading
/// frames and the newest [`TRACKER_WINDOW`] (a record's frames need not be copied out).
pub fn track_with(frames: usize, seen: impl Fn(usize) -> [f64; 3], dt: f64) -> ObservedObject {
    if frames == 0 {
        return ObservedObject {
            pos: [0.0; 3],
            vel: [0.0; 3],
        };
    }
    let k = frames - 1;
    let delay = match stall_with(frames, &seen) {
        Some(d) => d,
        // Every frame still shows the released object, or an object that has stayed put for
        // longer than any delay.
        None if frames <= MAX_DELAY_STEPS + 1 => {
            let n = frames as f64;
            let mut mean = [0.0; 3];
            for j in 0..frames {
                let p = seen(j);
                for c in 0..3 {
                    mean[c] += p[c];
                }
            }
            return ObservedObject {
                pos: mean.map(|v| v / n),
                vel: [0.0; 3],
            };
        }
        None => 0,
    };
    let first = (k + 1).saturating_sub(TRACKER_WINDOW);
    // Frame j shows the state of max(j − d, 0) steps.
    let time = |j: usize| j.saturating_sub(delay) as f64 * dt;
    if time(first) == time(k) {
        return ObservedObject {
            pos: seen(k),
            vel: [0.0; 3],
        };
    }
    fit_ballistic((first..=k).map(|j| (time(j), seen(j))), k as f64 * dt)
}

/// The least-squares ballistic flight (gravity known) through `(time, position)` samples
/// (at least two distinct times), evaluated at `at`: position and velocity.
fn fit_ballistic(
    samples: impl Iterator<Item = (f64, [f64; 3])> + Clone,
    at: f64,
) -> ObservedObject {
    let (mut n, mut sum_t) = (0.0, 0.0);
    for (t, _) in samples.clone() {
        n += 1.0;
        sum_t += t;
    }
    let mean_t = sum_t / n;
    // Gravity is known: remove it, then the flight is a line in t.
    let lifted = |t: f64, p: [f64; 3]| [p[0], p[1], p[2] + 0.5 * GRAVITY_MPS2 * t * t];
    let mut mean_y = [0.0; 3];
    for (t, p) in samples.clone() {
        let y = lifted(t, p);
        for c in 0..3 {
            mean_y[c] += y[c];
        }
    }
    let mean_y = mean_y.map(|v| v / n);
    let (mut s_tt, mut s_ty) = (0.0, [0.0; 3]);
    for (t, p) in samples {
        let y = lifted(t, p);
        s_tt += (t - mean_t).powi(2);
        for c in 0..3 {
            s_ty[c] += (t - mean_t) * (y[c] - mean_y[c]);
        }
    }
    let mut pos = [0.0; 3];
    let mut vel = [0.0; 3];
    for c in 0..3 {
        let slope = s_ty[c] / s_tt;
        let line = mean_y[c] + slope * (at - mean_t);
        if c == 2 {
            pos[c] = line - 0.5 * GRAVITY_MPS2 * at * at;
            vel[c] = slope - GRAVITY_MPS2 * at;
        } else {
            pos[c] = line;
            vel[c] = slope;
        }
    }
    ObservedObject { pos, vel }
}

fn distance(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use osms_core::rng::{normal, stream};

    const DT: f64 = 0.02;

    /// The state at time t of a ballistic flight from `p0` with velocity `v0`.
    fn state(p0: [f64; 3], v0: [f64; 3], t: f64) -> ([f64; 3], [f64; 3]) {
        let mut p = std::array::from_fn(|c| p0[c] + v0[c] * t);
        let mut v = v0;
        p[2] -= 0.5 * GRAVITY_MPS2 * t * t;
        v[2] -= GRAVITY_MPS2 * t;
        (p, v)
    }

    /// What `frames` observations show under an observation delay of `delay` steps: frame j
    /// is the state at max(j − delay, 0) steps, plus `noise` (sd per axis).
    fn observe(
        frames: usize,
        delay: usize,
        noise: f64,
        seed: u64,
    ) -> (Vec<[f64; 3]>, [f64; 3], [f64; 3]) {
        let (p0, v0) = ([1.2, 0.1, 1.0], [-3.5, 0.2, 1.5]);
        let mut r = stream(seed, "test", "flight", 0);
        let seen = (0..frames)
            .map(|j| {
                let (p, _) = state(p0, v0, j.saturating_sub(delay) as f64 * DT);
                std::array::from_fn(|c| p[c] + noise * normal(&mut r))
            })
            .collect();
        (seen, p0, v0)
    }

    #[test]
    fn a_noiseless_flight_is_recovered_now_whatever_the_delay() {
        for delay in 0..=2 {
            for frames in delay + 2..delay + 12 {
                let (seen, p0, v0) = observe(frames, delay, 0.0, 1);
                assert_eq!(stall(&seen), Some(delay), "{frames} frames, delay {delay}");
                let got = track(&seen, DT);
                let (p, v) = state(p0, v0, (frames - 1) as f64 * DT);
                for c in 0..3 {
                    assert!(
                        (got.pos[c] - p[c]).abs() < 1e-9,
                        "delay {delay}, {frames} frames: pos {c}"
                    );
                    assert!(
                        (got.vel[c] - v[c]).abs() < 1e-7,
                        "delay {delay}, {frames} frames: vel {c}"
                    );
                }
            }
        }
    }

    #[test]
    fn before_the_object_moves_it_is_seen_at_rest() {
        let (seen, _, _) = observe(2, 1, 0.0, 1);
        assert_eq!(stall(&seen), None);
        let got = track(&seen, DT);
        assert_eq!(got.vel, [0.0; 3]);
        assert_eq!(got.pos, seen[0]);
        assert_eq!(track(&[], DT).vel, [0.0; 3]);
    }

    /// Under the paper DR's noise, the delay is read right on every one of many throws, and the
    /// estimate after ten frames is far closer to the present state than the newest
    /// observation is (which lags by the delay).
    #[test]
    fn under_noise_the_delay_is_read_and_the_estimate_beats_the_raw_observation() {
        let (mut est, mut raw) = (0.0, 0.0);
        for seed in 0..400 {
            let delay = (seed % 2) as usize;
            let (seen, p0, v0) = observe(11, delay, 0.005, seed);
            assert_eq!(stall(&seen), Some(delay), "seed {seed}");
            let (p, _) = state(p0, v0, 10.0 * DT);
            let got = track(&seen, DT);
            est += distance(&got.pos, &p);
            raw += distance(&seen[10], &p);
        }
        // The raw observation is off by the delay's 7.5 cm half the time plus the noise; the
        // fit by a few millimetres.
        assert!(est / 400.0 < 0.006, "estimate off by {} m", est / 400.0);
        assert!(
            raw / 400.0 > 0.03,
            "raw observation off by {} m",
            raw / 400.0
        );
    }

    #[test]
    fn the_tracker_rounds_as_records_do_and_estimates_from_what_it_kept() {
        let mut tracker = FlightTracker::default();
        let (seen, _, _) = observe(6, 0, 0.005, 3);
        for p in &seen {
            tracker.push(*p);
        }
        let rounded: Vec<[f64; 3]> = seen
            .iter()
            .map(|p| p.map(|v| f64::from(v as f32)))
            .collect();
        assert_eq!(tracker.estimate(DT), track(&rounded, DT));
    }
}
