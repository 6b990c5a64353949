//! Headless offscreen rendering of rollouts with MuJoCo's own renderer through Mesa's OSMesa (no
//! GPU, no display): key-frame strips, animated GIFs and faded-pose figures.
//!
//! `libOSMesa.so.8` (Debian package `libosmesa6`, installed by `scripts/setup-render`) is loaded
//! at run time; nothing links against it, so the workspace builds without it and only
//! rendering fails, with [`RenderError::NoOsMesa`].
//!
//! * [`Renderer`] draws the kinematic state of an `MjData` from a fixed free camera into an
//!   RGB [`Image`].
//! * [`render_rollout`] replays a record once and renders its key frames (approach, before
//!   contact, contact, follow-through, hold) into a labelled strip, a faded-poses composite in
//!   the manner of a paper figure, and an animated GIF.
//!
//! Everything is deterministic on one machine: llvmpipe renders the same inputs to the same
//! pixels, the GIF palette is a median cut with fixed tie-breaks, and PNG/GIF encoding is
//! deterministic. Pixels are not promised identical across machines or Mesa versions.
//!
//! A GL context belongs to the thread that created it: [`Renderer`] is `!Send` and `!Sync`.

mod gif;
mod gl;
mod image;
mod rollout;
#[cfg(test)]
mod tests;

use mujoco_rs::prelude::*;
use mujoco_rs::wrappers::mj_model::traits::ModelType;
use osms_sim::{ObjectVariant, World};

pub use crate::gl::{OSMESA_LIB, osmesa_available};
pub use crate::image::Image;
pub use crate::rollout::{
    KeyFrame, KeyKind, RenderOptions, Rendered, RenderedFiles, render_rollout,
};

/// Largest frame side osms renders (far below llvmpipe's limit; a guard against typos).
pub const MAX_SIDE: u32 = 8192;

#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "cannot load {OSMESA_LIB} (Mesa's off-screen OpenGL, Debian package libosmesa6): {detail}; run scripts/setup-render to install it"
    )]
    NoOsMesa { detail: String },
    #[error("cannot render {width}x{height} frames (each side must be 1..={MAX_SIDE})")]
    Size { width: u32, height: u32 },
    #[error("OpenGL: {0}")]
    Gl(String),
    #[error("render model: {0}")]
    Model(String),
    #[error("replay: {0}")]
    Replay(#[from] osms_sim::replay::ReplayError),
    #[error("GIF encoding: {0}")]
    Gif(String),
}

pub type Result<T, E = RenderError> = std::result::Result<T, E>;

/// A free camera: it looks at `lookat` from `distance` metres, turned `azimuth_deg` about the
/// world z axis (0: looking along +x, 90: along +y) and `elevation_deg` above the horizon
/// (negative: looking down), with the model's vertical field of view (45° by default).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraSpec {
    pub lookat: [f64; 3],
    pub distance: f64,
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
}

impl CameraSpec {
    /// The default view of a catch: from the side, a little in front of the arm and above the
    /// palm, so the arm, the hand at its home position `palm` and the object's incoming flight
    /// (from +x) are all in the frame.
    pub fn catch_view(palm: [f64; 3]) -> Self {
        CameraSpec {
            lookat: [palm[0] + 0.28, palm[1], palm[2] - 0.17],
            distance: 1.6,
            azimuth_deg: 110.0,
            elevation_deg: -12.0,
        }
    }

    fn apply(&self, camera: &mut MjvCamera) {
        camera.free();
        camera.lookat = self.lookat;
        camera.distance = self.distance;
        camera.azimuth = self.azimuth_deg;
        camera.elevation = self.elevation_deg;
    }
}

/// The model a rollout of `variant` is rendered with: the world's MJCF for the variant with a
/// figure's visual dressing added: a gradient sky, a checkered floor, softer lighting and the
/// offscreen buffer of `width` × `height`. Bodies, joints and geoms are the world's own, in the
/// same order, so the simulator's `qpos` applies as it is; the dressing lives only here and does
/// not touch the stored MJCF or any artifact.
pub fn render_model(
    world: &World,
    variant: ObjectVariant,
    width: u32,
    height: u32,
) -> Result<MjModel, RenderError> {
    let xml = dress(world.xml(variant), width, height);
    let model = MjModel::from_xml_string(&xml).map_err(|e| RenderError::Model(e.to_string()))?;
    let base = world.model(variant);
    let (a, b) = (model.ffi(), base.ffi());
    if (a.nq, a.nbody, a.ngeom, a.nmocap) != (b.nq, b.nbody, b.ngeom, b.nmocap) {
        return Err(RenderError::Model(format!(
            "the dressed model of {variant} does not have the world's structure"
        )));
    }
    Ok(model)
}

/// Adds the visual dressing to an MJCF text (see [`render_model`]).
fn dress(xml: &str, width: u32, height: u32) -> String {
    let visual = format!(
        r#"<visual>
  <global offwidth="{width}" offheight="{height}"/>
  <quality shadowsize="2048" offsamples="4"/>
  <headlight ambient="0.3 0.3 0.3" diffuse="0.35 0.35 0.35" specular="0.05 0.05 0.05"/>
  <map haze="0.25"/>
  <rgba haze="0.9 0.93 0.97 1"/>
</visual>
<asset>
  <texture name="osms_render_sky" type="skybox" builtin="gradient" rgb1="0.97 0.98 1" rgb2="0.78 0.84 0.92" width="256" height="1536"/>
  <texture name="osms_render_grid" type="2d" builtin="checker" rgb1="0.68 0.69 0.71" rgb2="0.62 0.63 0.65" width="512" height="512" mark="edge" markrgb="0.58 0.59 0.61"/>
  <material name="osms_render_floor" texture="osms_render_grid" texrepeat="2 2" texuniform="true" specular="0.1" shininess="0.1"/>
</asset>
"#
    );
    let mut out = String::with_capacity(xml.len() + visual.len());
    let mut inserted = false;
    for line in xml.lines() {
        if line.contains("name=\"ground\"") {
            out.push_str(
                &line
                    .replace("rgba=\"0.8 0.8 0.8 1\"", "")
                    .replace("size=\"5 5 0.1\"", "size=\"0 0 1\"")
                    .replace(
                        "name=\"ground\"",
                        "name=\"ground\" material=\"osms_render_floor\"",
                    ),
            );
        } else {
            out.push_str(line);
        }
        out.push('\n');
        if !inserted && line.trim_start().starts_with("<mujoco") {
            out.push_str(&visual);
            inserted = true;
        }
    }
    out
}

/// An offscreen renderer: an OSMesa context with MuJoCo's rendering context, a scene, a free
/// camera and its own `MjData`, into which [`Renderer::frame`] copies the state to draw.
///
/// Bound to the thread that created it (`!Send`, `!Sync`): OpenGL contexts are per thread.
pub struct Renderer {
    // Dropped first: frees MuJoCo's GL resources with its context current, then the context.
    gl: gl::GlContext,
    data: MjData<Box<MjModel>>,
    scene: MjvScene,
    camera: MjvCamera,
    option: MjvOption,
    perturb: MjvPerturb,
    width: u32,
    height: u32,
    rgb: Vec<u8>,
    depth: Vec<f32>,
}

impl Renderer {
    /// A renderer of `width` × `height` frames of `model` (or any model of its structure) seen
    /// from `camera`. The model is cloned; its offscreen buffer is set to the frame size.
    pub fn new(
        model: &MjModel,
        width: u32,
        height: u32,
        camera: &CameraSpec,
    ) -> Result<Self, RenderError> {
        osmesa_available()?;
        if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
            return Err(RenderError::Size { width, height });
        }
        let mut model = model.clone();
        {
            let global = &mut model.vis_mut().global;
            global.offwidth = width as i32;
            global.offheight = height as i32;
        }
        let data = MjData::new(Box::new(model));
        let gl = gl::GlContext::new(data.model(), width, height)?;
        let scene = MjvScene::new(data.model(), 2000);
        let mut cam = MjvCamera::new_free(data.model());
        camera.apply(&mut cam);
        let n = width as usize * height as usize;
        let mut renderer = Renderer {
            gl,
            data,
            scene,
            camera: cam,
            option: MjvOption::default(),
            perturb: MjvPerturb::default(),
            width,
            height,
            rgb: vec![0; n * 3],
            depth: vec![0.0; n],
        };
        // With textures (the dressed model), llvmpipe's first frame in a new context differs
        // from later frames of the same state by one level in a few hundred pixels; a discarded
        // first frame makes every frame a function of its state alone.
        renderer.draw()?;
        Ok(renderer)
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// The renderer's copy of the model.
    pub fn model(&self) -> &MjModel {
        self.data.model()
    }

    pub fn set_camera(&mut self, camera: &CameraSpec) {
        camera.apply(&mut self.camera);
    }

    /// Draws the kinematic state (`qpos`, mocap poses) of `data`, whose model must have this
    /// renderer's structure (the same model, a per-episode copy with edited masses, or the
    /// dressed [`render_model`]).
    pub fn frame<M: ModelType>(&mut self, data: &MjData<M>) -> Result<Image, RenderError> {
        self.frame_with_depth(data).map(|(image, _)| image)
    }

    /// [`Renderer::frame`] with the depth buffer (MuJoCo's mapping into [0, 1], nearer is
    /// smaller), rows top to bottom like the image.
    pub fn frame_with_depth<M: ModelType>(
        &mut self,
        data: &MjData<M>,
    ) -> Result<(Image, Vec<f32>), RenderError> {
        let (nq, nmocap) = (self.data.qpos().len(), self.data.mocap_pos().len());
        if data.qpos().len() != nq || data.mocap_pos().len() != nmocap {
            return Err(RenderError::Model(format!(
                "the state has {} qpos and {} mocap bodies; the render model {nq} and {nmocap}",
                data.qpos().len(),
                data.mocap_pos().len()
            )));
        }
        self.data.qpos_mut().copy_from_slice(data.qpos());
        self.data.mocap_pos_mut().copy_from_slice(data.mocap_pos());
        self.data
            .mocap_quat_mut()
            .copy_from_slice(data.mocap_quat());
        self.draw()?;
        // OpenGL's rows run bottom to top.
        let (w, h) = (self.width as usize, self.height as usize);
        let mut rgb = Vec::with_capacity(w * h * 3);
        let mut depth = Vec::with_capacity(w * h);
        for row in (0..h).rev() {
            rgb.extend_from_slice(&self.rgb[row * w * 3..(row + 1) * w * 3]);
            depth.extend_from_slice(&self.depth[row * w..(row + 1) * w]);
        }
        Ok((
            Image {
                width: self.width,
                height: self.height,
                rgb,
            },
            depth,
        ))
    }

    /// Renders the state in `self.data` into `self.rgb` and `self.depth` (bottom row first).
    fn draw(&mut self) -> Result<(), RenderError> {
        self.data.forward_kinematics();
        self.scene.update(
            &mut self.data,
            &self.option,
            &self.perturb,
            &mut self.camera,
        );
        let rect = MjrRectangle::new(0, 0, self.width as i32, self.height as i32);
        let mjr = self.gl.current();
        mjr.offscreen();
        self.scene.render(&rect, mjr);
        mjr.read_pixels(Some(&mut self.rgb), Some(&mut self.depth), &rect)
            .map_err(|e| RenderError::Gl(e.to_string()))
    }
}
