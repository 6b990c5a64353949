//! Tests. Those that render need `libOSMesa.so.8`: they fail (not skip) without it, with the
//! hint to run `scripts/setup-render`, since the test command installs it first.

use osms_core::rng;
use osms_sim::catcher::{CatcherSpec, ScriptedCatcher};
use osms_sim::control::{DrDraw, DrSpec, hold_action};
use osms_sim::{
    Action, ConditionSpec, Episode, NoHooks, ObjectVariant, Phase, Policy, PolicyView,
    RolloutRecord, RolloutSpec, TaskCondition, World, WorldSpec, conditions,
};

use crate::gif::Palette;
use crate::image::Image;
use crate::rollout::{Plan, plan};
use crate::*;

/// Fails with the setup hint when OSMesa cannot be loaded.
fn require_osmesa() {
    if let Err(e) = osmesa_available() {
        panic!("{e}");
    }
}

struct Hold(Action);
impl Policy for Hold {
    fn act(&mut self, _: &PolicyView<'_>) -> Action {
        self.0
    }
}

fn condition(world: &World, index: u64) -> TaskCondition {
    conditions::sample(
        &ConditionSpec::default(),
        world.home_palm_pos,
        &mut rng::stream(0, "test", "omega", index),
    )
    .expect("ω")
}

fn paper_spec() -> RolloutSpec {
    RolloutSpec {
        dr: DrSpec::paper(),
        ..RolloutSpec::default()
    }
}

/// Pixels of the hand's colour (rgba 0.95 0.6 0.4, shaded): clearly red over green over blue.
fn hand_pixels(image: &Image) -> usize {
    image
        .rgb
        .chunks_exact(3)
        .filter(|p| {
            let [r, g, b] = [i32::from(p[0]), i32::from(p[1]), i32::from(p[2])];
            r > g + 30 && g > b + 15
        })
        .count()
}

/// A frame of a short episode's state has the stated size, is not blank (each channel's pixel
/// variance above 100, i.e. a standard deviation above 10 of 255) and shows the hand; rendering
/// the same state again gives the same pixels.
#[test]
fn a_frame_has_its_size_is_not_blank_and_is_reproducible() {
    require_osmesa();
    let world = World::new(WorldSpec::default()).expect("world");
    let spec = paper_spec();
    let mut hold = Hold(hold_action(&world.spec.hand_home_rad));
    let mut ep = Episode::new(
        &world,
        &spec,
        condition(&world, 3),
        rng::stream(0, "test", "roll", 3),
    );
    for _ in 0..5 {
        ep.step(&mut hold, &mut NoHooks);
    }
    // The episode's own (per-episode) model, undressed.
    let data = ep.data();
    let camera = CameraSpec::catch_view(world.home_palm_pos);
    let mut renderer = Renderer::new(data.model(), 320, 240, &camera).expect("renderer");
    let image = renderer.frame(data).expect("frame");
    assert_eq!((image.width, image.height), (320, 240));
    assert_eq!(image.rgb.len(), 320 * 240 * 3);
    let var = image.channel_variance();
    assert!(var.iter().all(|v| *v > 100.0), "channel variances {var:?}");
    let hand = hand_pixels(&image);
    assert!(hand > 50, "only {hand} hand-coloured pixels");
    assert_same(&renderer.frame(data).expect("frame"), &image);

    // The dressed model of the same variant poses the same way, and a frame depends on its
    // state alone: not on the frames before it, nor on the renderer.
    let dressed =
        render_model(&world, ep.record().condition.variant, 320, 240).expect("dressed model");
    let mut renderer = Renderer::new(&dressed, 320, 240, &camera).expect("renderer");
    let a = renderer.frame(data).expect("frame");
    assert!(hand_pixels(&a) > 50);
    assert!(a.channel_variance().iter().all(|v| *v > 100.0));
    let mut other = dressed.make_data();
    world.set_home(&mut other);
    other.qpos_mut()[world.ids.arm_qpos[0]] += 0.5;
    let b = renderer.frame(&other).expect("frame");
    assert!(differing(&a, &b) > 1000, "another pose changes the picture");
    assert_same(&renderer.frame(data).expect("frame"), &a);
    let mut second = Renderer::new(&dressed, 320, 240, &camera).expect("renderer");
    assert_same(&second.frame(data).expect("frame"), &a);
}

fn differing(a: &Image, b: &Image) -> usize {
    assert_eq!((a.width, a.height), (b.width, b.height));
    a.rgb.iter().zip(&b.rgb).filter(|(x, y)| x != y).count()
}

fn assert_same(a: &Image, b: &Image) {
    let n = differing(a, b);
    assert!(n == 0, "{n} bytes of the frames differ");
}

#[test]
fn a_state_of_another_structure_is_refused() {
    require_osmesa();
    let world = World::new(WorldSpec::default()).expect("world");
    let model = world.model(ObjectVariant::all()[0]);
    let mut renderer = Renderer::new(model, 64, 48, &CameraSpec::catch_view(world.home_palm_pos))
        .expect("renderer");
    let other = mujoco_rs::prelude::MjModel::from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom size=\"0.1\"/></body></worldbody></mujoco>",
    )
    .expect("model");
    let data = other.make_data();
    assert!(matches!(renderer.frame(&data), Err(RenderError::Model(_))));
    assert!(matches!(
        Renderer::new(model, 0, 48, &CameraSpec::catch_view([0.0; 3])),
        Err(RenderError::Size { .. })
    ));
}

#[test]
fn the_missing_library_error_names_the_package_and_the_setup_script() {
    let e = RenderError::NoOsMesa {
        detail: "libOSMesa.so.8: cannot open shared object file".into(),
    };
    let msg = e.to_string();
    assert!(msg.contains("libosmesa6"), "{msg}");
    assert!(msg.contains("scripts/setup-render"), "{msg}");
}

#[test]
fn every_dressed_variant_keeps_the_world_structure() {
    let world = World::new(WorldSpec::default()).expect("world");
    for v in ObjectVariant::all() {
        let m = render_model(&world, v, 200, 100).unwrap_or_else(|e| panic!("{v}: {e}"));
        assert_eq!(m.vis().global.offwidth, 200);
        assert_eq!(m.vis().global.offheight, 100);
        assert_eq!(m.ffi().nq, world.model(v).ffi().nq);
    }
}

fn synthetic_record(world: &World, steps: usize, contact: Option<usize>) -> RolloutRecord {
    let mut r = RolloutRecord::empty(condition(world, 1), DrDraw::none());
    r.steps = steps;
    for k in 0..steps {
        // The object closes in at 0.1 m per step and stops at the palm.
        let d = (2.0 - 0.1 * k as f32).max(0.0);
        r.object_pos.extend([d, 0.0, 0.0]);
        r.palm_pos.extend([0.0, 0.0, 0.0]);
        let phase = match contact {
            Some(c) if k == c => Phase::Contact,
            Some(c) if k > c => Phase::FollowThrough,
            _ => Phase::Approach,
        };
        r.phase.push(phase as u8);
    }
    r
}

#[test]
fn the_key_frames_follow_the_contact() {
    let world = World::new(WorldSpec::default()).expect("world");
    let opts = RenderOptions::default();
    let r = synthetic_record(&world, 40, Some(18));
    let Plan { keys, ghosts } = plan(&r, &opts);
    assert_eq!(
        keys,
        [
            // d(k) = 2 - 0.1 k ≥ 0.45 up to k = 15.
            (KeyKind::Approach, 15),
            (KeyKind::BeforeContact, 18),
            (KeyKind::Contact, 19),
            (KeyKind::FollowThrough, 24),
            (KeyKind::Hold, 39),
        ]
    );
    assert_eq!(ghosts, [15, 16, 17, 19, 24]);

    // Contact in the last step: the last two steps.
    let r = synthetic_record(&world, 10, Some(9));
    let keys: Vec<KeyKind> = plan(&r, &opts).keys.iter().map(|k| k.0).collect();
    assert_eq!(
        keys,
        [KeyKind::Approach, KeyKind::BeforeContact, KeyKind::Contact]
    );

    // No contact: the closest approach (the object stops at the palm at step 20).
    let r = synthetic_record(&world, 30, None);
    assert_eq!(
        plan(&r, &opts).keys,
        [
            (KeyKind::Approach, 15),
            (KeyKind::ClosestApproach, 20),
            (KeyKind::Hold, 29),
        ]
    );
    assert!(
        plan(&synthetic_record(&world, 0, None), &opts)
            .keys
            .is_empty()
    );
}

#[test]
fn the_gif_palette_is_exact_for_few_colours_and_deterministic() {
    let colors = [[10, 20, 30], [200, 100, 50], [255, 255, 255], [0, 128, 255]];
    let mut image = Image::filled(8, 4, [0, 0, 0]);
    for (i, px) in image.rgb.chunks_exact_mut(3).enumerate() {
        px.copy_from_slice(&colors[i % colors.len()]);
    }
    let p = Palette::median_cut([&image], 256);
    assert_eq!(p.colors.len(), 4);
    let back: Vec<u8> = p
        .indices(&image)
        .iter()
        .flat_map(|&i| p.colors[usize::from(i)])
        .collect();
    assert_eq!(back, image.rgb);

    let gradient = Image {
        width: 64,
        height: 64,
        rgb: (0..64 * 64)
            .flat_map(|i| [(i % 256) as u8, (i / 16) as u8, ((i * 7) % 256) as u8])
            .collect(),
    };
    let a = crate::gif::encode(&[(gradient.clone(), 4), (image.downscale(1), 4)]);
    assert!(a.is_err(), "frames of different sizes are refused");
    let a = crate::gif::encode(&[(gradient.clone(), 4), (gradient.clone(), 8)]).expect("gif");
    let b = crate::gif::encode(&[(gradient.clone(), 4), (gradient, 8)]).expect("gif");
    assert_eq!(a, b);
}

/// Decodes a GIF: (width, height, frame count).
fn decode_gif(bytes: &[u8]) -> (u16, u16, usize) {
    let mut decoder = ::gif::DecodeOptions::new()
        .read_info(bytes)
        .expect("GIF header");
    let (w, h) = (decoder.width(), decoder.height());
    let mut n = 0;
    while let Some(frame) = decoder.read_next_frame().expect("GIF frame") {
        assert_eq!((frame.width, frame.height), (w, h));
        n += 1;
    }
    (w, h, n)
}

#[test]
fn a_rendered_catch_writes_files_that_decode() {
    require_osmesa();
    let world = World::new(WorldSpec::default()).expect("world");
    let spec = paper_spec();
    let mut catcher = ScriptedCatcher::new(CatcherSpec::default(), spec.control.clone());
    let record = Episode::new(
        &world,
        &spec,
        condition(&world, 3),
        rng::stream(0, "test", "roll", 3),
    )
    .run(&mut catcher, &mut NoHooks);
    assert!(
        record.phase.contains(&(Phase::Contact as u8)),
        "the scripted catch makes contact"
    );
    let opts = RenderOptions {
        width: 320,
        height: 240,
        gif_every: 4,
        label_px: 14,
        ..RenderOptions::default()
    };
    let rendered = render_rollout(&world, &spec, &record, &opts).expect("render");
    assert!(rendered.replay.bit_exact);
    let kinds: Vec<KeyKind> = rendered.key_frames.iter().map(|f| f.kind).collect();
    assert_eq!(
        kinds,
        [
            KeyKind::Approach,
            KeyKind::BeforeContact,
            KeyKind::Contact,
            KeyKind::FollowThrough,
            KeyKind::Hold
        ]
    );
    for f in &rendered.key_frames {
        assert_eq!((f.image.width, f.image.height), (320, 240));
        assert!(f.image.channel_variance().iter().all(|v| *v > 100.0));
    }
    // The object is in view in flight: the approach frame has object-blue pixels (rgba
    // 0.2 0.5 0.9, shaded).
    let blue = |im: &Image| {
        im.rgb
            .chunks_exact(3)
            .filter(|p| {
                i32::from(p[2]) > i32::from(p[1]) + 40 && i32::from(p[1]) > i32::from(p[0]) + 20
            })
            .count()
    };
    assert!(blue(&rendered.key_frames[0].image) > 20);

    let dir = tempfile::tempdir().expect("tempdir");
    let files = rendered.write(dir.path(), "catch").expect("write");
    let n = rendered.key_frames.len() as u32;
    let strip = std::fs::read(&files.strip).expect("strip");
    let info = png::Decoder::new(strip.as_slice())
        .read_info()
        .expect("strip PNG");
    let band = 14 * 3 / 2 + 4;
    assert_eq!(
        (info.info().width, info.info().height),
        (n * 320 + (n - 1) * 6, 240 + band)
    );
    let poses = std::fs::read(&files.composite).expect("composite");
    let info = png::Decoder::new(poses.as_slice())
        .read_info()
        .expect("composite PNG");
    assert_eq!((info.info().width, info.info().height), (320, 240));
    let gif = std::fs::read(&files.gif).expect("gif");
    let expected_frames =
        record.steps.div_ceil(4) + usize::from(!(record.steps - 1).is_multiple_of(4));
    assert_eq!(decode_gif(&gif), (160, 120, expected_frames));
    assert_eq!(rendered.gif_frames, expected_frames);
}
