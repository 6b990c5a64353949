//! Synthetic pair data with known Eq. 7 parameters, and hand-built models, for the error
//! model's tests.

// The numerics index several parallel row-major arrays by the same channel index; iterator
// zips would obscure the formulas.
#![allow(clippy::needless_range_loop)]

use osms_core::rng::{StreamRng, normal, stream};

pub(crate) use super::fit::{assemble, fit};
use super::*;
use crate::linalg::lower_times_transpose;

pub(crate) const C: usize = 3;

pub(crate) fn rng(name: &str, i: u64) -> StreamRng {
    stream(7, "error_model_test", name, i)
}

/// Ground-truth parameters of one phase, with a full lower-triangular L.
pub(crate) struct Truth {
    pub(crate) d: usize,
    pub(crate) s: [f64; C],
    pub(crate) mu: [f64; C],
    pub(crate) ar: [f64; C],
    pub(crate) l: [f64; C * C],
}

pub(crate) fn truths() -> Vec<Truth> {
    vec![
        Truth {
            d: 0,
            s: [1.0, 0.9, 1.1],
            mu: [0.02, -0.03, 0.0],
            ar: [0.8, 0.5, 0.9],
            l: [0.05, 0.0, 0.0, 0.02, 0.04, 0.0, -0.01, 0.01, 0.03],
        },
        Truth {
            d: 2,
            s: [0.8, 1.0, 0.95],
            mu: [0.0, 0.05, -0.02],
            ar: [0.6, 0.9, 0.3],
            l: [0.03, 0.0, 0.0, 0.01, 0.05, 0.0, 0.0, -0.02, 0.04],
        },
        Truth {
            d: 4,
            s: [1.2, 0.7, 1.0],
            mu: [-0.04, 0.0, 0.03],
            ar: [0.95, 0.7, 0.0],
            l: [0.02, 0.0, 0.0, 0.0, 0.03, 0.0, 0.01, 0.01, 0.06],
        },
        Truth {
            d: 1,
            s: [1.0, 1.0, 0.85],
            mu: [0.01, 0.01, 0.01],
            ar: [0.2, -0.4, 0.85],
            l: [0.06, 0.0, 0.0, 0.03, 0.03, 0.0, 0.0, 0.0, 0.02],
        },
        Truth {
            d: 3,
            s: [0.9, 1.15, 1.05],
            mu: [0.0, -0.05, 0.02],
            ar: [0.7, 0.7, 0.7],
            l: [0.04, 0.0, 0.0, -0.02, 0.04, 0.0, 0.02, 0.0, 0.03],
        },
    ]
}

pub(crate) fn llt(l: &[f64]) -> Vec<f64> {
    lower_times_transpose(l, l.len().isqrt())
}

/// Smooth teacher actions in (−1, 1): a sinusoid plus an AR(0.9) wander, squashed.
pub(crate) fn teacher_sequence(steps: usize, r: &mut StreamRng) -> Vec<f64> {
    let mut x = [0.0; C];
    let mut out = Vec::with_capacity(steps * C);
    for n in 0..steps {
        for (k, xk) in x.iter_mut().enumerate() {
            *xk = 0.9 * *xk + 0.15 * normal(r);
            let wave = 0.3 * libm::sin(0.05 * n as f64 + k as f64);
            out.push(0.8 * libm::tanh(wave + *xk));
        }
    }
    out
}

pub(crate) struct Data {
    pub(crate) student: Vec<Vec<f32>>,
    pub(crate) teacher: Vec<Vec<f32>>,
    pub(crate) phase: Vec<Vec<u8>>,
}

impl Data {
    pub(crate) fn pairs(&self) -> Vec<PairSequence<'_>> {
        (0..self.phase.len())
            .map(|i| PairSequence {
                student: &self.student[i],
                teacher: &self.teacher[i],
                phase: &self.phase[i],
            })
            .collect()
    }
}

/// Student actions generated directly from Eq. 7 (κ = 1, no clip) with the given truths;
/// each sequence visits `phases` in runs of `run` steps. e starts at zero and carries over
/// phase changes; a teacher warm-up of 8 steps supplies ā_{n−d} at the first steps.
pub(crate) fn simulate(
    truths: &[Truth],
    phases: &[u8],
    run: usize,
    sequences: usize,
    seed: u64,
) -> Data {
    let warm = 8;
    let mut data = Data {
        student: Vec::new(),
        teacher: Vec::new(),
        phase: Vec::new(),
    };
    for q in 0..sequences {
        let mut r = rng("simulate", seed * 1000 + q as u64);
        let steps = run * phases.len();
        let teacher = teacher_sequence(steps + warm, &mut r);
        let mut e = [0.0; C];
        let mut student = Vec::with_capacity(steps * C);
        let mut phase = Vec::with_capacity(steps);
        for n in 0..steps {
            let ph = phases[n / run];
            let t = &truths[usize::from(ph)];
            let nu: Vec<f64> = (0..C).map(|_| normal(&mut r)).collect();
            for i in 0..C {
                let mut s = t.ar[i] * e[i];
                for j in 0..=i {
                    s += t.l[i * C + j] * nu[j];
                }
                e[i] = s;
            }
            for k in 0..C {
                let lagged = teacher[(n + warm - t.d) * C + k];
                student.push((t.s[k] * lagged + t.mu[k] + e[k]) as f32);
            }
            phase.push(ph);
        }
        data.student.push(student);
        data.teacher.push(
            teacher[warm * C..]
                .iter()
                .map(|v| *v as f32)
                .collect::<Vec<f32>>(),
        );
        data.phase.push(phase);
    }
    data
}

pub(crate) fn all_phases_data() -> Data {
    // 40 sequences × 500 steps per phase = 20k steps per phase.
    simulate(&truths(), &[0, 1, 2, 3, 4], 500, 40, 1)
}

pub(crate) fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
}

pub(crate) fn hand_model(variant: ErrorVariant, kappa: f64, p: PhaseModel) -> ErrorModel {
    ErrorModel {
        variant,
        channels: C,
        kappa,
        phases: vec![p; N_PHASES],
    }
}

pub(crate) fn hand_phase() -> PhaseModel {
    assemble(
        0,
        vec![0.9, 1.1, 1.0],
        vec![0.05, -0.02, 0.0],
        vec![0.8, 0.3, -0.5],
        vec![0.03, 0.0, 0.0, 0.01, 0.02, 0.0, -0.01, 0.0, 0.04],
        0,
    )
}
