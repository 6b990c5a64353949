//! Proximal policy optimisation (Schulman et al. 2017) with GAE(λ), for the privileged teacher.
//!
//! Determinism: episode `i` of iteration `t` is the task's episode `t · E + i` and samples its
//! actions from its own stream, so episodes can run on any thread; they are collected in episode
//! order, and every reduction after that runs sequentially in that order. The observation
//! statistics used while collecting are frozen at the start of the iteration.
//!
//! Actions are squashed: the policy samples u ~ N(μ(s), σ) and the task receives tanh(u) ∈
//! [-1, 1]. Probability ratios use the density of u; the tanh Jacobian is the same for the old
//! and the new policy at a stored u and cancels. The entropy bonus is the Gaussian's.

use std::borrow::Cow;

use osms_core::rng::{self, StreamRng};
use osms_nn::{
    Activation, Adam, AdamConfig, AdamMoments, DiagGaussian, Matrix, Mlp, Schedule, flatten_grads,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::checkpoint::Checkpoints;
use crate::norm::RunningNorm;

/// PPO's hyper-parameters; every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PpoConfig {
    pub iterations: u32,
    /// Complete episodes collected per iteration.
    pub episodes_per_iteration: u32,
    /// Hidden widths of the actor and of the critic (separate networks).
    pub hidden: Vec<usize>,
    pub activation: Activation,
    pub gamma: f32,
    /// GAE's λ.
    pub lambda: f32,
    /// PPO's ε: ratios are clipped to [1 − ε, 1 + ε].
    pub clip: f32,
    pub value_coef: f32,
    pub entropy_coef: f32,
    pub epochs: u32,
    /// KL early stop: an iteration's remaining epochs are skipped once an epoch's mean
    /// approximate KL(old ‖ new) exceeds 1.5 × this (the rule of Spinning Up's PPO and of
    /// Stable-Baselines3, checked per epoch here). `None`, the default, runs every epoch, and is
    /// left out of the encoded params so keys built before the field existed stay valid.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_kl: Option<f32>,
    pub minibatch: usize,
    pub lr: f32,
    /// The learning rate falls linearly from `lr` at the first iteration to `lr` × this at the
    /// last (1: constant). Late PPO updates on a near-deterministic policy move it far (clip
    /// fractions of 0.4 by the end of a constant-rate run); a falling rate keeps the end stable.
    pub lr_final_fraction: f32,
    pub max_grad_norm: f32,
    /// Initial log σ of the (state-independent) action noise.
    pub init_log_std: f32,
    /// Normalised observations are clipped to ±this.
    pub obs_clip: f32,
    /// Start with a zero actor output, so the first policy's mean is the task's own prior.
    pub zero_init_actor_output: bool,
}

impl Default for PpoConfig {
    fn default() -> Self {
        PpoConfig {
            iterations: 100,
            // Tuned for the catching teacher on 2 cores (docs/policy.md, tuning log).
            episodes_per_iteration: 32,
            hidden: vec![128, 128],
            activation: Activation::Silu,
            gamma: 0.99,
            lambda: 0.95,
            clip: 0.2,
            value_coef: 0.5,
            entropy_coef: 0.0,
            epochs: 4,
            target_kl: None,
            minibatch: 256,
            lr: 3e-4,
            // Tuned for the teacher on the development stream (docs/policy.md, issue 32): a
            // falling rate and a small initial noise (σ = 0.08) took success from 69 % to 88 %.
            lr_final_fraction: 0.1,
            max_grad_norm: 0.5,
            // At σ = 0.37 (log σ = −1) the noise on the residual and the grasp channel drops
            // 97 % of the prior's catches, so PPO first spends hundreds of iterations shrinking
            // it; at σ = 0.08 the noisy prior still completes most catches.
            init_log_std: -2.5,
            obs_clip: 5.0,
            zero_init_actor_output: true,
        }
    }
}

/// An environment PPO can train on. Episode `index` must be a pure function of the index (its
/// initial condition and any noise come from the task's own seeded streams).
pub trait Task: Sync {
    type Episode<'a>: TaskEpisode
    where
        Self: 'a;
    /// Why an episode could not start (e.g. its condition could not be drawn).
    type Error: std::error::Error + Send + Sync + 'static;
    /// The observation's length: what the critic reads.
    fn obs_len(&self) -> usize;
    /// How many leading entries of the observation the actor reads (asymmetric actor-critic,
    /// Pinto et al. 2018: the rest is for the critic only). All of them by default.
    fn actor_obs_len(&self) -> usize {
        self.obs_len()
    }
    fn act_len(&self) -> usize;
    fn start(&self, index: u64) -> Result<Self::Episode<'_>, Self::Error>;
}

/// One running episode of a [`Task`].
pub trait TaskEpisode {
    /// Runs one control step: calls `act` once with the observation, applies the action it
    /// returns (in [-1, 1]ⁿ), and returns the reward and whether the episode has ended.
    fn step(&mut self, act: &mut dyn FnMut(&[f32]) -> Vec<f32>) -> (f32, bool);
    /// Task figures for the learning curve.
    fn finish(self) -> EpisodeStats;
}

/// What a task reports about a finished episode.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EpisodeStats {
    pub success: bool,
    pub completion: bool,
    /// Peak impact force (N) where the task has one and the episode completed.
    pub f_max_n: Option<f64>,
}

/// One point of the learning curve.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IterationStats {
    pub iteration: u32,
    pub episodes: u32,
    pub steps: u64,
    pub mean_return: f64,
    pub mean_length: f64,
    pub success_rate: f64,
    pub completion_rate: f64,
    /// Mean f_max over completions; `None` without any.
    pub mean_f_max_n: Option<f64>,
    pub policy_loss: f64,
    pub value_loss: f64,
    pub entropy: f64,
    /// Mean (old log-prob − new log-prob) over the last epoch: an estimate of KL(old ‖ new).
    pub approx_kl: f64,
    pub clip_fraction: f64,
    pub action_std: f64,
}

/// A trained (or training) agent: networks, noise, frozen observation statistics, and the
/// learning curve that produced it. The critic reads the whole observation, the actor its
/// leading entries (as many as its first layer has inputs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Agent {
    pub actor: Mlp,
    pub critic: Mlp,
    pub log_std: Vec<f32>,
    pub obs_norm: RunningNorm,
    pub curve: Vec<IterationStats>,
}

impl Agent {
    /// A fresh agent whose weights draw from streams named by (seed, `stage`), so two stages
    /// of one run (two teachers, cross-fitted students) never start from the same weights.
    pub fn new(
        obs_len: usize,
        act_len: usize,
        config: &PpoConfig,
        streams: (u64, &str),
    ) -> crate::Result<Self> {
        Self::asymmetric(obs_len, obs_len, act_len, config, streams)
    }

    /// A fresh agent whose actor reads the first `actor_obs_len` of the `obs_len` observation
    /// entries and whose critic reads them all.
    pub fn asymmetric(
        obs_len: usize,
        actor_obs_len: usize,
        act_len: usize,
        config: &PpoConfig,
        (seed, stage): (u64, &str),
    ) -> crate::Result<Self> {
        if actor_obs_len == 0 || actor_obs_len > obs_len {
            return Err(crate::Error::Params(format!(
                "the actor reads {actor_obs_len} of {obs_len} observation entries: must be 1 to {obs_len}"
            )));
        }
        let sizes = |inputs: usize, out: usize| {
            std::iter::once(inputs)
                .chain(config.hidden.iter().copied())
                .chain(std::iter::once(out))
                .collect::<Vec<_>>()
        };
        let mut actor = Mlp::new(
            &sizes(actor_obs_len, act_len),
            config.activation,
            Activation::Identity,
            seed,
            &format!("{stage}/actor"),
        )?;
        if config.zero_init_actor_output
            && let Some(last) = actor.layers.last_mut()
        {
            last.w.data.fill(0.0);
            last.b.fill(0.0);
        }
        let critic = Mlp::new(
            &sizes(obs_len, 1),
            config.activation,
            Activation::Identity,
            seed,
            &format!("{stage}/critic"),
        )?;
        Ok(Agent {
            actor,
            critic,
            log_std: vec![config.init_log_std; act_len],
            obs_norm: RunningNorm::new(obs_len, config.obs_clip),
            curve: Vec::new(),
        })
    }

    /// How many leading observation entries the actor reads.
    pub fn actor_obs_len(&self) -> usize {
        self.actor.layers.first().map_or(0, |l| l.w.rows)
    }

    /// The actor's mean μ(s) at normalised observations `x` (one row per observation).
    fn actor_mean(&self, x: &Matrix) -> Matrix {
        self.actor.forward(&self.actor_input(x))
    }

    /// The actor's columns of normalised observations (borrowed when it reads them all).
    fn actor_input<'x>(&self, x: &'x Matrix) -> Cow<'x, Matrix> {
        let n = self.actor_obs_len();
        if n == x.cols {
            return Cow::Borrowed(x);
        }
        Cow::Owned(Matrix::from_fn(x.rows, n, |i, j| x.get(i, j)))
    }

    /// The deterministic action tanh(μ(s)) for a raw observation.
    pub fn act_deterministic(&self, obs: &[f32]) -> Vec<f32> {
        let x = self.obs_norm.apply(obs);
        let mean = self.actor_mean(&Matrix::from_vec(1, x.len(), x));
        mean.data.iter().map(|&m| libm::tanhf(m)).collect()
    }

    fn value(&self, x: &[f32]) -> f32 {
        self.critic
            .forward(&Matrix::from_vec(1, x.len(), x.to_vec()))
            .data[0]
    }
}

/// Everything PPO keeps of one collected episode.
struct Trajectory {
    /// Normalised observations, one row per step.
    obs: Vec<f32>,
    /// Pre-squash actions u.
    u: Vec<f32>,
    logp: Vec<f32>,
    value: Vec<f32>,
    reward: Vec<f32>,
    /// Raw observations, for the statistics of the next iteration.
    raw: Vec<f32>,
    stats: EpisodeStats,
}

const LN_2PI: f32 = 1.837_877_1;

fn run_episode<T: Task>(
    task: &T,
    agent: &Agent,
    index: u64,
    rng: &mut StreamRng,
) -> Result<Trajectory, T::Error> {
    let act_len = task.act_len();
    let mut episode = task.start(index)?;
    let mut t = Trajectory {
        obs: Vec::new(),
        u: Vec::new(),
        logp: Vec::new(),
        value: Vec::new(),
        reward: Vec::new(),
        raw: Vec::new(),
        stats: EpisodeStats {
            success: false,
            completion: false,
            f_max_n: None,
        },
    };
    loop {
        let mut act = |raw: &[f32]| {
            let x = agent.obs_norm.apply(raw);
            let mean = agent.actor_mean(&Matrix::from_vec(1, x.len(), x.clone()));
            let mut logp = 0.0f32;
            let mut action = Vec::with_capacity(act_len);
            for (j, &mu) in mean.data.iter().enumerate() {
                let z = rng::normal(rng) as f32;
                let ls = agent.log_std[j];
                let u = mu + libm::expf(ls) * z;
                logp += -0.5 * z * z - ls - 0.5 * LN_2PI;
                t.u.push(u);
                action.push(libm::tanhf(u));
            }
            t.value.push(agent.value(&x));
            t.logp.push(logp);
            t.obs.extend_from_slice(&x);
            t.raw.extend_from_slice(raw);
            action
        };
        let (reward, done) = episode.step(&mut act);
        t.reward.push(reward);
        if done {
            break;
        }
    }
    t.stats = episode.finish();
    Ok(t)
}

/// Generalised advantage estimates and returns of one episode that ended in a terminal state.
pub fn gae(reward: &[f32], value: &[f32], gamma: f32, lambda: f32) -> (Vec<f32>, Vec<f32>) {
    let n = reward.len();
    let mut adv = vec![0.0f32; n];
    let mut running = 0.0f32;
    for k in (0..n).rev() {
        let next = if k + 1 < n { value[k + 1] } else { 0.0 };
        let delta = reward[k] + gamma * next - value[k];
        running = delta + gamma * lambda * running;
        adv[k] = running;
    }
    let ret = adv.iter().zip(value).map(|(a, v)| a + v).collect();
    (adv, ret)
}

/// Everything PPO carries from one iteration to the next, so a checkpoint of it resumes
/// training exactly: the agent (weights, noise, observation statistics, curve) and both
/// optimisers' moments. The episodes' and minibatches' streams are indexed by iteration and
/// need no state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PpoState {
    pub agent: Agent,
    actor_opt: AdamMoments,
    critic_opt: AdamMoments,
    /// The agent's iterations when this training began: the learning rate falls from there.
    first: u32,
}

impl PpoState {
    /// The state before `config.iterations` more iterations of training `agent`.
    pub fn new(agent: Agent, config: &PpoConfig) -> Self {
        let fresh = optimiser(config).moments();
        PpoState {
            first: agent.curve.len() as u32,
            actor_opt: fresh.clone(),
            critic_opt: fresh,
            agent,
        }
    }

    /// Iterations of this training done so far.
    pub fn done(&self) -> u32 {
        self.agent.curve.len() as u32 - self.first
    }
}

/// The actor's and the critic's optimiser (their rate is set per iteration).
fn optimiser(config: &PpoConfig) -> Adam {
    Adam::new(
        AdamConfig {
            max_grad_norm: Some(config.max_grad_norm),
            ..AdamConfig::default()
        },
        Schedule::Constant { lr: config.lr },
    )
}

/// Trains `state`'s agent on `task` until it has done `config.iterations` iterations of this
/// training (from where a checkpoint left it, or from the start). `streams` names the RNG
/// streams (seed, stage name); `progress` sees each iteration's statistics.
pub fn train<T: Task>(
    task: &T,
    state: &mut PpoState,
    config: &PpoConfig,
    streams: (u64, &str),
    progress: &dyn Fn(&IterationStats),
    checkpoints: Option<Checkpoints<'_, PpoState>>,
) -> crate::Result<()> {
    let (seed, stage) = streams;
    let (obs_len, act_len) = (task.obs_len(), task.act_len());
    let first = state.first;
    let resumed_at = state.agent.curve.len() as u32;
    let mut actor_opt = optimiser(config).with_moments(state.actor_opt.clone());
    let mut critic_opt = optimiser(config).with_moments(state.critic_opt.clone());
    for iteration in resumed_at..first + config.iterations {
        let agent = &mut state.agent;
        let done = f64::from(iteration - first) / f64::from(config.iterations.max(2) - 1);
        let lr = (f64::from(config.lr) * (1.0 - done * (1.0 - f64::from(config.lr_final_fraction))))
            as f32;
        actor_opt.schedule = Schedule::Constant { lr };
        critic_opt.schedule = Schedule::Constant { lr };
        let per = u64::from(config.episodes_per_iteration);
        let base = u64::from(iteration) * per;
        let frozen = &*agent;
        let runs: Vec<Result<Trajectory, T::Error>> = (0..per)
            .into_par_iter()
            .map(|e| {
                let mut r = rng::stream(seed, stage, "ppo-act", base + e);
                run_episode(task, frozen, base + e, &mut r)
            })
            .collect();
        // The first failure in episode order, whichever thread met it first.
        let mut trajectories = Vec::with_capacity(runs.len());
        for (e, run) in (base..).zip(runs) {
            trajectories.push(run.map_err(|source| crate::Error::EpisodeStart {
                iteration,
                episode: e,
                source: Box::new(source),
            })?);
        }

        // Flatten in episode order.
        let mut obs = Vec::new();
        let mut u = Vec::new();
        let mut old_logp = Vec::new();
        let mut adv = Vec::new();
        let mut ret = Vec::new();
        let mut returns = 0.0f64;
        let (mut successes, mut completions, mut f_sum, mut f_n) = (0u32, 0u32, 0.0f64, 0u32);
        for t in &trajectories {
            let (a, r) = gae(&t.reward, &t.value, config.gamma, config.lambda);
            adv.extend(a);
            ret.extend(r);
            obs.extend_from_slice(&t.obs);
            u.extend_from_slice(&t.u);
            old_logp.extend_from_slice(&t.logp);
            returns += t.reward.iter().map(|&r| f64::from(r)).sum::<f64>();
            successes += u32::from(t.stats.success);
            completions += u32::from(t.stats.completion);
            if let (true, Some(f)) = (t.stats.completion, t.stats.f_max_n) {
                f_sum += f;
                f_n += 1;
            }
        }
        let n = old_logp.len();
        let mean_adv = adv.iter().map(|&a| f64::from(a)).sum::<f64>() / n as f64;
        let std_adv = (adv
            .iter()
            .map(|&a| (f64::from(a) - mean_adv).powi(2))
            .sum::<f64>()
            / n as f64)
            .sqrt();
        for a in &mut adv {
            *a = ((f64::from(*a) - mean_adv) / (std_adv + 1e-8)) as f32;
        }

        let mut losses = Losses::default();
        for epoch in 0..config.epochs {
            let mut order: Vec<usize> = (0..n).collect();
            let mut r = rng::stream(
                seed,
                stage,
                "ppo-shuffle",
                u64::from(iteration) * u64::from(config.epochs) + u64::from(epoch),
            );
            for i in (1..n).rev() {
                let j = rng::below(&mut r, i as u64 + 1) as usize;
                order.swap(i, j);
            }
            losses = Losses::default();
            for batch in order.chunks(config.minibatch.max(1)) {
                let mb = Minibatch {
                    obs: gather(&obs, obs_len, batch),
                    u: gather(&u, act_len, batch),
                    old_logp: batch.iter().map(|&i| old_logp[i]).collect(),
                    adv: batch.iter().map(|&i| adv[i]).collect(),
                    ret: batch.iter().map(|&i| ret[i]).collect(),
                };
                losses.add(update(agent, &mut actor_opt, &mut critic_opt, config, &mb));
            }
            if config
                .target_kl
                .is_some_and(|target| losses.mean(losses.kl_k3) > 1.5 * f64::from(target))
            {
                break;
            }
        }

        let episodes = trajectories.len() as f64;
        let stats = IterationStats {
            iteration,
            episodes: trajectories.len() as u32,
            steps: n as u64,
            mean_return: returns / episodes,
            mean_length: n as f64 / episodes,
            success_rate: f64::from(successes) / episodes,
            completion_rate: f64::from(completions) / episodes,
            mean_f_max_n: (f_n > 0).then(|| f_sum / f64::from(f_n)),
            policy_loss: losses.mean(losses.policy),
            value_loss: losses.mean(losses.value),
            entropy: losses.mean(losses.entropy),
            approx_kl: losses.mean(losses.kl),
            clip_fraction: losses.mean(losses.clipped),
            action_std: agent
                .log_std
                .iter()
                .map(|&s| f64::from(libm::expf(s)))
                .sum::<f64>()
                / act_len.max(1) as f64,
        };
        progress(&stats);
        agent.curve.push(stats);
        // Statistics for the next iteration, folded in episode order.
        for t in &trajectories {
            agent.obs_norm.update(&t.raw);
        }
        if let Some(c) = &checkpoints
            && c.due(iteration + 1 - first, config.iterations)
        {
            state.actor_opt = actor_opt.moments();
            state.critic_opt = critic_opt.moments();
            (c.save)(state).map_err(|why| crate::Error::Checkpoint {
                done: iteration + 1 - first,
                why,
            })?;
        }
    }
    state.actor_opt = actor_opt.moments();
    state.critic_opt = critic_opt.moments();
    Ok(())
}

fn gather(rows: &[f32], width: usize, index: &[usize]) -> Matrix {
    let mut data = Vec::with_capacity(index.len() * width);
    for &i in index {
        data.extend_from_slice(&rows[i * width..(i + 1) * width]);
    }
    Matrix::from_vec(index.len(), width, data)
}

struct Minibatch {
    obs: Matrix,
    u: Matrix,
    old_logp: Vec<f32>,
    adv: Vec<f32>,
    ret: Vec<f32>,
}

/// Per-minibatch means, summed over the minibatches of an epoch.
#[derive(Default)]
struct Losses {
    batches: u32,
    policy: f64,
    value: f64,
    entropy: f64,
    kl: f64,
    /// (r − 1) − log r, r the probability ratio: the same KL(old ‖ new) as `kl` in expectation,
    /// but never negative, so a KL stop cannot be missed because a minibatch's estimates cancel.
    kl_k3: f64,
    clipped: f64,
}

impl Losses {
    fn add(&mut self, other: Losses) {
        self.batches += 1;
        self.policy += other.policy;
        self.value += other.value;
        self.entropy += other.entropy;
        self.kl += other.kl;
        self.kl_k3 += other.kl_k3;
        self.clipped += other.clipped;
    }

    fn mean(&self, total: f64) -> f64 {
        total / f64::from(self.batches.max(1))
    }
}

/// One gradient step on a minibatch: clipped surrogate, value MSE, entropy bonus.
fn update(
    agent: &mut Agent,
    actor_opt: &mut Adam,
    critic_opt: &mut Adam,
    config: &PpoConfig,
    mb: &Minibatch,
) -> Losses {
    let b = mb.old_logp.len();
    let act_len = agent.log_std.len();
    let inv_b = 1.0 / b as f32;

    let (mean, actor_cache) = agent.actor.forward_cached(&agent.actor_input(&mb.obs));
    let log_std = Matrix::from_fn(b, act_len, |_, j| agent.log_std[j]);
    let dist = DiagGaussian {
        mean: &mean,
        log_std: &log_std,
    };
    let (logp, unit) = dist.log_prob(&mb.u, &vec![1.0; b]);
    let (lo, hi) = (1.0 - config.clip, 1.0 + config.clip);
    let mut coef = vec![0.0f32; b];
    let (mut policy, mut kl, mut kl_k3, mut clipped) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for i in 0..b {
        let ratio = libm::expf(logp[i] - mb.old_logp[i]);
        let a = mb.adv[i];
        let surrogate = (ratio * a).min(ratio.clamp(lo, hi) * a);
        policy -= f64::from(surrogate);
        kl += f64::from(mb.old_logp[i] - logp[i]);
        kl_k3 += f64::from(ratio - 1.0) - f64::from(logp[i] - mb.old_logp[i]);
        let outside = (a > 0.0 && ratio > hi) || (a < 0.0 && ratio < lo);
        clipped += f64::from(u8::from(ratio > hi || ratio < lo));
        // d(−surrogate/B)/d logp: the unclipped branch is active unless the ratio left the
        // trust region in the direction the advantage rewards.
        coef[i] = if outside { 0.0 } else { -ratio * a * inv_b };
    }
    let mut d_mean = unit.mean;
    for (row, &c) in d_mean.data.chunks_exact_mut(act_len).zip(&coef) {
        row.iter_mut().for_each(|g| *g *= c);
    }
    let mut d_log_std = vec![-config.entropy_coef; act_len];
    for (row, &c) in unit.log_std.data.chunks_exact(act_len).zip(&coef) {
        for (g, &v) in d_log_std.iter_mut().zip(row) {
            *g += v * c;
        }
    }
    let actor_grads = agent.actor.param_gradients(&actor_cache, &d_mean);
    let mut grads: Vec<&[f32]> = flatten_grads(&actor_grads);
    grads.push(&d_log_std);
    let mut params = agent.actor.params_mut();
    params.push(&mut agent.log_std);
    actor_opt.update(&mut params, &grads);

    let (values, critic_cache) = agent.critic.forward_cached(&mb.obs);
    let mut d_value = Matrix::zeros(b, 1);
    let mut value_loss = 0.0f64;
    for i in 0..b {
        let e = values.data[i] - mb.ret[i];
        value_loss += f64::from(e * e);
        d_value.data[i] = 2.0 * config.value_coef * e * inv_b;
    }
    let critic_grads = agent.critic.param_gradients(&critic_cache, &d_value);
    critic_opt.update(
        &mut agent.critic.params_mut(),
        &flatten_grads(&critic_grads),
    );

    let entropy: f32 = dist.entropy().first().copied().unwrap_or(0.0);
    Losses {
        batches: 1,
        policy: policy / b as f64,
        value: value_loss / b as f64,
        entropy: f64::from(entropy),
        kl: kl / b as f64,
        kl_k3: kl_k3 / b as f64,
        clipped: clipped / b as f64,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_asymmetric_actor_reads_only_the_leading_entries_and_the_critic_all() {
        let config = PpoConfig {
            hidden: vec![8],
            zero_init_actor_output: false,
            ..PpoConfig::default()
        };
        let agent = Agent::asymmetric(6, 4, 2, &config, (3, "test")).expect("agent");
        assert_eq!(agent.actor_obs_len(), 4);
        let obs = [0.1f32, -0.4, 0.7, 0.2, 1.5, -2.0];
        let mut critic_only = obs;
        critic_only[4] = -3.0;
        critic_only[5] = 0.9;
        assert_eq!(
            agent.act_deterministic(&obs),
            agent.act_deterministic(&critic_only)
        );
        let mut actor_seen = obs;
        actor_seen[3] = 0.9;
        assert_ne!(
            agent.act_deterministic(&obs),
            agent.act_deterministic(&actor_seen)
        );
        let value = |o: &[f32]| agent.value(&agent.obs_norm.apply(o));
        assert_ne!(value(&obs), value(&critic_only));
        for bad in [0, 7] {
            assert!(Agent::asymmetric(6, bad, 2, &config, (3, "test")).is_err());
        }
    }

    #[test]
    fn gae_with_lambda_one_is_the_discounted_return_minus_the_value() {
        let reward = [1.0f32, 0.0, 2.0];
        let value = [0.5f32, -0.25, 1.0];
        let (adv, ret) = gae(&reward, &value, 0.9, 1.0);
        let g2 = 2.0f32;
        let g1 = 0.0 + 0.9 * g2;
        let g0 = 1.0 + 0.9 * g1;
        for (k, g) in [g0, g1, g2].into_iter().enumerate() {
            assert!((ret[k] - g).abs() < 1e-6, "return {k}");
            assert!((adv[k] - (g - value[k])).abs() < 1e-6, "advantage {k}");
        }
        // λ = 0: one-step TD errors.
        let (adv0, _) = gae(&reward, &value, 0.9, 0.0);
        assert!((adv0[0] - (1.0 + 0.9 * -0.25 - 0.5)).abs() < 1e-6);
        assert!((adv0[2] - (2.0 - 1.0)).abs() < 1e-6);
    }
}
