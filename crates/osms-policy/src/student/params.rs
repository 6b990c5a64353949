//! A student's architecture and training protocol ([`StudentParams`]).

use osms_sim::policy::DEPLOYABLE_LEN;
use osms_sim::{N_ACTION, N_ARM};
use serde::{Deserialize, Serialize};

use crate::flow::UNetSpec;
use crate::{Error, Result};

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
