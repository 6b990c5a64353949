//! The catching world as a PPO [`Task`]: the privileged teacher acts as a residual on the
//! scripted catcher, rewarded by the five terms of paper section 5.1.
//!
//! Residual: the executed arm action is clamp(prior + s · r + u · g) with r the policy's arm
//! residual in [-1, 1]^7, s = `residual_scale`, and u its follow-through channel scaling g, the
//! fastest arm motion that moves the palm along the incoming direction; the hand follows the
//! prior unless `residual_hand`. With a zero-initialised actor the first policy's mean is the
//! prior. `from_scratch` drops the prior (r covers all 24 channels).

use osms_core::rng;
use osms_sim::catcher::{
    CatcherSpec, PALM_MOTION_DAMPING, ScriptedCatcher, follow_through_direction,
    palm_motion_channels,
};
use osms_sim::control::{DrSpec, hold_action};
use osms_sim::episode::{PRIVILEGED_LEN, Snapshot};
use osms_sim::vec3::{norm, sub};
use osms_sim::{
    Action, ConditionSpec, Episode, Hooks, N_ACTION, N_ARM, NoHooks, Phase, Policy, PolicyView,
    RolloutRecord, RolloutSpec, World, conditions,
};
use serde::{Deserialize, Serialize};

use crate::ppo::{Agent, EpisodeStats, Task, TaskEpisode};

/// Reward weights (paper 5.1). Every default lives here; `catch_only` zeroes the three
/// impact-mitigation terms.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RewardSpec {
    /// Catching: once, when the object is still held Δt_grasp after first contact.
    pub catching: f32,
    /// Grasp retention: per second of admissible contact after first contact.
    pub grasp_retention: f32,
    /// Velocity matching: per second, times the object–palm relative speed (m/s), while the
    /// object is within the matching distance before contact; and once if v_rel > δ_v.
    pub velocity_matching: f32,
    /// Peak-impact-force mitigation: per second, times the admissible normal force above δ_f / 2
    /// in units of δ_f; and once if f_max > δ_f.
    pub impact_force: f32,
    /// Follow-through: per metre of new palm progress along the incoming direction (up to δ_ℓ)
    /// within Δt_eval, in units of δ_ℓ; the sum reaches this weight at δ_ℓ.
    pub follow_through: f32,
    /// How far, in units of δ_ℓ, follow-through progress keeps earning at the same rate. At 1
    /// a policy is paid for exactly the criterion and learns to stop at it, so a DR draw that
    /// shortens its travel by a few centimetres fails ℓ_max; above 1 it is paid for a margin.
    pub follow_through_reach: f32,
    /// Task success: once, when the rollout meets every criterion. Not one of the paper's five
    /// terms: with them alone a completed catch earns the catching reward whether or not it
    /// met δ_f and δ_ℓ, so a policy trades an impact failure (−`impact_force`, or a little
    /// less follow-through) for any lower risk of a drop (−`catching`). 0: the paper's reward.
    pub success: f32,
}

impl Default for RewardSpec {
    fn default() -> Self {
        RewardSpec {
            catching: 10.0,
            grasp_retention: 1.0,
            velocity_matching: 1.0,
            impact_force: 2.0,
            follow_through: 5.0,
            follow_through_reach: 1.0,
            success: 0.0,
        }
    }
}

impl RewardSpec {
    /// Catching and grasp retention only (the catching-only baseline of Table I).
    pub fn catch_only() -> Self {
        RewardSpec {
            velocity_matching: 0.0,
            impact_force: 0.0,
            follow_through: 0.0,
            success: 0.0,
            ..RewardSpec::default()
        }
    }
}

/// How the teacher's episodes are made. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CatchTaskSpec {
    pub rollout: RolloutSpec,
    pub conditions: ConditionSpec,
    pub catcher: CatcherSpec,
    pub reward: RewardSpec,
    /// s in clamp(prior + s · r).
    pub residual_scale: f32,
    /// Train without the scripted prior (for machines with a larger budget).
    pub from_scratch: bool,
    /// Residuals on the 17 hand channels too. Off by default: the prior's open/close timing
    /// already completes most catches, impact mitigation is arm motion, and exploration noise
    /// on absolute finger targets costs more catches than it teaches on a 2-core budget.
    pub residual_hand: bool,
    /// Give the policy one more action channel u ∈ [-1, 1] that moves the palm along the
    /// object's incoming direction (frozen at first contact) at up to the fastest rate one
    /// control step allows: executed arm = clamp(prior + s · r + u · g). Without it PPO has to
    /// discover the Jacobian-dependent joint combination of a follow-through by itself.
    pub follow_through_channel: bool,
    /// Give the policy one more action channel c ∈ [-1, 1] over the whole hand: the executed
    /// hand action moves by c · (closed − open) from the prior's (in action units), so the
    /// policy can close earlier or later, or squeeze less, without exploring 17 absolute finger
    /// targets. Its index follows the follow-through channel's. On the development stream
    /// (issue 32) it took the teacher from 49.0 % to 69.4 % success: the policy learns to
    /// squeeze less, and f_max fell from 52 N to 32 N.
    pub grasp_channel: bool,
    /// Weight of the palm's orientation against its position when `g` is computed (see
    /// `osms_sim::catcher::palm_motion_channels`). 0: letting the palm turn adds about 12 cm of
    /// reachable follow-through (docs/sim.md), and on the development stream the teacher
    /// completed 74.2 % of catches at 0 against 60.8 % at 0.3 (400 iterations).
    pub palm_motion_orientation_weight: f64,
}

impl Default for CatchTaskSpec {
    fn default() -> Self {
        CatchTaskSpec {
            rollout: RolloutSpec::default(),
            conditions: ConditionSpec::default(),
            catcher: CatcherSpec::default(),
            reward: RewardSpec::default(),
            residual_scale: 0.5,
            from_scratch: false,
            residual_hand: false,
            follow_through_channel: true,
            grasp_channel: true,
            palm_motion_orientation_weight: 0.0,
        }
    }
}

impl CatchTaskSpec {
    /// This task with the rollouts' domain randomisation replaced when `dr` is given (an
    /// evaluation or a dataset under another DR setting than the teacher trained with).
    pub fn with_dr(&self, dr: &Option<DrSpec>) -> CatchTaskSpec {
        let mut task = self.clone();
        if let Some(dr) = dr {
            task.rollout.dr = dr.clone();
        }
        task
    }

    /// How many action channels get a residual: the arm's, and the hand's if `residual_hand`
    /// (always all of them from scratch).
    pub fn residual_channels(&self) -> usize {
        if self.residual_hand || self.from_scratch {
            N_ACTION
        } else {
            N_ARM
        }
    }

    /// The policy's action size: the residual channels, the follow-through channel and the
    /// grasp channel.
    pub fn act_len(&self) -> usize {
        self.residual_channels()
            + usize::from(self.follow_through_channel)
            + usize::from(self.grasp_channel)
    }
}

/// Observation: the privileged frame, the prior's action and the phase (one-hot).
pub const OBS_LEN: usize = PRIVILEGED_LEN + N_ACTION + 5;

/// The catching task. Episode `i` draws ω from stream (`stream`, i) of (`seed`, `stage`), and
/// its own DR draws and noise from (`stream`-dr, i).
pub struct CatchTask<'w> {
    pub world: &'w World,
    pub spec: CatchTaskSpec,
    pub seed: u64,
    pub stage: String,
    pub stream: String,
}

impl<'w> CatchTask<'w> {
    /// Checks that conditions can be drawn at all (an infeasible sampler is a user error before
    /// training starts; a later draw that fails stops training with an error).
    pub fn new(
        world: &'w World,
        spec: CatchTaskSpec,
        seed: u64,
        stage: &str,
        stream: &str,
    ) -> osms_sim::Result<Self> {
        spec.catcher.validate()?;
        draw(world, &spec, (seed, stage, stream), 0)?;
        Ok(CatchTask {
            world,
            spec,
            seed,
            stage: stage.to_string(),
            stream: stream.to_string(),
        })
    }

    /// ω of episode `index`.
    pub fn condition(&self, index: u64) -> osms_sim::Result<conditions::TaskCondition> {
        draw(
            self.world,
            &self.spec,
            (self.seed, &self.stage, &self.stream),
            index,
        )
    }
}

/// ω number `index` of the stream (seed, stage, stream).
fn draw(
    world: &World,
    spec: &CatchTaskSpec,
    (seed, stage, stream): (u64, &str, &str),
    index: u64,
) -> osms_sim::Result<conditions::TaskCondition> {
    let mut r = rng::stream(seed, stage, stream, index);
    conditions::sample(&spec.conditions, world.home_palm_pos, &mut r)
}

/// The prior plus a residual, as the simulator's policy for one control step.
struct Residual<'a, 'b> {
    prior: &'a mut ScriptedCatcher,
    spec: &'a CatchTaskSpec,
    phase: u8,
    act: &'a mut dyn FnMut(&[f32]) -> Vec<f32>,
    executed: &'b mut Action,
}

impl Policy for Residual<'_, '_> {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        let out = residual_action(self.prior, self.spec, self.phase, view, self.act);
        *self.executed = out;
        out
    }
}

/// The executed action of the residual policy `act` on the prior (advancing the prior's state).
fn residual_action(
    prior: &mut ScriptedCatcher,
    spec: &CatchTaskSpec,
    phase: u8,
    view: &PolicyView<'_>,
    act: &mut dyn FnMut(&[f32]) -> Vec<f32>,
) -> Action {
    let prior = if spec.from_scratch {
        [0.0; N_ACTION]
    } else {
        prior.act(view)
    };
    let mut obs = Vec::with_capacity(OBS_LEN);
    obs.extend(view.privileged.iter().map(|&v| v as f32));
    obs.extend(prior.iter().map(|&v| v as f32));
    obs.extend((0..5u8).map(|p| f32::from(u8::from(p == phase))));
    let r = act(&obs);
    let scale = f64::from(spec.residual_scale);
    let mut out = prior;
    let residual_channels = spec.residual_channels();
    for (o, r) in out.iter_mut().zip(&r[..residual_channels]) {
        *o += scale * f64::from(*r);
    }
    if spec.follow_through_channel {
        let u = f64::from(r.get(residual_channels).copied().unwrap_or(0.0));
        if u != 0.0 {
            let g = palm_motion_channels(
                view,
                follow_through_direction(view),
                spec.palm_motion_orientation_weight,
                PALM_MOTION_DAMPING,
            );
            for (o, g) in out.iter_mut().zip(g) {
                *o += u * g;
            }
        }
    }
    if spec.grasp_channel {
        let at = residual_channels + usize::from(spec.follow_through_channel);
        let c = f64::from(r.get(at).copied().unwrap_or(0.0));
        if c != 0.0 {
            let closed = hold_action(&spec.catcher.closed_hand_rad);
            let open = hold_action(&spec.catcher.open_hand_rad);
            for k in N_ARM..N_ACTION {
                out[k] += c * (closed[k] - open[k]);
            }
        }
    }
    for o in &mut out {
        *o = o.clamp(-1.0, 1.0);
    }
    out
}

/// The frozen teacher queried at states another policy visits (paper 4.3: the IL students'
/// actions are paired with the teacher's at the states the students reach). It keeps its own
/// prior and phase input, which follow the visited states as they would in a teacher rollout;
/// call [`TeacherQuery::observe_phase`] with each step's recorded phase.
pub struct TeacherQuery<'a> {
    agent: &'a Agent,
    spec: &'a CatchTaskSpec,
    prior: ScriptedCatcher,
    phase: u8,
}

impl<'a> TeacherQuery<'a> {
    pub fn new(agent: &'a Agent, spec: &'a CatchTaskSpec) -> Self {
        TeacherQuery {
            agent,
            spec,
            prior: ScriptedCatcher::new(spec.catcher.clone(), spec.rollout.control.clone()),
            phase: Phase::Approach as u8,
        }
    }

    /// The teacher's deterministic action at the state `view` shows.
    pub fn act(&mut self, view: &PolicyView<'_>) -> Action {
        let agent = self.agent;
        residual_action(&mut self.prior, self.spec, self.phase, view, &mut |obs| {
            agent.act_deterministic(obs)
        })
    }

    /// The phase the last control step ended in (`Phase as u8`), the teacher's phase input at
    /// the next step.
    pub fn observe_phase(&mut self, phase: u8) {
        self.phase = phase;
    }

    /// The phase input the next [`TeacherQuery::act`] uses.
    pub fn phase(&self) -> u8 {
        self.phase
    }
}

/// A running catching episode with its reward bookkeeping.
pub struct CatchEpisode<'w> {
    episode: Episode<'w>,
    prior: ScriptedCatcher,
    reward: RewardSpec,
    spec: &'w CatchTaskSpec,
    /// The last step's recorded phase (`Phase as u8`), the policy's phase input.
    phase: u8,
    /// The follow-through already rewarded (m, up to δ_ℓ).
    rewarded_follow_through: f64,
}

/// An exact copy of a catching episode at the start of a control step: the simulator's
/// snapshot and the policy side (the prior's state, the phase input, the reward bookkeeping).
/// Restoring it and stepping on with the same actions reproduces the episode bit for bit.
#[derive(Clone)]
pub struct CatchSnapshot {
    episode: Snapshot,
    prior: ScriptedCatcher,
    phase: u8,
    rewarded_follow_through: f64,
}

impl<'w> Task for CatchTask<'w> {
    type Episode<'a>
        = CatchEpisode<'a>
    where
        Self: 'a;
    type Error = osms_sim::SimError;

    fn obs_len(&self) -> usize {
        OBS_LEN
    }

    fn act_len(&self) -> usize {
        self.spec.act_len()
    }

    fn start(&self, index: u64) -> osms_sim::Result<CatchEpisode<'_>> {
        let condition = self.condition(index)?;
        let dr_stream = format!("{}-dr", self.stream);
        let r = rng::stream(self.seed, &self.stage, &dr_stream, index);
        Ok(CatchEpisode::new(self.world, &self.spec, condition, r))
    }
}

impl<'w> CatchEpisode<'w> {
    /// An episode on condition ω whose domain randomisation draws from `rng`.
    pub fn new(
        world: &'w World,
        spec: &'w CatchTaskSpec,
        condition: conditions::TaskCondition,
        rng: rng::StreamRng,
    ) -> Self {
        CatchEpisode {
            episode: Episode::new(world, &spec.rollout, condition, rng),
            prior: ScriptedCatcher::new(spec.catcher.clone(), spec.rollout.control.clone()),
            reward: spec.reward.clone(),
            spec,
            phase: Phase::Approach as u8,
            rewarded_follow_through: 0.0,
        }
    }

    /// The simulator episode (its record, first contact, step index).
    pub fn episode(&self) -> &Episode<'w> {
        &self.episode
    }

    /// A copy of the whole episode state at the start of the next control step.
    pub fn snapshot(&self) -> CatchSnapshot {
        CatchSnapshot {
            episode: self.episode.snapshot(),
            prior: self.prior.clone(),
            phase: self.phase,
            rewarded_follow_through: self.rewarded_follow_through,
        }
    }

    /// Returns to `snapshot`, taken from this episode (even after it has ended).
    pub fn restore(&mut self, snapshot: &CatchSnapshot) {
        self.episode.restore(&snapshot.episode);
        self.prior = snapshot.prior.clone();
        self.phase = snapshot.phase;
        self.rewarded_follow_through = snapshot.rewarded_follow_through;
    }

    /// Runs the episode to its end with `act` choosing the policy's actions, and returns its
    /// record (the intended actions are the executed residual actions).
    pub fn run(self, act: &mut dyn FnMut(&[f32]) -> Vec<f32>) -> RolloutRecord {
        self.run_with_hooks(act, &mut NoHooks)
    }

    /// [`CatchEpisode::run`] with `hooks` changing or watching every step.
    pub fn run_with_hooks(
        mut self,
        act: &mut dyn FnMut(&[f32]) -> Vec<f32>,
        hooks: &mut dyn Hooks,
    ) -> RolloutRecord {
        while !self.step_with_hooks(act, hooks).1 {}
        self.episode.finish()
    }
}

/// The frozen teacher's rollout on condition ω: deterministic actions tanh(μ(s)).
pub fn rollout(
    world: &World,
    spec: &CatchTaskSpec,
    agent: &Agent,
    condition: conditions::TaskCondition,
    rng: rng::StreamRng,
) -> RolloutRecord {
    CatchEpisode::new(world, spec, condition, rng).run(&mut |obs| agent.act_deterministic(obs))
}

/// DART's noise injection (Laskey et al. 2017): Gaussian noise of standard deviation `sigma`
/// on the arm channels of every executed action, drawn from `rng`, while the record keeps the
/// teacher's intended actions, the labels a student learns. The teacher then visits the states
/// a student's arm errors lead to and shows how it recovers from them.
pub struct ArmNoise {
    pub sigma: f64,
    pub rng: rng::StreamRng,
}

impl Hooks for ArmNoise {
    fn perturb(&mut self, _step: usize, action: &mut Action) {
        for a in &mut action[..N_ARM] {
            *a = (*a + self.sigma * rng::normal(&mut self.rng)).clamp(-1.0, 1.0);
        }
    }
}

/// Entry `k` of a record's 3-wide per-step array.
fn at3(v: &[f32], k: usize) -> [f64; 3] {
    [v[3 * k], v[3 * k + 1], v[3 * k + 2]].map(f64::from)
}

impl TaskEpisode for CatchEpisode<'_> {
    fn step(&mut self, act: &mut dyn FnMut(&[f32]) -> Vec<f32>) -> (f32, bool) {
        self.step_with_hooks(act, &mut NoHooks)
    }

    fn finish(self) -> EpisodeStats {
        let (outcome, metrics) = self.episode.outcome();
        EpisodeStats {
            success: outcome.success(),
            completion: outcome.completion(),
            f_max_n: outcome.completion().then_some(metrics.max_force_n),
        }
    }
}

impl CatchEpisode<'_> {
    /// One control step, as [`TaskEpisode::step`], with `hooks` changing or watching the rollout
    /// (an OSW snippet over the arm, modelled action errors, a contact witness).
    pub fn step_with_hooks(
        &mut self,
        act: &mut dyn FnMut(&[f32]) -> Vec<f32>,
        hooks: &mut dyn Hooks,
    ) -> (f32, bool) {
        let episode = &mut self.episode;
        if episode.is_done() {
            return (0.0, true);
        }
        let mut executed = [0.0; N_ACTION];
        let mut policy = Residual {
            prior: &mut self.prior,
            spec: self.spec,
            phase: self.phase,
            act,
            executed: &mut executed,
        };
        let running = episode.step(&mut policy, hooks);
        let dt = episode.control_period_secs();
        let success = &self.spec.rollout.success;
        let w = &self.reward;
        let rec = episode.record();
        let k = rec.steps - 1;
        let phase_after = rec.phase.get(k).copied().unwrap_or(0);
        let mut reward = 0.0f64;
        let force = f64::from(rec.normal_force[k]);
        if episode.first_contact().is_none() {
            if phase_after == Phase::VelocityMatching as u8 {
                let (palm_vel, object_vel) = (at3(&rec.palm_vel, k), at3(&rec.object_vel, k));
                reward -= f64::from(w.velocity_matching) * norm(sub(object_vel, palm_vel)) * dt;
            }
        } else {
            if force > 0.0 {
                reward += f64::from(w.grasp_retention) * dt;
            }
            let excess = (force - 0.5 * success.max_force_n).max(0.0) / success.max_force_n;
            reward -= f64::from(w.impact_force) * excess * dt;
            // ℓ_max as the success criterion measures it: along the pre-contact incoming
            // direction, from the palm at t_c, within Δt_eval.
            let progress = episode
                .follow_through_m()
                .min(f64::from(w.follow_through_reach) * success.min_follow_through_m);
            if progress > self.rewarded_follow_through {
                reward += f64::from(w.follow_through) * (progress - self.rewarded_follow_through)
                    / success.min_follow_through_m;
                self.rewarded_follow_through = progress;
            }
        }
        self.phase = phase_after;
        if running {
            return (reward as f32, false);
        }
        let (outcome, m) = episode.outcome();
        if outcome.completion() {
            reward += f64::from(w.catching);
        }
        if m.contact_speed_mps
            .is_some_and(|v| v > success.max_contact_speed_mps)
        {
            reward -= f64::from(w.velocity_matching);
        }
        if m.max_force_n > success.max_force_n {
            reward -= f64::from(w.impact_force);
        }
        if outcome.success() {
            reward += f64::from(w.success);
        }
        (reward as f32, true)
    }
}
