//! `dagger`: one round of DAgger (Ross et al. 2011) as a diagnostic of covariate shift
//! (issue 33), not as the paper's method (`dagger_round`, a round of the DAgger-IL baseline,
//! rolls out with the same [`Visits`]). The IL student π̄ runs on the D_E conditions it was
//! trained on, the frozen teacher is queried at every state it visits, and each of its rollouts,
//! labelled with those teacher actions, joins the teacher's own demonstration of the same
//! condition. A student trained on the set sees the states its predecessor drifted into; if it
//! closes much of the gap to the teacher, the gap was covariate shift, not missing information.

use std::collections::BTreeMap;

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Slot, StageError};
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
pub(super) struct Visits {
    pub(super) world: World,
    pub(super) teacher: Teacher,
    pub(super) student: Student,
    pub(super) spec: RolloutSpec,
}

impl Visits {
    pub(super) fn new<P>(
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
    pub(super) fn labelled(
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

impl Kind for DaggerStage {
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

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }
}

impl ItemStage for DaggerStage {
    type Prepared = DaggerPrepared;
    type Item = DemoGroup;
    type Output = DemoSet;

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
