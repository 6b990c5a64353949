//! How sampled chunks become executed actions ([`ChunkExecution`], [`ChunkRunner`]) and the
//! student as a rollout [`Policy`](osms_sim::Policy).

use osms_core::rng::StreamRng;
use osms_sim::{Action, N_ACTION, Policy, PolicyView};
use serde::{Deserialize, Serialize};

use super::params::StudentParams;
use super::train::Student;
use crate::flow::FlowSampler;
use crate::{Error, Result};

/// How a student's sampled chunks become executed actions (issue 68, beyond the paper; the
/// default is the paper's). Params of the evaluation stages, not of training: one trained
/// student runs under any of them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ChunkExecution {
    /// The execution horizon h: the first h actions of each sampled chunk run open loop before
    /// the next sample (1, the paper's: replan every step; at most the chunk's length).
    pub horizon: usize,
    /// ACT's temporal ensemble (Zhao et al. 2023): sample a chunk every step and execute the
    /// average of every live chunk's prediction for this step, the i-th oldest weighted by
    /// exp(−m·i); the value is m (ACT's 0.01, which favours the older predictions a little; a
    /// negative m favours the newest). Needs `horizon = 1`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ensemble: Option<f64>,
}

impl Default for ChunkExecution {
    fn default() -> Self {
        ChunkExecution {
            horizon: 1,
            ensemble: None,
        }
    }
}

impl ChunkExecution {
    /// The paper's: the first action of every step's chunk.
    pub fn is_paper(&self) -> bool {
        *self == ChunkExecution::default()
    }

    /// Refuses an execution the student's chunks cannot carry: the plan's checks
    /// (`osms_core::check::Check`), then a horizon past the chunk and ensemble weights that
    /// would overflow over it.
    pub fn check_for(&self, params: &StudentParams) -> Result<()> {
        <Self as osms_core::check::Check>::check(self)
            .map_err(|e| Error::from(e.within("execution")))?;
        if self.horizon > params.chunk {
            return Err(Error::Params(format!(
                "execution.horizon = {}: must be within 1 ..= {} (the student's chunk length)",
                self.horizon, params.chunk
            )));
        }
        if let Some(m) = self.ensemble
            && m.abs() * (params.chunk - 1) as f64 > MAX_ENSEMBLE_EXPONENT
        {
            return Err(Error::Params(format!(
                "execution.ensemble = {m}: over the student's {} overlapping predictions the weights exp(−m·i) span more than exp({MAX_ENSEMBLE_EXPONENT}) and overflow\nhint: |m| · (chunk − 1) must be at most {MAX_ENSEMBLE_EXPONENT}",
                params.chunk
            )));
        }
        Ok(())
    }
}

/// The largest |m| · i an ensemble's weights exp(−m·i) may reach: exp(709) is the last finite
/// f64, and the weights are summed.
const MAX_ENSEMBLE_EXPONENT: f64 = 700.0;

/// One episode's chunk state under a [`ChunkExecution`]: the chunks sampled so far that still
/// cover a step to come, each with the step it was sampled at.
#[derive(Debug, Clone, PartialEq)]
pub struct ChunkRunner {
    pub(super) execution: ChunkExecution,
    /// Actions per chunk.
    pub(super) chunk: usize,
    pub(super) step: usize,
    /// Oldest first.
    pub(super) live: std::collections::VecDeque<(usize, Vec<f64>)>,
}

impl ChunkRunner {
    pub fn new(execution: ChunkExecution, params: &StudentParams) -> Self {
        ChunkRunner {
            execution,
            chunk: params.chunk,
            step: 0,
            live: std::collections::VecDeque::new(),
        }
    }

    /// Whether this step samples a new chunk.
    pub fn samples(&self) -> bool {
        self.execution.ensemble.is_some()
            || self
                .live
                .back()
                .is_none_or(|(start, _)| self.step >= start + self.execution.horizon)
    }

    /// The chunk sampled at this step (de-standardised, step-major).
    pub(super) fn push(&mut self, chunk: Vec<f64>) {
        debug_assert_eq!(chunk.len(), self.chunk * N_ACTION);
        if self.execution.ensemble.is_none() {
            // Only the newest chunk is ever read without an ensemble.
            self.live.clear();
        }
        self.live.push_back((self.step, chunk));
    }

    /// This step's de-standardised action, then the next step. The paper's execution returns
    /// the newest chunk's first action unchanged.
    pub(super) fn next(&mut self) -> Vec<f64> {
        let step = self.step;
        self.step += 1;
        while self
            .live
            .front()
            .is_some_and(|(start, _)| start + self.chunk <= step)
        {
            self.live.pop_front();
        }
        let at = |(start, chunk): &(usize, Vec<f64>)| {
            let j = step - start;
            chunk[j * N_ACTION..(j + 1) * N_ACTION].to_vec()
        };
        match self.execution.ensemble {
            None => at(self.live.back().expect("a chunk covers every step")),
            Some(m) => {
                let mut sum = vec![0.0; N_ACTION];
                let mut total = 0.0;
                for (i, live) in self.live.iter().enumerate() {
                    // libm, not the platform's exp: the weights must have the same bits everywhere.
                    let w = libm::exp(-m * i as f64);
                    for (s, a) in sum.iter_mut().zip(at(live)) {
                        *s += w * a;
                    }
                    total += w;
                }
                sum.into_iter().map(|s| s / total).collect()
            }
        }
    }
}

/// A student as the simulator's policy: noise for each step's sample from `rng` (the policy's
/// own stream, apart from the rollout's DR stream), its network prepared once for the episode.
pub struct StudentPolicy<'s> {
    pub(super) student: &'s Student,
    pub(super) sampler: FlowSampler<'s>,
    pub(super) rng: StreamRng,
    pub(super) runner: ChunkRunner,
}

impl<'s> StudentPolicy<'s> {
    /// The paper's execution: a new chunk every step, its first action executed.
    pub fn new(student: &'s Student, rng: StreamRng) -> Self {
        Self::with_execution(student, rng, ChunkExecution::default())
    }

    /// The student under another [`ChunkExecution`] (checked by the caller,
    /// [`ChunkExecution::check_for`]).
    pub fn with_execution(student: &'s Student, rng: StreamRng, execution: ChunkExecution) -> Self {
        StudentPolicy {
            student,
            sampler: student.net.sampler(),
            rng,
            runner: ChunkRunner::new(execution, &student.params),
        }
    }

    pub fn student(&self) -> &'s Student {
        self.student
    }
}

impl Policy for StudentPolicy<'_> {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        let obs = self.student.observation(view);
        let [action] = self
            .student
            .act_executed(
                &self.sampler,
                std::slice::from_ref(&obs),
                [(&mut self.rng, &mut self.runner)],
            )
            .try_into()
            .unwrap_or_else(|_| unreachable!("one observation, one action"));
        action
    }

    /// A deployable policy: it reads no privileged quantity at all.
    fn reads_contact_force(&self) -> bool {
        false
    }
}
