//! Training a student: the flow-matching loop over demonstration chunks, its validation split,
//! learning-rate schedule and checkpointable state.

use osms_core::rng::{self, StreamRng};
use osms_nn::{Adam, AdamConfig, AdamMoments, Matrix, Schedule};
use osms_sim::N_ACTION;
use serde::{Deserialize, Serialize};

use super::demo::{ActionNorm, Demo};
use super::params::{StudentNetwork, StudentParams};
use crate::checkpoint::Checkpoints;
use crate::flow::{FlowBatch, FlowNet, normals};
use crate::{Error, Result, RunningNorm};

/// One point of a student's learning curve.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StudentCurvePoint {
    /// Gradient steps done.
    pub step: u32,
    /// Mean flow-matching loss over the steps since the previous point.
    pub train_loss: f32,
    /// The loss on the held-out demonstrations (fixed noise and times), if any are held out.
    pub validation_loss: Option<f32>,
    pub lr: f32,
}

/// A trained flow-matching student.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Student {
    pub params: StudentParams,
    pub obs_norm: RunningNorm,
    pub act_norm: ActionNorm,
    pub net: FlowNet,
    pub curve: Vec<StudentCurvePoint>,
    /// Demonstration rollouts and (step) samples trained on, and rollouts held out.
    pub train_rollouts: usize,
    pub train_samples: usize,
    pub heldout_rollouts: usize,
}

/// Fixed rows of the validation loss: (demo, step) pairs with their noise and times.
struct Validation {
    pub(super) obs: Matrix,
    x1: Matrix,
    pub(super) mask: Matrix,
    x0: Matrix,
    pub(super) t: Vec<f32>,
}

/// Draws training rows with replacement: uniformly, or by the weight of each row's phase.
pub(super) enum Sampler {
    Uniform(u64),
    /// Cumulative weights, one per row.
    Weighted(Vec<f64>),
}

impl Sampler {
    pub(super) fn new(
        p: &StudentParams,
        samples: &[(usize, usize)],
        train: &[&Demo],
    ) -> Result<Sampler> {
        let w = p.phase_weights;
        if w.iter().all(|&x| x == w[0]) {
            return Ok(Sampler::Uniform(samples.len() as u64));
        }
        let mut total = 0.0;
        let cumulative: Vec<f64> = samples
            .iter()
            .map(|&(r, n)| {
                total += f64::from(w[usize::from(train[r].phase[n])]);
                total
            })
            .collect();
        if total <= 0.0 {
            return Err(Error::Params(format!(
                "params.phase_weights {w:?}: no training step is in a phase of positive weight"
            )));
        }
        Ok(Sampler::Weighted(cumulative))
    }

    pub(super) fn draw(&self, r: &mut StreamRng) -> usize {
        match self {
            Sampler::Uniform(n) => rng::below(r, *n) as usize,
            Sampler::Weighted(cumulative) => {
                let total = *cumulative.last().expect("rows");
                let u = rng::uniform01(r) * total;
                // The first row whose cumulative weight exceeds u (never a weight-0 row).
                cumulative
                    .partition_point(|&c| c <= u)
                    .min(cumulative.len() - 1)
            }
        }
    }
}

/// At most this many held-out samples score each validation point.
const VALIDATION_ROWS: usize = 1024;

/// Everything a student's training carries from one gradient step to the next, for
/// checkpoints (the normalisers and the validation set are recomputed from the demonstrations;
/// minibatch `s` draws from its own stream).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StudentState {
    /// Gradient steps done.
    pub step: u32,
    pub(super) net: FlowNet,
    ema: Option<FlowNet>,
    opt: AdamMoments,
    pub(super) curve: Vec<StudentCurvePoint>,
    loss_sum: f64,
    loss_count: u32,
}

impl Student {
    /// Trains a student on `demos` with the conditional flow-matching loss. Weights draw from
    /// (seed, `stage`); minibatch `s` (rows drawn with replacement, noise and times) from
    /// stream ("batch", s). `progress` is called once per gradient step.
    pub fn train(
        demos: &[Demo],
        params: &StudentParams,
        streams: (u64, &str),
        progress: &dyn Fn(),
    ) -> Result<Student> {
        Self::train_resumable(demos, params, streams, progress, None, None)
    }

    /// [`Student::train`] from the state a checkpoint of the same training holds (if given),
    /// handing its state to `checkpoints` as it goes; the result's bytes are the same whether
    /// or not it was resumed.
    pub fn train_resumable(
        demos: &[Demo],
        params: &StudentParams,
        (seed, stage): (u64, &str),
        progress: &dyn Fn(),
        resume: Option<StudentState>,
        checkpoints: Option<Checkpoints<'_, StudentState>>,
    ) -> Result<Student> {
        let p = params;
        p.check()?;
        for (index, d) in demos.iter().enumerate() {
            d.check(index)?;
        }
        let relabelled: Vec<Demo>;
        let demos = if p.target_labels {
            relabelled = demos.iter().map(Demo::with_target_labels).collect();
            &relabelled[..]
        } else {
            demos
        };
        let held = |i: usize| p.holdout_every > 1 && i % p.holdout_every == p.holdout_every - 1;
        let nonempty = |i: &usize| demos[*i].steps > 0;
        let train_idx: Vec<usize> = (0..demos.len())
            .filter(|&i| !held(i))
            .filter(nonempty)
            .collect();
        let held_idx: Vec<usize> = (0..demos.len())
            .filter(|&i| held(i))
            .filter(nonempty)
            .collect();
        if train_idx.is_empty() {
            return Err(Error::NoDemos {
                given: demos.len(),
                heldout: held_idx.len(),
            });
        }
        let train: Vec<&Demo> = train_idx.iter().map(|&i| &demos[i]).collect();
        let samples: Vec<(usize, usize)> = train
            .iter()
            .enumerate()
            .flat_map(|(r, d)| (0..d.steps).map(move |n| (r, n)))
            .collect();

        let sampler = Sampler::new(p, &samples, &train)?;
        let mut obs_norm = RunningNorm::new(p.obs_len(), p.obs_clip);
        let mut row = Vec::with_capacity(p.obs_len());
        let mut block = Vec::new();
        for &(r, n) in &samples {
            row.clear();
            train[r].observation(n, p, &mut row);
            block.extend_from_slice(&row);
            if block.len() >= 4096 * p.obs_len() {
                obs_norm.update(&block);
                block.clear();
            }
        }
        obs_norm.update(&block);
        let mut student = Student {
            params: p.clone(),
            obs_norm,
            act_norm: ActionNorm::fit(&train),
            net: match p.network {
                StudentNetwork::Mlp => FlowNet::new(
                    p.chunk_len(),
                    p.obs_len(),
                    &p.hidden,
                    p.time_embedding,
                    seed,
                    &format!("{stage}/velocity"),
                )?,
                StudentNetwork::Unet => FlowNet::new_unet(
                    p.chunk_len(),
                    p.obs_len(),
                    p.chunk,
                    &p.unet,
                    p.time_embedding,
                    seed,
                    &format!("{stage}/velocity"),
                )?,
            },
            curve: Vec::new(),
            train_rollouts: train.len(),
            train_samples: samples.len(),
            heldout_rollouts: held_idx.len(),
        };
        let validation = (!held_idx.is_empty()).then(|| {
            let held: Vec<&Demo> = held_idx.iter().map(|&i| &demos[i]).collect();
            student.validation_set(&held, (seed, stage))
        });

        let mut opt = Adam::new(
            AdamConfig {
                weight_decay: p.weight_decay,
                max_grad_norm: Some(p.max_grad_norm),
                ..AdamConfig::default()
            },
            Schedule::Constant { lr: p.lr },
        );
        let (mut loss_sum, mut loss_count) = (0.0f64, 0u32);
        let mut ema = (p.ema_decay > 0.0).then(|| student.net.clone());
        let mut first = 0;
        if let Some(r) = resume {
            if r.step > p.steps || r.ema.is_some() != ema.is_some() {
                return Err(Error::Params(format!(
                    "a checkpoint after {} steps does not fit a training of {} steps",
                    r.step, p.steps
                )));
            }
            first = r.step;
            student.net = r.net;
            student.curve = r.curve;
            ema = r.ema;
            opt = opt.with_moments(r.opt);
            (loss_sum, loss_count) = (r.loss_sum, r.loss_count);
        }
        for s in first..p.steps {
            let lr = student.learning_rate(s);
            opt.schedule = Schedule::Constant { lr };
            let mut r = rng::stream(seed, stage, "batch", u64::from(s));
            let picks: Vec<(usize, usize)> = (0..p.batch)
                .map(|_| samples[sampler.draw(&mut r)])
                .collect();
            let rows: Vec<(&Demo, usize)> = picks.iter().map(|&(d, n)| (train[d], n)).collect();
            let (obs, x1, mask) = student.batch(&rows);
            let x0 = Matrix::from_vec(
                p.batch,
                p.chunk_len(),
                normals(&mut r, p.batch * p.chunk_len()),
            );
            let t: Vec<f32> = (0..p.batch)
                .map(|_| rng::uniform01(&mut r) as f32)
                .collect();
            let (loss, grads) = student.net.loss_and_gradients(&FlowBatch {
                x1: &x1,
                cond: &obs,
                x0: &x0,
                t: &t,
                mask: Some(&mask),
            });
            opt.update(&mut student.net.params_mut(), &grads.slices());
            if let Some(ema) = &mut ema {
                // The moving average forgets its initial weights early (the decay ramps up
                // as (1 + s) / (10 + s)), so short runs are not pulled towards them.
                let d = p.ema_decay.min((1 + s) as f32 / (10 + s) as f32);
                for (e, w) in ema.params_mut().into_iter().zip(student.net.params_mut()) {
                    for (e, &w) in e.iter_mut().zip(w.iter()) {
                        *e = d * *e + (1.0 - d) * w;
                    }
                }
            }
            loss_sum += f64::from(loss);
            loss_count += 1;
            if (s + 1) % p.log_every == 0 || s + 1 == p.steps {
                // The curve scores the network training would stop with: the average, if any.
                if let Some(ema) = &mut ema {
                    std::mem::swap(&mut student.net, ema);
                }
                let validation_loss = validation.as_ref().map(|v| {
                    student.net.loss(&FlowBatch {
                        x1: &v.x1,
                        cond: &v.obs,
                        x0: &v.x0,
                        t: &v.t,
                        mask: Some(&v.mask),
                    })
                });
                if let Some(ema) = &mut ema {
                    std::mem::swap(&mut student.net, ema);
                }
                student.curve.push(StudentCurvePoint {
                    step: s + 1,
                    train_loss: (loss_sum / f64::from(loss_count)) as f32,
                    validation_loss,
                    lr,
                });
                (loss_sum, loss_count) = (0.0, 0);
            }
            progress();
            if let Some(c) = &checkpoints
                && c.due(s + 1, p.steps)
            {
                let state = StudentState {
                    step: s + 1,
                    net: student.net.clone(),
                    ema: ema.clone(),
                    opt: opt.moments(),
                    curve: student.curve.clone(),
                    loss_sum,
                    loss_count,
                };
                (c.save)(&state).map_err(|why| Error::Checkpoint { done: s + 1, why })?;
            }
        }
        if let Some(ema) = ema {
            student.net = ema;
        }
        Ok(student)
    }

    /// Linear warm-up, then cosine decay to `min_lr` at the last step.
    fn learning_rate(&self, step: u32) -> f32 {
        let p = &self.params;
        if step < p.warmup {
            return p.lr * (step + 1) as f32 / p.warmup as f32;
        }
        Schedule::Cosine {
            lr: p.lr,
            min_lr: p.min_lr,
            steps: p.steps.saturating_sub(p.warmup).max(1),
        }
        .lr(step - p.warmup)
    }

    /// Standardised observations, standardised label chunks and their masks for `rows`.
    pub(super) fn batch(&self, rows: &[(&Demo, usize)]) -> (Matrix, Matrix, Matrix) {
        let p = &self.params;
        let (mut obs, mut labels, mut mask) = (
            Vec::with_capacity(rows.len() * p.obs_len()),
            Vec::with_capacity(rows.len() * p.chunk_len()),
            Vec::with_capacity(rows.len() * p.chunk_len()),
        );
        let mut raw = Vec::with_capacity(p.obs_len());
        for &(d, n) in rows {
            raw.clear();
            d.observation(n, p, &mut raw);
            obs.extend(self.obs_norm.apply(&raw));
            let start = labels.len();
            d.chunk(n, p.chunk, &mut labels, &mut mask);
            for (i, a) in labels[start..].iter_mut().enumerate() {
                let k = i % N_ACTION;
                *a = (*a - self.act_norm.mean[k]) / self.act_norm.std[k];
            }
        }
        (
            Matrix::from_vec(rows.len(), p.obs_len(), obs),
            Matrix::from_vec(rows.len(), p.chunk_len(), labels),
            Matrix::from_vec(rows.len(), p.chunk_len(), mask),
        )
    }

    /// Up to [`VALIDATION_ROWS`] held-out samples, evenly spaced, with noise and times from
    /// stream ("validation", 0).
    fn validation_set(&self, held: &[&Demo], (seed, stage): (u64, &str)) -> Validation {
        let all: Vec<(&Demo, usize)> = held
            .iter()
            .flat_map(|d| (0..d.steps).map(move |n| (*d, n)))
            .collect();
        let stride = all.len().div_ceil(VALIDATION_ROWS).max(1);
        let rows: Vec<(&Demo, usize)> = all.into_iter().step_by(stride).collect();
        let (obs, x1, mask) = self.batch(&rows);
        let mut r = rng::stream(seed, stage, "validation", 0);
        let len = self.params.chunk_len();
        let x0 = Matrix::from_vec(rows.len(), len, normals(&mut r, rows.len() * len));
        let t = (0..rows.len())
            .map(|_| rng::uniform01(&mut r) as f32)
            .collect();
        Validation {
            obs,
            x1,
            mask,
            x0,
            t,
        }
    }
}
