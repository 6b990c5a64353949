//! One running episode with the world and spec it borrows, as pools, vector environments and
//! single environments step it, and what an environment reports of it.

use std::sync::Arc;

use osms_sim::control::Action;
use osms_sim::episode::Observed;
use osms_sim::{Episode, NoHooks, PolicyView, RolloutRecord, RolloutSpec, World};
use self_cell::self_cell;

use crate::project::Protocol;

/// What an episode borrows: the world and its rollout spec.
struct Setting {
    world: Arc<World>,
    spec: Arc<RolloutSpec>,
}

type MaybeEpisode<'a> = Option<Episode<'a>>;

self_cell!(
    /// A running episode with the world and spec it borrows; empty once finished.
    struct LiveEpisode {
        owner: Setting,
        #[covariant]
        dependent: MaybeEpisode,
    }
);

/// One rollout in progress: its condition index and the observation awaiting an action.
pub(crate) struct Slot {
    live: LiveEpisode,
    pub index: usize,
    observed: Option<Observed>,
}

impl Slot {
    pub fn start(protocol: &Protocol, spec: &Arc<RolloutSpec>, index: usize) -> Slot {
        let setting = Setting {
            world: protocol.world.clone(),
            spec: spec.clone(),
        };
        let condition = protocol.conditions[index].clone();
        let dr = protocol.dr_rng(index);
        Slot {
            live: LiveEpisode::new(setting, |s| {
                Some(Episode::new(&s.world, &s.spec, condition, dr))
            }),
            index,
            observed: None,
        }
    }

    /// Whether an observation awaits its action.
    pub fn awaits_action(&self) -> bool {
        self.observed.is_some()
    }

    pub fn episode(&self) -> &Episode<'_> {
        self.live
            .borrow_dependent()
            .as_ref()
            .expect("a slot holds its episode until it is finished")
    }

    /// Observes the next control step; false once the episode is over.
    pub fn observe(&mut self, reads_contact_force: bool) -> bool {
        let observed = self.live.with_dependent_mut(|_, e| {
            e.as_mut().and_then(|e| e.observe_step(reads_contact_force))
        });
        self.observed = observed;
        self.observed.is_some()
    }

    /// Runs `action` on the observed step; false once the episode is over.
    pub fn act_only(&mut self, action: Action) -> bool {
        let observed = self
            .observed
            .take()
            .expect("an action answers an observation");
        self.live.with_dependent_mut(|_, e| {
            e.as_mut()
                .is_some_and(|e| e.act_step(observed, action, &mut NoHooks))
        })
    }

    /// Runs `action` on the observed step; the finished record once the episode is over (the
    /// episode is gone then).
    pub fn act(&mut self, action: Action) -> Option<RolloutRecord> {
        if self.act_only(action) {
            None
        } else {
            self.take_record()
        }
    }

    pub fn take_record(&mut self) -> Option<RolloutRecord> {
        self.live
            .with_dependent_mut(|_, e| e.take().map(Episode::finish))
    }

    /// The record as [`Episode::finish`] would return it, the episode kept (to draw it).
    pub fn record_now(&self) -> RolloutRecord {
        let e = self.episode();
        let mut record = e.record().clone();
        (record.outcome, record.metrics) = e.outcome();
        record
    }

    pub fn view(&self) -> PolicyView<'_> {
        let observed = self
            .observed
            .as_ref()
            .expect("a view is of an observed step");
        self.episode().view(observed)
    }

    pub fn step(&self) -> usize {
        self.episode().step_index()
    }

    /// What an environment reports of this episode: running, or ended (`done`) with its
    /// outcome.
    pub fn info(&self, done: bool) -> StepInfo {
        let e = self.episode();
        let (o, m) = e.outcome();
        StepInfo {
            condition: self.index,
            steps: e.step_index(),
            done,
            success: done && o.success(),
            completion: done && o.completion(),
            v_rel_mps: m.contact_speed_mps,
            f_max_n: m.contact_time_secs.map(|_| m.max_force_n),
            l_max_m: m.follow_through_m,
            failures: o
                .failures
                .iter()
                .map(|&f| osms_export::rollouts::failure_key(f))
                .collect(),
        }
    }

    /// The phase the last control step ended in; none before the first.
    pub fn last_phase(&self) -> Option<u8> {
        self.episode().record().phase.last().copied()
    }
}

/// What an environment reports after a step.
#[derive(Debug, Clone, PartialEq)]
pub struct StepInfo {
    pub condition: usize,
    /// Control steps taken.
    pub steps: usize,
    pub done: bool,
    /// The outcome as it stands (final once done).
    pub success: bool,
    pub completion: bool,
    /// v_rel at first contact (m/s), once it happened.
    pub v_rel_mps: Option<f64>,
    /// f_max within Δt_eval of first contact (N), once it happened.
    pub f_max_n: Option<f64>,
    /// ℓ_max (m).
    pub l_max_m: f64,
    /// The failure kinds, by their stored names (`drop`, `force_exceeded`).
    pub failures: Vec<String>,
}
