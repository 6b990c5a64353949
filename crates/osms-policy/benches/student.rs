//! The flow-matching student's costs, one thread, with PyTorch on the same shapes in the same
//! run when `OSMS_BENCH_TORCH_PYTHON` is set (`scripts/bench-nn` sets it):
//!
//! - one training step of the default student (batch 256; input = 8 deployable frames, a
//!   32-wide time embedding and an 8 × 24 noisy chunk = 824; hidden 3 × 256 SiLU; output 192;
//!   conditional flow-matching loss with the chunk mask; Adam);
//! - one training step of the U-Net student (`network = "unet"`, the default `unet` shape) on
//!   the same batch, as a ratio to the MLP's: how many U-Net steps fit the MLP's budget;
//! - one batch-1 action (10 Euler steps of the velocity network);
//! - env steps/s of a student rollout against the teacher's on the same conditions.
//!
//! Asserts nothing about time.

use std::collections::BTreeMap;
use std::process::Command;
use std::time::{Duration, Instant};

use osms_core::rng;
use osms_nn::{Adam, AdamConfig, Matrix, Schedule};
use osms_policy::catch::{CatchTask, CatchTaskSpec, rollout};
use osms_policy::flow::{FlowBatch, FlowNet, UNetSpec, normals};
use osms_policy::student::{self, Demo, Student, StudentParams};
use osms_policy::{Agent, PpoConfig, Task};
use osms_sim::{World, WorldSpec};

const EPISODES: u64 = 16;
/// Episodes of the lockstep comparison.
const BATCH_EPISODES: usize = 64;
/// Alternating rounds of the training-step comparison.
const ROUNDS: usize = 4;

fn best(runs: usize, mut f: impl FnMut()) -> Duration {
    (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed()
        })
        .min()
        .unwrap_or_default()
}

/// PyTorch's figures from `torch_student.py`, or why there are none.
fn torch() -> Result<BTreeMap<String, String>, String> {
    let python = std::env::var("OSMS_BENCH_TORCH_PYTHON")
        .map_err(|_| "not measured: run scripts/bench-nn to compare with PyTorch".to_string())?;
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/benches/torch_student.py");
    let out = Command::new(&python)
        .arg(script)
        .output()
        .map_err(|e| format!("could not run {python}: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "{script} failed: {}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    Ok(String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_once(' '))
        .map(|(k, v)| (k.to_string(), v.trim().to_string()))
        .collect())
}

/// The default student's training steps.
fn params_steps() -> u32 {
    StudentParams::default().steps
}

fn main() {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let world = World::new(WorldSpec::default()).expect("world");
    let spec = CatchTaskSpec::default();
    let task = CatchTask::new(&world, spec.clone(), 0, "bench", "train").expect("task");
    let agent = Agent::new(
        task.obs_len(),
        task.act_len(),
        &PpoConfig::default(),
        (0, "bench"),
    )
    .expect("a valid agent");
    let dr = |i: u64| rng::stream(0, "bench", "dr", i);
    let teacher_records: Vec<_> = (0..EPISODES)
        .map(|i| rollout(&world, &spec, &agent, task.condition(i).expect("ω"), dr(i)))
        .collect();

    // A student trained for a few steps on those rollouts: its cost per step does not depend
    // on how well it acts.
    let demos: Vec<Demo> = teacher_records.iter().map(Demo::from_record).collect();
    let params = StudentParams {
        steps: 5,
        holdout_every: 0,
        ..StudentParams::default()
    };
    let student = Student::train(&demos, &params, (0, "bench"), &|| {}).expect("student");
    let (t_step, t_unet, t_act, teacher_rate, student_rate, lockstep, figures) =
        pool.install(|| {
            let mut net = student.net.clone();
            let mut opt = Adam::new(AdamConfig::default(), Schedule::Constant { lr: 1e-4 });
            let (b, x_len, c_len) = (256, params.chunk_len(), params.obs_len());
            let mut r = rng::stream(0, "bench", "batch", 0);
            let x1 = Matrix::from_vec(b, x_len, normals(&mut r, b * x_len));
            let x0 = Matrix::from_vec(b, x_len, normals(&mut r, b * x_len));
            let cond = Matrix::from_vec(b, c_len, normals(&mut r, b * c_len));
            let mask = Matrix::from_fn(b, x_len, |_, _| 1.0);
            let t: Vec<f32> = (0..b).map(|_| rng::uniform01(&mut r) as f32).collect();
            let train = |net: &mut FlowNet, opt: &mut Adam| {
                let (_, grads) = net.loss_and_gradients(&FlowBatch {
                    x1: &x1,
                    cond: &cond,
                    x0: &x0,
                    t: &t,
                    mask: Some(&mask),
                });
                opt.update(&mut net.params_mut(), &grads.slices());
            };
            let mut step = || train(&mut net, &mut opt);
            step();
            // The osms and PyTorch measurements alternate, and each side keeps its best round: on
            // a shared machine the speed drifts between minutes, and alternating puts both sides
            // under the same drift.
            let mut t_step = Duration::MAX;
            let mut figures: Result<Vec<BTreeMap<String, String>>, String> = Ok(Vec::new());
            for _ in 0..ROUNDS {
                t_step = t_step.min(best(20, &mut step));
                if let Ok(all) = &mut figures {
                    match torch() {
                        Ok(f) => all.push(f),
                        Err(why) => figures = Err(why),
                    }
                }
            }
            let mut unet = FlowNet::new_unet(
                x_len,
                c_len,
                params.chunk,
                &UNetSpec::default(),
                params.time_embedding,
                0,
                "bench/unet",
            )
            .expect("a valid U-Net");
            let mut unet_opt = Adam::new(AdamConfig::default(), Schedule::Constant { lr: 1e-4 });
            let mut unet_step = || train(&mut unet, &mut unet_opt);
            unet_step();
            let t_unet = best(5, &mut unet_step);
            let obs = normals(&mut r, c_len);
            let mut noise = rng::stream(0, "bench", "noise", 0);
            let t_act = best(200, || {
                std::hint::black_box(student.act(&obs, &mut noise));
            });

            let rate = |f: &dyn Fn() -> usize| {
                let mut steps = 0;
                let d = best(3, || steps = f());
                steps as f64 / d.as_secs_f64()
            };
            let teacher_rate = rate(&|| {
                (0..EPISODES)
                    .map(|i| {
                        rollout(&world, &spec, &agent, task.condition(i).expect("ω"), dr(i)).steps
                    })
                    .sum()
            });
            let sspec = student.rollout_spec(&spec.rollout);
            let student_rate = rate(&|| {
                (0..EPISODES)
                    .map(|i| {
                        student::rollout(
                            &world,
                            &sspec,
                            &student,
                            task.condition(i).expect("ω"),
                            dr(i),
                            rng::stream(0, "bench", "policy", i),
                        )
                        .steps
                    })
                    .sum()
            });
            // The evaluation stages' pattern: episodes stepped in lockstep, the flow network acting
            // on all running ones at once, `len` episodes at a time, an ended episode's slot
            // taking the next (1 = one by one, through the same lockstep code).
            let lockstep: Vec<(usize, f64, Duration)> = [1, 4, 8, 16, 32]
                .into_iter()
                .map(|len| {
                    let items = |i: u64| {
                        (
                            task.condition(i).expect("ω"),
                            dr(i),
                            rng::stream(0, "bench", "policy", i),
                        )
                    };
                    let rate = rate(&|| {
                        student::rollouts_in_slots(
                            &world,
                            &sspec,
                            (&student, student::ChunkExecution::default()),
                            (0..BATCH_EPISODES as u64).map(items).collect(),
                            len,
                        )
                        .iter()
                        .map(|r| r.steps)
                        .sum()
                    });
                    let rows: Vec<Vec<f32>> = (0..len).map(|_| normals(&mut r, c_len)).collect();
                    let mut streams: Vec<_> = (0..len as u64)
                        .map(|i| rng::stream(0, "bench", "noise", i))
                        .collect();
                    let t = best(50, || {
                        std::hint::black_box(student.act_batch(&rows, streams.iter_mut()));
                    });
                    (len, rate, t / len as u32)
                })
                .collect();
            (
                t_step,
                t_unet,
                t_act,
                teacher_rate,
                student_rate,
                lockstep,
                figures,
            )
        });

    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    println!(
        "flow-matching student, one thread, {:?} kernels",
        osms_nn::kernels::Level::detected()
    );
    println!(
        "  training step (batch 256, 824-256-256-256-192 SiLU, CFM loss, Adam)  {:7.2} ms",
        ms(t_step)
    );
    let spec = UNetSpec::default();
    println!(
        "  U-Net training step (widths {:?}, kernel {}, FiLM width {})          {:7.2} ms   ratio to the MLP's {:.2}: {} MLP steps take as long as {:.0} U-Net steps",
        spec.widths,
        spec.kernel,
        spec.cond,
        ms(t_unet),
        t_unet.as_secs_f64() / t_step.as_secs_f64(),
        params_steps(),
        f64::from(params_steps()) * t_step.as_secs_f64() / t_unet.as_secs_f64()
    );
    println!(
        "  batch-1 action (10 Euler steps)                                      {:7.1} us",
        t_act.as_secs_f64() * 1e6
    );
    println!(
        "  rollouts, {EPISODES} episodes: teacher {teacher_rate:6.0} env steps/s, student {student_rate:6.0} env steps/s, ratio student/teacher {:.3}",
        student_rate / teacher_rate
    );
    let one = lockstep[0].1;
    println!(
        "  lockstep rollouts, {BATCH_EPISODES} episodes (the evaluations' pattern; ratio = env steps/s over one slot, the per-episode action time at that many rows):"
    );
    for (len, rate, t) in &lockstep {
        println!(
            "    slots {len:>2}: {rate:6.0} env steps/s   ratio {:.2}   action {:7.1} us per episode",
            rate / one,
            t.as_secs_f64() * 1e6
        );
    }
    match figures {
        Err(why) => println!("PyTorch: {why}"),
        Ok(rounds) => {
            // Each figure's best round.
            let get = |k: &str| {
                rounds
                    .iter()
                    .filter_map(|f| f.get(k).and_then(|v| v.parse::<f64>().ok()))
                    .reduce(f64::min)
            };
            let version = rounds
                .first()
                .and_then(|f| f.get("torch_version"))
                .map_or("?", String::as_str);
            println!(
                "PyTorch {version}, one thread, same shapes, alternating with osms over {ROUNDS} rounds, best round each (ratio = osms time / PyTorch time)"
            );
            if let Some(t) = get("train_step_ms") {
                println!(
                    "  training step      {t:7.2} ms   ratio {:.2}",
                    ms(t_step) / t
                );
            }
            if let Some(t) = get("act_us") {
                println!(
                    "  batch-1 action     {t:7.1} us   ratio {:.2}",
                    t_act.as_secs_f64() * 1e6 / t
                );
            }
        }
    }
}
