//! Talking to Slurm: `sbatch` to submit, `squeue` to see what is queued or running, `sacct`
//! (where accounting is on) to say how a finished job ended. Behind a trait so the driver's
//! bookkeeping can be unit-tested without a cluster; `scripts/slurm-test` runs it for real.

use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};

use crate::error::{Error, Result};

/// One job to submit.
#[derive(Debug, Clone, PartialEq)]
pub struct JobRequest {
    /// `--job-name`.
    pub name: String,
    /// Resource flags (`--partition=...`, `--cpus-per-task=...`, ...).
    pub flags: Vec<String>,
    /// `--array=` with these task indices.
    pub array: Option<Vec<u32>>,
    /// `--dependency=afterok:ID --kill-on-invalid-dep=yes`.
    pub after_ok: Option<u64>,
    /// `--output` and `--error` (Slurm's `%A`, `%a`, `%j` patterns allowed).
    pub log: PathBuf,
    /// `--chdir`.
    pub workdir: PathBuf,
    /// The batch script, passed on stdin.
    pub script: String,
}

/// A job, or one task of an array job, that Slurm still holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Queued {
    /// The job id, or the array's job id for an array task.
    pub job: u64,
    /// The array task index.
    pub task: Option<u32>,
    /// `PENDING`, `RUNNING`, `COMPLETING`, ...
    pub state: String,
    /// Why it waits (`Dependency`, `Resources`, `DependencyNeverSatisfied`, ...) or `None`.
    pub reason: String,
    /// The job id of this very task (`%A`, `SLURM_JOB_ID` inside it): an array task gets its
    /// own once it starts.
    pub id: u64,
}

impl Queued {
    /// How Slurm names the task in logs and `scancel`: `JOB` or `JOB_TASK`.
    pub fn task_name(&self) -> String {
        match self.task {
            Some(t) => format!("{}_{t}", self.job),
            None => self.job.to_string(),
        }
    }
}

/// How a finished job or task ended, from `sacct`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ended {
    pub job: u64,
    pub task: Option<u32>,
    /// `COMPLETED`, `FAILED`, `CANCELLED`, `TIMEOUT`, `OUT_OF_MEMORY`, `PREEMPTED`, ...
    pub state: String,
    pub exit_code: String,
}

pub trait Scheduler {
    /// Submits a job; returns its id.
    fn submit(&self, job: &JobRequest) -> Result<u64>;
    /// Every job of this user that Slurm still holds, array tasks one by one.
    fn queue_all(&self) -> Result<Vec<Queued>>;
    /// The jobs among `ids` (job or array ids) that Slurm still holds.
    fn queue(&self, ids: &[u64]) -> Result<Vec<Queued>> {
        if ids.is_empty() {
            return Ok(Vec::new());
        }
        Ok(self
            .queue_all()?
            .into_iter()
            .filter(|q| ids.contains(&q.job))
            .collect())
    }
    /// How jobs among `ids` ended, if the cluster keeps accounting (`None` if it does not).
    fn ended(&self, ids: &[u64]) -> Option<Vec<Ended>>;
    fn cancel(&self, ids: &[u64]) -> Result<()>;
}

/// The Slurm command-line tools on `PATH` (they read `SLURM_CONF` like any Slurm client).
pub struct SlurmCli;

fn run(cmd: &mut Command, stdin: Option<&str>) -> Result<String> {
    let program = cmd.get_program().to_string_lossy().into_owned();
    let mut child = cmd
        .stdin(if stdin.is_some() {
            Stdio::piped()
        } else {
            Stdio::null()
        })
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| {
            Error::usage(format!(
                "cannot run `{program}`: {e}; hint: --executor slurm needs the Slurm client \
                 commands (sbatch, squeue) on PATH, on a host that can submit jobs"
            ))
        })?;
    if let Some(text) = stdin
        && let Some(mut pipe) = child.stdin.take()
    {
        pipe.write_all(text.as_bytes())
            .map_err(|e| Error::usage(format!("cannot write the script to `{program}`: {e}")))?;
    }
    let out = child
        .wait_with_output()
        .map_err(|e| Error::usage(format!("`{program}` did not finish: {e}")))?;
    if !out.status.success() {
        return Err(Error::usage(format!(
            "`{program}` failed ({}): {}",
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// The sbatch arguments of a request (the script goes on stdin).
pub fn sbatch_args(job: &JobRequest) -> Vec<String> {
    let mut args = vec![
        "--parsable".to_string(),
        format!("--job-name={}", job.name),
        format!("--output={}", job.log.display()),
        format!("--error={}", job.log.display()),
        format!("--chdir={}", job.workdir.display()),
    ];
    if let Some(tasks) = &job.array {
        args.push(format!("--array={}", array_spec(tasks)));
    }
    if let Some(id) = job.after_ok {
        args.push(format!("--dependency=afterok:{id}"));
        args.push("--kill-on-invalid-dep=yes".to_string());
    }
    args.extend(job.flags.iter().cloned());
    args
}

/// `0-3,5,7-8`: Slurm's array syntax for sorted indices.
pub fn array_spec(tasks: &[u32]) -> String {
    let mut parts = Vec::new();
    let mut i = 0;
    while i < tasks.len() {
        let start = tasks[i];
        let mut end = start;
        while i + 1 < tasks.len() && tasks[i + 1] == end + 1 {
            i += 1;
            end = tasks[i];
        }
        parts.push(if start == end {
            start.to_string()
        } else {
            format!("{start}-{end}")
        });
        i += 1;
    }
    parts.join(",")
}

/// The job id `sbatch --parsable` prints (`ID` or `ID;CLUSTER`).
pub fn parse_sbatch(out: &str) -> Result<u64> {
    let line = out
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty())
        .unwrap_or("");
    line.split(';')
        .next()
        .and_then(|id| id.parse().ok())
        .ok_or_else(|| Error::usage(format!("sbatch printed `{}`, not a job id", out.trim())))
}

/// Lines of `squeue -h -r -o '%F|%K|%T|%r|%A'`: array job id (the job id for other jobs), array
/// task index (`N/A` for other jobs), state, reason, the task's own job id.
pub fn parse_squeue(out: &str) -> Vec<Queued> {
    out.lines()
        .filter_map(|line| {
            let mut f = line.trim().split('|');
            let job = f.next()?.trim().parse().ok()?;
            let task = f.next()?.trim().parse().ok();
            let state = f.next()?.trim().to_string();
            let reason = f.next().unwrap_or("").trim().to_string();
            let id = f.next().and_then(|i| i.trim().parse().ok()).unwrap_or(job);
            Some(Queued {
                job,
                task,
                state,
                reason,
                id,
            })
        })
        .collect()
}

/// Lines of `sacct -n -P -X -o JobID,State,ExitCode`: `123`, `123_4`; states like
/// `CANCELLED by 0` keep their first word.
pub fn parse_sacct(out: &str) -> Vec<Ended> {
    out.lines()
        .filter_map(|line| {
            let mut f = line.trim().split('|');
            let id = f.next()?.trim();
            let (job, task) = match id.split_once('_') {
                Some((j, t)) => (j.parse().ok()?, Some(t.parse().ok()?)),
                None => (id.parse().ok()?, None),
            };
            let state = f.next()?.split_whitespace().next()?.to_string();
            let exit_code = f.next().unwrap_or("").trim().to_string();
            Some(Ended {
                job,
                task,
                state,
                exit_code,
            })
        })
        .collect()
}

fn id_list(ids: &[u64]) -> String {
    ids.iter().map(u64::to_string).collect::<Vec<_>>().join(",")
}

impl Scheduler for SlurmCli {
    fn submit(&self, job: &JobRequest) -> Result<u64> {
        let out = run(
            Command::new("sbatch").args(sbatch_args(job)),
            Some(&job.script),
        )?;
        parse_sbatch(&out)
    }

    fn queue_all(&self) -> Result<Vec<Queued>> {
        // All of this user's jobs, filtered by the caller: `squeue -j` fails outright once every
        // listed job has left the controller's memory. `-r` gives pending array tasks a line
        // each. A busy controller times out now and then: three tries.
        let mut last = None;
        for attempt in 0..3u32 {
            if attempt > 0 {
                std::thread::sleep(std::time::Duration::from_secs(5 * u64::from(attempt)));
            }
            match run(
                Command::new("squeue").args(["-h", "-r", "--me", "-o", "%F|%K|%T|%r|%A"]),
                None,
            ) {
                Ok(out) => return Ok(parse_squeue(&out)),
                Err(e) => last = Some(e),
            }
        }
        Err(last.expect("at least one attempt"))
    }

    fn ended(&self, ids: &[u64]) -> Option<Vec<Ended>> {
        if ids.is_empty() {
            return Some(Vec::new());
        }
        let out = run(
            Command::new("sacct").args([
                "-n",
                "-P",
                "-X",
                "-o",
                "JobID,State,ExitCode",
                "-j",
                &id_list(ids),
            ]),
            None,
        )
        .ok()?;
        Some(parse_sacct(&out))
    }

    fn cancel(&self, ids: &[u64]) -> Result<()> {
        if ids.is_empty() {
            return Ok(());
        }
        run(
            Command::new("scancel").args(ids.iter().map(u64::to_string)),
            None,
        )
        .map(drop)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn array_specs_compress_runs() {
        assert_eq!(array_spec(&[0, 1, 2, 3]), "0-3");
        assert_eq!(array_spec(&[1, 3]), "1,3");
        assert_eq!(array_spec(&[0, 2, 3, 4, 7]), "0,2-4,7");
        assert_eq!(array_spec(&[5]), "5");
    }

    #[test]
    fn sbatch_output_and_errors() {
        assert_eq!(parse_sbatch("812\n").expect("id"), 812);
        assert_eq!(parse_sbatch("812;osms-test\n").expect("id"), 812);
        assert!(parse_sbatch("sbatch: error: oops").is_err());
    }

    #[test]
    fn squeue_lines_of_arrays_and_plain_jobs() {
        let out = "12|0|RUNNING|None|15\n12|1|PENDING|Resources|12\n13|N/A|PENDING|Dependency|13\n";
        let q = parse_squeue(out);
        assert_eq!(q.len(), 3);
        assert_eq!(q[0].task_name(), "12_0");
        assert_eq!(q[0].id, 15);
        assert_eq!(q[1].reason, "Resources");
        assert_eq!(q[2].task, None);
        assert_eq!(q[2].task_name(), "13");
    }

    #[test]
    fn sacct_lines() {
        let e = parse_sacct("12_1|FAILED|1:0\n13|CANCELLED by 0|0:15\n");
        assert_eq!(e[0].task, Some(1));
        assert_eq!(e[0].state, "FAILED");
        assert_eq!(e[1].state, "CANCELLED");
        assert_eq!(e[1].exit_code, "0:15");
    }

    #[test]
    fn a_merge_waits_for_its_array_and_dies_with_it() {
        let args = sbatch_args(&JobRequest {
            name: "osms-d_r".into(),
            flags: vec!["--cpus-per-task=2".into()],
            array: None,
            after_ok: Some(41),
            log: "/s/state/slurm/logs/osms-d_r-%j.log".into(),
            workdir: "/p".into(),
            script: String::new(),
        });
        assert!(args.contains(&"--dependency=afterok:41".to_string()));
        assert!(args.contains(&"--kill-on-invalid-dep=yes".to_string()));
        assert_eq!(args.last().map(String::as_str), Some("--cpus-per-task=2"));
    }
}
