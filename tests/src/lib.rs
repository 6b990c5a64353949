//! End-to-end tests of osms: test-only stage kinds, a test binary, golden snapshots and benchmarks.
//!
//! The kinds here exercise every engine feature (itemised and plain kinds, seeded and unseeded,
//! fixed seeds, several inputs, early cutoff, MuJoCo rollouts sharing one model across
//! threads); `pipelines/engine.toml` wires them into a pipeline with `tiny`, `small` and
//! `paper` profiles.

pub mod artifacts;
pub mod golden;
pub mod project;
pub mod python;
pub mod s3;
pub mod stages;

pub use project::Project;
pub use stages::registry;
