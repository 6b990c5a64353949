//! Adam/AdamW with bias correction, global-norm clipping and learning-rate schedules.

use serde::{Deserialize, Serialize};

use crate::level::{Level, dispatch, per_level};

/// Learning rate as a function of the step (0-based).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Schedule {
    Constant {
        lr: f32,
    },
    /// Linear warm-up from 0 to `lr` over `warmup` steps, then constant.
    Warmup {
        lr: f32,
        warmup: u32,
    },
    /// Cosine decay from `lr` to `min_lr` over `steps`, then `min_lr`.
    Cosine {
        lr: f32,
        min_lr: f32,
        steps: u32,
    },
}

impl Schedule {
    pub fn lr(&self, step: u32) -> f32 {
        match *self {
            Schedule::Constant { lr } => lr,
            Schedule::Warmup { lr, warmup } => {
                lr * ((step + 1) as f32 / warmup.max(1) as f32).min(1.0)
            }
            Schedule::Cosine { lr, min_lr, steps } => {
                let t = (step as f32 / steps.max(1) as f32).min(1.0);
                min_lr + 0.5 * (lr - min_lr) * (1.0 + libm::cosf(std::f32::consts::PI * t))
            }
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdamConfig {
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    /// Decoupled weight decay (AdamW); 0 gives Adam.
    pub weight_decay: f32,
    /// Clip the global gradient norm to this; `None` disables clipping.
    pub max_grad_norm: Option<f32>,
}

impl Default for AdamConfig {
    fn default() -> Self {
        AdamConfig {
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay: 0.0,
            max_grad_norm: None,
        }
    }
}

/// Optimiser state: first and second moments per parameter slice, and the step count.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Adam {
    pub config: AdamConfig,
    pub schedule: Schedule,
    pub step: u32,
    m: Vec<Vec<f32>>,
    v: Vec<Vec<f32>>,
}

/// What Adam learns as it runs (the step count and both moments), without its config and
/// schedule, which come from params: what a training checkpoint keeps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdamMoments {
    pub step: u32,
    m: Vec<Vec<f32>>,
    v: Vec<Vec<f32>>,
}

/// The constants of one Adam update.
#[derive(Clone, Copy)]
struct AdamStep {
    clip: f32,
    beta1: f32,
    beta2: f32,
    bc1: f32,
    bc2: f32,
    lr: f32,
    eps: f32,
    weight_decay: f32,
}

/// One parameter slice's update. Every operation is exactly rounded (`f32::sqrt` included) and
/// nothing is fused, so each SIMD level gives the scalar bits.
#[inline(always)]
fn adam_slice(p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], s: AdamStep) {
    for (((p, &g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
        let gi = g * s.clip;
        *m = s.beta1 * *m + (1.0 - s.beta1) * gi;
        *v = s.beta2 * *v + (1.0 - s.beta2) * gi * gi;
        let m_hat = *m / s.bc1;
        let v_hat = *v / s.bc2;
        *p -= s.lr * (m_hat / (v_hat.sqrt() + s.eps) + s.weight_decay * *p);
    }
}

per_level!(adam_baseline, adam_avx2, adam_avx512,
    (p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], s: AdamStep) => adam_slice(p, g, m, v, s));

fn adam_at(level: Level, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], s: AdamStep) {
    dispatch!(level, adam_baseline, adam_avx2, adam_avx512(p, g, m, v, s));
}

/// The global L2 norm of all gradients, summed slice by slice in order.
pub fn global_norm(grads: &[&[f32]]) -> f32 {
    let mut total = 0.0f64;
    for g in grads {
        total += f64::from(crate::kernels::sum_squares(g));
    }
    total.sqrt() as f32
}

impl Adam {
    pub fn new(config: AdamConfig, schedule: Schedule) -> Self {
        Adam {
            config,
            schedule,
            step: 0,
            m: Vec::new(),
            v: Vec::new(),
        }
    }

    /// The step count and moments so far.
    pub fn moments(&self) -> AdamMoments {
        AdamMoments {
            step: self.step,
            m: self.m.clone(),
            v: self.v.clone(),
        }
    }

    /// Continues from `moments` (of an optimiser of the same parameters).
    pub fn with_moments(mut self, moments: AdamMoments) -> Self {
        self.step = moments.step;
        self.m = moments.m;
        self.v = moments.v;
        self
    }

    /// One update of `params` with `grads` (same slices, same order every call). Returns the
    /// gradient norm before clipping.
    pub fn update(&mut self, params: &mut [&mut [f32]], grads: &[&[f32]]) -> f32 {
        assert_eq!(params.len(), grads.len());
        if self.m.is_empty() {
            self.m = grads.iter().map(|g| vec![0.0; g.len()]).collect();
            self.v = self.m.clone();
        }
        let norm = global_norm(grads);
        let clip = match self.config.max_grad_norm {
            Some(max) if norm > max => max / (norm + 1e-6),
            _ => 1.0,
        };
        let c = &self.config;
        let lr = self.schedule.lr(self.step);
        self.step += 1;
        let t = self.step as i32;
        let step = AdamStep {
            clip,
            beta1: c.beta1,
            beta2: c.beta2,
            bc1: 1.0 - libm::powf(c.beta1, t as f32),
            bc2: 1.0 - libm::powf(c.beta2, t as f32),
            lr,
            eps: c.eps,
            weight_decay: c.weight_decay,
        };
        let level = Level::detected();
        for (((p, g), m), v) in params
            .iter_mut()
            .zip(grads)
            .zip(&mut self.m)
            .zip(&mut self.v)
        {
            adam_at(level, p, g, m, v, step);
        }
        norm
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every level's update gives the scalar update's bits (ragged lengths exercise the tails).
    #[test]
    fn adam_updates_are_identical_on_every_level() {
        let mut r = osms_core::rng::stream(0, "optim", "test", 0);
        let mut draw = |n: usize| -> Vec<f32> {
            (0..n)
                .map(|_| osms_core::rng::uniform(&mut r, -1.0, 1.0) as f32)
                .collect()
        };
        let step = AdamStep {
            clip: 0.7,
            beta1: 0.9,
            beta2: 0.999,
            bc1: 0.1,
            bc2: 0.001,
            lr: 1e-3,
            eps: 1e-8,
            weight_decay: 0.01,
        };
        for n in [1, 7, 8, 31, 1000] {
            let (p0, g, m0) = (draw(n), draw(n), draw(n));
            let v0: Vec<f32> = draw(n).iter().map(|x| x.abs()).collect();
            let run = |level: Level| {
                let (mut p, mut m, mut v) = (p0.clone(), m0.clone(), v0.clone());
                adam_at(level, &mut p, &g, &mut m, &mut v, step);
                (p, m, v)
            };
            let reference = run(Level::Baseline);
            for level in Level::available() {
                let got = run(level);
                for (a, b) in [
                    (&got.0, &reference.0),
                    (&got.1, &reference.1),
                    (&got.2, &reference.2),
                ] {
                    let bits = |x: &Vec<f32>| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(a), bits(b), "{level:?}, n = {n}");
                }
            }
        }
    }

    #[test]
    fn the_global_norm_is_the_l2_norm() {
        let a = [3.0f32, 4.0];
        let b: Vec<f32> = vec![1.0; 300];
        let n = global_norm(&[&a, &b]);
        assert!((n - (25.0f32 + 300.0).sqrt()).abs() < 1e-5, "{n}");
    }
}
