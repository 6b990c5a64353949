//! Demonstration construction (paper 4.4 and 6, "Baselines"): what validation and the
//! constructions read, D_*'s groups from the validation's decisions (Alg. 1 step 4), and the
//! Naive and Normal baselines' groups. Each baseline is extended to D_*'s number of
//! demonstrations as the paper does, from condition streams of its own:
//!
//! - Naive: success-only filtering of D_R, extended with further successful teacher
//!   rollouts;
//! - Normal: unperturbed-only validation of the same candidate sets (the lowest-J candidate
//!   that succeeds unperturbed and, refining, beats J_org), extended with further mixed teacher
//!   rollouts put through the same construction (window, geodesic search, unperturbed
//!   validation).

use osms_core::rng::{StreamId, StreamRng};
use osms_policy::Agent;
use osms_policy::artifacts::{DemoEntry, DemoGroup, DemoRollout, Execution, Origin};
use osms_policy::catch::{CatchTaskSpec, rollout};
use osms_policy::osw::{OswSpec, OswWindow};
use osms_sim::World;
use osms_sim::conditions::sample;

use crate::candidates::{Candidate, SearchParams, candidate_set};
use crate::cvae::Cvae;
use crate::error_model::{ErrorModel, Perturber};
use crate::intervene::{Errors, Snippet, execute};
use crate::select::Decision;
use crate::validate::{
    CandidateReport, Case, Cost, Robustness, ValidateParams, ValidationItem, select_unperturbed,
    unperturbed_reports,
};
use crate::{Error, Result};

/// What validation and D_* read: the world, the teacher, the D_R rollouts with their task,
/// their candidate sets and the error model.
pub struct Inputs {
    pub world: World,
    pub agent: Agent,
    pub task: CatchTaskSpec,
    pub rollouts: Vec<DemoRollout>,
    pub sets: Vec<Vec<Candidate>>,
    pub generator: String,
    pub model: ErrorModel,
}

impl Inputs {
    /// Refuses a validation of other rollouts or other candidate sets than these.
    pub fn check_validation(&self, items: &[ValidationItem], generator: &str) -> Result<()> {
        if items.len() != self.rollouts.len()
            || items
                .iter()
                .zip(&self.rollouts)
                .any(|(v, r)| (v.item, v.attempt) != (r.item, r.attempt))
        {
            return Err(Error::MismatchedInputs(
                "input `validation` was run on other rollouts than `data`".into(),
            ));
        }
        if generator != self.generator
            || items
                .iter()
                .zip(&self.sets)
                .any(|(v, set)| v.validated && v.candidates.len() != set.len())
        {
            return Err(Error::MismatchedInputs(format!(
                "input `validation` was run on other candidate sets ({}) than `candidates` ({})",
                generator, self.generator
            )));
        }
        Ok(())
    }

    /// Rollout `index` as validation sees it; `errors(q)` gives perturbed rollout q's
    /// innovations.
    pub fn case<'a>(&'a self, index: usize, errors: &'a dyn Fn(usize) -> StreamRng) -> Case<'a> {
        Case {
            world: &self.world,
            task: &self.task,
            agent: &self.agent,
            rollout: &self.rollouts[index],
            candidates: &self.sets[index],
            model: &self.model,
            errors,
        }
    }
}

/// What D_* keeps of a selected candidate's successful perturbed rollouts. The paper keeps
/// them as demonstrations without saying which action labels them; `Executed` (the default)
/// labels them with the commanded, perturbed action, so the student learns the recovery the
/// rollout took. The other two are ablations: they separate that labelling from the extra
/// states the perturbed rollouts visit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PerturbedLabels {
    /// The commanded action after the modelled perturbation (Eq. 7's a).
    #[default]
    Executed,
    /// The action before the perturbation (Eq. 7's ā: ζ* in the window, the teacher's after).
    Intended,
    /// No perturbed rollout enters D_* (nor is re-run).
    Omit,
}

/// D_* (Alg. 1 step 4): for a refined or repaired rollout the selected ζ*'s unperturbed
/// rollout and every successful perturbed one (labelled as `labels` says); a kept original as
/// it ran; nothing for a dropped one. The rollouts are re-run with the validation's streams
/// (`errors(q)` for perturbed rollout q of `q_runs`) and checked against its outcomes.
pub fn dstar_group(
    inputs: &Inputs,
    index: usize,
    v: &ValidationItem,
    q_runs: usize,
    labels: PerturbedLabels,
    errors: &dyn Fn(usize) -> StreamRng,
) -> Result<DemoGroup> {
    let r = &inputs.rollouts[index];
    let mut group = DemoGroup {
        extension: false,
        item: r.item,
        attempt: r.attempt,
        condition: r.record.condition.clone(),
        original_success: v.original.success,
        origin: Origin::Dropped,
        demos: Vec::new(),
    };
    let (origin, k) = match v.decision {
        Decision::Drop => return Ok(group),
        Decision::KeepOriginal => {
            group.origin = Origin::Kept;
            group.demos.push(DemoEntry::labelled(
                Execution::Original,
                &r.record,
                r.record.intended.clone(),
            ));
            return Ok(group);
        }
        Decision::Refine { index: k } => (Origin::Refined, k),
        Decision::Repair { index: k } => (Origin::Repaired, k),
    };
    group.origin = origin;
    let zeta = &inputs.sets[index][k].zeta;
    let run = |errors: Option<Errors<'_>>| {
        execute(
            &inputs.world,
            &inputs.task,
            &inputs.agent,
            r.record.condition.clone(),
            r.dr_stream.rng(),
            Some(Snippet {
                start: r.osw.start,
                zeta,
            }),
            errors,
        )
    };
    let mismatch = |what: &str| Error::NotRepeated {
        what: format!("D_R item {}: the selected candidate's {what}", r.item),
    };
    let u = run(None);
    if !u.record.outcome.success() {
        return Err(mismatch("unperturbed rollout"));
    }
    group.demos.push(DemoEntry::labelled(
        Execution::Unperturbed,
        &u.record,
        u.commanded,
    ));
    if labels == PerturbedLabels::Omit {
        return Ok(group);
    }
    let mut successes = 0u32;
    for q in 0..q_runs {
        let e = run(Some(Errors {
            perturber: Perturber::new(&inputs.model),
            rng: errors(q),
        }));
        if e.record.outcome.success() {
            successes += 1;
            let label = match labels {
                PerturbedLabels::Intended => e.record.intended.clone(),
                _ => e.commanded,
            };
            group.demos.push(DemoEntry::labelled(
                Execution::Perturbed { q: q as u32 },
                &e.record,
                label,
            ));
        }
    }
    if v.candidates[k].robustness != (Robustness::Full { successes }) {
        return Err(mismatch("perturbed rollouts"));
    }
    Ok(group)
}

/// How many leading groups reach `target` demonstrations: every D_R group, then extension
/// groups up to the first one that reaches it.
pub fn used(groups: &[DemoGroup], target: Option<usize>) -> Option<usize> {
    let target = target?;
    let mut count = 0;
    for (i, g) in groups.iter().enumerate() {
        if g.extension && count >= target {
            return Some(i);
        }
        count += g.demos.len();
    }
    Some(groups.len())
}

/// A D_R rollout in the Naive set: kept if it succeeded, dropped otherwise.
pub fn naive_group(r: &DemoRollout) -> DemoGroup {
    let success = r.record.outcome.success();
    DemoGroup {
        extension: false,
        item: r.item,
        attempt: r.attempt,
        condition: r.record.condition.clone(),
        original_success: success,
        origin: if success {
            Origin::Kept
        } else {
            Origin::Dropped
        },
        demos: if success {
            vec![DemoEntry::labelled(
                Execution::Original,
                &r.record,
                r.record.intended.clone(),
            )]
        } else {
            Vec::new()
        },
    }
}

/// Naive extension item `index`: the first successful teacher rollout on conditions drawn from
/// `rng`, attempt `a` under the domain randomisation of `attempt_rng(index · max_attempts + a)`.
pub fn naive_extension(
    world: &World,
    task: &CatchTaskSpec,
    agent: &Agent,
    index: usize,
    max_attempts: u32,
    rng: &mut StreamRng,
    attempt_rng: &dyn Fn(u64) -> StreamRng,
) -> Result<DemoGroup> {
    for attempt in 0..max_attempts {
        let condition = sample(&task.conditions, world.home_palm_pos, rng)?;
        let dr = attempt_rng(index as u64 * u64::from(max_attempts) + u64::from(attempt));
        let record = rollout(world, task, agent, condition, dr);
        if record.outcome.success() {
            return Ok(DemoGroup {
                extension: true,
                item: index as u32,
                attempt,
                condition: record.condition.clone(),
                original_success: true,
                origin: Origin::Kept,
                demos: vec![DemoEntry::labelled(
                    Execution::Original,
                    &record,
                    record.intended.clone(),
                )],
            });
        }
    }
    Err(Error::NoTeacherSuccess {
        index,
        attempts: max_attempts,
    })
}

/// One condition through unperturbed-only validation: the selected candidate's unperturbed
/// rollout, the kept original, or nothing.
pub fn normal_group(
    inputs: &Inputs,
    p: &ValidateParams,
    rollout: &DemoRollout,
    candidates: &[Candidate],
    reports: &[CandidateReport],
    extension: bool,
) -> Result<DemoGroup> {
    let success = rollout.record.outcome.success();
    let j_org = p.j_org(success, rollout.record.metrics.max_force_n);
    let mut group = DemoGroup {
        extension,
        item: rollout.item,
        attempt: rollout.attempt,
        condition: rollout.record.condition.clone(),
        original_success: success,
        origin: Origin::Dropped,
        demos: Vec::new(),
    };
    match select_unperturbed(j_org, reports) {
        Some(k) => {
            let e = execute(
                &inputs.world,
                &inputs.task,
                &inputs.agent,
                rollout.record.condition.clone(),
                rollout.dr_stream.rng(),
                Some(Snippet {
                    start: rollout.osw.start,
                    zeta: &candidates[k].zeta,
                }),
                None,
            );
            if !e.record.outcome.success() {
                return Err(Error::NotRepeated {
                    what: format!(
                        "condition {} ({}): the selected candidate's unperturbed rollout",
                        rollout.item,
                        if extension { "extension" } else { "D_R" }
                    ),
                });
            }
            group.origin = if success {
                Origin::Refined
            } else {
                Origin::Repaired
            };
            group.demos.push(DemoEntry::labelled(
                Execution::Unperturbed,
                &e.record,
                e.commanded,
            ));
        }
        None if success => {
            group.origin = Origin::Kept;
            group.demos.push(DemoEntry::labelled(
                Execution::Original,
                &rollout.record,
                rollout.record.intended.clone(),
            ));
        }
        None => {}
    }
    Ok(group)
}

/// Normal extension item `index`: a mixed teacher rollout on a condition drawn from `rng`
/// under the domain randomisation of `dr_stream` (`task` records privileged frames for ω̄),
/// put through the D_R construction: its window, a geodesic search on `manifold` (projection
/// samples from `projection_rng`) and unperturbed-only validation.
#[allow(clippy::too_many_arguments)]
pub fn normal_extension(
    inputs: &Inputs,
    vp: &ValidateParams,
    task: &CatchTaskSpec,
    manifold: &Cvae,
    search: &SearchParams,
    index: usize,
    rng: &mut StreamRng,
    dr_stream: StreamId,
    projection_rng: &mut StreamRng,
) -> Result<DemoGroup> {
    let world = &inputs.world;
    let in_item = |e: Error| Error::Extension {
        index,
        source: Box::new(e),
    };
    let condition = sample(&task.conditions, world.home_palm_pos, rng)?;
    let record = rollout(world, task, &inputs.agent, condition, dr_stream.rng());
    let osw = OswWindow::extract(
        &record,
        &OswSpec {
            h_os: manifold.h_os,
        },
    )
    .map_err(|e| in_item(e.into()))?;
    let r = DemoRollout {
        item: index as u32,
        attempt: 0,
        dr_stream,
        record,
        osw,
    };
    let candidates = if r.osw.complete {
        candidate_set(
            manifold,
            &r.osw.zeta_org,
            &r.osw.omega_bar,
            None,
            search,
            projection_rng,
        )
        .map_err(in_item)?
        .candidates
    } else {
        Vec::new()
    };
    let never = |_: usize| -> StreamRng { unreachable!("unperturbed validation draws no errors") };
    let case = Case {
        world,
        task: &inputs.task,
        agent: &inputs.agent,
        rollout: &r,
        candidates: &candidates,
        model: &inputs.model,
        errors: &never,
    };
    let reports = unperturbed_reports(&case, vp, &mut Cost::default())?;
    normal_group(inputs, vp, &r, &candidates, &reports, true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use osms_policy::student::Demo;

    fn group(extension: bool, demos: usize) -> DemoGroup {
        DemoGroup {
            extension,
            item: 0,
            attempt: 0,
            condition: osms_sim::conditions::sample(
                &osms_sim::ConditionSpec::default(),
                [0.0, 0.0, 1.0],
                &mut osms_core::rng::stream(0, "test", "omega", 0),
            )
            .expect("ω"),
            original_success: true,
            origin: Origin::Kept,
            demos: (0..demos)
                .map(|_| osms_policy::artifacts::DemoEntry {
                    execution: Execution::Original,
                    max_force_n: 0.0,
                    demo: Demo {
                        steps: 0,
                        deployable: Vec::new(),
                        state: Vec::new(),
                        phase: Vec::new(),
                        actions: Vec::new(),
                    },
                })
                .collect(),
        }
    }

    #[test]
    fn an_extension_stops_at_the_group_that_reaches_the_target() {
        let groups = [
            group(false, 1),
            group(false, 0),
            group(true, 1),
            group(true, 0),
            group(true, 1),
            group(true, 1),
        ];
        // D_R gives 1; the extension reaches 3 with its third group (index 4).
        assert_eq!(used(&groups, Some(3)), Some(5));
        assert_eq!(used(&groups, Some(1)), Some(2));
        // D_R groups are never cut, even past the target.
        assert_eq!(used(&groups[..2], Some(0)), Some(2));
        assert_eq!(used(&groups, Some(9)), Some(6));
        assert_eq!(used(&groups, None), None);
    }
}
