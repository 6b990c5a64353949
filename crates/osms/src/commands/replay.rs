//! `osms replay`: a rollout's recorded controls, open loop, against its record.

use std::process::ExitCode;

use anyhow::{Context as _, Result};

use super::print_json;
use super::rollout_source::load;
use crate::cli::ReplayArgs;
use crate::context::Context;

pub fn replay(ctx: &Context, args: &ReplayArgs) -> Result<ExitCode> {
    let source = load(ctx, &args.at.target, &args.at.selection)?;
    let dataset = source.rollouts("replayed")?;
    source.check_episode(args.at.episode)?;
    let instance = source.resolved.record.instance();
    let world = source
        .world
        .world()
        .map_err(|e| anyhow::anyhow!("cannot compile the world of {instance}: {e}"))?;
    let rollout = &dataset.items[args.at.episode].rollout;
    let (_, report) = osms_sim::replay::replay(
        &world,
        &dataset.task.rollout,
        &rollout.record,
        &mut |_, _| {},
    )
    .with_context(|| format!("{instance} episode {}", args.at.episode))?;
    if args.json {
        print_json(&serde_json::json!({
            "stage": instance,
            "episode": args.at.episode,
            "item": rollout.item,
            "attempt": rollout.attempt,
            "report": report,
        }))?;
    } else {
        out!("{}", describe(&instance, args.at.episode, &report));
    }
    Ok(if report.bit_exact {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

fn describe(instance: &str, episode: usize, r: &osms_sim::replay::ReplayReport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{instance} episode {episode}: {} of {} control steps replayed from the recorded servo targets: {}",
        r.replayed_steps,
        r.steps,
        if r.bit_exact {
            "the record is reproduced bit for bit"
        } else {
            "the replay DEVIATES from the record"
        }
    );
    let _ = writeln!(
        s,
        "  {:<14} {:>8} {:>10} {:>12}",
        "field", "values", "differing", "max |Δ|"
    );
    for d in &r.deviations {
        let _ = writeln!(
            s,
            "  {:<14} {:>8} {:>10} {:>12.3e}",
            d.field, d.values, d.differing, d.max_abs
        );
    }
    let opt = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.4}"));
    let _ = writeln!(
        s,
        "  {:<14} {:>14} {:>14}",
        "metric", "recorded", "replayed"
    );
    let _ = writeln!(
        s,
        "  {:<14} {:>14} {:>14}",
        "success", r.recorded_success, r.replayed_success
    );
    let _ = writeln!(
        s,
        "  {:<14} {:>14.4} {:>14.4}",
        "f_max (N)", r.recorded.max_force_n, r.replayed.max_force_n
    );
    let _ = writeln!(
        s,
        "  {:<14} {:>14} {:>14}",
        "t_c (s)",
        opt(r.recorded.contact_time_secs),
        opt(r.replayed.contact_time_secs)
    );
    let _ = writeln!(
        s,
        "  {:<14} {:>14} {:>14}",
        "k_e", r.recorded.event_step, r.replayed.event_step
    );
    s
}
