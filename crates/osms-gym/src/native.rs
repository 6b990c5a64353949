//! The store's own policies acting on a pool's episodes: the scripted catcher, a teacher and a
//! student, each exactly as its evaluation stage rolls it out.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use osms_core::rng::StreamRng;
use osms_policy::artifacts::{StudentArtifact, Teacher};
use osms_policy::catch::TeacherQuery;
use osms_policy::flow::FlowSampler;
use osms_policy::student::{ChunkRunner, Student};
use osms_sim::catcher::ScriptedCatcher;
use osms_sim::control::Action;
use osms_sim::{Policy, PolicyView, RolloutSpec};
use self_cell::self_cell;

use crate::error::{GymError, Result};
use crate::project::{Project, Protocol};
use crate::slot::Slot;

/// A policy of the store, loaded once: its per-rollout state in a pool is keyed by this load
/// ([`Native::id`]), never by its name, so two loads (of one stage, or of same-named stages of
/// two profiles) never share a rollout's state.
#[derive(Clone)]
pub struct Native {
    id: u64,
    kind: NativeKind,
}

/// Which policy of the store.
#[derive(Clone)]
pub enum NativeKind {
    /// The scripted privileged catcher, as the protocol's stage sets it up (its gains, how it
    /// reads the world and its rollout spec: [`crate::ScriptedSetup`]).
    Scripted,
    /// A frozen teacher, deterministic: the residual on its prior (`eval_teacher`'s).
    Teacher { name: String, teacher: Arc<Teacher> },
    /// A flow-matching student with its noise from the protocol's ("policy", i) stream
    /// (`eval_student`'s), its network prepared for sampling once (packed weights), as an
    /// evaluation stage prepares it once per batch of rollouts.
    Student {
        name: String,
        student: Arc<StudentSampler>,
    },
}

self_cell!(
    /// A student with its network prepared for sampling.
    pub struct StudentSampler {
        owner: Student,
        #[covariant]
        dependent: FlowSampler,
    }
);

impl Native {
    /// The policy `name` names: `scripted`, or a built instance of a `teacher` or `student`
    /// stage (`teacher`, `student_naive@0`, `student_il#1`).
    pub fn load(project: &Project, name: &str) -> Result<Native> {
        static LOADS: AtomicU64 = AtomicU64::new(0);
        let kind = Self::load_kind(project, name)?;
        Ok(Native {
            id: LOADS.fetch_add(1, Ordering::Relaxed),
            kind,
        })
    }

    fn load_kind(project: &Project, name: &str) -> Result<NativeKind> {
        if name == "scripted" {
            return Ok(NativeKind::Scripted);
        }
        if !project.has_stage(name) {
            let mut known = vec!["scripted".to_string()];
            known.extend(project.stages_of(&["teacher", "student"]));
            return Err(project.unknown(name, "a policy", &known));
        }
        let (_, kind) = project.instance(name)?;
        match kind {
            "teacher" => Ok(NativeKind::Teacher {
                name: name.to_string(),
                teacher: Arc::new(project.load::<Teacher>(name)?),
            }),
            "student" => Ok(NativeKind::Student {
                name: name.to_string(),
                student: Arc::new(StudentSampler::new(
                    project.load::<StudentArtifact>(name)?.student,
                    |s| s.net.sampler(),
                )),
            }),
            other => Err(GymError::WrongKind {
                name: name.to_string(),
                kind: other.to_string(),
                expected: "a policy is `scripted` or an instance of a `teacher` or `student` stage (e.g. `teacher`, `student_naive@0`)".to_string(),
            }),
        }
    }

    /// This load's identity (unique in the process).
    pub fn id(&self) -> u64 {
        self.id
    }

    pub fn name(&self) -> &str {
        match &self.kind {
            NativeKind::Scripted => "scripted",
            NativeKind::Teacher { name, .. } | NativeKind::Student { name, .. } => name,
        }
    }

    /// The rollout spec this policy runs under in `protocol`: the protocol's, with the history
    /// a student reads, or a teacher's own task under the protocol's domain randomisation.
    pub fn spec(&self, protocol: &Protocol) -> RolloutSpec {
        match &self.kind {
            NativeKind::Scripted => protocol.rules.scripted.rollout.clone(),
            NativeKind::Teacher { teacher, .. } => {
                protocol.rules.teacher_task(&teacher.task).rollout
            }
            NativeKind::Student { student, .. } => {
                protocol.rules.student_spec(student.borrow_owner())
            }
        }
    }

    /// Refuses a protocol whose chunk execution this policy cannot run: a horizon longer than
    /// a student's chunks.
    pub fn check_protocol(&self, protocol: &Protocol) -> Result<()> {
        if let NativeKind::Student { student, name } = &self.kind {
            protocol
                .rules
                .execution
                .check_for(&student.borrow_owner().params)
                .map_err(|e| GymError::State(format!("`{name}` under `{}`: {e}", protocol.name)))?;
        }
        Ok(())
    }

    /// Whether the policy reads the admissible contact force (the teacher's privileged frame).
    pub fn reads_contact_force(&self) -> bool {
        matches!(self.kind, NativeKind::Teacher { .. })
    }

    /// The policy's state at the start of rollout `index` of `protocol`.
    pub fn start(&self, protocol: &Protocol, index: usize) -> NativeEpisode {
        match &self.kind {
            NativeKind::Scripted => NativeEpisode::Scripted(ScriptedCatcher::with_perception(
                protocol.rules.scripted.catcher.clone(),
                protocol.rules.rollout.control.clone(),
                protocol.rules.scripted.perception,
            )),
            NativeKind::Teacher { teacher, .. } => {
                NativeEpisode::Teacher(TeacherEpisode::new(teacher.clone(), |t| {
                    TeacherQuery::new(&t.agent, &t.task)
                }))
            }
            NativeKind::Student { student, .. } => NativeEpisode::Student(
                protocol.policy_rng(index),
                ChunkRunner::new(protocol.rules.execution, &student.borrow_owner().params),
            ),
        }
    }

    /// The actions of a batch of running episodes, each with its state and what it observed;
    /// `last_phase` is the phase the episode's last control step ended in (none at step 0).
    pub fn act(
        &self,
        batch: &mut [(&mut NativeEpisode, PolicyView<'_>, Option<u8>)],
    ) -> Vec<Action> {
        if let NativeKind::Student { student, .. } = &self.kind {
            let (sampler, student) = (student.borrow_dependent(), student.borrow_owner());
            let obs: Vec<Vec<f32>> = batch
                .iter()
                .map(|(_, v, _)| student.observation(v))
                .collect();
            let states = batch.iter_mut().map(|(state, _, _)| match state {
                NativeEpisode::Student(rng, runner) => (rng, runner),
                _ => unreachable!("a student's episodes hold its noise streams"),
            });
            return student.act_executed(sampler, &obs, states);
        }
        batch
            .iter_mut()
            .map(|(state, view, last_phase)| match state {
                NativeEpisode::Scripted(catcher) => catcher.act(view),
                NativeEpisode::Teacher(cell) => cell.with_dependent_mut(|_, query| {
                    if let Some(p) = last_phase {
                        query.observe_phase(*p);
                    }
                    query.act(view)
                }),
                NativeEpisode::Student(..) => {
                    unreachable!("a student acts on its whole batch at once")
                }
            })
            .collect()
    }
}

self_cell!(
    /// A teacher query with the teacher it borrows.
    pub struct TeacherEpisode {
        owner: Arc<Teacher>,
        #[covariant]
        dependent: TeacherQuery,
    }
);

/// A native policy's state in one rollout.
pub enum NativeEpisode {
    Scripted(ScriptedCatcher),
    Teacher(TeacherEpisode),
    /// Its noise stream and chunk state.
    Student(StreamRng, ChunkRunner),
}

/// The store's policies' state in the running episodes of a pool or a vector environment, by
/// (policy load, episode), with the generation each last acted in: a state lives and ends with
/// its episode.
#[derive(Default)]
pub(crate) struct NativeStates {
    states: std::collections::BTreeMap<(u64, u64), (NativeEpisode, u64)>,
}

/// One observed episode a native policy is asked to act on.
pub(crate) struct Asked<'s> {
    /// What keys the episode among the running ones (a pool's condition, an environment's
    /// episode number).
    pub episode: u64,
    pub slot: &'s Slot,
}

impl NativeStates {
    /// The actions of `native` for the observed episodes `asked` (an observation of generation
    /// `generation`), under `spec`, the rollout spec the episodes run under: `native` acts as
    /// its own evaluation stage does, which needs the episodes to run under its rollout spec,
    /// the policy to act from each episode's first step and once per observation (a second
    /// call on one observation would advance a student's noise stream). A refused call changes
    /// nothing.
    pub fn act(
        &mut self,
        native: &Native,
        protocol: &Protocol,
        spec: &RolloutSpec,
        generation: u64,
        asked: &[Asked<'_>],
    ) -> Result<Vec<Action>> {
        native.check_protocol(protocol)?;
        if native.spec(protocol) != *spec {
            return Err(GymError::State(format!(
                "`{}` runs under a rollout spec of its own: make it the policy the episodes run for (osms.eval.evaluate's `policy`, CatchVectorEnv's `native`) to act on them",
                native.name()
            )));
        }
        for a in asked {
            let (index, step) = (a.slot.index, a.slot.step());
            match self.states.get(&(native.id(), a.episode)) {
                Some((_, acted)) if *acted == generation => {
                    return Err(GymError::State(format!(
                        "`{}` already acted on this observation (condition {index}, control step {step}): a policy of the store answers each observation once, as its rollouts do",
                        native.name(),
                    )));
                }
                Some(_) => {}
                None if step == 0 => {}
                None => {
                    return Err(GymError::State(format!(
                        "`{}` first saw condition {index} at control step {step}: a policy of the store acts from a rollout's first step",
                        native.name(),
                    )));
                }
            }
        }
        let mut states: Vec<(u64, NativeEpisode)> = asked
            .iter()
            .map(|a| {
                let state = match self.states.remove(&(native.id(), a.episode)) {
                    Some((state, _)) => state,
                    None => native.start(protocol, a.slot.index),
                };
                (a.episode, state)
            })
            .collect();
        let mut batch: Vec<_> = states
            .iter_mut()
            .zip(asked)
            .map(|((_, state), a)| (state, a.slot.view(), a.slot.last_phase()))
            .collect();
        let actions = native.act(&mut batch);
        drop(batch);
        self.states.extend(
            states
                .into_iter()
                .map(|(episode, state)| ((native.id(), episode), (state, generation))),
        );
        Ok(actions)
    }

    /// Drops every policy's state in `episode` (it ended).
    pub fn end(&mut self, episode: u64) {
        self.states.retain(|(_, e), _| *e != episode);
    }
}
