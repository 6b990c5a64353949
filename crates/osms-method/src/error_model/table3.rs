//! Table III's metrics: a model's simulated deviations against the observed ones, per phase
//! and channel.

// The numerics index several parallel row-major arrays by the same channel index; iterator
// zips would obscure the formulas.
#![allow(clippy::needless_range_loop)]

use osms_core::rng::StreamRng;
use serde::{Deserialize, Serialize};

use super::fit::check_sequences;
use super::model::*;
use super::perturb::Perturber;

/// Table III metrics: simulate the model's deviations ã − ā (before κ and clipping, i.e. with
/// κ = 1 and no clip) on the recorded teacher sequences (phases as recorded, fresh ν from
/// `rng`) and compare with the observed deviations a − ā, per phase and channel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Table3Metrics {
    /// mean over (phase, channel) of (|m_sim − m_obs| + |s_sim − s_obs|) / s_obs  (s = std;
    /// skip cells with s_obs < 1e-9 or < 2 samples)
    pub moment_error: f64,
    /// mean over (phase, channel) of |ρ1_sim − ρ1_obs|, ρ1 = lag-1 autocorrelation of the
    /// deviation within runs of consecutive steps of that phase
    pub lag1_error: f64,
    /// (phase, channel) cells averaged in `moment_error`; 0 means the metric is 0 by default.
    pub moment_cells: usize,
    /// (phase, channel) cells averaged in `lag1_error` (cells with consecutive same-phase
    /// pairs and s_obs ≥ 1e-9).
    pub lag1_cells: usize,
}

/// Computes [`Table3Metrics`]. Each sequence gets a fresh rollout state (e drawn from the
/// stationary distribution at its first step); sequences consume `rng` in order.
///
/// ρ1 of a cell is the mean lag-1 product over consecutive same-phase pairs divided by the
/// variance over all the phase's steps (both about the phase mean), so many short runs do not
/// bias it towards zero. A simulated deviation with no variance (Unperturbed) has ρ1 = 0.
///
/// # Panics
/// If the model fails [`ErrorModel::validate`], or a sequence's lengths or phases do not match
/// the model (checked as in [`fit`](super::fit)).
pub fn table3_metrics(
    model: &ErrorModel,
    sequences: &[PairSequence<'_>],
    rng: &mut StreamRng,
) -> Table3Metrics {
    let c = model.channels;
    if let Err(e) = check_sequences(sequences, c) {
        panic!("{e}");
    }
    let mut perturber = Perturber::new(model);
    let mut observed = Vec::with_capacity(sequences.len());
    let mut simulated = Vec::with_capacity(sequences.len());
    let mut intended = vec![0.0; c];
    for s in sequences {
        perturber.reset();
        let mut obs = Vec::with_capacity(s.student.len());
        let mut sim = Vec::with_capacity(s.student.len());
        for n in 0..s.steps() {
            for k in 0..c {
                intended[k] = f64::from(s.teacher[n * c + k]);
                obs.push(f64::from(s.student[n * c + k]) - intended[k]);
            }
            let modeled = perturber.step_modeled(&intended, s.phase[n], rng);
            sim.extend(modeled.iter().zip(&intended).map(|(m, a)| m - a));
        }
        observed.push(obs);
        simulated.push(sim);
    }
    let obs = cell_stats(&observed, sequences, c);
    let sim = cell_stats(&simulated, sequences, c);

    let (mut moment_sum, mut moment_cells) = (0.0, 0usize);
    let (mut lag_sum, mut lag1_cells) = (0.0, 0usize);
    for phase in 0..N_PHASES {
        if obs.count[phase] < 2 {
            continue;
        }
        for k in 0..c {
            let i = phase * c + k;
            let s_obs = obs.std[i];
            if s_obs.is_nan() || s_obs < 1e-9 {
                continue;
            }
            moment_sum += ((sim.mean[i] - obs.mean[i]).abs() + (sim.std[i] - s_obs).abs()) / s_obs;
            moment_cells += 1;
            if let Some(rho_obs) = obs.rho1[i] {
                lag_sum += (sim.rho1[i].unwrap_or(0.0) - rho_obs).abs();
                lag1_cells += 1;
            }
        }
    }
    Table3Metrics {
        moment_error: if moment_cells > 0 {
            moment_sum / moment_cells as f64
        } else {
            0.0
        },
        lag1_error: if lag1_cells > 0 {
            lag_sum / lag1_cells as f64
        } else {
            0.0
        },
        moment_cells,
        lag1_cells,
    }
}

/// Per (phase, channel) mean, standard deviation (divisor n − 1) and lag-1 autocorrelation.
struct CellStats {
    count: Vec<usize>,
    mean: Vec<f64>,
    std: Vec<f64>,
    rho1: Vec<Option<f64>>,
}

fn cell_stats(devs: &[Vec<f64>], sequences: &[PairSequence<'_>], c: usize) -> CellStats {
    let cells = N_PHASES * c;
    let mut count = vec![0usize; N_PHASES];
    let mut sum = vec![0.0; cells];
    for (dev, s) in devs.iter().zip(sequences) {
        for n in 0..s.steps() {
            let p = usize::from(s.phase[n]);
            count[p] += 1;
            for k in 0..c {
                sum[p * c + k] += dev[n * c + k];
            }
        }
    }
    let mean: Vec<f64> = (0..cells)
        .map(|i| sum[i] / count[i / c].max(1) as f64)
        .collect();
    let mut ss = vec![0.0; cells];
    let mut lag = vec![0.0; cells];
    let mut pairs = [0usize; N_PHASES];
    for (dev, s) in devs.iter().zip(sequences) {
        for n in 0..s.steps() {
            let p = usize::from(s.phase[n]);
            let paired = n > 0 && s.phase[n - 1] == s.phase[n];
            if paired {
                pairs[p] += 1;
            }
            for k in 0..c {
                let i = p * c + k;
                let x = dev[n * c + k] - mean[i];
                ss[i] += x * x;
                if paired {
                    lag[i] += x * (dev[(n - 1) * c + k] - mean[i]);
                }
            }
        }
    }
    let mut std = vec![0.0; cells];
    let mut rho1 = vec![None; cells];
    for i in 0..cells {
        let (n, np) = (count[i / c], pairs[i / c]);
        if n >= 2 {
            std[i] = (ss[i] / (n - 1) as f64).sqrt();
        }
        let var = ss[i] / n.max(1) as f64;
        if np > 0 && var > 1e-18 {
            rho1[i] = Some((lag[i] / np as f64) / var);
        }
    }
    CellStats {
        count,
        mean,
        std,
        rho1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error_model::testdata::*;

    #[test]
    fn table3_metrics_rank_models() {
        let data = all_phases_data();
        let pairs = data.pairs();
        let truth = ErrorModel {
            variant: ErrorVariant::PhaseCorrelated,
            channels: C,
            kappa: 1.0,
            phases: truths()
                .into_iter()
                .map(|t| {
                    assemble(
                        t.d,
                        t.s.to_vec(),
                        t.mu.to_vec(),
                        t.ar.to_vec(),
                        t.l.to_vec(),
                        1,
                    )
                })
                .collect(),
        };
        let m_truth = table3_metrics(&truth, &pairs, &mut rng("t3", 0));
        let variants = [
            ErrorVariant::PhaseCorrelated,
            ErrorVariant::PhaseIndependent,
            ErrorVariant::GlobalIid,
            ErrorVariant::Unperturbed,
        ];
        let mut fitted = Vec::new();
        for v in variants {
            let params = ErrorFitParams {
                variant: v,
                ..ErrorFitParams::default()
            };
            let model = fit(&pairs, C, &params).expect("fit");
            let m = table3_metrics(&model, &pairs, &mut rng("t3", 1));
            println!("{v:?}: {m:?}");
            fitted.push(m);
        }
        println!("truth: {m_truth:?}");
        assert_eq!(m_truth.moment_cells, N_PHASES * C);
        assert_eq!(m_truth.lag1_cells, N_PHASES * C);
        assert!(m_truth.moment_error < 0.1);
        assert!(m_truth.lag1_error < 0.03);
        let (corr, indep, global, none) = (&fitted[0], &fitted[1], &fitted[2], &fitted[3]);
        assert!(corr.moment_error < 0.1);
        assert!(corr.lag1_error < 0.03);
        // The teacher's own autocorrelation leaks into S ā_{n−d} − ā_n, so dropping the AR
        // term does not zero the simulated ρ1; it still misses it by far.
        assert!(indep.lag1_error > 0.1);
        assert!(indep.lag1_error > 10.0 * corr.lag1_error);
        assert!(global.lag1_error > 0.3);
        assert!(global.moment_error > corr.moment_error);
        assert!(none.moment_error > global.moment_error);
        // Same stream, same metrics.
        assert_eq!(m_truth, table3_metrics(&truth, &pairs, &mut rng("t3", 0)));
    }
}
