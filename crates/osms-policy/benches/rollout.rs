//! The teacher's rollouts against MuJoCo alone, for two patterns, each against a bare `mj_step`
//! replay of the very same per-physics-step controls from the same state, measured in the same
//! run (the scripted catcher's pattern is osms-sim's rollout bench; both include its bare
//! replay, `osms-sim/benches/common/bare.rs`). The ratio (bare / osms) is the share of a
//! rollout's time that is MuJoCo's; 1.0 means osms adds nothing.
//!
//! - **teacher**: the PPO teacher's episode (`CatchEpisode`: the prior, the actor network of the
//!   default profile's size, the follow-through channel's Jacobian solve, the reward).
//! - **branch**: validation's pattern: the teacher runs to a window start shortly before its
//!   event step, is snapshotted, and every branch restores the snapshot, perturbs the arm over
//!   the window and runs to the end. The bare side restores MuJoCo's state (`mj_setState`) and
//!   replays each branch. The prefix is untimed on both sides.
//!
//! The teacher's observation includes the admissible contact force at the current state under
//! the held controls, a constraint solve the physics steps do not share (docs/sim.md, "What the
//! loop costs"). A third side replays the controls and also pays for those solves; the osms
//! time against it is the share of osms's own work.
//!
//! - **student**: an evaluation's pattern: a flow-matching student (the default network, briefly
//!   trained on teacher rollouts: its cost per step does not depend on how well it acts) runs
//!   [`ROLLOUT_BATCH`] rollouts, `LOCKSTEP_SLOTS` of them stepped in lockstep with one batched
//!   action per control step, as `eval_student` does. The bare side replays each of the batch's
//!   rollouts from its start. Its ratio is an evaluation's share of its MuJoCo floor (students
//!   read no contact force).
//!
//! Every rollout is timed on all sides back to back, in rotating order, `rounds` times; a
//! rollout's time is its fastest round (interruptions only ever add time), and a pattern's ratio
//! is the sum of bare times over the sum of osms times. The whole measurement repeats `runs`
//! times and the figures are min / median / max over runs. Prints figures; asserts nothing about
//! time.
//!
//! Settings (environment): `OSMS_BENCH_CONDITIONS` (default 48), `OSMS_BENCH_ROUNDS` (3),
//! `OSMS_BENCH_RUNS` (3), `OSMS_BENCH_PATTERNS` (comma-separated subset of `teacher,branch,student`; a student's
//! conditions are counted in batches),
//! `OSMS_BENCH_ONLY=<pattern>:<osms|bare>` (run only that side, for `perf record`).

#[path = "../../osms-sim/benches/common/bare.rs"]
mod bare;

use std::time::Instant;

use bare::{Bare, Controls, STATE, conditions, dr, measure, replay, report, setting, time};
use mujoco_rs::prelude::*;
use osms_policy::catch::{CatchEpisode, CatchSnapshot, CatchTaskSpec, OBS_LEN};
use osms_policy::student::{Demo, ROLLOUT_BATCH, Student, StudentParams, StudentPolicy, rollouts};
use osms_policy::{Agent, PpoConfig, TaskEpisode};
use osms_sim::control::DrSpec;
use osms_sim::episode::initial_data;
use osms_sim::policy::Hooks;
use osms_sim::{Action, Episode, N_ARM, RolloutSpec, TaskCondition, World, WorldSpec};

/// Branches per condition, as validation's Q perturbed rollouts.
const BRANCHES: usize = 4;
/// Control steps of the perturbed window (the paper's OSW is a few steps before contact).
const WINDOW: usize = 6;

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

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Pattern {
    Teacher,
    Branch,
    Student,
}

impl Pattern {
    const ALL: [Pattern; 3] = [Pattern::Teacher, Pattern::Branch, Pattern::Student];
    fn name(self) -> &'static str {
        match self {
            Pattern::Teacher => "teacher",
            Pattern::Branch => "branch",
            Pattern::Student => "student",
        }
    }
}

struct Bench<'a> {
    world: &'a World,
    spec: CatchTaskSpec,
    agent: Agent,
    conditions: Vec<TaskCondition>,
    student: Student,
    student_spec: RolloutSpec,
}

/// A student's policy stream for rollout `i`.
fn policy_rng(i: usize) -> osms_core::rng::StreamRng {
    osms_core::rng::stream(0, "bench", "policy", i as u64)
}

impl Bench<'_> {
    fn episode(&self, i: usize) -> CatchEpisode<'_> {
        CatchEpisode::new(self.world, &self.spec, self.conditions[i].clone(), dr(i))
    }

    fn teacher(&self, i: usize, hooks: &mut dyn Hooks) -> usize {
        let mut ep = self.episode(i);
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
        let mut probe = self.episode(i);
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
        let mut ep = self.episode(i);
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
        snapshot: &CatchSnapshot,
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

    /// Batch `b` of student rollouts, in lockstep.
    fn students(&self, b: usize) -> usize {
        let items = (b * ROLLOUT_BATCH..(b + 1) * ROLLOUT_BATCH)
            .map(|i| (self.conditions[i].clone(), dr(i), policy_rng(i)))
            .collect();
        let records = rollouts(self.world, &self.student_spec, &self.student, items);
        std::hint::black_box(records.iter().map(|r| r.steps).sum())
    }

    /// Student rollout `i` alone (the lockstep rollout's bits), recording its controls.
    fn student_bare(&self, i: usize) -> Bare {
        let mut controls = Controls::default();
        let mut policy = StudentPolicy::new(&self.student, policy_rng(i));
        let episode = Episode::new(
            self.world,
            &self.student_spec,
            self.conditions[i].clone(),
            dr(i),
        );
        let record = episode.run(&mut policy, &mut controls);
        let data = initial_data(self.world, &self.conditions[i], &record.dr);
        Bare {
            model: data.model().clone(),
            start: data.state(STATE),
            branches: vec![controls],
        }
    }

    /// What the bare side replays for item `i`: one rollout's controls, a condition's
    /// branches, or a student batch's rollouts, each from its own start.
    fn bares(&self, pattern: Pattern, i: usize) -> Vec<Bare> {
        match pattern {
            Pattern::Student => (i * ROLLOUT_BATCH..(i + 1) * ROLLOUT_BATCH)
                .map(|k| self.student_bare(k))
                .collect(),
            _ => vec![self.bare(pattern, i)],
        }
    }

    fn bare(&self, pattern: Pattern, i: usize) -> Bare {
        match pattern {
            Pattern::Student => unreachable!("a student batch replays through `bares`"),
            Pattern::Teacher => {
                let mut controls = Controls::default();
                let dr = self.episode(i).episode().record().dr.clone();
                self.teacher(i, &mut controls);
                let data = initial_data(self.world, &self.conditions[i], &dr);
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

    fn prefixes(&self) -> Vec<(CatchEpisode<'_>, CatchSnapshot)> {
        (0..self.conditions.len())
            .map(|i| {
                let ep = self.prefix(i);
                let s = ep.snapshot();
                (ep, s)
            })
            .collect()
    }
}

fn main() {
    // One core for every side, and the whole bench on the pool's thread: the bare replay is
    // single-threaded, and so must be the student's batched products. Called from outside the
    // pool, every product large enough for rayon would hand its work to the pool's thread and
    // sleep until it is done; the evaluation stages call it on a worker (the make's items run
    // on its pool), where it runs in place.
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a one-thread pool")
        .install(run);
}

fn run() {
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

    let world = World::new(WorldSpec::default()).expect("world");
    let mut spec = CatchTaskSpec::default();
    spec.rollout.dr = DrSpec::paper();
    let config = PpoConfig::default();
    let mut agent =
        Agent::new(OBS_LEN, spec.act_len(), &config, (0, "bench-teacher")).expect("a valid agent");
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
    let student = bench_student(&world, &spec, &agent);
    let student_spec = student.rollout_spec(&spec.rollout);
    let bench = Bench {
        world: &world,
        spec,
        agent,
        conditions: conditions(&world, n.max(ROLLOUT_BATCH)),
        student,
        student_spec,
    };

    if let Ok(only) = std::env::var("OSMS_BENCH_ONLY") {
        let (pattern, side) = only
            .split_once(':')
            .expect("OSMS_BENCH_ONLY=<pattern>:<side>");
        let pattern = Pattern::ALL
            .into_iter()
            .find(|p| p.name() == pattern)
            .expect("a pattern: teacher, branch or student");
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
    let classes = world.ids.geom_class.as_slice();
    for pattern in patterns {
        // A student's item is a lockstep batch of rollouts.
        let items = match pattern {
            Pattern::Student => bench.conditions.len() / ROLLOUT_BATCH,
            _ => n,
        };
        let bare: Vec<Vec<Bare>> = (0..items).map(|i| bench.bares(pattern, i)).collect();
        let physics_steps = bare.iter().flatten().map(Bare::physics_steps).sum();
        let mut prefixes = match pattern {
            Pattern::Branch => bench.prefixes(),
            Pattern::Teacher | Pattern::Student => Vec::new(),
        };
        let fresh = pattern != Pattern::Branch;
        let figures = measure(items, 3, rounds, runs, |i, side| {
            let mut data = MjData::new(Box::new(bare[i][0].model.clone()));
            Some(match side {
                0 => time(|| osms_side(&bench, pattern, &mut prefixes, i)),
                1 => time(|| {
                    bare[i]
                        .iter()
                        .for_each(|b| replay(b, &mut data, fresh, None))
                }),
                // Students read no contact force: their floor is the plain replay.
                _ if pattern == Pattern::Student => return None,
                _ => time(|| {
                    bare[i]
                        .iter()
                        .for_each(|b| replay(b, &mut data, fresh, Some(classes)))
                }),
            })
        });
        report(pattern.name(), physics_steps, &figures);
    }
}

/// The osms side of item `i` of a pattern.
fn osms_side(
    bench: &Bench<'_>,
    pattern: Pattern,
    prefixes: &mut [(CatchEpisode<'_>, CatchSnapshot)],
    i: usize,
) {
    match pattern {
        Pattern::Teacher => {
            std::hint::black_box(bench.teacher(i, &mut osms_sim::NoHooks));
        }
        Pattern::Branch => {
            let (ep, s) = &mut prefixes[i];
            bench.branches(ep, s, false);
        }
        Pattern::Student => {
            std::hint::black_box(bench.students(i));
        }
    }
}

/// A student of the default shape, trained for a few steps on teacher rollouts (its cost per
/// step does not depend on how well it acts).
fn bench_student(world: &World, spec: &CatchTaskSpec, agent: &Agent) -> Student {
    let demos: Vec<Demo> = (0..8)
        .map(|i| {
            let condition = conditions(world, 8)[i].clone();
            Demo::from_record(&osms_policy::catch::rollout(
                world,
                spec,
                agent,
                condition,
                dr(1000 + i),
            ))
        })
        .collect();
    let params = StudentParams {
        steps: 5,
        holdout_every: 0,
        ..StudentParams::default()
    };
    Student::train(&demos, &params, (0, "bench"), &|| {}).expect("a student")
}

/// Runs one side of one pattern `times` over, for a profiler.
fn profile(bench: &Bench<'_>, pattern: Pattern, bare_side: bool, times: usize) {
    let items = match pattern {
        Pattern::Student => bench.conditions.len() / ROLLOUT_BATCH,
        _ => bench.conditions.len(),
    };
    let bare: Vec<Vec<Bare>> = if bare_side {
        (0..items).map(|i| bench.bares(pattern, i)).collect()
    } else {
        Vec::new()
    };
    let mut prefixes = if pattern == Pattern::Branch && !bare_side {
        bench.prefixes()
    } else {
        Vec::new()
    };
    let t = Instant::now();
    profiled_loop(bench, pattern, &bare, &mut prefixes, items, times);
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
    bare: &[Vec<Bare>],
    prefixes: &mut [(CatchEpisode<'_>, CatchSnapshot)],
    items: usize,
    times: usize,
) {
    for _ in 0..times {
        for i in 0..items {
            if bare.is_empty() {
                osms_side(bench, pattern, prefixes, i);
            } else {
                for b in &bare[i] {
                    let mut data = MjData::new(Box::new(b.model.clone()));
                    replay(b, &mut data, pattern != Pattern::Branch, None);
                }
            }
        }
    }
}
