//! Student rollouts: one, many in lockstep batches, and paired with the teacher queried at
//! every state the student visits.

use osms_core::rng::StreamRng;
use osms_sim::conditions::TaskCondition;
use osms_sim::{Action, Episode, NoHooks, Policy, PolicyView, RolloutRecord, RolloutSpec, World};

use super::chunks::{ChunkExecution, ChunkRunner, StudentPolicy};
use super::train::Student;
use crate::catch::{CatchTaskSpec, TeacherQuery};
use crate::ppo::Agent;

impl Student {
    /// `base` with the history the student reads: the rollout must keep as many deployable
    /// frames as the student was trained on.
    pub fn rollout_spec(&self, base: &RolloutSpec) -> RolloutSpec {
        let mut spec = base.clone();
        spec.history_steps = self.params.history;
        spec
    }
}

/// The student's rollout on condition ω: domain randomisation from `dr`, the policy's noise
/// from `policy`. `spec` comes from [`Student::rollout_spec`].
pub fn rollout(
    world: &World,
    spec: &RolloutSpec,
    student: &Student,
    condition: TaskCondition,
    dr: StreamRng,
    policy: StreamRng,
) -> RolloutRecord {
    let mut policy = StudentPolicy::new(student, policy);
    Episode::new(world, spec, condition, dr).run(&mut policy, &mut NoHooks)
}

/// How many student rollouts an evaluation stage hands [`rollouts`] at once: a few times
/// [`LOCKSTEP_SLOTS`], so that the batch stays full while episodes of different lengths end,
/// few enough that two threads still share out a development stream evenly.
pub const ROLLOUT_BATCH: usize = 64;

/// How many student rollouts [`rollouts`] steps together: enough rows for the matrix kernels'
/// tiled path to pay (`cargo bench -p osms-policy --bench student` measures the batch
/// lengths).
pub const LOCKSTEP_SLOTS: usize = 16;

/// Student rollouts on many conditions, stepped in lockstep with the policy acting on every
/// running episode at once (one matrix product per layer for the batch instead of one
/// matrix-vector product per episode), [`LOCKSTEP_SLOTS`] episodes at a time: an episode that
/// ends gives its slot to the next item, so the products keep their rows while the short
/// episodes of a batch end before the long ones. `items` are (ω, DR stream, policy stream);
/// rollout i is bit for bit [`rollout`] on item i.
pub fn rollouts(
    world: &World,
    spec: &RolloutSpec,
    student: &Student,
    items: Vec<(TaskCondition, StreamRng, StreamRng)>,
) -> Vec<RolloutRecord> {
    rollouts_in_slots(
        world,
        spec,
        (student, ChunkExecution::default()),
        items,
        LOCKSTEP_SLOTS,
    )
}

/// [`rollouts`] under another [`ChunkExecution`]: rollout i is bit for bit the rollout of
/// [`StudentPolicy::with_execution`] on item i.
pub fn rollouts_executed(
    world: &World,
    spec: &RolloutSpec,
    (student, execution): (&Student, ChunkExecution),
    items: Vec<(TaskCondition, StreamRng, StreamRng)>,
) -> Vec<RolloutRecord> {
    rollouts_in_slots(world, spec, (student, execution), items, LOCKSTEP_SLOTS)
}

/// [`rollouts_executed`] with at most `slots` episodes running at once (at least 1).
pub fn rollouts_in_slots(
    world: &World,
    spec: &RolloutSpec,
    (student, execution): (&Student, ChunkExecution),
    items: Vec<(TaskCondition, StreamRng, StreamRng)>,
    slots: usize,
) -> Vec<RolloutRecord> {
    let mut records: Vec<Option<RolloutRecord>> = vec![None; items.len()];
    let mut pending = items.into_iter().enumerate();
    let mut running: Vec<(usize, Episode<'_>, (StreamRng, ChunkRunner))> = Vec::new();
    let sampler = student.net.sampler();
    loop {
        // Every slot observes its next step; an episode that is over finishes and its slot
        // takes the next item, so each running episode has observed once when this ends.
        let (mut observed, mut obs) = (Vec::new(), Vec::new());
        while observed.len() < running.len() || running.len() < slots.max(1) {
            let k = observed.len();
            if k == running.len() {
                let Some((i, (condition, dr, policy))) = pending.next() else {
                    break;
                };
                let runner = ChunkRunner::new(execution, &student.params);
                running.push((
                    i,
                    Episode::new(world, spec, condition, dr),
                    (policy, runner),
                ));
            }
            // A student reads no contact force (`StudentPolicy::reads_contact_force`).
            match running[k].1.observe_step(false) {
                Some(o) => {
                    obs.push(student.observation(&running[k].1.view(&o)));
                    observed.push(o);
                }
                None => {
                    let (i, episode, _) = running.swap_remove(k);
                    records[i] = Some(episode.finish());
                }
            }
        }
        if observed.is_empty() {
            break;
        }
        let states = running
            .iter_mut()
            .map(|(_, _, (rng, runner))| (rng, runner));
        let actions = student.act_executed(&sampler, &obs, states);
        for ((slot, o), action) in running.iter_mut().zip(observed).zip(actions) {
            slot.1.act_step(o, action, &mut NoHooks);
        }
    }
    records
        .into_iter()
        .map(|r| r.expect("every item ran to its end"))
        .collect()
}

/// A student rollout with the frozen teacher queried at every visited state.
pub struct PairedRollout {
    pub record: RolloutRecord,
    /// The teacher's action at each step's state, 24 per step.
    pub teacher: Vec<f32>,
    /// The phase known online when each step's action is chosen: the phase the previous step
    /// ended in (approach at step 0), as the teacher's phase input and the action-error model
    /// see it.
    pub phase: Vec<u8>,
}

/// The student's rollout on ω, as [`rollout`], recording what the teacher would have done at
/// every state the student reaches (paper 4.3). The teacher never acts.
pub fn paired_rollout(
    world: &World,
    spec: &RolloutSpec,
    student: &Student,
    teacher: (&Agent, &CatchTaskSpec),
    condition: TaskCondition,
    dr: StreamRng,
    policy: StreamRng,
) -> PairedRollout {
    struct Paired<'s, 't> {
        student: StudentPolicy<'s>,
        teacher: TeacherQuery<'t>,
        actions: Vec<f32>,
        phases: Vec<u8>,
    }
    impl Policy for Paired<'_, '_> {
        fn act(&mut self, view: &PolicyView<'_>) -> Action {
            let t = self.teacher.act(view);
            self.actions.extend(t.iter().map(|&a| a as f32));
            self.phases.push(self.teacher.phase());
            self.student.act(view)
        }
    }
    let mut paired = Paired {
        student: StudentPolicy::new(student, policy),
        teacher: TeacherQuery::new(teacher.0, teacher.1),
        actions: Vec::new(),
        phases: Vec::new(),
    };
    // A realisable teacher reads a history of its own; the student reads the newest of it.
    let spec = teacher.1.actor_inputs.rollout(spec);
    let mut episode = Episode::new(world, &spec, condition, dr);
    while episode.step(&mut paired, &mut NoHooks) {
        if let Some(&p) = episode.record().phase.last() {
            paired.teacher.observe_phase(p);
        }
    }
    PairedRollout {
        record: episode.finish(),
        teacher: paired.actions,
        phase: paired.phases,
    }
}
