//! `spin` (test kind): uses a given amount of CPU time on one thread, to check that a record's
//! core-seconds are the CPU time its build used, whatever ran beside it.

use osms_core::check::{Check, Checked};
use osms_make::{Ctx, Kind, Stage, StageError, thread_cpu_secs};
use serde::{Deserialize, Serialize};

use crate::artifacts::Total;

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpinParams {
    /// CPU milliseconds to use (by the thread's own CPU clock, not the wall clock: a loaded
    /// machine stretches the wall time, not the work).
    pub cpu_ms: u64,
}

/// Any value that parses: test kinds exercise the engine, not params' ranges.
impl Check for SpinParams {
    fn check(&self) -> Checked {
        Ok(())
    }
}

/// Uses `cpu_ms` of CPU on one thread; its output says how much.
pub struct SpinKind;
impl Kind for SpinKind {
    const KIND: &'static str = "spin";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [osms_make::Slot] = &[];
    const DOC: &'static str = "uses a given CPU time on one thread (test kind)";
    type Params = SpinParams;
}

impl Stage for SpinKind {
    type Output = Total;
    fn run(&self, ctx: &Ctx<'_, SpinParams>) -> Result<Total, StageError> {
        let target = ctx.params.cpu_ms as f64 * 1e-3;
        let start = thread_cpu_secs();
        let mut x = 1u64;
        while thread_cpu_secs() - start < target {
            for i in 0..10_000u64 {
                x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(i);
            }
        }
        std::hint::black_box(x);
        Ok(Total {
            count: ctx.params.cpu_ms,
            sum: 0.0,
        })
    }
}
