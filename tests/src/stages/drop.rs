//! `drop` (test kind): boxes thrown onto a plane in MuJoCo: every bit of the simulation shows in where they rest.

use mujoco_rs::prelude::MjModel;
use osms_core::check::{Check, Checked};
use osms_core::rng::{self, StreamRng};
use osms_make::{Ctx, ItemStage, Kind, Numerics, Scale, Slot, StageError};
use serde::{Deserialize, Serialize};

use crate::artifacts::Drops;

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DropParams {
    /// Number of drops (items).
    pub n: u32,
    /// Physics steps of 2 ms per drop.
    #[serde(default = "default_steps")]
    pub steps: u32,
}
fn default_steps() -> u32 {
    400
}

/// Any value that parses: test kinds exercise the engine, not params' ranges.
impl Check for DropParams {
    fn check(&self) -> Checked {
        Ok(())
    }
}

const DROP_XML: &str = r#"<mujoco>
  <option timestep="0.002" integrator="implicitfast" cone="elliptic"/>
  <worldbody>
    <geom type="plane" size="2 2 0.1" friction="0.8 0.02 0.001"/>
    <body pos="0 0 0.5">
      <freejoint/>
      <geom type="box" size="0.03 0.02 0.015" mass="0.05"/>
    </body>
  </worldbody>
</mujoco>"#;

/// Throws a small box onto a plane with a random velocity and records where it comes to rest:
/// contacts, friction and the elliptic cone make this sensitive to every bit of the simulation.
pub struct DropKind;
impl Kind for DropKind {
    const KIND: &'static str = "drop";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[];
    const DOC: &'static str = "MuJoCo box throws onto a plane (test kind)";
    type Params = DropParams;

    fn scale(params: &DropParams, _: &[(&str, f64)]) -> Scale {
        Scale::items(f64::from(params.n))
    }

    fn numerics() -> Vec<Numerics> {
        vec![Numerics {
            name: "mujoco",
            version: osms_sim::mujoco_version(),
        }]
    }
}

impl ItemStage for DropKind {
    type Prepared = MjModel;
    type Item = Vec<f64>;
    type Output = Drops;

    fn prepare(&self, _: &Ctx<'_, DropParams>) -> Result<MjModel, StageError> {
        Ok(MjModel::from_xml_string(DROP_XML)?)
    }
    fn n_items(&self, ctx: &Ctx<'_, DropParams>, _: &MjModel) -> usize {
        ctx.params.n as usize
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, DropParams>,
        model: &MjModel,
        _: usize,
        rng: &mut StreamRng,
    ) -> Result<Vec<f64>, StageError> {
        let mut data = model.make_data();
        let v: Vec<f64> = (0..6).map(|_| rng::uniform(rng, -2.0, 2.0)).collect();
        data.qvel_mut().copy_from_slice(&v);
        for _ in 0..ctx.params.steps {
            data.step();
        }
        Ok(data.qpos().to_vec())
    }
    fn merge(
        &self,
        _: &Ctx<'_, DropParams>,
        _: MjModel,
        items: Vec<Vec<f64>>,
    ) -> Result<Drops, StageError> {
        Ok(Drops { finals: items })
    }
}
