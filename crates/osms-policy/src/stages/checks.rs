//! The valid ranges of this crate's params (`osms_core::check`), in one place so that they are
//! read together. Caps are sanity bounds far above every profile's value. It lives with the
//! stages, which check params, so that no library module imports `stages`.

use osms_core::check::{
    Check, Checked, Invalid, count, each, nested, positive, unit, widths, within,
};

use super::{
    CollectParams, DaggerRoundParams, ErrorPairsParams, EvalStudentParams, EvalTeacherParams,
    EvaluateParams, TeacherParams,
};
use crate::catch::{CatchTaskSpec, RewardSpec};
use crate::flow::UNetSpec;
use crate::osw::OswSpec;
use crate::ppo::PpoConfig;
use crate::student::{ChunkExecution, StudentNetwork, StudentParams};

/// Layer widths and other network sizes.
const WIDTH: u64 = 16_384;
/// Optimiser steps, PPO iterations, epochs.
const STEPS: u64 = 100_000_000;

impl Check for RewardSpec {
    fn check(&self) -> Checked {
        for (field, w) in [
            ("catching", self.catching),
            ("grasp_retention", self.grasp_retention),
            ("velocity_matching", self.velocity_matching),
            ("impact_force", self.impact_force),
            ("follow_through", self.follow_through),
            ("success", self.success),
            ("residual_rate", self.residual_rate),
        ] {
            within(field, w, 0.0, 1e6)?;
        }
        positive("follow_through_reach", self.follow_through_reach, 100.0)
    }
}

impl Check for CatchTaskSpec {
    fn check(&self) -> Checked {
        nested("rollout", &self.rollout)?;
        nested("conditions", &self.conditions)?;
        nested("catcher", &self.catcher)?;
        nested("reward", &self.reward)?;
        within("residual_scale", self.residual_scale, 0.0, 100.0)?;
        within(
            "palm_motion_orientation_weight",
            self.palm_motion_orientation_weight,
            0.0,
            1e3,
        )
    }
}

impl Check for PpoConfig {
    fn check(&self) -> Checked {
        count("iterations", self.iterations, 1, STEPS)?;
        count(
            "episodes_per_iteration",
            self.episodes_per_iteration,
            1,
            1_000_000,
        )?;
        widths("hidden", &self.hidden, WIDTH)?;
        unit("gamma", self.gamma)?;
        unit("lambda", self.lambda)?;
        positive("clip", self.clip, 10.0)?;
        within("value_coef", self.value_coef, 0.0, 1e3)?;
        within("entropy_coef", self.entropy_coef, 0.0, 1e3)?;
        count("epochs", self.epochs, 1, 10_000)?;
        if let Some(kl) = self.target_kl {
            positive("target_kl", kl, 100.0)?;
        }
        count("minibatch", self.minibatch, 1, 10_000_000)?;
        positive("lr", self.lr, 1.0)?;
        unit("lr_final_fraction", self.lr_final_fraction)?;
        positive("max_grad_norm", self.max_grad_norm, 1e6)?;
        within("init_log_std", self.init_log_std, -20.0, 5.0)?;
        positive("obs_clip", self.obs_clip, 1e6)
    }
}

impl Check for TeacherParams {
    fn check(&self) -> Checked {
        nested("task", &self.task)?;
        nested("ppo", &self.ppo)
    }
}

impl Check for StudentParams {
    fn check(&self) -> Checked {
        count("history", self.history, 1, 1000)?;
        count("chunk", self.chunk, 1, 1000)?;
        count("euler_steps", self.euler_steps, 1, 10_000)?;
        within("noise_scale", self.noise_scale, 0.0, 100.0)?;
        widths("hidden", &self.hidden, WIDTH)?;
        count("time_embedding", self.time_embedding, 2, WIDTH)?;
        if !self.time_embedding.is_multiple_of(2) {
            return Err(Invalid::new(
                "time_embedding",
                format!(
                    "{} is not valid here: expected an even number (sine and cosine pairs) in [2, {WIDTH}]",
                    self.time_embedding
                ),
            ));
        }
        count("steps", self.steps, 1, STEPS)?;
        count("batch", self.batch, 1, 1_000_000)?;
        positive("lr", self.lr, 1.0)?;
        within("min_lr", self.min_lr, 0.0, f64::from(self.lr))?;
        count("warmup", self.warmup, 0, STEPS)?;
        within("weight_decay", self.weight_decay, 0.0, 1.0)?;
        positive("max_grad_norm", self.max_grad_norm, 1e6)?;
        count("holdout_every", self.holdout_every, 0, 1_000_000)?;
        count("log_every", self.log_every, 1, STEPS)?;
        positive("obs_clip", self.obs_clip, 1e6)?;
        if self.target_labels && !self.arm_target {
            return Err(Invalid::new(
                "target_labels",
                "true needs arm_target = true: an absolute arm target is executed as the increment from the controller's current target, which the student must then read",
            ));
        }
        // 1 would freeze the average at its initial weights.
        within("ema_decay", self.ema_decay, 0.0, 0.999_999)?;
        let weights = self.phase_weights.map(f64::from);
        each("phase_weights", &weights, 0.0, 1e6)?;
        if weights.iter().all(|w| *w == 0.0) {
            return Err(Invalid::new(
                "phase_weights",
                "all 0 is not valid here: at least one phase needs a positive weight",
            ));
        }
        nested("unet", &self.unet)?;
        if self.network == StudentNetwork::Unet {
            let halvings = self.unet.widths.len().saturating_sub(1) as u32;
            if !self.chunk.is_multiple_of(1 << halvings) {
                return Err(Invalid::new(
                    "unet.widths",
                    format!(
                        "{} levels are not valid here: the chunk's {} steps must halve {halvings} times (one level per halving, plus one)",
                        self.unet.widths.len(),
                        self.chunk
                    ),
                ));
            }
        }
        Ok(())
    }
}

impl Check for UNetSpec {
    fn check(&self) -> Checked {
        widths("widths", &self.widths, WIDTH)?;
        count("kernel", self.kernel, 1, 15)?;
        if self.kernel.is_multiple_of(2) {
            return Err(Invalid::new(
                "kernel",
                format!(
                    "{} is not valid here: expected an odd number in [1, 15] (a centred window)",
                    self.kernel
                ),
            ));
        }
        count("cond", self.cond, 1, WIDTH)
    }
}

impl Check for OswSpec {
    fn check(&self) -> Checked {
        count("h_os", self.h_os, 1, 1000)
    }
}

impl Check for CollectParams {
    fn check(&self) -> Checked {
        count("n", self.n, 1, 10_000_000)?;
        count("max_attempts", self.max_attempts, 1, 100_000)?;
        nested("osw", &self.osw)?;
        if let Some(dr) = &self.dr {
            nested("dr", dr)?;
        }
        within("dart_arm_noise", self.dart_arm_noise, 0.0, 10.0)
    }
}

impl Check for EvalTeacherParams {
    fn check(&self) -> Checked {
        match &self.dr {
            Some(dr) => nested("dr", dr),
            None => Ok(()),
        }
    }
}

impl Check for ErrorPairsParams {
    fn check(&self) -> Checked {
        match &self.dr {
            Some(dr) => nested("dr", dr),
            None => Ok(()),
        }
    }
}

impl Check for DaggerRoundParams {
    fn check(&self) -> Checked {
        count("rounds", self.rounds, 1, 100)?;
        if let Some(b) = self.conditions {
            count("conditions", b, 1, 10_000_000)?;
        }
        match &self.dr {
            Some(dr) => nested("dr", dr),
            None => Ok(()),
        }
    }
}

impl Check for EvalStudentParams {
    fn check(&self) -> Checked {
        nested("rollout", &self.rollout)?;
        nested("execution", &self.execution)
    }
}

/// The ranges a plan can check without the student (its chunk length bounds the horizon when
/// the stage runs, [`ChunkExecution::check_for`]).
impl Check for ChunkExecution {
    fn check(&self) -> Checked {
        count("horizon", self.horizon, 1, 1_000)?;
        if let Some(m) = self.ensemble {
            within("ensemble", m, -10.0, 10.0)?;
            if self.horizon != 1 {
                return Err(Invalid::new(
                    "horizon",
                    "the temporal ensemble samples a chunk every step (set horizon = 1 or leave ensemble out)",
                ));
            }
        }
        Ok(())
    }
}

impl Check for EvaluateParams {
    fn check(&self) -> Checked {
        nested("rollout", &self.rollout)?;
        nested("execution", &self.execution)?;
        nested("catcher", &self.catcher)?;
        if let Some(frames) = self.prior_fit_frames {
            if self.prior_inputs.perception().estimated_object.is_none() {
                return Err(Invalid::new(
                    "prior_fit_frames",
                    format!(
                        "prior_inputs = {:?} reads the observed velocity, not a fit (set prior_inputs to observed_velocity or a later rung, or leave prior_fit_frames out)",
                        self.prior_inputs
                    ),
                ));
            }
            count("prior_fit_frames", frames, 2, 10_000)?;
        }
        Ok(())
    }
}
