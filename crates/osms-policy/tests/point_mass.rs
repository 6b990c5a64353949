//! PPO on a 1-D point mass with a known optimal policy: it must close most of the gap between
//! the initial policy and the optimum within a fixed budget, and train to the same bytes on a
//! rerun and on 1 or 2 threads.

use osms_core::rng;
use osms_policy::{Agent, EpisodeStats, PpoConfig, PpoState, Task, TaskEpisode, train};

/// x' = x + 0.1·a, a ∈ [-1, 1] (a velocity command), reward −|x'| for 20 steps.
struct PointMass;

struct Run {
    x: f32,
    steps: u32,
}

const STEPS: u32 = 20;

impl PointMass {
    fn x0(index: u64) -> f32 {
        rng::uniform(&mut rng::stream(7, "point-mass", "x0", index), -1.0, 1.0) as f32
    }
}

impl Task for PointMass {
    type Episode<'a> = Run;
    type Error = std::convert::Infallible;
    fn obs_len(&self) -> usize {
        1
    }
    fn act_len(&self) -> usize {
        1
    }
    fn start(&self, index: u64) -> Result<Run, Self::Error> {
        Ok(Run {
            x: Self::x0(index),
            steps: 0,
        })
    }
}

impl TaskEpisode for Run {
    fn step(&mut self, act: &mut dyn FnMut(&[f32]) -> Vec<f32>) -> (f32, bool) {
        let action = act(&[self.x]);
        self.x += 0.1 * action[0];
        self.steps += 1;
        (-self.x.abs(), self.steps == STEPS)
    }
    fn finish(self) -> EpisodeStats {
        EpisodeStats {
            success: self.x.abs() < 0.05,
            completion: self.x.abs() < 0.05,
            f_max_n: None,
        }
    }
}

/// Mean return of `policy` over held-out episodes (indices far from training's).
fn evaluate(policy: &dyn Fn(f32) -> f32) -> f64 {
    let episodes = 200;
    let mut total = 0.0f64;
    for i in 0..episodes {
        let mut run = PointMass.start(1_000_000 + i).expect("starts");
        loop {
            let (r, done) = run.step(&mut |obs| vec![policy(obs[0]).clamp(-1.0, 1.0)]);
            total += f64::from(r);
            if done {
                break;
            }
        }
    }
    total / episodes as f64
}

fn config() -> PpoConfig {
    PpoConfig {
        iterations: 30,
        episodes_per_iteration: 32,
        hidden: vec![32, 32],
        epochs: 4,
        minibatch: 128,
        lr: 1e-3,
        lr_final_fraction: 1.0,
        init_log_std: -0.5,
        ..PpoConfig::default()
    }
}

fn trained(threads: usize) -> Agent {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("pool");
    pool.install(|| train_with(&config()))
}

/// A fresh agent trained with `config`.
fn train_with(config: &PpoConfig) -> Agent {
    let agent = Agent::new(1, 1, config, (3, "test")).expect("a valid agent");
    let mut state = PpoState::new(agent, config);
    train(
        &PointMass,
        &mut state,
        config,
        (3, "point-mass"),
        &|_| {},
        None,
    )
    .expect("trains");
    state.agent
}

fn hash(agent: &Agent) -> blake3::Hash {
    blake3::hash(&postcard::to_stdvec(agent).expect("encodes"))
}

#[test]
fn ppo_closes_most_of_the_gap_to_the_optimum() {
    let initial = evaluate(&|_| 0.0);
    let optimum = evaluate(&|x| -x / 0.1);
    let agent = trained(2);
    let learned = evaluate(&|x| agent.act_deterministic(&[x])[0]);
    let closed = (learned - initial) / (optimum - initial);
    assert!(
        closed > 0.8,
        "initial {initial:.3}, optimum {optimum:.3}, learned {learned:.3} ({:.0} % of the gap)",
        closed * 100.0
    );
    let first = &agent.curve[0];
    let last = agent.curve.last().expect("a curve");
    assert!(last.mean_return > first.mean_return, "{first:?} → {last:?}");
}

#[test]
fn training_is_identical_on_rerun_and_across_thread_counts() {
    let one = trained(1);
    assert_eq!(hash(&one), hash(&trained(1)), "rerun");
    assert_eq!(hash(&one), hash(&trained(2)), "1 vs 2 threads");
}

/// `lr_final_fraction` 0: the rate falls to zero at the last iteration, which therefore moves
/// no weight, while the first iteration trains at the full rate (the same weights as a
/// one-iteration run at a constant rate).
#[test]
fn a_rate_falling_to_zero_leaves_the_last_iteration_without_an_update() {
    let run = |iterations: u32, lr_final_fraction: f32| {
        let config = PpoConfig {
            iterations,
            lr_final_fraction,
            ..config()
        };
        train_with(&config)
    };
    let weights = |a: &Agent| (a.actor.clone(), a.critic.clone(), a.log_std.clone());
    let once = run(1, 1.0);
    let twice = run(2, 0.0);
    assert_eq!(weights(&twice), weights(&once));
    let constant = run(2, 1.0);
    assert_ne!(
        weights(&constant),
        weights(&once),
        "a constant rate does move"
    );
}

/// The KL early stop: a target no epoch can stay under leaves one epoch per iteration (the
/// same weights as a one-epoch run), one no epoch can reach leaves training as without a stop.
#[test]
fn a_kl_target_stops_an_iterations_epochs_early() {
    let run = |epochs: u32, target_kl: Option<f32>| {
        let config = PpoConfig {
            iterations: 1,
            epochs,
            target_kl,
            ..config()
        };
        train_with(&config)
    };
    let all = hash(&run(4, None));
    let one = hash(&run(1, None));
    assert_ne!(one, all, "more epochs do move");
    assert_eq!(hash(&run(4, Some(1e-12))), one);
    assert_eq!(hash(&run(4, Some(1e9))), all);
}
