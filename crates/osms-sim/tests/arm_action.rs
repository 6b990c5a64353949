//! The absolute-target arm (issue 74) against the increment arm it must equal where both can
//! command the same thing: the scripted catcher, which moves by increments of its commanded
//! targets, commands the same servo targets on either arm, step for step, with and without an
//! actuation delay; an arm channel replaced by a snippet moves the commanded targets with it;
//! and perturbing an absolute arm's action does not integrate into the targets.

use osms_core::rng;
use osms_sim::catcher::{CatcherSpec, ScriptedCatcher};
use osms_sim::conditions::sample;
use osms_sim::control::{ArmAction, DrSpec, N_ACTION, N_ARM, joint_ranges, targets};
use osms_sim::episode::{Episode, RolloutSpec};
use osms_sim::policy::{Hooks, NoHooks, Policy, PolicyView};
use osms_sim::{Action, ConditionSpec, RolloutRecord, World, WorldSpec};

fn world(arm: ArmAction) -> World {
    World::new(WorldSpec {
        arm_action: arm,
        ..WorldSpec::default()
    })
    .expect("world")
}

fn catcher_rollout(w: &World, spec: &RolloutSpec, i: u64) -> RolloutRecord {
    let condition = sample(
        &ConditionSpec::default(),
        w.home_palm_pos,
        &mut rng::stream(0, "arm", "omega", i),
    )
    .expect("ω");
    let mut catcher = ScriptedCatcher::new(CatcherSpec::default(), spec.control.clone());
    Episode::new(w, spec, condition, rng::stream(0, "arm", "roll", i))
        .run(&mut catcher, &mut NoHooks)
}

/// The steps before the object first touches the robot: both rollouts are the same physics
/// there up to rounding (a contact amplifies the last bit of a target into a different bounce).
fn steps_before_contact(r: &RolloutRecord) -> usize {
    r.phase.iter().take_while(|p| **p == 0).count()
}

#[test]
fn the_scripted_catcher_commands_the_same_targets_on_either_arm() {
    let inc = world(ArmAction::Increment);
    let abs = world(ArmAction::Absolute);
    let ranges = joint_ranges();
    let mut compared = 0;
    for (delay, label) in [(0, "no delay"), (1, "a one-step actuation delay")] {
        let spec = RolloutSpec {
            dr: DrSpec {
                max_actuation_delay_steps: delay,
                ..DrSpec::default()
            },
            ..RolloutSpec::default()
        };
        for i in 0..4 {
            let a = catcher_rollout(&inc, &spec, i);
            let b = catcher_rollout(&abs, &spec, i);
            assert_eq!(a.dr, b.dr, "the same DR draws");
            let n = steps_before_contact(&a).min(steps_before_contact(&b));
            assert!(n > 5, "{label}, throw {i}: only {n} steps before contact");
            for k in 0..n {
                for j in 0..N_ARM {
                    let (x, y) = (a.arm_targets[k * N_ARM + j], b.arm_targets[k * N_ARM + j]);
                    assert!(
                        (x - y).abs() < 1e-5,
                        "{label}, throw {i}, step {k}, joint {j}: increment arm {x}, absolute arm {y}"
                    );
                }
                // The absolute arm's recorded action is the target itself.
                let next = if k + 1 < b.steps {
                    &b.arm_targets[(k + 1) * N_ARM..(k + 2) * N_ARM]
                } else {
                    continue;
                };
                if delay == 0 || b.dr.actuation_delay_steps == 0 {
                    for j in 0..N_ARM {
                        let [lo, hi] = ranges[j];
                        let a = f64::from(b.intended[k * N_ACTION + j]);
                        let t = lo + 0.5 * (a + 1.0) * (hi - lo);
                        assert!(
                            (t - f64::from(next[j])).abs() < 1e-5,
                            "{label}, throw {i}, step {k}, joint {j}: action {a} designates {t}, the target became {}",
                            next[j]
                        );
                    }
                }
            }
            compared += n;
            // The hand is commanded the same on both arms throughout.
            assert_eq!(a.intended[N_ARM..N_ACTION], b.intended[N_ARM..N_ACTION]);
        }
    }
    assert!(compared > 60, "only {compared} steps compared");
}

/// Replaces the arm channels with fixed values from step `from` on.
struct Override {
    from: usize,
    arm: [f64; N_ARM],
}

impl Hooks for Override {
    fn override_arm(&mut self, step: usize, action: &mut Action) {
        if step >= self.from {
            action[..N_ARM].copy_from_slice(&self.arm);
        }
    }
}

/// Records the commanded targets the view shows.
struct Watch {
    inner: ScriptedCatcher,
    seen: Vec<[f64; N_ARM]>,
}

impl Policy for Watch {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        self.seen.push(view.commanded_arm);
        self.inner.act(view)
    }
    fn reads_contact_force(&self) -> bool {
        false
    }
}

#[test]
fn commanded_targets_follow_a_snippet_that_replaces_the_arm() {
    for arm in [ArmAction::Increment, ArmAction::Absolute] {
        let w = world(arm);
        let spec = RolloutSpec::default();
        let condition = sample(
            &ConditionSpec::default(),
            w.home_palm_pos,
            &mut rng::stream(0, "arm", "omega", 11),
        )
        .expect("ω");
        let snippet = [0.02, -0.01, 0.03, 0.01, -0.02, 0.0, 0.01];
        let mut hooks = Override {
            from: 3,
            arm: snippet,
        };
        let mut watch = Watch {
            inner: ScriptedCatcher::new(CatcherSpec::default(), spec.control.clone()),
            seen: Vec::new(),
        };
        let record = Episode::new(&w, &spec, condition, rng::stream(0, "arm", "roll", 11))
            .run(&mut watch, &mut hooks);
        assert!(record.steps > 8);
        for k in 3..8 {
            let mut previous = [0.0; N_ACTION];
            previous[..N_ARM].copy_from_slice(&watch.seen[k]);
            let mut action = [0.0; N_ACTION];
            action[..N_ARM].copy_from_slice(&snippet);
            let want = targets(&spec.control, arm, &previous, &action);
            for (j, (&got, &want)) in watch.seen[k + 1].iter().zip(&want[..N_ARM]).enumerate() {
                assert!(
                    (got - want).abs() < 1e-12,
                    "{arm:?}, step {k}, joint {j}: commanded {got}, the snippet designates {want}"
                );
            }
        }
    }
}

/// Adds a constant to the executed arm channels (an action bias, as Eq. 7's κμ).
struct Bias(f64);

impl Hooks for Bias {
    fn perturb(&mut self, _: usize, action: &mut Action) {
        for a in &mut action[..N_ARM] {
            *a = (*a + self.0).clamp(-1.0, 1.0);
        }
    }
}

/// Holds its commanded targets.
struct HoldCommanded;

impl Policy for HoldCommanded {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        osms_sim::control::hold_action_at(
            view.world.spec.arm_action,
            &view.commanded_arm,
            &view.world.spec.hand_home_rad,
        )
    }
    fn reads_contact_force(&self) -> bool {
        false
    }
}

#[test]
fn an_action_bias_drifts_an_increment_arm_and_offsets_an_absolute_one() {
    let spec = RolloutSpec::default();
    let bias = 0.01;
    let mut drift = Vec::new();
    for arm in [ArmAction::Increment, ArmAction::Absolute] {
        let w = world(arm);
        let condition = sample(
            &ConditionSpec::default(),
            w.home_palm_pos,
            &mut rng::stream(0, "arm", "omega", 3),
        )
        .expect("ω");
        let record = Episode::new(&w, &spec, condition, rng::stream(0, "arm", "roll", 3))
            .run(&mut HoldCommanded, &mut Bias(bias));
        assert!(record.steps > 12, "{arm:?}: {} steps", record.steps);
        let at = |k: usize| f64::from(record.arm_targets[k * N_ARM]);
        drift.push((at(12) - at(6), at(6) - at(0)));
    }
    let step = osms_sim::control::ControlSpec::default().arm_max_delta_rad;
    let (inc_late, _) = drift[0];
    assert!(
        (inc_late - 6.0 * bias * step).abs() < 1e-5,
        "increment arm: the bias adds up over 6 steps to {inc_late}"
    );
    let (abs_late, abs_early) = drift[1];
    let [lo, hi] = joint_ranges()[0];
    assert!(
        abs_late.abs() < 1e-6,
        "absolute arm: the target moved {abs_late} late"
    );
    assert!(
        (abs_early - bias * 0.5 * (hi - lo)).abs() < 1e-5,
        "absolute arm: one offset of the bias, {abs_early}"
    );
}
