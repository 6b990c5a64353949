//! Deployable flow-matching students (paper section 5, "Policies and search"): the IL students
//! π̄ behind the action-error model and, later, the final students π_θ.
//!
//! - **Observation** o_n: the last `history` deployable frames, oldest first. A frame is the
//!   robot's proprioception (arm and hand q, q̇), the object's *observed* position (delayed and
//!   noisy under DR; no velocity, no contacts, nothing privileged) and the previous executed
//!   action ([`osms_sim::episode::DEPLOYABLE_LEN`] values; `previous_actions = false` drops
//!   the action). Before `history` frames exist, the oldest one is repeated, as the rollout's
//!   history holds it. Optional features of the current step follow the frames: the palm's
//!   position and velocity and the observed object's offset from the palm (`palm`: forward
//!   kinematics of the measured joint state, so deployable), the observed object position's
//!   frame-to-frame differences (`object_differences`: deployable), and the object's true velocity
//!   (`oracle_object_velocity`: privileged, a diagnostic of whether information is what the
//!   student lacks, never a deployable student).
//! - **Action chunk**: the labels of steps n … n + chunk − 1, all 24 channels. A chunk that
//!   runs past the rollout's end repeats its last action and masks those steps out of the
//!   loss, so the network is never asked to predict what happens after termination.
//! - **Policy**: at every control step draw noise from the policy's own stream, integrate the
//!   velocity field with `euler_steps` Euler steps, execute the chunk's first action (clamped
//!   to [−1, 1]) and replan at the next step (the paper's). [`ChunkExecution`] runs other
//!   execution horizons and ACT's temporal ensemble instead (issue 68, beyond the paper).
//!
//! Observations and actions are standardised per feature with statistics of the training
//! demonstrations, frozen into the artifact.

use osms_core::rng::{self, StreamRng};
use osms_nn::{Adam, AdamConfig, AdamMoments, Matrix, Schedule};
use osms_sim::conditions::TaskCondition;
use osms_sim::control::{ArmAction, ControlSpec, targets};
use osms_sim::episode::{DEPLOYABLE_LEN, OBSERVED_OBJECT, PRIVILEGED_PALM};
use osms_sim::flight::track_with;
use osms_sim::{
    Action, Episode, N_ACTION, N_ARM, NoHooks, Policy, PolicyView, RolloutRecord, RolloutSpec,
    World,
};
use serde::{Deserialize, Serialize};

use crate::catch::{CatchTaskSpec, TeacherQuery};
use crate::checkpoint::Checkpoints;
use crate::flow::{FlowBatch, FlowNet, FlowSampler, UNetSpec, normals};
use crate::ppo::Agent;
use crate::{Error, Result, RunningNorm};

/// A student's architecture and training protocol. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StudentParams {
    /// Deployable frames in the observation (the current one included).
    pub history: usize,
    /// Steps per predicted action chunk.
    pub chunk: usize,
    /// Euler steps per sample.
    pub euler_steps: usize,
    /// Scale of the initial noise when acting (1: sample the learned distribution; 0: integrate
    /// from its centre, a deterministic policy). Training always uses N(0, I).
    pub noise_scale: f32,
    /// Hidden widths of the MLP velocity network (SiLU); unused by the U-Net.
    pub hidden: Vec<usize>,
    /// Width of the flow time's sinusoidal embedding (even).
    pub time_embedding: usize,
    /// Gradient steps.
    pub steps: u32,
    pub batch: usize,
    /// Peak learning rate, after a linear warm-up of `warmup` steps; cosine decay to
    /// `min_lr` at the last step.
    pub lr: f32,
    pub min_lr: f32,
    pub warmup: u32,
    /// Decoupled weight decay (AdamW).
    pub weight_decay: f32,
    /// Global gradient-norm clip.
    pub max_grad_norm: f32,
    /// Every `holdout_every`-th demonstration rollout is held out of training and scores the
    /// learning curve's validation loss (0: none held out).
    pub holdout_every: usize,
    /// The learning curve gets a point every `log_every` steps.
    pub log_every: u32,
    /// Standardised observations are clipped to ±`obs_clip`.
    pub obs_clip: f32,
    /// Keep the previous executed action in each frame (false drops its 24 values: the
    /// copycat diagnostic of issue 33, de Haan et al. 2019).
    pub previous_actions: bool,
    /// Append the palm's position and linear velocity and the observed object's position
    /// relative to the palm at the current step (9 values; deployable: forward kinematics of the
    /// robot's own joint state).
    pub palm: bool,
    /// Append the observed object position's differences between consecutive frames of the
    /// history ((`history` − 1) × 3 values, oldest first): its velocity by finite differences,
    /// deployable, on a scale standardisation can see (the positions themselves vary over
    /// metres, their step-to-step changes by centimetres).
    pub object_differences: bool,
    /// Append the object's true linear velocity at the current step (3 values). Privileged:
    /// for the diagnosis only (does the student lack information?), never a final student.
    pub oracle_object_velocity: bool,
    /// Append the arm's commanded servo targets at the current step (7 values; deployable:
    /// the controller's own accumulated command, which the frames' joint positions and last
    /// action do not determine). Issue 54's arm interface.
    pub arm_target: bool,
    /// Label and predict the arm channels as the arm's absolute servo target after each step
    /// (the demonstrator's integrated command: its target at the step's start plus its
    /// increment, clamped to the joint's range), executed as the increment from the
    /// controller's current target (clamped to ±1): an error in one step's prediction is not
    /// integrated into every later target, as it is with increment labels (issue 54, item 3b;
    /// Diffusion Policy's position control). Needs `arm_target`, the current target the
    /// increment is taken from. Assumes the default control spec's arm step
    /// ([`ARM_STEP_RAD`]); the student stage refuses a dataset that ran another. Measured on
    /// the development stream: 7.9 % ± 7.3 success against 69.1 % ± 2.1 with increments
    /// (docs/students.md), so off.
    pub target_labels: bool,
    /// Append the deployable flight estimate of the object now (position and velocity, 6
    /// values; `osms_sim::flight`: the observation delay read off the first frames and a
    /// ballistic fit over every observed position so far, what the `tracked` teacher rung
    /// reads), computed with the nominal control period [`NOMINAL_CONTROL_PERIOD_SECS`] in
    /// training and acting alike (issue 66).
    pub tracked_object: bool,
    /// Decay of an exponential moving average of the weights, updated after every step and
    /// used as the trained network (0: none, the last step's weights).
    pub ema_decay: f32,
    /// Relative sampling weight of a training step by the phase it ended in (approach,
    /// velocity matching, contact, follow-through, grasping): oversamples the rare decisive
    /// steps around contact. All equal: uniform sampling.
    pub phase_weights: [f32; 5],
    /// The velocity network: an MLP over the flattened chunk (`hidden`), or a temporal U-Net
    /// over the chunk's steps with FiLM from an encoding of the observation and the flow time
    /// (`unet`; issue 54, item 4).
    pub network: StudentNetwork,
    /// The U-Net's shape, when `network = "unet"`.
    pub unet: UNetSpec,
}

/// Which velocity network a student trains.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StudentNetwork {
    Mlp,
    Unet,
}

impl Default for StudentParams {
    fn default() -> Self {
        StudentParams {
            history: 8,
            chunk: 8,
            euler_steps: 10,
            noise_scale: 0.0,
            hidden: vec![256, 256, 256],
            time_embedding: 32,
            // Issue 33 on the development stream (docs/students.md), three seeds each: 10 k
            // steps 43.8 % ± 2.0, 15 k 48.1 % ± 1.9, 20 k 49.9 % ± 2.5; 20 k puts the
            // default make over its 2.5 h.
            steps: 15_000,
            batch: 256,
            lr: 1e-3,
            min_lr: 1e-5,
            warmup: 100,
            weight_decay: 0.0,
            max_grad_norm: 1.0,
            holdout_every: 10,
            log_every: 50,
            obs_clip: 5.0,
            previous_actions: true,
            // Issue 33's diagnosis on the development stream (docs/students.md): together they
            // took π̄ from 28.4 % to 43.4 % success.
            palm: true,
            object_differences: true,
            oracle_object_velocity: false,
            arm_target: false,
            target_labels: false,
            tracked_object: false,
            ema_decay: 0.0,
            phase_weights: [1.0; 5],
            network: StudentNetwork::Mlp,
            unet: UNetSpec::default(),
        }
    }
}

impl StudentParams {
    /// Refuses params no student can be trained with (the ranges `osms_core::check::Check`
    /// gives the planner, for callers that build params in code).
    pub fn check(&self) -> Result<()> {
        <Self as osms_core::check::Check>::check(self).map_err(Error::from)
    }

    /// Width of an observation: `history` frames, then the current step's features.
    pub fn obs_len(&self) -> usize {
        self.history * self.frame_len() + self.features_len()
    }

    /// Width of one frame of the history: a deployable frame, without the previous action
    /// unless `previous_actions`.
    pub fn frame_len(&self) -> usize {
        if self.previous_actions {
            DEPLOYABLE_LEN
        } else {
            DEPLOYABLE_LEN - N_ACTION
        }
    }

    /// Width of the current step's features after the frames.
    pub fn features_len(&self) -> usize {
        9 * usize::from(self.palm)
            + 3 * (self.history - 1) * usize::from(self.object_differences)
            + 3 * usize::from(self.oracle_object_velocity)
            + N_ARM * usize::from(self.arm_target)
            + 6 * usize::from(self.tracked_object)
    }

    /// Width of an action chunk.
    pub fn chunk_len(&self) -> usize {
        self.chunk * N_ACTION
    }
}

/// The arm's largest target step per control step (rad) under the default control spec:
/// the scale between an arm action and its target increment, for `target_labels`.
pub const ARM_STEP_RAD: f64 = osms_sim::control::ARM_MAX_DELTA_RAD;

/// Values per step of [`Demo::state`].
pub const DEMO_STATE_LEN: usize = 9 + N_ARM;

/// One demonstration rollout as students read it: its deployable frames, the palm and object
/// state the optional features come from, and its action labels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Demo {
    pub steps: usize,
    /// [`DEPLOYABLE_LEN`] per step.
    pub deployable: Vec<f32>,
    /// [`DEMO_STATE_LEN`] per step, at the step's start: the palm's position and linear
    /// velocity, the object's true linear velocity, the arm's servo targets (the record's
    /// `palm_pos`, `palm_vel`, `object_vel`, `arm_targets`).
    pub state: Vec<f32>,
    /// The phase each step ended in (`Phase as u8`, the record's).
    pub phase: Vec<u8>,
    /// 24 per step: the action the demonstrating policy commanded at that step.
    pub actions: Vec<f32>,
}

impl Demo {
    /// A teacher rollout as a demonstration: its deployable frames and, as labels, its
    /// commanded actions (`record.intended`: the full 24-channel action the policy sent, before
    /// the environment's actuation noise and delay, which the student cannot command).
    pub fn from_record(record: &RolloutRecord) -> Demo {
        Demo::labelled(record, record.intended.clone())
    }

    /// A rollout's frames and state labelled with `actions` (24 per step).
    pub fn labelled(record: &RolloutRecord, actions: Vec<f32>) -> Demo {
        let state = (0..record.steps)
            .flat_map(|n| {
                let at = |v: &[f32]| {
                    let row: [f32; 3] = v[3 * n..3 * n + 3].try_into().expect("3 per step");
                    row
                };
                [
                    &at(&record.palm_pos)[..],
                    &at(&record.palm_vel),
                    &at(&record.object_vel),
                    &record.arm_targets[N_ARM * n..N_ARM * (n + 1)],
                ]
                .concat()
            })
            .collect();
        Demo {
            steps: record.steps,
            deployable: record.deployable.clone(),
            state,
            phase: record.phase.clone(),
            actions,
        }
    }

    /// The demonstration with its arm labels as the absolute servo target after each step:
    /// clamp(target at the step's start + [`ARM_STEP_RAD`] · increment) to the joint's range,
    /// as the controller integrates it (`osms_sim::control::targets`).
    pub fn with_target_labels(&self) -> Demo {
        let control = ControlSpec::default();
        let mut actions = self.actions.clone();
        for (n, row) in actions.chunks_exact_mut(N_ACTION).enumerate() {
            let start = &self.state[n * DEMO_STATE_LEN + 9..][..N_ARM];
            // Only the arm's targets are integrated; the hand channels are left as they are.
            let previous: [f64; N_ACTION] =
                std::array::from_fn(|i| start.get(i).map_or(0.0, |t| f64::from(*t)));
            let action: Action = std::array::from_fn(|i| f64::from(row[i]));
            let next = targets(&control, ArmAction::Increment, &previous, &action);
            for (a, t) in row[..N_ARM].iter_mut().zip(next) {
                *a = t as f32;
            }
        }
        Demo {
            actions,
            ..self.clone()
        }
    }

    fn check(&self, index: usize) -> Result<()> {
        if self.deployable.len() != self.steps * DEPLOYABLE_LEN
            || self.state.len() != self.steps * DEMO_STATE_LEN
            || self.phase.len() != self.steps
            || self.phase.iter().any(|&p| usize::from(p) >= 5)
            || self.actions.len() != self.steps * N_ACTION
        {
            return Err(Error::Demo {
                index,
                why: format!(
                    "a demonstration of {} steps has {} deployable, {} state, {} phase and {} action values (expected {}, {}, {} phases below 5 and {})",
                    self.steps,
                    self.deployable.len(),
                    self.state.len(),
                    self.phase.len(),
                    self.actions.len(),
                    self.steps * DEPLOYABLE_LEN,
                    self.steps * DEMO_STATE_LEN,
                    self.steps,
                    self.steps * N_ACTION
                ),
            });
        }
        Ok(())
    }

    /// o_n: frames n − history + 1 … n, the oldest frame repeated before the rollout's start,
    /// then step n's features.
    pub fn observation(&self, n: usize, p: &StudentParams, out: &mut Vec<f32>) {
        let width = p.frame_len();
        let start = out.len();
        for h in 0..p.history {
            let k = (n + h + 1).saturating_sub(p.history);
            out.extend_from_slice(&self.deployable[k * DEPLOYABLE_LEN..k * DEPLOYABLE_LEN + width]);
        }
        let state = &self.state[n * DEMO_STATE_LEN..(n + 1) * DEMO_STATE_LEN];
        let object = &self.deployable[n * DEPLOYABLE_LEN + OBSERVED_OBJECT..][..3];
        let tracked = if p.tracked_object {
            let seen = |j: usize| {
                let at = j * DEPLOYABLE_LEN + OBSERVED_OBJECT;
                std::array::from_fn(|c| f64::from(self.deployable[at + c]))
            };
            tracked_features(track_with(n + 1, seen, NOMINAL_CONTROL_PERIOD_SECS))
        } else {
            [0.0; 6]
        };
        let now = Current {
            palm_pos: &state[0..3],
            palm_vel: &state[3..6],
            object,
            object_vel: &state[6..9],
            arm_targets: &state[9..9 + N_ARM],
            tracked: &tracked,
        };
        push_features(p, start, &now, out);
    }

    /// The label chunk at step n and its mask: steps past the end repeat the last action with
    /// mask 0.
    pub fn chunk(&self, n: usize, chunk: usize, labels: &mut Vec<f32>, mask: &mut Vec<f32>) {
        for j in 0..chunk {
            let k = (n + j).min(self.steps - 1);
            labels.extend_from_slice(&self.actions[k * N_ACTION..(k + 1) * N_ACTION]);
            let m = if n + j < self.steps { 1.0 } else { 0.0 };
            mask.extend(std::iter::repeat_n(m, N_ACTION));
        }
    }
}

/// Per-channel standardisation of actions: (a − mean) / std.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ActionNorm {
    pub mean: Vec<f32>,
    /// Floored at [`ActionNorm::MIN_STD`]: a channel the demonstrations barely move must not
    /// turn sampling noise into large actions.
    pub std: Vec<f32>,
}

impl ActionNorm {
    pub const MIN_STD: f64 = 0.01;

    fn fit(demos: &[&Demo]) -> ActionNorm {
        let mut stats = RunningNorm::new(N_ACTION, f32::INFINITY);
        for d in demos {
            stats.update(&d.actions);
        }
        ActionNorm {
            mean: stats.mean.iter().map(|&m| m as f32).collect(),
            std: stats
                .var
                .iter()
                .map(|&v| v.sqrt().max(Self::MIN_STD) as f32)
                .collect(),
        }
    }
}

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
    obs: Matrix,
    x1: Matrix,
    mask: Matrix,
    x0: Matrix,
    t: Vec<f32>,
}

/// Draws training rows with replacement: uniformly, or by the weight of each row's phase.
enum Sampler {
    Uniform(u64),
    /// Cumulative weights, one per row.
    Weighted(Vec<f64>),
}

impl Sampler {
    fn new(p: &StudentParams, samples: &[(usize, usize)], train: &[&Demo]) -> Result<Sampler> {
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

    fn draw(&self, r: &mut StreamRng) -> usize {
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
    net: FlowNet,
    ema: Option<FlowNet>,
    opt: AdamMoments,
    curve: Vec<StudentCurvePoint>,
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
    fn batch(&self, rows: &[(&Demo, usize)]) -> (Matrix, Matrix, Matrix) {
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

    /// The first action of a sampled chunk for a raw observation (the policy's output),
    /// drawing the initial noise from `rng`.
    pub fn act(&self, obs: &[f32], rng: &mut StreamRng) -> Action {
        self.act_with(&self.net.sampler(), obs, rng)
    }

    /// [`Student::act`] through a sampler prepared once ([`FlowNet::sampler`]).
    pub fn act_with(&self, sampler: &FlowSampler<'_>, obs: &[f32], rng: &mut StreamRng) -> Action {
        let [action] = self
            .act_batch_with(sampler, std::slice::from_ref(&obs), [rng])
            .try_into()
            .unwrap_or_else(|_| unreachable!("one observation, one action"));
        action
    }

    /// [`Student::act`] on many observations at once, observation i drawing its noise from the
    /// i-th stream: action i is bit for bit `act(obs[i], rng_i)` (the flow network's batch
    /// invariance, [`FlowNet::sample_batch`]), at matrix-product instead of matrix-vector speed.
    pub fn act_batch<'r, O: AsRef<[f32]>>(
        &self,
        obs: &[O],
        rngs: impl IntoIterator<Item = &'r mut StreamRng>,
    ) -> Vec<Action> {
        self.act_batch_with(&self.net.sampler(), obs, rngs)
    }

    /// [`Student::act_batch`] through a sampler of this student's network prepared once
    /// ([`FlowNet::sampler`]) for many actions, with the same bits.
    pub fn act_batch_with<'r, O: AsRef<[f32]>>(
        &self,
        sampler: &FlowSampler<'_>,
        obs: &[O],
        rngs: impl IntoIterator<Item = &'r mut StreamRng>,
    ) -> Vec<Action> {
        self.chunks_batch_with(sampler, obs, rngs)
            .iter()
            .zip(obs)
            .map(|(chunk, o)| self.executable(&chunk[..N_ACTION], o.as_ref()))
            .collect()
    }

    /// The sampled chunks for `obs`, each de-standardised (`chunk` steps of [`N_ACTION`]
    /// values), observation i drawing its noise from the i-th stream.
    fn chunks_batch_with<'r, O: AsRef<[f32]>>(
        &self,
        sampler: &FlowSampler<'_>,
        obs: &[O],
        rngs: impl IntoIterator<Item = &'r mut StreamRng>,
    ) -> Vec<Vec<f64>> {
        let (c_len, x_len) = (self.params.obs_len(), self.params.chunk_len());
        let mut cond = Vec::with_capacity(obs.len() * c_len);
        let mut noise = Vec::with_capacity(obs.len() * x_len);
        for (o, rng) in obs.iter().zip(rngs) {
            cond.extend(self.obs_norm.apply(o.as_ref()));
            noise.extend(
                normals(rng, x_len)
                    .into_iter()
                    .map(|x| x * self.params.noise_scale),
            );
        }
        assert_eq!(
            noise.len(),
            obs.len() * x_len,
            "student: one stream per observation"
        );
        let rows = obs.len();
        if rows == 0 {
            return Vec::new();
        }
        let x = sampler.sample_batch(
            &Matrix::from_vec(rows, c_len, cond),
            Matrix::from_vec(rows, x_len, noise),
            self.params.euler_steps,
        );
        (0..rows)
            .map(|i| {
                x.row(i)
                    .iter()
                    .enumerate()
                    .map(|(j, &v)| {
                        let k = j % N_ACTION;
                        f64::from(v * self.act_norm.std[k] + self.act_norm.mean[k])
                    })
                    .collect()
            })
            .collect()
    }

    /// The action executed for a de-standardised chunk step at the observation `obs` of the step
    /// it runs in: a target label turned into the increment from the current target, clamped
    /// to [−1, 1].
    fn executable(&self, step: &[f64], obs: &[f32]) -> Action {
        let mut action: Action = std::array::from_fn(|k| step[k]);
        if self.params.target_labels {
            // The arm target features close the observation (`push_features`).
            let current = &obs[obs.len() - N_ARM..];
            for (a, t) in action[..N_ARM].iter_mut().zip(current) {
                *a = (*a - f64::from(*t)) / ARM_STEP_RAD;
            }
        }
        action.map(|a| a.clamp(-1.0, 1.0))
    }

    /// One control step of many running episodes, each with its own noise stream and chunk
    /// state ([`ChunkRunner`]): the episodes whose runner samples this step get a chunk in one
    /// batched sample, then every runner gives its step's action. With the paper's execution
    /// (h = 1) action i is bit for bit [`Student::act_batch_with`]'s.
    pub fn act_executed<'r, O: AsRef<[f32]>>(
        &self,
        sampler: &FlowSampler<'_>,
        obs: &[O],
        states: impl IntoIterator<Item = (&'r mut StreamRng, &'r mut ChunkRunner)>,
    ) -> Vec<Action> {
        let mut runners: Vec<&mut ChunkRunner> = Vec::with_capacity(obs.len());
        let mut sampling = Vec::new();
        let mut rngs = Vec::new();
        for (i, (rng, runner)) in states.into_iter().enumerate() {
            if runner.samples() {
                sampling.push(i);
                rngs.push(rng);
            }
            runners.push(runner);
        }
        assert_eq!(
            runners.len(),
            obs.len(),
            "student: one runner per observation"
        );
        let sampled_obs: Vec<&[f32]> = sampling.iter().map(|&i| obs[i].as_ref()).collect();
        let chunks = self.chunks_batch_with(sampler, &sampled_obs, rngs);
        for (&i, chunk) in sampling.iter().zip(chunks) {
            runners[i].push(chunk);
        }
        runners
            .into_iter()
            .zip(obs)
            .map(|(runner, o)| self.executable(&runner.next(), o.as_ref()))
            .collect()
    }

    /// The observation of a running rollout: its history of deployable frames, the oldest
    /// repeated to `history` frames, then the current step's features (as the record keeps
    /// them: in f32).
    pub fn observation(&self, view: &PolicyView<'_>) -> Vec<f32> {
        let p = &self.params;
        let h = p.history;
        let frames = view.history;
        let mut out = Vec::with_capacity(p.obs_len());
        for i in 0..h {
            let k = (frames.len() + i).saturating_sub(h);
            out.extend(frames[k][..p.frame_len()].iter().map(|&v| v as f32));
        }
        let f32s = |v: &[f64]| -> [f32; 3] { std::array::from_fn(|c| v[c] as f32) };
        let palm_pos = f32s(&view.privileged[PRIVILEGED_PALM..]);
        let palm_vel = f32s(&view.privileged[PRIVILEGED_PALM + 6..]);
        let object = f32s(&view.deployable[OBSERVED_OBJECT..]);
        let velocity = f32s(&view.data.qvel()[view.world.ids.object_dof..]);
        let targets = view.arm_targets.map(|v| v as f32);
        let tracked = if p.tracked_object {
            tracked_features(view.tracker.estimate(NOMINAL_CONTROL_PERIOD_SECS))
        } else {
            [0.0; 6]
        };
        let now = Current {
            palm_pos: &palm_pos,
            palm_vel: &palm_vel,
            object: &object,
            object_vel: &velocity,
            arm_targets: &targets,
            tracked: &tracked,
        };
        push_features(p, 0, &now, &mut out);
        out
    }
}

/// What the current step's features are computed from, as training (from a demonstration's
/// state) and acting (from the running rollout) both have it.
struct Current<'a> {
    palm_pos: &'a [f32],
    palm_vel: &'a [f32],
    /// The observed object position.
    object: &'a [f32],
    /// The object's true velocity (the oracle diagnostic only).
    object_vel: &'a [f32],
    arm_targets: &'a [f32],
    /// The flight estimate's position and velocity.
    tracked: &'a [f32; 6],
}

/// The control period the students' flight-estimate input assumes: the default world's
/// (10 physics steps of 2 ms), in training and acting alike, so the two agree whatever world a
/// rollout runs in.
pub const NOMINAL_CONTROL_PERIOD_SECS: f64 = 0.02;

fn tracked_features(o: osms_sim::episode::ObservedObject) -> [f32; 6] {
    std::array::from_fn(|i| if i < 3 { o.pos[i] } else { o.vel[i - 3] } as f32)
}

/// The current step's features (see the module's doc), in the order training and acting share.
/// The history's frames are already in `out`, from index `frames`.
fn push_features(p: &StudentParams, frames: usize, now: &Current<'_>, out: &mut Vec<f32>) {
    let Current {
        palm_pos,
        palm_vel,
        object,
        object_vel,
        arm_targets,
        tracked,
    } = *now;
    if p.palm {
        out.extend_from_slice(&palm_pos[..3]);
        out.extend_from_slice(&palm_vel[..3]);
        out.extend((0..3).map(|c| object[c] - palm_pos[c]));
    }
    if p.object_differences {
        let w = p.frame_len();
        for h in 1..p.history {
            let at = |k: usize, c: usize| out[frames + k * w + OBSERVED_OBJECT + c];
            let change: [f32; 3] = std::array::from_fn(|c| at(h, c) - at(h - 1, c));
            out.extend(change);
        }
    }
    if p.oracle_object_velocity {
        out.extend_from_slice(&object_vel[..3]);
    }
    if p.arm_target {
        out.extend_from_slice(&arm_targets[..N_ARM]);
    }
    if p.tracked_object {
        out.extend_from_slice(tracked);
    }
}

/// How a student's sampled chunks become executed actions (issue 68, beyond the paper; the
/// default is the paper's). Params of the evaluation stages, not of training: one trained
/// student runs under any of them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ChunkExecution {
    /// The execution horizon h: the first h actions of each sampled chunk run open loop before
    /// the next sample (1, the paper's: replan every step; at most the chunk's length).
    pub horizon: usize,
    /// ACT's temporal ensemble (Zhao et al. 2023): sample a chunk every step and execute the
    /// average of every live chunk's prediction for this step, the i-th oldest weighted by
    /// exp(−m·i); the value is m (ACT's 0.01, which favours the older predictions a little; a
    /// negative m favours the newest). Needs `horizon = 1`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ensemble: Option<f64>,
}

impl Default for ChunkExecution {
    fn default() -> Self {
        ChunkExecution {
            horizon: 1,
            ensemble: None,
        }
    }
}

impl ChunkExecution {
    /// The paper's: the first action of every step's chunk.
    pub fn is_paper(&self) -> bool {
        *self == ChunkExecution::default()
    }

    /// Refuses an execution the student's chunks cannot carry: the plan's checks
    /// (`osms_core::check::Check`), then a horizon past the chunk and ensemble weights that
    /// would overflow over it.
    pub fn check_for(&self, params: &StudentParams) -> Result<()> {
        <Self as osms_core::check::Check>::check(self)
            .map_err(|e| Error::from(e.within("execution")))?;
        if self.horizon > params.chunk {
            return Err(Error::Params(format!(
                "execution.horizon = {}: must be within 1 ..= {} (the student's chunk length)",
                self.horizon, params.chunk
            )));
        }
        if let Some(m) = self.ensemble
            && m.abs() * (params.chunk - 1) as f64 > MAX_ENSEMBLE_EXPONENT
        {
            return Err(Error::Params(format!(
                "execution.ensemble = {m}: over the student's {} overlapping predictions the weights exp(−m·i) span more than exp({MAX_ENSEMBLE_EXPONENT}) and overflow\nhint: |m| · (chunk − 1) must be at most {MAX_ENSEMBLE_EXPONENT}",
                params.chunk
            )));
        }
        Ok(())
    }
}

/// The largest |m| · i an ensemble's weights exp(−m·i) may reach: exp(709) is the last finite
/// f64, and the weights are summed.
const MAX_ENSEMBLE_EXPONENT: f64 = 700.0;

/// One episode's chunk state under a [`ChunkExecution`]: the chunks sampled so far that still
/// cover a step to come, each with the step it was sampled at.
#[derive(Debug, Clone, PartialEq)]
pub struct ChunkRunner {
    execution: ChunkExecution,
    /// Actions per chunk.
    chunk: usize,
    step: usize,
    /// Oldest first.
    live: std::collections::VecDeque<(usize, Vec<f64>)>,
}

impl ChunkRunner {
    pub fn new(execution: ChunkExecution, params: &StudentParams) -> Self {
        ChunkRunner {
            execution,
            chunk: params.chunk,
            step: 0,
            live: std::collections::VecDeque::new(),
        }
    }

    /// Whether this step samples a new chunk.
    pub fn samples(&self) -> bool {
        self.execution.ensemble.is_some()
            || self
                .live
                .back()
                .is_none_or(|(start, _)| self.step >= start + self.execution.horizon)
    }

    /// The chunk sampled at this step (de-standardised, step-major).
    fn push(&mut self, chunk: Vec<f64>) {
        debug_assert_eq!(chunk.len(), self.chunk * N_ACTION);
        if self.execution.ensemble.is_none() {
            // Only the newest chunk is ever read without an ensemble.
            self.live.clear();
        }
        self.live.push_back((self.step, chunk));
    }

    /// This step's de-standardised action, then the next step. The paper's execution returns
    /// the newest chunk's first action unchanged.
    fn next(&mut self) -> Vec<f64> {
        let step = self.step;
        self.step += 1;
        while self
            .live
            .front()
            .is_some_and(|(start, _)| start + self.chunk <= step)
        {
            self.live.pop_front();
        }
        let at = |(start, chunk): &(usize, Vec<f64>)| {
            let j = step - start;
            chunk[j * N_ACTION..(j + 1) * N_ACTION].to_vec()
        };
        match self.execution.ensemble {
            None => at(self.live.back().expect("a chunk covers every step")),
            Some(m) => {
                let mut sum = vec![0.0; N_ACTION];
                let mut total = 0.0;
                for (i, live) in self.live.iter().enumerate() {
                    // libm, not the platform's exp: the weights must have the same bits everywhere.
                    let w = libm::exp(-m * i as f64);
                    for (s, a) in sum.iter_mut().zip(at(live)) {
                        *s += w * a;
                    }
                    total += w;
                }
                sum.into_iter().map(|s| s / total).collect()
            }
        }
    }
}

/// A student as the simulator's policy: noise for each step's sample from `rng` (the policy's
/// own stream, apart from the rollout's DR stream), its network prepared once for the episode.
pub struct StudentPolicy<'s> {
    student: &'s Student,
    sampler: FlowSampler<'s>,
    rng: StreamRng,
    runner: ChunkRunner,
}

impl<'s> StudentPolicy<'s> {
    /// The paper's execution: a new chunk every step, its first action executed.
    pub fn new(student: &'s Student, rng: StreamRng) -> Self {
        Self::with_execution(student, rng, ChunkExecution::default())
    }

    /// The student under another [`ChunkExecution`] (checked by the caller,
    /// [`ChunkExecution::check_for`]).
    pub fn with_execution(student: &'s Student, rng: StreamRng, execution: ChunkExecution) -> Self {
        StudentPolicy {
            student,
            sampler: student.net.sampler(),
            rng,
            runner: ChunkRunner::new(execution, &student.params),
        }
    }

    pub fn student(&self) -> &'s Student {
        self.student
    }
}

impl Policy for StudentPolicy<'_> {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        let obs = self.student.observation(view);
        let [action] = self
            .student
            .act_executed(
                &self.sampler,
                std::slice::from_ref(&obs),
                [(&mut self.rng, &mut self.runner)],
            )
            .try_into()
            .unwrap_or_else(|_| unreachable!("one observation, one action"));
        action
    }

    /// A deployable policy: it reads no privileged quantity at all.
    fn reads_contact_force(&self) -> bool {
        false
    }
}

impl Student {
    /// `base` with the history the student reads: the rollout must keep as many deployable
    /// frames as the student was trained on.
    pub fn rollout_spec(&self, base: &RolloutSpec) -> RolloutSpec {
        let mut spec = base.clone();
        spec.history_steps = self.params.history;
        spec
    }
}

/// The student's rollout on condition ω: domain randomisation from `dr`, the policy's noise
/// from `policy`. `spec` comes from [`Student::rollout_spec`].
pub fn rollout(
    world: &World,
    spec: &RolloutSpec,
    student: &Student,
    condition: TaskCondition,
    dr: StreamRng,
    policy: StreamRng,
) -> RolloutRecord {
    let mut policy = StudentPolicy::new(student, policy);
    Episode::new(world, spec, condition, dr).run(&mut policy, &mut NoHooks)
}

/// How many student rollouts an evaluation stage hands [`rollouts`] at once: a few times
/// [`LOCKSTEP_SLOTS`], so that the batch stays full while episodes of different lengths end,
/// few enough that two threads still share out a development stream evenly.
pub const ROLLOUT_BATCH: usize = 64;

/// How many student rollouts [`rollouts`] steps together: enough rows for the matrix kernels'
/// tiled path to pay (`cargo bench -p osms-policy --bench student` measures the batch
/// lengths).
pub const LOCKSTEP_SLOTS: usize = 16;

/// Student rollouts on many conditions, stepped in lockstep with the policy acting on every
/// running episode at once (one matrix product per layer for the batch instead of one
/// matrix-vector product per episode), [`LOCKSTEP_SLOTS`] episodes at a time: an episode that
/// ends gives its slot to the next item, so the products keep their rows while the short
/// episodes of a batch end before the long ones. `items` are (ω, DR stream, policy stream);
/// rollout i is bit for bit [`rollout`] on item i.
pub fn rollouts(
    world: &World,
    spec: &RolloutSpec,
    student: &Student,
    items: Vec<(TaskCondition, StreamRng, StreamRng)>,
) -> Vec<RolloutRecord> {
    rollouts_in_slots(
        world,
        spec,
        (student, ChunkExecution::default()),
        items,
        LOCKSTEP_SLOTS,
    )
}

/// [`rollouts`] under another [`ChunkExecution`]: rollout i is bit for bit the rollout of
/// [`StudentPolicy::with_execution`] on item i.
pub fn rollouts_executed(
    world: &World,
    spec: &RolloutSpec,
    (student, execution): (&Student, ChunkExecution),
    items: Vec<(TaskCondition, StreamRng, StreamRng)>,
) -> Vec<RolloutRecord> {
    rollouts_in_slots(world, spec, (student, execution), items, LOCKSTEP_SLOTS)
}

/// [`rollouts_executed`] with at most `slots` episodes running at once (at least 1).
pub fn rollouts_in_slots(
    world: &World,
    spec: &RolloutSpec,
    (student, execution): (&Student, ChunkExecution),
    items: Vec<(TaskCondition, StreamRng, StreamRng)>,
    slots: usize,
) -> Vec<RolloutRecord> {
    let mut records: Vec<Option<RolloutRecord>> = vec![None; items.len()];
    let mut pending = items.into_iter().enumerate();
    let mut running: Vec<(usize, Episode<'_>, (StreamRng, ChunkRunner))> = Vec::new();
    let sampler = student.net.sampler();
    loop {
        // Every slot observes its next step; an episode that is over finishes and its slot
        // takes the next item, so each running episode has observed once when this ends.
        let (mut observed, mut obs) = (Vec::new(), Vec::new());
        while observed.len() < running.len() || running.len() < slots.max(1) {
            let k = observed.len();
            if k == running.len() {
                let Some((i, (condition, dr, policy))) = pending.next() else {
                    break;
                };
                let runner = ChunkRunner::new(execution, &student.params);
                running.push((
                    i,
                    Episode::new(world, spec, condition, dr),
                    (policy, runner),
                ));
            }
            // A student reads no contact force (`StudentPolicy::reads_contact_force`).
            match running[k].1.observe_step(false) {
                Some(o) => {
                    obs.push(student.observation(&running[k].1.view(&o)));
                    observed.push(o);
                }
                None => {
                    let (i, episode, _) = running.swap_remove(k);
                    records[i] = Some(episode.finish());
                }
            }
        }
        if observed.is_empty() {
            break;
        }
        let states = running
            .iter_mut()
            .map(|(_, _, (rng, runner))| (rng, runner));
        let actions = student.act_executed(&sampler, &obs, states);
        for ((slot, o), action) in running.iter_mut().zip(observed).zip(actions) {
            slot.1.act_step(o, action, &mut NoHooks);
        }
    }
    records
        .into_iter()
        .map(|r| r.expect("every item ran to its end"))
        .collect()
}

/// A student rollout with the frozen teacher queried at every visited state.
pub struct PairedRollout {
    pub record: RolloutRecord,
    /// The teacher's action at each step's state, 24 per step.
    pub teacher: Vec<f32>,
    /// The phase known online when each step's action is chosen: the phase the previous step
    /// ended in (approach at step 0), as the teacher's phase input and the action-error model
    /// see it.
    pub phase: Vec<u8>,
}

/// The student's rollout on ω, as [`rollout`], recording what the teacher would have done at
/// every state the student reaches (paper 4.3). The teacher never acts.
pub fn paired_rollout(
    world: &World,
    spec: &RolloutSpec,
    student: &Student,
    teacher: (&Agent, &CatchTaskSpec),
    condition: TaskCondition,
    dr: StreamRng,
    policy: StreamRng,
) -> PairedRollout {
    struct Paired<'s, 't> {
        student: StudentPolicy<'s>,
        teacher: TeacherQuery<'t>,
        actions: Vec<f32>,
        phases: Vec<u8>,
    }
    impl Policy for Paired<'_, '_> {
        fn act(&mut self, view: &PolicyView<'_>) -> Action {
            let t = self.teacher.act(view);
            self.actions.extend(t.iter().map(|&a| a as f32));
            self.phases.push(self.teacher.phase());
            self.student.act(view)
        }
    }
    let mut paired = Paired {
        student: StudentPolicy::new(student, policy),
        teacher: TeacherQuery::new(teacher.0, teacher.1),
        actions: Vec::new(),
        phases: Vec::new(),
    };
    // A realisable teacher reads a history of its own; the student reads the newest of it.
    let spec = teacher.1.actor_inputs.rollout(spec);
    let mut episode = Episode::new(world, &spec, condition, dr);
    while episode.step(&mut paired, &mut NoHooks) {
        if let Some(&p) = episode.record().phase.last() {
            paired.teacher.observe_phase(p);
        }
    }
    PairedRollout {
        record: episode.finish(),
        teacher: paired.actions,
        phase: paired.phases,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A demonstration whose frame n holds n + 1 in every entry and whose action at n holds
    /// labels derived from n, so each value names where it came from.
    fn numbered(steps: usize) -> Demo {
        Demo {
            steps,
            deployable: (0..steps)
                .flat_map(|n| std::iter::repeat_n((n + 1) as f32, DEPLOYABLE_LEN))
                .collect(),
            state: (0..steps)
                .flat_map(|n| (0..DEMO_STATE_LEN).map(move |c| (n * 10 + c) as f32))
                .collect(),
            phase: (0..steps).map(|n| (n % 5) as u8).collect(),
            actions: (0..steps)
                .flat_map(|n| (0..N_ACTION).map(move |k| (n * 100 + k) as f32 / 1e4))
                .collect(),
        }
    }

    #[test]
    fn observations_repeat_the_oldest_frame_and_chunks_pad_with_a_mask() {
        let d = numbered(5);
        let frames = |n: usize, h: usize| {
            let mut out = Vec::new();
            let p = StudentParams {
                history: h,
                palm: false,
                object_differences: false,
                ..StudentParams::default()
            };
            d.observation(n, &p, &mut out);
            out.chunks(DEPLOYABLE_LEN).map(|f| f[0]).collect::<Vec<_>>()
        };
        assert_eq!(frames(0, 3), [1.0, 1.0, 1.0]);
        assert_eq!(frames(1, 3), [1.0, 1.0, 2.0]);
        assert_eq!(frames(4, 3), [3.0, 4.0, 5.0]);
        assert_eq!(frames(4, 1), [5.0]);

        let (mut labels, mut mask) = (Vec::new(), Vec::new());
        d.chunk(3, 4, &mut labels, &mut mask);
        let first = |j: usize| labels[j * N_ACTION];
        assert_eq!(
            [first(0), first(1), first(2), first(3)],
            [0.03, 0.04, 0.04, 0.04]
        );
        let m: Vec<f32> = mask.iter().step_by(N_ACTION).copied().collect();
        assert_eq!(m, [1.0, 1.0, 0.0, 0.0]);
        assert_eq!(mask.len(), 4 * N_ACTION);
    }

    #[test]
    fn optional_inputs_come_from_the_current_step_and_previous_actions_can_be_dropped() {
        let d = numbered(4);
        let p = StudentParams {
            history: 2,
            previous_actions: false,
            palm: true,
            object_differences: true,
            oracle_object_velocity: true,
            arm_target: true,
            ..StudentParams::default()
        };
        let mut out = Vec::new();
        d.observation(2, &p, &mut out);
        assert_eq!(out.len(), p.obs_len());
        assert_eq!(p.frame_len(), DEPLOYABLE_LEN - N_ACTION);
        // Frames 1 and 2 without their previous actions, then step 2's features: palm
        // position (20, 21, 22), velocity (23, 24, 25), object − palm (3 − 20, ...), the
        // object's change from frame 1 to 2 (1, 1, 1), its velocity (26, 27, 28) and the arm's
        // targets (29 … 35).
        let frames = 2 * p.frame_len();
        assert!(out[..p.frame_len()].iter().all(|&v| v == 2.0));
        assert!(out[p.frame_len()..frames].iter().all(|&v| v == 3.0));
        assert_eq!(
            out[frames..],
            [
                20.0, 21.0, 22.0, 23.0, 24.0, 25.0, -17.0, -18.0, -19.0, 1.0, 1.0, 1.0, 26.0, 27.0,
                28.0, 29.0, 30.0, 31.0, 32.0, 33.0, 34.0, 35.0
            ]
        );
    }

    #[test]
    fn the_nominal_control_period_is_the_default_worlds() {
        let w = osms_sim::WorldSpec::default();
        assert_eq!(
            NOMINAL_CONTROL_PERIOD_SECS,
            w.timestep_secs * f64::from(w.substeps)
        );
    }

    /// Weighted draws follow the phase weights: with phases 0..4 cycling over the steps and
    /// weights (1, 0, 8, 1, 0), phase 2 takes 80 % of the draws and phases 1 and 4 none.
    #[test]
    fn phase_weights_set_how_often_each_phase_is_drawn() {
        let demos = [numbered(50), numbered(30)];
        let train: Vec<&Demo> = demos.iter().collect();
        let samples: Vec<(usize, usize)> = train
            .iter()
            .enumerate()
            .flat_map(|(r, d)| (0..d.steps).map(move |n| (r, n)))
            .collect();
        let p = StudentParams {
            phase_weights: [1.0, 0.0, 8.0, 1.0, 0.0],
            ..StudentParams::default()
        };
        let sampler = Sampler::new(&p, &samples, &train).expect("weights");
        let mut r = rng::stream(0, "test", "draws", 0);
        let mut counts = [0usize; 5];
        let draws = 20_000;
        for _ in 0..draws {
            let (d, n) = samples[sampler.draw(&mut r)];
            counts[usize::from(train[d].phase[n])] += 1;
        }
        assert_eq!((counts[1], counts[4]), (0, 0), "{counts:?}");
        let share = counts[2] as f64 / draws as f64;
        assert!((share - 0.8).abs() < 0.015, "{counts:?}");
        let none = StudentParams {
            phase_weights: [0.0, 1.0, 0.0, 0.0, 0.0],
            ..StudentParams::default()
        };
        let one_phase: Vec<&Demo> = vec![&demos[0]];
        let zero_phase: Vec<(usize, usize)> =
            (0..50).filter(|n| n % 5 == 0).map(|n| (0, n)).collect();
        assert!(Sampler::new(&none, &zero_phase, &one_phase).is_err());
    }

    #[test]
    fn malformed_demos_and_params_are_refused() {
        let mut d = numbered(3);
        d.actions.pop();
        let err = Student::train(&[d], &StudentParams::default(), (0, "t"), &|| {})
            .expect_err("short actions");
        assert!(err.to_string().contains("demonstration 0"), "{err}");
        let bad = StudentParams {
            time_embedding: 7,
            ..StudentParams::default()
        };
        assert!(Student::train(&[numbered(3)], &bad, (0, "t"), &|| {}).is_err());
        let bad = StudentParams {
            ema_decay: 1.0,
            ..StudentParams::default()
        };
        let err = Student::train(&[numbered(3)], &bad, (0, "t"), &|| {}).expect_err("decay 1");
        assert!(err.to_string().contains("ema_decay"), "{err}");
        let none = Student::train(&[], &StudentParams::default(), (0, "t"), &|| {});
        assert!(matches!(none, Err(Error::NoDemos { .. })));
    }

    /// Demonstrations whose every action channel is a fixed function of the current frame's
    /// one varying feature:
    /// a student learns it (its sampled actions land near the labels, far closer than the
    /// labels' spread), and training is a function of its seed.
    #[test]
    fn students_learn_a_deterministic_policy_reproducibly() {
        learns_a_deterministic_policy(0.0, false, StudentNetwork::Mlp);
    }

    /// With absolute-target labels the student predicts where the arm's target goes and
    /// executes the increment from the current target: it still reproduces the
    /// demonstrator's increments, whatever target each step starts from.
    #[test]
    fn students_with_target_labels_execute_the_demonstrated_increments() {
        learns_a_deterministic_policy(0.0, true, StudentNetwork::Mlp);
    }

    /// The arm step the target labels assume is the default control spec's.
    #[test]
    fn target_labels_use_the_default_arm_step_and_the_controllers_integration() {
        let control = osms_sim::control::ControlSpec::default();
        assert_eq!(ARM_STEP_RAD, control.arm_max_delta_rad);
        let mut d = numbered(3);
        for n in 0..3 {
            d.state[n * DEMO_STATE_LEN + 9..][..N_ARM]
                .copy_from_slice(&[0.1, -0.2, 0.3, 1.0, 0.0, 0.5, 3.1]);
            d.actions[n * N_ACTION..][..N_ARM]
                .copy_from_slice(&[0.5, -1.0, 0.0, 1.0, 0.2, -0.4, 1.0]);
        }
        let relabelled = d.with_target_labels();
        let previous: [f64; N_ACTION] = std::array::from_fn(|i| {
            if i < N_ARM {
                f64::from(d.state[9 + i])
            } else {
                0.0
            }
        });
        let action: Action = std::array::from_fn(|i| f64::from(d.actions[i]));
        let integrated =
            osms_sim::control::targets(&control, ArmAction::Increment, &previous, &action);
        for (i, t) in integrated[..N_ARM].iter().enumerate() {
            assert_eq!(relabelled.actions[i], *t as f32, "joint {i}");
        }
        assert_eq!(
            relabelled.actions[N_ARM..N_ACTION],
            d.actions[N_ARM..N_ACTION]
        );
        assert!(
            StudentParams {
                target_labels: true,
                ..StudentParams::default()
            }
            .check()
            .is_err_and(|e| e.to_string().contains("arm_target")),
            "target labels without the current target"
        );
    }

    /// The moving average of the weights is the trained network, and it learns as well.
    /// The U-Net backbone (one level over a one-step chunk) learns the same policy.
    #[test]
    fn unet_students_learn_a_deterministic_policy_reproducibly() {
        learns_a_deterministic_policy(0.0, false, StudentNetwork::Unet);
    }

    #[test]
    fn students_with_a_moving_average_of_weights_learn_too() {
        learns_a_deterministic_policy(0.99, false, StudentNetwork::Mlp);
    }

    /// Chunk c of a runner's test holds 100·c + j + k/100 at step j, channel k.
    fn numbered_chunk(c: usize, chunk: usize) -> Vec<f64> {
        (0..chunk * N_ACTION)
            .map(|i| 100.0 * c as f64 + (i / N_ACTION) as f64 + (i % N_ACTION) as f64 / 100.0)
            .collect()
    }

    fn run(execution: ChunkExecution, steps: usize) -> (Vec<bool>, Vec<Vec<f64>>) {
        let params = StudentParams {
            chunk: 4,
            ..StudentParams::default()
        };
        execution.check_for(&params).expect("valid");
        let mut runner = ChunkRunner::new(execution, &params);
        let (mut sampled, mut actions) = (Vec::new(), Vec::new());
        let mut c = 0;
        for _ in 0..steps {
            sampled.push(runner.samples());
            if runner.samples() {
                runner.push(numbered_chunk(c, 4));
                c += 1;
            }
            actions.push(runner.next());
        }
        (sampled, actions)
    }

    #[test]
    fn a_horizon_of_h_runs_h_actions_of_each_chunk_open_loop() {
        for h in [1, 2, 3, 4] {
            let (sampled, actions) = run(
                ChunkExecution {
                    horizon: h,
                    ensemble: None,
                },
                9,
            );
            for (n, (s, a)) in sampled.iter().zip(&actions).enumerate() {
                assert_eq!(*s, n % h == 0, "h = {h}, step {n}");
                // Chunk n / h, its action n mod h.
                let want = 100.0 * (n / h) as f64 + (n % h) as f64;
                assert_eq!(a[0], want, "h = {h}, step {n}");
                assert_eq!(a[5], want + 0.05, "h = {h}, step {n}");
            }
        }
    }

    #[test]
    fn the_temporal_ensemble_weights_older_predictions_by_exp_minus_m_i() {
        let m = 0.5;
        let (sampled, actions) = run(
            ChunkExecution {
                horizon: 1,
                ensemble: Some(m),
            },
            7,
        );
        assert!(sampled.iter().all(|&s| s), "a chunk every step");
        for (n, a) in actions.iter().enumerate() {
            // Chunks max(0, n − 3) ..= n predict step n, the oldest first (weight exp(0)).
            let live: Vec<usize> = (n.saturating_sub(3)..=n).collect();
            let (mut num, mut den) = (0.0, 0.0);
            for (i, &c) in live.iter().enumerate() {
                let w = (-m * i as f64).exp();
                num += w * (100.0 * c as f64 + (n - c) as f64);
                den += w;
            }
            assert!(
                (a[0] - num / den).abs() < 1e-9,
                "step {n}: {} vs {}",
                a[0],
                num / den
            );
        }
        // m = 0: the plain mean of the live predictions.
        let (_, flat) = run(
            ChunkExecution {
                horizon: 1,
                ensemble: Some(0.0),
            },
            5,
        );
        // Step 4: chunks 1..=4 predict 101 + 3, 201 + 2, 302 + 1 (their steps 3, 2, 1), 400.
        let mean = (103.0 + 202.0 + 301.0 + 400.0) / 4.0;
        assert!((flat[4][0] - mean).abs() < 1e-9, "{}", flat[4][0]);
        // A steep negative m: the newest chunk's first action, as replanning every step does.
        let (_, newest) = run(
            ChunkExecution {
                horizon: 1,
                ensemble: Some(-10.0),
            },
            6,
        );
        for (n, a) in newest.iter().enumerate() {
            assert!((a[0] - 100.0 * n as f64).abs() < 0.01, "step {n}: {}", a[0]);
        }
    }

    #[test]
    fn executions_the_chunks_cannot_carry_are_refused() {
        let params = StudentParams::default();
        let bad = |horizon, ensemble| {
            ChunkExecution { horizon, ensemble }
                .check_for(&params)
                .expect_err("refused")
                .to_string()
        };
        assert!(bad(0, None).contains("execution.horizon"));
        assert!(bad(9, None).contains("within 1 ..= 8"));
        assert!(bad(2, Some(0.01)).contains("horizon = 1"));
        assert!(bad(1, Some(-11.0)).contains("execution.ensemble"));
        assert!(bad(1, Some(f64::NAN)).contains("execution.ensemble"));
        // Within the plan's ±10, but 8 · 100 overlapping predictions would overflow.
        let long = StudentParams {
            chunk: 100,
            ..StudentParams::default()
        };
        let overflow = ChunkExecution {
            horizon: 1,
            ensemble: Some(-8.0),
        }
        .check_for(&long)
        .expect_err("overflow")
        .to_string();
        assert!(overflow.contains("overflow"), "{overflow}");
        assert!(
            ChunkExecution {
                horizon: 1,
                ensemble: Some(-1.0)
            }
            .check_for(&params)
            .is_ok(),
            "a negative m favours the newest predictions"
        );
        assert!(ChunkExecution::default().is_paper());
    }

    fn learns_a_deterministic_policy(ema_decay: f32, target_labels: bool, network: StudentNetwork) {
        let demos: Vec<Demo> = (0..12)
            .map(|r| {
                let steps = 10;
                let mut rng = rng::stream(0, "test", "demo", r);
                // One informative feature per frame; the constant rest standardises to 0.
                let deployable: Vec<f32> = (0..steps * DEPLOYABLE_LEN)
                    .map(|i| {
                        if i % DEPLOYABLE_LEN == 0 {
                            rng::uniform(&mut rng, -1.0, 1.0) as f32
                        } else {
                            0.5
                        }
                    })
                    .collect();
                let actions = (0..steps)
                    .flat_map(|n| {
                        let x = deployable[n * DEPLOYABLE_LEN];
                        (0..N_ACTION).map(move |k| 0.8 * x * if k % 2 == 0 { 1.0 } else { -1.0 })
                    })
                    .collect();
                // With target labels each step starts from its own arm target.
                let state = (0..steps * DEMO_STATE_LEN)
                    .map(|i| {
                        if target_labels && i % DEMO_STATE_LEN >= 9 {
                            rng::uniform(&mut rng, -0.5, 0.5) as f32
                        } else {
                            0.0
                        }
                    })
                    .collect();
                Demo {
                    steps,
                    deployable,
                    state,
                    phase: vec![0; steps],
                    actions,
                }
            })
            .collect();
        let params = StudentParams {
            history: 2,
            // Later steps of a chunk would depend on frames not yet seen: unpredictable here.
            chunk: 1,
            hidden: vec![64, 64],
            time_embedding: 8,
            steps: 600,
            batch: 64,
            lr: 3e-3,
            warmup: 20,
            holdout_every: 4,
            log_every: 100,
            ema_decay,
            arm_target: target_labels,
            target_labels,
            network,
            unet: UNetSpec {
                widths: vec![32],
                kernel: 3,
                cond: 64,
            },
            ..StudentParams::default()
        };
        let student = Student::train(&demos, &params, (1, "s"), &|| {}).expect("train");
        if ema_decay > 0.0 {
            let last = Student::train(
                &demos,
                &StudentParams {
                    ema_decay: 0.0,
                    ..params.clone()
                },
                (1, "s"),
                &|| {},
            )
            .expect("train");
            assert_ne!(last.net, student.net, "the average is not the last weights");
        }
        assert_eq!((student.train_rollouts, student.heldout_rollouts), (9, 3));
        let first = &student.curve[0];
        let last = student.curve.last().expect("curve");
        assert_eq!(last.step, 600);
        assert!(
            last.validation_loss.expect("held out")
                < 0.3 * first.validation_loss.expect("held out"),
            "{:?}",
            student.curve
        );
        let mut rng = rng::stream(0, "test", "act", 0);
        let mut err = 0.0f64;
        let mut count = 0;
        for d in demos.iter().skip(3).step_by(4) {
            for n in 0..d.steps {
                let mut obs = Vec::new();
                d.observation(n, &params, &mut obs);
                let a = student.act(&obs, &mut rng);
                let labels = &d.actions[n * N_ACTION..(n + 1) * N_ACTION];
                for (a, &l) in a.iter().zip(labels) {
                    err += (a - f64::from(l)).abs();
                    count += 1;
                }
            }
        }
        // The labels' mean absolute value is 0.4.
        let err = err / f64::from(count);
        assert!(
            err < 0.12,
            "mean absolute action error on held-out demos {err}"
        );
        let again = Student::train(&demos, &params, (1, "s"), &|| {}).expect("train");
        assert_eq!(again, student, "same seed, same student");
        // Resumed from a checkpoint taken mid-block of the curve's running loss (every 250
        // steps: after 250 and 500), the same student.
        let saved = std::sync::Mutex::new(Vec::new());
        let save = |s: &StudentState| {
            saved.lock().expect("lock").push(s.clone());
            Ok(())
        };
        let every = Checkpoints {
            every: 250,
            save: &save,
        };
        let through =
            Student::train_resumable(&demos, &params, (1, "s"), &|| {}, None, Some(every))
                .expect("train");
        assert_eq!(through, student, "checkpointing changes nothing");
        let saved = saved.into_inner().expect("lock");
        assert_eq!(saved.iter().map(|s| s.step).collect::<Vec<_>>(), [250, 500]);
        for checkpoint in saved {
            let step = checkpoint.step;
            let encoded = postcard::to_stdvec(&checkpoint).expect("encodes");
            let resumed = Student::train_resumable(
                &demos,
                &params,
                (1, "s"),
                &|| {},
                Some(postcard::from_bytes(&encoded).expect("decodes")),
                None,
            )
            .expect("resumes");
            assert_eq!(resumed, student, "resumed after {step} steps");
        }
        let other = Student::train(&demos, &params, (2, "s"), &|| {}).expect("train");
        assert_ne!(other.net, student.net);
    }
}
