//! Test-only stage kinds, one file each; `pipelines/engine.toml` wires them together.

mod combine;
mod drop;
mod fold_rows;
mod gather;
mod numbers;
mod offset;
mod panic;
mod shift;
mod signs;
mod spin;
mod sum;
mod sum_of_a;

pub use combine::CombineKind;
pub use drop::{DropKind, DropParams};
pub use fold_rows::FoldRowsKind;
pub use gather::GatherKind;
pub use numbers::{NumbersKind, NumbersParams, TestRole};
pub use offset::OffsetKind;
pub use panic::{PanicKind, PanicParams};
pub use shift::{ShiftKind, ShiftParams};
pub use signs::SignsKind;
pub use spin::{SpinKind, SpinParams};
pub use sum::SumKind;
pub use sum_of_a::SumOfAKind;

use osms_make::Registry;

/// All test kinds.
pub fn registry() -> Registry {
    let mut r = Registry::new();
    r.register_itemised(NumbersKind)
        .register_itemised(DropKind)
        .register(SignsKind)
        .register(ShiftKind)
        .register(OffsetKind)
        .register(SumKind)
        .register(CombineKind)
        .register_itemised(PanicKind)
        .register(FoldRowsKind)
        .register(GatherKind)
        .register(SumOfAKind)
        .register(SpinKind);
    r
}
