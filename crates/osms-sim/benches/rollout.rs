//! Rollouts per second per core of the scripted catcher against a bare `mj_step` loop doing the
//! same physics: the raw baseline replays each episode's exact per-physics-step controls on a copy
//! of the episode's model and initial state, so the ratio is the cost of everything osms adds
//! (policy, control mapping, observations, contact classification, metrics, record).
//! Target ratio ≥ 0.85. Prints figures; asserts nothing about time.

use std::time::{Duration, Instant};

use mujoco_rs::prelude::*;
use osms_make::rng;
use osms_sim::catcher::{CatcherSpec, ScriptedCatcher};
use osms_sim::conditions::sample;
use osms_sim::episode::{Episode, Hooks, NoHooks, RolloutSpec};
use osms_sim::{ConditionSpec, World, WorldSpec};

/// Records the controls of every physics step.
#[derive(Default)]
struct Controls(Vec<Vec<f64>>);
impl Hooks for Controls {
    fn after_physics_step(&mut self, data: &MjData<Box<MjModel>>) {
        self.0.push(data.ctrl().to_vec());
    }
}

struct Replay {
    model: MjModel,
    qpos: Vec<f64>,
    qvel: Vec<f64>,
    controls: Vec<Vec<f64>>,
}

fn best(runs: usize, mut f: impl FnMut()) -> Duration {
    (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed()
        })
        .min()
        .unwrap_or_default()
}

fn main() {
    let world = World::new(WorldSpec::default()).expect("world");
    let spec = RolloutSpec::default();
    let n = 100u64;
    let conditions: Vec<_> = (0..n)
        .map(|i| {
            sample(
                &ConditionSpec::default(),
                world.home_palm_pos,
                &mut rng::stream(0, "bench", "omega", i),
            )
            .expect("ω")
        })
        .collect();

    let replays: Vec<Replay> = conditions
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let ep = Episode::new(
                &world,
                &spec,
                c.clone(),
                rng::stream(0, "bench", "rollout", i as u64),
            );
            let data = ep.data();
            let (model, qpos, qvel) = (
                data.model().clone(),
                data.qpos().to_vec(),
                data.qvel().to_vec(),
            );
            let mut controls = Controls::default();
            let mut catcher = ScriptedCatcher::new(CatcherSpec::default(), spec.control.clone());
            ep.run(&mut catcher, &mut controls);
            Replay {
                model,
                qpos,
                qvel,
                controls: controls.0,
            }
        })
        .collect();
    let physics_steps: usize = replays.iter().map(|r| r.controls.len()).sum();

    let t_episode = best(3, || {
        for (i, c) in conditions.iter().enumerate() {
            let mut catcher = ScriptedCatcher::new(CatcherSpec::default(), spec.control.clone());
            let r = Episode::new(
                &world,
                &spec,
                c.clone(),
                rng::stream(0, "bench", "rollout", i as u64),
            )
            .run(&mut catcher, &mut NoHooks);
            std::hint::black_box(r);
        }
    });
    let t_bare = best(3, || {
        for r in &replays {
            let mut data = MjData::new(Box::new(r.model.clone()));
            data.qpos_mut().copy_from_slice(&r.qpos);
            data.qvel_mut().copy_from_slice(&r.qvel);
            for ctrl in &r.controls {
                data.ctrl_mut().copy_from_slice(ctrl);
                data.step();
            }
            std::hint::black_box(data.qpos()[0]);
        }
    });

    let us = |t: Duration| t.as_secs_f64() * 1e6 / physics_steps as f64;
    let rate = |t: Duration| n as f64 / t.as_secs_f64();
    println!(
        "scripted-catcher rollouts: {n} conditions, one core, {} physics steps per rollout on average",
        physics_steps as u64 / n
    );
    println!(
        "  episode loop        {:8.1} rollouts/s   {:6.2} us per physics step",
        rate(t_episode),
        us(t_episode)
    );
    println!(
        "  bare mj_step replay {:8.1} rollouts/s   {:6.2} us per physics step",
        rate(t_bare),
        us(t_bare)
    );
    println!(
        "  ratio (episode / bare)  {:.3}   (target >= 0.85)",
        t_bare.as_secs_f64() / t_episode.as_secs_f64()
    );
}
