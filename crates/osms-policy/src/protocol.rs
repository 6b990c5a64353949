//! What an evaluation's rollouts are: rollout `i` runs condition `i` of its set in its world,
//! its domain randomisation from the stage's ("item", i) stream and a stochastic policy's noise
//! from ("policy", i), under the [`EvalProtocol`] its params set. Every evaluation kind reads
//! its protocol from its params through [`crate::stages::evaluation_kinds`], and so does the
//! gym, so an evaluation means one thing wherever it is run.

use osms_sim::RolloutSpec;
use osms_sim::catcher::{CatcherSpec, Perception};

use crate::catch::CatchTaskSpec;
use crate::student::{ChunkExecution, Student};

/// The rollout rules an evaluation stage's params set, besides its world and conditions.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalProtocol {
    /// The rollout spec a policy without needs of its own runs under: a student reads its own
    /// history on top of it ([`EvalProtocol::student_spec`]), a teacher runs its training task
    /// with its domain randomisation ([`EvalProtocol::teacher_task`]).
    pub rollout: RolloutSpec,
    /// How the scripted catcher runs under it.
    pub scripted: ScriptedSetup,
    /// How a student's chunks are executed.
    pub execution: ChunkExecution,
}

impl EvalProtocol {
    /// The paper's execution, the default catcher under `rollout`.
    pub fn on(rollout: RolloutSpec) -> Self {
        EvalProtocol {
            scripted: ScriptedSetup::default_on(rollout.clone()),
            rollout,
            execution: ChunkExecution::default(),
        }
    }

    /// A teacher's task under this protocol: its own, with the protocol's domain
    /// randomisation.
    pub fn teacher_task(&self, task: &CatchTaskSpec) -> CatchTaskSpec {
        task.with_dr(&Some(self.rollout.dr.clone()))
    }

    /// A student's rollout spec under this protocol: the protocol's, with the history the
    /// student reads.
    pub fn student_spec(&self, student: &Student) -> RolloutSpec {
        student.rollout_spec(&self.rollout)
    }
}

/// The scripted catcher of a protocol: its gains, how it reads the world and the rollout spec
/// it runs under (`eval_scripted`'s `catcher`; an `evaluate` stage's `catcher` and `prior_*`
/// params; the defaults under any other kind, with the protocol's own spec).
#[derive(Clone, Debug, PartialEq)]
pub struct ScriptedSetup {
    pub catcher: CatcherSpec,
    pub perception: Perception,
    pub rollout: RolloutSpec,
}

impl ScriptedSetup {
    /// The default catcher, reading the world as the privileged prior does, under `rollout`.
    pub fn default_on(rollout: RolloutSpec) -> Self {
        ScriptedSetup {
            catcher: CatcherSpec::default(),
            perception: Perception::default(),
            rollout,
        }
    }
}
