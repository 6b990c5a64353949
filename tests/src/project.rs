//! A temporary osms project (pipeline.toml + store) for tests and benchmarks.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use osms_make::{MakeOptions, MakeReport, Observer, Outcome, Pipeline, Plan, Registry};
use osms_store::{Hash, Store};

/// The engine test pipeline.
pub const ENGINE_PIPELINE: &str = include_str!("../pipelines/engine.toml");

pub struct Project {
    pub dir: tempfile::TempDir,
    pub pipeline: PathBuf,
    pub store: PathBuf,
    pub registry: Registry,
}

pub use osms_make::Silent;

impl Project {
    pub fn new(pipeline_text: &str) -> Self {
        let dir = tempfile::tempdir().expect("temp dir");
        let pipeline = dir.path().join("pipeline.toml");
        std::fs::write(&pipeline, pipeline_text).expect("write pipeline.toml");
        let store = dir.path().join("store");
        Project {
            dir,
            pipeline,
            store,
            registry: crate::registry(),
        }
    }

    pub fn engine() -> Self {
        Self::new(ENGINE_PIPELINE)
    }

    pub fn write_pipeline(&self, text: &str) {
        std::fs::write(&self.pipeline, text).expect("write pipeline.toml");
    }

    pub fn plan(&self, profile: Option<&str>) -> osms_make::Result<Plan> {
        let pipeline = Pipeline::load(&self.pipeline, profile)?;
        Plan::new(&pipeline, &self.registry)
    }

    pub fn open_store(&self) -> Store {
        Store::open(&self.store).expect("open store")
    }

    /// Builds everything for `profile` and `seeds` with `jobs` threads through the library.
    pub fn make(&self, profile: Option<&str>, seeds: &[u64], jobs: usize) -> MakeReport {
        self.make_with_stages(profile, seeds, jobs, 1)
    }

    /// [`Project::make`] building up to `stages` instances at the same time.
    pub fn make_with_stages(
        &self,
        profile: Option<&str>,
        seeds: &[u64],
        jobs: usize,
        stages: usize,
    ) -> MakeReport {
        self.make_observed(profile, seeds, jobs, stages, &Silent)
    }

    /// [`Project::make_with_stages`] shown to `observer`.
    pub fn make_observed(
        &self,
        profile: Option<&str>,
        seeds: &[u64],
        jobs: usize,
        stages: usize,
        observer: &dyn Observer,
    ) -> MakeReport {
        let plan = self.plan(profile).expect("plan");
        let opts = MakeOptions {
            targets: vec![],
            seeds: seeds.to_vec(),
            jobs,
            stages,
            dry_run: false,
        };
        osms_make::make(&plan, &self.open_store(), &opts, observer).expect("make")
    }

    /// Runs an osms binary on this project with progress bars off.
    pub fn run(&self, bin: &Path, args: &[&str]) -> Output {
        self.command(bin, args).output().expect("run osms")
    }

    /// The command [`Project::run`] runs, for a test that sets its own stdio or environment.
    pub fn command(&self, bin: &Path, args: &[&str]) -> Command {
        self.command_on(bin, &self.store, args)
    }

    /// [`Project::command`] with the store at `store` (a mount of the project's own, say).
    pub fn command_on(&self, bin: &Path, store: &Path, args: &[&str]) -> Command {
        let mut c = Command::new(bin);
        c.arg("--pipeline")
            .arg(&self.pipeline)
            .arg("--store")
            .arg(store)
            .args(args)
            .env("OSMS_NO_PROGRESS", "1")
            // One build at a time unless a test asks for more: the snapshots record the log
            // lines in the order one-at-a-time builds print them (the engine tests cover
            // builds side by side).
            .env("OSMS_STAGES", "1")
            .env_remove("OSMS_LOG")
            .current_dir(self.dir.path());
        c
    }
}

/// Instance name -> content hash of every instance the report built or found.
pub fn hashes(report: &MakeReport) -> BTreeMap<String, Hash> {
    report
        .instances
        .iter()
        .filter_map(|r| r.content_hash.map(|h| (r.instance.clone(), h)))
        .collect()
}

/// Instance name -> outcome label.
pub fn outcomes(report: &MakeReport) -> BTreeMap<String, &'static str> {
    report
        .instances
        .iter()
        .map(|r| {
            let label = match r.outcome {
                Outcome::Built { .. } => "built",
                Outcome::Cached => "cached",
                Outcome::Pulled { .. } => "pulled",
                Outcome::CutOff => "cut off",
                Outcome::WouldBuild { .. } => "would build",
                Outcome::Failed { .. } => "failed",
                Outcome::Skipped { .. } => "skipped",
            };
            (r.instance.clone(), label)
        })
        .collect()
}

/// The error of the first failed instance of `report`.
pub fn first_failure(report: &MakeReport) -> Option<String> {
    report.instances.iter().find_map(|r| match &r.outcome {
        Outcome::Failed { error } => Some(error.clone()),
        _ => None,
    })
}
