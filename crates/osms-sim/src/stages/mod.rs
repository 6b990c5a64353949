//! The simulator's stage kinds, one file each: `world`, `conditions` and `eval_scripted`.

mod checks;
mod conditions;
mod eval_scripted;
mod world;

pub use conditions::{ConditionsParams, ConditionsStage};
pub use eval_scripted::{EvalParams, EvalScriptedStage};
pub use world::WorldStage;

/// What the output of a kind that steps MuJoCo through osms-sim depends on beyond its inputs:
/// the loaded MuJoCo and osms-sim's numerics.
pub fn numerics() -> Vec<osms_make::Numerics> {
    vec![
        osms_make::Numerics {
            name: "mujoco",
            version: crate::mujoco_version(),
        },
        osms_make::Numerics {
            name: "osms-sim",
            version: crate::NUMERICS_VERSION.to_string(),
        },
    ]
}

/// Registers the simulator's stage kinds.
pub fn register(registry: &mut osms_make::Registry) {
    registry
        .register(WorldStage)
        .register_itemised(ConditionsStage)
        .register_itemised(EvalScriptedStage);
}
