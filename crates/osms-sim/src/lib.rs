//! The MuJoCo catching world: xArm7 + ORCA-like hand + ten objects as MJCF, task conditions ω,
//! domain randomisation, the rollout loop with contacts, metrics and success, the scripted catcher
//! and open-loop replay, with the world, conditions and scripted-evaluation stage kinds.
//!
//! Rooms: the world and its rollouts ([`world`], [`mjcf`], [`episode`], [`control`],
//! [`metrics`], [`catcher`], [`replay`]) know nothing of the engine; [`artifacts`] holds the
//! world, condition-set and evaluation artifacts and [`stages`] one thin adapter per stage
//! kind.

pub mod artifacts;
pub mod catcher;
pub mod conditions;
pub mod control;
pub mod episode;
mod error;
pub mod ffi;
pub mod flight;
pub mod metrics;
pub mod mjcf;
pub mod policy;
pub mod reach;
pub mod replay;
pub mod robot;
pub mod spec;
pub mod stages;
pub mod vec3;
pub mod world;

pub use conditions::{ConditionSpec, TaskCondition};
pub use control::{Action, N_ACTION, N_ARM};
pub use episode::{Episode, RolloutRecord, RolloutSpec};
pub use error::{Result, SimError};
pub use metrics::{Failure, FirstContact, Metrics, Outcome, Phase, SuccessSpec};
pub use policy::{Hooks, NoHooks, Policy, PolicyView};
pub use spec::{ObjectFamily, ObjectSize, ObjectVariant, WorldSpec};
pub use world::{GeomClass, Ids, World};

/// The numerics version of osms-sim: bump it whenever world, control, episode or metrics code
/// may change the bytes of an artifact built by simulation, so no stale artifact stays cached.
/// It enters the keys of every kind that simulates (with MuJoCo's own version).
pub const NUMERICS_VERSION: u32 = 2;

/// The MuJoCo release osms is pinned to (scripts/setup-mujoco installs it).
pub const MUJOCO_PINNED: &str = "3.17.0";

/// The version of the MuJoCo library actually loaded (its own `mj_versionString`).
pub fn mujoco_version() -> String {
    mujoco_rs::mujoco_version().to_string()
}

#[cfg(test)]
mod tests {
    use mujoco_rs::prelude::*;

    use super::*;

    #[test]
    fn home_posture_is_collision_free_and_holds_still() {
        let world = World::new(WorldSpec::default()).expect("world");
        let v = ObjectVariant::all()[3];
        let model = world.model(v);
        let mut data = model.make_data();
        world.set_home(&mut data);
        // Park the object far away so only robot contacts could appear.
        data.qpos_mut()[world.ids.object_qpos..world.ids.object_qpos + 3]
            .copy_from_slice(&[3.0, 3.0, 1.0]);
        let home: Vec<f64> = world
            .spec
            .arm_home_rad
            .iter()
            .chain(world.spec.hand_home_rad.iter())
            .copied()
            .collect();
        data.ctrl_mut().copy_from_slice(&home);
        data.forward();
        assert_eq!(data.ffi().ncon, 0, "contacts at home");
        // Gravity-compensated servos hold the posture: after 1 s every joint is within 5 mrad.
        for _ in 0..500 {
            data.step();
        }
        for (i, &adr) in world.ids.arm_qpos.iter().enumerate() {
            let err = (data.qpos()[adr] - world.spec.arm_home_rad[i]).abs();
            assert!(err < 0.005, "arm joint {i} moved by {err} rad");
        }
        let p = world.home_palm_pos;
        assert!(
            (p[0] - 0.52).abs() < 0.03 && p[1].abs() < 0.03 && (p[2] - 0.87).abs() < 0.03,
            "palm at {p:?}"
        );
        assert!(
            world.home_palm_normal[2] > 0.99,
            "palm normal {:?}",
            world.home_palm_normal
        );
    }

    #[test]
    fn every_variant_compiles() {
        let spec = WorldSpec::default();
        for v in ObjectVariant::all() {
            let xml = mjcf::world_xml(&spec, v);
            let model =
                MjModel::from_xml_string(&xml).unwrap_or_else(|e| panic!("{v}: {e}\n{xml}"));
            assert_eq!(model.ffi().nu, 24, "{v}");
            assert_eq!(model.ffi().nq, 7 + 17 + 7, "{v}");
        }
    }
}
