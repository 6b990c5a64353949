//! `world`: the MJCF of the ten object variants, each compiled by MuJoCo once.

use osms_make::{Ctx, Kind, Numerics, Slot, Stage, StageError};

use crate::artifacts::WorldArtifact;
use crate::spec::WorldSpec;
use crate::world::World;

/// Builds the MJCF of the ten variants and checks that MuJoCo compiles each.
pub struct WorldStage;
impl Kind for WorldStage {
    const KIND: &'static str = "world";
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[];
    const DOC: &'static str =
        "the MuJoCo catching world: xArm7 + ORCA-like hand + ten objects (MJCF per object)";
    type Params = WorldSpec;

    fn numerics() -> Vec<Numerics> {
        super::numerics()
    }
}

impl Stage for WorldStage {
    type Output = WorldArtifact;

    fn run(&self, ctx: &Ctx<'_, WorldSpec>) -> Result<WorldArtifact, StageError> {
        let world = World::new(ctx.params.clone())?;
        Ok(WorldArtifact {
            spec: world.spec.clone(),
            xml: world.all_xml().to_vec(),
            home_palm_pos: world.home_palm_pos,
            home_palm_normal: world.home_palm_normal,
        })
    }
}
