//! Adam/AdamW with bias correction, global-norm clipping and learning-rate schedules.

use serde::{Deserialize, Serialize};

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

/// The global L2 norm of all gradients, summed slice by slice in order.
pub fn global_norm(grads: &[&[f32]]) -> f32 {
    let mut total = 0.0f64;
    for g in grads {
        let squares: Vec<f32> = g.iter().map(|x| x * x).collect();
        total += f64::from(crate::kernels::sum(&squares));
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
        let bc1 = 1.0 - libm::powf(c.beta1, t as f32);
        let bc2 = 1.0 - libm::powf(c.beta2, t as f32);
        for (((p, g), m), v) in params
            .iter_mut()
            .zip(grads)
            .zip(&mut self.m)
            .zip(&mut self.v)
        {
            // `f32::sqrt` is correctly rounded (IEEE 754) on every target, so it may vectorise.
            for (((p, &g), m), v) in p.iter_mut().zip(*g).zip(m.iter_mut()).zip(v.iter_mut()) {
                let gi = g * clip;
                *m = c.beta1 * *m + (1.0 - c.beta1) * gi;
                *v = c.beta2 * *v + (1.0 - c.beta2) * gi * gi;
                let m_hat = *m / bc1;
                let v_hat = *v / bc2;
                *p -= lr * (m_hat / (v_hat.sqrt() + c.eps) + c.weight_decay * *p);
            }
        }
        norm
    }
}
