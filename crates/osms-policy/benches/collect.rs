//! Environment steps per second of the teacher against the bare rollout loop of the world, one
//! thread each, measured in the same run (best of 3). Prints figures; asserts nothing about time.
//!
//! - **Same physics**: the teacher's rollouts (`catch::rollout`: observation, normalisation,
//!   actor forward pass, the follow-through channel's Jacobian solve, reward bookkeeping) against
//!   `Episode::run` replaying the very same actions open-loop. The actor's follow-through output
//!   is biased away from zero so that the channel's solve runs on every step.
//! - **PPO**: a whole collection (sampling, critic, trajectory buffers; no update) and a whole
//!   iteration (collection + 4 epochs) of an untrained agent, against the scripted catcher
//!   through `Episode::run` on the same conditions. Their episodes differ (exploration noise),
//!   so this ratio also carries the different contact load per step.

use std::time::Instant;

use osms_core::rng;
use osms_policy::catch::{CatchTask, CatchTaskSpec, rollout};
use osms_policy::{Agent, PpoConfig, PpoState, Task, train};
use osms_sim::catcher::ScriptedCatcher;
use osms_sim::{Action, Episode, N_ACTION, NoHooks, Policy, PolicyView, World, WorldSpec};

const EPISODES: u64 = 64;

/// Plays back recorded actions.
struct Replay<'a>(&'a [f32]);
impl Policy for Replay<'_> {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        let k = view.step * N_ACTION;
        std::array::from_fn(|c| f64::from(self.0.get(k + c).copied().unwrap_or(0.0)))
    }
}

fn best<T>(f: impl Fn() -> (f64, T)) -> (f64, f64, T) {
    let mut out = None;
    for _ in 0..3 {
        let t = Instant::now();
        let (steps, extra) = f();
        let secs = t.elapsed().as_secs_f64();
        if out.as_ref().is_none_or(|(_, s, _)| secs < *s) {
            out = Some((steps, secs, extra));
        }
    }
    out.expect("three runs")
}

fn main() {
    let world = World::new(WorldSpec::default()).expect("world");
    let spec = CatchTaskSpec::default();
    let task = CatchTask::new(&world, spec.clone(), 0, "bench", "train").expect("task");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let dr = |i: u64| rng::stream(0, "bench", "train-dr", i);
    let config = PpoConfig {
        iterations: 1,
        episodes_per_iteration: EPISODES as u32,
        ..PpoConfig::default()
    };

    let mut agent =
        Agent::new(task.obs_len(), task.act_len(), &config, (0, "bench")).expect("a valid agent");
    if let Some(b) = agent
        .actor
        .layers
        .last_mut()
        .and_then(|last| last.b.last_mut())
    {
        *b = 0.3;
    }
    let (teacher_steps, teacher_secs, records) = pool.install(|| {
        best(|| {
            let records: Vec<_> = (0..EPISODES)
                .map(|i| rollout(&world, &spec, &agent, task.condition(i).expect("ω"), dr(i)))
                .collect();
            (records.iter().map(|r| r.steps as f64).sum(), records)
        })
    });
    let (replay_steps, replay_secs, ()) = pool.install(|| {
        best(|| {
            let mut steps = 0;
            for (i, r) in (0..EPISODES).zip(&records) {
                let replayed = Episode::new(&world, &spec.rollout, r.condition.clone(), dr(i))
                    .run(&mut Replay(&r.intended), &mut NoHooks);
                assert_eq!(replayed.executed, r.executed, "replay diverged");
                steps += replayed.steps;
            }
            (steps as f64, ())
        })
    });

    let (bare_steps, bare_secs, ()) = pool.install(|| {
        best(|| {
            let mut steps = 0;
            for i in 0..EPISODES {
                let mut catcher =
                    ScriptedCatcher::new(spec.catcher.clone(), spec.rollout.control.clone());
                steps += Episode::new(&world, &spec.rollout, task.condition(i).expect("ω"), dr(i))
                    .run(&mut catcher, &mut NoHooks)
                    .steps;
            }
            (steps as f64, ())
        })
    });
    let ppo = |epochs: u32| {
        let config = PpoConfig {
            epochs,
            ..config.clone()
        };
        pool.install(|| {
            best(|| {
                let agent = Agent::new(task.obs_len(), task.act_len(), &config, (0, "bench"))
                    .expect("a valid agent");
                let mut state = PpoState::new(agent, &config);
                train(&task, &mut state, &config, (0, "bench"), &|_| {}, None).expect("trains");
                (state.agent.curve[0].steps as f64, ())
            })
        })
    };
    let (collect_steps, collect_secs, ()) = ppo(0);
    let (iter_steps, iter_secs, ()) = ppo(config.epochs);

    let replay = replay_steps / replay_secs;
    let teacher = teacher_steps / teacher_secs;
    let bare = bare_steps / bare_secs;
    let collect = collect_steps / collect_secs;
    let iteration = iter_steps / iter_secs;
    println!("{EPISODES} episodes on one thread, best of 3");
    println!("same physics:");
    println!("  bare loop replaying the teacher's actions  {replay:7.0} env steps/s");
    println!(
        "  teacher rollouts                           {teacher:7.0} env steps/s   ratio {:.3}",
        teacher / replay
    );
    println!("PPO:");
    println!("  bare loop, scripted catcher                {bare:7.0} env steps/s");
    println!(
        "  PPO collection (no update)                 {collect:7.0} env steps/s   ratio {:.3}",
        collect / bare
    );
    println!(
        "  PPO iteration (collection + {} epochs)      {iteration:7.0} env steps/s   ratio {:.3}",
        config.epochs,
        iteration / bare
    );
}
