//! `fold_rows` (test kind): the rows of one fold (a cross-fitting split in miniature).

use osms_core::NoParams;
use osms_make::{Ctx, Kind, Slot, Stage, StageError};

use crate::artifacts::Numbers;

/// The rows of fold k of `count` (row i belongs to fold i mod count), or every row when the
/// stage has no folds: a cross-fitting split in miniature.
pub struct FoldRowsKind;
impl Kind for FoldRowsKind {
    const KIND: &'static str = "fold_rows";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Numbers>("values")];
    const DOC: &'static str = "the rows of this instance's fold (test kind)";
    type Params = NoParams;
}

impl Stage for FoldRowsKind {
    type Output = Numbers;
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Numbers, StageError> {
        let v: Numbers = ctx.sharded("values")?;
        let keep = |i: usize| {
            ctx.fold()
                .is_none_or(|f| i % f.count as usize == f.index as usize)
        };
        Ok(Numbers {
            rows: v
                .rows
                .into_iter()
                .enumerate()
                .filter(|(i, _)| keep(*i))
                .map(|(_, r)| r)
                .collect(),
        })
    }
}
