//! The Rust-native baselines that `scripts/bench-python` measures Python-driven evaluation
//! against: the same rollouts under one constant action, stepped without Python.

use std::sync::Arc;

use osms_sim::control::Action;
use osms_sim::{Episode, NoHooks, Policy, PolicyView, RolloutSpec};
use rayon::prelude::*;

use crate::error::Result;
use crate::pool::Pool;
use crate::project::Protocol;

/// A policy that always answers `action`.
struct Constant(Action);

impl Policy for Constant {
    fn act(&mut self, _: &PolicyView<'_>) -> Action {
        self.0
    }

    fn reads_contact_force(&self) -> bool {
        false
    }
}

/// The rollouts of `indices` under `action`, `n_envs` at a time in a [`Pool`] (what
/// `osms.eval.evaluate` runs, less the Python call per control step): their control steps.
pub fn pooled(
    protocol: Arc<Protocol>,
    spec: RolloutSpec,
    indices: Vec<i64>,
    n_envs: usize,
    action: Action,
) -> Result<usize> {
    let mut pool = Pool::new(protocol, spec, false, indices, n_envs)?;
    loop {
        let slots = pool.observe();
        if slots.is_empty() {
            break;
        }
        pool.act(slots.into_iter().map(|k| (k, action.to_vec())).collect())?;
    }
    Ok(pool.rows()?.iter().map(|(_, r)| r.steps as usize).sum())
}

/// The same rollouts one per task on rayon's threads, as the evaluation stages run rollouts:
/// their control steps.
pub fn per_thread(
    protocol: &Protocol,
    spec: &RolloutSpec,
    indices: &[i64],
    action: Action,
) -> Result<usize> {
    for &i in indices {
        protocol.condition(i)?;
    }
    Ok(indices
        .par_iter()
        .map(|&i| {
            let i = i as usize;
            let episode = Episode::new(
                &protocol.world,
                spec,
                protocol.conditions[i].clone(),
                protocol.dr_rng(i),
            );
            episode.run(&mut Constant(action), &mut NoHooks).steps
        })
        .sum())
}
