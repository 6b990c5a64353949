//! `teacher`: the privileged PPO teacher, a residual on the scripted catcher (paper 5.1).

use osms_make::{Ctx, Kind, Numerics, Scale, Slot, Stage, StageError};
use osms_sim::artifacts::WorldArtifact;
use serde::{Deserialize, Serialize};

use crate::artifacts::Teacher;
use crate::catch::{CatchTask, CatchTaskSpec};
use crate::checkpoint::Checkpoints;
use crate::ppo::{Agent, PpoConfig, PpoState, Task, train};

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TeacherParams {
    /// The catching task: rollout settings, condition sampler, prior, reward weights.
    pub task: CatchTaskSpec,
    pub ppo: PpoConfig,
}

/// PPO iterations between checkpoints (pipeline.toml's `checkpoint_every` overrides it): the
/// default teacher's 800 iterations take ≈ 20 minutes on 2 cores, so a kill loses ≈ 1 minute.
const CHECKPOINT_EVERY: u32 = 50;

/// PPO on the catching task; episode i of iteration t draws ω from stream ("train", t·E + i).
pub struct TeacherStage;
impl Kind for TeacherStage {
    const KIND: &'static str = "teacher";
    /// 3: the actor's inputs are a declared rung (`task.actor_inputs`) with a privileged
    /// critic, and the task is stored realised (issue 54). 4: deployable frames carry the
    /// palm's touch reading, which the `touch` and `deployable` rungs' actors read.
    const CODE_VERSION: u32 = 4;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[Slot::one::<WorldArtifact>("world")];
    const DOC: &'static str =
        "the privileged PPO teacher: a residual on the scripted catcher, rewarded by paper 5.1";
    type Params = TeacherParams;

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }

    /// PPO's episodes (their rollouts dominate; the network's width is not counted).
    fn scale(params: &TeacherParams, _: &[(&str, f64)]) -> Scale {
        Scale {
            work: f64::from(params.ppo.iterations) * f64::from(params.ppo.episodes_per_iteration),
            size: 1.0,
        }
    }
}

impl Stage for TeacherStage {
    type Output = Teacher;

    fn run(&self, ctx: &Ctx<'_, TeacherParams>) -> Result<Teacher, StageError> {
        let world = ctx.input::<WorldArtifact>("world")?.world()?;
        let seed = ctx.seed().unwrap_or_default();
        let p = ctx.params;
        if p.ppo.episodes_per_iteration == 0 || p.ppo.minibatch == 0 {
            return Err(
                "params.ppo: episodes_per_iteration and minibatch must be at least 1".into(),
            );
        }
        if !(0.0..=1.0).contains(&p.ppo.lr_final_fraction) {
            return Err(format!(
                "params.ppo.lr_final_fraction: {} is not in [0, 1] (1 keeps the rate constant)",
                p.ppo.lr_final_fraction
            )
            .into());
        }
        if let Some(target) = p.ppo.target_kl.filter(|t| !(t.is_finite() && *t > 0.0)) {
            return Err(format!(
                "params.ppo.target_kl: {target} is not a positive number (leave it out to run every epoch)"
            )
            .into());
        }
        let spec = p.task.realised();
        let task = CatchTask::new(&world, spec.clone(), seed, ctx.stage(), "train")?;
        let mut state = match ctx.resume::<PpoState>() {
            Some(state) => state,
            None => {
                let agent = Agent::asymmetric(
                    task.obs_len(),
                    task.actor_obs_len(),
                    task.act_len(),
                    &p.ppo,
                    (seed, ctx.stage()),
                )
                .map_err(|e| format!("params.ppo: {e}"))?;
                PpoState::new(agent, &p.ppo)
            }
        };
        let progress = ctx.progress();
        progress.set_total(u64::from(p.ppo.iterations));
        progress.inc(u64::from(state.done()));
        let save = |s: &PpoState| {
            ctx.checkpoint(u64::from(s.done()), s)
                .map_err(|e| e.to_string())
        };
        let checkpoints = Checkpoints {
            every: ctx.checkpoint_every(CHECKPOINT_EVERY),
            save: &save,
        };
        train(
            &task,
            &mut state,
            &p.ppo,
            (seed, ctx.stage()),
            &|_| progress.inc(1),
            Some(checkpoints),
        )?;
        let agent = state.agent;
        Ok(Teacher { task: spec, agent })
    }
}
