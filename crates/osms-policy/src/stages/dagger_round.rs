//! `dagger_round`: a round of the DAgger-IL baseline (Ross et al. 2011; issue 68, beyond the
//! paper): a student rolled out on the conditions it was trained on, the frozen teacher queried
//! at every state it visits, the labelled rollouts aggregated with the set it learnt from.

use serde::{Deserialize, Serialize};

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Slot, StageError};
use osms_sim::artifacts::WorldArtifact;
use osms_sim::control::DrSpec;

use super::dagger::Visits;
use crate::artifacts::{DemoGroup, DemoSet, StudentArtifact, Teacher};

/// A round of the DAgger-IL baseline. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DaggerRoundParams {
    /// The chain's number of rounds R: each of its B = ⌊N / (R + 1)⌋ conditions ends with its
    /// demonstration and R labelled student rollouts, N the `target` set's demonstrations
    /// (size-matched). Every round of a chain carries the same R: a later round with a larger
    /// one would relabel fewer conditions and drop the rest of its input.
    pub rounds: u32,
    /// B itself instead of ⌊N / (R + 1)⌋ (absent: size-matched). For a target too small to
    /// share between R + 1 demonstrations per condition (the tiny profile's D_*); the final set
    /// may then exceed the target.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub conditions: Option<usize>,
    /// Domain randomisation of the student's rollouts (a preset name or a table); absent: the
    /// teacher's training setting.
    pub dr: Option<DrSpec>,
}

impl Default for DaggerRoundParams {
    fn default() -> Self {
        DaggerRoundParams {
            rounds: 1,
            conditions: None,
            dr: None,
        }
    }
}

/// What `dagger_round` builds once: its [`Visits`] and the set's leading groups to extend.
pub struct DaggerRoundPrepared {
    visits: Visits,
    groups: Vec<DemoGroup>,
}

/// One DAgger round (Ross et al. 2011) on a demonstration set: the student trained on `demos`
/// runs on the conditions of its B leading groups, the frozen teacher labels every state it
/// visits, and each condition's group gains that rollout. Round 1 reads the Naive set and
/// Naive-IL's student, round r the set of round r − 1 and the student trained on it; after R
/// rounds the set holds B · (R + 1) ≤ N demonstrations. Rollout `i` draws its domain
/// randomisation from ("item", i) and the student's noise from ("policy", i).
pub struct DaggerRoundStage;

impl Kind for DaggerRoundStage {
    const KIND: &'static str = "dagger_round";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<DemoSet>("demos"),
        Slot::one::<StudentArtifact>("student"),
        Slot::one::<Teacher>("teacher"),
        Slot::one::<DemoSet>("target"),
    ];
    const DOC: &'static str = "a round of the DAgger-IL baseline: the student trained on a demonstration set on its leading conditions, labelled by the teacher, added to their groups (size-matched to `target` over the chain's rounds)";
    type Params = DaggerRoundParams;

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }
}

impl ItemStage for DaggerRoundStage {
    type Prepared = DaggerRoundPrepared;
    type Item = DemoGroup;
    type Output = DemoSet;

    fn prepare(&self, ctx: &Ctx<'_, DaggerRoundParams>) -> Result<DaggerRoundPrepared, StageError> {
        let target = ctx.sharded::<DemoSet>("target")?.len();
        let conditions = ctx
            .params
            .conditions
            .unwrap_or(target / (ctx.params.rounds as usize + 1));
        if conditions == 0 {
            return Err(format!(
                "`target` holds {target} demonstrations: too few to share between {} per condition ({} rounds)\nhint: set params.conditions, or fewer rounds",
                ctx.params.rounds + 1,
                ctx.params.rounds
            )
            .into());
        }
        let demos: DemoSet = ctx.sharded("demos")?;
        let used = demos.used_groups().len();
        let mut groups: Vec<DemoGroup> = demos
            .groups
            .into_iter()
            .take(used)
            .filter(|g| !g.demos.is_empty())
            .take(conditions)
            .collect();
        if groups.len() < conditions {
            return Err(format!(
                "input `demos` has {} conditions with demonstrations; {} rounds size-matched to `target`'s {target} demonstrations need {conditions}\nhint: wire a larger set, fewer rounds, or set params.conditions",
                groups.len(),
                ctx.params.rounds
            )
            .into());
        }
        let student: StudentArtifact = ctx.input("student")?;
        let trained: std::collections::BTreeSet<u32> = student.items.iter().copied().collect();
        if groups.iter().any(|g| !trained.contains(&g.item)) {
            return Err("input `student` was not trained on the conditions of input `demos`' leading groups\nhint: wire the student trained on `demos` (round 1: the Naive set's student)".into());
        }
        // The relabelled conditions are this set's own conditions, whichever stream they were
        // drawn from: its construction statistics count them as its target conditions.
        for g in &mut groups {
            g.extension = false;
        }
        Ok(DaggerRoundPrepared {
            visits: Visits::new(ctx, student.student, &ctx.params.dr)?,
            groups,
        })
    }
    fn n_items(&self, _: &Ctx<'_, DaggerRoundParams>, p: &DaggerRoundPrepared) -> usize {
        p.groups.len()
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, DaggerRoundParams>,
        p: &DaggerRoundPrepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<DemoGroup, StageError> {
        let mut group = p.groups[index].clone();
        group.demos.push(p.visits.labelled(
            group.condition.clone(),
            rng.clone(),
            ctx.rng("policy", index as u64),
        ));
        Ok(group)
    }
    fn merge(
        &self,
        _: &Ctx<'_, DaggerRoundParams>,
        _: DaggerRoundPrepared,
        groups: Vec<DemoGroup>,
    ) -> Result<DemoSet, StageError> {
        Ok(DemoSet {
            construction: "dagger".into(),
            target: None,
            used: None,
            groups,
        })
    }
}
