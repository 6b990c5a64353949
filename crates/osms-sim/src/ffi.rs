//! Process-wide MuJoCo settings. The workspace denies `unsafe_code`; this module is one of the
//! few files that allow it (ARCHITECTURE.md, "Unsafe code").
#![allow(unsafe_code)]

/// Routes MuJoCo's warnings and errors to the `log` crate (and from there to osms's tracing
/// output) instead of a `MUJOCO_LOG.TXT` in the working directory. Call once at the very start
/// of `main`, before any other thread exists.
pub fn route_mujoco_logs_at_startup() {
    // SAFETY: MuJoCo's log handler is a non-atomic global; this runs at the start of `main`,
    // before any thread that could use MuJoCo is spawned, and mujoco-rs installs it only once.
    unsafe { mujoco_rs::prelude::install_logging_hook() }
}
