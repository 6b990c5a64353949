//! The rollout loop against MuJoCo alone: for three patterns, the time of osms's rollout against
//! a bare `mj_step` replay of the very same per-physics-step controls from the same initial
//! state, measured in the same run. The ratio (bare / osms) is the share of a rollout's time that
//! is MuJoCo's; 1.0 means osms adds nothing.
//!
//! - **scripted**: the scripted catcher through `Episode::run` (setup, observations, the
//!   catcher's interception and IK, servo targets, DR, per-physics-step evaluation, the record).
//!   The bare side makes its `MjData` from the rollout's model and sets its initial state.
//! - **teacher**: the PPO teacher's episode (`CatchEpisode`: the prior, the actor network of the
//!   default profile's size, the follow-through channel's Jacobian solve, the reward).
//! - **branch**: validation's pattern: the teacher runs to a window start shortly before its
//!   event step, is snapshotted, and every branch restores the snapshot, perturbs the arm over
//!   the window and runs to the end. The bare side restores MuJoCo's state (`mj_setState`) and
//!   replays each branch. The prefix is untimed on both sides.
//!
//! The teacher's observation includes the admissible contact force at the current state under
//! the held controls, a constraint solve the physics steps do not share (docs/sim.md, "What the
//! loop costs"). For the teacher and branches a third side replays the controls and also pays
//! for those solves; the osms time against it is the share of osms's own work.
//!
//! Every rollout is timed on all sides back to back, in rotating order, `rounds` times; a
//! rollout's time is its fastest round (interruptions only ever add time), and a pattern's ratio
//! is the sum of bare times over the sum of osms times. The whole measurement repeats `runs`
//! times and the figures are min / median / max over runs. Prints figures; asserts nothing about
//! time.
//!
//! Settings (environment): `OSMS_BENCH_CONDITIONS` (default 48), `OSMS_BENCH_ROUNDS` (3),
//! `OSMS_BENCH_RUNS` (3), `OSMS_BENCH_PATTERNS` (comma-separated subset of
//! `scripted,teacher,branch`), `OSMS_BENCH_ONLY=<pattern>:<osms|bare>` (run only that side, for
//! `perf record`).

use std::time::{Duration, Instant};

use mujoco_rs::mujoco_c::{mjtStage, mjtState};
use mujoco_rs::prelude::*;
use osms_core::rng;
use osms_policy::catch::{CatchEpisode, CatchTaskSpec, OBS_LEN};
use osms_policy::{Agent, PpoConfig, TaskEpisode};
use osms_sim::catcher::{CatcherSpec, ScriptedCatcher};
use osms_sim::conditions::sample;
use osms_sim::control::DrSpec;
use osms_sim::episode::{Episode, Hooks, RolloutSpec, initial_data};
use osms_sim::metrics::scan;
use osms_sim::{Action, ConditionSpec, GeomClass, N_ARM, TaskCondition, World, WorldSpec};

const STATE: u32 = mjtState::mjSTATE_INTEGRATION as u32;
/// Branches per condition, as validation's Q perturbed rollouts.
const BRANCHES: usize = 4;
/// Control steps of the perturbed window (the paper's OSW is a few steps before contact).
const WINDOW: usize = 6;

/// Records the controls of every physics step and where each control step starts.
#[derive(Default, Clone)]
struct Controls {
    ctrl: Vec<Vec<f64>>,
    control_starts: Vec<usize>,
}
impl Hooks for Controls {
    fn override_arm(&mut self, _step: usize, _action: &mut Action) {
        self.control_starts.push(self.ctrl.len());
    }
    fn after_physics_step(&mut self, data: &MjData<Box<MjModel>>) {
        self.ctrl.push(data.ctrl().to_vec());
    }
}

/// Validation's hooks, cut down: a branch-specific offset on the arm channels in the window.
struct Perturb {
    from: usize,
    offset: f64,
    controls: Option<Controls>,
}
impl Hooks for Perturb {
    fn override_arm(&mut self, step: usize, action: &mut Action) {
        if let Some(c) = &mut self.controls {
            c.override_arm(step, action);
        }
    }
    fn perturb(&mut self, step: usize, action: &mut Action) {
        if (self.from..self.from + WINDOW).contains(&step) {
            for (c, a) in action[..N_ARM].iter_mut().enumerate() {
                *a = (*a + self.offset * if c % 2 == 0 { 1.0 } else { -1.0 }).clamp(-1.0, 1.0);
            }
        }
    }
    fn after_physics_step(&mut self, data: &MjData<Box<MjModel>>) {
        if let Some(c) = &mut self.controls {
            c.after_physics_step(data);
        }
    }
}

fn setting(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Pattern {
    Scripted,
    Teacher,
    Branch,
}

impl Pattern {
    const ALL: [Pattern; 3] = [Pattern::Scripted, Pattern::Teacher, Pattern::Branch];
    fn name(self) -> &'static str {
        match self {
            Pattern::Scripted => "scripted",
            Pattern::Teacher => "teacher",
            Pattern::Branch => "branch",
        }
    }
}

/// What the bare side replays for one condition: from `start` (a model and integration state),
/// each branch's controls.
struct Bare {
    model: MjModel,
    start: Box<[f64]>,
    branches: Vec<Controls>,
}

impl Bare {
    fn physics_steps(&self) -> usize {
        self.branches.iter().map(|b| b.ctrl.len()).sum()
    }
}

struct Bench<'a> {
    world: &'a World,
    scripted_spec: RolloutSpec,
    teacher_spec: CatchTaskSpec,
    agent: Agent,
    conditions: Vec<TaskCondition>,
}

impl Bench<'_> {
    fn dr(&self, i: usize) -> rng::StreamRng {
        rng::stream(0, "bench", "rollout", i as u64)
    }

    fn scripted(&self, i: usize, hooks: &mut dyn Hooks) -> osms_sim::RolloutRecord {
        let mut catcher =
            ScriptedCatcher::new(CatcherSpec::default(), self.scripted_spec.control.clone());
        Episode::new(
            self.world,
            &self.scripted_spec,
            self.conditions[i].clone(),
            self.dr(i),
        )
        .run(&mut catcher, hooks)
    }

    fn teacher_episode(&self, i: usize) -> CatchEpisode<'_> {
        CatchEpisode::new(
            self.world,
            &self.teacher_spec,
            self.conditions[i].clone(),
            self.dr(i),
        )
    }

    fn teacher(&self, i: usize, hooks: &mut dyn Hooks) -> usize {
        let mut ep = self.teacher_episode(i);
        let agent = &self.agent;
        while !ep
            .step_with_hooks(&mut |obs| agent.act_deterministic(obs), hooks)
            .1
        {}
        let steps = ep.episode().record().steps;
        std::hint::black_box(ep.finish());
        steps
    }

    /// The teacher run to its window start, which is a few steps before the unperturbed
    /// rollout's event step.
    fn prefix(&self, i: usize) -> CatchEpisode<'_> {
        let mut probe = self.teacher_episode(i);
        let agent = &self.agent;
        while !probe
            .step_with_hooks(
                &mut |obs| agent.act_deterministic(obs),
                &mut Controls::default(),
            )
            .1
        {}
        let from = probe
            .episode()
            .outcome()
            .1
            .event_step
            .saturating_sub(WINDOW + 2);
        let mut ep = self.teacher_episode(i);
        for _ in 0..from {
            ep.step_with_hooks(
                &mut |obs| agent.act_deterministic(obs),
                &mut Controls::default(),
            );
        }
        ep
    }

    /// Every branch of condition `i` from the prefix's snapshot, optionally recording controls.
    fn branches(
        &self,
        ep: &mut CatchEpisode<'_>,
        snapshot: &osms_policy::catch::CatchSnapshot,
        record: bool,
    ) -> Vec<Controls> {
        let agent = &self.agent;
        (0..BRANCHES)
            .map(|b| {
                ep.restore(snapshot);
                let from = ep.episode().step_index();
                let mut hooks = Perturb {
                    from,
                    offset: 0.05 * (b as f64 + 1.0),
                    controls: record.then(Controls::default),
                };
                while !ep
                    .step_with_hooks(&mut |obs| agent.act_deterministic(obs), &mut hooks)
                    .1
                {}
                std::hint::black_box(ep.episode().outcome());
                hooks.controls.unwrap_or_default()
            })
            .collect()
    }

    fn bare(&self, pattern: Pattern, i: usize) -> Bare {
        let c = &self.conditions[i];
        match pattern {
            Pattern::Scripted | Pattern::Teacher => {
                let mut controls = Controls::default();
                let (dr, data) = match pattern {
                    Pattern::Scripted => {
                        let r = self.scripted(i, &mut controls);
                        (r.dr.clone(), initial_data(self.world, c, &r.dr))
                    }
                    _ => {
                        let dr = self.teacher_episode(i).episode().record().dr.clone();
                        self.teacher(i, &mut controls);
                        let data = initial_data(self.world, c, &dr);
                        (dr, data)
                    }
                };
                std::hint::black_box(dr);
                Bare {
                    model: data.model().clone(),
                    start: data.state(STATE),
                    branches: vec![controls],
                }
            }
            Pattern::Branch => {
                let mut ep = self.prefix(i);
                let snapshot = ep.snapshot();
                let data = ep.episode().data();
                let (model, start) = (data.model().clone(), data.state(STATE));
                Bare {
                    model,
                    start,
                    branches: self.branches(&mut ep, &snapshot, true),
                }
            }
        }
    }
}

/// One bare replay: a fresh `MjData` for a whole rollout (as osms makes one), an `mj_setState`
/// onto a live one for branches (as osms restores one). With `classes`, it also pays for what
/// the teacher's observation must cost on top of the physics: at every control step that
/// starts with an admissible hand–object contact, the constraint solve of the observed contact
/// force under the held controls (`Episode::observe`).
fn replay(
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

fn time(f: impl FnOnce()) -> Duration {
    let t = Instant::now();
    f();
    t.elapsed()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let n = setting("OSMS_BENCH_CONDITIONS", 48);
    let rounds = setting("OSMS_BENCH_ROUNDS", 3).max(1);
    let runs = setting("OSMS_BENCH_RUNS", 3).max(1);
    let patterns: Vec<Pattern> = match std::env::var("OSMS_BENCH_PATTERNS") {
        Ok(list) => Pattern::ALL
            .into_iter()
            .filter(|p| list.split(',').any(|s| s.trim() == p.name()))
            .collect(),
        Err(_) => Pattern::ALL.to_vec(),
    };
    let only = std::env::var("OSMS_BENCH_ONLY").ok();

    let world = World::new(WorldSpec::default()).expect("world");
    let scripted_spec = RolloutSpec {
        dr: DrSpec::paper(),
        ..RolloutSpec::default()
    };
    let mut teacher_spec = CatchTaskSpec::default();
    teacher_spec.rollout.dr = DrSpec::paper();
    let config = PpoConfig::default();
    let mut agent = Agent::new(
        OBS_LEN,
        teacher_spec.act_len(),
        &config,
        (0, "bench-teacher"),
    )
    .expect("a valid agent");
    // An untrained actor's follow-through output sits near zero, where the channel's Jacobian
    // solve is skipped; a trained teacher uses it at most steps.
    if let Some(b) = agent
        .actor
        .layers
        .last_mut()
        .and_then(|last| last.b.last_mut())
    {
        *b = 0.3;
    }
    let conditions = (0..n as u64)
        .map(|i| {
            sample(
                &ConditionSpec::default(),
                world.home_palm_pos,
                &mut rng::stream(0, "bench", "omega", i),
            )
            .expect("ω")
        })
        .collect();
    let bench = Bench {
        world: &world,
        scripted_spec,
        teacher_spec,
        agent,
        conditions,
    };

    if let Some(only) = only {
        let (pattern, side) = only
            .split_once(':')
            .expect("OSMS_BENCH_ONLY=<pattern>:<side>");
        let pattern = Pattern::ALL
            .into_iter()
            .find(|p| p.name() == pattern)
            .expect("a pattern");
        profile(&bench, pattern, side == "bare", runs * rounds);
        return;
    }

    println!(
        "rollout loop vs bare mj_step replay: {n} conditions, paper DR, one core; {rounds} rounds per run (fastest kept), {runs} runs"
    );
    println!(
        "teacher: actor {:?} hidden, follow-through channel on",
        config.hidden
    );
    for pattern in patterns {
        let bare: Vec<Bare> = (0..n).map(|i| bench.bare(pattern, i)).collect();
        let physics_steps: usize = bare.iter().map(Bare::physics_steps).sum();
        let mut prefixes: Vec<_> = match pattern {
            Pattern::Branch => (0..n)
                .map(|i| {
                    let ep = bench.prefix(i);
                    let s = ep.snapshot();
                    Some((ep, s))
                })
                .collect(),
            _ => (0..n).map(|_| None).collect(),
        };
        // The scripted catcher does not read the contact force, so its observation solves
        // nothing: its third side would be its second.
        let classes = (pattern != Pattern::Scripted).then_some(world.ids.geom_class.as_slice());
        let mut figures: Vec<[f64; 4]> = Vec::new();
        for _ in 0..runs {
            let mut best = vec![[Duration::MAX; 3]; n];
            for round in 0..rounds {
                for (i, best) in best.iter_mut().enumerate() {
                    let b = &bare[i];
                    let mut data = MjData::new(Box::new(b.model.clone()));
                    let fresh = pattern != Pattern::Branch;
                    // Rotate the order of the sides so that none always runs first.
                    for k in 0..3 {
                        let side = (k + round + i) % 3;
                        let t = match side {
                            0 => time(|| match pattern {
                                Pattern::Scripted => {
                                    std::hint::black_box(bench.scripted(i, &mut osms_sim::NoHooks));
                                }
                                Pattern::Teacher => {
                                    std::hint::black_box(bench.teacher(i, &mut osms_sim::NoHooks));
                                }
                                Pattern::Branch => {
                                    let (ep, s) = prefixes[i].as_mut().expect("prefix");
                                    bench.branches(ep, s, false);
                                }
                            }),
                            1 => time(|| replay(b, &mut data, fresh, None)),
                            _ => match classes {
                                Some(_) => time(|| replay(b, &mut data, fresh, classes)),
                                None => continue,
                            },
                        };
                        best[side] = best[side].min(t);
                    }
                }
            }
            let sum = |side: usize| -> f64 {
                best.iter().map(|b| b[side]).sum::<Duration>().as_secs_f64()
            };
            let (osms, raw) = (sum(0), sum(1));
            let solves = if classes.is_some() { sum(2) } else { raw };
            figures.push([raw / osms, solves / osms, osms, raw]);
        }
        let column = |c: usize| figures.iter().map(|f| f[c]).collect::<Vec<_>>();
        let spread = |v: Vec<f64>| {
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            (lo, median(v), hi)
        };
        let (lo, mid, hi) = spread(column(0));
        let (_, solves_mid, _) = spread(column(1));
        let us = |c: usize| median(column(c)) * 1e6 / physics_steps as f64;
        let (osms_us, bare_us) = (us(2), us(3));
        println!(
            "  {:<9} {:>6} physics steps  osms {:6.2} us/step  bare {:6.2} us/step  ratio min {:.3}  median {:.3}  max {:.3}  (target >= 0.95)",
            pattern.name(),
            physics_steps,
            osms_us,
            bare_us,
            lo,
            mid,
            hi
        );
        if classes.is_some() {
            println!(
                "  {:<9} against bare + the observed contact-force solves: median {:.3} (the rest is osms's own work)",
                "", solves_mid
            );
        }
    }
}

/// Runs one side of one pattern `times` over, for a profiler.
fn profile(bench: &Bench<'_>, pattern: Pattern, bare_side: bool, times: usize) {
    let n = bench.conditions.len();
    let bare: Vec<Bare> = if bare_side {
        (0..n).map(|i| bench.bare(pattern, i)).collect()
    } else {
        Vec::new()
    };
    let mut prefixes: Vec<_> = if pattern == Pattern::Branch && !bare_side {
        (0..n)
            .map(|i| {
                let ep = bench.prefix(i);
                let s = ep.snapshot();
                (ep, s)
            })
            .collect()
    } else {
        Vec::new()
    };
    let t = Instant::now();
    profiled_loop(bench, pattern, &bare, &mut prefixes, times);
    println!(
        "{}:{} ran {times} times in {:.1} s",
        pattern.name(),
        if bare_side { "bare" } else { "osms" },
        t.elapsed().as_secs_f64()
    );
}

/// The profiled work alone, in a frame of its own: scripts/perf-breakdown.py counts only the
/// samples under it, so the preparation above (probe rollouts, prefixes) stays out.
#[inline(never)]
fn profiled_loop(
    bench: &Bench<'_>,
    pattern: Pattern,
    bare: &[Bare],
    prefixes: &mut [(CatchEpisode<'_>, osms_policy::catch::CatchSnapshot)],
    times: usize,
) {
    let n = bench.conditions.len();
    for _ in 0..times {
        for i in 0..n {
            if !bare.is_empty() {
                let b = &bare[i];
                let mut data = MjData::new(Box::new(b.model.clone()));
                replay(b, &mut data, pattern != Pattern::Branch, None);
            } else {
                match pattern {
                    Pattern::Scripted => {
                        std::hint::black_box(bench.scripted(i, &mut osms_sim::NoHooks));
                    }
                    Pattern::Teacher => {
                        std::hint::black_box(bench.teacher(i, &mut osms_sim::NoHooks));
                    }
                    Pattern::Branch => {
                        let (ep, s) = &mut prefixes[i];
                        bench.branches(ep, s, false);
                    }
                }
            }
        }
    }
}
