//! Renders one scripted catch: `cargo run -p osms-render --example render_catch -- [DIR] [INDEX]`
//! writes `catch-<INDEX>-strip.png`, `catch-<INDEX>-poses.png` and `catch-<INDEX>.gif` into DIR
//! (default /tmp/osms-render) and prints the render time per frame.

use std::time::Instant;

use osms_core::rng;
use osms_render::{RenderOptions, render_rollout};
use osms_sim::catcher::{CatcherSpec, ScriptedCatcher};
use osms_sim::control::DrSpec;
use osms_sim::{ConditionSpec, Episode, NoHooks, RolloutSpec, World, WorldSpec, conditions};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let dir = args.next().unwrap_or_else(|| "/tmp/osms-render".into());
    let index: u64 = args.next().map_or(Ok(3), |s| s.parse())?;
    let world = World::new(WorldSpec::default())?;
    let spec = RolloutSpec {
        dr: DrSpec::paper(),
        ..RolloutSpec::default()
    };
    let condition = conditions::sample(
        &ConditionSpec::default(),
        world.home_palm_pos,
        &mut rng::stream(0, "render", "omega", index),
    )?;
    let mut catcher = ScriptedCatcher::new(CatcherSpec::default(), spec.control.clone());
    let record = Episode::new(
        &world,
        &spec,
        condition,
        rng::stream(0, "render", "roll", index),
    )
    .run(&mut catcher, &mut NoHooks);
    let opts = RenderOptions::default();
    let start = Instant::now();
    let rendered = render_rollout(&world, &spec, &record, &opts)?;
    let secs = start.elapsed().as_secs_f64();
    let files = rendered.write(std::path::Path::new(&dir), &format!("catch-{index}"))?;
    println!(
        "{} steps, success {}, {} GIF frames, {:.1} s ({:.0} ms per rendered frame at {}x{}), replay bit-exact {}",
        record.steps,
        record.outcome.success(),
        rendered.gif_frames,
        secs,
        1000.0 * secs / rendered.gif_frames.max(1) as f64,
        opts.width,
        opts.height,
        rendered.replay.bit_exact
    );
    for f in &rendered.key_frames {
        println!(
            "  {:?} at step {} (t = {:.3} s)",
            f.kind, f.step, f.time_secs
        );
    }
    println!(
        "{}\n{}\n{}",
        files.strip.display(),
        files.composite.display(),
        files.gif.display()
    );
    Ok(())
}
