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
    CatcherSpec, PALM_MOTION_DAMPING, Perception, ScriptedCatcher, palm_motion_channels,
};
use osms_sim::control::{DrSpec, hold_action};
use osms_sim::episode::Snapshot;
use osms_sim::policy::{
    DEPLOYABLE_LEN, OBSERVED_OBJECT, PALM_TOUCH, PRIVILEGED_LEN, PRIVILEGED_PALM,
};
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
    /// Smoothness, not one of the paper's terms (issue 54): per second, times the squared
    /// change of the policy's action channels (residuals, follow-through, grasp) from the
    /// previous step, summed over the channels. Smoother commands are easier for a student to
    /// imitate and survive modelled action errors better. 0: off.
    pub residual_rate: f32,
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
            residual_rate: 0.0,
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

/// What the teacher's actor acts on (issue 54): a ladder from the privileged actor to the
/// students' own inputs, each rung removing more of what no student can know. The critic
/// always reads the privileged observation (asymmetric actor-critic), and the scripted prior
/// reads the world as the rung's actor does ([`ActorInputs::perception`]), so the teacher's
/// whole command (prior + residual) is a function of the rung's inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ActorInputs {
    /// The privileged frame (robot, observed object state with its delayed exact velocity,
    /// palm, contact force and count, ω's mass and variant, time), the prior's action and the
    /// phase.
    #[default]
    Privileged,
    /// Without ω's mass and variant and the episode time; the prior aims with the variants'
    /// mean radius.
    NoIdentity,
    /// And the object's velocity and orientation replaced by what the students get: the
    /// observed positions' differences over [`REALISABLE_HISTORY`] frames and a ballistic
    /// least-squares fit to them (position and velocity), which the prior reads too.
    ObservedVelocity,
    /// And no contact count, contact force or phase (the phase is entered on the simulator's
    /// contact): the prior closes the hand on the observed distance only, and the
    /// follow-through moves along the flight direction seen when it began to close.
    NoContact,
    /// The students' exact observation ([`REALISABLE_HISTORY`] deployable frames, the palm's
    /// position and velocity and the object's offset from it, the observed positions'
    /// differences), plus the ballistic fit and the prior's action, both functions of it.
    Deployable,
    /// `NoContact` plus the palm's touch readings of the last [`REALISABLE_HISTORY`] frames
    /// (the deployable contact signal, `osms_sim::policy::PALM_TOUCH`). Declared after the
    /// others so they keep their keys; on the ladder it sits between `NoContact` and
    /// `Deployable`.
    Touch,
    /// `NoContact` with the object read from the delay-aware flight estimate over every
    /// observation so far (`osms_sim::flight`: the observation delay read off the first
    /// frames, a ballistic least-squares fit, extrapolated to the present) instead of the
    /// 8-frame fit, by the actor and the prior (issue 66). Declared last so the other rungs
    /// keep their keys; on the ladder it sits beside `NoContact`.
    Tracked,
}

/// Frames of deployable history the realisable rungs read: the students' default history.
pub const REALISABLE_HISTORY: usize = 8;

impl ActorInputs {
    pub fn is_privileged(&self) -> bool {
        *self == ActorInputs::Privileged
    }

    /// How the prior reads the world on this rung.
    pub fn perception(self) -> Perception {
        Perception {
            nominal_radius: self >= ActorInputs::NoIdentity,
            estimated_object: (self >= ActorInputs::ObservedVelocity).then_some(REALISABLE_HISTORY),
            close_on_distance_only: self >= ActorInputs::NoContact,
            hold_steps: 0,
            tracked: self == ActorInputs::Tracked,
        }
    }

    /// Frames of deployable history the rung needs: the prior's fit window, else one.
    pub fn history(self) -> usize {
        self.perception().estimated_object.unwrap_or(1)
    }

    /// `base` keeping at least the history this rung reads (a longer one is left alone: the
    /// rung reads the newest frames).
    pub fn rollout(self, base: &RolloutSpec) -> RolloutSpec {
        let mut spec = base.clone();
        spec.history_steps = spec.history_steps.max(self.history());
        spec
    }

    /// Length of the actor's observation.
    pub fn obs_len(self) -> usize {
        let h = REALISABLE_HISTORY;
        let differences = 3 * (h - 1);
        match self {
            ActorInputs::Privileged => OBS_LEN,
            ActorInputs::NoIdentity => IDENTITY + N_ACTION + 5,
            ActorInputs::ObservedVelocity => 48 + 3 + 9 + 2 + 6 + differences + N_ACTION + 5,
            ActorInputs::NoContact | ActorInputs::Tracked => {
                48 + 3 + 9 + 6 + differences + N_ACTION
            }
            ActorInputs::Deployable => h * DEPLOYABLE_LEN + 9 + differences + 6 + N_ACTION,
            ActorInputs::Touch => 48 + 3 + 9 + 6 + differences + h + N_ACTION,
        }
    }
}

/// Where ω's mass, the variant one-hot and the time start in a privileged frame.
const IDENTITY: usize = 48 + 13 + 9 + 2;

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
    /// What the actor (and the prior) act on: today's privileged actor or a more realisable
    /// rung (issue 54).
    pub actor_inputs: ActorInputs,
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
            actor_inputs: ActorInputs::Privileged,
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

    /// This task with the rollouts' history raised to what the actor reads.
    pub fn realised(&self) -> CatchTaskSpec {
        CatchTaskSpec {
            rollout: self.actor_inputs.rollout(&self.rollout),
            ..self.clone()
        }
    }

    /// The observation's length: the actor's inputs, then (on a realisable rung) the
    /// privileged observation the critic reads besides.
    pub fn obs_len(&self) -> usize {
        match self.actor_inputs {
            ActorInputs::Privileged => OBS_LEN,
            rung => rung.obs_len() + OBS_LEN,
        }
    }

    /// How many leading observation entries the actor reads.
    pub fn actor_obs_len(&self) -> usize {
        self.actor_inputs.obs_len()
    }

    /// The scripted prior as this task's actor rung reads the world.
    pub fn prior(&self) -> ScriptedCatcher {
        ScriptedCatcher::with_perception(
            self.catcher.clone(),
            self.rollout.control.clone(),
            self.actor_inputs.perception(),
        )
    }

    /// The policy's action size: the residual channels, the follow-through channel and the
    /// grasp channel.
    pub fn act_len(&self) -> usize {
        self.residual_channels()
            + usize::from(self.follow_through_channel)
            + usize::from(self.grasp_channel)
    }
}

/// The privileged observation: the privileged frame, the prior's action and the phase
/// (one-hot). The privileged actor's input and, on every rung, the critic's.
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
        if spec.rollout.history_steps < spec.actor_inputs.history() {
            return Err(osms_sim::SimError::Params(format!(
                "task.rollout.history_steps = {}: actor_inputs = {:?} reads {} frames (use the task's `realised()` spec)",
                spec.rollout.history_steps,
                spec.actor_inputs,
                spec.actor_inputs.history()
            )));
        }
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
    /// The policy's raw output r of this step.
    residual: &'b mut Vec<f32>,
}

impl Policy for Residual<'_, '_> {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        let (out, r) = residual_action(self.prior, self.spec, self.phase, view, self.act);
        *self.residual = r;
        out
    }
}

/// The observation of the residual policy: the actor's inputs on the task's rung, then (on a
/// realisable rung) the privileged observation for the critic.
fn observation(
    spec: &CatchTaskSpec,
    prior_state: &ScriptedCatcher,
    prior: &Action,
    phase: u8,
    view: &PolicyView<'_>,
) -> Vec<f32> {
    let mut obs = Vec::with_capacity(spec.obs_len());
    let privileged = |obs: &mut Vec<f32>| {
        obs.extend(view.privileged.iter().map(|&v| v as f32));
        obs.extend(prior.iter().map(|&v| v as f32));
        obs.extend((0..5u8).map(|p| f32::from(u8::from(p == phase))));
    };
    let rung = spec.actor_inputs;
    if rung == ActorInputs::Privileged {
        privileged(&mut obs);
        return obs;
    }
    let p = |range: std::ops::Range<usize>| view.privileged[range].iter().map(|&v| v as f32);
    let h = REALISABLE_HISTORY;
    // The newest `h` deployable frames, the oldest repeated before the rollout's start (as the
    // students' observation holds them).
    let frame = |i: usize| {
        let frames = view.history;
        &frames[(frames.len() + i).saturating_sub(h).min(frames.len() - 1)]
    };
    let differences = (1..h).flat_map(|i| {
        (0..3).map(move |c| {
            (frame(i)[OBSERVED_OBJECT + c] - frame(i - 1)[OBSERVED_OBJECT + c]) as f32
        })
    });
    let fit = prior_state.object(view);
    let fitted = fit.pos.into_iter().chain(fit.vel).map(|v| v as f32);
    match rung {
        ActorInputs::Privileged => unreachable!("returned above"),
        ActorInputs::NoIdentity => {
            obs.extend(p(0..IDENTITY));
        }
        ActorInputs::ObservedVelocity
        | ActorInputs::NoContact
        | ActorInputs::Touch
        | ActorInputs::Tracked => {
            obs.extend(p(0..48));
            obs.extend(p(48..51));
            obs.extend(p(PRIVILEGED_PALM..PRIVILEGED_PALM + 9));
            if rung == ActorInputs::ObservedVelocity {
                obs.extend(p(PRIVILEGED_PALM + 9..IDENTITY));
            }
            obs.extend(fitted);
            obs.extend(differences);
            if rung == ActorInputs::Touch {
                obs.extend((0..h).map(|i| frame(i)[PALM_TOUCH] as f32));
            }
        }
        ActorInputs::Deployable => {
            for i in 0..h {
                obs.extend(frame(i)[..DEPLOYABLE_LEN].iter().map(|&v| v as f32));
            }
            let palm = &view.privileged[PRIVILEGED_PALM..];
            obs.extend(palm[..3].iter().map(|&v| v as f32));
            obs.extend(palm[6..9].iter().map(|&v| v as f32));
            let object = &view.deployable[OBSERVED_OBJECT..];
            obs.extend((0..3).map(|c| (object[c] - palm[c]) as f32));
            obs.extend(differences);
            obs.extend(fitted);
        }
    }
    obs.extend(prior.iter().map(|&v| v as f32));
    if rung <= ActorInputs::ObservedVelocity {
        obs.extend((0..5u8).map(|p| f32::from(u8::from(p == phase))));
    }
    debug_assert_eq!(obs.len(), rung.obs_len());
    privileged(&mut obs);
    obs
}

/// The executed action of the residual policy `act` on the prior (advancing the prior's
/// state), and the policy's raw output.
fn residual_action(
    prior_state: &mut ScriptedCatcher,
    spec: &CatchTaskSpec,
    phase: u8,
    view: &PolicyView<'_>,
    act: &mut dyn FnMut(&[f32]) -> Vec<f32>,
) -> (Action, Vec<f32>) {
    let prior = if spec.from_scratch {
        [0.0; N_ACTION]
    } else {
        prior_state.act_increments(view)
    };
    let obs = observation(spec, prior_state, &prior, phase, view);
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
                prior_state.follow_through_direction(view),
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
    // The residuals act on increments of the commanded targets, whatever the world's arm: on an
    // absolute arm the command is the targets they reach (issue 74).
    view.arm_from_increments(&spec.rollout.control, &mut out);
    (out, r)
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
            prior: spec.prior(),
            phase: Phase::Approach as u8,
        }
    }

    /// The teacher's deterministic action at the state `view` shows.
    pub fn act(&mut self, view: &PolicyView<'_>) -> Action {
        let agent = self.agent;
        residual_action(&mut self.prior, self.spec, self.phase, view, &mut |obs| {
            agent.act_deterministic(obs)
        })
        .0
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
    /// The policy's raw output at the last step (empty before the first), for the smoothness
    /// term.
    last_residual: Vec<f32>,
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
    last_residual: Vec<f32>,
}

impl<'w> Task for CatchTask<'w> {
    type Episode<'a>
        = CatchEpisode<'a>
    where
        Self: 'a;
    type Error = osms_sim::SimError;

    fn obs_len(&self) -> usize {
        self.spec.obs_len()
    }

    fn actor_obs_len(&self) -> usize {
        self.spec.actor_obs_len()
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
            prior: spec.prior(),
            reward: spec.reward.clone(),
            spec,
            phase: Phase::Approach as u8,
            rewarded_follow_through: 0.0,
            last_residual: Vec::new(),
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
            last_residual: self.last_residual.clone(),
        }
    }

    /// Returns to `snapshot`, taken from this episode (even after it has ended).
    pub fn restore(&mut self, snapshot: &CatchSnapshot) {
        self.episode.restore(&snapshot.episode);
        self.prior = snapshot.prior.clone();
        self.phase = snapshot.phase;
        self.rewarded_follow_through = snapshot.rewarded_follow_through;
        self.last_residual.clone_from(&snapshot.last_residual);
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
        let mut residual = Vec::new();
        let mut policy = Residual {
            prior: &mut self.prior,
            spec: self.spec,
            phase: self.phase,
            act,
            residual: &mut residual,
        };
        let running = episode.step(&mut policy, hooks);
        let dt = episode.control_period_secs();
        let success = &self.spec.rollout.success;
        let w = &self.reward;
        let rec = episode.record();
        let k = rec.steps - 1;
        let phase_after = rec.phase.get(k).copied().unwrap_or(0);
        let mut reward = 0.0f64;
        if w.residual_rate != 0.0 && residual.len() == self.last_residual.len() {
            let change: f64 = residual
                .iter()
                .zip(&self.last_residual)
                .map(|(a, b)| f64::from(a - b).powi(2))
                .sum();
            reward -= f64::from(w.residual_rate) * change * dt;
        }
        self.last_residual = residual;
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
