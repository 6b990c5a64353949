//! Finding the project (pipeline.toml) and the store, and loading the plan.

use std::path::{Path, PathBuf};

use anyhow::{Context as _, Result, bail};
use osms_make::overrides::Override;
use osms_make::{Pipeline, Plan, Registry};
use osms_store::Store;

use crate::cli::{Global, Selection};
use crate::term::Printer;

pub struct Context {
    pub pipeline_path: PathBuf,
    pub store_path: PathBuf,
    /// The `--pipeline` and `--store` the call was given (on its command line or through
    /// `OSMS_PIPELINE`/`OSMS_STORE`), as a command names them: a hint's command repeats them.
    location_args: String,
    pub registry: Registry,
    pub printer: Printer,
}

impl Context {
    pub fn new(global: &Global, registry: Registry) -> Result<Self> {
        let pipeline_path = match &global.pipeline {
            Some(p) => p.clone(),
            None => find_pipeline()?,
        };
        let store_path = match &global.store {
            Some(s) => s.clone(),
            None => pipeline_path
                .parent()
                .unwrap_or(Path::new("."))
                .join("store"),
        };
        let mut location_args = String::new();
        if let Some(p) = &global.pipeline {
            location_args.push_str(&format!(" --pipeline {}", p.display()));
        }
        if let Some(s) = &global.store {
            location_args.push_str(&format!(" --store {}", s.display()));
        }
        Ok(Context {
            pipeline_path,
            store_path,
            location_args,
            registry,
            printer: Printer::new(global),
        })
    }

    /// The `osms make` command that builds `target` under `profile` into this call's project,
    /// in backticks, for a hint: it works where the user is.
    pub fn make_command(&self, target: &str, profile: &str) -> String {
        format!(
            "`osms make {target} --profile {profile}{}`",
            self.location_args
        )
    }

    pub fn store(&self) -> Result<Store> {
        Store::open(&self.store_path)
            .with_context(|| format!("cannot open the store at {}", self.store_path.display()))
    }

    pub fn plan(&self, profile: Option<&str>) -> Result<Plan> {
        self.plan_with(profile, &[])
    }

    /// The plan of a selection: its profile, with its `--set` overrides applied.
    pub fn selected_plan(&self, selection: &Selection) -> Result<Plan> {
        self.plan_with(
            selection.profile.as_deref(),
            &parse_overrides(&selection.set)?,
        )
    }

    pub fn plan_with(&self, profile: Option<&str>, overrides: &[Override]) -> Result<Plan> {
        self.plan_of(Pipeline::load(&self.pipeline_path, profile)?, overrides)
    }

    /// The plan of a loaded pipeline with `overrides` applied.
    pub fn plan_of(&self, mut pipeline: Pipeline, overrides: &[Override]) -> Result<Plan> {
        pipeline.apply(overrides)?;
        Ok(Plan::new(&pipeline, &self.registry)?)
    }

    /// Worker threads: `--jobs`, else every core.
    pub fn jobs(requested: Option<usize>) -> usize {
        requested.unwrap_or_else(|| {
            std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1)
        })
    }

    /// Seeds of a selection: `--seeds`, else `--seed`, else the pipeline's run seeds.
    pub fn seeds(selection: &Selection, plan: &Plan) -> Vec<u64> {
        match (&selection.seeds, selection.seed) {
            (Some(seeds), _) if !seeds.is_empty() => {
                let mut s = seeds.clone();
                s.sort_unstable();
                s.dedup();
                s
            }
            (_, Some(seed)) => vec![seed],
            _ => plan.default_seeds.clone(),
        }
    }
}

/// `--set` arguments, each `STAGE.PATH=VALUE`.
pub fn parse_overrides(texts: &[String]) -> Result<Vec<Override>> {
    Ok(texts
        .iter()
        .map(|t| t.parse::<Override>())
        .collect::<std::result::Result<_, _>>()?)
}

fn find_pipeline() -> Result<PathBuf> {
    let cwd = std::env::current_dir().context("cannot read the current directory")?;
    for dir in cwd.ancestors() {
        let candidate = dir.join("pipeline.toml");
        if candidate.is_file() {
            return Ok(candidate);
        }
    }
    bail!(
        "no pipeline.toml in {} or any parent directory\nhint: run osms inside an osms project, or pass --pipeline FILE",
        cwd.display()
    )
}
