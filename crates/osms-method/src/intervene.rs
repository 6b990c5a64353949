//! The event-aligned intervention of paper 4.2, with optional modelled student action errors
//! (Eq. 7): the rollout a candidate snippet ζ is judged by.
//!
//! Before the window W_OS = {start, …, end − 1} the frozen teacher controls arm and hand. Inside
//! it, ζ's rows replace the arm channels open loop while the teacher keeps closed-loop control of
//! the hand. From the first object–robot contact or the window's end, whichever comes first,
//! the teacher controls everything until termination; a snippet handed back is never resumed.
//! The teacher acts at every step (its prior and phase input follow the states), so handing
//! back is seamless. With an error model, every channel of every step is perturbed
//! (`Perturber::step`, phase known online: the one the previous step ended in), e₀ drawn from
//! the first phase's stationary distribution.

use osms_core::rng::StreamRng;
use osms_policy::Agent;
use osms_policy::catch::{CatchEpisode, CatchSnapshot, CatchTaskSpec};
use osms_sim::conditions::TaskCondition;
use osms_sim::{Action, Hooks, N_ACTION, N_ARM, Phase, RolloutRecord, World};

use crate::error_model::Perturber;

/// An arm snippet and the window it replaces.
#[derive(Debug, Clone, Copy)]
pub struct Snippet<'a> {
    /// The window's first control step.
    pub start: usize,
    /// ζ, step-major (`[step][arm channel]`): one row per window step.
    pub zeta: &'a [f32],
}

impl Snippet<'_> {
    /// The window's end (exclusive).
    pub fn end(&self) -> usize {
        self.start + self.zeta.len() / N_ARM
    }
}

/// Modelled student action errors and the stream of their innovations (common random numbers:
/// every candidate of a condition gets the same stream for the same q).
#[derive(Clone)]
pub struct Errors<'m> {
    pub perturber: Perturber<'m>,
    pub rng: StreamRng,
}

/// An executed rollout.
#[derive(Debug, Clone, PartialEq)]
pub struct Executed {
    pub record: RolloutRecord,
    /// The commanded action of every step after the modelled perturbation and before the
    /// environment's actuation noise and delay (24 per step): the students' labels.
    pub commanded: Vec<f32>,
    /// The step from which the teacher had the arm back: the window's end, or the first step
    /// after first contact (the window's start if contact came before it). `None` without a
    /// snippet, or if the episode ended while the snippet ran.
    pub handed_back_at: Option<usize>,
}

#[derive(Clone)]
struct Executor<'a, 'm> {
    snippet: Option<Snippet<'a>>,
    /// Whether contact ends the snippet (paper 4.2) or it runs its whole window.
    hand_back_at_contact: bool,
    /// Whether the snippet drives the arm this step.
    active: bool,
    errors: Option<Errors<'m>>,
    phase: u8,
    commanded: Vec<f32>,
}

impl Hooks for Executor<'_, '_> {
    fn override_arm(&mut self, step: usize, action: &mut Action) {
        if let (true, Some(s)) = (self.active, &self.snippet) {
            let row = &s.zeta[(step - s.start) * N_ARM..(step - s.start + 1) * N_ARM];
            // Snippets are stored in f32. Where a row equals the teacher's own command at that
            // precision, the command itself is kept, so replaying ζ_org reproduces the original
            // rollout bit for bit instead of a rollout with f32-rounded commands.
            for (a, &z) in action.iter_mut().zip(row) {
                if *a as f32 != z {
                    *a = f64::from(z);
                }
            }
        }
    }

    fn perturb(&mut self, _step: usize, action: &mut Action) {
        if let Some(e) = &mut self.errors {
            let perturbed = e.perturber.step(action, self.phase, &mut e.rng);
            action.copy_from_slice(&perturbed);
        }
        self.commanded.extend(action.iter().map(|&a| a as f32));
    }
}

/// A rollout under intervention that runs step by step and branches: run the shared prefix
/// once, [`Intervention::snapshot`] it at the window's start, then for each candidate
/// [`Intervention::restore`] and [`Intervention::set_snippet`]. Every branch is bit for bit the
/// rollout [`execute`] runs from step 0 with the same inputs.
pub struct Intervention<'w, 'a, 'm> {
    episode: CatchEpisode<'w>,
    hooks: Executor<'a, 'm>,
    handed_back_at: Option<usize>,
}

/// An intervention's whole state at the start of a control step.
#[derive(Clone)]
pub struct InterventionSnapshot<'a, 'm> {
    episode: CatchSnapshot,
    hooks: Executor<'a, 'm>,
    handed_back_at: Option<usize>,
}

impl<'w, 'a, 'm> Intervention<'w, 'a, 'm> {
    /// The teacher's rollout on ω (its DR draws from `dr`), `errors` on every step; no snippet
    /// until one is set.
    pub fn new(
        world: &'w World,
        task: &'w CatchTaskSpec,
        condition: TaskCondition,
        dr: StreamRng,
        errors: Option<Errors<'m>>,
    ) -> Self {
        Intervention {
            episode: CatchEpisode::new(world, task, condition, dr),
            hooks: Executor {
                snippet: None,
                hand_back_at_contact: true,
                active: false,
                errors,
                phase: Phase::Approach as u8,
                commanded: Vec::new(),
            },
            handed_back_at: None,
        }
    }

    /// The snippet to run in its window. Set it before the window starts.
    ///
    /// # Panics
    /// If the window has already started.
    pub fn set_snippet(&mut self, snippet: Option<Snippet<'a>>) {
        if let Some(s) = &snippet {
            assert!(
                self.step_index() <= s.start,
                "a snippet for step {} set at step {}",
                s.start,
                self.step_index()
            );
        }
        self.hooks.snippet = snippet;
    }

    /// Runs the snippet through its whole window even after contact: an intervention on any
    /// window (the IOS profile), not the event-aligned one of paper 4.2.
    pub fn through_contact(&mut self) {
        self.hooks.hand_back_at_contact = false;
    }

    /// The next control step's index.
    pub fn step_index(&self) -> usize {
        self.episode.episode().step_index()
    }

    pub fn is_done(&self) -> bool {
        self.episode.episode().is_done()
    }

    /// The record so far.
    pub fn record(&self) -> &RolloutRecord {
        self.episode.episode().record()
    }

    /// Whether the rollout will fail however it continues.
    pub fn failure_decided(&self) -> bool {
        self.episode.episode().failure_decided()
    }

    /// One control step; returns true once the episode is over.
    pub fn step(&mut self, agent: &Agent) -> bool {
        let inner = self.episode.episode();
        let k = inner.step_index();
        let snippet = self.hooks.snippet;
        if let Some(s) = &snippet
            && self.handed_back_at.is_none()
            && k >= s.start
            && (k >= s.end()
                || (self.hooks.hand_back_at_contact && inner.first_contact().is_some()))
        {
            self.handed_back_at = Some(k);
        }
        self.hooks.active = snippet.is_some_and(|s| k >= s.start) && self.handed_back_at.is_none();
        self.hooks.phase = inner
            .record()
            .phase
            .last()
            .copied()
            .unwrap_or(Phase::Approach as u8);
        let mut act = |obs: &[f32]| agent.act_deterministic(obs);
        self.episode.step_with_hooks(&mut act, &mut self.hooks).1
    }

    /// Steps until the next step is `step` or the episode is over.
    pub fn run_until(&mut self, agent: &Agent, step: usize) {
        while self.step_index() < step && !self.step(agent) {}
    }

    pub fn snapshot(&self) -> InterventionSnapshot<'a, 'm> {
        InterventionSnapshot {
            episode: self.episode.snapshot(),
            hooks: self.hooks.clone(),
            handed_back_at: self.handed_back_at,
        }
    }

    /// Returns to `snapshot`, taken from this intervention (even after it has ended).
    pub fn restore(&mut self, snapshot: &InterventionSnapshot<'a, 'm>) {
        self.episode.restore(&snapshot.episode);
        self.hooks.clone_from(&snapshot.hooks);
        self.handed_back_at = snapshot.handed_back_at;
    }

    /// Runs to the end.
    pub fn run(&mut self, agent: &Agent) {
        while !self.step(agent) {}
    }

    /// The outcome as it stands (final once the episode is over).
    pub fn outcome(&self) -> (osms_sim::Outcome, osms_sim::Metrics) {
        self.episode.episode().outcome()
    }

    /// The rollout, run to its end.
    pub fn finish(mut self, agent: &Agent) -> Executed {
        self.run(agent);
        let mut act = |obs: &[f32]| agent.act_deterministic(obs);
        let record = self.episode.run(&mut act);
        debug_assert_eq!(self.hooks.commanded.len(), record.steps * N_ACTION);
        Executed {
            record,
            commanded: self.hooks.commanded,
            handed_back_at: self.handed_back_at,
        }
    }
}

/// The teacher's rollout on ω (its DR draws from `dr`) with `snippet` in its window and `errors`
/// on every step (paper 4.2 with Eq. 7). Without either it is the teacher's own rollout.
///
/// # Panics
/// If the error model does not have the 24 action channels.
pub fn execute(
    world: &World,
    task: &CatchTaskSpec,
    agent: &Agent,
    condition: TaskCondition,
    dr: StreamRng,
    snippet: Option<Snippet<'_>>,
    errors: Option<Errors<'_>>,
) -> Executed {
    let mut run = Intervention::new(world, task, condition, dr, errors);
    run.set_snippet(snippet);
    run.finish(agent)
}
