//! The policy crate's stage kinds, one file each: the teacher (`teacher`, `eval_teacher`,
//! `teacher_table`), its datasets (`collect`, `osw_windows`) and the students (`student`,
//! `eval_student`, `error_pairs`, the `dagger` diagnostic) and `evaluate`, any of the three
//! policies on a condition set.

mod checks;
mod collect;
mod dagger;
mod dagger_round;
mod error_pairs;
mod eval_student;
mod eval_teacher;
mod evaluate;
mod evaluations;
mod osw_windows;
mod student;
mod teacher;
mod teacher_table;

pub use collect::{CollectParams, CollectStage, DatasetRole};
pub use dagger::{DaggerPrepared, DaggerStage};
pub use dagger_round::{DaggerRoundParams, DaggerRoundPrepared, DaggerRoundStage};
pub use error_pairs::{ErrorPairsParams, ErrorPairsStage, PairsPrepared};
pub use eval_student::{EvalStudentParams, EvalStudentStage};
pub use eval_teacher::{EvalTeacherParams, EvalTeacherStage};
pub use evaluate::{EvaluateParams, EvaluateStage, Evaluated};
pub use evaluations::{Evaluates, EvaluationKind, evaluation_kinds};
pub use osw_windows::OswWindowsStage;
pub use student::StudentStage;
pub use teacher::{TeacherParams, TeacherStage};
pub use teacher_table::TeacherTableStage;

use osms_core::rng::StreamRng;
use osms_make::{Ctx, Fold, Numerics};
use osms_sim::artifacts::{Conditions, EvalRow};
use osms_sim::{RolloutSpec, World};

use crate::student::{ChunkExecution, Student, rollouts_executed};

/// What a kind that rolls out or trains networks depends on beyond its inputs: MuJoCo,
/// osms-sim's and osms-nn's numerics.
pub fn numerics() -> Vec<Numerics> {
    let mut n = osms_sim::stages::numerics();
    n.push(Numerics {
        name: "osms-nn",
        version: osms_nn::NUMERICS_VERSION.to_string(),
    });
    n
}

/// A student's evaluation rows for items `first ..`: rollout i on condition i, its domain
/// randomisation from `dr[i - first]` (its ("item", i) stream), its noise from ("policy", i),
/// all stepped in lockstep ([`rollouts`]).
pub(crate) fn student_rows<P>(
    ctx: &Ctx<'_, P>,
    (world, conditions): (&World, &Conditions),
    (student, execution, spec): (&Student, ChunkExecution, &RolloutSpec),
    first: usize,
    dr: Vec<StreamRng>,
) -> Vec<EvalRow> {
    let items = dr
        .into_iter()
        .enumerate()
        .map(|(k, dr)| {
            let i = first + k;
            (conditions.items[i].clone(), dr, ctx.rng("policy", i as u64))
        })
        .collect();
    rollouts_executed(world, spec, (student, execution), items)
        .into_iter()
        .map(EvalRow::of)
        .collect()
}

/// Whether D_E item `item` belongs to fold `fold` (the conditions held out from π̄_fold).
pub fn in_fold(item: u32, fold: Fold) -> bool {
    item % fold.count == fold.index
}

/// Registers the policy stage kinds.
pub fn register(registry: &mut osms_make::Registry) {
    registry
        .register(TeacherStage)
        .register_itemised(EvalTeacherStage)
        .register(TeacherTableStage)
        .register_itemised(CollectStage)
        .register(OswWindowsStage)
        .register(StudentStage)
        .register_itemised(EvalStudentStage)
        .register_itemised(EvaluateStage)
        .register_itemised(ErrorPairsStage)
        .register_itemised(DaggerStage)
        .register_itemised(DaggerRoundStage);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folds_partition_the_items() {
        let count = 3;
        for item in 0..30u32 {
            let owners: Vec<u32> = (0..count)
                .filter(|&index| in_fold(item, Fold { index, count }))
                .collect();
            assert_eq!(owners, vec![item % count], "item {item}");
        }
    }
}
