//! The world's reachable follow-through (crate::reach): after first contact the probe drives
//! the palm along the incoming direction as fast as the control allows; the rollout's own
//! evaluator measures ℓ_max within Δt_eval. Prints the distribution, so the figure behind
//! docs/sim.md's "arm target rate" deviation is reproducible: `cargo test -p osms-sim --test
//! reach -- --nocapture`.

use osms_core::rng;
use osms_sim::catcher::{CatcherSpec, ScriptedCatcher};
use osms_sim::conditions::sample;
use osms_sim::control::ControlSpec;
use osms_sim::episode::{Episode, NoHooks, Policy, RolloutSpec};
use osms_sim::reach::FollowThroughProbe;
use osms_sim::{ConditionSpec, TaskCondition, World, WorldSpec};

const CONDITIONS: u64 = 16;

fn conditions(world: &World) -> Vec<TaskCondition> {
    (0..CONDITIONS)
        .map(|i| {
            let mut r = rng::stream(0, "reach", "condition", i);
            sample(&ConditionSpec::default(), world.home_palm_pos, &mut r).expect("condition")
        })
        .collect()
}

/// ℓ_max of every rollout that made contact, in condition order.
fn follow_through(
    world: &World,
    spec: &RolloutSpec,
    conditions: &[TaskCondition],
    policy: &mut dyn FnMut() -> Box<dyn Policy>,
) -> Vec<f64> {
    conditions
        .iter()
        .enumerate()
        .filter_map(|(i, c)| {
            let record = Episode::new(
                world,
                spec,
                c.clone(),
                rng::stream(0, "reach", "rollout", i as u64),
            )
            .run(policy().as_mut(), &mut NoHooks);
            record
                .metrics
                .contact_time_secs
                .map(|_| record.metrics.follow_through_m)
        })
        .collect()
}

/// The default world with the arm servos' force ranges and velocity gains scaled (the MJCF
/// edited as text: the servo parameters are not part of `WorldSpec`).
fn servo_world(force: f64, kv: f64) -> World {
    let xml: Vec<String> = osms_sim::ObjectVariant::all()
        .into_iter()
        .map(|v| {
            let mut text = osms_sim::mjcf::world_xml(&WorldSpec::default(), v);
            for f in [50.0, 30.0, 20.0] {
                text = text.replace(
                    &format!("forcerange=\"-{f} {f}\""),
                    &format!("forcerange=\"-{0} {0}\"", f * force),
                );
            }
            for kp in [1500.0, 1000.0, 800.0] {
                text = text.replace(
                    &format!("biasprm=\"0 -{kp} -{}\"", kp / 10.0),
                    &format!("biasprm=\"0 -{kp} -{}\"", kp / 10.0 * kv),
                );
            }
            text
        })
        .collect();
    World::from_xml(WorldSpec::default(), xml).expect("world")
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

#[test]
fn the_probe_follows_through_further_than_the_catcher_that_holds_its_arm() {
    let world = World::new(WorldSpec::default()).expect("world");
    let conditions = conditions(&world);
    let spec = RolloutSpec::default();
    let control = spec.control.clone();
    let held = follow_through(&world, &spec, &conditions, &mut || {
        Box::new(ScriptedCatcher::new(
            CatcherSpec::default(),
            control.clone(),
        ))
    });
    let report = |label: &str, control: ControlSpec, weight: f64| -> Vec<f64> {
        let spec = RolloutSpec {
            control: control.clone(),
            ..RolloutSpec::default()
        };
        let l = follow_through(&world, &spec, &conditions, &mut || {
            Box::new(FollowThroughProbe::new(
                CatcherSpec::default(),
                control.clone(),
                weight,
            ))
        });
        let (lo, hi) = l.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), x| {
            (lo.min(*x), hi.max(*x))
        });
        println!(
            "{label:<44} contacts {:>2}/{CONDITIONS}  ℓ_max mean {:.3} m  min {:.3}  max {:.3}  ≥ 0.2 m: {}",
            l.len(),
            mean(&l),
            lo,
            hi,
            l.iter().filter(|x| **x >= 0.2).count()
        );
        l
    };
    println!(
        "{:<44} contacts {:>2}/{CONDITIONS}  ℓ_max mean {:.3} m",
        "scripted catcher (arm held after closing)",
        held.len(),
        mean(&held)
    );
    let default = ControlSpec::default();
    let probe = report(
        "probe, default control, orientation weight 0.3",
        default.clone(),
        0.3,
    );
    for (rate, weight) in [(0.06, 0.3), (0.24, 0.3), (default.arm_max_delta_rad, 0.0)] {
        let mut c = default.clone();
        c.arm_max_delta_rad = rate;
        report(
            &format!("probe, {rate} rad/step, orientation weight {weight}"),
            c,
            weight,
        );
    }
    // Moving before contact, as a velocity-matching catch does.
    for start in [0.2, 0.4] {
        let spec = RolloutSpec::default();
        let l = follow_through(&world, &spec, &conditions, &mut || {
            Box::new(
                FollowThroughProbe::new(CatcherSpec::default(), default.clone(), 0.3)
                    .starting_at(start),
            )
        });
        println!(
            "{:<44} contacts {:>2}/{CONDITIONS}  ℓ_max mean {:.3} m  max {:.3}  ≥ 0.2 m: {}",
            format!("probe moving from {start} m before contact"),
            l.len(),
            mean(&l),
            l.iter().fold(0.0f64, |m, x| m.max(*x)),
            l.iter().filter(|x| **x >= 0.2).count()
        );
    }
    // Stronger arm servos (force ranges and velocity gains scaled) with faster targets.
    for (rate, force, kv) in [
        (0.12, 2.0, 1.0),
        (0.12, 4.0, 1.0),
        (0.24, 4.0, 1.0),
        (0.36, 4.0, 1.0),
        (0.24, 4.0, 0.5),
        (0.36, 4.0, 0.5),
    ] {
        let strong = servo_world(force, kv);
        let mut control = default.clone();
        control.arm_max_delta_rad = rate;
        let spec = RolloutSpec {
            control: control.clone(),
            ..RolloutSpec::default()
        };
        let l = follow_through(&strong, &spec, &conditions, &mut || {
            Box::new(FollowThroughProbe::new(
                CatcherSpec::default(),
                control.clone(),
                0.3,
            ))
        });
        println!(
            "{:<44} contacts {:>2}/{CONDITIONS}  ℓ_max mean {:.3} m  max {:.3}  ≥ 0.2 m: {}",
            format!("probe, {rate} rad/step, force x{force}, kv x{kv}"),
            l.len(),
            mean(&l),
            l.iter().fold(0.0f64, |m, x| m.max(*x)),
            l.iter().filter(|x| **x >= 0.2).count()
        );
    }
    assert!(!probe.is_empty() && !held.is_empty(), "no contact at all");
    assert!(
        mean(&probe) > mean(&held) + 0.05,
        "the probe's follow-through ({:.3} m) is not clearly beyond the held arm's ({:.3} m)",
        mean(&probe),
        mean(&held)
    );
}
