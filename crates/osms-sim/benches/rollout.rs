//! The scripted catcher's rollout against MuJoCo alone: the time of `Episode::run` (setup,
//! observations, the catcher's interception and IK, servo targets, DR, per-physics-step
//! evaluation, the record) against a bare `mj_step` replay of the very same per-physics-step
//! controls from the same initial state, measured in the same run. The ratio (bare / osms) is
//! the share of a rollout's time that is MuJoCo's; 1.0 means osms adds nothing. The teacher's
//! and validation's branch patterns, which need osms-policy, are osms-policy's rollout bench.
//!
//! Every rollout is timed on both sides back to back, in rotating order, `rounds` times; a
//! rollout's time is its fastest round, and the ratio is the sum of bare times over the sum of
//! osms times. The whole measurement repeats `runs` times and the figures are min / median /
//! max over runs. Prints figures; asserts nothing about time.
//!
//! Settings (environment): `OSMS_BENCH_CONDITIONS` (default 48), `OSMS_BENCH_ROUNDS` (3),
//! `OSMS_BENCH_RUNS` (3), `OSMS_BENCH_ONLY=scripted:<osms|bare>` (run only that side, for
//! `perf record`).

#[path = "common/bare.rs"]
mod bare;

use std::time::Instant;

use bare::{Bare, Controls, STATE, conditions, dr, measure, replay, report, setting, time};
use mujoco_rs::prelude::*;
use osms_sim::catcher::{CatcherSpec, ScriptedCatcher};
use osms_sim::control::DrSpec;
use osms_sim::episode::{Episode, RolloutSpec, initial_data};
use osms_sim::policy::Hooks;
use osms_sim::{TaskCondition, World, WorldSpec};

struct Bench<'a> {
    world: &'a World,
    spec: RolloutSpec,
    conditions: Vec<TaskCondition>,
}

impl Bench<'_> {
    fn scripted(&self, i: usize, hooks: &mut dyn Hooks) -> osms_sim::RolloutRecord {
        let mut catcher = ScriptedCatcher::new(CatcherSpec::default(), self.spec.control.clone());
        Episode::new(self.world, &self.spec, self.conditions[i].clone(), dr(i))
            .run(&mut catcher, hooks)
    }

    fn bare(&self, i: usize) -> Bare {
        let mut controls = Controls::default();
        let r = self.scripted(i, &mut controls);
        let data = initial_data(self.world, &self.conditions[i], &r.dr);
        Bare {
            model: data.model().clone(),
            start: data.state(STATE),
            branches: vec![controls],
        }
    }
}

fn main() {
    let n = setting("OSMS_BENCH_CONDITIONS", 48);
    let rounds = setting("OSMS_BENCH_ROUNDS", 3).max(1);
    let runs = setting("OSMS_BENCH_RUNS", 3).max(1);
    let world = World::new(WorldSpec::default()).expect("world");
    let bench = Bench {
        world: &world,
        spec: RolloutSpec {
            dr: DrSpec::paper(),
            ..RolloutSpec::default()
        },
        conditions: conditions(&world, n),
    };
    let bare: Vec<Bare> = (0..n).map(|i| bench.bare(i)).collect();

    if let Ok(only) = std::env::var("OSMS_BENCH_ONLY") {
        let bare_side = match only.as_str() {
            "scripted:osms" => false,
            "scripted:bare" => true,
            other => {
                panic!("OSMS_BENCH_ONLY={other}: this bench has scripted:osms and scripted:bare")
            }
        };
        let t = Instant::now();
        profiled_loop(&bench, bare_side.then_some(bare.as_slice()), runs * rounds);
        println!(
            "scripted:{} ran {} times in {:.1} s",
            if bare_side { "bare" } else { "osms" },
            runs * rounds,
            t.elapsed().as_secs_f64()
        );
        return;
    }

    println!(
        "rollout loop vs bare mj_step replay: {n} conditions, paper DR, one core; {rounds} rounds per run (fastest kept), {runs} runs"
    );
    let physics_steps = bare.iter().map(Bare::physics_steps).sum();
    let figures = measure(n, 2, rounds, runs, |i, side| {
        Some(match side {
            0 => time(|| {
                std::hint::black_box(bench.scripted(i, &mut osms_sim::NoHooks));
            }),
            _ => {
                let mut data = MjData::new(Box::new(bare[i].model.clone()));
                time(|| replay(&bare[i], &mut data, true, None))
            }
        })
    });
    report("scripted", physics_steps, &figures);
}

/// The profiled work alone, in a frame of its own: scripts/perf-breakdown.py counts only the
/// samples under it, so the preparation above stays out.
#[inline(never)]
fn profiled_loop(bench: &Bench<'_>, bare: Option<&[Bare]>, times: usize) {
    for _ in 0..times {
        for i in 0..bench.conditions.len() {
            match bare {
                Some(bare) => {
                    let mut data = MjData::new(Box::new(bare[i].model.clone()));
                    replay(&bare[i], &mut data, true, None);
                }
                None => {
                    std::hint::black_box(bench.scripted(i, &mut osms_sim::NoHooks));
                }
            }
        }
    }
}
