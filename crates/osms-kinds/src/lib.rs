//! Every stage kind osms ships, in one registry: what the command line, the Python package and
//! the end-to-end tests plan a pipeline with.
//!
//! A stage key holds its kind's name and code version, so whatever reads a project's store (the
//! CLI, osms-gym) must plan with the same kinds; keeping the list here lets the Python package
//! read a pipeline without linking the command line.

use osms_make::Registry;

/// The stage kinds osms ships: each crate's own `register` list, lowest crate first.
pub fn registry() -> Registry {
    let mut registry = Registry::new();
    osms_sim::stages::register(&mut registry);
    osms_policy::stages::register(&mut registry);
    osms_method::stages::register(&mut registry);
    osms_report::register(&mut registry);
    registry
}

/// The pipeline osms ships (the checkout's `pipeline.toml`, byte for byte): what `osms init`
/// writes into a new project, so a user of the wheel alone has the same stages and profiles
/// (tests/tests/cli.rs plans each of its profiles with [`registry`]).
pub const PIPELINE: &str = include_str!("../../../pipeline.toml");
