//! `error_pairs`: the cross-fitted IL students π̄ on their held-out D_E conditions, the frozen
//! teacher queried at every visited state (paper 4.3).

use std::collections::BTreeSet;

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Kind, Numerics, Slot, StageError};
use osms_sim::artifacts::{EvalRow, WorldArtifact};
use osms_sim::conditions::TaskCondition;
use osms_sim::control::DrSpec;
use osms_sim::{RolloutSpec, World};
use serde::{Deserialize, Serialize};

use super::in_fold;
use crate::artifacts::{Dataset, ErrorPairs, PairRollout, StudentArtifact, Teacher};
use crate::student::{Student, paired_rollout};

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ErrorPairsParams {
    /// Domain randomisation of the student's rollouts (a preset name or a table); absent: the
    /// teacher's training setting.
    pub dr: Option<DrSpec>,
}

/// What `error_pairs` builds once: the world, the teacher, the student, the rollout spec and
/// the conditions of the student's held-out fold (with their D_E items).
pub struct PairsPrepared {
    world: World,
    teacher: Teacher,
    student: Student,
    spec: RolloutSpec,
    conditions: Vec<(u32, TaskCondition)>,
}

/// What a stage that rolls a student out with the teacher queried needs: the world, the
/// teacher with the rollouts' domain randomisation `dr` (absent: its training setting), and
/// the student's rollout spec under it.
pub(crate) fn beside_teacher<P>(
    ctx: &Ctx<'_, P>,
    student: &Student,
    dr: &Option<DrSpec>,
) -> Result<(World, Teacher, RolloutSpec), StageError> {
    let mut teacher: Teacher = ctx.input("teacher")?;
    teacher.task = teacher.task.with_dr(dr);
    let spec = student.rollout_spec(&teacher.task.rollout);
    Ok((ctx.input::<WorldArtifact>("world")?.world()?, teacher, spec))
}

/// The IL student π̄_f on the D_E conditions held out from it, the teacher queried at every
/// visited state (paper 4.3). Rollout `i` draws its domain randomisation from ("item", i) and
/// the policy's noise from ("policy", i).
pub struct ErrorPairsStage;
impl Kind for ErrorPairsStage {
    const KIND: &'static str = "error_pairs";
    /// 2: the rollouts' evaluation rows keep their DR draws.
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Dataset>("data").roles(&["d_e"]),
        Slot::one::<StudentArtifact>("student"),
        Slot::one::<Teacher>("teacher"),
    ];
    const DOC: &'static str =
        "cross-fitted IL students on their held-out D_E conditions, paired with teacher actions";
    type Params = ErrorPairsParams;

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }
}

impl ItemStage for ErrorPairsStage {
    type Prepared = PairsPrepared;
    type Item = PairRollout;
    type Output = ErrorPairs;

    fn prepare(&self, ctx: &Ctx<'_, ErrorPairsParams>) -> Result<PairsPrepared, StageError> {
        let student: StudentArtifact = ctx.input("student")?;
        let fold = ctx.fold();
        let own = fold.map(|f| (f.index, f.count));
        if student.fold != own {
            let name = |f: Option<(u32, u32)>| {
                f.map_or_else(|| "no fold".into(), |(i, n)| format!("fold {i} of {n}"))
            };
            return Err(format!(
                "input `student` is cross-fitted for {} but this stage is {}\nhint: declare both stages with the same `folds` and reference the student stage by name, so each fold takes its own student",
                name(student.fold),
                name(own)
            )
            .into());
        }
        let trained: BTreeSet<u32> = student.items.iter().copied().collect();
        let mut conditions = Vec::new();
        for item in ctx.items::<Dataset>("data")? {
            let r = item?.rollout;
            if fold.is_some_and(|f| !in_fold(r.item, f)) {
                continue;
            }
            // Holds by construction for students of this fold; a student trained elsewhere on
            // the same items would be scored on its own training conditions.
            if fold.is_some() && trained.contains(&r.item) {
                return Err(format!(
                    "input `student` trained on D_E item {} of the fold held out from it",
                    r.item
                )
                .into());
            }
            conditions.push((r.item, r.record.condition));
        }
        let (world, teacher, spec) = beside_teacher(ctx, &student.student, &ctx.params.dr)?;
        Ok(PairsPrepared {
            world,
            teacher,
            student: student.student,
            spec,
            conditions,
        })
    }
    fn n_items(&self, _: &Ctx<'_, ErrorPairsParams>, p: &PairsPrepared) -> usize {
        p.conditions.len()
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, ErrorPairsParams>,
        p: &PairsPrepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<PairRollout, StageError> {
        let (item, condition) = &p.conditions[index];
        let paired = paired_rollout(
            &p.world,
            &p.spec,
            &p.student,
            (&p.teacher.agent, &p.teacher.task),
            condition.clone(),
            rng.clone(),
            ctx.rng("policy", index as u64),
        );
        Ok(PairRollout {
            item: *item,
            student: paired.record.intended.clone(),
            teacher: paired.teacher,
            phase: paired.phase,
            eval: EvalRow::of(paired.record),
        })
    }
    fn merge(
        &self,
        ctx: &Ctx<'_, ErrorPairsParams>,
        _: PairsPrepared,
        rollouts: Vec<PairRollout>,
    ) -> Result<ErrorPairs, StageError> {
        Ok(ErrorPairs {
            fold: ctx.fold().map(|f| (f.index, f.count)),
            rollouts,
        })
    }
}
