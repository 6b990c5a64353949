//! `[executor]` settings: where `osms make` runs stages, and the Slurm job resources.
//!
//! ```toml
//! [executor]
//! kind = "local"              # or "slurm"; `osms make --executor` overrides it
//!
//! [executor.slurm]
//! partition = "cpu"           # sbatch --partition
//! account = "my-lab"          # sbatch --account
//! time = "04:00:00"           # sbatch --time, per job
//! cpus_per_task = 8           # sbatch --cpus-per-task, also the threads of each task
//! mem = "16G"                 # sbatch --mem
//! sbatch_args = ["--qos=normal"]
//! poll_secs = 10              # how often the driver looks at squeue and the store
//!
//! [executor.slurm.stages.teacher]   # per-stage overrides of the job resources
//! time = "2-00:00:00"
//! cpus_per_task = 16
//! ```
//!
//! The same tables may sit in a user config (`$OSMS_CONFIG`, else
//! `$XDG_CONFIG_HOME/osms/config.toml`, else `~/.config/osms/config.toml`), so an account and
//! partition need not be committed with the pipeline: its values override the pipeline's one by
//! one. None of this enters a stage key: where a stage ran does not change its bytes.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{Error, Location, Result};

/// Where stages run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ExecutorKind {
    /// In this process, one stage at a time, items in parallel.
    #[default]
    Local,
    /// As Slurm jobs: a job array per sharded stage, one job per other stage.
    Slurm,
}

impl std::str::FromStr for ExecutorKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "local" => Ok(ExecutorKind::Local),
            "slurm" => Ok(ExecutorKind::Slurm),
            other => Err(format!("unknown executor `{other}`; valid: local, slurm")),
        }
    }
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExecutorConfig {
    #[serde(default)]
    pub kind: Option<ExecutorKind>,
    #[serde(default)]
    pub slurm: SlurmConfig,
}

/// The resources of one job; every field falls back to the `[executor.slurm]` value, then to
/// the cluster's defaults.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobResources {
    pub partition: Option<String>,
    pub account: Option<String>,
    pub time: Option<String>,
    pub cpus_per_task: Option<u32>,
    pub mem: Option<String>,
    /// More sbatch flags, appended after the global ones.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sbatch_args: Vec<String>,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SlurmConfig {
    // The fields of `JobResources`, spelt out: `#[serde(flatten)]` would lose the line of an
    // unknown field in error messages.
    pub partition: Option<String>,
    pub account: Option<String>,
    pub time: Option<String>,
    pub cpus_per_task: Option<u32>,
    pub mem: Option<String>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sbatch_args: Vec<String>,
    /// Seconds between looks at squeue and the store [default: 10].
    pub poll_secs: Option<f64>,
    /// Build on a filesystem osms does not know (e.g. a FUSE one) after its own check of
    /// renames and locks passed.
    pub trust_filesystem: Option<bool>,
    /// The osms binary as the compute nodes see it [default: this one].
    pub binary: Option<PathBuf>,
    /// Per-stage overrides, by stage name.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub stages: BTreeMap<String, JobResources>,
}

/// sbatch flags osms sets itself or that would break the driver, long and short.
const OWN_FLAGS: &[&str] = &[
    "array",
    "dependency",
    "parsable",
    "output",
    "error",
    "job-name",
    "wrap",
    "chdir",
    "cpus-per-task",
    "clusters",
    "cluster",
    "wait",
    "kill-on-invalid-dep",
];
const OWN_SHORT: &[char] = &['a', 'd', 'o', 'e', 'J', 'D', 'c', 'M', 'W'];

/// Default seconds between polls.
pub const DEFAULT_POLL_SECS: f64 = 10.0;

impl JobResources {
    /// `self`, with `over`'s fields where it sets them (flags are appended).
    fn overlaid(&self, over: &JobResources) -> JobResources {
        JobResources {
            partition: over.partition.clone().or_else(|| self.partition.clone()),
            account: over.account.clone().or_else(|| self.account.clone()),
            time: over.time.clone().or_else(|| self.time.clone()),
            cpus_per_task: over.cpus_per_task.or(self.cpus_per_task),
            mem: over.mem.clone().or_else(|| self.mem.clone()),
            sbatch_args: self
                .sbatch_args
                .iter()
                .chain(&over.sbatch_args)
                .cloned()
                .collect(),
        }
    }

    /// The sbatch flags these resources stand for.
    pub fn sbatch_flags(&self) -> Vec<String> {
        let mut flags = Vec::new();
        let mut add = |name: &str, value: &Option<String>| {
            if let Some(v) = value {
                flags.push(format!("--{name}={v}"));
            }
        };
        add("partition", &self.partition);
        add("account", &self.account);
        add("time", &self.time);
        add("mem", &self.mem);
        flags.push(format!("--cpus-per-task={}", self.cpus()));
        flags.extend(self.sbatch_args.iter().cloned());
        flags
    }

    /// The CPUs a task asks for, and so the threads it runs.
    pub fn cpus(&self) -> u32 {
        self.cpus_per_task.unwrap_or(1)
    }
}

impl SlurmConfig {
    /// The job resources every stage starts from.
    pub fn resources(&self) -> JobResources {
        JobResources {
            partition: self.partition.clone(),
            account: self.account.clone(),
            time: self.time.clone(),
            cpus_per_task: self.cpus_per_task,
            mem: self.mem.clone(),
            sbatch_args: self.sbatch_args.clone(),
        }
    }
}

impl ExecutorConfig {
    /// The pipeline's settings with a user config's on top.
    pub fn overlaid(&self, user: &ExecutorConfig) -> ExecutorConfig {
        let (base, over) = (&self.slurm, &user.slurm);
        let mut stages = base.stages.clone();
        for (name, res) in &over.stages {
            let merged = stages.get(name).cloned().unwrap_or_default().overlaid(res);
            stages.insert(name.clone(), merged);
        }
        let resources = base.resources().overlaid(&over.resources());
        ExecutorConfig {
            kind: user.kind.or(self.kind),
            slurm: SlurmConfig {
                partition: resources.partition,
                account: resources.account,
                time: resources.time,
                cpus_per_task: resources.cpus_per_task,
                mem: resources.mem,
                sbatch_args: resources.sbatch_args,
                poll_secs: over.poll_secs.or(base.poll_secs),
                trust_filesystem: over.trust_filesystem.or(base.trust_filesystem),
                binary: over.binary.clone().or_else(|| base.binary.clone()),
                stages,
            },
        }
    }

    /// Checks what serde cannot: stage names exist, numbers are sensible. `locate` finds a key
    /// path (e.g. `["executor", "slurm", "poll_secs"]`) in the file the settings came from.
    pub fn validate(
        &self,
        stage_names: &[&str],
        locate: &dyn Fn(&[&str]) -> Option<Location>,
    ) -> Result<()> {
        let s = &self.slurm;
        if let Some(p) = s.poll_secs
            && !(0.01..=86_400.0).contains(&p)
        {
            return Err(Error::invalid(
                locate(&["executor", "slurm", "poll_secs"]),
                format!("[executor.slurm] poll_secs = {p} is out of range"),
                Some("use seconds between 0.01 and 86400 (a day)".into()),
            ));
        }
        let global = s.resources();
        let all = std::iter::once((None, &global))
            .chain(s.stages.iter().map(|(n, r)| (Some(n.as_str()), r)));
        for (stage, res) in all {
            let mut keys = vec!["executor", "slurm"];
            if let Some(n) = stage {
                keys.extend(["stages", n]);
            }
            let at = |field: &str| {
                let mut k = keys.clone();
                k.push(field);
                locate(&k)
            };
            let table = stage
                .map(|n| format!("[executor.slurm.stages.{n}]"))
                .unwrap_or_else(|| "[executor.slurm]".to_string());
            if let Some(n) = stage
                && !stage_names.is_empty()
                && !stage_names.contains(&n)
            {
                return Err(Error::invalid(
                    locate(&keys),
                    format!("{table} names stage `{n}`, which is not declared"),
                    Some(format!(
                        "declared stages are {}",
                        crate::error::list(stage_names)
                    )),
                ));
            }
            if res.cpus_per_task == Some(0) {
                return Err(Error::invalid(
                    at("cpus_per_task"),
                    format!("{table} cpus_per_task = 0; it must be at least 1"),
                    None,
                ));
            }
            for flag in &res.sbatch_args {
                let name = flag.trim_start_matches('-').split('=').next().unwrap_or("");
                // A short flag may carry its value: `-a0-3`, `-J name`.
                let short = (flag.starts_with('-') && !flag.starts_with("--"))
                    .then(|| flag.chars().nth(1))
                    .flatten();
                if OWN_FLAGS.contains(&name) || short.is_some_and(|c| OWN_SHORT.contains(&c)) {
                    return Err(Error::invalid(
                        at("sbatch_args"),
                        format!("{table} sbatch_args holds `{flag}`, which osms sets itself"),
                        Some("osms sets --array, --dependency, --parsable, --output, --error, --job-name, --chdir and the script itself; --cpus-per-task goes in `cpus_per_task` (it is also the task's thread count); jobs must stay on the cluster squeue sees (no --clusters), and the driver waits itself (no --wait)".into()),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The resources of `stage`'s jobs.
    pub fn resources(&self, stage: &str) -> JobResources {
        match self.slurm.stages.get(stage) {
            Some(over) => self.slurm.resources().overlaid(over),
            None => self.slurm.resources(),
        }
    }

    pub fn poll_secs(&self) -> f64 {
        self.slurm.poll_secs.unwrap_or(DEFAULT_POLL_SECS)
    }
}

/// The user config file osms reads, if any: `$OSMS_CONFIG`, else the XDG location.
pub fn user_config_path() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("OSMS_CONFIG") {
        return Some(PathBuf::from(p));
    }
    let base = std::env::var_os("XDG_CONFIG_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".config")))?;
    let path = base.join("osms").join("config.toml");
    path.is_file().then_some(path)
}

/// A user config file: an `[executor]` table and `[remotes.NAME]` tables.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct UserConfig {
    #[serde(default)]
    executor: ExecutorConfig,
    #[serde(default)]
    remotes: BTreeMap<String, crate::remotes::RemoteSpec>,
}

/// Reads a user config file, with errors located in it. Per-stage tables for stages this
/// pipeline does not declare are allowed (one user config serves many projects); `unknown`
/// lists them so the caller can say so.
pub fn load_user_config(
    path: &Path,
    stage_names: &[&str],
    unknown: &mut Vec<String>,
) -> Result<ExecutorConfig> {
    Ok(read_user_config(path, stage_names, unknown)?.executor)
}

/// The `[remotes.NAME]` tables of a user config file (which win over the pipeline's of the
/// same name, as its `[executor]` does).
pub fn load_user_remotes(path: &Path) -> Result<BTreeMap<String, crate::remotes::RemoteSpec>> {
    Ok(read_user_config(path, &[], &mut Vec::new())?.remotes)
}

fn read_user_config(
    path: &Path,
    stage_names: &[&str],
    unknown: &mut Vec<String>,
) -> Result<UserConfig> {
    let source = std::fs::read_to_string(path).map_err(|source| Error::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let parsed: UserConfig = toml::from_str(&source).map_err(|e| {
        let location = e.span().map(|s| {
            let before = &source[..s.start.min(source.len())];
            Location {
                path: path.to_path_buf(),
                line: before.matches('\n').count() + 1,
                column: before.len() - before.rfind('\n').map(|i| i + 1).unwrap_or(0) + 1,
            }
        });
        Error::invalid(
            location,
            e.message().trim_end().to_string(),
            Some(
                "a user config holds only [executor], [executor.slurm] and [remotes.NAME] \
                 tables; see \"Running on a cluster\" and \"Share what you built: remotes\" in README.md"
                    .into(),
            ),
        )
    })?;
    let doc = toml_edit::Document::parse(source.clone()).map_err(|e| {
        Error::invalid(
            None,
            format!("{}: {}", path.display(), e.message().trim_end()),
            None,
        )
    })?;
    parsed.executor.validate(&[], &|keys| {
        crate::error::key_location(path, &source, &doc, keys)
    })?;
    unknown.extend(
        parsed
            .executor
            .slurm
            .stages
            .keys()
            .filter(|n| !stage_names.contains(&n.as_str()))
            .cloned(),
    );
    Ok(parsed)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> ExecutorConfig {
        toml::from_str::<UserConfig>(text).expect("parses").executor
    }

    #[test]
    fn user_values_override_the_pipeline_s_field_by_field() {
        let pipeline = parse(
            "[executor]\nkind = \"local\"\n[executor.slurm]\npartition = \"cpu\"\ntime = \"01:00:00\"\n\
             cpus_per_task = 4\nsbatch_args = [\"--qos=low\"]\n\
             [executor.slurm.stages.teacher]\ntime = \"10:00:00\"\n",
        );
        let user = parse(
            "[executor]\nkind = \"slurm\"\n[executor.slurm]\naccount = \"lab\"\ncpus_per_task = 8\n\
             sbatch_args = [\"--constraint=avx2\"]\n[executor.slurm.stages.teacher]\nmem = \"32G\"\n",
        );
        let c = pipeline.overlaid(&user);
        assert_eq!(c.kind, Some(ExecutorKind::Slurm));
        let teacher = c.resources("teacher");
        assert_eq!(
            teacher.sbatch_flags(),
            [
                "--partition=cpu",
                "--account=lab",
                "--time=10:00:00",
                "--mem=32G",
                "--cpus-per-task=8",
                "--qos=low",
                "--constraint=avx2"
            ]
        );
        assert_eq!(c.resources("d_r").time.as_deref(), Some("01:00:00"));
        assert_eq!(c.poll_secs(), DEFAULT_POLL_SECS);
    }

    #[test]
    fn bad_settings_are_refused_with_what_is_valid() {
        let bad = toml::from_str::<UserConfig>("[executor.slurm]\ncpus = 4\n")
            .err()
            .expect("unknown field");
        assert!(bad.message().contains("unknown field `cpus`"), "{bad}");
        let c = parse("[executor.slurm.stages.techer]\ntime = \"1:00:00\"\n");
        let e = c
            .validate(&["teacher", "d_r"], &|_| None)
            .expect_err("no such stage");
        assert!(
            e.to_string().contains("`techer`") && e.to_string().contains("teacher"),
            "{e}"
        );
        let c = parse("[executor.slurm]\nsbatch_args = [\"--array=0-3\"]\n");
        let e = c.validate(&[], &|_| None).expect_err("osms's own flag");
        assert!(e.to_string().contains("--array=0-3"), "{e}");
        let c = parse("[executor.slurm]\npoll_secs = 0\n");
        assert!(c.validate(&[], &|_| None).is_err());
        let e = "pbs".parse::<ExecutorKind>().expect_err("unknown executor");
        assert!(e.contains("local, slurm"), "{e}");
    }

    #[test]
    fn a_user_config_error_names_its_file_and_line() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("config.toml");
        std::fs::write(
            &path,
            "[executor.slurm]\npartition = \"cpu\"\nmemory = \"4G\"\n",
        )
        .expect("write");
        let e = load_user_config(&path, &[], &mut Vec::new()).expect_err("unknown field");
        let text = e.to_string();
        assert!(text.contains("config.toml:3:"), "{text}");
        assert!(text.contains("memory"), "{text}");
        std::fs::write(&path, "[executor.slurm]\npartition = \"cpu\"\n[executor.slurm.stages.nope]\ncpus_per_task = 2\n").expect("write");
        let mut unknown = Vec::new();
        load_user_config(&path, &["teacher"], &mut unknown).expect("other projects' stages");
        assert_eq!(unknown, ["nope"]);
        std::fs::write(&path, "[executor.slurm]\nsbatch_args = [\"-J\", \"x\"]\n").expect("write");
        let e = load_user_config(&path, &[], &mut Vec::new()).expect_err("-J");
        assert!(e.to_string().contains("config.toml:2:"), "{e}");
        for bad in [
            "-a0-3",
            "--clusters=x",
            "-M",
            "--cpus-per-task=4",
            "--chdir=/",
            "-W",
        ] {
            let c = parse(&format!("[executor.slurm]\nsbatch_args = [\"{bad}\"]\n"));
            assert!(c.validate(&[], &|_| None).is_err(), "{bad}");
        }
        let c = parse("[executor.slurm]\nsbatch_args = [\"--qos=low\", \"--constraint=avx2\"]\n");
        c.validate(&[], &|_| None).expect("ordinary flags");
        let c = parse("[executor.slurm]\npoll_secs = 1e300\n");
        assert!(c.validate(&[], &|_| None).is_err());
    }
}
