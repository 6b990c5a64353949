//! The MuJoCo catching world: xArm7 + ORCA-like hand + ten objects as MJCF, task conditions,
//! domain randomisation, control loop, contacts, metrics and success, scripted catcher.

pub mod mjcf;
pub mod robot;
pub mod spec;

pub use spec::{ObjectFamily, ObjectSize, ObjectVariant, WorldSpec};

#[cfg(test)]
mod tests {
    use mujoco_rs::prelude::*;

    use super::*;

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
