//! The teacher's catching task: the residual starts exactly at the scripted prior, and a short
//! teacher training gives the same bytes on a rerun and on 1 or 2 threads.

use osms_make::rng;
use osms_policy::catch::{CatchTask, CatchTaskSpec};
use osms_policy::{Agent, PpoConfig, Task, TaskEpisode, train};
use osms_sim::catcher::ScriptedCatcher;
use osms_sim::{Episode, NoHooks, World, WorldSpec};

fn world() -> World {
    World::new(WorldSpec::default()).expect("the default world builds")
}

#[test]
fn a_zero_residual_reproduces_the_scripted_catcher() {
    let world = world();
    let spec = CatchTaskSpec::default();
    let task = CatchTask::new(&world, spec.clone(), 5, "test", "train").expect("task");
    for index in 0..3 {
        let mut episode = task.start(index).expect("condition");
        let mut total = 0.0f32;
        loop {
            let (r, done) = episode.step(&mut |_| vec![0.0; 24]);
            total += r;
            if done {
                break;
            }
        }
        let ours = episode.finish();
        let condition = task.condition(index).expect("condition");
        let prior = Episode::new(
            &world,
            &spec.rollout,
            condition,
            rng::stream(5, "test", "train-dr", index),
        )
        .run(
            &mut ScriptedCatcher::new(spec.catcher.clone(), spec.rollout.control.clone()),
            &mut NoHooks,
        );
        assert_eq!(
            ours.completion,
            prior.outcome.completion(),
            "episode {index}"
        );
        assert_eq!(ours.success, prior.outcome.success(), "episode {index}");
        assert_eq!(
            ours.f_max_n,
            prior
                .outcome
                .completion()
                .then_some(prior.metrics.max_force_n),
            "episode {index}"
        );
        assert!(total.is_finite());
    }
}

fn short_training(threads: usize) -> blake3::Hash {
    let world = world();
    let task = CatchTask::new(&world, CatchTaskSpec::default(), 1, "test", "train").expect("task");
    let config = PpoConfig {
        iterations: 2,
        episodes_per_iteration: 3,
        hidden: vec![16],
        epochs: 2,
        minibatch: 64,
        ..PpoConfig::default()
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("pool");
    let agent = pool.install(|| {
        let mut agent = Agent::new(task.obs_len(), task.act_len(), &config, (1, "test"));
        train(&task, &mut agent, &config, (1, "test"), &|_| {}).expect("trains");
        agent
    });
    assert_eq!(agent.curve.len(), 2);
    blake3::hash(&postcard::to_stdvec(&agent).expect("encodes"))
}

#[test]
fn a_short_teacher_training_is_identical_on_rerun_and_across_thread_counts() {
    let one = short_training(1);
    assert_eq!(one, short_training(1), "rerun");
    assert_eq!(one, short_training(2), "1 vs 2 threads");
}
