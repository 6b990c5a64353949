//! Eq. 7 applied step by step within one rollout: the perturber validation's rollouts run.

// The numerics index several parallel row-major arrays by the same channel index; iterator
// zips would obscure the formulas.
#![allow(clippy::needless_range_loop)]

use std::collections::VecDeque;

use osms_core::rng::{StreamRng, normal};

use super::model::*;
use crate::linalg::robust_cholesky;

/// Eq. 7 applied step by step within one rollout.
///
/// Every step of a perturbed model draws exactly `channels` standard normals, so rollouts that
/// share a stream share their noise step for step (common random numbers). A clone continues
/// exactly where the original is, so a perturbed rollout can branch.
#[derive(Clone)]
pub struct Perturber<'m> {
    model: &'m ErrorModel,
    /// Cholesky factors of each phase's stationary covariance, for the first draw of e.
    stationary_l: Vec<Vec<f64>>,
    /// Intended actions, most recent first, as deep as the longest delay needs.
    history: VecDeque<Vec<f64>>,
    depth: usize,
    e: Vec<f64>,
    started: bool,
    phase: Option<u8>,
    nu: Vec<f64>,
}

impl<'m> Perturber<'m> {
    /// # Panics
    /// If the model fails [`ErrorModel::validate`].
    pub fn new(model: &'m ErrorModel) -> Self {
        if let Err(e) = model.validate() {
            panic!("{e}");
        }
        let c = model.channels;
        let stationary_l = model
            .phases
            .iter()
            .map(|p| robust_cholesky(&p.stationary, c))
            .collect();
        Self {
            model,
            stationary_l,
            history: VecDeque::new(),
            depth: model.max_delay() + 1,
            e: vec![0.0; c],
            started: false,
            phase: None,
            nu: vec![0.0; c],
        }
    }

    /// Forgets the rollout so far; the next step starts a new one.
    pub fn reset(&mut self) {
        self.history.clear();
        self.e.iter_mut().for_each(|v| *v = 0.0);
        self.started = false;
        self.phase = None;
    }

    /// The phase of the last step, if any.
    pub fn phase(&self) -> Option<u8> {
        self.phase
    }

    /// The current AR state e_n (zero before the first step).
    pub fn state(&self) -> &[f64] {
        &self.e
    }

    /// The executed action for intended ā_n in phase φ_n: Eq. 7's
    /// `clip(ā_n + κ_ε (ã_n − ā_n), −1, 1)`.
    ///
    /// e is drawn from the phase's stationary distribution at the first step, then follows
    /// the AR recursion with the current phase's A and L (at a phase change e carries over).
    /// Unperturbed returns ā unchanged and draws nothing.
    ///
    /// # Panics
    /// If `intended` does not have `channels` entries or `phase ≥ N_PHASES`.
    pub fn step(&mut self, intended: &[f64], phase: u8, rng: &mut StreamRng) -> Vec<f64> {
        if self.model.variant == ErrorVariant::Unperturbed {
            self.check(intended, phase);
            self.phase = Some(phase);
            return intended.to_vec();
        }
        let kappa = self.model.kappa;
        let modeled = self.step_modeled(intended, phase, rng);
        intended
            .iter()
            .zip(&modeled)
            .map(|(a, m)| (a + kappa * (m - a)).clamp(-1.0, 1.0))
            .collect()
    }

    /// The modeled student action ã_n of Eq. 7 (before κ_ε and clipping); advances the state
    /// exactly like [`Perturber::step`].
    ///
    /// # Panics
    /// As [`Perturber::step`].
    pub fn step_modeled(&mut self, intended: &[f64], phase: u8, rng: &mut StreamRng) -> Vec<f64> {
        self.check(intended, phase);
        self.phase = Some(phase);
        if self.model.variant == ErrorVariant::Unperturbed {
            return intended.to_vec();
        }
        let c = self.model.channels;
        let p = &self.model.phases[usize::from(phase)];

        self.history.push_front(intended.to_vec());
        self.history.truncate(self.depth);

        for v in self.nu.iter_mut() {
            *v = normal(rng);
        }
        let (factor, carry): (&[f64], bool) = if self.started {
            (&p.l, true)
        } else {
            (&self.stationary_l[usize::from(phase)], false)
        };
        let mut next = vec![0.0; c];
        for (i, out) in next.iter_mut().enumerate() {
            let mut s = if carry { p.ar[i] * self.e[i] } else { 0.0 };
            for (j, nu) in self.nu.iter().enumerate().take(i + 1) {
                s += factor[i * c + j] * nu;
            }
            *out = s;
        }
        self.e = next;
        self.started = true;

        // Before d commands exist the oldest one stands in (see module docs).
        let lagged = self
            .history
            .get(p.delay)
            .or_else(|| self.history.back())
            .map_or(intended, |v| v.as_slice());
        (0..c)
            .map(|k| p.gain[k] * lagged[k] + p.bias[k] + self.e[k])
            .collect()
    }

    fn check(&self, intended: &[f64], phase: u8) {
        assert_eq!(
            intended.len(),
            self.model.channels,
            "intended action has the wrong number of channels"
        );
        assert!(
            usize::from(phase) < N_PHASES,
            "phase {phase} out of range (phases are 0..=4)"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error_model::testdata::*;

    #[test]
    fn perturber_moments_match_the_model() {
        let model = hand_model(ErrorVariant::PhaseCorrelated, 1.0, hand_phase());
        let p = &model.phases[0];
        let intended = [0.3, -0.2, 0.1];
        let steps = 200_000;
        let mut r = rng("moments", 0);
        let mut pert = Perturber::new(&model);
        let mut dev: Vec<Vec<f64>> = (0..C).map(|_| Vec::with_capacity(steps)).collect();
        for _ in 0..steps {
            let m = pert.step_modeled(&intended, 2, &mut r);
            for k in 0..C {
                dev[k].push(m[k] - intended[k]);
            }
        }
        for k in 0..C {
            let x = &dev[k];
            let n = x.len() as f64;
            let mean = x.iter().sum::<f64>() / n;
            let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
            let lag = x
                .windows(2)
                .map(|w| (w[0] - mean) * (w[1] - mean))
                .sum::<f64>()
                / (n - 1.0)
                / var;
            let want_mean = (p.gain[k] - 1.0) * intended[k] + p.bias[k];
            let want_var = p.stationary[k * C + k];
            println!(
                "channel {k}: mean {mean:.5} (model {want_mean:.5}), var {var:.6} (model \
                 {want_var:.6}), lag-1 {lag:.4} (model {:.4})",
                p.ar[k]
            );
            let sd = want_var.sqrt();
            assert!((mean - want_mean).abs() < 0.03 * sd.max(0.01) + 3e-4);
            assert!((var / want_var - 1.0).abs() < 0.03);
            assert!((lag - p.ar[k]).abs() < 0.01);
        }

        // The first draw comes from the stationary distribution: across many fresh rollouts the
        // step-0 deviation has variance Σ_kk.
        let mut first = vec![Vec::new(); C];
        for i in 0..20_000 {
            let mut r = rng("first", i);
            let mut pert = Perturber::new(&model);
            let m = pert.step_modeled(&intended, 0, &mut r);
            for k in 0..C {
                first[k].push(m[k] - intended[k]);
            }
        }
        for k in 0..C {
            let n = first[k].len() as f64;
            let mean = first[k].iter().sum::<f64>() / n;
            let var = first[k]
                .iter()
                .map(|v| (v - mean) * (v - mean))
                .sum::<f64>()
                / n;
            let want = p.stationary[k * C + k];
            println!("step 0, channel {k}: var {var:.6} (stationary {want:.6})");
            assert!((var / want - 1.0).abs() < 0.05);
        }
    }

    #[test]
    fn perturber_kappa_clip_delay_unperturbed_and_determinism() {
        let base = hand_model(ErrorVariant::PhaseCorrelated, 1.0, hand_phase());
        let scaled = hand_model(ErrorVariant::PhaseCorrelated, 2.5, hand_phase());
        let intended = [0.1, 0.0, -0.1];
        let (mut r1, mut r2) = (rng("kappa", 0), rng("kappa", 0));
        let (mut p1, mut p2) = (Perturber::new(&base), Perturber::new(&scaled));
        let mut worst = 0.0f64;
        for _ in 0..1000 {
            let a1 = p1.step(&intended, 1, &mut r1);
            let a2 = p2.step(&intended, 1, &mut r2);
            for k in 0..C {
                worst = worst.max(((a2[k] - intended[k]) - 2.5 * (a1[k] - intended[k])).abs());
            }
        }
        println!("κ scaling residual {worst:e}");
        assert!(worst < 1e-12);

        // A bias far outside the action range is clipped.
        let mut far = hand_phase();
        far.bias = vec![5.0, -5.0, 0.0];
        let clipped = hand_model(ErrorVariant::PhaseCorrelated, 1.5, far);
        let mut p = Perturber::new(&clipped);
        let mut r = rng("clip", 0);
        for _ in 0..100 {
            let a = p.step(&[0.9, -0.9, 0.0], 0, &mut r);
            assert_eq!(a[0], 1.0);
            assert_eq!(a[1], -1.0);
            assert!(a.iter().all(|v| (-1.0..=1.0).contains(v)));
        }

        // A delay of 2 reproduces the intended action of two steps back (noise-free model);
        // before that the first action stands in.
        let mut delayed = assemble(2, vec![1.0; C], vec![0.0; C], vec![0.0; C], vec![0.0; 9], 0);
        delayed.samples = 1;
        let dm = hand_model(ErrorVariant::PhaseIndependent, 1.0, delayed);
        let mut p = Perturber::new(&dm);
        let mut r = rng("delay", 0);
        let inputs: Vec<[f64; C]> = (0..6).map(|n| [0.1 * n as f64, 0.0, -0.1]).collect();
        let outs: Vec<Vec<f64>> = inputs
            .iter()
            .map(|a| p.step_modeled(a, 3, &mut r))
            .collect();
        for n in 0..6usize {
            let src = inputs[n.saturating_sub(2)];
            assert_eq!(outs[n], src.to_vec(), "step {n}");
        }

        // Unperturbed returns ā and draws nothing.
        let none = ErrorModel::unperturbed(C);
        let mut p = Perturber::new(&none);
        let mut r = rng("none", 0);
        let a = p.step(&[0.4, 2.0, -0.3], 4, &mut r);
        assert_eq!(a, vec![0.4, 2.0, -0.3]);
        assert_eq!(r, rng("none", 0));

        // Same stream, same output.
        let run = |i| {
            let mut p = Perturber::new(&base);
            let mut r = rng("same", i);
            (0..50)
                .map(|n| p.step(&intended, (n / 10) as u8, &mut r))
                .collect::<Vec<_>>()
        };
        assert_eq!(run(0), run(0));
        assert_ne!(run(0), run(1));
    }

    #[test]
    fn phase_change_keeps_the_state() {
        // Phase 1 is noise-free with A = 0.5 I: after a switch from phase 0, e must be half of
        // phase 0's last state rather than a fresh stationary draw.
        let mut model2 = hand_model(ErrorVariant::PhaseCorrelated, 1.0, hand_phase());
        let mut carry = hand_phase();
        carry.ar = vec![0.5; C];
        carry.l = vec![0.0; C * C];
        model2.phases[1] = assemble(0, carry.gain, carry.bias, carry.ar, carry.l, 0);
        let mut p = Perturber::new(&model2);
        let mut r = rng("switch", 0);
        p.step_modeled(&[0.0; C], 0, &mut r);
        let e0 = p.state().to_vec();
        p.step_modeled(&[0.0; C], 1, &mut r);
        let want: Vec<f64> = e0.iter().map(|v| 0.5 * v).collect();
        assert_eq!(p.state(), want.as_slice());
        assert_eq!(p.phase(), Some(1));
    }
}
