//! Environment steps per second of PPO collection on the catching task against the bare rollout
//! loop of the world (the scripted catcher through `Episode::run`) on the same conditions, one
//! thread each, measured in the same run. Collection adds the residual policy's forward pass,
//! the Gaussian sample, the follow-through channel's Jacobian solve and the reward bookkeeping.
//! Also reports a whole PPO iteration (collection + 4 epochs of updates). Prints figures;
//! asserts nothing about time.

use std::time::Instant;

use osms_make::rng;
use osms_policy::catch::{CatchTask, CatchTaskSpec};
use osms_policy::{Agent, PpoConfig, Task, train};
use osms_sim::catcher::ScriptedCatcher;
use osms_sim::{Episode, NoHooks, World, WorldSpec};

const EPISODES: u32 = 64;

fn main() {
    let world = World::new(WorldSpec::default()).expect("world");
    let spec = CatchTaskSpec::default();
    let task = CatchTask::new(&world, spec.clone(), 0, "bench", "train").expect("task");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");

    let (bare_steps, bare_secs) = pool.install(|| {
        let t = Instant::now();
        let mut steps = 0usize;
        for i in 0..u64::from(EPISODES) {
            let condition = task.condition(i).expect("ω");
            let mut catcher =
                ScriptedCatcher::new(spec.catcher.clone(), spec.rollout.control.clone());
            let record = Episode::new(
                &world,
                &spec.rollout,
                condition,
                rng::stream(0, "bench", "train-dr", i),
            )
            .run(&mut catcher, &mut NoHooks);
            steps += record.steps;
        }
        (steps as f64, t.elapsed().as_secs_f64())
    });

    let run = |epochs: u32| {
        let config = PpoConfig {
            iterations: 1,
            episodes_per_iteration: EPISODES,
            epochs,
            ..PpoConfig::default()
        };
        let mut agent = Agent::new(task.obs_len(), task.act_len(), &config, 0);
        pool.install(|| {
            let t = Instant::now();
            train(&task, &mut agent, &config, (0, "bench"), &|_| {});
            let secs = t.elapsed().as_secs_f64();
            (agent.curve[0].steps as f64, secs)
        })
    };
    let (collect_steps, collect_secs) = run(0);
    let (iter_steps, iter_secs) = run(PpoConfig::default().epochs);

    let rate = |s: f64, t: f64| s / t;
    let bare = rate(bare_steps, bare_secs);
    let collect = rate(collect_steps, collect_secs);
    let iteration = rate(iter_steps, iter_secs);
    println!("{EPISODES} episodes on one thread");
    println!("bare rollout loop (scripted catcher)   {bare:8.0} env steps/s");
    println!(
        "PPO collection (teacher, no update)    {collect:8.0} env steps/s   ratio {:.3}",
        collect / bare
    );
    println!(
        "PPO iteration (collection + 4 epochs)  {iteration:8.0} env steps/s   ratio {:.3}",
        iteration / bare
    );
}
