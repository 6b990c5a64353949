//! The interventional outcome sensitivity profile (paper Eq. 1, measured rather than assumed):
//! how much a small change of the arm's actions in an H-step window changes the rollout's
//! outcome, as a function of where the window sits relative to the event step k_e.
//!
//! For a D_R rollout and a window W = {k_e + o, …, k_e + o + H − 1}, the window's recorded arm
//! actions ζ_W are replaced open loop by clip(ζ_W + Δζ, −1, 1), Δζ uniform on the sphere of
//! radius `size` (Euclidean over the window's arm entries); the teacher keeps the hand inside
//! the window and everything outside it, and the snippet runs through contact (unlike the
//! event-aligned intervention, which hands back at contact). The rollout's own DR stream is
//! reused, so without Δζ the rollout is the recorded one and every change is the
//! intervention's. With ‖Δζ‖ the norm after clipping,
//!
//! d_Y = |I_succ(τ') − I_succ(τ)| + |f_max(τ') − f_max(τ)| / δ_f,
//! S_IOS(o) = mean over rollouts and draws of d_Y / ‖Δζ‖,
//!
//! with a normal-approximation 95 % interval. f_max is 0 for a rollout without contact.

use osms_core::rng::{self, StreamRng};
use osms_policy::Agent;
use osms_policy::artifacts::DemoRollout;
use osms_policy::catch::CatchTaskSpec;
use osms_sim::{N_ACTION, N_ARM, World};
use serde::{Deserialize, Serialize};

use crate::{Error, Result};

use crate::intervene::{Intervention, Snippet};

/// The profile's settings. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IosParams {
    /// D_R rollouts profiled (the first ones of the dataset).
    pub rollouts: usize,
    /// Window starts relative to k_e: first_offset, first_offset + stride, …, up to
    /// last_offset. The paper's OSW is the offset −H.
    pub first_offset: i64,
    pub last_offset: i64,
    pub stride: usize,
    /// H: the window's length in control steps (the paper's H_OS).
    pub window: usize,
    /// Random Δζ per rollout and offset.
    pub draws: usize,
    /// ‖Δζ‖ before clipping (action units; every channel spans [−1, 1]).
    pub size: f64,
}

impl Default for IosParams {
    fn default() -> Self {
        IosParams {
            rollouts: 100,
            first_offset: -40,
            last_offset: 8,
            stride: 4,
            window: 8,
            draws: 4,
            size: 0.5,
        }
    }
}

impl IosParams {
    pub fn check(&self) -> Result<()> {
        <Self as osms_core::check::Check>::check(self).map_err(Error::from)
    }

    pub fn offsets(&self) -> Vec<i64> {
        (self.first_offset..=self.last_offset)
            .step_by(self.stride)
            .collect()
    }
}

/// One intervention's effect.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IosSample {
    pub offset: i64,
    /// ‖Δζ‖ after clipping.
    pub norm: f64,
    pub success_changed: bool,
    /// f_max(τ') − f_max(τ) (N).
    pub force_change_n: f64,
}

/// One rollout's interventions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IosItem {
    pub item: u32,
    pub event_step: usize,
    pub success: bool,
    pub samples: Vec<IosSample>,
}

/// One offset's window start and its perturbed snippets with their ‖Δζ‖.
type Plan = (i64, usize, Vec<(Vec<f32>, f64)>);

/// Δζ uniform on the sphere of radius `size` in `len` dimensions.
fn direction(rng: &mut StreamRng, len: usize, size: f64) -> Vec<f64> {
    loop {
        let v: Vec<f64> = (0..len).map(|_| rng::normal(rng)).collect();
        let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if n > 1e-12 {
            return v.into_iter().map(|x| x * size / n).collect();
        }
    }
}

/// One D_R rollout's interventions at every offset of `p` (its Δζ drawn from `rng` in offset
/// order), each branched from the teacher's replay of the rollout under its own DR stream.
pub fn profile(
    world: &World,
    task: &CatchTaskSpec,
    agent: &Agent,
    r: &DemoRollout,
    p: &IosParams,
    rng: &mut StreamRng,
) -> Result<IosItem> {
    let rec = &r.record;
    let k_e = rec.metrics.event_step as i64;
    let success = rec.outcome.success();
    let f0 = rec.metrics.max_force_n;
    // Every Δζ first (in offset order), so the snippets outlive the branching rollout.
    let len = p.window * N_ARM;
    let mut plans: Vec<Plan> = Vec::new();
    for offset in p.offsets() {
        let start = k_e + offset;
        if start < 0 || (start as usize) + p.window > rec.steps {
            continue;
        }
        let start = start as usize;
        let original: Vec<f32> = (start..start + p.window)
            .flat_map(|k| {
                rec.intended[k * N_ACTION..k * N_ACTION + N_ARM]
                    .iter()
                    .copied()
            })
            .collect();
        let draws = (0..p.draws)
            .map(|_| {
                let delta = direction(rng, len, p.size);
                let zeta: Vec<f32> = original
                    .iter()
                    .zip(&delta)
                    .map(|(&z, d)| (f64::from(z) + d).clamp(-1.0, 1.0) as f32)
                    .collect();
                let norm = zeta
                    .iter()
                    .zip(&original)
                    .map(|(a, b)| (f64::from(*a) - f64::from(*b)).powi(2))
                    .sum::<f64>()
                    .sqrt();
                (zeta, norm)
            })
            .collect();
        plans.push((offset, start, draws));
    }
    let mut base = Intervention::new(world, task, rec.condition.clone(), r.dr_stream.rng(), None);
    base.through_contact();
    let mut samples = Vec::new();
    for (offset, start, draws) in &plans {
        base.run_until(agent, *start);
        let n = start * N_ACTION;
        if base.step_index() != *start || base.record().intended[..n] != rec.intended[..n] {
            return Err(Error::ReplayDiverged {
                item: r.item,
                until: format!("step {start} (of {} recorded)", rec.steps),
            });
        }
        let snapshot = base.snapshot();
        for (zeta, norm) in draws.iter().filter(|(_, n)| *n > 0.0) {
            base.restore(&snapshot);
            base.set_snippet(Some(Snippet {
                start: *start,
                zeta,
            }));
            base.run(agent);
            let (outcome, metrics) = base.outcome();
            samples.push(IosSample {
                offset: *offset,
                norm: *norm,
                success_changed: outcome.success() != success,
                force_change_n: metrics.max_force_n - f0,
            });
        }
        base.restore(&snapshot);
    }
    Ok(IosItem {
        item: r.item,
        event_step: rec.metrics.event_step,
        success,
        samples,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directions_have_the_requested_size() {
        let mut rng = rng::stream(0, "test", "ios", 0);
        for _ in 0..20 {
            let d = direction(&mut rng, 56, 0.5);
            let n = d.iter().map(|x| x * x).sum::<f64>().sqrt();
            assert!((n - 0.5).abs() < 1e-12, "{n}");
        }
    }
}
