use std::collections::BTreeMap;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context as _, Result, bail};
use osms_make::cost::Cost;
use osms_make::executor::{ExecutorConfig, ExecutorKind, load_user_config, user_config_path};
use osms_make::slurm::Launch;
use osms_make::slurm::cmd::SlurmCli;
use osms_make::{MakeOptions, Outcome, Plan};

use crate::EXIT_FAILURE;
use crate::cli::MakeArgs;
use crate::commands::{human_bytes, print_json, report};
use crate::context::Context;
use crate::progress::MakeObserver;

pub fn run(ctx: &Context, args: &MakeArgs) -> Result<ExitCode> {
    let started = Instant::now();
    let plan = ctx.selected_plan(&args.selection)?;
    if let Some(problem) = foreign_mujoco(&plan, osms_sim::MUJOCO_PINNED) {
        bail!("{problem}");
    }
    let store = ctx.store()?;
    let seeds = Context::seeds(&args.selection, &plan);
    let jobs = Context::jobs(args.jobs);
    let targets = if args.targets.is_empty() {
        plan.default_targets.clone()
    } else {
        args.targets.clone()
    };
    let opts = MakeOptions {
        targets,
        seeds: seeds.clone(),
        jobs,
        stages: crate::cli::Stages::resolve(args.stages, jobs),
        dry_run: args.dry_run,
    };
    let observer = MakeObserver::of(ctx);
    let config = executor_config(&plan)?;
    let executor = args.executor.or(config.kind).unwrap_or(ExecutorKind::Local);
    if !args.dry_run && ctx.printer.says() {
        warn_if_short_of_space(ctx, &plan, &store, &opts, &seeds);
    }
    // The remote is opened (and asked for its listing) before anything builds, so a bad URL,
    // server or credential fails at once; a dry run asks it nothing.
    let remote_name = if args.no_remote {
        None
    } else {
        args.remote.as_deref().or(plan.default_remote.as_deref())
    };
    let remote = match remote_name {
        Some(name) if !args.dry_run => Some(crate::commands::remote::open(
            ctx,
            &plan,
            Some(name),
            osms_remote::DEFAULT_JOBS,
        )?),
        _ => None,
    };
    // On a cluster the driver pulls what the remote holds before it submits anything: its
    // tasks write the store directly, so the lookup cannot sit between a stage and its job.
    let mut cluster_pulled = BTreeMap::new();
    let fetch = match remote {
        Some(remote) if executor == ExecutorKind::Slurm => {
            cluster_pulled = crate::commands::remote::pull_before_cluster_make(
                ctx,
                &plan,
                &store,
                &seeds,
                &opts.targets,
                &remote,
            )?;
            None
        }
        Some(remote) => Some(crate::commands::remote::MakeFetch {
            remote,
            bar: crate::commands::remote::Bar::new(ctx, "pulling"),
        }),
        None => None,
    };
    // A dry run submits nothing: it is the same plan whatever the executor.
    let report = if let Some(fetch) = &fetch {
        osms_make::make_fetching(&plan, &store, &opts, &observer, fetch)?
    } else if executor == ExecutorKind::Slurm && !args.dry_run {
        let launch = launch(ctx, &store, &config)?;
        let mut report = osms_make::slurm::make_slurm(
            &plan, &store, &opts, &config, &SlurmCli, &launch, &observer,
        )?;
        for r in &mut report.instances {
            if let (Outcome::Cached, Some(bytes)) = (&r.outcome, cluster_pulled.get(&r.instance)) {
                r.outcome = Outcome::Pulled { bytes: *bytes };
            }
        }
        report
    } else {
        osms_make::make(&plan, &store, &opts, &observer)?
    };

    // A dry run also says what the work would cost, scaled from the builds in the store.
    let estimate = if args.dry_run {
        Some(estimate(ctx, &plan, &store, &report, &seeds, Vec::new())?)
    } else {
        None
    };
    let cost = Cost::of(&plan, &seeds, &report, started.elapsed().as_secs_f64());
    if args.json {
        let mut value = serde_json::to_value(&report)?;
        if let Some(e) = &estimate {
            value["estimate"] = serde_json::to_value(e)?;
        }
        if !args.dry_run {
            value["cost"] = serde_json::to_value(&cost)?;
        }
        print_json(&value)?;
    } else if let Some(e) = &estimate
        && ctx.printer.says()
    {
        print_estimate(e);
    }
    let built = report.count(|o| matches!(o, Outcome::Built { .. }));
    let cached = report.count(|o| matches!(o, Outcome::Cached));
    let cut = report.count(|o| matches!(o, Outcome::CutOff));
    let pulled = report.count(|o| matches!(o, Outcome::Pulled { .. }));
    let failed = report.failed();
    if ctx.printer.says() {
        let seeds_text = seeds
            .iter()
            .map(u64::to_string)
            .collect::<Vec<_>>()
            .join(",");
        let what = if args.dry_run {
            format!(
                "{} would be built",
                report.count(|o| matches!(o, Outcome::WouldBuild { .. }))
            )
        } else {
            format!("{built} built")
        };
        let failed_text = if failed.is_empty() {
            String::new()
        } else {
            format!(", {} failed", failed.len())
        };
        let skipped = report.count(|o| matches!(o, Outcome::Skipped { .. }));
        let skipped_text = if skipped == 0 {
            String::new()
        } else {
            format!(", {skipped} skipped")
        };
        errln!(
            "osms make: {what}, {cached} cached, {cut} cut off{}{failed_text}{skipped_text} (profile {}, seed {seeds_text}) in {:.2}s",
            if fetch.is_some() {
                format!(", {pulled} pulled")
            } else {
                String::new()
            },
            plan.profile,
            started.elapsed().as_secs_f64()
        );
        if built > 0 && !args.dry_run {
            errln!(
                "osms make: the builds used {:.0} core-s in {:.0} s: {:.0} % of {} cores",
                cost.cpu_secs,
                cost.wall_secs,
                100.0 * cost.machine_share,
                cost.cores
            );
        }
        if report.instances.is_empty() {
            errln!(
                "hint: {} declares no stages yet",
                ctx.pipeline_path.display()
            );
        }
    }
    if failed.is_empty() {
        if !args.dry_run && args.selection.set.is_empty() {
            write_reports(ctx, &plan, &store, &report, &seeds)?;
        } else if !args.dry_run && has_report(&plan) {
            say!(
                ctx,
                "osms make: report/ left as pipeline.toml makes it, since --set is in force; \
                 `osms export report --set ... --out DIR` writes this variant's"
            );
        }
    }
    Ok(failure_exit(&failed))
}

/// Success, or exit 1 after naming the instances that failed.
pub(crate) fn failure_exit(failed: &[&str]) -> ExitCode {
    if failed.is_empty() {
        return ExitCode::SUCCESS;
    }
    errln!(
        "error: {} stage(s) failed: {}",
        failed.len(),
        failed.join(", ")
    );
    ExitCode::from(EXIT_FAILURE)
}

/// The core-hours of what a dry run would build, from the measured builds of every profile
/// and of the `more` plans (an experiment's recorded points).
pub(crate) fn estimate(
    ctx: &Context,
    plan: &Plan,
    store: &osms_store::Store,
    report: &osms_make::MakeReport,
    seeds: &[u64],
    more: Vec<Plan>,
) -> Result<osms_make::Estimate> {
    let profiles = osms_make::Pipeline::load(&ctx.pipeline_path, None)?.profiles;
    let mut references = profiles
        .iter()
        .map(|p| ctx.plan(Some(p)))
        .collect::<Result<Vec<_>>>()?;
    references.extend(more);
    let would_build: Vec<String> = report
        .instances
        .iter()
        .filter(|i| matches!(i.outcome, Outcome::WouldBuild { .. }))
        .map(|i| i.instance.clone())
        .collect();
    let threads = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    Ok(osms_make::estimate(
        plan,
        &references,
        store,
        seeds,
        &would_build,
        threads,
    )?)
}

pub(crate) fn print_estimate(e: &osms_make::Estimate) {
    if e.instances.is_empty() {
        return;
    }
    if e.unmeasured.len() == e.instances.len() {
        errln!(
            "no core-hour estimate: no profile has a build of these stages to scale; build a \
             smaller profile first (e.g. `osms make -p tiny`)"
        );
        return;
    }
    errln!(
        "estimate for profile {} (core-hours, scaled from measured builds; see docs/slurm.md):",
        e.profile
    );
    for i in &e.instances {
        match (&i.core_hours, &i.measured) {
            (Some(h), Some(m)) => errln!(
                "  {:<28} {:>10.2}  ({} work {:.0} vs {:.0} on {}: {:.1} core-s{}{}{})",
                i.instance,
                h,
                i.kind,
                i.work,
                m.work,
                m.profile,
                m.core_secs,
                if m.threads_assumed {
                    ", threads assumed"
                } else {
                    ""
                },
                if m.stale { ", stale build" } else { "" },
                // A sweep's variant (`validate~2`) is its stage's own.
                if i.instance.split(['#', '@', '~']).next() == Some(m.stage.as_str()) {
                    String::new()
                } else {
                    format!(", from stage {} of its kind", m.stage)
                }
            ),
            _ => errln!("  {:<28} {:>10}  (no measured build)", i.instance, "?"),
        }
    }
    errln!(
        "  {:<28} {:>10.2}  (≈ {} to store)",
        "total",
        e.total_core_hours,
        human_bytes(e.total_bytes as u64)
    );
    if !e.unmeasured.is_empty() {
        errln!(
            "  not in the total ({} unmeasured): build a smaller profile first, e.g. `osms make -p tiny`",
            e.unmeasured.len()
        );
    }
}

/// Before a make, warns when the store's filesystem has less free space than what the stages
/// to build stored when last measured (scaled as `--dry-run`'s estimate): a stage that runs out
/// fails, and nothing built before it is lost, but a long make is better not started. Best
/// effort: whatever cannot be estimated is left out, and nothing here stops the make.
fn warn_if_short_of_space(
    ctx: &Context,
    plan: &Plan,
    store: &osms_store::Store,
    opts: &MakeOptions,
    seeds: &[u64],
) {
    let Some(free) = osms_make::free_bytes(store.root()) else {
        return;
    };
    let dry = MakeOptions {
        dry_run: true,
        ..opts.clone()
    };
    let Ok(report) = osms_make::make(plan, store, &dry, &osms_make::Silent) else {
        return;
    };
    if !report
        .instances
        .iter()
        .any(|i| matches!(i.outcome, Outcome::WouldBuild { .. }))
    {
        return;
    }
    let Ok(e) = estimate(ctx, plan, store, &report, seeds, Vec::new()) else {
        return;
    };
    if (free as f64) < e.total_bytes {
        errln!(
            "warning: the store's filesystem has {} free, and this make will store ≈ {} (scaled from the last builds of the same stages{})\nhint: free space or use another --store first: a stage that runs out of space fails, and nothing built before it is lost",
            human_bytes(free),
            human_bytes(e.total_bytes as u64),
            if e.unmeasured.is_empty() {
                String::new()
            } else {
                format!("; {} never measured, not counted", e.unmeasured.len())
            }
        );
    }
}

/// The pipeline's `[executor]` with the user config's on top.
pub(crate) fn executor_config(plan: &Plan) -> Result<ExecutorConfig> {
    match user_config_path() {
        Some(path) => {
            let mut unknown = Vec::new();
            let user = load_user_config(&path, &plan.stage_names(), &mut unknown)?;
            if !unknown.is_empty() {
                tracing::debug!(
                    "{}: [executor.slurm.stages] for stages this pipeline does not declare: {}",
                    path.display(),
                    unknown.join(", ")
                );
            }
            Ok(plan.executor.overlaid(&user))
        }
        None => Ok(plan.executor.clone()),
    }
}

/// How Slurm tasks start this osms: absolute paths, since a job's working directory and
/// host differ from ours.
fn launch(ctx: &Context, store: &osms_store::Store, config: &ExecutorConfig) -> Result<Launch> {
    let abs = |p: &std::path::Path| {
        std::fs::canonicalize(p).with_context(|| format!("cannot resolve {}", p.display()))
    };
    let binary = match &config.slurm.binary {
        Some(b) => b.clone(),
        None => pinned_binary(store)?,
    };
    let pipeline = abs(&ctx.pipeline_path)?;
    let workdir = pipeline
        .parent()
        .map(std::path::Path::to_path_buf)
        .unwrap_or_else(|| "/".into());
    Ok(Launch {
        binary,
        pipeline,
        store: abs(store.root())?,
        workdir,
        platform: crate::platform::class(),
    })
}

/// A copy of this osms in the store, named by its hash, for the tasks to run: rebuilding
/// `target/release/osms` while jobs wait (`./osms` rebuilds it on every call) must not give
/// one stage shards from two binaries.
fn pinned_binary(store: &osms_store::Store) -> Result<std::path::PathBuf> {
    use std::os::unix::fs::PermissionsExt;
    let exe = std::env::current_exe().context("cannot find the osms executable")?;
    let bytes = std::fs::read(&exe).with_context(|| format!("cannot read {}", exe.display()))?;
    let name = format!("osms-{}", &osms_store::Hash::of(&bytes).to_hex()[..16]);
    let dir = store.state_path("slurm/bin");
    let dest = dir.join(&name);
    if !dest.is_file() {
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        let tmp = dir.join(format!(".{name}.{}", std::process::id()));
        std::fs::write(&tmp, &bytes).with_context(|| format!("cannot write {}", tmp.display()))?;
        std::fs::set_permissions(&tmp, std::fs::Permissions::from_mode(0o755))
            .with_context(|| format!("cannot make {} executable", tmp.display()))?;
        std::fs::rename(&tmp, &dest).with_context(|| format!("cannot write {}", dest.display()))?;
    }
    std::fs::canonicalize(&dest).with_context(|| format!("cannot resolve {}", dest.display()))
}

/// Writes every report, ablations or baselines stage this make built or found to its directory
/// (`report/` for the stage named `report`).
fn write_reports(
    ctx: &Context,
    plan: &Plan,
    store: &osms_store::Store,
    made: &osms_make::MakeReport,
    seeds: &[u64],
) -> Result<()> {
    for stage in plan
        .stages
        .iter()
        .filter(|s| report::REPORT_KINDS.contains(&s.info.name))
    {
        let done = made.instances.iter().any(|i| {
            i.instance == stage.name
                && matches!(
                    i.outcome,
                    Outcome::Built { .. }
                        | Outcome::Cached
                        | Outcome::CutOff
                        | Outcome::Pulled { .. }
                )
        });
        if !done {
            continue;
        }
        let dir = report::default_dir(ctx, &stage.name);
        let written = report::write(ctx, plan, store, &stage.name, seeds, &dir)?;
        say!(
            ctx,
            "osms make: wrote {} ({} files)",
            dir.join("index.md").display(),
            written.len()
        );
    }
    Ok(())
}

fn has_report(plan: &Plan) -> bool {
    plan.stages
        .iter()
        .any(|s| report::REPORT_KINDS.contains(&s.info.name))
}

/// Why `plan` must not be built with the MuJoCo that is loaded, if it must not: a stage steps
/// MuJoCo and the library is not the pinned release. Its version would enter the keys, so
/// nothing cached would be reused wrongly, but results from an unpinned MuJoCo are not the
/// project's results (a `MUJOCO_DYNAMIC_LINK_DIR` in the shell links another one at build time).
pub(crate) fn foreign_mujoco(plan: &Plan, pinned: &str) -> Option<String> {
    let (stage, loaded) = plan.stages.iter().find_map(|s| {
        s.info
            .numerics
            .iter()
            .find(|n| n.name == "mujoco" && n.version != pinned)
            .map(|n| (s.name.as_str(), n.version.clone()))
    })?;
    Some(format!(
        "stage `{stage}` steps MuJoCo, and the loaded MuJoCo is {loaded}, not the pinned {pinned}\n\
         hint: unset MUJOCO_DYNAMIC_LINK_DIR (and LD_LIBRARY_PATH entries with another MuJoCo), run \
         scripts/setup-mujoco, then rebuild osms (`./osms` does both); `osms doctor` shows what is loaded"
    ))
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use osms_make::Pipeline;

    use super::*;

    fn plan(text: &str) -> Plan {
        let pipeline = Pipeline::parse(Path::new("pipeline.toml"), text.to_string(), None)
            .expect("pipeline parses");
        Plan::new(&pipeline, &osms_kinds::registry()).expect("plans")
    }

    #[test]
    fn a_foreign_mujoco_is_refused_with_the_stage_and_both_versions() {
        let world = plan("[stages.world]\nkind = \"world\"\n");
        let loaded = osms_sim::mujoco_version();
        assert_eq!(foreign_mujoco(&world, &loaded), None);
        let problem = foreign_mujoco(&world, "9.9.9").expect("refused");
        assert!(
            problem.starts_with(&format!(
                "stage `world` steps MuJoCo, and the loaded MuJoCo is {loaded}, not the pinned 9.9.9"
            )),
            "{problem}"
        );
        assert!(problem.contains("MUJOCO_DYNAMIC_LINK_DIR"), "{problem}");
    }

    #[test]
    fn the_pinned_mujoco_is_the_loaded_one_and_the_installed_one() {
        assert_eq!(osms_sim::mujoco_version(), osms_sim::MUJOCO_PINNED);
        let script = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scripts/setup-mujoco"
        ))
        .expect("scripts/setup-mujoco");
        assert!(
            script
                .lines()
                .any(|l| l == format!("MJ_VERSION={}", osms_sim::MUJOCO_PINNED)),
            "scripts/setup-mujoco installs another MuJoCo than osms_sim::MUJOCO_PINNED"
        );
    }
}
