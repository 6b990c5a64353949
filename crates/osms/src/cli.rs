//! Every clap type of the `osms` command line.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "osms",
    version,
    about = "Outcome-sensitive motion search as a deterministic, content-addressed build"
)]
pub struct Cli {
    #[command(flatten)]
    pub global: Global,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Args)]
pub struct Global {
    /// The pipeline declaration [default: pipeline.toml in this or a parent directory]
    #[arg(long, global = true, env = "OSMS_PIPELINE", value_name = "FILE")]
    pub pipeline: Option<PathBuf>,
    /// The artifact store [default: store/ beside pipeline.toml]
    #[arg(long, global = true, env = "OSMS_STORE", value_name = "DIR")]
    pub store: Option<PathBuf>,
    /// Print only errors (and data on stdout)
    #[arg(short, long, global = true)]
    pub quiet: bool,
    /// Print more: cached stages, debug logs
    #[arg(short, long, global = true)]
    pub verbose: bool,
    /// Hide progress bars
    #[arg(long, global = true, env = "OSMS_NO_PROGRESS", value_parser = clap::builder::BoolishValueParser::new())]
    pub no_progress: bool,
}

#[derive(Debug, Args, Clone)]
pub struct Selection {
    /// Profile overlaying the params [default: the pipeline's default_profile]
    #[arg(long, short = 'p')]
    pub profile: Option<String>,
    /// Run seed [default: the pipeline's run seeds]
    #[arg(long, conflicts_with = "seeds")]
    pub seed: Option<u64>,
    /// A seed sweep: the seed-dependent stages once per seed, the rest shared
    #[arg(long, value_delimiter = ',', value_name = "S,S,...")]
    pub seeds: Option<Vec<u64>>,
    /// Override a knob for this command: a param by its dotted path, or `shards`/`seed`
    /// (repeatable; applied after the profile; see "Experiments" in README.md)
    #[arg(long = "set", value_name = "STAGE.PATH=VALUE")]
    pub set: Vec<String>,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Build the targets (the pipeline's `targets` if none), reusing everything already in the store
    Make(MakeArgs),
    /// Show which stages are cached, stale (and why) or missing
    Status(StatusArgs),
    /// Show the lineage of a stage: its inputs, recursively, with keys and content hashes
    Why(WhyArgs),
    /// Show an artifact's metadata and a summary of its contents
    Show(ShowArgs),
    /// Write an artifact's files (tables as Markdown, CSV and JSON; learning curves as CSV)
    Export(ExportArgs),
    /// Write a rollout dataset or demonstration set as LeRobot v3.0 (Parquet) or robomimic (HDF5)
    ExportDataset(ExportDatasetArgs),
    /// Replay a rollout open loop from its recorded controls and compare it with its record
    Replay(ReplayArgs),
    /// Render a rollout offscreen: key frames as a PNG strip, a GIF and a faded-poses picture
    Render(RenderArgs),
    /// List the artifacts in the store
    Ls(JsonArg),
    /// Re-hash every object in the store and report damage
    Verify(JsonArg),
    /// Remove objects that no current stage key and no named experiment reaches
    Gc(GcArgs),
    /// Upload the targets' current builds (objects, then their stage records) to a remote cache
    Push(TransferArgs),
    /// Download the targets' builds from a remote cache, following stage keys from the first
    /// stage down; builds nothing
    Pull(TransferArgs),
    /// Named experiments: run variants of the pipeline (overrides, sweeps) and compare them
    #[command(subcommand)]
    Exp(ExpCommand),
    /// Start a project: the pipeline osms ships (pipeline.toml) and an empty store in DIR
    Init(InitArgs),
    /// Check the set-up: MuJoCo, store, pipeline, platform class
    Doctor(JsonArg),
    /// List the stage kinds this osms knows, with their inputs and code versions
    Kinds(JsonArg),
    /// The simulated world
    #[command(subcommand)]
    World(WorldCommand),
    /// Build one submitted instance or shard (run by Slurm jobs of `make --executor slurm`)
    #[command(hide = true)]
    RunTask(RunTaskArgs),
}

#[derive(Debug, Subcommand)]
pub enum ExpCommand {
    /// Build the targets under overrides and sweeps, and record what each point produced
    Run(ExpRunArgs),
    /// List the experiments: name, profile, points, targets and knobs (reads their records only)
    Ls(JsonArg),
    /// Compare experiments: one row per experiment (per sweep point), its knobs and metrics
    Show(ExpShowArgs),
    /// Two experiments (or points, `NAME/k`) side by side: knobs, metric deltas, shared work
    Diff(ExpDiffArgs),
    /// Draw metrics against a knob over experiments' points (a data curve, a regime map):
    /// SVG, PNG and the CSV of the numbers, each point with its 95 % interval
    Plot(ExpPlotArgs),
    /// Forget experiments; their artifacts go at the next `osms gc` unless something else keeps them
    Rm(ExpRmArgs),
}

#[derive(Debug, Args)]
pub struct ExpRunArgs {
    /// The experiment's name (letters, digits, `_`, `-`, `.`)
    pub name: String,
    /// Stages to build [default: the pipeline's `experiment_targets`]
    pub targets: Vec<String>,
    #[command(flatten)]
    pub selection: Selection,
    /// Sweep a knob over values (repeatable: the points are the product of the axes)
    #[arg(long, value_name = "STAGE.PATH=A,B,...")]
    pub sweep: Vec<String>,
    /// Replace an experiment of this name
    #[arg(long)]
    pub force: bool,
    /// Show what would be built, build and record nothing
    #[arg(long, short = 'n')]
    pub dry_run: bool,
    /// Worker threads of each build [default: all cores]
    #[arg(long, short = 'j')]
    pub jobs: Option<usize>,
    /// Stage instances built at the same time (at most --jobs), each with --jobs worker threads
    /// of its own, sharing the cores: a number from 1 to 64, or `auto` (2 when there are at
    /// least 2 jobs: a student's training leaves part of 2 cores idle) [default: auto]
    #[arg(long, value_name = "N|auto", env = "OSMS_STAGES")]
    pub stages: Option<Stages>,
    /// Print the experiment's record as JSON on stdout
    #[arg(long)]
    pub json: bool,
}

/// What `exp show` and `exp diff` compare when not told.
const DEFAULT_METRICS: &str = "success,completion,f_max,train_secs";

#[derive(Debug, Args)]
pub struct ExpShowArgs {
    /// Experiments to show [default: all]
    pub names: Vec<String>,
    /// Metrics: keys of the targets' summaries (`osms show`), with the short names `success`,
    /// `completion`, `f_max`, `train_secs` (the build time of the networks a target reads, from
    /// the build records) and `train_core_secs` (their CPU time: the same at any `--stages`);
    /// the total build time is always shown
    #[arg(long, value_delimiter = ',', default_value = DEFAULT_METRICS)]
    pub metrics: Vec<String>,
    /// Print JSON on stdout
    #[arg(long, conflicts_with = "csv")]
    pub json: bool,
    /// Print CSV on stdout (one line per row)
    #[arg(long)]
    pub csv: bool,
    /// After each rate (success, completion), its 95 % Wilson interval and n over the
    /// rollouts pooled over the run seeds
    #[arg(long)]
    pub ci: bool,
}

#[derive(Debug, Args)]
pub struct ExpDiffArgs {
    /// An experiment, or one point of a sweep as `NAME/k`
    pub a: String,
    /// The other
    pub b: String,
    #[arg(long, value_delimiter = ',', default_value = DEFAULT_METRICS)]
    pub metrics: Vec<String>,
    /// Compare STAGE's success rollout by rollout instead: every evaluation of STAGE in A (each
    /// point and run seed one seed) against every one in B, paired by condition (all on the
    /// same condition set), with a 95 % interval that holds the seeds' spread. `A_STAGE:B_STAGE`
    /// compares two stages (A and B may then name the same experiment)
    #[arg(long, value_name = "STAGE")]
    pub paired: Option<String>,
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct ExpPlotArgs {
    /// Experiments, or points `NAME/k`, whose points are drawn (points that share the x value,
    /// `--by` value and metric pool into one)
    #[arg(required = true)]
    pub names: Vec<String>,
    /// The knob on the x axis (`STAGE.PATH`, as given to --set or --sweep); its values are
    /// the axis' steps, in numeric order when all are numbers
    #[arg(long, value_name = "STAGE.PATH")]
    pub x: String,
    /// A line per value of this knob
    #[arg(long, value_name = "STAGE.PATH")]
    pub by: Option<String>,
    /// Metrics, a panel each (as `osms exp show --metrics`); a line per target stage that has it
    #[arg(long, value_delimiter = ',', default_value = "success")]
    pub metrics: Vec<String>,
    /// Directory the files go to (created if missing; files of the same name are replaced)
    #[arg(long, short, default_value = ".")]
    pub out: PathBuf,
    /// File stem of the figure [default: exp-NAME-KNOB]
    #[arg(long)]
    pub id: Option<String>,
    /// The figure's title [default: METRICS against KNOB]
    #[arg(long)]
    pub title: Option<String>,
    /// Name a target stage, metric or knob in the figure and its CSV (repeatable), e.g.
    /// `--label dev_student=Ours-IL --label validate.kappa=κ`
    #[arg(long, value_name = "NAME=TEXT")]
    pub label: Vec<String>,
    /// Print the files written and the plotted numbers as JSON on stdout
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct ExpRmArgs {
    #[arg(required = true)]
    pub names: Vec<String>,
}

#[derive(Debug, Subcommand)]
pub enum WorldCommand {
    /// Print the exact MJCF of the world (the `world` stage's params under the profile)
    Dump(WorldDumpArgs),
}

#[derive(Debug, Args)]
pub struct WorldDumpArgs {
    /// Profile overlaying the params [default: the pipeline's default_profile]
    #[arg(long, short = 'p')]
    pub profile: Option<String>,
    /// Which object variant's model, e.g. `sphere-small`
    #[arg(long, default_value = "sphere-large")]
    pub object: String,
    /// The stage of kind `world` to read params from [default: the only one]
    #[arg(long)]
    pub stage: Option<String>,
}

#[derive(Debug, Args)]
pub struct InitArgs {
    /// The project's directory, created if absent [default: the working directory]; the store
    /// goes to DIR/store unless --store says otherwise
    pub dir: Option<PathBuf>,
    /// Print the written paths as JSON on stdout
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct JsonArg {
    /// Print JSON on stdout
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct MakeArgs {
    /// Stages to build (with everything they need) [default: the pipeline's `targets`, else
    /// every stage]
    pub targets: Vec<String>,
    #[command(flatten)]
    pub selection: Selection,
    /// Show what would be built, build nothing
    #[arg(long, short = 'n')]
    pub dry_run: bool,
    /// Worker threads of each build [default: all cores]
    #[arg(long, short = 'j')]
    pub jobs: Option<usize>,
    /// Stage instances built at the same time (at most --jobs), each with --jobs worker threads
    /// of its own, sharing the cores: a number from 1 to 64, or `auto` (2 when there are at
    /// least 2 jobs: a student's training leaves part of 2 cores idle) [default: auto]
    #[arg(long, value_name = "N|auto", env = "OSMS_STAGES")]
    pub stages: Option<Stages>,
    /// Where stages run: `local`, or `slurm` (a job array per sharded stage; see "Running on a
    /// cluster" in README.md) [default: `[executor] kind`, else local]
    #[arg(long, value_name = "local|slurm")]
    pub executor: Option<osms_make::executor::ExecutorKind>,
    /// Before building an instance, look its stage key up on this remote cache and download it
    /// if found [default: `[pipeline] remote`, if set]
    #[arg(long, short = 'r', value_name = "NAME", conflicts_with = "no_remote")]
    pub remote: Option<String>,
    /// Build everything here, even if the pipeline names a default remote
    #[arg(long)]
    pub no_remote: bool,
    /// Print the report as JSON on stdout
    #[arg(long)]
    pub json: bool,
}

/// `osms push` and `osms pull`.
#[derive(Debug, Args)]
pub struct TransferArgs {
    /// Stages whose builds move, with everything they need [default: the pipeline's
    /// `targets`, else every stage]
    pub targets: Vec<String>,
    #[command(flatten)]
    pub selection: Selection,
    /// The remote: a `[remotes.NAME]` of pipeline.toml or of the user config
    /// [default: `[pipeline] remote`]
    #[arg(long, short = 'r', value_name = "NAME")]
    pub remote: Option<String>,
    /// Transfers at once
    #[arg(long, value_name = "N", default_value_t = osms_remote::DEFAULT_JOBS)]
    pub transfers: usize,
    /// Print what moved as JSON on stdout
    #[arg(long)]
    pub json: bool,
}

/// `osms run-task`: what a Slurm job runs on a compute node (not for people).
#[derive(Debug, Args)]
pub struct RunTaskArgs {
    /// The stage key the driver submitted
    pub key: String,
    /// Compute this shard only (an array task); without it, build the instance (the merge)
    #[arg(long)]
    pub shard: Option<u32>,
}

#[derive(Debug, Args)]
pub struct StatusArgs {
    pub targets: Vec<String>,
    #[command(flatten)]
    pub selection: Selection,
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct WhyArgs {
    /// A stage name, or `stage@seed`
    pub target: String,
    #[command(flatten)]
    pub selection: Selection,
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct ShowArgs {
    /// A stage name (`name` or `name@seed`, its current build under the profile), or a stage
    /// key or content hash (a unique prefix of at least 6 hex digits is enough)
    pub hash: String,
    #[command(flatten)]
    pub selection: Selection,
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct ExportArgs {
    /// A stage name (`name` or `name@seed`), or a key or content hash prefix
    pub target: String,
    #[command(flatten)]
    pub selection: Selection,
    /// Directory to write into [default: reports/<profile>/<instance>/ beside pipeline.toml]
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Print the written paths as JSON on stdout
    #[arg(long)]
    pub json: bool,
}

/// The layouts `osms export-dataset` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DatasetFormat {
    /// LeRobot v3.0: meta/ (info, stats, tasks, episodes) and data/ Parquet files
    Lerobot,
    /// robomimic: one HDF5 file with data/demo_i/{actions, obs, states, rewards, dones} and mask/
    Robomimic,
}

impl DatasetFormat {
    pub fn name(self) -> &'static str {
        match self {
            DatasetFormat::Lerobot => "lerobot",
            DatasetFormat::Robomimic => "robomimic",
        }
    }
}

#[derive(Debug, Args)]
pub struct ExportDatasetArgs {
    /// A dataset stage (`d_r`, `dstar`, ...), or a key or content hash prefix
    pub target: String,
    #[command(flatten)]
    pub selection: Selection,
    #[arg(long, value_enum)]
    pub format: DatasetFormat,
    /// Directory to write [default: exports/<profile>/<stage>-<format>/ beside pipeline.toml]
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Put the privileged frame (true object state, mass, contact force, ...) among the policy
    /// inputs: LeRobot's `observation.environment_state`, robomimic's `obs/privileged`.
    /// Without it the frame is kept under `osms.privileged` / `osms/privileged`, which no
    /// library feeds to a policy by default
    #[arg(long)]
    pub privileged_obs: bool,
    /// Print what was written as JSON on stdout
    #[arg(long)]
    pub json: bool,
}

/// One episode of a rollout dataset.
#[derive(Debug, Args)]
pub struct EpisodeRef {
    /// A rollout dataset stage (`d_m`, `d_e`, `d_r`), or a key or content hash prefix
    pub target: String,
    #[command(flatten)]
    pub selection: Selection,
    /// Which episode (0-based, in the dataset's order)
    #[arg(long)]
    pub episode: usize,
}

#[derive(Debug, Args)]
pub struct ReplayArgs {
    #[command(flatten)]
    pub at: EpisodeRef,
    /// Print the report as JSON on stdout
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct RenderArgs {
    #[command(flatten)]
    pub at: EpisodeRef,
    /// The PNG strip of key frames (NAME.png); the GIF and the faded-poses picture are written
    /// beside it (NAME.gif, NAME-poses.png)
    #[arg(long)]
    pub out: PathBuf,
    /// Width of one frame in pixels
    #[arg(long, default_value_t = 480)]
    pub width: u32,
    /// Height of one frame in pixels
    #[arg(long, default_value_t = 360)]
    pub height: u32,
    /// Print what was written as JSON on stdout
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct GcArgs {
    /// Keep only what these profiles reach [default: every declared profile]
    #[arg(long = "profile", short = 'p')]
    pub profiles: Vec<String>,
    /// Keep only these seeds [default: the pipeline's run seeds and every seed built before]
    #[arg(long, value_delimiter = ',')]
    pub seeds: Option<Vec<u64>>,
    /// Report what would be removed, remove nothing
    #[arg(long, short = 'n')]
    pub dry_run: bool,
    #[arg(long)]
    pub json: bool,
}

/// How many stage instances a make builds at once (`--stages`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stages {
    Auto,
    Count(u32),
}

impl Stages {
    /// Instances at once for a make of `jobs` worker threads per build. `auto` is 2 from 2
    /// jobs up: measured on 2 cores (docs/make.md, "Where the time goes"), where a student's
    /// training keeps ≈ 1.4 cores busy and two builds side by side fill both.
    pub fn resolve(stages: Option<Stages>, jobs: usize) -> usize {
        match stages.unwrap_or(Stages::Auto) {
            Stages::Auto => jobs.clamp(1, 2),
            Stages::Count(n) => n as usize,
        }
    }
}

impl std::str::FromStr for Stages {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        if s == "auto" {
            return Ok(Stages::Auto);
        }
        match s.parse::<u32>() {
            Ok(n) if (1..=64).contains(&n) => Ok(Stages::Count(n)),
            _ => Err(format!(
                "`{s}` is not a number of stages: expected 1 to 64, or `auto`"
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stages_parse_a_count_or_auto_and_auto_is_two_from_two_jobs() {
        assert_eq!("auto".parse::<Stages>(), Ok(Stages::Auto));
        assert_eq!("3".parse::<Stages>(), Ok(Stages::Count(3)));
        for bad in ["0", "65", "-1", "two", ""] {
            let e = bad.parse::<Stages>().expect_err(bad);
            assert!(e.contains("expected 1 to 64, or `auto`"), "{bad}: {e}");
        }
        assert_eq!(Stages::resolve(None, 1), 1);
        assert_eq!(Stages::resolve(None, 2), 2);
        assert_eq!(Stages::resolve(Some(Stages::Auto), 16), 2);
        assert_eq!(Stages::resolve(Some(Stages::Count(3)), 2), 3);
    }
}
