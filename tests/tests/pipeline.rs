//! The shipped `pipeline.toml` on the `tiny` profile with the shipped stage kinds: outputs that
//! do not depend on threads or shards, and content hashes per platform class
//! (`golden/outputs_pipeline_tiny@<class>.snap`, checked where the running class has one); on
//! the same store, the datasets' exports, the report, and the Python package against osms's own
//! evaluations.

use std::collections::BTreeMap;
use std::path::Path;

use osms_make::{MakeOptions, Pipeline, Plan};
use osms_store::{Hash, Store};
use osms_tests::golden;
use osms_tests::project::{Silent, hashes};

#[path = "pipeline/remote.rs"]
mod remote;

fn shipped() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../pipeline.toml"))
        .expect("pipeline.toml")
}

struct Made {
    hashes: BTreeMap<String, Hash>,
    /// Instances computed by this make (not found in the store).
    built: usize,
    outputs: Vec<golden::Output>,
    plan: Plan,
    store: Store,
    _dir: tempfile::TempDir,
}

/// Builds `text` on the tiny profile in a fresh store. With `teachers_from`, that build's
/// teachers are copied in first: PPO's thread independence has its own test
/// (osms-policy's catching.rs), and retraining the teachers per variation would double CI.
fn make(text: &str, jobs: usize, teachers_from: Option<&Made>) -> Made {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("pipeline.toml");
    std::fs::write(&path, text).expect("write");
    let plan = Plan::new(
        &Pipeline::load(&path, Some("tiny")).expect("load"),
        &osms_kinds::registry(),
    )
    .expect("plan");
    let store = Store::open(dir.path().join("store")).expect("store");
    if let Some(from) = teachers_from {
        let (records, _) = from.store.records().expect("records");
        for r in records.iter().filter(|r| r.kind == "teacher") {
            let bytes = from.store.get(&r.content_hash).expect("teacher object");
            assert_eq!(store.put(&bytes).expect("put"), r.content_hash);
            store.put_record(r).expect("record");
        }
    }
    let opts = MakeOptions {
        targets: vec![],
        seeds: vec![0],
        jobs,
        stages: 1,
        dry_run: false,
    };
    let report = osms_make::make(&plan, &store, &opts, &Silent).expect("make");
    assert!(report.failed().is_empty(), "{:?}", report.failed());
    Made {
        hashes: hashes(&report),
        built: report.count(|o| matches!(o, osms_make::Outcome::Built { .. })),
        outputs: golden::outputs(&plan, &report),
        plan,
        store,
        _dir: dir,
    }
}

/// Builds `text` on the tiny profile in `made`'s store (what is there is reused): the hashes and
/// the instances computed.
fn remake(made: &Made, text: &str) -> (BTreeMap<String, Hash>, Vec<String>) {
    remake_seeds(made, text, &[0])
}

/// [`remake`] for the run seeds `seeds`.
fn remake_seeds(made: &Made, text: &str, seeds: &[u64]) -> (BTreeMap<String, Hash>, Vec<String>) {
    let path = made._dir.path().join("variant.toml");
    std::fs::write(&path, text).expect("write");
    let plan = Plan::new(
        &Pipeline::load(&path, Some("tiny")).expect("load"),
        &osms_kinds::registry(),
    )
    .expect("plan");
    let opts = MakeOptions {
        targets: vec![],
        seeds: seeds.to_vec(),
        jobs: 2,
        stages: 1,
        dry_run: false,
    };
    let report = osms_make::make(&plan, &made.store, &opts, &Silent).expect("make");
    assert!(report.failed().is_empty(), "{:?}", report.failed());
    let built = report
        .instances
        .iter()
        .filter(|r| matches!(r.outcome, osms_make::Outcome::Built { .. }))
        .map(|r| r.instance.clone())
        .collect();
    (hashes(&report), built)
}

fn load<A: osms_core::Artifact>(made: &Made, instance: &str) -> A {
    osms_core::decode(&object(made, instance)).expect("decode")
}

fn object(made: &Made, instance: &str) -> Vec<u8> {
    let hash = made
        .hashes
        .get(instance)
        .unwrap_or_else(|| panic!("{instance} built"));
    made.store.get(hash).expect("object")
}

/// The whole artifact of an itemised stage (a manifest of its items in the store).
fn load_sharded<A: osms_make::Sharded>(made: &Made, instance: &str) -> A {
    osms_make::assemble(
        &object(made, instance),
        &osms_make::StoreObjects(&made.store),
    )
    .expect("assemble")
}

#[test]
fn tiny_outputs_do_not_depend_on_threads_or_shards_and_match_the_golden_hashes() {
    let text = shipped();
    let first = make(&text, 1, None);
    let reference = first.hashes.clone();
    assert_eq!(reference.len(), 123, "{reference:?}");
    datasets_are_disjoint_successes_and_aligned(&first);
    osw_alignment_holds_in_independent_replays(&first);
    successful_rollouts_pass_through_all_five_phases(&first);
    the_osw_projection_is_its_datasets_windows(&first);
    candidate_sets_cover_d_r_and_are_matched(&first);
    the_tiny_teacher_beats_the_scripted_prior(&first);
    a_damaged_dataset_shard_is_detected_and_rebuilt(&first);
    cross_fitting_never_scores_a_student_on_its_training_conditions(&first);
    calibration_compares_pi_bar_and_the_models_on_common_draws(&first);
    teacher_queries_reproduce_the_teacher(&first);
    student_rollouts_are_deterministic_and_see_their_training_features(&first);
    interventions_replay_hand_back_and_share_random_numbers(&first);
    validation_is_exact_when_fast_and_dstar_repeats_it(&first);
    dagger_adds_the_students_rollouts_labelled_by_the_teacher(&first);
    dart_and_dagger_il_are_size_matched_to_dstar(&first);
    let two = make(&text, 2, Some(&first));
    assert_eq!(two.hashes, reference, "1 vs 2 threads");
    assert_eq!(
        two.built,
        reference.len() - 3,
        "everything but the three teachers rebuilt"
    );
    let reshard = text
        .replace(
            "params = { n = 40 }\nshards = 2",
            "params = { n = 40 }\nshards = 5",
        )
        .replace(
            "inputs = { world = \"world\", conditions = \"heldout\" }\nshards = 4",
            "inputs = { world = \"world\", conditions = \"heldout\" }\nshards = 3",
        )
        .replace(
            "params = { n = 6 }\nshards = 2",
            "params = { n = 6 }\nshards = 4",
        )
        .replace(
            "[profiles.tiny.candidates_geodesic]\nshards = 2",
            "[profiles.tiny.candidates_geodesic]\nshards = 3",
        )
        .replace(
            "[profiles.tiny.candidates_unconditional]\nshards = 2",
            "[profiles.tiny.candidates_unconditional]\nshards = 5",
        )
        .replace(
            "[profiles.tiny.error_pairs]\nshards = 1",
            "[profiles.tiny.error_pairs]\nshards = 3",
        )
        .replace(
            "[profiles.tiny.eval_student_il]\nshards = 2",
            "[profiles.tiny.eval_student_il]\nshards = 5",
        )
        .replace(
            "[profiles.tiny.validate]\nshards = 2",
            "[profiles.tiny.validate]\nshards = 3",
        )
        .replace(
            "[profiles.tiny.dstar]\nshards = 2",
            "[profiles.tiny.dstar]\nshards = 5",
        );
    assert_eq!(
        (
            reshard.matches("shards = 5").count(),
            reshard.matches("shards = 3").count(),
            reshard.matches("params = { n = 6 }\nshards = 4").count()
        ),
        (4, 4, 2),
        "the overlays were edited"
    );
    assert_eq!(
        make(&reshard, 2, Some(&first)).hashes,
        reference,
        "other shard counts"
    );
    the_report_shows_its_sources(&first);
    remote::a_remote_cache_serves_a_fresh_store(&first);
    datasets_export_replay_and_render(&first);
    a_sweep_rebuilds_only_its_seeds_and_the_aggregates(&first, &text);
    paired_experiments_compare_rollout_by_rollout(&first);
    long_builds_resume_from_their_checkpoints(&first);
    // Last: it builds a condition set into a store of its own beside this one.
    the_python_package_reproduces_osms_evaluations(&first, &text);
    golden::check("outputs_pipeline_tiny", first.outputs);
}

/// The closed-loop calibration and a student, killed after a checkpoint (a calibration
/// checkpoints after every block of tuning conditions, a student every so many gradient
/// steps), resume from it and end with the bytes of a build that ran through.
fn long_builds_resume_from_their_checkpoints(made: &Made) {
    let bin = env!("CARGO_BIN_EXE_osms-shipped");
    let pipeline = made._dir.path().join("pipeline.toml");
    let root = made.store.root();
    let make = |stage: &str, sets: &[&str]| {
        let mut c = std::process::Command::new(bin);
        c.arg("--pipeline")
            .arg(&pipeline)
            .arg("--store")
            .arg(root)
            .args(["make", stage, "-p", "tiny", "--seed", "0", "--json"]);
        for s in sets {
            c.args(["--set", s]);
        }
        c.env("OSMS_NO_PROGRESS", "1")
            .env_remove("OSMS_LOG")
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped());
        c
    };
    let built = |o: &std::process::Output, instance: &str| -> (Hash, String) {
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let report: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
        let i = report["instances"]
            .as_array()
            .expect("instances")
            .iter()
            .find(|i| i["instance"] == instance || i["instance"] == format!("{instance}@0"))
            .unwrap_or_else(|| panic!("{instance} in {report}"));
        let key: Hash = i["key"].as_str().expect("key").parse().expect("a hash");
        (key, i["content_hash"].as_str().expect("hash").to_string())
    };
    for (stage, sets) in [
        (
            "error_model_calibrated",
            &["error_model_calibrated.checkpoint_every=1"][..],
        ),
        (
            "student_ours",
            &[
                "student_ours.steps=2000",
                "student_ours.checkpoint_every=50",
            ],
        ),
    ] {
        // `stage`, or `stage@0` for one that depends on the run seed.
        let instance = stage.to_string();
        let (key, through) = built(&make(stage, sets).output().expect("run osms"), &instance);
        // Forget the build and any checkpoint it left, then build again and kill it.
        std::fs::write(made.store.record_path(&key), "garbled").expect("garble");
        let _ = std::fs::remove_file(made.store.record_path(&osms_make::checkpoint_key(&key)));
        let mut child = make(stage, sets).spawn().expect("start osms");
        let done = loop {
            if let Some(status) = child.try_wait().expect("wait") {
                panic!("{instance} ended ({status}) before a checkpoint was seen");
            }
            if let Ok(Some(r)) = made.store.record(&osms_make::checkpoint_key(&key)) {
                child.kill().expect("kill -9");
                child.wait().expect("reap");
                break r.shard.expect("a checkpoint names its build").end;
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        };
        let o = make(stage, sets).output().expect("run osms");
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(
            err.contains(&format!("{stage}: resuming from its checkpoint after")),
            "killed after {done} steps: {err}"
        );
        assert_eq!(built(&o, &instance), (key, through), "{instance}");
    }
}

/// The tables and figures hold what their source artifacts say, and every file renders.
fn the_report_shows_its_sources(made: &Made) {
    use osms_core::table::{Table, Value};
    use osms_report::artifacts::Report;
    use osms_report::plot::Figure;
    use osms_sim::artifacts::Evaluation;

    let ours: Evaluation = load_sharded(made, "eval_ours@0");
    let teacher: Evaluation = load_sharded(made, "eval_teacher");
    let success = |e: &Evaluation| {
        e.rows.iter().filter(|r| r.outcome.success()).count() as f64 / e.rows.len() as f64
    };
    let table2: Table = load(made, "table2");
    let cell = |row: &str, col: &str| table2.cell(row, col).expect("cell").ours.clone();
    assert_eq!(
        cell("Our method / Ours-IL", "task success"),
        Value::Seeds(vec![success(&ours)])
    );
    assert_eq!(
        cell("RL teacher (original)", "task success"),
        Value::One(success(&teacher))
    );

    // Table III: the phase-wise correlated row is the model validation applies (the calibrated
    // one: D_* and Ours-IL); the paper's least-squares fit keeps its metrics in a row of its own.
    {
        use osms_method::artifacts::ErrorModelArtifact;
        use osms_method::error_model::ErrorVariant;
        let table3: Table = load(made, "table3");
        let errors: ErrorModelArtifact = load(made, "error_model_calibrated");
        assert_eq!(errors.model.variant, ErrorVariant::Calibrated);
        let moment = |v: ErrorVariant| {
            let fit = errors.variants.iter().find(|f| f.model.variant == v);
            Value::One(fit.expect("fitted").metrics.moment_error)
        };
        let adopted =
            "Phase-wise correlated, calibrated in closed loop (validation's `calibrated`)";
        let least_squares = "Phase-wise correlated, least squares (the paper's fit)";
        let cell3 = |row: &str, col: &str| table3.cell(row, col).expect(row).ours.clone();
        assert_eq!(
            cell3(adopted, "π_θ task success"),
            Value::Seeds(vec![success(&ours)])
        );
        assert_eq!(
            cell3(adopted, "moment err."),
            moment(ErrorVariant::Calibrated)
        );
        assert_eq!(
            cell3(least_squares, "moment err."),
            moment(ErrorVariant::PhaseCorrelated)
        );
        assert_eq!(cell3(least_squares, "π_θ task success"), Value::Missing);
    }

    // Figure (a): the teacher's mean force at the contact step, from the rows themselves.
    let impact: Figure = load(made, "impact_profiles");
    let forces: Vec<f64> = teacher
        .rows
        .iter()
        .filter_map(|r| r.trace.as_ref()?.at(0))
        .map(|s| f64::from(s.0))
        .collect();
    assert!(forces.len() > 1, "the tiny teacher touches the object");
    let mean = forces.iter().sum::<f64>() / forces.len() as f64;
    let at_contact = impact.panels[3].series[0]
        .points
        .iter()
        .find(|p| p.x == 0.0)
        .expect("a point at t_c");
    assert_eq!(at_contact.y, mean);
    let line = format!("{},RL teacher,0,{mean},", impact.panels[3].title);
    assert!(impact.csv().contains(&line), "the CSV holds {line}");

    // Figures (b): teacher success per object variant.
    let conditions: Figure = load(made, "task_conditions");
    assert!(!conditions.panels[0].series[0].points.is_empty());
    for p in &conditions.panels[0].series[0].points {
        let v = osms_sim::spec::ObjectVariant::all()[p.x as usize];
        let rows: Vec<_> = teacher.rows.iter().filter(|r| r.variant == v).collect();
        let s = rows.iter().filter(|r| r.outcome.success()).count() as f64 / rows.len() as f64;
        assert_eq!(p.y, s, "{v}");
    }

    let report: Report = load(made, "report");
    let files = report.render().expect("render");
    let names: Vec<&str> = files.iter().map(|(n, _)| n.as_str()).collect();
    for want in [
        "index.md",
        "table1.md",
        "table2.csv",
        "table3.json",
        "fig_impact_profiles.png",
        "fig_task_conditions.svg",
        "fig_candidate_selection.png",
        "fig_ios_profile.csv",
        "fig_learning_curves.png",
        "claims.json",
    ] {
        assert!(names.contains(&want), "{want} in {names:?}");
    }
    for (name, bytes) in &files {
        assert!(!bytes.is_empty(), "{name} is empty");
    }
    let (_, png) = files
        .iter()
        .find(|(n, _)| n == "fig_impact_profiles.png")
        .expect("png");
    let (w, h) = impact.size();
    assert_eq!(u32::from_be_bytes(png[16..20].try_into().expect("w")), w);
    assert_eq!(u32::from_be_bytes(png[20..24].try_into().expect("h")), h);
    let index = String::from_utf8(files[0].1.clone()).expect("utf-8");
    for section in [
        "Table I",
        "Table II",
        "Table III",
        "Claims check",
        "![Learning curves]",
    ] {
        assert!(index.contains(section), "index.md has {section}");
    }
}

/// Adding a run seed builds only that seed's students and evaluations and the stages that
/// gather them; a seed set whose members are all cached rebuilds only the aggregates.
fn a_sweep_rebuilds_only_its_seeds_and_the_aggregates(made: &Made, text: &str) {
    let aggregates = [
        "ablations",
        "baselines",
        "impact_profiles",
        "learning_curves",
        "report",
        "table2",
        "table3",
        "task_conditions",
    ];
    let per_seed = |seed: u64| -> Vec<String> {
        [
            "naive",
            "normal",
            "ours",
            "global_iid",
            "phase_independent",
            "refine_only",
            "repair_only",
            "ab_direct",
            "ab_unconditional",
            "ab_euclidean",
            "ab_geodesic",
            "intended",
            "omitted",
            "least_squares",
            "dart",
            "dagger1",
            "dagger3",
        ]
        .iter()
        .flat_map(|s| [format!("student_{s}@{seed}"), format!("eval_{s}@{seed}")])
        // The development stream's evaluations of the final students.
        .chain(
            [
                "dev_student",
                "dev_student_naive",
                "dev_student_normal",
                "dev_student_dart",
                "student_naive_curve",
                "dev_student_naive_curve",
            ]
            .map(|s| format!("{s}@{seed}")),
        )
        // DAgger-IL's rounds, on the run seed's Naive-IL student.
        .chain(
            [
                "dagger1_round1",
                "dagger3_round1",
                "student_dagger3_round1",
                "dagger3_round2",
                "student_dagger3_round2",
                "dagger3_round3",
            ]
            .map(|s| format!("{s}@{seed}")),
        )
        .collect()
    };
    let sorted = |mut v: Vec<String>| {
        v.sort();
        v
    };
    let expect = |seeds: &[u64]| {
        let mut v: Vec<String> = aggregates.iter().map(|s| s.to_string()).collect();
        for &s in seeds {
            v.extend(per_seed(s));
        }
        sorted(v)
    };
    let (_, built) = remake_seeds(made, text, &[0, 2]);
    assert_eq!(sorted(built), expect(&[2]), "seed 2 added");
    let (_, built) = remake_seeds(made, text, &[0, 1, 2]);
    assert_eq!(sorted(built), expect(&[1]), "seed 1 added");
    let (hashes, built) = remake_seeds(made, text, &[1, 2]);
    assert_eq!(
        sorted(built),
        expect(&[]),
        "seed 0 removed: only the aggregates"
    );
    let (_, built) = remake_seeds(made, text, &[0]);
    assert!(
        built.is_empty(),
        "every instance for seed 0 is cached: {built:?}"
    );
    let table2: osms_core::table::Table =
        osms_core::decode(&made.store.get(&hashes["table2"]).expect("object")).expect("table2");
    let cell = table2
        .cell("Our method / Ours-IL", "task success")
        .expect("cell");
    let osms_core::table::Value::Seeds(v) = &cell.ours else {
        panic!("per-seed values: {:?}", cell.ours)
    };
    assert_eq!(v.len(), 2, "two run seeds aggregated");
}

/// D_M and D_E hold successes only; no ω is shared between D_M, D_E, D_R and the held-out set;
/// every OSW window is the teacher's arm actions of the H_OS steps before k_e.
fn datasets_are_disjoint_successes_and_aligned(made: &Made) {
    use osms_policy::artifacts::Dataset;
    use osms_sim::N_ARM;
    use osms_sim::artifacts::Conditions;

    let heldout: Conditions = load_sharded(made, "heldout");
    let mut seen: Vec<(String, String)> = heldout
        .items
        .iter()
        .map(|c| ("heldout".to_string(), format!("{c:?}")))
        .collect();
    for name in ["d_m", "d_e", "d_r"] {
        let d: Dataset = load_sharded(made, name);
        let stats = d.stats();
        assert!(!d.items.is_empty(), "{name} is empty");
        if name != "d_r" {
            assert!(d.successes_only, "{name}");
            assert!(
                d.rollouts().all(|r| r.record.outcome.success()),
                "{name} holds a failure"
            );
            assert!(stats.attempts >= d.items.len() as u64);
        } else {
            assert_eq!(
                stats.attempts,
                d.items.len() as u64,
                "D_R keeps every attempt"
            );
        }
        for r in d.rollouts() {
            let c = format!("{:?}", r.record.condition);
            if let Some((other, _)) = seen.iter().find(|(_, s)| *s == c) {
                panic!("{name} item {} shares ω with {other}", r.item);
            }
            seen.push((name.to_string(), c));
            let w = &r.osw;
            assert_eq!(w.event_step, r.record.metrics.event_step);
            assert_eq!(w.complete, w.event_step >= d.osw.h_os);
            assert_eq!(w.zeta_org.len(), (w.event_step - w.start) * N_ARM);
            let k = w.start;
            if k < w.event_step {
                assert_eq!(
                    &w.zeta_org[..N_ARM],
                    &r.record.intended[k * osms_sim::N_ACTION..k * osms_sim::N_ACTION + N_ARM]
                );
            }
        }
    }
}

/// Watches a replay from outside the catching code: the first control step at which the
/// object touches any geom of the robot (found through MuJoCo's body tree, not osms's geom
/// classes) and the step of the closest object–palm approach.
struct Witness {
    step: usize,
    object_geom: usize,
    robot_root: usize,
    object_body: usize,
    palm_site: usize,
    first_contact: Option<usize>,
    closest: (f64, usize),
}

impl osms_sim::Hooks for Witness {
    fn override_arm(&mut self, step: usize, _: &mut osms_sim::Action) {
        self.step = step;
    }
    fn after_physics_step(
        &mut self,
        data: &mujoco_rs::prelude::MjData<Box<mujoco_rs::prelude::MjModel>>,
    ) {
        let model = data.model();
        let root = |g: i32| model.body_rootid()[model.geom_bodyid()[g as usize] as usize] as usize;
        for c in data.contact() {
            let (a, b) = (c.geom[0] as usize, c.geom[1] as usize);
            let other = match (a == self.object_geom, b == self.object_geom) {
                (true, false) => c.geom[1],
                (false, true) => c.geom[0],
                _ => continue,
            };
            if root(other) == self.robot_root && self.first_contact.is_none() {
                self.first_contact = Some(self.step);
            }
        }
        let (o, p) = (
            data.xpos()[self.object_body],
            data.site_xpos()[self.palm_site],
        );
        let d = ((o[0] - p[0]).powi(2) + (o[1] - p[1]).powi(2) + (o[2] - p[2]).powi(2)).sqrt();
        if d < self.closest.0 {
            self.closest = (d, self.step);
        }
    }
}

/// Every rollout of D_M and D_R, replayed with the teacher on its recorded ω and DR stream
/// under a contact witness: the replay gives the stored record, k_e is the first object–robot
/// contact the witness saw (or its closest approach when there was none), and all H_OS × 7
/// values of ζ_org are the teacher's intended arm actions of the steps before k_e.
fn osw_alignment_holds_in_independent_replays(made: &Made) {
    use osms_policy::artifacts::Dataset;
    use osms_policy::artifacts::Teacher;
    use osms_policy::catch::CatchEpisode;
    use osms_sim::artifacts::WorldArtifact;
    use osms_sim::{N_ACTION, N_ARM};

    let world = load::<WorldArtifact>(made, "world").world().expect("world");
    let mut teacher: Teacher = load(made, "teacher");
    teacher.task.rollout.record_privileged = true;
    let model = world.model(osms_sim::ObjectVariant::all()[0]);
    let robot_root = model
        .name_to_id(mujoco_rs::prelude::MjtObjBase::mjOBJ_BODY, "arm_base")
        .expect("arm_base");
    let object_geom = model
        .name_to_id(mujoco_rs::prelude::MjtObjBase::mjOBJ_GEOM, "object_geom")
        .expect("object_geom");
    let mut with_contact = 0;
    for name in ["d_m", "d_r"] {
        let d: Dataset = load_sharded(made, name);
        // D_M runs under the paper DR, D_R without it (pipeline.toml, docs/deviations.md row 17).
        teacher.task.rollout.dr = if name == "d_m" {
            osms_sim::control::DrSpec::paper()
        } else {
            osms_sim::control::DrSpec::default()
        };
        for item in &d.items {
            let r = &item.rollout;
            let stream = osms_core::rng::stream(
                0,
                name,
                "attempt",
                u64::from(r.item) * 100 + u64::from(r.attempt),
            );
            let mut witness = Witness {
                step: 0,
                object_geom,
                robot_root,
                object_body: world.ids.object_body,
                palm_site: world.ids.palm_site,
                first_contact: None,
                closest: (f64::INFINITY, 0),
            };
            let mut episode =
                CatchEpisode::new(&world, &teacher.task, r.record.condition.clone(), stream);
            let mut act = |obs: &[f32]| teacher.agent.act_deterministic(obs);
            while !episode.step_with_hooks(&mut act, &mut witness).1 {}
            let replay = episode.run(&mut act);
            assert_eq!(
                replay, r.record,
                "{name} item {}: the replay differs",
                r.item
            );
            let k_e = r.osw.event_step;
            match witness.first_contact {
                Some(k) => {
                    with_contact += 1;
                    assert_eq!(k_e, k, "{name} item {}: k_e vs first contact", r.item);
                }
                None => assert_eq!(k_e, witness.closest.1, "{name} item {}", r.item),
            }
            assert_eq!(r.osw.start, k_e.saturating_sub(d.osw.h_os));
            let rows = k_e - r.osw.start;
            assert_eq!(r.osw.zeta_org.len(), rows * N_ARM);
            for j in 0..rows {
                let k = r.osw.start + j;
                assert_eq!(
                    &r.osw.zeta_org[j * N_ARM..(j + 1) * N_ARM],
                    &replay.intended[k * N_ACTION..k * N_ACTION + N_ARM],
                    "{name} item {}: ζ_org row {j}",
                    r.item
                );
            }
        }
    }
    assert!(with_contact > 0, "no replay touched the robot");
}

/// A successful catch passes through approach, velocity matching, one contact step, the
/// follow-through window and grasping, in that order.
fn successful_rollouts_pass_through_all_five_phases(made: &Made) {
    use osms_policy::artifacts::Dataset;
    use osms_sim::Phase;

    let d: Dataset = load_sharded(made, "d_m");
    for r in d.rollouts() {
        let phases = &r.record.phase;
        let count = |p: Phase| phases.iter().filter(|&&x| x == p as u8).count();
        assert!(
            phases.windows(2).all(|w| w[0] <= w[1]),
            "item {}: phases go back: {phases:?}",
            r.item
        );
        assert_eq!(count(Phase::Contact), 1, "item {}: {phases:?}", r.item);
        let k_c = phases
            .iter()
            .position(|&p| p == Phase::Contact as u8)
            .expect("contact");
        assert_eq!(k_c, r.record.metrics.event_step, "item {}", r.item);
        for p in [Phase::Approach, Phase::VelocityMatching, Phase::Grasping] {
            assert!(count(p) > 0, "item {}: no {p:?} in {phases:?}", r.item);
        }
        // Δt_eval = 0.2 s is ten control periods; a step is recorded as follow-through when
        // its last physics step is within Δt_eval of t_c, which holds for the nine steps after
        // the contact step, give or take one under timing jitter.
        let ft = count(Phase::FollowThrough);
        assert!(
            (8..=10).contains(&ft),
            "item {}: {ft} follow-through steps",
            r.item
        );
    }
}

fn the_tiny_teacher_beats_the_scripted_prior(made: &Made) {
    use osms_sim::artifacts::Evaluation;
    let success = |name: &str| {
        let e: Evaluation = load_sharded(made, name);
        e.overall().success_rate
    };
    let (teacher, scripted) = (success("eval_teacher"), success("eval_scripted"));
    assert!(
        teacher > scripted,
        "tiny teacher {teacher:.3} vs scripted prior {scripted:.3}"
    );
}

/// Damage one stored shard of D_M and the merged artifact: the next make detects both,
/// recomputes the shard and rebuilds D_M to the same bytes.
/// The projection holds exactly the OSW windows and ω̄ of D_M's rollouts, in order.
fn the_osw_projection_is_its_datasets_windows(made: &Made) {
    use osms_policy::artifacts::Dataset;
    use osms_policy::artifacts::OswSet;

    let d: Dataset = load_sharded(made, "d_m");
    let p: OswSet = load(made, "d_m_osw");
    assert_eq!(p.osw, d.osw);
    assert_eq!(p.windows.len(), d.items.len());
    for (w, r) in p.windows.iter().zip(d.rollouts()) {
        assert_eq!((w.item, w.attempt), (r.item, r.attempt));
        assert_eq!(w.zeta_org, r.osw.zeta_org);
        assert_eq!(w.omega_bar, r.osw.omega_bar);
        assert_eq!(w.complete, r.osw.complete);
        assert!(w.success);
    }
}

/// Every complete D_R window gets |η| = 2K + 1 candidates inside Z from each generator; the
/// ablations share the geodesic sets' rollouts and are matched to their largest deviation.
fn candidate_sets_cover_d_r_and_are_matched(made: &Made) {
    use osms_method::artifacts::CandidateSets;
    use osms_method::candidates::Generator;
    use osms_method::cvae::Cvae;
    use osms_policy::artifacts::OswSet;

    let windows: OswSet = load(made, "d_r_osw");
    let manifold: Cvae = load(made, "manifold");
    assert!(manifold.params.conditional);
    assert_eq!(manifold.w_a.len(), 8 * osms_sim::N_ARM);
    assert_eq!(manifold.windows_train + manifold.windows_heldout, 6);
    assert!(!load::<Cvae>(made, "manifold_uncond").params.conditional);
    let geo: CandidateSets = load_sharded(made, "candidates_geodesic");
    assert_eq!(geo.params.generator, Generator::Geodesic);
    for (name, generator) in [
        ("candidates_geodesic", Generator::Geodesic),
        ("candidates_euclidean", Generator::Euclidean),
        ("candidates_unconditional", Generator::Unconditional),
        ("candidates_direct", Generator::Direct),
    ] {
        let sets: CandidateSets = load_sharded(made, name);
        assert_eq!(sets.params.generator, generator);
        assert_eq!(sets.items.len(), windows.windows.len(), "{name}");
        for ((item, w), g) in sets.items.iter().zip(&windows.windows).zip(&geo.items) {
            assert_eq!(
                (item.item, item.attempt, item.success),
                (w.item, w.attempt, w.success)
            );
            assert_eq!(
                item.set.is_some(),
                w.complete,
                "{name}: sets for complete windows only"
            );
            let (Some(set), Some(g)) = (&item.set, &g.set) else {
                continue;
            };
            assert_eq!(
                set.candidates.len(),
                2 * sets.params.directions + 1,
                "{name}"
            );
            for c in &set.candidates {
                assert!(
                    c.z.iter().all(|v| v.abs() <= sets.params.bound),
                    "{name}: z in Z"
                );
                assert!(c.zeta.iter().all(|v| v.abs() <= 1.0), "{name}: ζ in bounds");
            }
            if generator == Generator::Euclidean {
                assert_eq!(
                    set.projection, g.projection,
                    "{name}: the geodesic sets' z⁰"
                );
            }
            if set.matched && generator != Generator::Geodesic {
                let rel = (set.max_deviation() - g.max_deviation()).abs() / g.max_deviation();
                assert!(rel < 1e-3, "{name}: matched deviation off by {rel}");
            }
        }
    }
    let table: osms_method::artifacts::CandidateTable = load(made, "candidates");
    let names: Vec<&str> = table.rows.iter().map(|r| r.generator.as_str()).collect();
    assert_eq!(names, ["geodesic", "euclidean", "unconditional", "direct"]);
    assert_eq!(table.rows[0], geo.stats());
}

fn a_damaged_dataset_shard_is_detected_and_rebuilt(made: &Made) {
    let d_m = made.hashes["d_m"];
    let (records, _) = made.store.records().expect("records");
    let rec = records
        .iter()
        .find(|r| r.content_hash == d_m && r.shard.is_none())
        .expect("d_m record");
    let shard = records
        .iter()
        .find(|r| r.shard.as_ref().is_some_and(|s| s.stage_key == rec.key))
        .expect("a stored shard of d_m");
    // The shard (a list of items), the manifest and one rollout.
    for hash in [shard.content_hash, d_m, rec.parts[0]] {
        let path = made.store.object_path(&hash);
        let mut bytes = std::fs::read(&path).expect("read");
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x10;
        std::fs::write(&path, bytes).expect("write");
    }
    assert!(
        !made.store.verify().expect("verify").problems.is_empty(),
        "verify sees the damage"
    );
    let opts = MakeOptions {
        targets: vec!["d_m".into()],
        seeds: vec![0],
        jobs: 2,
        stages: 1,
        dry_run: false,
    };
    let report = osms_make::make(&made.plan, &made.store, &opts, &Silent).expect("make");
    assert!(report.failed().is_empty(), "{:?}", report.failed());
    assert_eq!(hashes(&report)["d_m"], d_m, "rebuilt to the same bytes");
    assert!(
        made.store.verify().expect("verify").problems.is_empty(),
        "shard, rollout and D_M repaired"
    );
}

/// Each cross-fitted student π̄_f trains on exactly the D_E items outside fold f, and its pairs
/// come from exactly the items of fold f: no student is scored on a condition it saw, and
/// every D_E condition is scored once.
fn cross_fitting_never_scores_a_student_on_its_training_conditions(made: &Made) {
    use osms_policy::artifacts::Dataset;
    use osms_policy::artifacts::{ErrorPairs, StudentArtifact};
    use osms_sim::N_ACTION;

    let d_e: Dataset = load_sharded(made, "d_e");
    let items: Vec<u32> = d_e.rollouts().map(|r| r.item).collect();
    let mut scored = Vec::new();
    for f in 0..2u32 {
        let student: StudentArtifact = load(made, &format!("student_il#{f}"));
        let pairs: ErrorPairs = load_sharded(made, &format!("error_pairs#{f}"));
        assert_eq!(student.fold, Some((f, 2)));
        assert_eq!(pairs.fold, Some((f, 2)));
        let trained: Vec<u32> = items.iter().copied().filter(|i| i % 2 != f).collect();
        assert_eq!(
            student.items, trained,
            "student {f} trains on the other fold"
        );
        let held: Vec<u32> = pairs.rollouts.iter().map(|r| r.item).collect();
        assert!(!held.is_empty(), "fold {f} has conditions");
        for i in &held {
            assert!(
                !student.items.contains(i),
                "fold {f}: student scored on item {i}"
            );
        }
        for r in &pairs.rollouts {
            let n = r.steps();
            assert!(n > 0 && r.student.len() == n * N_ACTION && r.teacher.len() == n * N_ACTION);
            assert_eq!(r.phase[0], osms_sim::Phase::Approach as u8);
            // The pair ran on the D_E item's condition.
            let source = d_e.rollouts().find(|d| d.item == r.item).expect("item");
            assert_eq!(
                r.eval.lateral_offset_m,
                source.record.condition.lateral_offset_m
            );
            assert_eq!(r.eval.variant, source.record.condition.variant);
        }
        scored.extend(held);
    }
    scored.sort_unstable();
    assert_eq!(scored, items, "every D_E condition is scored exactly once");
}

/// `calibration` compares like with like: every held-out D_E condition of each fold once, π̄
/// and every run spec `draws` times on it, draw q with the same DR draws for π̄ and under every
/// model and κ; a run's calibration error is the mean per-condition difference of success.
fn calibration_compares_pi_bar_and_the_models_on_common_draws(made: &Made) {
    use osms_method::artifacts::{Calibration, Folds};
    use osms_policy::artifacts::ErrorPairs;

    let c: Calibration = load_sharded(made, "calibration");
    assert!(c.draws >= 2, "tiny runs {} draws", c.draws);
    let mut held: Vec<(u32, u32)> = Vec::new();
    for f in 0..2u32 {
        let pairs: ErrorPairs = load_sharded(made, &format!("error_pairs#{f}"));
        held.extend(pairs.rollouts.iter().map(|r| (f, r.item)));
    }
    let mut items: Vec<(u32, u32)> = c.items.iter().map(|i| (i.fold, i.item)).collect();
    held.sort_unstable();
    items.sort_unstable();
    assert_eq!(
        items, held,
        "the conditions `error_pairs` held out, each once"
    );
    let unperturbed = c
        .run_index("unperturbed", 1.0)
        .expect("the unperturbed teacher runs");
    let mut differ = 0;
    for i in &c.items {
        assert_eq!(i.student.rows.len(), c.draws, "item {}: π̄'s draws", i.item);
        assert_eq!(i.runs.len(), c.runs.len());
        for (r, run) in i.runs.iter().enumerate() {
            assert_eq!(run.rows.len(), c.draws, "item {}, run {r}", i.item);
            for (q, (m, s)) in run.rows.iter().zip(&i.student.rows).enumerate() {
                assert_eq!(
                    m.dr, s.dr,
                    "item {}, run {r}, draw {q}: DR draws differ",
                    i.item
                );
                assert_eq!(
                    (m.variant, m.lateral_offset_m),
                    (s.variant, s.lateral_offset_m)
                );
            }
        }
        // The draws are draws: two of them on one condition do not share their DR.
        differ += usize::from(i.student.rows[0].dr != i.student.rows[1].dr);
        let teacher = &i.runs[unperturbed].rows;
        assert!(teacher.iter().all(|r| r.steps > 0));
    }
    assert_eq!(
        differ,
        c.items.len(),
        "every condition's draws differ in DR"
    );
    let rate = |rows: &[osms_sim::artifacts::EvalRow]| {
        rows.iter().filter(|r| r.outcome.success()).count() as f64 / rows.len() as f64
    };
    for r in 0..c.runs.len() {
        let by_hand = c
            .items
            .iter()
            .map(|i| rate(&i.runs[r].rows) - rate(&i.student.rows))
            .sum::<f64>()
            / c.items.len() as f64;
        let error = c
            .run_summary(r, Folds::Both)
            .calibration_error
            .expect("an interval over the conditions");
        assert!(
            (error.estimate - by_hand).abs() < 1e-12,
            "run {r}: {} against {by_hand}",
            error.estimate
        );
        assert!(error.low <= error.estimate && error.estimate <= error.high);
    }
}

/// The DAgger diagnostic (not part of the report): one group per D_E condition π̄_0 trained on,
/// each with the teacher's own demonstration of it and π̄_0's rollout labelled with teacher
/// actions; a student trains on the set and is evaluated on the development stream.
fn dagger_adds_the_students_rollouts_labelled_by_the_teacher(made: &Made) {
    use osms_policy::artifacts::{Dataset, DemoSet, Execution, StudentArtifact};
    use osms_policy::student::Demo;
    use osms_sim::N_ACTION;

    let set: DemoSet = load_sharded(made, "dagger");
    let student: StudentArtifact = load(made, "student_il#0");
    let d_e: Dataset = load_sharded(made, "d_e");
    assert_eq!(
        set.groups.iter().map(|g| g.item).collect::<Vec<_>>(),
        student.items,
        "one group per condition π̄_0 trained on"
    );
    for g in &set.groups {
        let source = d_e.rollouts().find(|r| r.item == g.item).expect("item");
        assert_eq!(g.demos.len(), 2, "item {}", g.item);
        assert_eq!(g.demos[0].execution, Execution::Original);
        assert_eq!(g.demos[0].demo, Demo::from_record(&source.record));
        let visited = &g.demos[1];
        assert_eq!(visited.execution, Execution::StudentVisited);
        let d = &visited.demo;
        assert!(d.steps > 0 && d.actions.len() == d.steps * N_ACTION);
        // Its frames are the student's rollout, not the teacher's.
        assert_ne!(d.deployable, g.demos[0].demo.deployable, "item {}", g.item);
        assert!(
            d.actions.iter().all(|a| a.is_finite() && a.abs() <= 1.0),
            "teacher labels are actions in [-1, 1]"
        );
    }
    let trained: StudentArtifact = load(made, "student_dagger");
    assert_eq!(
        trained.items, student.items,
        "the student trains on those groups"
    );
}

/// Issue 68's baselines. DART-IL: as many teacher successes under the calibrated error model
/// (κ = 1) as D_* has demonstrations, from conditions of its own stream, each labelled with the
/// actions the teacher intended: a replay from the stage's streams reproduces the rollout, its
/// intended actions are the labels and the executed (perturbed) ones differ from them.
/// DAgger-IL: after R rounds each of the B = ⌊|D_*| / (R + 1)⌋ leading Naive conditions holds
/// its Naive demonstration, then one teacher-labelled rollout per round of the student trained
/// on the round before.
fn dart_and_dagger_il_are_size_matched_to_dstar(made: &Made) {
    use osms_method::artifacts::ErrorModelArtifact;
    use osms_method::error_model::Perturber;
    use osms_method::intervene::{Errors, execute};
    use osms_method::stages::DartParams;
    use osms_policy::artifacts::{Dataset, DemoSet, Execution, StudentArtifact, Teacher};
    use osms_policy::student::Demo;
    use osms_sim::artifacts::WorldArtifact;

    let dstar: DemoSet = load_sharded(made, "dstar");
    let target = dstar.len();
    let dart: DemoSet = load_sharded(made, "dart");
    assert_eq!((dart.target, dart.len()), (Some(target), target));
    let world = load::<WorldArtifact>(made, "world").world().expect("world");
    let mut teacher: Teacher = load(made, "teacher");
    teacher.task = load_sharded::<Dataset>(made, "d_r").task;
    teacher.task.rollout.record_privileged = false;
    // The tiny profile injects another fit and keeps failures (pipeline.toml says why).
    let stage = made
        .plan
        .stages
        .iter()
        .find(|s| s.name == "dart")
        .expect("dart");
    let p: DartParams = serde_json::from_value(stage.params.json.clone()).expect("params");
    let artifact: ErrorModelArtifact = load(made, "error_model_calibrated");
    let model = match p.error_model {
        None => artifact.model,
        Some(v) => {
            artifact
                .variants
                .into_iter()
                .find(|f| f.model.variant == v)
                .expect("fit")
                .model
        }
    }
    .with_kappa(p.kappa);
    let mut perturbed = 0;
    for g in dart.used_groups() {
        assert_eq!(g.demos.len(), 1, "item {}", g.item);
        let entry = &g.demos[0];
        assert_eq!(entry.execution, Execution::Dart);
        assert!(g.original_success || !p.successes_only, "successes only");
        let stream = u64::from(g.item) * 100 + u64::from(g.attempt);
        let e = execute(
            &world,
            &teacher.task,
            &teacher.agent,
            g.condition.clone(),
            osms_core::rng::stream(0, "dart", "attempt", stream),
            None,
            Some(Errors {
                perturber: Perturber::new(&model),
                rng: osms_core::rng::stream(0, "dart", "noise", stream),
            }),
        );
        assert_eq!(
            e.record.outcome.success(),
            g.original_success,
            "item {}",
            g.item
        );
        assert_eq!(
            entry.demo,
            Demo::labelled(&e.record, e.record.intended.clone()),
            "item {}: the replay's frames, labelled with the intended actions",
            g.item
        );
        if e.commanded != e.record.intended {
            perturbed += 1;
        }
    }
    assert_eq!(
        perturbed,
        dart.used_groups().len(),
        "the noise moves every rollout"
    );
    let naive: DemoSet = load_sharded(made, "naive");
    let leading: Vec<_> = naive
        .used_groups()
        .iter()
        .filter(|g| !g.demos.is_empty())
        .collect();
    for (rounds, stage, last) in [
        (1, "dagger1_round1", "dagger1_round1@0"),
        (3, "dagger3_round3", "dagger3_round3@0"),
    ] {
        // B from the size match, unless the profile sets it (tiny's D_* is too small for three
        // rounds).
        let params = &made
            .plan
            .stages
            .iter()
            .find(|s| s.name == stage)
            .expect("stage")
            .params
            .json;
        let b = params["conditions"]
            .as_u64()
            .map_or(target / (rounds + 1), |b| b as usize);
        let set: DemoSet = load_sharded(made, last);
        assert_eq!(set.groups.len(), b, "{last}");
        assert_eq!(set.len(), b * (rounds + 1), "{last}");
        if params["conditions"].is_null() {
            assert!(set.len() <= target, "{last}: size-matched");
        }
        for (g, naive_group) in set.groups.iter().zip(&leading) {
            assert_eq!(
                g.item, naive_group.item,
                "{last}: the leading Naive conditions"
            );
            assert_eq!(
                g.demos[0], naive_group.demos[0],
                "{last}: the Naive demonstration first"
            );
            for visited in &g.demos[1..] {
                assert_eq!(visited.execution, Execution::StudentVisited);
                assert_ne!(
                    visited.demo.deployable,
                    naive_group.demos[0].demo.deployable
                );
            }
        }
    }
    // Each round's student trains on the round before, the final one on the last round.
    for (student, set) in [
        ("student_dagger3_round1@0", "dagger3_round1@0"),
        ("student_dagger3_round2@0", "dagger3_round2@0"),
        ("student_dagger3@0", "dagger3_round3@0"),
        ("student_dagger1@0", "dagger1_round1@0"),
    ] {
        let trained: StudentArtifact = load(made, student);
        let groups: Vec<u32> = load_sharded::<DemoSet>(made, set)
            .groups
            .iter()
            .map(|g| g.item)
            .collect();
        assert_eq!(trained.items, groups, "{student} trains on {set}");
    }
    let round2: DemoSet = load_sharded(made, "dagger3_round2@0");
    assert!(round2.groups.iter().all(|g| g.demos.len() == 3));
}

/// The teacher as a query (its own prior and phase input following the visited states) is the
/// teacher: acting with its answers reproduces the teacher's own rollout bit for bit.
fn teacher_queries_reproduce_the_teacher(made: &Made) {
    use osms_policy::artifacts::Dataset;
    use osms_policy::artifacts::Teacher;
    use osms_policy::catch::{TeacherQuery, rollout};
    use osms_sim::artifacts::WorldArtifact;

    struct Query<'a>(TeacherQuery<'a>);
    impl osms_sim::Policy for Query<'_> {
        fn act(&mut self, view: &osms_sim::PolicyView<'_>) -> osms_sim::Action {
            self.0.act(view)
        }
    }
    let world = load::<WorldArtifact>(made, "world").world().expect("world");
    let mut teacher: Teacher = load(made, "teacher");
    teacher.task.rollout.dr = osms_sim::control::DrSpec::paper();
    let d_e: Dataset = load_sharded(made, "d_e");
    for r in d_e.rollouts().take(3) {
        let stream = osms_core::rng::stream(0, "test", "query", u64::from(r.item));
        let own = rollout(
            &world,
            &teacher.task,
            &teacher.agent,
            r.record.condition.clone(),
            stream.clone(),
        );
        let mut policy = Query(TeacherQuery::new(&teacher.agent, &teacher.task));
        let mut episode = osms_sim::Episode::new(
            &world,
            &teacher.task.rollout,
            r.record.condition.clone(),
            stream,
        );
        while episode.step(&mut policy, &mut osms_sim::NoHooks) {
            if let Some(&p) = episode.record().phase.last() {
                policy.0.observe_phase(p);
            }
        }
        assert_eq!(episode.finish(), own, "item {}", r.item);
    }
}

/// A student rollout is a function of its streams (twice the same record; another policy
/// stream, another record), and the observation the policy sees online is the one training
/// builds from the record.
fn student_rollouts_are_deterministic_and_see_their_training_features(made: &Made) {
    use osms_policy::artifacts::Dataset;
    use osms_policy::artifacts::StudentArtifact;
    use osms_policy::artifacts::Teacher;
    use osms_policy::student::{Demo, Student, StudentPolicy, paired_rollout, rollout};
    use osms_sim::artifacts::WorldArtifact;

    struct Watch<'s> {
        inner: StudentPolicy<'s>,
        seen: Vec<Vec<f32>>,
    }
    impl osms_sim::Policy for Watch<'_> {
        fn act(&mut self, view: &osms_sim::PolicyView<'_>) -> osms_sim::Action {
            self.seen.push(self.inner.student().observation(view));
            self.inner.act(view)
        }
    }
    let world = load::<WorldArtifact>(made, "world").world().expect("world");
    let student: Student = load::<StudentArtifact>(made, "student_il#0").student;
    let mut teacher: Teacher = load(made, "teacher");
    teacher.task.rollout.dr = osms_sim::control::DrSpec::paper();
    let spec = student.rollout_spec(&teacher.task.rollout);
    let d_e: Dataset = load_sharded(made, "d_e");
    let condition = d_e
        .rollouts()
        .next()
        .expect("a rollout")
        .record
        .condition
        .clone();
    let dr = || osms_core::rng::stream(0, "test", "dr", 0);
    let policy = |i: u64| osms_core::rng::stream(0, "test", "policy", i);
    let once = rollout(&world, &spec, &student, condition.clone(), dr(), policy(0));
    let twice = rollout(&world, &spec, &student, condition.clone(), dr(), policy(0));
    assert_eq!(once, twice, "same streams, same record");
    // Sampling from the learned distribution (noise scale 1) makes the policy stream matter.
    let mut sampling = student.clone();
    sampling.params.noise_scale = 1.0;
    let first = rollout(&world, &spec, &sampling, condition.clone(), dr(), policy(0));
    let again = rollout(&world, &spec, &sampling, condition.clone(), dr(), policy(0));
    let other = rollout(&world, &spec, &sampling, condition.clone(), dr(), policy(1));
    assert_eq!(first, again, "same streams, same record");
    assert_ne!(first.intended, other.intended, "the policy's noise matters");
    // Episodes stepped in lockstep, the policy acting on all running ones at once, are the
    // episodes run one by one: conditions of D_E, episodes of different lengths, noise that
    // matters.
    let items: Vec<_> = d_e
        .rollouts()
        .take(6)
        .enumerate()
        .map(|(i, r)| {
            let dr = osms_core::rng::stream(0, "test", "dr", i as u64);
            (r.record.condition.clone(), dr, policy(i as u64))
        })
        .collect();
    let alone: Vec<_> = items
        .iter()
        .map(|(c, dr, p)| rollout(&world, &spec, &sampling, c.clone(), dr.clone(), p.clone()))
        .collect();
    let lengths: std::collections::BTreeSet<usize> = alone.iter().map(|r| r.steps).collect();
    assert!(
        lengths.len() > 1,
        "episodes of one length only: {lengths:?}"
    );
    // Fewer slots than episodes: an ended episode's slot takes the next condition.
    let paper = osms_policy::student::ChunkExecution::default();
    for slots in [1, 2, 4] {
        assert_eq!(
            osms_policy::student::rollouts_in_slots(
                &world,
                &spec,
                (&sampling, paper),
                items.clone(),
                slots
            ),
            alone,
            "lockstep in {slots} slots = one by one"
        );
    }
    assert_eq!(
        osms_policy::student::rollouts(&world, &spec, &sampling, items.clone()),
        alone,
        "lockstep = one by one"
    );
    // Other chunk executions (issue 68): in lockstep, where only some episodes sample at a
    // step, each episode is still its rollout alone under the same execution, and the
    // execution changes what the student does.
    for execution in [
        osms_policy::student::ChunkExecution {
            horizon: 3,
            ensemble: None,
        },
        osms_policy::student::ChunkExecution {
            horizon: 1,
            ensemble: Some(0.01),
        },
    ] {
        let alone_executed: Vec<_> = items
            .iter()
            .map(|(c, dr, p)| {
                let mut policy = StudentPolicy::with_execution(&sampling, p.clone(), execution);
                osms_sim::Episode::new(&world, &spec, c.clone(), dr.clone())
                    .run(&mut policy, &mut osms_sim::NoHooks)
            })
            .collect();
        for slots in [1, 4] {
            assert_eq!(
                osms_policy::student::rollouts_in_slots(
                    &world,
                    &spec,
                    (&sampling, execution),
                    items.clone(),
                    slots
                ),
                alone_executed,
                "{execution:?}: lockstep in {slots} slots = one by one"
            );
        }
        for (a, b) in alone_executed.iter().zip(&alone) {
            assert_ne!(a.intended, b.intended, "{execution:?} acts as the paper's");
        }
    }
    // Querying the teacher does not change what the student does.
    let paired = paired_rollout(
        &world,
        &spec,
        &student,
        (&teacher.agent, &teacher.task),
        condition.clone(),
        dr(),
        policy(0),
    );
    assert_eq!(paired.record, once);
    assert_eq!(paired.phase.len(), once.steps);
    for n in 1..once.steps {
        assert_eq!(
            paired.phase[n],
            once.phase[n - 1],
            "online phase at step {n}"
        );
    }

    let mut watch = Watch {
        inner: StudentPolicy::new(&student, policy(0)),
        seen: Vec::new(),
    };
    let record = osms_sim::Episode::new(&world, &spec, condition, dr())
        .run(&mut watch, &mut osms_sim::NoHooks);
    assert_eq!(record, once);
    let demo = Demo::from_record(&record);
    for (n, seen) in watch.seen.iter().enumerate() {
        let mut built = Vec::new();
        demo.observation(n, &student.params, &mut built);
        assert_eq!(
            &built, seen,
            "step {n}: training and deployment observations differ"
        );
    }
    // The optional inputs too (palm features, the oracle's object velocity, the arm's targets,
    // the flight estimate, no previous actions): only the observation is compared, so the
    // untrained shapes do not matter.
    let mut variant = student.clone();
    variant.params.palm = true;
    variant.params.object_differences = true;
    variant.params.oracle_object_velocity = true;
    variant.params.arm_target = true;
    variant.params.tracked_object = true;
    variant.params.previous_actions = false;
    let mut views = Vec::new();
    struct Views<'s> {
        student: &'s Student,
        inner: StudentPolicy<'s>,
        seen: &'s mut Vec<Vec<f32>>,
    }
    impl osms_sim::Policy for Views<'_> {
        fn act(&mut self, view: &osms_sim::PolicyView<'_>) -> osms_sim::Action {
            self.seen.push(self.student.observation(view));
            self.inner.act(view)
        }
    }
    let again = osms_sim::Episode::new(&world, &spec, record.condition.clone(), dr()).run(
        &mut Views {
            student: &variant,
            inner: StudentPolicy::new(&student, policy(0)),
            seen: &mut views,
        },
        &mut osms_sim::NoHooks,
    );
    assert_eq!(again, record);
    for (n, seen) in views.iter().enumerate() {
        let mut built = Vec::new();
        demo.observation(n, &variant.params, &mut built);
        assert_eq!(built.len(), variant.params.obs_len());
        assert_eq!(&built, seen, "step {n}: the optional inputs differ");
    }
}

/// The event-aligned intervention (paper 4.2): replaying ζ_org in its window reproduces the D_R
/// rollout; a window reaching past the first contact hands the arm back the step after it (the
/// snippet's later rows never run); with the error model, two runs of one candidate on the same
/// stream are identical, and two candidates share the rollout up to the window's start.
fn interventions_replay_hand_back_and_share_random_numbers(made: &Made) {
    use osms_method::artifacts::ErrorModelArtifact;
    use osms_method::error_model::Perturber;
    use osms_method::intervene::{Errors, Snippet, execute};
    use osms_policy::artifacts::Dataset;
    use osms_policy::artifacts::Teacher;
    use osms_sim::artifacts::WorldArtifact;
    use osms_sim::{N_ACTION, N_ARM, Phase};

    let world = load::<WorldArtifact>(made, "world").world().expect("world");
    let mut teacher: Teacher = load(made, "teacher");
    // D_R runs without DR (pipeline.toml, docs/deviations.md row 17), the teacher trained under it.
    teacher.task.rollout.dr = osms_sim::control::DrSpec::default();
    teacher.task.rollout.record_privileged = true;
    let model = load::<ErrorModelArtifact>(made, "error_model").model;
    let d_r: Dataset = load_sharded(made, "d_r");
    assert_eq!(d_r.task, teacher.task, "D_R keeps the task it ran");
    let (mut replayed, mut handed_back) = (0, 0);
    for r in d_r.rollouts().filter(|r| r.osw.complete) {
        assert_eq!(
            r.dr_stream,
            osms_core::rng::StreamId {
                seed: 0,
                stage: "d_r".into(),
                name: "attempt".into(),
                index: u64::from(r.item) * 100 + u64::from(r.attempt),
            }
        );
        let dr = || r.dr_stream.rng();
        let run = |snippet: Option<Snippet<'_>>, errors: Option<Errors<'_>>| {
            execute(
                &world,
                &d_r.task,
                &teacher.agent,
                r.record.condition.clone(),
                dr(),
                snippet,
                errors,
            )
        };
        let (start, k_e) = (r.osw.start, r.osw.event_step);
        let original = Snippet {
            start,
            zeta: &r.osw.zeta_org,
        };
        let replay = run(Some(original), None);
        assert_eq!(replay.record, r.record, "item {}: ζ_org replay", r.item);
        assert_eq!(
            replay.commanded, r.record.intended,
            "no errors, no perturbation"
        );
        if r.record.steps > k_e {
            assert_eq!(replay.handed_back_at, Some(k_e));
        }
        replayed += 1;

        // The original's arm rows up to and including the contact step, then rows the teacher
        // never sent: they must not run.
        if r.record.phase.get(k_e) == Some(&(Phase::Contact as u8)) && k_e >= 2 {
            let mut zeta = Vec::new();
            for k in k_e - 2..=k_e {
                zeta.extend_from_slice(&r.record.intended[k * N_ACTION..k * N_ACTION + N_ARM]);
            }
            zeta.extend(std::iter::repeat_n(0.9f32, 3 * N_ARM));
            let past = run(
                Some(Snippet {
                    start: k_e - 2,
                    zeta: &zeta,
                }),
                None,
            );
            assert_eq!(past.handed_back_at, Some(k_e + 1), "item {}", r.item);
            assert_eq!(
                past.record, r.record,
                "item {}: the teacher took over",
                r.item
            );
            handed_back += 1;
        }

        // Common random numbers: the same candidate twice, and another candidate, on stream q.
        let errors = || Errors {
            perturber: Perturber::new(&model),
            rng: osms_core::rng::stream(0, "test", "errors", u64::from(r.item)),
        };
        let a = run(Some(original), Some(errors()));
        assert_eq!(
            a,
            run(Some(original), Some(errors())),
            "same candidate, same stream"
        );
        assert!(a.commanded.iter().all(|c| c.abs() <= 1.0));
        assert_ne!(a.commanded, a.record.intended, "the error model perturbs");
        let shifted: Vec<f32> = r
            .osw
            .zeta_org
            .iter()
            .map(|z| (z * 0.5).clamp(-1.0, 1.0))
            .collect();
        let b = run(
            Some(Snippet {
                start,
                zeta: &shifted,
            }),
            Some(errors()),
        );
        let prefix = start * N_ACTION;
        assert_eq!(
            a.commanded[..prefix],
            b.commanded[..prefix],
            "shared prefix"
        );
        assert_eq!(a.record.executed[..prefix], b.record.executed[..prefix]);
        assert_eq!(
            a.record.deployable[..start * osms_sim::policy::DEPLOYABLE_LEN],
            b.record.deployable[..start * osms_sim::policy::DEPLOYABLE_LEN]
        );
    }
    assert!(
        replayed > 0 && handed_back > 0,
        "{replayed} replays, {handed_back} hand-backs"
    );
}

/// Validation's fast path (shared prefixes, early stops, Alg. 1's order) gives the exhaustive
/// evaluation's bytes, for the geodesic sets and for the `direct` sets (near ζ_org, so on tiny
/// they reach the perturbed rollouts the geodesic ones do not); D_* repeats the validation's
/// rollouts and keeps successes only; a duplicated candidate gets identical outcomes (common
/// random numbers).
fn validation_is_exact_when_fast_and_dstar_repeats_it(made: &Made) {
    use osms_method::artifacts::CandidateSets;
    use osms_method::artifacts::ErrorModelArtifact;
    use osms_method::artifacts::Validation;
    use osms_method::validate::{Case, Robustness, ValidateParams, validate};
    use osms_policy::artifacts::Dataset;
    use osms_policy::artifacts::Teacher;
    use osms_policy::artifacts::{DemoSet, Execution, Origin};
    use osms_sim::artifacts::WorldArtifact;
    use osms_sim::policy::DEPLOYABLE_LEN;
    use osms_sim::{N_ACTION, N_ARM};

    let extra = r#"
[stages.validate_direct]
kind = "validate"
seed = 0
inputs = { world = "world", teacher = "teacher", data = "d_r", candidates = "candidates_direct", error_model = "error_model" }
shards = 2
params = { q = 6 }

[stages.dstar_direct]
kind = "dstar"
inputs = { world = "world", teacher = "teacher", data = "d_r", candidates = "candidates_direct", error_model = "error_model", validation = "validate_direct" }
shards = 3

# Errors small enough that tiny's selected candidates survive some perturbed rollouts: the
# ablation labels of D_* act on those.
[stages.error_model_gentle]
kind = "error_model"
seed = 0
inputs = { pairs = "error_pairs#*" }
params = { kappa = 0.05 }

[stages.validate_gentle]
kind = "validate"
seed = 0
inputs = { world = "world", teacher = "teacher", data = "d_r", candidates = "candidates_direct", error_model = "error_model_gentle" }
params = { q = 6, rollouts = 0 }

[stages.dstar_gentle]
kind = "dstar"
inputs = { world = "world", teacher = "teacher", data = "d_r", candidates = "candidates_direct", error_model = "error_model_gentle", validation = "validate_gentle" }

[stages.dstar_gentle_intended]
kind = "dstar"
inputs = { world = "world", teacher = "teacher", data = "d_r", candidates = "candidates_direct", error_model = "error_model_gentle", validation = "validate_gentle" }
params = { perturbed_labels = "intended" }

[stages.dstar_gentle_omit]
kind = "dstar"
inputs = { world = "world", teacher = "teacher", data = "d_r", candidates = "candidates_direct", error_model = "error_model_gentle", validation = "validate_gentle" }
params = { perturbed_labels = "omit" }

[stages.validate_unperturbed]
kind = "validate"
seed = 0
inputs = { world = "world", teacher = "teacher", data = "d_r", candidates = "candidates_direct", error_model = "error_model" }
shards = 2
params = { q = 6, error_model = "unperturbed" }

[stages.dstar_unperturbed]
kind = "dstar"
inputs = { world = "world", teacher = "teacher", data = "d_r", candidates = "candidates_direct", error_model = "error_model", validation = "validate_unperturbed" }
shards = 2

[stages.naive_direct]
kind = "naive"
seed = 0
inputs = { world = "world", teacher = "teacher", data = "d_r", target = "dstar_unperturbed" }
shards = 2

[stages.validate_kappa]
kind = "validate"
seed = 0
inputs = { world = "world", teacher = "teacher", data = "d_r", candidates = "candidates_direct", error_model = "error_model" }
params = { q = 6, rollouts = 0, kappa = 0.05, deviation_scale = 1.0 }

[stages.normal_extended]
kind = "normal"
seed = 0
inputs = { world = "world", teacher = "teacher", data = "d_r", candidates = "candidates_geodesic", error_model = "error_model", validation = "validate", manifold = "manifold", target = "dstar_unperturbed" }
shards = 3
"#;
    let text = format!("{}{extra}", shipped());
    let (fast, _) = remake(made, &text);
    let exhaustive = text
        .replace(
            "params = { q = 6 }",
            "params = { q = 6, exhaustive = true }",
        )
        .replace(
            "params = { q = 6, error_model = \"unperturbed\" }",
            "params = { q = 6, error_model = \"unperturbed\", exhaustive = true }",
        )
        .replace(
            "[profiles.tiny.validate]\nshards = 2",
            "[profiles.tiny.validate]\nshards = 2\nparams = { exhaustive = true }",
        );
    assert_eq!(
        exhaustive.matches("exhaustive = true").count(),
        text.matches("exhaustive = true").count() + 3,
        "the three validations were switched"
    );
    let (slow, built) = remake(made, &exhaustive);
    assert_eq!(
        built,
        ["validate", "validate_direct", "validate_unperturbed"],
        "the validations ran again, exhaustively, and nothing after them"
    );
    for s in [
        "validate",
        "dstar",
        "validate_direct",
        "dstar_direct",
        "validate_unperturbed",
        "dstar_unperturbed",
    ] {
        assert_eq!(fast[s], slow[s], "{s}: fast and exhaustive bytes");
    }
    baselines_reach_dstar_from_streams_of_their_own(made, &fast);

    // The Naive-IL data curve's set: `demos` fixes the size with no D_* wired (tiny: 20).
    let sized: DemoSet = load_sharded(made, "naive_curve");
    assert_eq!((sized.target, sized.len()), (Some(20), 20));
    assert!(sized.stats().extension_conditions > 0);

    let world = load::<WorldArtifact>(made, "world").world().expect("world");
    let teacher: Teacher = load(made, "teacher");
    let d_r: Dataset = load_sharded(made, "d_r");
    let model = load::<ErrorModelArtifact>(made, "error_model").model;
    let direct: CandidateSets = load_sharded(made, "candidates_direct");
    let v: Validation = osms_make::assemble(
        &made.store.get(&fast["validate_direct"]).expect("object"),
        &osms_make::StoreObjects(&made.store),
    )
    .expect("validation");
    let dstar: DemoSet = osms_make::assemble(
        &made.store.get(&fast["dstar_direct"]).expect("object"),
        &osms_make::StoreObjects(&made.store),
    )
    .expect("D_*");
    let stats = v.stats();
    assert!(
        stats.perturbed > 0 && stats.unperturbed_successes > stats.perturbed,
        "the tiny direct sets exercise every path: {stats:?}"
    );
    let built = |stage: &str| -> DemoSet {
        osms_make::assemble(
            &made.store.get(&fast[stage]).expect("object"),
            &osms_make::StoreObjects(&made.store),
        )
        .expect("D_*")
    };
    let (executed, intended, omit) = (
        built("dstar_gentle"),
        built("dstar_gentle_intended"),
        built("dstar_gentle_omit"),
    );
    let mut relabelled = 0;
    for (((g, gi), go), r) in executed
        .groups
        .iter()
        .zip(&intended.groups)
        .zip(&omit.groups)
        .zip(d_r.rollouts())
    {
        // The ablations change perturbed rollouts' labels or drop them, nothing else.
        assert_eq!((g.origin, g.item), (gi.origin, gi.item));
        assert_eq!((g.origin, g.item), (go.origin, go.item));
        assert_eq!(g.demos.len(), gi.demos.len());
        let unperturbed = g.demos.len().min(1);
        assert_eq!(go.demos[..], g.demos[..unperturbed]);
        for (e, ei) in g.demos.iter().zip(&gi.demos) {
            assert_eq!(e.execution, ei.execution);
            assert_eq!(e.demo.deployable, ei.demo.deployable, "the same states");
            if matches!(e.execution, Execution::Perturbed { .. }) {
                assert_ne!(e.demo.actions, ei.demo.actions, "relabelled with ā");
                let start = r.osw.start;
                assert_eq!(
                    ei.demo.actions[start * N_ACTION..start * N_ACTION + N_ARM],
                    gi.demos[0].demo.actions[start * N_ACTION..start * N_ACTION + N_ARM],
                    "ā opens the window with ζ*, as the unperturbed rollout does"
                );
                relabelled += 1;
            } else {
                assert_eq!(e.demo.actions, ei.demo.actions);
            }
        }
    }
    assert!(
        relabelled > 0,
        "the tiny direct sets have perturbed survivors"
    );

    // D_*: successes only, as validated; labels are the commanded actions.
    assert_eq!(dstar.groups.len(), v.items.len());
    for ((g, item), r) in dstar.groups.iter().zip(&v.items).zip(d_r.rollouts()) {
        assert_eq!((g.item, g.attempt), (item.item, item.attempt));
        for e in &g.demos {
            assert_eq!(e.demo.deployable.len(), e.demo.steps * DEPLOYABLE_LEN);
            assert_eq!(e.demo.actions.len(), e.demo.steps * N_ACTION);
            assert!(e.demo.actions.iter().all(|a| a.abs() <= 1.0));
        }
        match g.origin {
            Origin::Dropped => assert!(g.demos.is_empty() && !item.original.success),
            Origin::Kept => {
                assert!(item.original.success);
                assert_eq!(g.demos.len(), 1);
                assert_eq!(g.demos[0].execution, Execution::Original);
                assert_eq!(g.demos[0].demo.deployable, r.record.deployable);
                assert_eq!(g.demos[0].demo.actions, r.record.intended);
            }
            Origin::Refined | Origin::Repaired => {
                let k = item.decision.selected().expect("selected");
                let Robustness::Full { successes } = item.candidates[k].robustness else {
                    panic!("a selected candidate has its full SR");
                };
                assert_eq!(g.demos.len(), 1 + successes as usize);
                assert_eq!(g.demos[0].execution, Execution::Unperturbed);
                // Inside the window the arm ran ζ*, until contact handed it back.
                let zeta = &direct.items[g.item as usize]
                    .set
                    .as_ref()
                    .expect("η")
                    .candidates[k]
                    .zeta;
                let start = r.osw.start;
                assert_eq!(
                    g.demos[0].demo.actions[start * N_ACTION..start * N_ACTION + N_ARM],
                    zeta[..N_ARM]
                );
                for e in &g.demos[1..] {
                    assert!(matches!(e.execution, Execution::Perturbed { .. }));
                    assert_ne!(e.demo.actions, g.demos[0].demo.actions, "perturbed labels");
                }
            }
        }
    }

    // Common random numbers: η with one candidate twice gets the same report twice.
    let mut task = d_r.task.clone();
    task.rollout.record_privileged = false;
    let (index, item) = v
        .items
        .iter()
        .enumerate()
        .find(|(_, i)| {
            i.candidates
                .iter()
                .any(|c| c.robustness != Robustness::NotRun)
        })
        .expect("a candidate with perturbed rollouts");
    let k = item
        .candidates
        .iter()
        .position(|c| c.robustness != Robustness::NotRun)
        .expect("k");
    let set = &direct.items[index].set.as_ref().expect("η").candidates;
    let twice = vec![set[k].clone(), set[k].clone()];
    let streams = v.streams.clone();
    let errors = move |q| streams.rng(item.item, q);
    let rollout = d_r.rollouts().nth(index).expect("rollout");
    for exhaustive in [false, true] {
        let (report, _) = validate(
            &Case {
                world: &world,
                task: &task,
                agent: &teacher.agent,
                rollout,
                candidates: &twice,
                model: &model,
                errors: &errors,
            },
            &ValidateParams {
                exhaustive,
                ..v.params.clone()
            },
        )
        .expect("validate");
        assert_eq!(report.candidates[0], report.candidates[1]);
        assert_eq!(report.candidates[0], item.candidates[k]);
    }

    // Validation's κ param is the model's κ: the default model validated at κ = 0.05 (and
    // deviation scale 1) by the param reports, on its own streams, what the gentle model (whose
    // fit recorded κ = 0.05) reports when validated directly.
    let by_param: Validation = osms_make::assemble(
        &made.store.get(&fast["validate_kappa"]).expect("object"),
        &osms_make::StoreObjects(&made.store),
    )
    .expect("validation");
    let gentle: ErrorModelArtifact =
        osms_core::decode(&made.store.get(&fast["error_model_gentle"]).expect("object"))
            .expect("decode");
    assert_eq!(gentle.model.kappa, 0.05);
    assert_ne!(model.kappa, 0.05, "the param changes κ");
    let mut perturbed = 0;
    for (index, item) in by_param.items.iter().enumerate() {
        let Some(set) = direct.items[index].set.as_ref() else {
            continue;
        };
        let streams = by_param.streams.clone();
        let it = item.item;
        let errors = move |q| streams.rng(it, q);
        let (report, _) = validate(
            &Case {
                world: &world,
                task: &task,
                agent: &teacher.agent,
                rollout: d_r.rollouts().nth(index).expect("rollout"),
                candidates: &set.candidates,
                model: &gentle.model,
                errors: &errors,
            },
            &ValidateParams {
                kappa: None,
                deviation_scale: None,
                ..by_param.params.clone()
            },
        )
        .expect("validate");
        assert_eq!(report.original, item.original, "item {index}");
        assert_eq!(report.candidates, item.candidates, "item {index}");
        perturbed += item
            .candidates
            .iter()
            .filter(|c| c.robustness != Robustness::NotRun)
            .count();
    }
    assert!(
        perturbed > 0,
        "the κ = 0.05 reports include perturbed rollouts"
    );
}

/// Naive reaches D_*'s count exactly, Normal at least (its extension runs with a margin and
/// keeps the first groups that reach it); their extensions draw conditions no other set has.
fn baselines_reach_dstar_from_streams_of_their_own(made: &Made, hashes: &BTreeMap<String, Hash>) {
    use osms_policy::artifacts::Dataset;
    use osms_policy::artifacts::{DemoSet, Execution, Origin};
    use osms_sim::artifacts::Conditions;

    let set = |name: &str| -> DemoSet {
        osms_make::assemble(
            &made.store.get(&hashes[name]).expect("object"),
            &osms_make::StoreObjects(&made.store),
        )
        .expect("demo set")
    };
    let (dstar, naive, normal) = (
        set("dstar_unperturbed"),
        set("naive_direct"),
        set("normal_extended"),
    );
    let target = dstar.len();
    assert_eq!(naive.target, Some(target));
    assert_eq!(naive.len(), target, "naive reaches D_*'s count");
    assert!(
        naive.stats().extension_conditions > 0,
        "the tiny D_* ({target} demonstrations) outgrows D_R's successes: {:?}",
        naive.stats()
    );
    for g in naive.used_groups().iter().filter(|g| g.extension) {
        assert_eq!((g.origin, g.demos.len()), (Origin::Kept, 1));
        assert_eq!(g.demos[0].execution, Execution::Original);
    }
    assert_eq!(normal.target, Some(target));
    assert!(
        normal.stats().extension_conditions > 0,
        "normal extends too"
    );
    // The extension keeps its groups up to the first that reaches the target, no further.
    let used = normal.used_groups();
    if let Some(last) = used.iter().rposition(|g| g.extension) {
        assert!(
            normal.len() - used[last].demos.len() < target,
            "no extension group is used after the one that reaches the target"
        );
    }
    if used.len() < normal.groups.len() {
        assert!(
            normal.len() >= target,
            "groups were left out only past the target"
        );
    }
    for g in &normal.groups {
        assert!(
            g.demos.len() <= 1,
            "unperturbed-only: one rollout per condition"
        );
        assert_eq!(g.demos.is_empty(), g.origin == Origin::Dropped);
    }

    let mut seen: Vec<(String, String)> = Vec::new();
    let heldout: Conditions = load_sharded(made, "heldout");
    seen.extend(
        heldout
            .items
            .iter()
            .map(|c| ("heldout".into(), format!("{c:?}"))),
    );
    for name in ["d_m", "d_e", "d_r"] {
        let d: Dataset = load_sharded(made, name);
        seen.extend(
            d.rollouts()
                .map(|r| (name.into(), format!("{:?}", r.record.condition))),
        );
    }
    for (name, s) in [("naive", &naive), ("normal", &normal)] {
        for g in s.groups.iter().filter(|g| g.extension) {
            let c = format!("{:?}", g.condition);
            if let Some((other, _)) = seen.iter().find(|(_, s)| *s == c) {
                panic!("{name} extension item {} shares ω with {other}", g.item);
            }
            seen.push((name.into(), c));
        }
    }
}

/// Whether the JSON array `list` holds the string `s`.
fn lists(list: &serde_json::Value, s: &str) -> bool {
    list.as_array().expect("an array").iter().any(|x| x == s)
}

/// `osms export-dataset`, `replay` and `render` on the tiny datasets through the real command
/// line, with pyarrow, h5py and MuJoCo's own Python bindings as independent readers.
/// `osms exp diff A B --paired STAGE`: the difference of the mean success over A's and B's
/// evaluations of STAGE, from the artifacts themselves; refused where nothing pairs.
fn paired_experiments_compare_rollout_by_rollout(made: &Made) {
    use osms_sim::artifacts::Evaluation;
    let bin = env!("CARGO_BIN_EXE_osms-shipped");
    let pipeline = made._dir.path().join("pipeline.toml");
    let osms = |args: &[&str]| {
        std::process::Command::new(bin)
            .arg("--pipeline")
            .arg(&pipeline)
            .arg("--store")
            .arg(made.store.root())
            .args(args)
            .env("OSMS_NO_PROGRESS", "1")
            .output()
            .expect("run osms")
    };
    let ok = |args: &[&str]| {
        let o = osms(args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        o
    };
    let json = |args: &[&str]| -> serde_json::Value {
        serde_json::from_slice(&ok(args).stdout).expect("json")
    };
    ok(&[
        "exp",
        "run",
        "one",
        "-p",
        "tiny",
        "--seed",
        "0",
        "dev_student",
    ]);
    ok(&[
        "exp",
        "run",
        "three",
        "-p",
        "tiny",
        "--seeds",
        "0,1,2",
        "dev_student",
    ]);
    let d = json(&[
        "exp",
        "diff",
        "one",
        "three",
        "--paired",
        "dev_student",
        "--json",
    ]);
    // The seeds' evaluations as the experiment recorded them (`first` names seed 0's only).
    let three = osms_make::experiment::load(&made.store, "three")
        .expect("read")
        .expect("recorded");
    let success = |seed: u64| -> f64 {
        let i = three.points[0]
            .instances
            .iter()
            .find(|i| i.stage == "dev_student" && i.run_seed == Some(seed))
            .expect("recorded");
        let e: Evaluation = osms_make::assemble(
            &made.store.get(&i.content_hash).expect("object"),
            &osms_make::StoreObjects(&made.store),
        )
        .expect("evaluation");
        e.rows.iter().filter(|r| r.outcome.success()).count() as f64 / e.rows.len() as f64
    };
    let mean = (success(0) + success(1) + success(2)) / 3.0;
    let x = &d["difference"];
    let estimate = x["estimate"].as_f64().expect("estimate");
    assert!((estimate - (mean - success(0))).abs() < 1e-12, "{d}");
    assert_eq!(x["seeds"], serde_json::json!([3, 1]), "{d}");
    assert_eq!(x["n"][0], 12, "tiny dev's conditions: {d}");
    assert!(x["low"].as_f64() <= Some(estimate) && Some(estimate) <= x["high"].as_f64());
    assert_eq!(d["b"]["evaluations"].as_array().map(Vec::len), Some(3));
    // A sweep of a knob dev_student does not read shares its evaluations between the points:
    // still three seeds.
    ok(&[
        "exp",
        "run",
        "swept",
        "-p",
        "tiny",
        "--seeds",
        "0,1,2",
        "--sweep",
        "dev_teacher.shards=1,2",
        "dev_student",
        "dev_teacher",
    ]);
    let swept = json(&[
        "exp",
        "diff",
        "one",
        "swept",
        "--paired",
        "dev_student",
        "--json",
    ]);
    assert_eq!(swept["difference"], d["difference"], "{swept}");
    assert_eq!(swept["b"]["evaluations"].as_array().map(Vec::len), Some(3));
    // Two stages of one experiment (Ours-IL against Naive-IL, say): here the student against
    // its teacher, on the same dev conditions and seeds.
    let against = json(&[
        "exp",
        "diff",
        "swept",
        "swept",
        "--paired",
        "dev_teacher:dev_student",
        "--json",
    ]);
    let teacher: Vec<f64> = against["a"]["success"]
        .as_array()
        .expect("teacher's evaluations")
        .iter()
        .map(|x| x.as_f64().expect("rate"))
        .collect();
    assert!(!teacher.is_empty(), "{against}");
    let teacher_mean = teacher.iter().sum::<f64>() / teacher.len() as f64;
    let x = against["difference"]["estimate"]
        .as_f64()
        .expect("estimate");
    assert!((x - (mean - teacher_mean)).abs() < 1e-12, "{against}");
    assert!(
        osms(&["exp", "diff", "three", "three", "--paired", "dev_student:"])
            .status
            .code()
            == Some(1)
    );
    // `exp plot`: a line per target over the swept knob, each point the seeds' mean with the
    // pooled rollouts behind its interval; the figure and its numbers on disk.
    let plots = tempfile::tempdir().expect("plot dir");
    let out = plots.path().join("figs");
    let out_arg = out.to_str().expect("utf-8 path");
    let plot = json(&[
        "exp",
        "plot",
        "swept",
        "--x",
        "dev_teacher.shards",
        "--id",
        "shards",
        "-o",
        out_arg,
        "--json",
    ])["plot"]
        .clone();
    assert_eq!(plot["categories"], serde_json::json!(["1", "2"]), "{plot}");
    let student = plot["series"]
        .as_array()
        .expect("series")
        .iter()
        .find(|s| s["name"] == "success (dev_student)")
        .expect("dev_student's line");
    for p in student["points"].as_array().expect("points") {
        assert!(
            (p["y"].as_f64().expect("y") - 100.0 * mean).abs() < 1e-9,
            "{p}"
        );
        assert_eq!(
            (p["values"].as_u64(), p["rollouts"].as_u64()),
            (Some(3), Some(36)),
            "{p}"
        );
        assert!(p["low"].as_f64() <= p["y"].as_f64() && p["y"].as_f64() <= p["high"].as_f64());
    }
    let png = std::fs::read(out.join("shards.png")).expect("png");
    assert_eq!(&png[1..4], b"PNG");
    let svg = std::fs::read_to_string(out.join("shards.svg")).expect("svg");
    assert!(svg.starts_with("<svg"), "{svg:.100}");
    let csv = std::fs::read_to_string(out.join("shards.csv")).expect("csv");
    assert_eq!(csv.lines().count(), 1 + 2 * 2, "{csv}");
    let fails = |args: &[&str], says: &str| {
        let o = osms(args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(err.contains(says), "{err}");
    };
    fails(
        &["exp", "diff", "one", "three", "--paired", "dev_teacher"],
        "has no instance of `dev_teacher`",
    );
    fails(
        &["exp", "diff", "one", "three", "--paired", "student_ours"],
        "only evaluations pair by condition",
    );
    fails(
        &[
            "exp",
            "plot",
            "three",
            "--x",
            "dev_teacher.shards",
            "-o",
            out_arg,
        ],
        "three: --x `dev_teacher.shards` is not a knob of this point",
    );
}

fn datasets_export_replay_and_render(made: &Made) {
    use osms_policy::artifacts::Dataset;
    use osms_policy::artifacts::DemoSet;
    let bin = env!("CARGO_BIN_EXE_osms-shipped");
    let pipeline = made._dir.path().join("pipeline.toml");
    let store = made.store.root().to_path_buf();
    let out = tempfile::tempdir().expect("out dir");
    let osms = |args: &[&str]| {
        std::process::Command::new(bin)
            .arg("--pipeline")
            .arg(&pipeline)
            .arg("--store")
            .arg(&store)
            .args(args)
            .args(["--profile", "tiny"])
            .env("OSMS_NO_PROGRESS", "1")
            .output()
            .expect("run osms")
    };
    let ok = |args: &[&str]| {
        let o = osms(args);
        assert!(
            o.status.success(),
            "osms {args:?}:\n{}",
            String::from_utf8_lossy(&o.stderr)
        );
        o
    };
    let fails = |args: &[&str], says: &str| {
        let o = osms(args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "osms {args:?} should fail");
        assert!(err.contains(says), "osms {args:?}: {err}");
    };
    let d_r: Dataset = load_sharded(made, "d_r");
    let frames: usize = d_r.items.iter().map(|i| i.rollout.record.steps).sum();
    let p = |d: &Path| d.to_str().expect("utf-8 path").to_string();

    // Every tiny D_R episode replays bit for bit in Rust (the library; the CLI for two).
    let world: osms_sim::artifacts::WorldArtifact = load(made, "world");
    let world = world.world().expect("world");
    for (i, item) in d_r.items.iter().enumerate() {
        let (_, report) = osms_sim::replay::replay(
            &world,
            &d_r.task.rollout,
            &item.rollout.record,
            &mut |_, _| {},
        )
        .expect("replay");
        assert!(report.bit_exact, "d_r episode {i}: {report:#?}");
    }
    let last = (d_r.items.len() - 1).to_string();
    for episode in ["0", last.as_str()] {
        let o = ok(&["replay", "d_r", "--episode", episode, "--json"]);
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
        assert_eq!(v["report"]["bit_exact"], true, "{v}");
    }

    // Exports: twice the same bytes; what they say they wrote is there.
    let lerobot = out.path().join("lerobot");
    let robomimic = out.path().join("robomimic");
    let export_with = |format: &str, dir: &Path, stage: &str, extra: &[&str]| {
        let dir = p(dir);
        let mut args = vec![
            "export-dataset",
            stage,
            "--format",
            format,
            "--out",
            &dir,
            "--json",
        ];
        args.extend_from_slice(extra);
        let o = ok(&args);
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
        let files: Vec<std::path::PathBuf> = v["files"]
            .as_array()
            .expect("files")
            .iter()
            .map(|f| f.as_str().expect("path").into())
            .collect();
        assert!(!files.is_empty());
        files
            .iter()
            .map(|f| (f.clone(), std::fs::read(f).expect("written file")))
            .collect::<Vec<_>>()
    };
    let export = |format: &str, dir: &Path, stage: &str| export_with(format, dir, stage, &[]);
    let first = export("lerobot", &lerobot, "d_r");
    assert_eq!(export("lerobot", &lerobot, "d_r"), first, "LeRobot bytes");
    let first = export("robomimic", &robomimic, "d_r");
    assert_eq!(
        export("robomimic", &robomimic, "d_r"),
        first,
        "robomimic bytes"
    );
    let dstar_dir = out.path().join("dstar");
    export("lerobot", &dstar_dir, "dstar");
    // The privileged frame among the policy inputs, on request only.
    let lerobot_privileged = out.path().join("lerobot-privileged");
    let robomimic_privileged = out.path().join("robomimic-privileged");
    export_with("lerobot", &lerobot_privileged, "d_r", &["--privileged-obs"]);
    export_with(
        "robomimic",
        &robomimic_privileged,
        "d_r",
        &["--privileged-obs"],
    );

    // Bad input: a clear error and nothing written.
    fails(
        &["replay", "no_such_stage", "--episode", "0"],
        "no_such_stage",
    );
    fails(&["replay", "teacher", "--episode", "0"], "is not a dataset");
    fails(&["replay", "dstar", "--episode", "0"], "demonstration set");
    fails(
        &["replay", "d_r", "--episode", &d_r.items.len().to_string()],
        "out of range",
    );
    let theirs = out.path().join("theirs");
    std::fs::create_dir(&theirs).expect("mkdir");
    std::fs::write(theirs.join("notes.txt"), "mine").expect("write");
    fails(
        &[
            "export-dataset",
            "d_r",
            "--format",
            "lerobot",
            "--out",
            &p(&theirs),
        ],
        "not a dataset export directory osms wrote",
    );
    let blocked = out.path().join("a-file");
    std::fs::write(&blocked, "x").expect("write");
    fails(
        &[
            "export-dataset",
            "d_r",
            "--format",
            "robomimic",
            "--out",
            &p(&blocked.join("inside")),
        ],
        "cannot create",
    );
    assert_eq!(std::fs::read(&blocked).expect("read"), b"x");
    assert_eq!(
        std::fs::read_dir(&theirs).expect("ls").count(),
        1,
        "nothing written beside someone's files"
    );

    // Render: the strip names the other two files (a dotted stem keeps its dots).
    let strip = out.path().join("pictures").join("catch.v2.png");
    let o = ok(&[
        "render",
        "d_r",
        "--episode",
        "0",
        "--out",
        &p(&strip),
        "--width",
        "160",
        "--height",
        "120",
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let poses = out.path().join("pictures").join("catch.v2-poses.png");
    let gif = out.path().join("pictures").join("catch.v2.gif");
    assert_eq!(
        v["files"],
        serde_json::json!([p(&strip), p(&poses), p(&gif)])
    );
    for f in [&strip, &poses, &gif] {
        assert!(
            std::fs::metadata(f).expect("rendered file").len() > 1000,
            "{}",
            f.display()
        );
    }
    fails(
        &[
            "render",
            "d_r",
            "--episode",
            "0",
            "--out",
            &p(&out.path().join("x.jpg")),
        ],
        "must name a .png file",
    );

    // Independent readers.
    let Some(python) = osms_tests::python::interpreter("dataset exports read back in Python")
    else {
        return;
    };
    let f32s = |v: &serde_json::Value| -> Vec<f32> {
        v.as_array()
            .expect("array")
            .iter()
            .map(|x| x.as_f64().expect("number") as f32)
            .collect()
    };
    let lr =
        osms_tests::python::run_script(&python, "read-lerobot.py", &[&p(&lerobot), "--all-frames"]);
    assert_eq!(lr["frames"], frames);
    // No privileged column under `observation.` unless asked for.
    let observations = |v: &serde_json::Value| -> Vec<String> {
        v["columns"]
            .as_array()
            .expect("columns")
            .iter()
            .filter_map(|c| c.as_str().filter(|c| c.starts_with("observation")))
            .map(String::from)
            .collect()
    };
    assert_eq!(observations(&lr), ["observation.state"]);
    assert!(lists(&lr["columns"], "osms.privileged"));
    assert_eq!(lr["info"]["osms"]["privileged_is_policy_input"], false);
    let lrp =
        osms_tests::python::run_script(&python, "read-lerobot.py", &[&p(&lerobot_privileged)]);
    assert_eq!(
        observations(&lrp),
        ["observation.state", "observation.environment_state"]
    );
    assert_eq!(lrp["info"]["osms"]["privileged_is_policy_input"], true);
    assert_eq!(lr["action_shape"], serde_json::json!([frames, 24]));
    assert_eq!(lr["info"]["codebase_version"], "v3.0");
    assert_eq!(lr["info"]["fps"], 50);
    let episodes = lr["episodes"].as_array().expect("episodes");
    assert_eq!(episodes.len(), d_r.items.len());
    let mut from = 0;
    for (e, item) in episodes.iter().zip(&d_r.items) {
        let r = &item.rollout.record;
        assert_eq!(e["from"], from);
        assert_eq!(e["length"], r.steps);
        assert_eq!(e["to"], from + r.steps);
        assert_eq!(f32s(&e["first_action"]), r.executed[..24]);
        // Every frame's state and action, as the record holds them (f32 both ways).
        let rows = |key: &str| -> Vec<f32> {
            e[key]
                .as_array()
                .expect("rows")
                .iter()
                .flat_map(&f32s)
                .collect()
        };
        assert_eq!(
            rows("actions"),
            r.executed,
            "episode {}: actions",
            e["episode_index"]
        );
        assert_eq!(
            rows("states"),
            r.deployable,
            "episode {}: states",
            e["episode_index"]
        );
        assert_eq!(e["task"], format!("catch the {}", r.condition.variant));
        from += r.steps;
    }

    let rm = osms_tests::python::run_script(
        &python,
        "read-robomimic.py",
        &[&p(&robomimic.join("d_r.hdf5"))],
    );
    assert_eq!(rm["total"], frames);
    let demos = rm["demos"].as_array().expect("demos");
    assert_eq!(demos.len(), d_r.items.len());
    for (d, item) in demos.iter().zip(&d_r.items) {
        let r = &item.rollout.record;
        assert_eq!(d["num_samples"], r.steps);
        assert_eq!(d["actions_shape"], serde_json::json!([r.steps, 24]));
        assert_eq!(f32s(&d["first_action"]), r.executed[..24]);
        assert_eq!(d["success"], r.outcome.success());
        assert_eq!(d["last_done"], 1);
        // The script checked next_obs[t] == obs[t + 1] for every key.
        assert_eq!(d["next_obs_keys"], d["obs_keys"]);
        assert!(!lists(&d["obs_keys"], "privileged"), "{d}");
        assert!(lists(&d["osms_keys"], "privileged"), "{d}");
        assert_eq!(d["task_index"], r.condition.variant.index());
    }
    let rmp = osms_tests::python::run_script(
        &python,
        "read-robomimic.py",
        &[&p(&robomimic_privileged.join("d_r.hdf5"))],
    );
    for d in rmp["demos"].as_array().expect("demos") {
        assert!(lists(&d["obs_keys"], "privileged"), "{d}");
        assert_eq!(d["next_obs_keys"], d["obs_keys"]);
    }
    let masks = rm["mask"]["train"].as_array().expect("train").len()
        + rm["mask"]["valid"].as_array().expect("valid").len();
    assert_eq!(masks, d_r.items.len());

    // MuJoCo's Python bindings replay the robomimic file from `osms world dump`'s MJCF.
    let osms_cmd = format!("{bin} --pipeline {} --store {}", p(&pipeline), p(&store));
    let replayed = osms_tests::python::run_script(
        &python,
        "replay-robomimic.py",
        &[&p(&robomimic.join("d_r.hdf5")), "--osms", &osms_cmd],
    );
    let tolerance = 1e-9;
    let worst = replayed["max_abs_state_deviation"]
        .as_f64()
        .expect("deviation");
    assert!(
        worst <= tolerance,
        "Python replay deviates by {worst}: {replayed}"
    );
    for (i, item) in d_r.items.iter().enumerate() {
        let d = &replayed["demos"][format!("demo_{i}")];
        let m = &item.rollout.record.metrics;
        let f = d["f_max_replayed"].as_f64().expect("f_max");
        assert!(
            (f - m.max_force_n).abs() <= 1e-9 * m.max_force_n.max(1.0),
            "{d}"
        );
        let t_c = d["t_c_replayed"].as_f64();
        assert_eq!(t_c.is_some(), m.contact_time_secs.is_some(), "{d}");
    }

    let set: DemoSet = load_sharded(made, "dstar");
    let demo_frames: usize = set.demos().map(|d| d.steps).sum();
    let ds = osms_tests::python::run_script(&python, "read-lerobot.py", &[&p(&dstar_dir)]);
    assert_eq!(ds["frames"], demo_frames);
    // D_R and D_* give every variant the same task index: the fixed one.
    assert_eq!(ds["tasks"], lr["tasks"]);
    for v in osms_sim::ObjectVariant::all() {
        assert_eq!(lr["tasks"][format!("catch the {v}")], v.index(), "{v}");
    }
}

/// The stages the Python package's identity check adds to the tiny pipeline: a student acting
/// with noise (also under two other chunk executions) and the scripted catcher with other gains
/// and inputs than the defaults, each with its evaluation (protocol), so that the store's
/// policies are checked for every param their stages read.
const PYTHON_IDENTITY_STAGES: &str = r#"
[stages.student_noisy]
kind = "student"
seed = 0
inputs = { data = "d_e" }
params = { steps = 40, batch = 32, hidden = [32, 32], log_every = 10, noise_scale = 1.0 }

[stages.eval_student_noisy]
kind = "eval_student"
seed = 0
inputs = { world = "world", conditions = "heldout", student = "student_noisy" }
params = { rollout = { dr = "paper" } }

[stages.eval_scripted_tuned]
kind = "evaluate"
seed = 0
inputs = { world = "world", conditions = "heldout" }
params = { rollout = { dr = "paper" }, catcher = { gain = 0.35 }, prior_inputs = "tracked" }

[stages.eval_student_h3]
kind = "eval_student"
seed = 0
inputs = { world = "world", conditions = "heldout", student = "student_noisy" }
params = { rollout = { dr = "paper" }, execution = { horizon = 3 } }

[stages.eval_student_ensemble]
kind = "evaluate"
seed = 0
inputs = { world = "world", conditions = "heldout", student = "student_noisy" }
params = { rollout = { dr = "paper" }, execution = { ensemble = 0.01 } }

# Never built: a protocol whose horizon is past the student's chunks, for the refusal.
[stages.eval_student_h9]
kind = "eval_student"
seed = 0
inputs = { world = "world", conditions = "heldout", student = "student_noisy" }
params = { rollout = { dr = "paper" }, execution = { horizon = 9 } }
"#;

/// The Python package `osms` (crates/osms-py) against osms's own evaluations: the store's
/// teacher, students (with and without noise, under the paper's chunk execution, a horizon of 3
/// and the temporal ensemble) and scripted catcher (default and tuned)
/// evaluated from Python give `osms export`'s rows bit for bit at 1, 3 and 16 rollouts at once;
/// a NumPy policy's rows do not depend on batching and match the gymnasium environment's;
/// gymnasium's checker passes; bad actions and arguments raise errors naming what would do and
/// leave the pool and the store alone; a fresh store gets its condition set on first use and
/// evaluates `heldout` without a teacher (crates/osms-py/tests/check_package.py does the Python
/// side and exits non-zero on any failed check; scripts/test builds the package into the test
/// venv).
fn the_python_package_reproduces_osms_evaluations(made: &Made, text: &str) {
    use osms_sim::artifacts::Evaluation;
    let Some(python) = osms_tests::python::interpreter("the Python package's checks") else {
        return;
    };
    // The identity check's own stages, built into the same store beside the pipeline.
    let pipeline = made._dir.path().join("python.toml");
    std::fs::write(&pipeline, format!("{text}{PYTHON_IDENTITY_STAGES}")).expect("write");
    let plan = Plan::new(
        &Pipeline::load(&pipeline, Some("tiny")).expect("load"),
        &osms_kinds::registry(),
    )
    .expect("plan");
    let added = [
        "eval_student_noisy",
        "eval_scripted_tuned",
        "eval_student_h3",
        "eval_student_ensemble",
    ];
    let opts = MakeOptions {
        targets: added.iter().map(|s| s.to_string()).collect(),
        seeds: vec![0],
        jobs: 2,
        stages: 1,
        dry_run: false,
    };
    let report = osms_make::make(&plan, &made.store, &opts, &Silent).expect("make");
    assert!(report.failed().is_empty(), "{:?}", report.failed());
    let built = hashes(&report);
    // The reference rows: each evaluation's rollouts.csv as `osms export` writes it.
    let reference = tempfile::tempdir().expect("reference dir");
    let protocols = [
        "eval_teacher",
        "eval_student_il",
        "eval_student_noisy",
        "eval_scripted",
        "eval_scripted_tuned",
        "eval_student_h3",
        "eval_student_ensemble",
    ];
    for stage in protocols {
        let hash = built
            .get(stage)
            .or_else(|| made.hashes.get(stage))
            .unwrap_or_else(|| panic!("{stage} built"));
        let evaluation: Evaluation = osms_make::assemble(
            &made.store.get(hash).expect("object"),
            &osms_make::StoreObjects(&made.store),
        )
        .expect("assemble");
        let files = osms_export::rollouts::files(&evaluation).expect("files");
        let (_, csv) = files
            .iter()
            .find(|(name, _)| name == osms_export::rollouts::CSV_FILE)
            .expect("a csv");
        std::fs::write(reference.path().join(format!("{stage}.csv")), csv).expect("write csv");
    }
    // The tuned catcher and the noisy student are other policies than the defaults: their rows
    // differ from the default stages' on the same conditions.
    let read = |stage: &str| {
        std::fs::read_to_string(reference.path().join(format!("{stage}.csv"))).expect("csv")
    };
    assert_ne!(read("eval_scripted_tuned"), read("eval_scripted"));
    assert_ne!(read("eval_student_noisy"), read("eval_student_il"));
    // So are the same noisy student under other chunk executions (issue 68).
    assert_ne!(read("eval_student_h3"), read("eval_student_noisy"));
    assert_ne!(read("eval_student_ensemble"), read("eval_student_noisy"));
    let checkout = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .canonicalize()
        .expect("checkout");
    let mut runs = vec![("editable install", python)];
    runs.extend(
        osms_tests::python::wheel_interpreter("the Python package's checks from its wheel")
            .map(|p| ("wheel in a fresh venv", p)),
    );
    for (install, python) in runs {
        // The vector environment's section runs once: it steps the same Rust code whichever
        // install loads it.
        let vector = install == "editable install";
        let mut args = vec![
            pipeline.to_str().expect("utf-8 path"),
            reference.path().to_str().expect("utf-8 path"),
        ];
        if vector {
            args.push("--vector");
        }
        let summary = osms_tests::python::run_file(
            &python,
            &checkout.join("crates/osms-py/tests/check_package.py"),
            &args,
        );
        check_python_summary(&summary, &read("eval_teacher"), vector);
        let (package, mujoco) = (
            summary["package"].as_str().expect("package path"),
            summary["mujoco"].as_str().expect("mujoco path"),
        );
        if install == "editable install" {
            assert!(
                package.starts_with(
                    checkout
                        .join("crates/osms-py/python")
                        .to_str()
                        .expect("utf-8")
                ),
                "{install}: {package}"
            );
            assert!(
                mujoco.starts_with(checkout.join(".mujoco").to_str().expect("utf-8")),
                "{install}: {mujoco}"
            );
        } else {
            // The wheel's package and the MuJoCo library it carries, nothing of the checkout.
            let venv = python
                .parent()
                .and_then(Path::parent)
                .expect("venv")
                .canonicalize()
                .expect("venv");
            let venv = venv.to_str().expect("utf-8 path");
            assert!(package.starts_with(venv), "{install}: {package}");
            assert!(mujoco.starts_with(venv), "{install}: {mujoco}");
        }
    }
}

/// What every run of check_package.py must have measured (it exits non-zero itself on a failed
/// check; these are the counts and values it reports).
fn check_python_summary(summary: &serde_json::Value, teacher_csv: &str, vector: bool) {
    // 21 identity checks (seven (policy, protocol) pairs × three batch sizes), each over the
    // whole set.
    let conditions = teacher_csv.lines().count() - 1;
    let identity = summary["identity"].as_object().expect("identity");
    assert_eq!(identity.len(), 21, "{summary}");
    assert!(
        identity
            .values()
            .all(|n| n.as_u64() == Some(conditions as u64)),
        "{summary}"
    );
    if vector {
        // 18 vector-environment identity checks: three store policies against `osms export`'s
        // rows and a NumPy policy in each of gymnasium's three autoreset modes against
        // `evaluate`'s, at 1, 3 and 16 sub-environments.
        let identity = summary["vector"].as_object().expect("vector");
        assert_eq!(identity.len(), 18, "{summary}");
        assert!(
            identity.values().all(|n| n.as_u64().is_some_and(|n| n > 0)),
            "{summary}"
        );
        for label in ["native", "sync"] {
            assert!(
                summary["lerobot_calls"][label]
                    .as_u64()
                    .is_some_and(|frames| frames > 1),
                "{summary}"
            );
        }
        assert_eq!(
            summary["vector_errors"].as_object().map(|e| e.len()),
            Some(10),
            "{summary}"
        );
    }
    assert_eq!(summary["render"], serde_json::json!([480, 480, 3]));
    assert!(
        summary["dev_built_on_use"].as_u64().is_some_and(|n| n > 0),
        "{summary}"
    );
    assert!(
        summary["refused_then_clean"]
            .as_u64()
            .is_some_and(|n| n >= 4),
        "{summary}"
    );
    let warnings = summary["check_env_warnings"].as_array().expect("warnings");
    assert!(
        warnings.is_empty(),
        "gymnasium's checker warned: {warnings:?}"
    );
    // One definition: the package's version and Wilson interval are the Rust crates'.
    assert_eq!(summary["version"], env!("CARGO_PKG_VERSION"));
    let z = osms_core::stats::normal_quantile(0.975);
    for (x, n) in [(0, 40), (7, 40), (40, 40)] {
        let (low, high) = osms_core::stats::wilson_bounds(x, n, z).expect("n > 0");
        assert_eq!(
            summary["wilson"][format!("{x}/{n}")],
            serde_json::json!([low.to_bits(), high.to_bits()]),
            "{summary}"
        );
    }
}
