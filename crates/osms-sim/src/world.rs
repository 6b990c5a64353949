//! The compiled world: one `MjModel` per object variant (identical but for the object geom),
//! the ids the control loop and metrics need, and the class of every geom.

use mujoco_rs::prelude::*;
use mujoco_rs::wrappers::mj_model::traits::ModelType;

use crate::error::{Result, SimError};
use crate::mjcf::{self, BIT_ARM, BIT_HAND, BIT_MOUNT, BIT_OBJECT, BIT_WORLD};
use crate::robot::{ARM_JOINTS, HAND_JOINTS};
use crate::spec::{ObjectVariant, WorldSpec};

/// What a geom belongs to, for classifying contacts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GeomClass {
    /// Ground and pedestal.
    World,
    Arm,
    /// Flange adapter and servo tower: part of the hand assembly, but not an admissible
    /// catching surface.
    Mount,
    Palm,
    Finger,
    Object,
}

impl GeomClass {
    pub const ALL: [GeomClass; 6] = [
        GeomClass::World,
        GeomClass::Arm,
        GeomClass::Mount,
        GeomClass::Palm,
        GeomClass::Finger,
        GeomClass::Object,
    ];

    /// Palm and fingers: the surfaces a catch may start on.
    pub fn is_admissible(self) -> bool {
        matches!(self, GeomClass::Palm | GeomClass::Finger)
    }
}

/// Indices into the model's arrays, the same for every variant.
#[derive(Debug, Clone, PartialEq)]
pub struct Ids {
    pub palm_site: usize,
    pub palm_body: usize,
    pub object_body: usize,
    pub object_geom: usize,
    /// Address of the object's free joint in qpos (7: position, quaternion) and qvel (6).
    pub object_qpos: usize,
    pub object_dof: usize,
    pub arm_qpos: [usize; 7],
    pub arm_dof: [usize; 7],
    pub hand_qpos: [usize; 17],
    pub hand_dof: [usize; 17],
    pub geom_class: Vec<GeomClass>,
}

pub struct World {
    pub spec: WorldSpec,
    models: Vec<MjModel>,
    xml: Vec<String>,
    pub ids: Ids,
    /// Palm centre and normal at the home posture (world frame).
    pub home_palm_pos: [f64; 3],
    pub home_palm_normal: [f64; 3],
}

fn id(model: &MjModel, kind: MjtObjBase, what: &'static str, name: &str) -> Result<usize> {
    model
        .name_to_id(kind, name)
        .ok_or_else(|| SimError::MissingName {
            what,
            name: name.to_string(),
        })
}

fn ids(model: &MjModel) -> Result<Ids> {
    let joint = |name: &str| id(model, MjtObjBase::mjOBJ_JOINT, "joint", name);
    let qpos_of = |j: usize| model.jnt_qposadr()[j] as usize;
    let dof_of = |j: usize| model.jnt_dofadr()[j] as usize;
    let mut arm_qpos = [0; 7];
    let mut arm_dof = [0; 7];
    for (i, name) in ARM_JOINTS.iter().enumerate() {
        let j = joint(name)?;
        arm_qpos[i] = qpos_of(j);
        arm_dof[i] = dof_of(j);
    }
    let mut hand_qpos = [0; 17];
    let mut hand_dof = [0; 17];
    for (i, name) in HAND_JOINTS.iter().enumerate() {
        let j = joint(name)?;
        hand_qpos[i] = qpos_of(j);
        hand_dof[i] = dof_of(j);
    }
    let free = joint("object_free")?;
    let geom_class = (0..model.ffi().ngeom as usize)
        .map(|g| {
            let bits = model.geom_contype()[g] as u32;
            let name = model.id_to_name(MjtObjBase::mjOBJ_GEOM, g).unwrap_or("");
            match bits {
                BIT_WORLD => Ok(GeomClass::World),
                BIT_ARM => Ok(GeomClass::Arm),
                BIT_MOUNT => Ok(GeomClass::Mount),
                BIT_OBJECT => Ok(GeomClass::Object),
                BIT_HAND if name == "hand_palm_geom" => Ok(GeomClass::Palm),
                BIT_HAND => Ok(GeomClass::Finger),
                _ => Err(SimError::Spec(format!(
                    "geom `{name}` has contype {bits}, which is no contact class"
                ))),
            }
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Ids {
        palm_site: id(model, MjtObjBase::mjOBJ_SITE, "site", mjcf::PALM_SITE)?,
        palm_body: id(model, MjtObjBase::mjOBJ_BODY, "body", mjcf::PALM_BODY)?,
        object_body: id(model, MjtObjBase::mjOBJ_BODY, "body", mjcf::OBJECT_BODY)?,
        object_geom: id(model, MjtObjBase::mjOBJ_GEOM, "geom", "object_geom")?,
        object_qpos: qpos_of(free),
        object_dof: dof_of(free),
        arm_qpos,
        arm_dof,
        hand_qpos,
        hand_dof,
        geom_class,
    })
}

impl World {
    /// The control period (s): physics steps per control step times the timestep.
    pub fn control_period_secs(&self) -> f64 {
        self.spec.timestep_secs * f64::from(self.spec.substeps)
    }

    /// Builds and compiles the ten variants.
    pub fn new(spec: WorldSpec) -> Result<Self> {
        spec.validate()?;
        let xml = ObjectVariant::all()
            .into_iter()
            .map(|v| mjcf::world_xml(&spec, v))
            .collect();
        Self::from_xml(spec, xml)
    }

    /// Compiles the given MJCF texts (one per variant, in [`ObjectVariant::all`] order), e.g.
    /// those stored in a `world` artifact.
    pub fn from_xml(spec: WorldSpec, xml: Vec<String>) -> Result<Self> {
        if xml.len() != ObjectVariant::all().len() {
            return Err(SimError::Spec(format!(
                "a world has 10 object variants, not {}",
                xml.len()
            )));
        }
        let mut models = Vec::new();
        for (variant, text) in ObjectVariant::all().into_iter().zip(&xml) {
            let model = MjModel::from_xml_string(text).map_err(|e| SimError::Compile {
                variant: variant.to_string(),
                message: e.to_string(),
            })?;
            models.push(model);
        }
        let ids0 = ids(&models[0])?;
        for (variant, model) in ObjectVariant::all().into_iter().zip(&models) {
            if ids(model)? != ids0 {
                return Err(SimError::Spec(format!(
                    "the model of {variant} does not have the layout of the others"
                )));
            }
        }
        let mut world = World {
            spec,
            models,
            xml,
            ids: ids0,
            home_palm_pos: [0.0; 3],
            home_palm_normal: [0.0; 3],
        };
        let (pos, normal) = {
            let mut data = world.models[0].make_data();
            world.set_home(&mut data);
            data.forward_kinematics();
            (
                data.site_xpos()[world.ids.palm_site],
                palm_normal(&data.site_xmat()[world.ids.palm_site]),
            )
        };
        world.home_palm_pos = pos;
        world.home_palm_normal = normal;
        Ok(world)
    }

    pub fn model(&self, variant: ObjectVariant) -> &MjModel {
        &self.models[variant.index()]
    }

    pub fn xml(&self, variant: ObjectVariant) -> &str {
        &self.xml[variant.index()]
    }

    pub fn all_xml(&self) -> &[String] {
        &self.xml
    }

    /// Puts the robot in its home posture with zero velocity; the object is left where it is.
    pub fn set_home<M: ModelType>(&self, data: &mut MjData<M>) {
        let qpos = data.qpos_mut();
        for (i, &adr) in self.ids.arm_qpos.iter().enumerate() {
            qpos[adr] = self.spec.arm_home_rad[i];
        }
        for (i, &adr) in self.ids.hand_qpos.iter().enumerate() {
            qpos[adr] = self.spec.hand_home_rad[i];
        }
        data.qvel_mut().fill(0.0);
    }
}

/// The palm normal (+y of the palm site's frame) from a row-major rotation matrix.
pub fn palm_normal(xmat: &[f64; 9]) -> [f64; 3] {
    [xmat[1], xmat[4], xmat[7]]
}
