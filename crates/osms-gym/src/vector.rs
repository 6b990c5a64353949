//! A fixed number of episodes stepped together for one batch policy: a vector environment's
//! core (gymnasium's `VectorEnv`). Unlike a [`crate::Pool`], which runs a list of conditions
//! once each and then stops, every sub-environment always holds an episode; one that ends is
//! restarted on the set's next condition, as the autoreset mode says.

use std::sync::Arc;

use osms_sim::artifacts::EvalRow;
use osms_sim::control::Action;
use osms_sim::{Episode, PolicyView, RolloutSpec};
use rayon::prelude::*;

use crate::error::{GymError, Result};
use crate::native::{Asked, Native, NativeStates};
use crate::pool::check_action;
use crate::project::Protocol;
use crate::slot::{Slot, StepInfo};

/// When an ended episode's sub-environment starts its next one (gymnasium's `AutoresetMode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Autoreset {
    /// On the next step, whose action for it is ignored; the ending step returns the episode's
    /// last observation.
    NextStep,
    /// In the step that ends it: that step returns the next episode's first observation, the
    /// ended one's last observation and info beside it.
    SameStep,
    /// Only on a reset the caller asks for; stepping an ended sub-environment is an error.
    Disabled,
}

/// An observation as a gymnasium environment returns it: the deployable frame and, if asked
/// for, the privileged one, in float32.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub deployable: Vec<f32>,
    pub privileged: Option<Vec<f32>>,
}

impl Frame {
    fn of(view: &PolicyView<'_>, privileged: bool) -> Frame {
        Frame {
            deployable: view.deployable.iter().map(|&v| v as f32).collect(),
            privileged: privileged.then(|| view.privileged.iter().map(|&v| v as f32).collect()),
        }
    }
}

/// What one sub-environment reports after a reset or a step.
#[derive(Debug, Clone)]
pub struct SubStep {
    /// The observation: the running episode's, or the ended one's last (NEXT_STEP, DISABLED).
    pub frame: Frame,
    /// 1 at the end of a successful catch, else 0.
    pub reward: f64,
    /// The episode ended by the world's rules in this step.
    pub terminated: bool,
    /// The episode reached the caller's step limit before the world ended it.
    pub truncated: bool,
    pub info: StepInfo,
    /// Under SAME_STEP, the episode that ended in this step (its last observation and info);
    /// `frame` and `info` are then the next episode's first.
    pub ended: Option<(Frame, StepInfo)>,
}

/// One sub-environment's episode.
struct Sub {
    slot: Slot,
    /// The episode's number (in the order episodes started), which keys a native policy's state.
    episode: u64,
    running: bool,
    /// The last observation (returned again once the episode has ended).
    frame: Frame,
}

impl Sub {
    /// What a sub-environment reports when this episode has just started.
    fn first_report(&self) -> SubStep {
        SubStep {
            frame: self.frame.clone(),
            reward: 0.0,
            terminated: false,
            truncated: false,
            info: self.slot.info(!self.running),
            ended: None,
        }
    }
}

/// What a step does to one sub-environment.
enum Move {
    Act(Action),
    /// A NEXT_STEP autoreset onto this condition, as this episode number.
    Start(usize, u64),
}

/// `num_envs` episodes of a protocol, each under `spec`, stepped in parallel; conditions handed
/// out in order, once each per pass over the set, across sub-environments in sub-environment
/// order. Each episode is its protocol's rollout of its condition, whatever the number of
/// sub-environments and whichever sub-environment runs it.
pub struct VectorEpisodes {
    protocol: Arc<Protocol>,
    spec: Arc<RolloutSpec>,
    reads_contact_force: bool,
    privileged: bool,
    mode: Autoreset,
    max_episode_steps: Option<usize>,
    subs: Vec<Option<Sub>>,
    /// The next condition to hand out (mod the set's size).
    next: usize,
    started: u64,
    /// Counts observations: a native policy answers each once.
    generation: u64,
    native: NativeStates,
    /// The rows of episodes that ended by the world's rules: (episode number, condition, row).
    rows: Vec<(u64, usize, EvalRow)>,
}

impl VectorEpisodes {
    /// `num_envs` sub-environments on `protocol`'s conditions, episodes under `spec` (observing
    /// the contact force if `reads_contact_force`), observations with the privileged frame if
    /// `privileged`, truncated after `max_episode_steps` control steps if given. Nothing runs
    /// before the first [`VectorEpisodes::reset`].
    pub fn new(
        protocol: Arc<Protocol>,
        spec: RolloutSpec,
        reads_contact_force: bool,
        privileged: bool,
        num_envs: usize,
        mode: Autoreset,
        max_episode_steps: Option<usize>,
    ) -> Result<VectorEpisodes> {
        if num_envs == 0 {
            return Err(GymError::Argument(
                "num_envs must be at least 1 (sub-environments stepped together)".to_string(),
            ));
        }
        if max_episode_steps == Some(0) {
            return Err(GymError::Argument(
                "max_episode_steps must be at least 1 (control steps before truncation)"
                    .to_string(),
            ));
        }
        if protocol.conditions.is_empty() {
            return Err(GymError::Argument(format!(
                "the condition set `{}` of `{}` is empty",
                protocol.conditions_name, protocol.name
            )));
        }
        Ok(VectorEpisodes {
            protocol,
            spec: Arc::new(spec),
            reads_contact_force: reads_contact_force || privileged,
            privileged,
            mode,
            max_episode_steps,
            subs: (0..num_envs).map(|_| None).collect(),
            next: 0,
            started: 0,
            generation: 0,
            native: NativeStates::default(),
            rows: Vec::new(),
        })
    }

    pub fn num_envs(&self) -> usize {
        self.subs.len()
    }

    pub fn protocol(&self) -> &Protocol {
        &self.protocol
    }

    /// Whether observations carry the privileged frame.
    pub fn privileged(&self) -> bool {
        self.privileged
    }

    /// The condition sub-environment `k`'s episode runs (or ran, once ended); none before its
    /// first reset.
    pub fn condition(&self, k: usize) -> Option<usize> {
        self.subs.get(k)?.as_ref().map(|s| s.slot.index)
    }

    /// Each sub-environment's last observation (none before its first reset).
    pub fn frames(&self) -> Vec<Option<&Frame>> {
        self.subs
            .iter()
            .map(|s| s.as_ref().map(|s| &s.frame))
            .collect()
    }

    /// Sub-environment `k`'s episode, running or ended (its last state can be drawn).
    pub fn episode(&self, k: usize) -> Option<&Episode<'_>> {
        self.subs.get(k)?.as_ref().map(|s| s.slot.episode())
    }

    /// The next condition to hand out, and the counter moved past it.
    fn hand_out(&mut self, index: Option<usize>) -> (usize, u64) {
        let n = self.protocol.conditions.len();
        let index = index.unwrap_or(self.next % n);
        self.next = index + 1;
        self.started += 1;
        (index, self.started - 1)
    }

    /// Starts episodes (on the conditions given, else the next ones) in sub-environments
    /// `starts` (in order) and observes them, in parallel; what each reports. A condition out of
    /// range or a sub-environment that does not exist fails the call before anything starts.
    pub fn reset(&mut self, starts: &[(usize, Option<i64>)]) -> Result<Vec<(usize, SubStep)>> {
        let mut seen = vec![false; self.subs.len()];
        for &(k, index) in starts {
            if k >= self.subs.len() {
                return Err(GymError::Argument(format!(
                    "sub-environment {k} does not exist (there are {}: 0 to {})",
                    self.subs.len(),
                    self.subs.len() - 1
                )));
            }
            if std::mem::replace(&mut seen[k], true) {
                return Err(GymError::Argument(format!(
                    "sub-environment {k} is reset twice in one call"
                )));
            }
            if let Some(i) = index {
                self.protocol.condition(i)?;
            }
        }
        let planned: Vec<(usize, usize, u64)> = starts
            .iter()
            .map(|&(k, index)| {
                let (index, episode) = self.hand_out(index.map(|i| i as usize));
                (k, index, episode)
            })
            .collect();
        for &(k, _, _) in &planned {
            self.end_native(k);
        }
        let started = self.start_all(&planned);
        let mut out = Vec::with_capacity(started.len());
        for (k, sub) in started {
            out.push((k, sub.first_report()));
            self.subs[k] = Some(sub);
        }
        self.generation += 1;
        Ok(out)
    }

    /// Starts and observes the planned episodes (sub-environment, condition, episode number),
    /// in parallel.
    fn start_all(&self, planned: &[(usize, usize, u64)]) -> Vec<(usize, Sub)> {
        let (protocol, spec) = (&self.protocol, &self.spec);
        let (reads, privileged) = (self.reads_contact_force, self.privileged);
        planned
            .par_iter()
            .map(|&(k, index, episode)| {
                (k, start(protocol, spec, index, episode, reads, privileged))
            })
            .collect()
    }

    fn end_native(&mut self, k: usize) {
        if let Some(sub) = &self.subs[k] {
            self.native.end(sub.episode);
        }
    }

    /// Runs one action per sub-environment (ignored for one that restarts under NEXT_STEP),
    /// in parallel; what each reports. An action the world cannot run, a sub-environment never
    /// reset, or (DISABLED) one whose episode ended fails the call before any episode moves.
    pub fn step(&mut self, actions: &[Vec<f64>]) -> Result<Vec<SubStep>> {
        if actions.len() != self.subs.len() {
            return Err(GymError::Argument(format!(
                "{} actions for {} sub-environments: one per sub-environment",
                actions.len(),
                self.subs.len()
            )));
        }
        let mut moves = Vec::with_capacity(self.subs.len());
        for (k, (sub, action)) in self.subs.iter().zip(actions).enumerate() {
            let Some(sub) = sub else {
                return Err(GymError::State(format!(
                    "sub-environment {k} has no episode: call reset() first"
                )));
            };
            if sub.running {
                moves.push(Some(check_action(action, sub.slot.index, sub.slot.step())?));
            } else if self.mode == Autoreset::Disabled {
                return Err(GymError::State(format!(
                    "sub-environment {k}'s episode (condition {}) has ended and autoreset is disabled: reset it first (reset(options={{\"reset_mask\": mask}}) with mask[{k}] set)",
                    sub.slot.index
                )));
            } else {
                moves.push(None);
            }
        }
        let moves: Vec<Move> = moves
            .into_iter()
            .map(|m| match m {
                Some(action) => Move::Act(action),
                None => {
                    let (index, episode) = self.hand_out(None);
                    Move::Start(index, episode)
                }
            })
            .collect();
        for (k, m) in moves.iter().enumerate() {
            if matches!(m, Move::Start(..)) {
                self.end_native(k);
            }
        }
        let (protocol, spec) = (&self.protocol, &self.spec);
        let (reads, privileged) = (self.reads_contact_force, self.privileged);
        let max_steps = self.max_episode_steps;
        let outcomes: Vec<(Option<Sub>, SubStep)> = self
            .subs
            .par_iter_mut()
            .zip(moves)
            .map(|(sub, m)| match m {
                Move::Start(index, episode) => {
                    let new = start(protocol, spec, index, episode, reads, privileged);
                    let report = new.first_report();
                    (Some(new), report)
                }
                Move::Act(action) => {
                    let sub = sub.as_mut().expect("checked above");
                    sub.running = sub.slot.act_only(action) && sub.slot.observe(reads);
                    if sub.running {
                        sub.frame = Frame::of(&sub.slot.view(), privileged);
                    }
                    let info = sub.slot.info(!sub.running);
                    let truncated = sub.running && max_steps.is_some_and(|m| info.steps >= m);
                    if truncated {
                        sub.running = false;
                    }
                    let report = SubStep {
                        frame: sub.frame.clone(),
                        reward: if info.done && info.success { 1.0 } else { 0.0 },
                        terminated: info.done,
                        truncated,
                        info,
                        ended: None,
                    };
                    (None, report)
                }
            })
            .collect();
        let mut reports = Vec::with_capacity(outcomes.len());
        let mut restarts = Vec::new();
        for (k, (new, report)) in outcomes.into_iter().enumerate() {
            if let Some(new) = new {
                self.subs[k] = Some(new);
            } else if report.terminated || report.truncated {
                let sub = self.subs[k].as_ref().expect("acted");
                if report.terminated {
                    let row = EvalRow::of(sub.slot.record_now());
                    self.rows.push((sub.episode, sub.slot.index, row));
                }
                if self.mode == Autoreset::SameStep {
                    restarts.push(k);
                }
            }
            reports.push(report);
        }
        if !restarts.is_empty() {
            let planned: Vec<(usize, usize, u64)> = restarts
                .iter()
                .map(|&k| {
                    let (index, episode) = self.hand_out(None);
                    (k, index, episode)
                })
                .collect();
            for &k in &restarts {
                self.end_native(k);
            }
            for (k, new) in self.start_all(&planned) {
                let first = new.first_report();
                let report = &mut reports[k];
                let ended_frame = std::mem::replace(&mut report.frame, first.frame);
                let ended_info = std::mem::replace(&mut report.info, first.info);
                report.ended = Some((ended_frame, ended_info));
                self.subs[k] = Some(new);
            }
        }
        self.generation += 1;
        Ok(reports)
    }

    /// The actions of the store's policy `native` for the current observation of every
    /// sub-environment (zeros for one whose episode has ended: a step ignores them or refuses
    /// the call). The episodes must run under `native`'s rollout spec
    /// ([`Native::spec`]), and `native` must act on them from their first step, once per
    /// observation.
    pub fn native_act(&mut self, native: &Native) -> Result<Vec<Action>> {
        let mut asked = Vec::new();
        let mut at = Vec::new();
        for (k, sub) in self.subs.iter().enumerate() {
            let Some(sub) = sub else {
                return Err(GymError::State(format!(
                    "sub-environment {k} has no episode: call reset() first"
                )));
            };
            if sub.running {
                asked.push(Asked {
                    episode: sub.episode,
                    slot: &sub.slot,
                });
                at.push(k);
            }
        }
        let acted = self
            .native
            .act(native, &self.protocol, &self.spec, self.generation, &asked)?;
        let mut actions = vec![[0.0; osms_sim::N_ACTION]; self.subs.len()];
        for (k, a) in at.into_iter().zip(acted) {
            actions[k] = a;
        }
        Ok(actions)
    }

    /// The rows of the episodes that ended by the world's rules (not truncated), in the order
    /// the episodes started, each with its condition.
    pub fn rows(&self) -> Vec<(usize, EvalRow)> {
        let mut rows: Vec<&(u64, usize, EvalRow)> = self.rows.iter().collect();
        rows.sort_by_key(|(episode, _, _)| *episode);
        rows.into_iter()
            .map(|(_, index, row)| (*index, row.clone()))
            .collect()
    }
}

/// Episode number `episode` of `protocol` on condition `index`, started and observed.
fn start(
    protocol: &Protocol,
    spec: &Arc<RolloutSpec>,
    index: usize,
    episode: u64,
    reads_contact_force: bool,
    privileged: bool,
) -> Sub {
    let mut slot = Slot::start(protocol, spec, index);
    let running = slot.observe(reads_contact_force);
    let frame = if running {
        Frame::of(&slot.view(), privileged)
    } else {
        Frame {
            deployable: vec![0.0; osms_sim::policy::DEPLOYABLE_LEN],
            privileged: privileged.then(|| vec![0.0; osms_sim::policy::PRIVILEGED_LEN]),
        }
    };
    Sub {
        slot,
        episode,
        running,
        frame,
    }
}
