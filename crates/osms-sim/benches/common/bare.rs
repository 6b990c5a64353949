//! The bare side of the rollout benches: a `mj_step` replay of the very controls a rollout
//! applied, from the same state, timed beside the rollout in the same run. osms-sim's rollout
//! bench (the scripted catcher) and osms-policy's (the teacher and validation's branches)
//! include this one file (`#[path]`), so both measure against the same baseline without a
//! bench-to-bench dependency.

use std::time::{Duration, Instant};

use mujoco_rs::mujoco_c::{mjtStage, mjtState};
use mujoco_rs::prelude::*;
use osms_core::rng;
use osms_sim::conditions::sample;
use osms_sim::metrics::scan;
use osms_sim::policy::Hooks;
use osms_sim::{Action, ConditionSpec, GeomClass, TaskCondition, World};

pub const STATE: u32 = mjtState::mjSTATE_INTEGRATION as u32;

/// Records the controls of every physics step and where each control step starts.
#[derive(Default, Clone)]
pub struct Controls {
    pub ctrl: Vec<Vec<f64>>,
    pub control_starts: Vec<usize>,
}

impl Hooks for Controls {
    fn override_arm(&mut self, _step: usize, _action: &mut Action) {
        self.control_starts.push(self.ctrl.len());
    }
    fn after_physics_step(&mut self, data: &MjData<Box<MjModel>>) {
        self.ctrl.push(data.ctrl().to_vec());
    }
}

/// What the bare side replays for one condition: from `start` (a model and integration state),
/// each branch's controls.
pub struct Bare {
    pub model: MjModel,
    pub start: Box<[f64]>,
    pub branches: Vec<Controls>,
}

impl Bare {
    pub fn physics_steps(&self) -> usize {
        self.branches.iter().map(|b| b.ctrl.len()).sum()
    }
}

/// One bare replay: a fresh `MjData` for a whole rollout (as osms makes one), an `mj_setState`
/// onto a live one for branches (as osms restores one). With `classes`, it also pays for what
/// the teacher's observation must cost on top of the physics: at every control step that
/// starts with an admissible hand–object contact, the constraint solve of the observed contact
/// force under the held controls (`Episode::observe`).
pub fn replay(
    bare: &Bare,
    data: &mut MjData<Box<MjModel>>,
    fresh: bool,
    classes: Option<&[GeomClass]>,
) {
    if fresh {
        *data = MjData::new(Box::new(bare.model.clone()));
    }
    for branch in &bare.branches {
        data.set_state(&bare.start, STATE).expect("state");
        let mut starts = branch.control_starts.iter().peekable();
        for (j, ctrl) in branch.ctrl.iter().enumerate() {
            let observe = classes.filter(|_| starts.next_if_eq(&&j).is_some());
            if let Some(classes) = observe {
                data.step1();
                if scan(data, classes, false).admissible_contacts > 0 {
                    data.forward_skip(mjtStage::mjSTAGE_VEL, false);
                }
                data.ctrl_mut().copy_from_slice(ctrl);
                data.step2();
            } else {
                data.ctrl_mut().copy_from_slice(ctrl);
                data.step();
            }
        }
        std::hint::black_box(data.qpos()[0]);
    }
}

pub fn setting(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The bench's conditions: condition `i` from stream ("bench", "omega", i).
pub fn conditions(world: &World, n: usize) -> Vec<TaskCondition> {
    (0..n as u64)
        .map(|i| {
            sample(
                &ConditionSpec::default(),
                world.home_palm_pos,
                &mut rng::stream(0, "bench", "omega", i),
            )
            .expect("ω")
        })
        .collect()
}

/// Rollout `i`'s domain randomisation stream.
pub fn dr(i: usize) -> rng::StreamRng {
    rng::stream(0, "bench", "rollout", i as u64)
}

pub fn time(f: impl FnOnce()) -> Duration {
    let t = Instant::now();
    f();
    t.elapsed()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Every rollout `i < n` is timed on each of `sides` sides back to back, in rotating order,
/// `rounds` times; a rollout's time on a side is its fastest round (interruptions only ever
/// add time). `side(i, s)` runs side `s` of rollout `i` and returns its time, or `None` when
/// the pattern has no such side. Returns, per run, the summed seconds of each side.
pub fn measure(
    n: usize,
    sides: usize,
    rounds: usize,
    runs: usize,
    mut side: impl FnMut(usize, usize) -> Option<Duration>,
) -> Vec<Vec<f64>> {
    (0..runs)
        .map(|_| {
            let mut best = vec![vec![Duration::MAX; sides]; n];
            for round in 0..rounds {
                for (i, best) in best.iter_mut().enumerate() {
                    for k in 0..sides {
                        let s = (k + round + i) % sides;
                        if let Some(t) = side(i, s) {
                            best[s] = best[s].min(t);
                        }
                    }
                }
            }
            (0..sides)
                .map(|s| {
                    best.iter()
                        .map(|b| b[s])
                        .filter(|t| *t != Duration::MAX)
                        .sum::<Duration>()
                        .as_secs_f64()
                })
                .collect()
        })
        .collect()
}

/// Prints one pattern's line: per-physics-step times and the ratio bare / osms (side 1 over
/// side 0) as min / median / max over runs, and, when side 2 ran (bare plus the observed
/// contact-force solves), the median ratio against it.
pub fn report(name: &str, physics_steps: usize, runs: &[Vec<f64>]) {
    let ratio = |s: usize| runs.iter().map(|r| r[s] / r[0]).collect::<Vec<_>>();
    let spread = |v: Vec<f64>| {
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (lo, median(v), hi)
    };
    let (lo, mid, hi) = spread(ratio(1));
    let us = |s: usize| median(runs.iter().map(|r| r[s]).collect()) * 1e6 / physics_steps as f64;
    println!(
        "  {:<9} {:>6} physics steps  osms {:6.2} us/step  bare {:6.2} us/step  ratio min {:.3}  median {:.3}  max {:.3}  (target >= 0.95)",
        name,
        physics_steps,
        us(0),
        us(1),
        lo,
        mid,
        hi
    );
    if runs.iter().all(|r| r.len() > 2 && r[2] > 0.0) {
        println!(
            "  {:<9} against bare + the observed contact-force solves: median {:.3} (the rest is osms's own work)",
            "",
            median(ratio(2))
        );
    }
}
