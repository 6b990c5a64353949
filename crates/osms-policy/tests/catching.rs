//! The teacher's catching task: the residual starts exactly at the scripted prior, and a short
//! teacher training gives the same bytes on a rerun and on 1 or 2 threads.

use osms_core::rng;
use osms_policy::catch::{ActorInputs, CatchTask, CatchTaskSpec, OBS_LEN};
use osms_policy::{Agent, Checkpoints, PpoConfig, PpoState, Task, TaskEpisode, train};
use osms_sim::catcher::ScriptedCatcher;
use osms_sim::{Episode, NoHooks, World, WorldSpec};

fn world() -> World {
    World::new(WorldSpec::default()).expect("the default world builds")
}

#[test]
fn a_zero_residual_reproduces_the_scripted_catcher() {
    let world = world();
    for grasp_channel in [false, true] {
        let spec = CatchTaskSpec {
            grasp_channel,
            ..CatchTaskSpec::default()
        };
        zero_residual_is_the_prior(&world, &spec);
    }
}

/// On every rung of the actor-input ladder the zero residual is the prior that reads the world
/// as the rung's actor does (issue 54).
#[test]
fn a_zero_residual_reproduces_the_rungs_prior() {
    let world = world();
    for (_, spec) in rung_specs() {
        zero_residual_is_the_prior(&world, &spec);
    }
}

/// Every rung with the default task, realised.
fn rung_specs() -> Vec<(ActorInputs, CatchTaskSpec)> {
    [
        ActorInputs::Privileged,
        ActorInputs::NoIdentity,
        ActorInputs::ObservedVelocity,
        ActorInputs::NoContact,
        ActorInputs::Touch,
        ActorInputs::Deployable,
        ActorInputs::Tracked,
    ]
    .into_iter()
    .map(|rung| {
        let spec = CatchTaskSpec {
            actor_inputs: rung,
            ..CatchTaskSpec::default()
        };
        (rung, spec.realised())
    })
    .collect()
}

/// The actor's part of the observation has the rung's length and ends before the critic's
/// privileged part; on the rungs without identity it is the same for two throws that differ in
/// ω's mass alone (at the first step, before contact could tell them apart), while the
/// critic's part is not.
#[test]
fn each_rungs_actor_reads_its_own_inputs_and_the_critic_the_privileged_ones() {
    let world = world();
    for (rung, spec) in rung_specs() {
        let task = CatchTask::new(&world, spec.clone(), 5, "test", "inputs").expect("task");
        assert_eq!(task.actor_obs_len(), rung.obs_len(), "{rung:?}");
        let expected_obs = if rung == ActorInputs::Privileged {
            OBS_LEN
        } else {
            rung.obs_len() + OBS_LEN
        };
        assert_eq!(task.obs_len(), expected_obs, "{rung:?}");
        let first_obs = |mass: Option<f64>| {
            let mut condition = task.condition(0).expect("condition");
            if let Some(m) = mass {
                condition.mass_kg = m;
            }
            let mut episode = osms_policy::catch::CatchEpisode::new(
                &world,
                &spec,
                condition,
                rng::stream(5, "test", "inputs-dr", 0),
            );
            let mut seen = Vec::new();
            let mut steps = 0;
            while steps < 12 {
                let (_, done) = episode.step(&mut |obs| {
                    assert_eq!(obs.len(), expected_obs, "{rung:?}");
                    assert!(obs.iter().all(|v| v.is_finite()), "{rung:?}");
                    if seen.is_empty() {
                        seen = obs.to_vec();
                    }
                    vec![0.0; spec.act_len()]
                });
                steps += 1;
                if done {
                    break;
                }
            }
            seen
        };
        let (light, heavy) = (first_obs(Some(0.04)), first_obs(Some(0.06)));
        let actor = rung.obs_len();
        if rung == ActorInputs::Privileged {
            assert_ne!(
                light[..actor],
                heavy[..actor],
                "the privileged actor reads ω's mass"
            );
        } else {
            assert_eq!(light[..actor], heavy[..actor], "{rung:?} reads ω's mass");
            assert_ne!(
                light[actor..],
                heavy[actor..],
                "{rung:?}: the critic reads ω's mass"
            );
        }
    }
}

fn zero_residual_is_the_prior(world: &World, spec: &CatchTaskSpec) {
    let task = CatchTask::new(world, spec.clone(), 5, "test", "train").expect("task");
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
            world,
            &spec.rollout,
            condition,
            rng::stream(5, "test", "train-dr", index),
        )
        .run(
            &mut ScriptedCatcher::with_perception(
                spec.catcher.clone(),
                spec.rollout.control.clone(),
                spec.actor_inputs.perception(),
            ),
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
        let agent = Agent::new(task.obs_len(), task.act_len(), &config, (1, "test"))
            .expect("a valid agent");
        let mut state = PpoState::new(agent, &config);
        train(&task, &mut state, &config, (1, "test"), &|_| {}, None).expect("trains");
        state.agent
    });
    assert_eq!(agent.curve.len(), 2);
    blake3::hash(&postcard::to_stdvec(&agent).expect("encodes"))
}

/// A training killed after any checkpoint and resumed from it ends with the same bytes as one
/// that ran through; a checkpoint that cannot be stored stops training with its iteration.
#[test]
fn a_teacher_training_resumed_from_any_checkpoint_equals_an_uninterrupted_one() {
    let world = world();
    let task = CatchTask::new(&world, CatchTaskSpec::default(), 2, "test", "train").expect("task");
    let config = PpoConfig {
        iterations: 4,
        episodes_per_iteration: 3,
        hidden: vec![16],
        epochs: 2,
        minibatch: 64,
        ..PpoConfig::default()
    };
    let fresh = || {
        let agent = Agent::new(task.obs_len(), task.act_len(), &config, (2, "test"))
            .expect("a valid agent");
        PpoState::new(agent, &config)
    };
    let saved = std::sync::Mutex::new(Vec::new());
    let save = |s: &PpoState| {
        saved.lock().expect("lock").push(s.clone());
        Ok(())
    };
    let mut through = fresh();
    let every = Checkpoints {
        every: 1,
        save: &save,
    };
    train(
        &task,
        &mut through,
        &config,
        (2, "test"),
        &|_| {},
        Some(every),
    )
    .expect("trains");
    let saved = saved.into_inner().expect("lock");
    // After iterations 1, 2 and 3; none after the last.
    assert_eq!(
        saved.iter().map(PpoState::done).collect::<Vec<_>>(),
        [1, 2, 3]
    );
    let bytes = |s: &PpoState| postcard::to_stdvec(&s.agent).expect("encodes");
    for checkpoint in &saved {
        let mut resumed: PpoState =
            postcard::from_bytes(&postcard::to_stdvec(checkpoint).expect("encodes"))
                .expect("decodes");
        let ran = std::sync::Mutex::new(Vec::new());
        train(
            &task,
            &mut resumed,
            &config,
            (2, "test"),
            &|s| ran.lock().expect("lock").push(s.iteration),
            None,
        )
        .expect("resumes");
        assert_eq!(
            ran.into_inner().expect("lock"),
            (checkpoint.done()..4).collect::<Vec<_>>(),
            "only the iterations after the checkpoint run"
        );
        assert_eq!(
            bytes(&resumed),
            bytes(&through),
            "resumed after {}",
            checkpoint.done()
        );
    }
    // Without the optimisers' moments the resumed agent differs: the checkpoint must hold them.
    let mut forgetful = PpoState::new(saved[0].agent.clone(), &config);
    let shorter = PpoConfig {
        iterations: 3,
        ..config.clone()
    };
    train(&task, &mut forgetful, &shorter, (2, "test"), &|_| {}, None).expect("trains");
    assert_ne!(bytes(&forgetful), bytes(&through));

    let refuse = |_: &PpoState| Err("no space left".to_string());
    let every_two = Checkpoints {
        every: 2,
        save: &refuse,
    };
    let err = train(
        &task,
        &mut fresh(),
        &config,
        (2, "test"),
        &|_| {},
        Some(every_two),
    )
    .expect_err("a failed checkpoint stops training");
    assert!(
        matches!(err, osms_policy::Error::Checkpoint { done: 2, .. }),
        "{err}"
    );
}

#[test]
fn a_short_teacher_training_is_identical_on_rerun_and_across_thread_counts() {
    let one = short_training(1);
    assert_eq!(one, short_training(1), "rerun");
    assert_eq!(one, short_training(2), "1 vs 2 threads");
}

/// The grasp channel at +1 closes the open hand at the first step (the prior keeps it open
/// until the object is near); at −1 a closed prior's hand would open the same way.
#[test]
fn the_grasp_channel_moves_the_hand_from_open_to_closed() {
    use osms_sim::control::hold_action;
    let world = world();
    let spec = CatchTaskSpec {
        grasp_channel: true,
        ..CatchTaskSpec::default()
    };
    let task = CatchTask::new(&world, spec.clone(), 5, "test", "grasp").expect("task");
    let first_hand = |c: f32| {
        let mut episode = task.start(0).expect("condition");
        let mut act = vec![0.0f32; spec.act_len()];
        act[spec.act_len() - 1] = c;
        episode.step(&mut |_| act.clone());
        episode.episode().record().intended[osms_sim::N_ARM..osms_sim::N_ACTION].to_vec()
    };
    let as_f32 = |a: osms_sim::Action| {
        a[osms_sim::N_ARM..]
            .iter()
            .map(|x| *x as f32)
            .collect::<Vec<_>>()
    };
    assert_eq!(
        first_hand(0.0),
        as_f32(hold_action(&spec.catcher.open_hand_rad))
    );
    assert_eq!(
        first_hand(1.0),
        as_f32(hold_action(&spec.catcher.closed_hand_rad))
    );
}

/// An untrained agent whose actor is not zeroed, so the residual and the follow-through
/// channel both act.
fn lively_agent(task: &CatchTask<'_>) -> Agent {
    let config = PpoConfig {
        hidden: vec![32],
        zero_init_actor_output: false,
        ..PpoConfig::default()
    };
    Agent::new(task.obs_len(), task.act_len(), &config, (2, "test")).expect("a valid agent")
}

#[test]
fn a_restored_catching_episode_continues_bit_identically_under_the_teacher() {
    let world = world();
    let mut spec = CatchTaskSpec::default();
    // Every source of randomness on: the snapshot carries the generator too.
    spec.rollout.dr = osms_sim::control::DrSpec::paper();
    let task = CatchTask::new(&world, spec, 4, "test", "branch").expect("task");
    let agent = lively_agent(&task);
    let mut teacher = |obs: &[f32]| agent.act_deterministic(obs);
    let mut wander = |_: &[f32]| vec![0.6f32; 8];

    // Find an episode with a first contact, and its rewards when run straight through.
    let (index, rewards, full) = (0..20)
        .find_map(|index| {
            let mut e = task.start(index).expect("condition");
            let mut rewards = Vec::new();
            loop {
                let (r, done) = e.step(&mut teacher);
                rewards.push(r.to_bits());
                if done {
                    break;
                }
            }
            e.episode().first_contact()?;
            Some((index, rewards, e.run(&mut teacher)))
        })
        .expect("some episode touches the hand");
    let contact_step = full.metrics.event_step;
    assert!(contact_step >= 3, "contact at step {contact_step}");

    // Branch before the contact (the prior has not closed the hand yet) and right after it
    // (the follow-through direction, the phase input and the reward bookkeeping are set).
    for at in [contact_step - 2, contact_step + 1] {
        let mut e = task.start(index).expect("condition");
        let mut got = Vec::new();
        for _ in 0..at {
            got.push(e.step(&mut teacher).0.to_bits());
        }
        let snap = e.snapshot();
        for _ in 0..6 {
            e.step(&mut wander);
        }
        e.restore(&snap);
        loop {
            let (r, done) = e.step(&mut teacher);
            got.push(r.to_bits());
            if done {
                break;
            }
        }
        assert_eq!(got, rewards, "rewards after a restore at step {at}");
        assert_eq!(
            e.run(&mut teacher),
            full,
            "record after a restore at step {at}"
        );
    }
}

#[test]
fn network_initialisation_streams_include_the_stage_name() {
    let world = world();
    let task = CatchTask::new(&world, CatchTaskSpec::default(), 0, "t", "train").expect("task");
    let config = PpoConfig {
        hidden: vec![16],
        ..PpoConfig::default()
    };
    let agent = |stage: &str| {
        Agent::new(task.obs_len(), task.act_len(), &config, (0, stage)).expect("a valid agent")
    };
    let (a, b) = (agent("teacher"), agent("teacher_catch_only"));
    assert_ne!(a.actor.layers[0].w.data, b.actor.layers[0].w.data);
    assert_ne!(a.critic.layers[0].w.data, b.critic.layers[0].w.data);
    assert_eq!(a, agent("teacher"));
}

#[test]
fn a_condition_that_cannot_be_drawn_is_an_error_not_condition_zero() {
    let world = world();
    let mut task = CatchTask::new(&world, CatchTaskSpec::default(), 0, "t", "train").expect("task");
    // Throws far too slow to reach the palm from any launch point.
    task.spec.conditions.speed_mps = [0.1, 0.2];
    let err = task.start(3).err().expect("an error");
    assert!(
        matches!(err, osms_sim::SimError::NoFeasibleLaunch { .. }),
        "{err}"
    );
    let config = PpoConfig {
        iterations: 1,
        episodes_per_iteration: 2,
        hidden: vec![8],
        ..PpoConfig::default()
    };
    let agent =
        Agent::new(task.obs_len(), task.act_len(), &config, (0, "t")).expect("a valid agent");
    let err = train(
        &task,
        &mut PpoState::new(agent, &config),
        &config,
        (0, "t"),
        &|_| {},
        None,
    )
    .expect_err("training stops");
    assert!(
        matches!(
            err,
            osms_policy::Error::EpisodeStart {
                iteration: 0,
                episode: 0,
                ..
            }
        ),
        "{err}"
    );
    assert!(
        err.to_string().contains("no launch reaches the palm"),
        "{err}"
    );
}

/// The teacher reads the object through the rollout's observation delay (paper 5: delays are
/// randomised during teacher training): two rollouts that differ only in that delay give the
/// teacher other inputs, so other actions, from the step the delay first hides.
#[test]
fn the_teachers_action_changes_when_only_the_observation_delay_changes() {
    use osms_policy::catch::TeacherQuery;
    use osms_sim::control::DrDraw;
    use osms_sim::{Action, Policy, PolicyView};

    struct Recording<'q, 'a> {
        query: &'q mut TeacherQuery<'a>,
        actions: Vec<Action>,
    }
    impl Policy for Recording<'_, '_> {
        fn act(&mut self, view: &PolicyView<'_>) -> Action {
            let a = self.query.act(view);
            self.actions.push(a);
            a
        }
    }

    let world = world();
    let spec = CatchTaskSpec::default();
    let task = CatchTask::new(&world, spec.clone(), 4, "test", "delay").expect("task");
    let agent = lively_agent(&task);
    let condition = task.condition(0).expect("condition");
    let actions = |delay: u32| -> Vec<Action> {
        let draw = DrDraw {
            observation_delay_steps: delay,
            ..DrDraw::none()
        };
        let mut episode = Episode::with_draw(
            &world,
            &spec.rollout,
            condition.clone(),
            draw,
            rng::stream(4, "test", "delay-dr", 0),
        );
        let mut query = TeacherQuery::new(&agent, &spec);
        let mut policy = Recording {
            query: &mut query,
            actions: Vec::new(),
        };
        for _ in 0..4 {
            assert!(
                episode.step(&mut policy, &mut NoHooks),
                "the episode ended early"
            );
            let phase = *episode.record().phase.last().expect("a recorded step");
            policy.query.observe_phase(phase);
        }
        policy.actions
    };
    let (now, late) = (actions(0), actions(1));
    assert_eq!(
        now[0], late[0],
        "at the first step both delays see the same (initial) state"
    );
    for k in 1..now.len() {
        assert_ne!(now[k], late[k], "step {k}: the delay changed nothing");
    }
    assert_eq!(actions(1), late, "the same delay gives the same actions");
}

/// The success term pays `reward.success` once, at the last step of a rollout that meets every
/// criterion, and nothing anywhere else: not for a completed catch that fails an impact
/// criterion. The criteria are loosened (ℓ_max, v_rel; δ_f halved to 40 N) so that the scripted
/// prior's rollouts under a zero residual come in all three kinds.
#[test]
fn the_success_term_is_paid_once_at_the_end_of_a_successful_rollout() {
    let world = world();
    let mut loose = CatchTaskSpec::default();
    loose.rollout.success.min_follow_through_m = 0.0;
    loose.rollout.success.max_force_n = 40.0;
    loose.rollout.success.max_contact_speed_mps = 1e9;
    let rewards = |success: f32, index: u64| {
        let mut spec = loose.clone();
        spec.reward.success = success;
        let task = CatchTask::new(&world, spec, 5, "test", "train").expect("task");
        let mut episode = task.start(index).expect("condition");
        let mut out = Vec::new();
        loop {
            let (r, done) = episode.step(&mut |_| vec![0.0; 24]);
            out.push(r);
            if done {
                break;
            }
        }
        let stats = episode.finish();
        (out, stats.success, stats.completion)
    };
    // Incomplete, completed but failing f_max, successful.
    let mut seen = [false; 3];
    for index in 0..12 {
        let (paid, succeeded, completed) = rewards(3.0, index);
        let (unpaid, ..) = rewards(0.0, index);
        seen[usize::from(completed) + usize::from(succeeded)] = true;
        let last = paid.len() - 1;
        assert_eq!(paid[..last], unpaid[..last], "episode {index}");
        let bonus = paid[last] - unpaid[last];
        let want = if succeeded { 3.0 } else { 0.0 };
        assert!((bonus - want).abs() < 1e-4, "episode {index}: {bonus}");
    }
    assert_eq!(
        seen,
        [true, true, true],
        "every kind of outcome among the episodes"
    );
}

/// DART's arm noise moves only the executed arm channels, keeps the teacher's intended actions
/// as the record's labels (the same as a noiseless rollout's until the states part), and
/// draws from its own stream: the same stream gives the same record.
#[test]
fn dart_arm_noise_perturbs_executed_arm_channels_and_keeps_intended_labels() {
    use osms_policy::catch::ArmNoise;
    use osms_sim::{N_ACTION, N_ARM};
    let world = world();
    let spec = CatchTaskSpec::default();
    assert!(
        spec.rollout.dr.is_off(),
        "executed = intended + noise needs DR off"
    );
    let task = CatchTask::new(&world, spec.clone(), 3, "test", "dart").expect("task");
    let agent = lively_agent(&task);
    let condition = task.condition(0).expect("condition");
    let run = |sigma: f64| {
        osms_policy::catch::CatchEpisode::new(
            &world,
            &spec,
            condition.clone(),
            rng::stream(3, "test", "dart-dr", 0),
        )
        .run_with_hooks(
            &mut |obs| agent.act_deterministic(obs),
            &mut ArmNoise {
                sigma,
                rng: rng::stream(3, "test", "dart-noise", 0),
            },
        )
    };
    let clean = run(0.0);
    let noisy = run(0.1);
    assert_eq!(noisy, run(0.1), "same stream, same record");
    // Step 0 acts on the same state, so the labels agree there; the executed arm channels do not.
    assert_eq!(noisy.intended[..N_ACTION], clean.intended[..N_ACTION]);
    for k in 0..noisy.steps.min(clean.steps) {
        let (i, e) = (
            &noisy.intended[k * N_ACTION..(k + 1) * N_ACTION],
            &noisy.executed[k * N_ACTION..(k + 1) * N_ACTION],
        );
        assert!(e.iter().all(|a| a.abs() <= 1.0), "step {k}: {e:?}");
        assert_eq!(e[N_ARM..], i[N_ARM..], "step {k}: hand channels untouched");
    }
    let moved = (0..noisy.steps)
        .filter(|k| {
            noisy.executed[k * N_ACTION..k * N_ACTION + N_ARM]
                != noisy.intended[k * N_ACTION..k * N_ACTION + N_ARM]
        })
        .count();
    assert!(
        moved * 10 >= noisy.steps * 9,
        "arm noise on {moved} of {} steps",
        noisy.steps
    );
    assert_ne!(noisy.executed, clean.executed);
}

/// The smoothness term (issue 54) costs `residual_rate` per second times the squared change of
/// the policy's action channels since the last step, and nothing at the first step: the same
/// actions with and without it give the same rollout and rewards that differ by exactly that.
#[test]
fn the_smoothness_term_costs_the_squared_change_of_the_policys_action() {
    let world = world();
    let spec = CatchTaskSpec::default();
    let dt = world.control_period_secs();
    let rewards = |rate: f32| {
        let mut spec = spec.clone();
        spec.reward.residual_rate = rate;
        let task = CatchTask::new(&world, spec.clone(), 5, "test", "smooth").expect("task");
        let mut episode = task.start(0).expect("condition");
        let mut out = Vec::new();
        let mut k = 0usize;
        loop {
            // Channel 0 alternates 0.0, 0.2, 0.0, …: a change of 0.2 at every step after the
            // first; the rest stays at 0.
            let (r, done) = episode.step(&mut |_| {
                let mut a = vec![0.0; spec.act_len()];
                a[0] = if k % 2 == 1 { 0.2 } else { 0.0 };
                a
            });
            k += 1;
            out.push(f64::from(r));
            if done {
                break;
            }
        }
        out
    };
    let (smooth, free) = (rewards(3.0), rewards(0.0));
    assert_eq!(smooth.len(), free.len());
    assert!(smooth.len() > 2);
    for (k, (s, f)) in smooth.iter().zip(&free).enumerate() {
        let want = if k == 0 { 0.0 } else { 3.0 * 0.04 * dt };
        assert!((f - s - want).abs() < 1e-5, "step {k}: {}", f - s);
    }
}
