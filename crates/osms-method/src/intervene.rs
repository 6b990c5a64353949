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

use osms_make::rng::StreamRng;
use osms_policy::Agent;
use osms_policy::catch::{CatchEpisode, CatchTaskSpec};
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

struct Executor<'a, 'm> {
    snippet: Option<Snippet<'a>>,
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
    let mut hooks = Executor {
        snippet,
        active: false,
        errors,
        phase: Phase::Approach as u8,
        commanded: Vec::new(),
    };
    let mut handed_back_at = None;
    let mut act = |obs: &[f32]| agent.act_deterministic(obs);
    let mut episode = CatchEpisode::new(world, task, condition, dr);
    loop {
        let inner = episode.episode();
        let k = inner.step_index();
        if let Some(s) = &snippet
            && handed_back_at.is_none()
            && k >= s.start
            && (k >= s.end() || inner.first_contact().is_some())
        {
            handed_back_at = Some(k);
        }
        hooks.active = snippet.is_some_and(|s| k >= s.start) && handed_back_at.is_none();
        hooks.phase = inner
            .record()
            .phase
            .last()
            .copied()
            .unwrap_or(Phase::Approach as u8);
        if episode.step_with_hooks(&mut act, &mut hooks).1 {
            break;
        }
    }
    let record = episode.run(&mut act);
    debug_assert_eq!(hooks.commanded.len(), record.steps * N_ACTION);
    Executed {
        record,
        commanded: hooks.commanded,
        handed_back_at,
    }
}
