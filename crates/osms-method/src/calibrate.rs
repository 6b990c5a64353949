//! Closed-loop calibration of the action-error model (issue 66): does the frozen teacher, run
//! under a fitted model of π̄'s errors (Eq. 7 on every channel of every step, as validation's
//! perturbed rollouts run), do what π̄ itself does on the same conditions? Table III compares
//! the model's open-loop moments with π̄'s; this compares outcomes (success, the failure kinds,
//! f_max, ℓ_max, v_rel) and the arm deviation as it occurs in closed loop.

use osms_core::rng::StreamRng;
use osms_policy::Agent;
use osms_policy::catch::CatchTaskSpec;
use osms_sim::artifacts::EvalRow;
use osms_sim::conditions::TaskCondition;
use osms_sim::{N_ACTION, N_ARM, Phase, World};
use serde::{Deserialize, Serialize};

use crate::error_model::{ErrorModel, N_PHASES, Perturber};
use crate::intervene::{Errors, execute};

/// Sums of one (phase, arm channel) cell of deviations x = a − ā: what its mean, standard
/// deviation and lag-1 correlation are computed from, additive over rollouts.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct CellSums {
    pub n: u64,
    pub sum: f64,
    pub sum_sq: f64,
    /// Consecutive steps of the same phase within one rollout.
    pub pairs: u64,
    /// Σ x_n x_{n−1} over the pairs.
    pub sum_lag: f64,
    /// Σ (x_n + x_{n−1}) over the pairs.
    pub sum_pair: f64,
}

/// The arm deviation's moments in one cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellMoments {
    pub mean: f64,
    /// Sample standard deviation (divisor n − 1).
    pub sd: f64,
    /// ρ₁ as Table III defines it: the mean over pairs of (x_n − m)(x_{n−1} − m) over the
    /// mean over steps of (x_n − m)², m the cell's mean (`None` without pairs or variance).
    pub lag1: Option<f64>,
}

impl CellSums {
    fn push(&mut self, x: f64, previous: Option<f64>) {
        self.n += 1;
        self.sum += x;
        self.sum_sq += x * x;
        if let Some(p) = previous {
            self.pairs += 1;
            self.sum_lag += x * p;
            self.sum_pair += x + p;
        }
    }

    fn add(&mut self, o: &CellSums) {
        self.n += o.n;
        self.sum += o.sum;
        self.sum_sq += o.sum_sq;
        self.pairs += o.pairs;
        self.sum_lag += o.sum_lag;
        self.sum_pair += o.sum_pair;
    }

    /// `None` with fewer than two steps.
    pub fn moments(&self) -> Option<CellMoments> {
        if self.n < 2 {
            return None;
        }
        let n = self.n as f64;
        let mean = self.sum / n;
        let centred = (self.sum_sq - n * mean * mean).max(0.0);
        let sd = (centred / (n - 1.0)).sqrt();
        let variance = centred / n;
        let lag1 = (self.pairs > 0 && variance > 1e-18).then(|| {
            let p = self.pairs as f64;
            (self.sum_lag - mean * self.sum_pair + p * mean * mean) / p / variance
        });
        Some(CellMoments { mean, sd, lag1 })
    }
}

/// Deviation sums of the arm channels per phase known online (the phase the previous step
/// ended in; approach at step 0), [`N_PHASES`] × [`N_ARM`] cells, phase-major.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DeviationStats {
    pub cells: Vec<CellSums>,
}

impl Default for DeviationStats {
    fn default() -> Self {
        DeviationStats {
            cells: vec![CellSums::default(); N_PHASES * N_ARM],
        }
    }
}

impl DeviationStats {
    /// One rollout's deviations: `actual` and `intended` hold 24 actions per step, `phase`
    /// the online phase of each step.
    pub fn push_rollout(&mut self, actual: &[f32], intended: &[f32], phase: &[u8]) {
        let steps = phase.len();
        debug_assert!(actual.len() >= steps * N_ACTION && intended.len() >= steps * N_ACTION);
        let x = |n: usize, k: usize| {
            f64::from(actual[n * N_ACTION + k]) - f64::from(intended[n * N_ACTION + k])
        };
        for n in 0..steps {
            let p = usize::from(phase[n]).min(N_PHASES - 1);
            let same = n > 0 && phase[n - 1] == phase[n];
            for k in 0..N_ARM {
                self.cells[p * N_ARM + k].push(x(n, k), same.then(|| x(n - 1, k)));
            }
        }
    }

    pub fn add(&mut self, other: &DeviationStats) {
        for (a, b) in self.cells.iter_mut().zip(&other.cells) {
            a.add(b);
        }
    }

    pub fn cell(&self, phase: usize, channel: usize) -> &CellSums {
        &self.cells[phase * N_ARM + channel]
    }

    /// Steps of a phase (the same for every channel).
    pub fn steps(&self, phase: usize) -> u64 {
        self.cell(phase, 0).n
    }

    /// Means over the arm channels of a phase's |mean|, sd and lag-1 correlation (`None`
    /// where no channel has them).
    pub fn phase_summary(&self, phase: usize) -> PhaseDeviation {
        let moments: Vec<CellMoments> = (0..N_ARM)
            .filter_map(|k| self.cell(phase, k).moments())
            .collect();
        let mean = |f: &dyn Fn(&CellMoments) -> Option<f64>| {
            let v: Vec<f64> = moments.iter().filter_map(f).collect();
            (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
        };
        PhaseDeviation {
            steps: self.steps(phase),
            abs_mean: mean(&|m| Some(m.mean.abs())),
            sd: mean(&|m| Some(m.sd)),
            lag1: mean(&|m| m.lag1),
        }
    }
}

/// A phase's arm deviation, averaged over the seven arm channels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhaseDeviation {
    pub steps: u64,
    pub abs_mean: Option<f64>,
    pub sd: Option<f64>,
    pub lag1: Option<f64>,
}

/// The online phase of each step of a record's phases: the phase the previous step ended in.
pub fn online_phases(recorded: &[u8]) -> Vec<u8> {
    std::iter::once(Phase::Approach as u8)
        .chain(recorded.iter().copied())
        .take(recorded.len())
        .collect()
}

/// The frozen teacher's rollout on ω under `model` on every channel of every step (Eq. 7 with
/// the model's κ; e₀ from the first phase's stationary distribution; innovations from
/// `noise`), its DR draws from `dr`: its row (without the impact trace) and its arm deviation
/// (executed command minus the teacher's intended action).
pub fn teacher_under(
    world: &World,
    task: &CatchTaskSpec,
    agent: &Agent,
    condition: TaskCondition,
    dr: StreamRng,
    model: &ErrorModel,
    noise: StreamRng,
) -> (EvalRow, DeviationStats) {
    let errors = Errors {
        perturber: Perturber::new(model),
        rng: noise,
    };
    let run = execute(world, task, agent, condition, dr, None, Some(errors));
    let mut stats = DeviationStats::default();
    stats.push_rollout(
        &run.commanded,
        &run.record.intended,
        &online_phases(&run.record.phase),
    );
    let mut row = EvalRow::of(run.record);
    row.trace = None;
    (row, stats)
}

/// The deviation scale at which a success rate that falls with the scale reaches `target`, by
/// linear interpolation between the two grid points around it (`grid`: (scale, success) in
/// increasing scale). Where the rate is not monotone, the first crossing from below the
/// smallest scale is taken; outside the grid's range, the nearer end.
pub fn interpolate_scale(grid: &[(f64, f64)], target: f64) -> Option<f64> {
    let (first, last) = (grid.first()?, grid.last()?);
    if target >= first.1 {
        return Some(first.0);
    }
    for w in grid.windows(2) {
        let ((c0, s0), (c1, s1)) = (w[0], w[1]);
        if s0 >= target && target >= s1 {
            if s0 == s1 {
                return Some(c0);
            }
            return Some(c0 + (c1 - c0) * (s0 - target) / (s0 - s1));
        }
    }
    Some(last.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_moments_match_a_direct_computation() {
        // Two runs of one phase: x = 1, 3, 2 then 4, 0.
        let runs: [&[f64]; 2] = [&[1.0, 3.0, 2.0], &[4.0, 0.0]];
        let mut c = CellSums::default();
        for run in runs {
            for (i, &x) in run.iter().enumerate() {
                c.push(x, (i > 0).then(|| run[i - 1]));
            }
        }
        let all: Vec<f64> = runs.concat();
        let m = all.iter().sum::<f64>() / 5.0;
        let var = all.iter().map(|x| (x - m).powi(2)).sum::<f64>();
        let pairs = [(3.0, 1.0), (2.0, 3.0), (0.0, 4.0)];
        let lag = pairs.iter().map(|(a, b)| (a - m) * (b - m)).sum::<f64>() / 3.0;
        let got = c.moments().expect("moments");
        assert!((got.mean - m).abs() < 1e-12);
        assert!((got.sd - (var / 4.0).sqrt()).abs() < 1e-12);
        assert!((got.lag1.expect("lag1") - lag / (var / 5.0)).abs() < 1e-12);
        // Adding two halves equals pushing everything into one.
        let mut a = CellSums::default();
        a.push(1.0, None);
        a.push(3.0, Some(1.0));
        let mut b = CellSums::default();
        b.push(2.0, Some(3.0));
        b.push(4.0, None);
        b.push(0.0, Some(4.0));
        a.add(&b);
        assert_eq!(a, c);
    }

    #[test]
    fn deviations_go_to_their_online_phase_and_pairs_stay_within_a_phase() {
        let steps = 4;
        let intended = vec![0.0f32; steps * N_ACTION];
        let mut actual = vec![0.0f32; steps * N_ACTION];
        for n in 0..steps {
            actual[n * N_ACTION] = n as f32 + 1.0;
        }
        let recorded = [0u8, 1, 1, 3];
        let phase = online_phases(&recorded);
        assert_eq!(phase, vec![0, 0, 1, 1]);
        let mut s = DeviationStats::default();
        s.push_rollout(&actual, &intended, &phase);
        let approach = s.cell(0, 0);
        assert_eq!((approach.n, approach.sum, approach.pairs), (2, 3.0, 1));
        let matching = s.cell(1, 0);
        assert_eq!((matching.n, matching.sum, matching.pairs), (2, 7.0, 1));
        assert_eq!(matching.sum_lag, 12.0);
        assert_eq!(s.steps(3), 0);
        assert_eq!(s.cell(1, 1).sum, 0.0);
    }

    #[test]
    fn the_scale_is_interpolated_where_the_rate_crosses_the_target() {
        let grid = [(0.0, 0.9), (0.5, 0.7), (1.0, 0.3)];
        assert_eq!(interpolate_scale(&grid, 0.95), Some(0.0));
        assert_eq!(interpolate_scale(&grid, 0.1), Some(1.0));
        let c = interpolate_scale(&grid, 0.5).expect("scale");
        assert!((c - 0.75).abs() < 1e-12, "{c}");
        let c = interpolate_scale(&grid, 0.8).expect("scale");
        assert!((c - 0.25).abs() < 1e-12, "{c}");
        assert_eq!(interpolate_scale(&[], 0.5), None);
    }
}
