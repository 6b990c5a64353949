use std::process::ExitCode;

use anyhow::{Context as _, Result, bail};
use osms_sim::{ObjectVariant, WorldSpec, mjcf};

use crate::cli::WorldDumpArgs;
use crate::context::Context;

pub fn dump(ctx: &Context, args: &WorldDumpArgs) -> Result<ExitCode> {
    let variant: ObjectVariant = args
        .object
        .parse()
        .map_err(|e: String| anyhow::anyhow!(e))?;
    let plan = ctx.plan(args.profile.as_deref())?;
    let worlds: Vec<_> = plan
        .stages
        .iter()
        .filter(|s| s.info.name == "world")
        .collect();
    let stage = match (&args.stage, worlds.as_slice()) {
        (Some(name), _) => match worlds.iter().find(|s| &s.name == name) {
            Some(s) => *s,
            None => bail!(
                "`{name}` is not a stage of kind `world` in {}",
                ctx.pipeline_path.display()
            ),
        },
        (None, [only]) => *only,
        (None, []) => bail!(
            "{} declares no stage of kind `world`",
            ctx.pipeline_path.display()
        ),
        (None, many) => {
            let names: Vec<&str> = many.iter().map(|s| s.name.as_str()).collect();
            bail!(
                "several stages of kind `world` ({}); hint: choose one with --stage",
                names.join(", ")
            )
        }
    };
    let spec: WorldSpec =
        serde_json::from_value(stage.params.json.clone()).context("the world stage's params")?;
    out!("{}", mjcf::world_xml(&spec, variant));
    Ok(ExitCode::SUCCESS)
}
