//! Rendering a recorded rollout: one open-loop replay, the key frames, a labelled strip, a
//! faded-poses composite and an animated GIF.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use osms_sim::replay::{ReplayReport, replay};
use osms_sim::{Phase, RolloutRecord, RolloutSpec, World};

use crate::image::{Image, strip};
use crate::{CameraSpec, RenderError, Renderer, render_model};

/// What to render. Every default lives here.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOptions {
    /// Size of the key frames, the strip's tiles and the composite (pixels).
    pub width: u32,
    pub height: u32,
    /// The camera; `None`: [`CameraSpec::catch_view`] at the world's home palm position.
    pub camera: Option<CameraSpec>,
    /// The approach key frame is the last step before the contact at which the object was
    /// still this far from the palm centre (m), so it shows the object in flight near the hand.
    pub approach_distance_m: f32,
    /// Control steps from the contact to the follow-through key frame.
    pub follow_through_steps: usize,
    /// Earlier poses faded into the composite: this many evenly spaced steps from the approach
    /// to the contact, then the follow-through.
    pub ghost_poses: usize,
    /// Every n-th control step becomes a GIF frame (the last step always does).
    pub gif_every: usize,
    /// The GIF's frames are the rendered frames shrunk by this integer factor (box filter,
    /// which also smooths edges).
    pub gif_downscale: u32,
    /// The GIF plays this many times slower than real time.
    pub gif_slowdown: f64,
    /// Text height of the labels (pixels at the key-frame size); 0: no labels.
    pub label_px: u32,
    /// Opacity of the earlier poses in the composite: the oldest gets half of it, the newest
    /// all of it.
    pub ghost_alpha: f32,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            width: 640,
            height: 480,
            camera: None,
            approach_distance_m: 0.45,
            follow_through_steps: 5,
            ghost_poses: 4,
            gif_every: 1,
            gif_downscale: 2,
            gif_slowdown: 2.0,
            label_px: 22,
            ghost_alpha: 0.55,
        }
    }
}

/// Which moment of the catch a key frame shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum KeyKind {
    /// The object in flight toward the hand (see [`RenderOptions::approach_distance_m`]).
    Approach,
    /// The start of the contact step: the last state without contact.
    BeforeContact,
    /// The end of the contact step (the start of the next): the first state with contact.
    Contact,
    /// A few control steps after the contact.
    FollowThrough,
    /// Without contact: the step at which the object came closest to the palm centre.
    ClosestApproach,
    /// The start of the last control step.
    Hold,
}

impl KeyKind {
    pub fn label(self) -> &'static str {
        match self {
            KeyKind::Approach => "approach",
            KeyKind::BeforeContact => "before contact",
            KeyKind::Contact => "contact",
            KeyKind::FollowThrough => "follow-through",
            KeyKind::ClosestApproach => "closest approach",
            KeyKind::Hold => "hold",
        }
    }
}

/// A rendered key frame: the simulator at the start of control step `step`.
#[derive(Debug, Clone)]
pub struct KeyFrame {
    pub kind: KeyKind,
    pub step: usize,
    /// Simulated time at that state (s).
    pub time_secs: f64,
    pub image: Image,
}

/// What [`render_rollout`] made.
#[derive(Debug, Clone)]
pub struct Rendered {
    /// In time order.
    pub key_frames: Vec<KeyFrame>,
    /// The key frames side by side, each under its label.
    pub strip: Image,
    /// The earlier key-frame poses faded over the last one (depth-tested, so a ghost shows only
    /// where it was in front of the final scene).
    pub composite: Image,
    /// The animated GIF's bytes.
    pub gif: Vec<u8>,
    pub gif_frames: usize,
    /// How the replay compared with the record (a record that does not replay bit for bit
    /// still renders, as the replay ran).
    pub replay: ReplayReport,
}

/// Where [`Rendered::write`] put the files.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RenderedFiles {
    pub strip: PathBuf,
    pub composite: PathBuf,
    pub gif: PathBuf,
}

impl Rendered {
    /// Writes `<stem>-strip.png`, `<stem>-poses.png` and `<stem>.gif` into `dir` (created if
    /// missing).
    pub fn write(&self, dir: &Path, stem: &str) -> std::io::Result<RenderedFiles> {
        std::fs::create_dir_all(dir)?;
        let files = RenderedFiles {
            strip: dir.join(format!("{stem}-strip.png")),
            composite: dir.join(format!("{stem}-poses.png")),
            gif: dir.join(format!("{stem}.gif")),
        };
        std::fs::write(&files.strip, self.strip.to_png())?;
        std::fs::write(&files.composite, self.composite.to_png())?;
        std::fs::write(&files.gif, &self.gif)?;
        Ok(files)
    }
}

/// Which steps to render: the key frames and, for the composite, the faded poses (the last key
/// frame is the composite's base).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Plan {
    /// In time order, without repeats.
    pub keys: Vec<(KeyKind, usize)>,
    /// In time order, without repeats, all before the last key frame.
    pub ghosts: Vec<usize>,
}

pub(crate) fn plan(record: &RolloutRecord, opts: &RenderOptions) -> Plan {
    let n = record.steps;
    if n == 0 {
        return Plan {
            keys: Vec::new(),
            ghosts: Vec::new(),
        };
    }
    let last = n - 1;
    let has_positions = record.object_pos.len() >= 3 * n && record.palm_pos.len() >= 3 * n;
    let dist = |k: usize| -> f32 {
        if !has_positions {
            return f32::INFINITY;
        }
        (0..3)
            .map(|c| (record.object_pos[3 * k + c] - record.palm_pos[3 * k + c]).powi(2))
            .sum::<f32>()
            .sqrt()
    };
    // The last step before `end` at which the object was still `approach_distance_m` away.
    let approach = |end: usize| {
        (0..end)
            .rev()
            .find(|&k| dist(k) >= opts.approach_distance_m)
            .unwrap_or(0)
    };
    let contact = record.phase.iter().position(|&p| p == Phase::Contact as u8);
    let (mut keys, flight_end, after) = match contact {
        Some(c) => {
            // The contact is made during step c: the state at its end is the start of c + 1.
            let (before, touch) = if c < last {
                (c, c + 1)
            } else {
                (c.saturating_sub(1), c)
            };
            let follow = (touch + opts.follow_through_steps).min(last);
            let keys = vec![
                (KeyKind::Approach, approach(before)),
                (KeyKind::BeforeContact, before),
                (KeyKind::Contact, touch),
                (KeyKind::FollowThrough, follow),
                (KeyKind::Hold, last),
            ];
            (keys, touch, Some(follow))
        }
        None => {
            let closest = if has_positions {
                (0..n)
                    .min_by(|&a, &b| dist(a).total_cmp(&dist(b)))
                    .unwrap_or(0)
            } else {
                last
            };
            let keys = vec![
                (KeyKind::Approach, approach(closest)),
                (KeyKind::ClosestApproach, closest),
                (KeyKind::Hold, last),
            ];
            (keys, closest, None)
        }
    };
    // Short episodes can map two moments to one step: keep the first.
    let mut seen = Vec::new();
    keys.retain(|&(_, k)| {
        let new = !seen.contains(&k);
        seen.push(k);
        new
    });
    let start = keys.first().map_or(0, |&(_, k)| k);
    let m = opts.ghost_poses;
    let mut ghosts: Vec<usize> = (0..m)
        .map(|i| {
            if m == 1 {
                flight_end
            } else {
                start + (flight_end - start) * i / (m - 1)
            }
        })
        .chain(after)
        .filter(|&k| k < last)
        .collect();
    ghosts.dedup();
    Plan { keys, ghosts }
}

struct Shot {
    time_secs: f64,
    image: Image,
    depth: Vec<f32>,
}

/// Replays `record` (made under `spec` in `world`) once and renders it: key frames, strip,
/// faded-poses composite and GIF. The scene is the dressed [`render_model`] of the record's
/// object variant, posed with the replay's `qpos` at the start of each control step.
pub fn render_rollout(
    world: &World,
    spec: &RolloutSpec,
    record: &RolloutRecord,
    opts: &RenderOptions,
) -> Result<Rendered, RenderError> {
    let model = render_model(world, record.condition.variant, opts.width, opts.height)?;
    let camera = opts
        .camera
        .unwrap_or_else(|| CameraSpec::catch_view(world.home_palm_pos));
    let mut renderer = Renderer::new(&model, opts.width, opts.height, &camera)?;
    let Plan { keys, ghosts } = plan(record, opts);
    let last = record.steps.saturating_sub(1);
    let every = opts.gif_every.max(1);
    let downscale = opts.gif_downscale.max(1);

    let mut shots: BTreeMap<usize, Shot> = BTreeMap::new();
    let mut animation: Vec<(usize, f64, Image)> = Vec::new();
    let mut failed = None;
    let (_, report) = replay(world, spec, record, &mut |k, data| {
        if failed.is_some() {
            return;
        }
        let key = keys.iter().any(|&(_, s)| s == k) || ghosts.contains(&k);
        let animated = k.is_multiple_of(every) || k == last;
        if !key && !animated {
            return;
        }
        match renderer.frame_with_depth(data) {
            Ok((image, depth)) => {
                if animated {
                    animation.push((k, data.time(), image.downscale(downscale)));
                }
                if key {
                    let time_secs = data.time();
                    shots.insert(
                        k,
                        Shot {
                            time_secs,
                            image,
                            depth,
                        },
                    );
                }
            }
            Err(e) => failed = Some(e),
        }
    })?;
    if let Some(e) = failed {
        return Err(e);
    }
    drop(renderer);

    // A replay that ended early has no state for later steps.
    let composite = match keys.last().and_then(|(_, k)| shots.get(k)) {
        Some(base) => {
            let layers: Vec<&Shot> = ghosts.iter().filter_map(|k| shots.get(k)).collect();
            composite(base, &layers, opts.ghost_alpha)
        }
        None => Image::filled(opts.width, opts.height, [255, 255, 255]),
    };
    let key_frames: Vec<KeyFrame> = keys
        .iter()
        .filter_map(|&(kind, step)| {
            shots.get(&step).map(|shot| KeyFrame {
                kind,
                step,
                time_secs: shot.time_secs,
                image: shot.image.clone(),
            })
        })
        .collect();

    let labels: Vec<String> = key_frames
        .iter()
        .map(|f| format!("{}  t = {:.2} s", f.kind.label(), f.time_secs))
        .collect();
    let tiles: Vec<(&Image, String)> = key_frames
        .iter()
        .zip(labels)
        .map(|(f, l)| (&f.image, l))
        .collect();
    let strip = strip(&tiles, 6, opts.label_px, [255, 255, 255]);

    let period = world.spec.timestep_secs * f64::from(world.spec.substeps);
    let delay = (period * every as f64 * 100.0 * opts.gif_slowdown)
        .round()
        .clamp(2.0, 1000.0) as u16;
    let label_px = opts.label_px as f32 / downscale as f32;
    let frames: Vec<(Image, u16)> = animation
        .into_iter()
        .map(|(k, t, mut image)| {
            if label_px >= 6.0 {
                let phase = record
                    .phase
                    .get(k)
                    .and_then(|&p| Phase::ALL.get(usize::from(p)))
                    .map_or("", |p| p.name());
                let text = format!("t = {t:.2} s  {phase}");
                image.draw_text(
                    &text,
                    label_px * 0.5,
                    label_px * 0.3,
                    label_px,
                    [20, 20, 20],
                );
            }
            let d = if k == last { 150 } else { delay };
            (image, d)
        })
        .collect();
    let gif = crate::gif::encode(&frames)?;
    Ok(Rendered {
        key_frames,
        strip,
        composite,
        gif,
        gif_frames: frames.len(),
        replay: report,
    })
}

/// `base` with the `ghosts` (earlier states, oldest first) faded in where they were nearer the
/// camera than the base scene, so the static background and the final pose stay as they are.
/// Opacity rises with time, from half of `alpha` to `alpha`.
fn composite(base: &Shot, ghosts: &[&Shot], alpha: f32) -> Image {
    let mut out = base.image.clone();
    let n = ghosts.len();
    for (i, g) in ghosts.iter().enumerate() {
        let a = if n > 1 {
            alpha * (0.5 + 0.5 * i as f32 / (n - 1) as f32)
        } else {
            alpha
        };
        for (p, (&d, &b)) in g.depth.iter().zip(&base.depth).enumerate() {
            if d + 1e-6 < b {
                for c in 0..3 {
                    let j = 3 * p + c;
                    let v = f32::from(out.rgb[j]) * (1.0 - a) + f32::from(g.image.rgb[j]) * a;
                    out.rgb[j] = v.round() as u8;
                }
            }
        }
    }
    out
}
