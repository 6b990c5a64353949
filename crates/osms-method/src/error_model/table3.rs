//! Table III's metrics: a model's simulated deviations against the observed ones, per phase
//! and channel.

// The numerics index several parallel row-major arrays by the same channel index; iterator
// zips would obscure the formulas.
#![allow(clippy::needless_range_loop)]

use osms_core::rng::{StreamRng, below};
use serde::{Deserialize, Serialize};

use super::fit::check_sequences;
use super::model::*;
use super::perturb::Perturber;
use crate::Result;

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
    let all: Vec<usize> = (0..sequences.len()).collect();
    let obs = cell_stats(&observed_deviations(sequences, c), sequences, &all, c);
    let sim = cell_stats(
        &simulated_deviations(model, sequences, rng),
        sequences,
        &all,
        c,
    );
    compare(&obs, &sim, c)
}

/// Table III's metrics of several models on the held-out sequences and on bootstrap
/// resamples of them (Efron & Tibshirani 1993, ch. 6), conditional on the fitted models.
pub struct Table3Bootstrap {
    /// Each model's metrics on every sequence.
    pub full: Vec<Table3Metrics>,
    /// Per resample, each model's metrics on the same resampled sequences.
    pub resamples: Vec<Vec<Table3Metrics>>,
}

/// Scores `models` as [`table3_metrics`] does, then on `resamples` sets of sequences drawn
/// with replacement. Each model's deviations are simulated once (models in order, each over
/// the sequences in order, all from `rng`), and every resample scores every model on the same
/// sequences against the same observed deviations, so differences between models are paired
/// by condition. The sequences are the unit of resampling because a rollout's steps are
/// correlated; the fits are not repeated, so the intervals say how far the conditions alone
/// move the comparison.
pub fn table3_bootstrap(
    models: &[&ErrorModel],
    sequences: &[PairSequence<'_>],
    rng: &mut StreamRng,
    resamples: usize,
) -> Result<Table3Bootstrap> {
    // Every model is checked against the sequences, so they all share the first one's width.
    let c = models.first().map_or(0, |m| m.channels);
    for m in models {
        m.validate()?;
        check_sequences(sequences, m.channels)?;
    }
    let observed = observed_deviations(sequences, c);
    let simulated: Vec<_> = models
        .iter()
        .map(|m| simulated_deviations(m, sequences, rng))
        .collect();
    let score = |idx: &[usize]| -> Vec<Table3Metrics> {
        let obs = cell_stats(&observed, sequences, idx, c);
        simulated
            .iter()
            .map(|sim| compare(&obs, &cell_stats(sim, sequences, idx, c), c))
            .collect()
    };
    let all: Vec<usize> = (0..sequences.len()).collect();
    let full = score(&all);
    let n = sequences.len() as u64;
    let resamples = (0..resamples)
        .map(|_| {
            let mut idx: Vec<usize> = (0..n).map(|_| below(rng, n) as usize).collect();
            // Cell sums run over sequences in index order whatever order they were drawn in.
            idx.sort_unstable();
            score(&idx)
        })
        .collect();
    Ok(Table3Bootstrap { full, resamples })
}

/// Per sequence, the observed deviations a − ā (row-major, steps × channels).
fn observed_deviations(sequences: &[PairSequence<'_>], c: usize) -> Vec<Vec<f64>> {
    sequences
        .iter()
        .map(|s| {
            s.student
                .iter()
                .zip(s.teacher)
                .take(s.steps() * c)
                .map(|(&a, &t)| f64::from(a) - f64::from(t))
                .collect()
        })
        .collect()
}

/// Per sequence, the model's simulated deviations ã − ā with a fresh rollout state each.
fn simulated_deviations(
    model: &ErrorModel,
    sequences: &[PairSequence<'_>],
    rng: &mut StreamRng,
) -> Vec<Vec<f64>> {
    let c = model.channels;
    let mut perturber = Perturber::new(model);
    let mut intended = vec![0.0; c];
    sequences
        .iter()
        .map(|s| {
            perturber.reset();
            let mut sim = Vec::with_capacity(s.steps() * c);
            for n in 0..s.steps() {
                for k in 0..c {
                    intended[k] = f64::from(s.teacher[n * c + k]);
                }
                let modeled = perturber.step_modeled(&intended, s.phase[n], rng);
                sim.extend(modeled.iter().zip(&intended).map(|(m, a)| m - a));
            }
            sim
        })
        .collect()
}

/// The moment and lag-1 errors of simulated against observed cell statistics.
fn compare(obs: &CellStats, sim: &CellStats, c: usize) -> Table3Metrics {
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

/// Over the sequences `idx` (repeats count again), in the order given.
fn cell_stats(
    devs: &[Vec<f64>],
    sequences: &[PairSequence<'_>],
    idx: &[usize],
    c: usize,
) -> CellStats {
    let cells = N_PHASES * c;
    let mut count = vec![0usize; N_PHASES];
    let mut sum = vec![0.0; cells];
    for &j in idx {
        let (dev, s) = (&devs[j], &sequences[j]);
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
    for &j in idx {
        let (dev, s) = (&devs[j], &sequences[j]);
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
    use osms_core::stats::bootstrap_difference;

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

    #[test]
    fn the_bootstrap_scores_every_model_on_shared_resamples() {
        let data = all_phases_data();
        let pairs = data.pairs();
        let fitted = |variant| {
            let params = ErrorFitParams {
                variant,
                ..ErrorFitParams::default()
            };
            fit(&pairs, C, &params).expect("fit")
        };
        let corr = fitted(ErrorVariant::PhaseCorrelated);
        let indep = fitted(ErrorVariant::PhaseIndependent);
        // One model: the full sample is exactly table3_metrics on the same stream.
        let one = table3_bootstrap(&[&corr], &pairs, &mut rng("t3b", 0), 0).expect("scores");
        assert_eq!(
            one.full[0],
            table3_metrics(&corr, &pairs, &mut rng("t3b", 0))
        );
        assert!(one.resamples.is_empty());

        let b = table3_bootstrap(&[&corr, &indep, &corr], &pairs, &mut rng("t3b", 1), 200)
            .expect("scores");
        assert_eq!(b.resamples.len(), 200);
        assert!(b.resamples.iter().all(|r| r.len() == 3));
        let lag = |i: usize, j: usize| -> Vec<f64> {
            b.resamples
                .iter()
                .map(|r| r[i].lag1_error - r[j].lag1_error)
                .collect()
        };
        let interval = |d: Vec<f64>, estimate: f64| {
            bootstrap_difference(estimate, &d, pairs.len()).expect("replicates")
        };
        // The truth is phase-correlated: the independent model's lag-1 error is far higher,
        // on every resample's interval.
        let full = |i: usize| b.full[i].lag1_error;
        let d = interval(lag(0, 1), full(0) - full(1));
        assert!(d.high < 0.0, "{d:?}");
        // The same model simulated twice: a null difference the interval covers.
        let moment: Vec<f64> = b
            .resamples
            .iter()
            .map(|r| r[0].moment_error - r[2].moment_error)
            .collect();
        let null = interval(moment, b.full[0].moment_error - b.full[2].moment_error);
        assert!(null.low <= 0.0 && 0.0 <= null.high, "{null:?}");
        // Resamples move the metrics (they are not all the full sample's).
        assert!(b.resamples.iter().any(|r| r[1] != b.full[1]));
    }
}
