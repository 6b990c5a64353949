//! Episodes of a protocol stepped for a caller that chooses the actions: many in parallel for a
//! batch policy ([`Pool`]), or one at a time for an environment ([`SingleEpisode`]).

use std::sync::Arc;

use osms_sim::artifacts::EvalRow;
use osms_sim::control::{Action, N_ACTION};
use osms_sim::{Episode, PolicyView, RolloutRecord, RolloutSpec};
use rayon::prelude::*;

use crate::error::{ActionProblem, GymError, Result};
use crate::native::{Asked, Native, NativeStates};
use crate::project::Protocol;
use crate::slot::Slot;
pub use crate::slot::StepInfo;

/// Fails unless `action` is one the world runs: 24 finite channels in [−1, 1].
pub fn check_action(action: &[f64], condition: usize, step: usize) -> Result<Action> {
    let problem = if action.len() != N_ACTION {
        Some(ActionProblem::Shape {
            expected: format!("({N_ACTION},)"),
            got: format!("({},)", action.len()),
        })
    } else if let Some(channel) = action.iter().position(|a| !a.is_finite()) {
        Some(ActionProblem::NotFinite { channel })
    } else {
        // The world's own bound (`Episode::act_step`), so whatever passes here runs.
        action
            .iter()
            .position(|a| a.abs() > 1.0 + 1e-9)
            .map(|channel| ActionProblem::OutOfRange {
                channel,
                value: action[channel],
            })
    };
    match problem {
        Some(problem) => Err(GymError::Action {
            condition,
            step,
            problem,
        }),
        None => Ok(std::array::from_fn(|i| action[i])),
    }
}

/// Slot `k` of `slots`, if it awaits an action.
fn awaiting(slots: &[Option<Slot>], k: usize) -> Result<&Slot> {
    slots
        .get(k)
        .and_then(Option::as_ref)
        .filter(|s| s.awaits_action())
        .ok_or_else(|| GymError::State(format!("slot {k} awaits no action")))
}

/// Rollouts of a protocol on a list of its conditions, `n_envs` at a time, stepped in lockstep
/// for one batch policy: [`Pool::observe`] starts rollouts in free slots and observes every
/// running one, the caller chooses their actions, [`Pool::act`] runs them. Slots refill in
/// list order. Each rollout is its stage's rollout on its condition, whatever `n_envs` and the
/// order the others finish in (nothing is shared between episodes but the world).
pub struct Pool {
    protocol: Arc<Protocol>,
    spec: Arc<RolloutSpec>,
    reads_contact_force: bool,
    indices: Vec<usize>,
    next: usize,
    slots: Vec<Option<Slot>>,
    records: Vec<Option<RolloutRecord>>,
    /// Which slot holds which entry of `indices`.
    position: Vec<usize>,
    /// Counts observations: a batch is answered at the generation it was observed in.
    generation: u64,
    /// The store's policies' state in each running rollout, keyed by its condition.
    native: NativeStates,
}

impl Pool {
    /// A pool over conditions `indices` of `protocol` (each at most once), episodes under
    /// `spec`, observing the contact force if `reads_contact_force`.
    pub fn new(
        protocol: Arc<Protocol>,
        spec: RolloutSpec,
        reads_contact_force: bool,
        indices: Vec<i64>,
        n_envs: usize,
    ) -> Result<Pool> {
        if n_envs == 0 {
            return Err(GymError::Argument(
                "n_envs must be at least 1 (rollouts stepped at once)".to_string(),
            ));
        }
        if indices.is_empty() {
            return Err(GymError::Argument(format!(
                "no conditions to run: the list of condition indices is empty (`{}` has {} conditions; leave indices out to run them all)",
                protocol.conditions_name,
                protocol.conditions.len()
            )));
        }
        let mut checked = Vec::with_capacity(indices.len());
        let mut seen = vec![false; protocol.conditions.len()];
        for &i in &indices {
            protocol.condition(i)?;
            let i = i as usize;
            if std::mem::replace(&mut seen[i], true) {
                return Err(GymError::Argument(format!(
                    "condition {i} is listed twice: a protocol's rollout of a condition is one rollout"
                )));
            }
            checked.push(i);
        }
        let n = checked.len();
        Ok(Pool {
            protocol,
            spec: Arc::new(spec),
            reads_contact_force,
            indices: checked,
            next: 0,
            slots: (0..n_envs.min(n.max(1))).map(|_| None).collect(),
            records: (0..n).map(|_| None).collect(),
            position: vec![0; n_envs.min(n.max(1))],
            generation: 0,
            native: NativeStates::default(),
        })
    }

    pub fn protocol(&self) -> &Protocol {
        &self.protocol
    }

    pub fn spec(&self) -> &RolloutSpec {
        &self.spec
    }

    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// Starts the next rollouts in free slots and observes every running episode, in parallel.
    /// The observed slots, in slot order; empty once every rollout has finished.
    pub fn observe(&mut self) -> Vec<usize> {
        let reads = self.reads_contact_force;
        loop {
            for (k, slot) in self.slots.iter_mut().enumerate() {
                if slot.is_none() && self.next < self.indices.len() {
                    *slot = Some(Slot::start(
                        &self.protocol,
                        &self.spec,
                        self.indices[self.next],
                    ));
                    self.position[k] = self.next;
                    self.next += 1;
                }
            }
            // Only slots not yet observed: observing pushes a frame onto the history.
            let running: Vec<bool> = self
                .slots
                .par_iter_mut()
                .map(|slot| match slot {
                    Some(s) if !s.awaits_action() => s.observe(reads),
                    Some(_) => true,
                    None => false,
                })
                .collect();
            // An episode over before an observation (none is today) finishes, and its slot
            // takes the next condition.
            let mut refilled = false;
            for (k, &r) in running.iter().enumerate() {
                if !r && let Some(mut slot) = self.slots[k].take() {
                    self.records[self.position[k]] = slot.take_record();
                    refilled = true;
                }
            }
            if !refilled {
                self.generation += 1;
                return (0..self.slots.len()).filter(|&k| running[k]).collect();
            }
        }
    }

    fn slot(&self, k: usize) -> &Slot {
        self.slots[k]
            .as_ref()
            .expect("only observed slots are asked about")
    }

    /// What the policy sees in slot `k` (observed).
    pub fn view(&self, k: usize) -> PolicyView<'_> {
        self.slot(k).view()
    }

    /// The condition index of slot `k`'s rollout.
    pub fn condition(&self, k: usize) -> usize {
        self.slot(k).index
    }

    /// The control step slot `k` observed.
    pub fn step(&self, k: usize) -> usize {
        self.slot(k).step()
    }

    /// Runs one action per observed slot (`(slot, action)`), in parallel; an action the world
    /// cannot run fails the call before any episode moves.
    pub fn act(&mut self, actions: Vec<(usize, Vec<f64>)>) -> Result<()> {
        let mut checked: Vec<Option<Action>> = vec![None; self.slots.len()];
        for (k, a) in actions {
            let slot = awaiting(&self.slots, k)?;
            checked[k] = Some(check_action(&a, slot.index, slot.step())?);
        }
        if let Some(k) =
            self.slots.iter().enumerate().position(|(k, s)| {
                s.as_ref().is_some_and(Slot::awaits_action) && checked[k].is_none()
            })
        {
            return Err(GymError::State(format!(
                "condition {} awaits an action",
                self.slot(k).index
            )));
        }
        let finished: Vec<Option<RolloutRecord>> = self
            .slots
            .par_iter_mut()
            .zip(checked)
            .map(|(slot, action)| match (slot.as_mut(), action) {
                (Some(s), Some(a)) => s.act(a),
                _ => None,
            })
            .collect();
        for (k, record) in finished.into_iter().enumerate() {
            if let Some(record) = record {
                let condition = self.indices[self.position[k]];
                self.native.end(condition as u64);
                self.records[self.position[k]] = Some(record);
                self.slots[k] = None;
            }
        }
        Ok(())
    }

    /// The actions of the store's policy `native` for the observed `slots` (an observation of
    /// generation `generation`): it acts as its own evaluation stage does, which needs the
    /// pool to run under its rollout spec, the policy to act from each rollout's first step and
    /// once per observation (a second call on one batch would advance a student's noise
    /// stream). A refused call changes nothing.
    pub fn native_act(
        &mut self,
        native: &Native,
        generation: u64,
        slots: &[usize],
    ) -> Result<Vec<Action>> {
        if generation != self.generation {
            return Err(GymError::State(
                "these observations are stale: act on the latest observation of the pool"
                    .to_string(),
            ));
        }
        let asked = slots
            .iter()
            .map(|&k| {
                let slot = awaiting(&self.slots, k)?;
                Ok(Asked {
                    episode: slot.index as u64,
                    slot,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        self.native
            .act(native, &self.protocol, &self.spec, generation, &asked)
    }

    /// Whether every rollout has finished.
    pub fn is_done(&self) -> bool {
        self.records.iter().all(Option::is_some)
    }

    /// The condition indices, in the order given, with each rollout's row.
    pub fn rows(&self) -> Result<Vec<(usize, EvalRow)>> {
        if !self.is_done() {
            return Err(GymError::State(
                "the pool's rollouts have not all finished".to_string(),
            ));
        }
        Ok(self
            .indices
            .iter()
            .zip(&self.records)
            .filter_map(|(&i, r)| r.as_ref().map(|r| (i, EvalRow::of(r.clone()))))
            .collect())
    }
}

/// One episode at a time, stepped by the caller: a gymnasium environment's core. An ended
/// episode stays (its last state can be drawn) until the next reset.
pub struct SingleEpisode {
    protocol: Arc<Protocol>,
    spec: Arc<RolloutSpec>,
    reads_contact_force: bool,
    slot: Option<Slot>,
    running: bool,
}

impl SingleEpisode {
    pub fn new(protocol: Arc<Protocol>, spec: RolloutSpec, reads_contact_force: bool) -> Self {
        SingleEpisode {
            protocol,
            spec: Arc::new(spec),
            reads_contact_force,
            slot: None,
            running: false,
        }
    }

    pub fn protocol(&self) -> &Protocol {
        &self.protocol
    }

    /// Starts the rollout of condition `index` (the protocol's, whatever came before) and
    /// observes its first step.
    pub fn reset(&mut self, index: i64) -> Result<()> {
        self.protocol.condition(index)?;
        let mut slot = Slot::start(&self.protocol, &self.spec, index as usize);
        self.running = slot.observe(self.reads_contact_force);
        self.slot = Some(slot);
        Ok(())
    }

    /// The observation awaiting an action, while the episode runs.
    pub fn view(&self) -> Option<PolicyView<'_>> {
        self.slot.as_ref().filter(|_| self.running).map(Slot::view)
    }

    /// The episode, running or ended (its last state can be drawn), since the last reset.
    pub fn episode(&self) -> Option<&Episode<'_>> {
        self.slot.as_ref().map(Slot::episode)
    }

    /// Runs `action` and observes the next step; fails on an action the world cannot run, or
    /// when no episode runs.
    pub fn step(&mut self, action: &[f64]) -> Result<StepInfo> {
        let slot = match self.slot.as_mut() {
            Some(slot) if self.running => slot,
            _ => {
                return Err(GymError::State(
                    "no episode is running: call reset() first (and again after an episode ends)"
                        .to_string(),
                ));
            }
        };
        let action = check_action(action, slot.index, slot.step())?;
        self.running = slot.act_only(action) && slot.observe(self.reads_contact_force);
        Ok(self.info())
    }

    /// The episode's state: running, or ended with its outcome.
    pub fn info(&self) -> StepInfo {
        match &self.slot {
            Some(slot) => slot.info(!self.running),
            None => StepInfo {
                condition: 0,
                steps: 0,
                done: true,
                success: false,
                completion: false,
                v_rel_mps: None,
                f_max_n: None,
                l_max_m: 0.0,
                failures: Vec::new(),
            },
        }
    }

    /// The ended episode's row (its condition and the row), once it has ended.
    pub fn row(&self) -> Option<(usize, EvalRow)> {
        self.slot
            .as_ref()
            .filter(|_| !self.running)
            .map(|s| (s.index, EvalRow::of(s.record_now())))
    }
}

/// `rollouts.csv` of rows on conditions of one set, as `osms export` writes an evaluation's:
/// the same columns, the `condition` column naming each row's condition.
pub fn rows_csv(rows: &[(usize, EvalRow)]) -> Result<String> {
    let (conditions, rows): (Vec<usize>, Vec<EvalRow>) = rows.iter().cloned().unzip();
    osms_export::rollouts::table_on(&rows, &conditions)
        .csv()
        .map_err(|e| GymError::State(format!("cannot write the rows: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn problem(action: &[f64]) -> Option<ActionProblem> {
        match check_action(action, 6, 2) {
            Ok(_) => None,
            Err(GymError::Action {
                condition: 6,
                step: 2,
                problem,
            }) => Some(problem),
            Err(e) => panic!("not an action error: {e}"),
        }
    }

    #[test]
    fn actions_the_world_cannot_run_are_named_by_channel() {
        let mut a = vec![0.0; N_ACTION];
        assert_eq!(problem(&a), None);
        a[23] = 1.0;
        a[0] = -1.0;
        assert_eq!(problem(&a), None, "the bounds themselves are valid");
        a[3] = f64::NAN;
        assert_eq!(problem(&a), Some(ActionProblem::NotFinite { channel: 3 }));
        a[3] = 0.0;
        a[5] = 1.5;
        assert_eq!(
            problem(&a),
            Some(ActionProblem::OutOfRange {
                channel: 5,
                value: 1.5
            })
        );
        assert!(matches!(
            problem(&a[..7]),
            Some(ActionProblem::Shape { .. })
        ));
        let message = check_action(&[f64::INFINITY; N_ACTION], 6, 2)
            .expect_err("infinite")
            .to_string();
        assert!(
            message.contains("condition 6 at control step 2") && message.contains("channel 0"),
            "{message}"
        );
    }
}
