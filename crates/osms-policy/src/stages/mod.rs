//! The policy crate's stage kinds, one file each: the teacher (`teacher`, `eval_teacher`,
//! `teacher_table`), its datasets (`collect`, `osw_windows`) and the students (`student`,
//! `eval_student`, `error_pairs`) and `evaluate`, any of the three policies on a condition set.

mod collect;
mod error_pairs;
mod eval_student;
mod eval_teacher;
mod evaluate;
mod osw_windows;
mod student;
mod teacher;
mod teacher_table;

pub use collect::{CollectParams, CollectStage, DatasetRole};
pub use error_pairs::{ErrorPairsParams, ErrorPairsStage, PairsPrepared};
pub use eval_student::{EvalStudentParams, EvalStudentStage};
pub use eval_teacher::{EvalTeacherParams, EvalTeacherStage};
pub use evaluate::{EvaluateParams, EvaluateStage, Evaluated};
pub use osw_windows::OswWindowsStage;
pub use student::StudentStage;
pub use teacher::{TeacherParams, TeacherStage};
pub use teacher_table::TeacherTableStage;

use osms_make::{Fold, Numerics};

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
        .register_itemised(ErrorPairsStage);
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
