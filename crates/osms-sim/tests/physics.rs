//! The world against independent truths: closed-form flight and impact, a separate summation of
//! contact forces, the failure taxonomy on constructed throws, exact snapshot/restore, and
//! thread-count independence.

use mujoco_rs::prelude::*;
use osms_core::rng;
use osms_sim::conditions::{GRAVITY_MPS2, launch_velocity, sample};
use osms_sim::control::{N_ACTION, N_ARM, N_HAND, hold_action};
use osms_sim::episode::{Episode, RolloutSpec};
use osms_sim::policy::{Hooks, NoHooks, Policy, PolicyView};
use osms_sim::{
    Action, ConditionSpec, Failure, ObjectFamily, ObjectSize, ObjectVariant, Phase, TaskCondition,
    World, WorldSpec,
};

fn world() -> World {
    World::new(WorldSpec::default()).expect("world")
}

/// Holds the arm still and the hand at a fixed posture.
struct Hold(Action);
impl Policy for Hold {
    fn act(&mut self, _: &PolicyView<'_>) -> Action {
        self.0
    }
}

fn open_hand() -> Hold {
    Hold(hold_action(&[0.0; N_HAND]))
}

fn throw(variant: ObjectVariant, from: [f64; 3], vel: [f64; 3]) -> TaskCondition {
    TaskCondition {
        variant,
        mass_kg: 0.05,
        launch_pos_m: from,
        launch_vel_mps: vel,
        lateral_offset_m: 0.0,
        crossing_time_secs: 0.0,
        arm_perturbation_rad: [0.0; N_ARM],
        hand_perturbation_rad: [0.0; N_HAND],
    }
}

fn sphere_small() -> ObjectVariant {
    ObjectVariant {
        family: ObjectFamily::Sphere,
        size: ObjectSize::Small,
    }
}

#[test]
fn free_flight_matches_the_integrators_closed_form_and_the_parabola() {
    let w = world();
    let dt = w.spec.timestep_secs;
    for v in ObjectVariant::all() {
        let mut data = w.model(v).make_data();
        w.set_home(&mut data);
        let (x0, v0) = ([2.0, 2.0, 3.0], [1.0, -0.5, 2.0]);
        let o = w.ids.object_qpos;
        data.qpos_mut()[o..o + 3].copy_from_slice(&x0);
        data.qvel_mut()[w.ids.object_dof..w.ids.object_dof + 3].copy_from_slice(&v0);
        let n = 250; // 0.5 s
        for _ in 0..n {
            data.step();
        }
        let t = n as f64 * dt;
        for k in 0..3 {
            let g = if k == 2 { -GRAVITY_MPS2 } else { 0.0 };
            let x = data.qpos()[o + k];
            // Semi-implicit Euler: v += g dt, then x += v dt, n times.
            let discrete = x0[k] + v0[k] * t + g * dt * dt * (n * (n + 1)) as f64 / 2.0;
            assert!(
                (x - discrete).abs() < 1e-9,
                "{v} axis {k}: {x} vs {discrete}"
            );
            let parabola = x0[k] + v0[k] * t + 0.5 * g * t * t;
            let bound = GRAVITY_MPS2 * dt * t / 2.0 + 1e-9;
            assert!(
                (x - parabola).abs() <= bound,
                "{v} axis {k}: off the parabola by {}",
                (x - parabola).abs()
            );
        }
    }
}

#[test]
fn objects_of_any_mass_fall_at_g_in_an_episode() {
    let w = world();
    let spec = RolloutSpec::default();
    for mass in [0.04, 0.05, 0.06] {
        let mut cond = throw(sphere_small(), [3.0, 3.0, 5.0], [0.0; 3]);
        cond.mass_kg = mass;
        let mut ep = Episode::new(&w, &spec, cond, rng::stream(0, "t", "mass", 0));
        let mut policy = Hold(hold_action(&w.spec.hand_home_rad));
        for _ in 0..10 {
            ep.step(&mut policy, &mut NoHooks);
        }
        let d = ep.data();
        let vz = d.qvel()[w.ids.object_dof + 2];
        assert!(
            (vz + GRAVITY_MPS2 * d.time()).abs() < 1e-9,
            "mass {mass}: vz {vz} after {} s",
            d.time()
        );
    }
}

#[test]
fn a_throw_into_the_static_open_palm_hits_when_the_closed_form_says() {
    let w = world();
    let spec = RolloutSpec::default();
    let r = 0.025; // the small sphere's radius
    let n = w.home_palm_normal;
    // Aim 15 mm toward the pinky side of the palm centre, clear of the thumb's base.
    let palm = {
        let mut data = w.model(sphere_small()).make_data();
        w.set_home(&mut data);
        data.forward();
        let m = data.site_xmat()[w.ids.palm_site];
        let p = w.home_palm_pos;
        [
            p[0] + 0.015 * m[0],
            p[1] + 0.015 * m[3],
            p[2] + 0.015 * m[6],
        ]
    };
    // The sphere's centre reaches palm + r·n (touching the palm plane) at exactly T.
    let target = [palm[0] + r * n[0], palm[1] + r * n[1], palm[2] + r * n[2]];
    let from = [
        palm[0] + 0.6 * n[0],
        palm[1] + 0.6 * n[1],
        palm[2] + 0.6 * n[2] + 0.1,
    ];
    let t_impact = 0.2;
    let vel = launch_velocity(from, target, t_impact);
    let mut policy = SeesContact {
        hold: open_hand(),
        seen: None,
    };
    let rec = Episode::new(
        &w,
        &spec,
        throw(sphere_small(), from, vel),
        rng::stream(0, "t", "x", 0),
    )
    .run(&mut policy, &mut NoHooks);
    let m = &rec.metrics;
    let dt = w.spec.timestep_secs;
    let t_c = m.contact_time_secs.expect("the palm is touched");
    assert!(
        t_c >= t_impact - 1e-9 && t_c <= t_impact + dt + 1e-9,
        "t_c = {t_c}, closed form {t_impact}"
    );
    let v_at = [vel[0], vel[1], vel[2] - GRAVITY_MPS2 * t_impact];
    let speed = (v_at[0].powi(2) + v_at[1].powi(2) + v_at[2].powi(2)).sqrt();
    let v_rel = m.contact_speed_mps.expect("v_rel");
    // One physics step of gravity plus the holding servo's residual palm motion.
    assert!(
        (v_rel - speed).abs() < GRAVITY_MPS2 * dt + 0.01,
        "v_rel {v_rel} vs {speed}"
    );

    // At control rate: the step containing t_c is the one contact step, after an approach and
    // a velocity-matching stretch, and the follow-through comes next.
    let period = dt * f64::from(w.spec.substeps);
    let k_c = (t_c / period + 1e-9).floor() as usize;
    assert_eq!(m.event_step, k_c);
    let phase = |p: Phase| p as u8;
    assert_eq!(rec.phase[k_c], phase(Phase::Contact), "{:?}", rec.phase);
    assert_eq!(
        rec.phase
            .iter()
            .filter(|&&p| p == phase(Phase::Contact))
            .count(),
        1
    );
    assert_eq!(rec.phase[0], phase(Phase::Approach));
    assert!(rec.phase[..k_c].windows(2).all(|w| w[0] <= w[1]));
    assert_eq!(rec.phase[k_c - 1], phase(Phase::VelocityMatching));
    if rec.steps > k_c + 1 {
        assert_eq!(rec.phase[k_c + 1], phase(Phase::FollowThrough));
    }

    // A policy sees the first contact from the next control step on, with the pre-contact
    // incoming direction: the closed-form velocity at T, normalised.
    let (seen_at, dir) = policy.seen.expect("the policy saw the contact");
    assert_eq!(seen_at, k_c + 1);
    for (d, v) in dir.iter().zip(v_at) {
        assert!((d - v / speed).abs() < 0.01, "{dir:?} vs {v_at:?}");
    }
}

/// Holds still and notes when it first sees the first contact, and its incoming direction.
struct SeesContact {
    hold: Hold,
    seen: Option<(usize, [f64; 3])>,
}
impl Policy for SeesContact {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        if self.seen.is_none()
            && let Some(c) = view.first_contact
        {
            self.seen = Some((view.step, c.incoming_dir));
        }
        self.hold.act(view)
    }
}

/// The names of a contact's two geoms.
fn geom_names(
    model: &MjModel,
    c: &mujoco_rs::wrappers::mj_auxiliary::MjContact,
) -> (String, String) {
    let name = |g: i32| {
        model
            .id_to_name(MjtObjBase::mjOBJ_GEOM, g as usize)
            .unwrap_or("")
            .to_string()
    };
    (name(c.geom[0]), name(c.geom[1]))
}

/// The small sphere thrown from 0.8 m along the palm normal (0.2 m higher) to touch the palm
/// centre after 0.25 s.
fn palm_throw(w: &World) -> TaskCondition {
    let n = w.home_palm_normal;
    let palm = w.home_palm_pos;
    let r = 0.025;
    let target = [palm[0] + r * n[0], palm[1] + r * n[1], palm[2] + r * n[2]];
    let from = [
        palm[0] + 0.8 * n[0],
        palm[1] + 0.8 * n[1],
        palm[2] + 0.8 * n[2] + 0.2,
    ];
    throw(sphere_small(), from, launch_velocity(from, target, 0.25))
}

/// Sums admissible normal forces itself, from geom names and `mj_contactForce`.
#[derive(Default)]
struct ForceLog {
    samples: Vec<(f64, f64)>,
}
impl Hooks for ForceLog {
    fn after_physics_step(&mut self, data: &MjData<Box<MjModel>>) {
        let model = data.model();
        let mut total = 0.0;
        for (i, c) in data.contact().iter().enumerate() {
            let (a, b) = geom_names(model, c);
            let hand =
                |s: &str| s.starts_with("hand_") && s != "hand_adapter" && s != "hand_tower_geom";
            if (a == "object_geom" && hand(&b)) || (b == "object_geom" && hand(&a)) {
                total += data.contact_force(i)[0];
            }
        }
        // Contacts describe the state before the step's integration.
        self.samples
            .push((data.time() - model.opt().timestep, total));
    }
}

#[test]
fn f_max_equals_a_separate_summation_of_contact_normal_forces() {
    let w = world();
    let spec = RolloutSpec::default();
    let mut log = ForceLog::default();
    let rec = Episode::new(&w, &spec, palm_throw(&w), rng::stream(0, "t", "x", 1))
        .run(&mut open_hand(), &mut log);
    let t_c = rec.metrics.contact_time_secs.expect("contact");
    let window = spec.success.eval_window_secs;
    let expected = log
        .samples
        .iter()
        .filter(|(t, _)| *t >= t_c - 1e-12 && *t <= t_c + window + 1e-12)
        .map(|(_, f)| *f)
        .fold(0.0, f64::max);
    assert!(expected > 0.0);
    assert!(
        (rec.metrics.max_force_n - expected).abs() < 1e-9,
        "{} vs {expected}",
        rec.metrics.max_force_n
    );
}

#[test]
fn a_throw_at_the_forearm_is_a_forbidden_contact() {
    let w = world();
    let spec = RolloutSpec::default();
    let mut data = w.model(sphere_small()).make_data();
    w.set_home(&mut data);
    data.forward();
    let link = w
        .model(sphere_small())
        .name_to_id(MjtObjBase::mjOBJ_BODY, "arm_link4")
        .expect("link4");
    let elbow = data.xpos()[link];
    let from = [elbow[0] + 0.8, elbow[1], elbow[2] + 0.1];
    let vel = launch_velocity(from, elbow, 0.25);
    let rec = Episode::new(
        &w,
        &spec,
        throw(sphere_small(), from, vel),
        rng::stream(0, "t", "x", 2),
    )
    .run(&mut open_hand(), &mut NoHooks);
    assert_eq!(
        rec.outcome.failures,
        vec![Failure::ForbiddenContactArm],
        "{:?}",
        rec.metrics
    );
    assert!(!rec.outcome.completion());
}

#[test]
fn an_object_released_onto_the_open_palm_is_dropped() {
    let w = world();
    let spec = RolloutSpec::default();
    let n = w.home_palm_normal;
    let palm = w.home_palm_pos;
    // Just in front of the palm face and above the palm centre, drifting into it.
    let from = [palm[0] + 0.03 * n[0], palm[1], palm[2] + 0.06];
    let vel = [-0.2 * n[0], 0.0, 0.0];
    let rec = Episode::new(
        &w,
        &spec,
        throw(sphere_small(), from, vel),
        rng::stream(0, "t", "x", 3),
    )
    .run(&mut open_hand(), &mut NoHooks);
    assert!(
        rec.metrics.contact_time_secs.is_some(),
        "the palm is touched first: {:?}",
        rec.outcome
    );
    assert!(
        rec.outcome.failures.contains(&Failure::Drop),
        "{:?}",
        rec.outcome
    );
    assert!(!rec.outcome.completion());
}

#[test]
fn driving_a_joint_into_its_limit_is_a_joint_limit_failure() {
    let w = world();
    let spec = RolloutSpec::default();
    let mut action = hold_action(&w.spec.hand_home_rad);
    action[3] = -1.0; // the elbow toward its lower limit, 1.4 rad from home
    // The object falls far away for 1.4 s, long after the joint reaches its limit.
    let rec = Episode::new(
        &w,
        &spec,
        throw(sphere_small(), [3.0, 3.0, 10.0], [0.0; 3]),
        rng::stream(0, "t", "x", 4),
    )
    .run(&mut Hold(action), &mut NoHooks);
    assert_eq!(rec.outcome.failures, vec![Failure::JointLimit]);
}

/// Checks what the policy sees of the past.
struct HistoryCheck {
    hold: Action,
    seen: Vec<usize>,
}
impl Policy for HistoryCheck {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        assert_eq!(
            view.history.back().map(Vec::as_slice),
            Some(view.deployable)
        );
        assert!(
            view.history
                .iter()
                .all(|f| f.len() == osms_sim::policy::DEPLOYABLE_LEN)
        );
        self.seen.push(view.history.len());
        self.hold
    }
}

#[test]
fn policies_see_the_last_frames_oldest_first() {
    let w = world();
    let spec = RolloutSpec {
        history_steps: 3,
        ..RolloutSpec::default()
    };
    let mut policy = HistoryCheck {
        hold: hold_action(&w.spec.hand_home_rad),
        seen: Vec::new(),
    };
    let rec = Episode::new(
        &w,
        &spec,
        throw(sphere_small(), [3.0, 3.0, 3.0], [0.0; 3]),
        rng::stream(0, "t", "h", 0),
    )
    .run(&mut policy, &mut NoHooks);
    assert!(rec.steps > 5);
    assert_eq!(&policy.seen[..5], &[1, 2, 3, 3, 3]);
}

#[test]
fn a_nan_action_is_an_invalid_action_failure_not_a_panic() {
    let w = world();
    let spec = RolloutSpec::default();
    let mut action = hold_action(&w.spec.hand_home_rad);
    action[10] = f64::NAN;
    let rec = Episode::new(
        &w,
        &spec,
        throw(sphere_small(), [3.0, 3.0, 3.0], [0.0; 3]),
        rng::stream(0, "t", "x", 5),
    )
    .run(&mut Hold(action), &mut NoHooks);
    assert_eq!(rec.outcome.failures, vec![Failure::InvalidAction]);
    assert_eq!(rec.steps, 1);
}

fn sampled(i: u64, w: &World) -> TaskCondition {
    sample(
        &ConditionSpec::default(),
        w.home_palm_pos,
        &mut rng::stream(0, "test", "omega", i),
    )
    .expect("ω")
}

#[test]
fn restoring_a_snapshot_reproduces_the_trajectory_bit_for_bit() {
    let w = world();
    // Every source of randomness on, so the snapshot must carry the generator too.
    let spec = RolloutSpec {
        dr: osms_sim::control::DrSpec::paper(),
        record_privileged: true,
        ..RolloutSpec::default()
    };
    let cond = sampled(7, &w);
    let mut policy = Hold(hold_action(&w.spec.hand_home_rad));
    let full = Episode::new(&w, &spec, cond.clone(), rng::stream(0, "t", "roll", 7))
        .run(&mut policy, &mut NoHooks);
    assert!(full.steps >= 6, "{} steps", full.steps);

    let mut ep = Episode::new(&w, &spec, cond, rng::stream(0, "t", "roll", 7));
    for _ in 0..full.steps / 2 {
        ep.step(&mut policy, &mut NoHooks);
    }
    let snap = ep.snapshot();
    // Wander off: a different action for a while, then come back to the snapshot.
    let mut other = Hold([0.3; osms_sim::N_ACTION]);
    for _ in 0..8 {
        ep.step(&mut other, &mut NoHooks);
    }
    ep.restore(&snap);
    let resumed = ep.run(&mut policy, &mut NoHooks);
    let bytes = |r: &osms_sim::RolloutRecord| postcard::to_stdvec(r).expect("encode");
    assert_eq!(bytes(&full), bytes(&resumed));
}

#[test]
fn rollouts_do_not_depend_on_the_thread_count() {
    use rayon::prelude::*;
    let w = world();
    let spec = RolloutSpec {
        dr: osms_sim::control::DrSpec::paper(),
        ..RolloutSpec::default()
    };
    let run_all = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        let records: Vec<osms_sim::RolloutRecord> = pool.install(|| {
            (0..64u64)
                .into_par_iter()
                .map(|i| {
                    let mut policy = Hold(hold_action(&w.spec.hand_home_rad));
                    Episode::new(&w, &spec, sampled(i, &w), rng::stream(0, "t", "roll", i))
                        .run(&mut policy, &mut NoHooks)
                })
                .collect()
        });
        blake3::hash(&postcard::to_stdvec(&records).expect("encode"))
    };
    assert_eq!(run_all(1), run_all(2));
}

#[test]
fn every_world_variant_loads_from_a_file_with_mujocos_own_parser() {
    let w = world();
    let dir = tempfile::tempdir().expect("dir");
    for v in ObjectVariant::all() {
        let path = dir.path().join(format!("{v}.xml"));
        std::fs::write(&path, w.xml(v)).expect("write");
        let model = MjModel::from_xml(&path).unwrap_or_else(|e| panic!("{v}: {e}"));
        assert_eq!(model.ffi().nu, 24);
    }
}

/// The scripted catcher, reading the privileged contact force or saying it does not.
struct Catcher {
    inner: osms_sim::catcher::ScriptedCatcher,
    reads: bool,
    /// (admissible contact count, admissible normal force) observed at every step.
    seen: Vec<(f64, f64)>,
}
impl Policy for Catcher {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        let count = osms_sim::policy::PRIVILEGED_CONTACT_COUNT;
        self.seen
            .push((view.privileged[count], view.privileged[count - 1]));
        self.inner.act(view)
    }
    fn reads_contact_force(&self) -> bool {
        self.reads
    }
}

fn catcher(spec: &RolloutSpec, reads: bool) -> Catcher {
    Catcher {
        inner: osms_sim::catcher::ScriptedCatcher::new(
            osms_sim::catcher::CatcherSpec::default(),
            spec.control.clone(),
        ),
        reads,
        seen: Vec::new(),
    }
}

/// The controls of every physics step and where each control step starts.
#[derive(Default)]
struct Controls {
    ctrl: Vec<Vec<f64>>,
    starts: Vec<usize>,
}
impl Hooks for Controls {
    fn override_arm(&mut self, _: usize, _: &mut Action) {
        self.starts.push(self.ctrl.len());
    }
    fn after_physics_step(&mut self, data: &MjData<Box<MjModel>>) {
        self.ctrl.push(data.ctrl().to_vec());
    }
}

impl Controls {
    /// Replays the recorded controls on `data` with plain `mj_forward` and `mj_step`: at each
    /// control step's start, a full forward pass, then `at_start(k, data)`.
    fn replay(
        &self,
        data: &mut MjData<Box<MjModel>>,
        mut at_start: impl FnMut(usize, &MjData<Box<MjModel>>),
    ) {
        let ends = self.starts.iter().skip(1).copied().chain([self.ctrl.len()]);
        for (k, (&start, end)) in self.starts.iter().zip(ends).enumerate() {
            data.forward();
            at_start(k, data);
            for ctrl in &self.ctrl[start..end] {
                data.ctrl_mut().copy_from_slice(ctrl);
                data.step();
            }
        }
    }
}

/// The loop splits the control step's first physics step into the observation's `mj_step1` and
/// a later `mj_step2`, and solves for the observed contact force only where it can be non-zero
/// and is read. Against a plain replay that calls `mj_forward` at every control step's start
/// and `mj_step` for every physics step: the same observed counts and forces, bit for bit, the
/// same final state, and the same record whether or not the policy reads the force.
#[test]
fn the_observed_contact_force_matches_a_full_forward_pass_and_skipping_it_changes_nothing() {
    let w = world();
    let spec = RolloutSpec {
        dr: osms_sim::control::DrSpec::paper(),
        ..RolloutSpec::default()
    };
    let mut contact_steps = 0;
    for i in 0..6 {
        let cond = sampled(i, &w);
        let stream = || rng::stream(0, "t", "force", i);
        let mut reading = catcher(&spec, true);
        let mut controls = Controls::default();
        let mut ep = Episode::new(&w, &spec, cond.clone(), stream());
        while ep.step(&mut reading, &mut controls) {}
        let final_qpos = ep.data().qpos().to_vec();
        let record = ep.finish();

        let mut blind = catcher(&spec, false);
        let blind_record =
            Episode::new(&w, &spec, cond.clone(), stream()).run(&mut blind, &mut NoHooks);
        let bytes = |r: &osms_sim::RolloutRecord| postcard::to_stdvec(r).expect("encode");
        assert_eq!(bytes(&record), bytes(&blind_record), "condition {i}");

        let mut data = osms_sim::episode::initial_data(&w, &cond, &record.dr);
        controls.replay(&mut data, |k, data| {
            let scan = osms_sim::metrics::scan(data, &w.ids.geom_class, true);
            let (count, force) = reading.seen[k];
            assert_eq!(
                count, scan.admissible_contacts as f64,
                "condition {i} step {k}"
            );
            assert_eq!(
                force.to_bits(),
                scan.admissible_force_n.to_bits(),
                "condition {i} step {k}"
            );
            let (blind_count, blind_force) = blind.seen[k];
            assert_eq!(blind_count, count);
            // The palm's touch reading needs the same solve wherever the palm has a contact,
            // so there even a policy that does not read the force sees it.
            if count > 0.0 && scan.palm_contacts == 0 {
                contact_steps += 1;
                assert!(
                    blind_force.is_nan(),
                    "condition {i} step {k}: {blind_force}"
                );
            } else {
                assert_eq!(blind_force.to_bits(), force.to_bits());
            }
        });
        assert_eq!(data.qpos(), final_qpos.as_slice(), "condition {i}");
    }
    assert!(contact_steps > 10, "{contact_steps} steps with contact");
}

/// The palm's touch reading in the deployable frame is the summed normal force of the palm's
/// contacts at the control step's start, as a full forward pass and a summation by geom names
/// give it, and exactly 0 without a palm contact while domain randomisation (and with it the
/// sensor's noise) is off.
#[test]
fn the_touch_reading_is_the_palms_contact_force() {
    let w = world();
    let spec = RolloutSpec::default();
    let mut controls = Controls::default();
    let mut ep = Episode::new(&w, &spec, palm_throw(&w), rng::stream(0, "t", "touch", 0));
    let mut hand = open_hand();
    while ep.step(&mut hand, &mut controls) {}
    let record = ep.finish();
    let len = osms_sim::policy::DEPLOYABLE_LEN;
    let touch = osms_sim::policy::PALM_TOUCH;
    let mut data = osms_sim::episode::initial_data(&w, &record.condition, &record.dr);
    let mut touched = 0;
    controls.replay(&mut data, |k, data| {
        let mut expected = 0.0;
        for (i, c) in data.contact().iter().enumerate() {
            let (a, b) = geom_names(data.model(), c);
            if a == "hand_palm_geom" || b == "hand_palm_geom" {
                expected += data.contact_force(i)[0];
            }
        }
        let read = record.deployable[k * len + touch];
        assert_eq!(read, expected as f32, "step {k}");
        touched += usize::from(read > 0.0);
    });
    assert!(touched > 3, "{touched} steps with the palm touched");
}

/// Under domain randomisation the touch reading carries zero-mean noise of
/// `TOUCH_NOISE_N` before anything touches the palm.
#[test]
fn the_touch_readings_noise_has_its_stated_size() {
    let w = world();
    let spec = RolloutSpec {
        dr: osms_sim::control::DrSpec::paper(),
        ..RolloutSpec::default()
    };
    let len = osms_sim::policy::DEPLOYABLE_LEN;
    let mut readings = Vec::new();
    for i in 0..12 {
        let record = Episode::new(&w, &spec, sampled(i, &w), rng::stream(0, "t", "noise", i))
            .run(&mut open_hand(), &mut NoHooks);
        let before = record
            .metrics
            .contact_time_secs
            .map_or(record.steps, |t| (t / w.control_period_secs()) as usize)
            .saturating_sub(2);
        readings.extend(
            (0..before)
                .map(|k| f64::from(record.deployable[k * len + osms_sim::policy::PALM_TOUCH])),
        );
    }
    let n = readings.len() as f64;
    assert!(n > 100.0, "{n} readings");
    let mean = readings.iter().sum::<f64>() / n;
    let sd = (readings.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let sigma = osms_sim::policy::TOUCH_NOISE_N;
    assert!(mean.abs() < 4.0 * sigma / n.sqrt(), "mean {mean}");
    assert!((sd / sigma - 1.0).abs() < 0.2, "sd {sd} against {sigma}");
}

/// A record that keeps privileged frames gets the solved force even from a policy that does
/// not read it.
#[test]
fn recorded_privileged_frames_carry_the_force_whatever_the_policy_reads() {
    let w = world();
    let spec = RolloutSpec {
        dr: osms_sim::control::DrSpec::paper(),
        record_privileged: true,
        ..RolloutSpec::default()
    };
    let run = |reads| {
        let mut policy = catcher(&spec, reads);
        let record = Episode::new(&w, &spec, sampled(2, &w), rng::stream(0, "t", "force", 2))
            .run(&mut policy, &mut NoHooks);
        (record, policy.seen)
    };
    let (reading, seen) = run(true);
    let (blind, blind_seen) = run(false);
    assert_eq!(reading, blind);
    assert_eq!(seen.len(), reading.steps);
    let count = osms_sim::policy::PRIVILEGED_CONTACT_COUNT;
    let len = osms_sim::policy::PRIVILEGED_LEN;
    let mut touching = 0;
    for (k, ((_, force), (_, blind_force))) in seen.iter().zip(&blind_seen).enumerate() {
        assert_eq!(force.to_bits(), blind_force.to_bits(), "step {k}");
        assert_eq!(
            reading.privileged[k * len + count - 1],
            *force as f32,
            "step {k}"
        );
        touching += usize::from(reading.privileged[k * len + count] > 0.0);
    }
    assert!(touching > 3, "{touching} steps with contact");
}

/// Notes the sliding friction and time constant of every contact between the object and a
/// hand geom, as MuJoCo resolved them.
#[derive(Default)]
struct ContactParams {
    seen: Vec<(f64, f64)>,
}
impl Hooks for ContactParams {
    fn after_physics_step(&mut self, data: &MjData<Box<MjModel>>) {
        for c in data.contact() {
            let (a, b) = geom_names(data.model(), c);
            if (a == "object_geom" && b.starts_with("hand_"))
                || (b == "object_geom" && a.starts_with("hand_"))
            {
                self.seen.push((c.friction[0], c.solref[0]));
            }
        }
    }
}

/// The hand's geoms have friction 1 and MuJoCo's default time constant 0.02 s; without the
/// object's contact priority MuJoCo would take the larger friction and average the time
/// constants, and the world's values and their domain randomisation would not be the ones in
/// force.
#[test]
fn the_worlds_friction_and_time_constant_govern_every_object_contact_with_their_dr() {
    let w = World::new(WorldSpec {
        friction: 0.6,
        contact_timeconst_secs: 0.007,
        ..WorldSpec::default()
    })
    .expect("world");
    let mut spec = RolloutSpec::default();
    spec.dr.friction_variation = 0.2;
    spec.dr.contact_timeconst_variation = 0.3;
    for seed in 0..3 {
        let mut log = ContactParams::default();
        let rec = Episode::new(&w, &spec, palm_throw(&w), rng::stream(0, "t", "x", seed))
            .run(&mut open_hand(), &mut log);
        assert_ne!(rec.dr.friction_scale, 1.0);
        assert_ne!(rec.dr.contact_timeconst_scale, 1.0);
        assert!(!log.seen.is_empty(), "seed {seed}: no hand contact");
        let friction = 0.6 * rec.dr.friction_scale;
        let timeconst = 0.007 * rec.dr.contact_timeconst_scale;
        for &(f, t) in &log.seen {
            assert!((f - friction).abs() < 1e-12, "friction {f} vs {friction}");
            assert!(
                (t - timeconst).abs() < 1e-12,
                "time constant {t} vs {timeconst}"
            );
        }
    }
}

/// The scripted catcher with a grip margin, checking every hand target against the joint it
/// drives.
struct Gripping {
    inner: osms_sim::catcher::ScriptedCatcher,
    margin: f64,
    open: Action,
    closing_steps: usize,
}
impl Policy for Gripping {
    fn act(&mut self, view: &PolicyView<'_>) -> Action {
        let a = self.inner.act(view);
        if a[N_ARM..] != self.open[N_ARM..] {
            self.closing_steps += 1;
            let ranges = osms_sim::control::joint_ranges();
            // Hand targets are absolute, so the previous targets do not matter.
            let targets = osms_sim::control::targets(
                &osms_sim::control::ControlSpec::default(),
                osms_sim::control::ArmAction::Increment,
                &[0.0; N_ACTION],
                &a,
            );
            let q = view.data.qpos();
            for i in 0..N_HAND {
                let [lo, hi] = ranges[N_ARM + i];
                let target = targets[N_ARM + i];
                let at = q[view.world.ids.hand_qpos[i]].clamp(lo, hi);
                assert!(
                    (target - at).abs() <= self.margin + 1e-9,
                    "hand joint {i}: target {target} is more than {} from {at}",
                    self.margin
                );
            }
        }
        a
    }
}

/// With `grip_margin_rad` (0.1 rad), every closing target leads its joint by at most the
/// margin, and a large box held in the hand is squeezed less than by targets that jump to the
/// closed posture (`None`); measured: 16.5 N against 31.7 N.
#[test]
fn a_grip_margin_bounds_each_finger_target_and_the_squeeze() {
    let w = world();
    let spec = RolloutSpec::default();
    let margin = 0.1;
    let catcher = |m: Option<f64>| osms_sim::catcher::CatcherSpec {
        grip_margin_rad: m,
        ..osms_sim::catcher::CatcherSpec::default()
    };
    let open = hold_action(&catcher(None).open_hand_rad);
    // Mean summed normal force over a rollout's last ten steps, if it still holds the object.
    let held_squeeze = |r: &osms_sim::RolloutRecord| {
        (r.outcome.completion() && r.steps > 10).then(|| {
            let tail = &r.normal_force[r.steps - 10..];
            tail.iter().map(|&f| f64::from(f)).sum::<f64>() / 10.0
        })
    };
    let (mut with, mut without) = (Vec::new(), Vec::new());
    let mut closing_steps = 0;
    for i in 0..12 {
        let mut cond = sampled(i, &w);
        cond.variant = ObjectVariant {
            family: ObjectFamily::Box,
            size: ObjectSize::Large,
        };
        let stream = || rng::stream(0, "t", "grip", i);
        let mut gripping = Gripping {
            inner: osms_sim::catcher::ScriptedCatcher::new(
                catcher(Some(margin)),
                spec.control.clone(),
            ),
            margin,
            open,
            closing_steps: 0,
        };
        let soft = Episode::new(&w, &spec, cond.clone(), stream()).run(&mut gripping, &mut NoHooks);
        closing_steps += gripping.closing_steps;
        let mut jumping =
            osms_sim::catcher::ScriptedCatcher::new(catcher(None), spec.control.clone());
        let hard = Episode::new(&w, &spec, cond, stream()).run(&mut jumping, &mut NoHooks);
        if let (Some(s), Some(h)) = (held_squeeze(&soft), held_squeeze(&hard)) {
            with.push(s);
            without.push(h);
        }
    }
    assert!(
        closing_steps > 100,
        "only {closing_steps} closing steps checked"
    );
    assert!(with.len() >= 3, "only {} throws held both ways", with.len());
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(
        mean(&with) < 0.7 * mean(&without),
        "squeeze with a {margin} rad margin {:.1} N, without {:.1} N ({} throws)",
        mean(&with),
        mean(&without),
        with.len()
    );
}

#[test]
fn a_grip_margin_that_is_not_a_positive_angle_is_refused() {
    for m in [0.0, -0.1, f64::NAN, f64::INFINITY] {
        let spec = osms_sim::catcher::CatcherSpec {
            grip_margin_rad: Some(m),
            ..osms_sim::catcher::CatcherSpec::default()
        };
        let e = spec.validate().expect_err("refused").to_string();
        assert!(e.contains("grip_margin_rad"), "{e}");
    }
    assert!(osms_sim::catcher::CatcherSpec::default().validate().is_ok());
}

/// The flight estimate a policy reads (`PolicyView::tracked`) against the object's true state
/// in real rollouts under the paper DR (5 mm noise, a delay of 0 or 1 step): from the fifth
/// control step to the first contact its position error is a few millimetres, several times
/// below the 8-frame fit's and the raw observation's, which lag by the delay.
#[test]
fn the_flight_estimate_tracks_the_object_now_under_noise_and_delay() {
    use osms_sim::catcher::{CatcherSpec, ScriptedCatcher, estimate_object, fit_range};
    use osms_sim::control::DrSpec;

    /// Four 3-vectors a step, in the order the watcher records them.
    type Seen = ([f64; 3], [f64; 3], [f64; 3], [f64; 3]);
    struct Watch {
        inner: ScriptedCatcher,
        seen: Vec<Seen>,
    }
    impl Policy for Watch {
        fn act(&mut self, view: &PolicyView<'_>) -> Action {
            let tracked = view.tracked();
            let frames: Vec<&[f64]> = view
                .history
                .range(fit_range(view.step, view.history.len(), 8))
                .map(Vec::as_slice)
                .collect();
            let fit = estimate_object(&frames, view.world.control_period_secs());
            let truth = view.data.qpos()[view.world.ids.object_qpos..][..3].to_vec();
            if view.step >= 5 && view.first_contact.is_none() {
                self.seen.push((
                    tracked.pos,
                    fit.pos,
                    view.object.pos,
                    [truth[0], truth[1], truth[2]],
                ));
            }
            self.inner.act(view)
        }
        fn reads_contact_force(&self) -> bool {
            false
        }
    }
    let world = world();
    let spec = RolloutSpec {
        dr: DrSpec::paper(),
        history_steps: 8,
        ..RolloutSpec::default()
    };
    let mut watch = Watch {
        inner: ScriptedCatcher::new(CatcherSpec::default(), spec.control.clone()),
        seen: Vec::new(),
    };
    for i in 0..20 {
        let condition = sample(
            &ConditionSpec::default(),
            world.home_palm_pos,
            &mut rng::stream(3, "test", "tracked", i),
        )
        .expect("condition");
        Episode::new(
            &world,
            &spec,
            condition,
            rng::stream(3, "test", "tracked-dr", i),
        )
        .run(&mut watch, &mut NoHooks);
    }
    let error = |pick: fn(&Seen) -> [f64; 3]| {
        watch
            .seen
            .iter()
            .map(|s| {
                let (p, t) = (pick(s), s.3);
                ((p[0] - t[0]).powi(2) + (p[1] - t[1]).powi(2) + (p[2] - t[2]).powi(2)).sqrt()
            })
            .sum::<f64>()
            / watch.seen.len() as f64
    };
    let (tracked, fit, raw) = (error(|s| s.0), error(|s| s.1), error(|s| s.2));
    println!(
        "{} steps: mean position error tracked {tracked:.4} m, 8-frame fit {fit:.4} m, observed {raw:.4} m",
        watch.seen.len()
    );
    assert!(watch.seen.len() > 100, "{} steps", watch.seen.len());
    assert!(tracked < 0.01, "tracked off by {tracked} m");
    assert!(tracked < fit / 3.0 && tracked < raw / 3.0);
}
