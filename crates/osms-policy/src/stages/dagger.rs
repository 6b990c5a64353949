//! `dagger`: one round of DAgger (Ross et al. 2011) as a diagnostic of covariate shift
//! (issue 33), not as the paper's method; `dagger_round`, a round of the DAgger-IL baseline
//! (issue 68, beyond the paper). The IL student π̄ runs on the D_E conditions it was
//! trained on, the frozen teacher is queried at every state it visits, and each of its rollouts,
//! labelled with those teacher actions, joins the teacher's own demonstration of the same
//! condition. A student trained on the set sees the states its predecessor drifted into; if it
//! closes much of the gap to the teacher, the gap was covariate shift, not missing information.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Numerics, Slot, StageError};
use osms_sim::artifacts::WorldArtifact;
use osms_sim::control::DrSpec;
use osms_sim::{RolloutSpec, World};

use super::error_pairs::{ErrorPairsParams, beside_teacher};
use crate::artifacts::{
    Dataset, DemoEntry, DemoGroup, DemoRollout, DemoSet, Execution, Origin, StudentArtifact,
    Teacher,
};
use crate::student::{Student, paired_rollout};

/// What both DAgger kinds roll out with: the world, the frozen teacher, the student and its
/// rollout spec beside the teacher.
struct Visits {
    world: World,
    teacher: Teacher,
    student: Student,
    spec: RolloutSpec,
}

impl Visits {
    fn new<P>(
        ctx: &Ctx<'_, P>,
        student: Student,
        dr: &Option<DrSpec>,
    ) -> Result<Visits, StageError> {
        let (world, teacher, spec) = beside_teacher(ctx, &student, dr)?;
        Ok(Visits {
            world,
            teacher,
            student,
            spec,
        })
    }

    /// The student's rollout on ω (DR from `dr`, its noise from `policy`) as a demonstration
    /// labelled with the teacher's action at every state it visited.
    fn labelled(
        &self,
        condition: osms_sim::conditions::TaskCondition,
        dr: StreamRng,
        policy: StreamRng,
    ) -> DemoEntry {
        let paired = paired_rollout(
            &self.world,
            &self.spec,
            &self.student,
            (&self.teacher.agent, &self.teacher.task),
            condition,
            dr,
            policy,
        );
        DemoEntry::labelled(Execution::StudentVisited, &paired.record, paired.teacher)
    }
}

/// What `dagger` builds once: its [`Visits`] and the D_E rollouts the student was trained on,
/// in item order.
pub struct DaggerPrepared {
    visits: Visits,
    trained: Vec<DemoRollout>,
}

/// π̄'s rollouts on its own training conditions, labelled by the teacher, beside the teacher's
/// demonstrations of the same conditions. Rollout `i` draws its domain randomisation from
/// ("item", i) and the student's noise from ("policy", i).
pub struct DaggerStage;
impl ItemStage for DaggerStage {
    const KIND: &'static str = "dagger";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Dataset>("data").roles(&["d_e"]),
        Slot::one::<StudentArtifact>("student"),
        Slot::one::<Teacher>("teacher"),
    ];
    const DOC: &'static str = "one DAgger round (a diagnostic): a student's rollouts on its training conditions, labelled with the teacher's actions, added to its demonstrations";
    type Params = ErrorPairsParams;
    type Prepared = DaggerPrepared;
    type Item = DemoGroup;
    type Output = DemoSet;

    fn check_params(params: &Self::Params) -> osms_core::check::Checked {
        osms_core::check::Check::check(params)
    }

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }
    fn prepare(&self, ctx: &Ctx<'_, ErrorPairsParams>) -> Result<DaggerPrepared, StageError> {
        let student: StudentArtifact = ctx.input("student")?;
        let mut by_item = BTreeMap::new();
        for item in ctx.items::<Dataset>("data")? {
            let r = item?.rollout;
            by_item.insert(r.item, r);
        }
        let mut trained = Vec::with_capacity(student.items.len());
        for item in &student.items {
            let Some(r) = by_item.remove(item) else {
                return Err(format!(
                    "input `student` was trained on item {item}, which input `data` does not hold\nhint: wire the dataset the student was trained on"
                )
                .into());
            };
            trained.push(r);
        }
        if trained.is_empty() {
            return Err("input `student` was trained on no rollouts of a dataset (it trained on a demonstration set)\nhint: wire a student whose input is `data`, e.g. `student_il#0`".into());
        }
        Ok(DaggerPrepared {
            visits: Visits::new(ctx, student.student, &ctx.params.dr)?,
            trained,
        })
    }
    fn n_items(&self, _: &Ctx<'_, ErrorPairsParams>, p: &DaggerPrepared) -> usize {
        p.trained.len()
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, ErrorPairsParams>,
        p: &DaggerPrepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<DemoGroup, StageError> {
        let original = &p.trained[index];
        let visited = p.visits.labelled(
            original.record.condition.clone(),
            rng.clone(),
            ctx.rng("policy", index as u64),
        );
        Ok(DemoGroup {
            extension: false,
            item: original.item,
            attempt: original.attempt,
            condition: original.record.condition.clone(),
            original_success: original.record.outcome.success(),
            origin: Origin::Kept,
            demos: vec![
                DemoEntry::labelled(
                    Execution::Original,
                    &original.record,
                    original.record.intended.clone(),
                ),
                visited,
            ],
        })
    }
    fn merge(
        &self,
        _: &Ctx<'_, ErrorPairsParams>,
        _: DaggerPrepared,
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
impl ItemStage for DaggerRoundStage {
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
    type Prepared = DaggerRoundPrepared;
    type Item = DemoGroup;
    type Output = DemoSet;

    fn check_params(params: &Self::Params) -> osms_core::check::Checked {
        osms_core::check::Check::check(params)
    }

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }
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
