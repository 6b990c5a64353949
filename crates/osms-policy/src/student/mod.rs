//! Deployable flow-matching students (paper section 5, "Policies and search"): the IL students
//! π̄ behind the action-error model and, later, the final students π_θ.
//!
//! - **Observation** o_n: the last `history` deployable frames, oldest first. A frame is the
//!   robot's proprioception (arm and hand q, q̇), the object's *observed* position (delayed and
//!   noisy under DR; no velocity, no contacts, nothing privileged) and the previous executed
//!   action ([`osms_sim::policy::DEPLOYABLE_LEN`] values; `previous_actions = false` drops
//!   the action). Before `history` frames exist, the oldest one is repeated, as the rollout's
//!   history holds it. Optional features of the current step follow the frames: the palm's
//!   position and velocity and the observed object's offset from the palm (`palm`: forward
//!   kinematics of the measured joint state, so deployable), the observed object position's
//!   frame-to-frame differences (`object_differences`: deployable), and the object's true velocity
//!   (`oracle_object_velocity`: privileged, a diagnostic of whether information is what the
//!   student lacks, never a deployable student).
//! - **Action chunk**: the labels of steps n … n + chunk − 1, all 24 channels. A chunk that
//!   runs past the rollout's end repeats its last action and masks those steps out of the
//!   loss, so the network is never asked to predict what happens after termination.
//! - **Policy**: at every control step draw noise from the policy's own stream, integrate the
//!   velocity field with `euler_steps` Euler steps, execute the chunk's first action (clamped
//!   to [−1, 1]) and replan at the next step (the paper's). [`ChunkExecution`] runs other
//!   execution horizons and ACT's temporal ensemble instead (issue 68, beyond the paper).
//!
//! Observations and actions are standardised per feature with statistics of the training
//! demonstrations, frozen into the artifact.

mod act;
mod chunks;
mod demo;
mod params;
mod rollouts;
mod train;

pub use chunks::{ChunkExecution, ChunkRunner, StudentPolicy};
pub use demo::{ARM_STEP_RAD, ActionNorm, DEMO_STATE_LEN, Demo, NOMINAL_CONTROL_PERIOD_SECS};
pub use params::{StudentNetwork, StudentParams};
pub use rollouts::{
    LOCKSTEP_SLOTS, PairedRollout, ROLLOUT_BATCH, paired_rollout, rollout, rollouts,
    rollouts_executed, rollouts_in_slots,
};
pub use train::{Student, StudentCurvePoint, StudentState};

#[cfg(test)]
mod tests {
    use osms_core::rng;
    use osms_sim::control::ArmAction;
    use osms_sim::policy::DEPLOYABLE_LEN;
    use osms_sim::{Action, N_ACTION, N_ARM};

    use super::train::Sampler;
    use super::*;
    use crate::Error;
    use crate::checkpoint::Checkpoints;
    use crate::flow::UNetSpec;

    /// A demonstration whose frame n holds n + 1 in every entry and whose action at n holds
    /// labels derived from n, so each value names where it came from.
    fn numbered(steps: usize) -> Demo {
        Demo {
            steps,
            deployable: (0..steps)
                .flat_map(|n| std::iter::repeat_n((n + 1) as f32, DEPLOYABLE_LEN))
                .collect(),
            state: (0..steps)
                .flat_map(|n| (0..DEMO_STATE_LEN).map(move |c| (n * 10 + c) as f32))
                .collect(),
            phase: (0..steps).map(|n| (n % 5) as u8).collect(),
            actions: (0..steps)
                .flat_map(|n| (0..N_ACTION).map(move |k| (n * 100 + k) as f32 / 1e4))
                .collect(),
        }
    }

    #[test]
    fn observations_repeat_the_oldest_frame_and_chunks_pad_with_a_mask() {
        let d = numbered(5);
        let frames = |n: usize, h: usize| {
            let mut out = Vec::new();
            let p = StudentParams {
                history: h,
                palm: false,
                object_differences: false,
                ..StudentParams::default()
            };
            d.observation(n, &p, &mut out);
            out.chunks(DEPLOYABLE_LEN).map(|f| f[0]).collect::<Vec<_>>()
        };
        assert_eq!(frames(0, 3), [1.0, 1.0, 1.0]);
        assert_eq!(frames(1, 3), [1.0, 1.0, 2.0]);
        assert_eq!(frames(4, 3), [3.0, 4.0, 5.0]);
        assert_eq!(frames(4, 1), [5.0]);

        let (mut labels, mut mask) = (Vec::new(), Vec::new());
        d.chunk(3, 4, &mut labels, &mut mask);
        let first = |j: usize| labels[j * N_ACTION];
        assert_eq!(
            [first(0), first(1), first(2), first(3)],
            [0.03, 0.04, 0.04, 0.04]
        );
        let m: Vec<f32> = mask.iter().step_by(N_ACTION).copied().collect();
        assert_eq!(m, [1.0, 1.0, 0.0, 0.0]);
        assert_eq!(mask.len(), 4 * N_ACTION);
    }

    #[test]
    fn optional_inputs_come_from_the_current_step_and_previous_actions_can_be_dropped() {
        let d = numbered(4);
        let p = StudentParams {
            history: 2,
            previous_actions: false,
            palm: true,
            object_differences: true,
            oracle_object_velocity: true,
            arm_target: true,
            ..StudentParams::default()
        };
        let mut out = Vec::new();
        d.observation(2, &p, &mut out);
        assert_eq!(out.len(), p.obs_len());
        assert_eq!(p.frame_len(), DEPLOYABLE_LEN - N_ACTION);
        // Frames 1 and 2 without their previous actions, then step 2's features: palm
        // position (20, 21, 22), velocity (23, 24, 25), object − palm (3 − 20, ...), the
        // object's change from frame 1 to 2 (1, 1, 1), its velocity (26, 27, 28) and the arm's
        // targets (29 … 35).
        let frames = 2 * p.frame_len();
        assert!(out[..p.frame_len()].iter().all(|&v| v == 2.0));
        assert!(out[p.frame_len()..frames].iter().all(|&v| v == 3.0));
        assert_eq!(
            out[frames..],
            [
                20.0, 21.0, 22.0, 23.0, 24.0, 25.0, -17.0, -18.0, -19.0, 1.0, 1.0, 1.0, 26.0, 27.0,
                28.0, 29.0, 30.0, 31.0, 32.0, 33.0, 34.0, 35.0
            ]
        );
    }

    #[test]
    fn the_nominal_control_period_is_the_default_worlds() {
        let w = osms_sim::WorldSpec::default();
        assert_eq!(
            NOMINAL_CONTROL_PERIOD_SECS,
            w.timestep_secs * f64::from(w.substeps)
        );
    }

    /// Weighted draws follow the phase weights: with phases 0..4 cycling over the steps and
    /// weights (1, 0, 8, 1, 0), phase 2 takes 80 % of the draws and phases 1 and 4 none.
    #[test]
    fn phase_weights_set_how_often_each_phase_is_drawn() {
        let demos = [numbered(50), numbered(30)];
        let train: Vec<&Demo> = demos.iter().collect();
        let samples: Vec<(usize, usize)> = train
            .iter()
            .enumerate()
            .flat_map(|(r, d)| (0..d.steps).map(move |n| (r, n)))
            .collect();
        let p = StudentParams {
            phase_weights: [1.0, 0.0, 8.0, 1.0, 0.0],
            ..StudentParams::default()
        };
        let sampler = Sampler::new(&p, &samples, &train).expect("weights");
        let mut r = rng::stream(0, "test", "draws", 0);
        let mut counts = [0usize; 5];
        let draws = 20_000;
        for _ in 0..draws {
            let (d, n) = samples[sampler.draw(&mut r)];
            counts[usize::from(train[d].phase[n])] += 1;
        }
        assert_eq!((counts[1], counts[4]), (0, 0), "{counts:?}");
        let share = counts[2] as f64 / draws as f64;
        assert!((share - 0.8).abs() < 0.015, "{counts:?}");
        let none = StudentParams {
            phase_weights: [0.0, 1.0, 0.0, 0.0, 0.0],
            ..StudentParams::default()
        };
        let one_phase: Vec<&Demo> = vec![&demos[0]];
        let zero_phase: Vec<(usize, usize)> =
            (0..50).filter(|n| n % 5 == 0).map(|n| (0, n)).collect();
        assert!(Sampler::new(&none, &zero_phase, &one_phase).is_err());
    }

    #[test]
    fn malformed_demos_and_params_are_refused() {
        let mut d = numbered(3);
        d.actions.pop();
        let err = Student::train(&[d], &StudentParams::default(), (0, "t"), &|| {})
            .expect_err("short actions");
        assert!(err.to_string().contains("demonstration 0"), "{err}");
        let bad = StudentParams {
            time_embedding: 7,
            ..StudentParams::default()
        };
        assert!(Student::train(&[numbered(3)], &bad, (0, "t"), &|| {}).is_err());
        let bad = StudentParams {
            ema_decay: 1.0,
            ..StudentParams::default()
        };
        let err = Student::train(&[numbered(3)], &bad, (0, "t"), &|| {}).expect_err("decay 1");
        assert!(err.to_string().contains("ema_decay"), "{err}");
        let none = Student::train(&[], &StudentParams::default(), (0, "t"), &|| {});
        assert!(matches!(none, Err(Error::NoDemos { .. })));
    }

    /// Demonstrations whose every action channel is a fixed function of the current frame's
    /// one varying feature:
    /// a student learns it (its sampled actions land near the labels, far closer than the
    /// labels' spread), and training is a function of its seed.
    #[test]
    fn students_learn_a_deterministic_policy_reproducibly() {
        learns_a_deterministic_policy(0.0, false, StudentNetwork::Mlp);
    }

    /// With absolute-target labels the student predicts where the arm's target goes and
    /// executes the increment from the current target: it still reproduces the
    /// demonstrator's increments, whatever target each step starts from.
    #[test]
    fn students_with_target_labels_execute_the_demonstrated_increments() {
        learns_a_deterministic_policy(0.0, true, StudentNetwork::Mlp);
    }

    /// The arm step the target labels assume is the default control spec's.
    #[test]
    fn target_labels_use_the_default_arm_step_and_the_controllers_integration() {
        let control = osms_sim::control::ControlSpec::default();
        assert_eq!(ARM_STEP_RAD, control.arm_max_delta_rad);
        let mut d = numbered(3);
        for n in 0..3 {
            d.state[n * DEMO_STATE_LEN + 9..][..N_ARM]
                .copy_from_slice(&[0.1, -0.2, 0.3, 1.0, 0.0, 0.5, 3.1]);
            d.actions[n * N_ACTION..][..N_ARM]
                .copy_from_slice(&[0.5, -1.0, 0.0, 1.0, 0.2, -0.4, 1.0]);
        }
        let relabelled = d.with_target_labels();
        let previous: [f64; N_ACTION] = std::array::from_fn(|i| {
            if i < N_ARM {
                f64::from(d.state[9 + i])
            } else {
                0.0
            }
        });
        let action: Action = std::array::from_fn(|i| f64::from(d.actions[i]));
        let integrated =
            osms_sim::control::targets(&control, ArmAction::Increment, &previous, &action);
        for (i, t) in integrated[..N_ARM].iter().enumerate() {
            assert_eq!(relabelled.actions[i], *t as f32, "joint {i}");
        }
        assert_eq!(
            relabelled.actions[N_ARM..N_ACTION],
            d.actions[N_ARM..N_ACTION]
        );
        assert!(
            StudentParams {
                target_labels: true,
                ..StudentParams::default()
            }
            .check()
            .is_err_and(|e| e.to_string().contains("arm_target")),
            "target labels without the current target"
        );
    }

    /// The moving average of the weights is the trained network, and it learns as well.
    /// The U-Net backbone (one level over a one-step chunk) learns the same policy.
    #[test]
    fn unet_students_learn_a_deterministic_policy_reproducibly() {
        learns_a_deterministic_policy(0.0, false, StudentNetwork::Unet);
    }

    #[test]
    fn students_with_a_moving_average_of_weights_learn_too() {
        learns_a_deterministic_policy(0.99, false, StudentNetwork::Mlp);
    }

    /// Chunk c of a runner's test holds 100·c + j + k/100 at step j, channel k.
    fn numbered_chunk(c: usize, chunk: usize) -> Vec<f64> {
        (0..chunk * N_ACTION)
            .map(|i| 100.0 * c as f64 + (i / N_ACTION) as f64 + (i % N_ACTION) as f64 / 100.0)
            .collect()
    }

    fn run(execution: ChunkExecution, steps: usize) -> (Vec<bool>, Vec<Vec<f64>>) {
        let params = StudentParams {
            chunk: 4,
            ..StudentParams::default()
        };
        execution.check_for(&params).expect("valid");
        let mut runner = ChunkRunner::new(execution, &params);
        let (mut sampled, mut actions) = (Vec::new(), Vec::new());
        let mut c = 0;
        for _ in 0..steps {
            sampled.push(runner.samples());
            if runner.samples() {
                runner.push(numbered_chunk(c, 4));
                c += 1;
            }
            actions.push(runner.next());
        }
        (sampled, actions)
    }

    #[test]
    fn a_horizon_of_h_runs_h_actions_of_each_chunk_open_loop() {
        for h in [1, 2, 3, 4] {
            let (sampled, actions) = run(
                ChunkExecution {
                    horizon: h,
                    ensemble: None,
                },
                9,
            );
            for (n, (s, a)) in sampled.iter().zip(&actions).enumerate() {
                assert_eq!(*s, n % h == 0, "h = {h}, step {n}");
                // Chunk n / h, its action n mod h.
                let want = 100.0 * (n / h) as f64 + (n % h) as f64;
                assert_eq!(a[0], want, "h = {h}, step {n}");
                assert_eq!(a[5], want + 0.05, "h = {h}, step {n}");
            }
        }
    }

    #[test]
    fn the_temporal_ensemble_weights_older_predictions_by_exp_minus_m_i() {
        let m = 0.5;
        let (sampled, actions) = run(
            ChunkExecution {
                horizon: 1,
                ensemble: Some(m),
            },
            7,
        );
        assert!(sampled.iter().all(|&s| s), "a chunk every step");
        for (n, a) in actions.iter().enumerate() {
            // Chunks max(0, n − 3) ..= n predict step n, the oldest first (weight exp(0)).
            let live: Vec<usize> = (n.saturating_sub(3)..=n).collect();
            let (mut num, mut den) = (0.0, 0.0);
            for (i, &c) in live.iter().enumerate() {
                let w = (-m * i as f64).exp();
                num += w * (100.0 * c as f64 + (n - c) as f64);
                den += w;
            }
            assert!(
                (a[0] - num / den).abs() < 1e-9,
                "step {n}: {} vs {}",
                a[0],
                num / den
            );
        }
        // m = 0: the plain mean of the live predictions.
        let (_, flat) = run(
            ChunkExecution {
                horizon: 1,
                ensemble: Some(0.0),
            },
            5,
        );
        // Step 4: chunks 1..=4 predict 101 + 3, 201 + 2, 302 + 1 (their steps 3, 2, 1), 400.
        let mean = (103.0 + 202.0 + 301.0 + 400.0) / 4.0;
        assert!((flat[4][0] - mean).abs() < 1e-9, "{}", flat[4][0]);
        // A steep negative m: the newest chunk's first action, as replanning every step does.
        let (_, newest) = run(
            ChunkExecution {
                horizon: 1,
                ensemble: Some(-10.0),
            },
            6,
        );
        for (n, a) in newest.iter().enumerate() {
            assert!((a[0] - 100.0 * n as f64).abs() < 0.01, "step {n}: {}", a[0]);
        }
    }

    #[test]
    fn executions_the_chunks_cannot_carry_are_refused() {
        let params = StudentParams::default();
        let bad = |horizon, ensemble| {
            ChunkExecution { horizon, ensemble }
                .check_for(&params)
                .expect_err("refused")
                .to_string()
        };
        assert!(bad(0, None).contains("execution.horizon"));
        assert!(bad(9, None).contains("within 1 ..= 8"));
        assert!(bad(2, Some(0.01)).contains("horizon = 1"));
        assert!(bad(1, Some(-11.0)).contains("execution.ensemble"));
        assert!(bad(1, Some(f64::NAN)).contains("execution.ensemble"));
        // Within the plan's ±10, but 8 · 100 overlapping predictions would overflow.
        let long = StudentParams {
            chunk: 100,
            ..StudentParams::default()
        };
        let overflow = ChunkExecution {
            horizon: 1,
            ensemble: Some(-8.0),
        }
        .check_for(&long)
        .expect_err("overflow")
        .to_string();
        assert!(overflow.contains("overflow"), "{overflow}");
        assert!(
            ChunkExecution {
                horizon: 1,
                ensemble: Some(-1.0)
            }
            .check_for(&params)
            .is_ok(),
            "a negative m favours the newest predictions"
        );
        assert!(ChunkExecution::default().is_paper());
    }

    fn learns_a_deterministic_policy(ema_decay: f32, target_labels: bool, network: StudentNetwork) {
        let demos: Vec<Demo> = (0..12)
            .map(|r| {
                let steps = 10;
                let mut rng = rng::stream(0, "test", "demo", r);
                // One informative feature per frame; the constant rest standardises to 0.
                let deployable: Vec<f32> = (0..steps * DEPLOYABLE_LEN)
                    .map(|i| {
                        if i % DEPLOYABLE_LEN == 0 {
                            rng::uniform(&mut rng, -1.0, 1.0) as f32
                        } else {
                            0.5
                        }
                    })
                    .collect();
                let actions = (0..steps)
                    .flat_map(|n| {
                        let x = deployable[n * DEPLOYABLE_LEN];
                        (0..N_ACTION).map(move |k| 0.8 * x * if k % 2 == 0 { 1.0 } else { -1.0 })
                    })
                    .collect();
                // With target labels each step starts from its own arm target.
                let state = (0..steps * DEMO_STATE_LEN)
                    .map(|i| {
                        if target_labels && i % DEMO_STATE_LEN >= 9 {
                            rng::uniform(&mut rng, -0.5, 0.5) as f32
                        } else {
                            0.0
                        }
                    })
                    .collect();
                Demo {
                    steps,
                    deployable,
                    state,
                    phase: vec![0; steps],
                    actions,
                }
            })
            .collect();
        let params = StudentParams {
            history: 2,
            // Later steps of a chunk would depend on frames not yet seen: unpredictable here.
            chunk: 1,
            hidden: vec![64, 64],
            time_embedding: 8,
            steps: 600,
            batch: 64,
            lr: 3e-3,
            warmup: 20,
            holdout_every: 4,
            log_every: 100,
            ema_decay,
            arm_target: target_labels,
            target_labels,
            network,
            unet: UNetSpec {
                widths: vec![32],
                kernel: 3,
                cond: 64,
            },
            ..StudentParams::default()
        };
        let student = Student::train(&demos, &params, (1, "s"), &|| {}).expect("train");
        if ema_decay > 0.0 {
            let last = Student::train(
                &demos,
                &StudentParams {
                    ema_decay: 0.0,
                    ..params.clone()
                },
                (1, "s"),
                &|| {},
            )
            .expect("train");
            assert_ne!(last.net, student.net, "the average is not the last weights");
        }
        assert_eq!((student.train_rollouts, student.heldout_rollouts), (9, 3));
        let first = &student.curve[0];
        let last = student.curve.last().expect("curve");
        assert_eq!(last.step, 600);
        assert!(
            last.validation_loss.expect("held out")
                < 0.3 * first.validation_loss.expect("held out"),
            "{:?}",
            student.curve
        );
        let mut rng = rng::stream(0, "test", "act", 0);
        let mut err = 0.0f64;
        let mut count = 0;
        for d in demos.iter().skip(3).step_by(4) {
            for n in 0..d.steps {
                let mut obs = Vec::new();
                d.observation(n, &params, &mut obs);
                let a = student.act(&obs, &mut rng);
                let labels = &d.actions[n * N_ACTION..(n + 1) * N_ACTION];
                for (a, &l) in a.iter().zip(labels) {
                    err += (a - f64::from(l)).abs();
                    count += 1;
                }
            }
        }
        // The labels' mean absolute value is 0.4.
        let err = err / f64::from(count);
        assert!(
            err < 0.12,
            "mean absolute action error on held-out demos {err}"
        );
        let again = Student::train(&demos, &params, (1, "s"), &|| {}).expect("train");
        assert_eq!(again, student, "same seed, same student");
        // Resumed from a checkpoint taken mid-block of the curve's running loss (every 250
        // steps: after 250 and 500), the same student.
        let saved = std::sync::Mutex::new(Vec::new());
        let save = |s: &StudentState| {
            saved.lock().expect("lock").push(s.clone());
            Ok(())
        };
        let every = Checkpoints {
            every: 250,
            save: &save,
        };
        let through =
            Student::train_resumable(&demos, &params, (1, "s"), &|| {}, None, Some(every))
                .expect("train");
        assert_eq!(through, student, "checkpointing changes nothing");
        let saved = saved.into_inner().expect("lock");
        assert_eq!(saved.iter().map(|s| s.step).collect::<Vec<_>>(), [250, 500]);
        for checkpoint in saved {
            let step = checkpoint.step;
            let encoded = postcard::to_stdvec(&checkpoint).expect("encodes");
            let resumed = Student::train_resumable(
                &demos,
                &params,
                (1, "s"),
                &|| {},
                Some(postcard::from_bytes(&encoded).expect("decodes")),
                None,
            )
            .expect("resumes");
            assert_eq!(resumed, student, "resumed after {step} steps");
        }
        let other = Student::train(&demos, &params, (2, "s"), &|| {}).expect("train");
        assert_ne!(other.net, student.net);
    }
}
