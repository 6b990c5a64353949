//! The policy stage kinds: `teacher` (PPO), `eval_teacher` (a frozen teacher on a condition
//! set), `teacher_table` (the Table I analog) and `collect` (the D_M / D_E / D_R datasets).

use std::collections::BTreeMap;
use std::fmt::Write;

use osms_core::rng::StreamRng;
use osms_core::{Artifact, NoParams};
use osms_make::{Ctx, ItemStage, Numerics, Scale, Slot, Stage, StageError, Summarize};
use osms_sim::World;
use osms_sim::artifacts::{Conditions, EvalRow, Evaluation, TableLine, WorldArtifact};
use osms_sim::conditions::sample;
use osms_sim::control::DrSpec;
use serde::{Deserialize, Serialize};

use crate::catch::{CatchTask, CatchTaskSpec, rollout};
use crate::dataset::{Dataset, DatasetItem, DatasetRole, DemoRollout, OswSpec, OswWindow};
use crate::ppo::{Agent, IterationStats, PpoConfig, Task, train};

/// What a kind that rolls out or trains networks depends on beyond its inputs: MuJoCo,
/// osms-sim's and osms-nn's numerics.
pub fn policy_numerics() -> Vec<Numerics> {
    let mut n = osms_sim::stages::numerics();
    n.push(Numerics {
        name: "osms-nn",
        version: osms_nn::NUMERICS_VERSION.to_string(),
    });
    n
}

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TeacherParams {
    /// The catching task: rollout settings, condition sampler, prior, reward weights.
    pub task: CatchTaskSpec,
    pub ppo: PpoConfig,
}

/// A trained teacher: the task it was trained on (needed to replay it) and the agent, whose
/// learning curve is kept with it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Teacher {
    pub task: CatchTaskSpec,
    pub agent: Agent,
}

impl Artifact for Teacher {
    const TYPE_TAG: &'static str = "policy.teacher";
    const SCHEMA_VERSION: u16 = 1;
}

/// Means of the curve's points over consecutive blocks of iterations.
fn curve_blocks(curve: &[IterationStats], rows: usize) -> Vec<(u32, u32, [f64; 5])> {
    let block = curve.len().div_ceil(rows.max(1)).max(1);
    curve
        .chunks(block)
        .map(|c| {
            let n = c.len() as f64;
            let mean = |f: &dyn Fn(&IterationStats) -> f64| c.iter().map(f).sum::<f64>() / n;
            let f_max: Vec<f64> = c.iter().filter_map(|s| s.mean_f_max_n).collect();
            (
                c[0].iteration,
                c[c.len() - 1].iteration,
                [
                    mean(&|s| s.mean_return),
                    mean(&|s| s.success_rate),
                    mean(&|s| s.completion_rate),
                    if f_max.is_empty() {
                        f64::NAN
                    } else {
                        f_max.iter().sum::<f64>() / f_max.len() as f64
                    },
                    mean(&|s| s.clip_fraction),
                ],
            )
        })
        .collect()
}

impl Summarize for Teacher {
    fn summary(&self) -> serde_json::Value {
        let curve = &self.agent.curve;
        let last = curve_blocks(curve, 10).pop();
        serde_json::json!({
            "iterations": curve.len(),
            "env_steps": curve.iter().map(|s| s.steps).sum::<u64>(),
            "episodes": curve.iter().map(|s| u64::from(s.episodes)).sum::<u64>(),
            "obs_len": self.agent.obs_norm.mean.len(),
            "act_len": self.agent.log_std.len(),
            "last_tenth": last.map(|(a, b, m)| serde_json::json!({
                "iterations": [a, b],
                "return": m[0],
                "success_rate": m[1],
                "completion_rate": m[2],
                "f_max_n": m[3].is_finite().then_some(m[3]),
            })),
            "note": "curve rates are under exploration noise; eval_teacher measures the deterministic policy",
        })
    }

    fn text(&self) -> Option<String> {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "Learning curve (means over blocks of iterations, under exploration noise):\n"
        );
        let _ = writeln!(
            out,
            "| iterations | return | success | completion | f_max (N) | clip fraction |"
        );
        let _ = writeln!(out, "|---|---:|---:|---:|---:|---:|");
        for (a, b, m) in curve_blocks(&self.agent.curve, 20) {
            let f = if m[3].is_finite() {
                format!("{:.1}", m[3])
            } else {
                "-".into()
            };
            let _ = writeln!(
                out,
                "| {a}–{b} | {:.2} | {:.1}% | {:.1}% | {f} | {:.3} |",
                m[0],
                100.0 * m[1],
                100.0 * m[2],
                m[4]
            );
        }
        Some(out)
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut csv = String::from(
            "iteration,episodes,steps,return,length,success_rate,completion_rate,f_max_n,policy_loss,value_loss,entropy,approx_kl,clip_fraction,action_std\n",
        );
        for s in &self.agent.curve {
            let _ = writeln!(
                csv,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                s.iteration,
                s.episodes,
                s.steps,
                s.mean_return,
                s.mean_length,
                s.success_rate,
                s.completion_rate,
                s.mean_f_max_n.map(|f| f.to_string()).unwrap_or_default(),
                s.policy_loss,
                s.value_loss,
                s.entropy,
                s.approx_kl,
                s.clip_fraction,
                s.action_std
            );
        }
        vec![("curve.csv".into(), csv.into_bytes())]
    }
}

/// PPO on the catching task; episode i of iteration t draws ω from stream ("train", t·E + i).
pub struct TeacherStage;
impl Stage for TeacherStage {
    const KIND: &'static str = "teacher";
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[Slot::one::<WorldArtifact>("world")];
    const DOC: &'static str =
        "the privileged PPO teacher: a residual on the scripted catcher, rewarded by paper 5.1";
    type Params = TeacherParams;
    type Output = Teacher;

    fn numerics() -> Vec<Numerics> {
        policy_numerics()
    }

    /// PPO's episodes (their rollouts dominate; the network's width is not counted).
    fn scale(params: &TeacherParams, _: &[(&str, f64)]) -> Scale {
        Scale {
            work: f64::from(params.ppo.iterations) * f64::from(params.ppo.episodes_per_iteration),
            size: 1.0,
        }
    }

    fn run(&self, ctx: &Ctx<'_, TeacherParams>) -> Result<Teacher, StageError> {
        let world = ctx.input::<WorldArtifact>("world")?.world()?;
        let seed = ctx.seed().unwrap_or_default();
        let p = ctx.params;
        if p.ppo.episodes_per_iteration == 0 || p.ppo.minibatch == 0 {
            return Err(
                "params.ppo: episodes_per_iteration and minibatch must be at least 1".into(),
            );
        }
        let task = CatchTask::new(&world, p.task.clone(), seed, ctx.stage(), "train")?;
        let mut agent = Agent::new(task.obs_len(), task.act_len(), &p.ppo, (seed, ctx.stage()));
        let progress = ctx.progress();
        progress.set_total(u64::from(p.ppo.iterations));
        train(&task, &mut agent, &p.ppo, (seed, ctx.stage()), &|_| {
            progress.inc(1)
        })?;
        Ok(Teacher {
            task: p.task.clone(),
            agent,
        })
    }
}

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalTeacherParams {
    /// Domain randomisation of the evaluation rollouts (a preset name or a table); absent:
    /// the teacher's training setting.
    pub dr: Option<DrSpec>,
}

/// A teacher's task with the rollouts' domain randomisation replaced when `dr` is given.
pub(crate) fn with_dr(task: &CatchTaskSpec, dr: &Option<DrSpec>) -> CatchTaskSpec {
    let mut task = task.clone();
    if let Some(dr) = dr {
        task.rollout.dr = dr.clone();
    }
    task
}

/// The frozen teacher (deterministic actions) on every condition of a set; rollout `i` draws
/// its domain randomisation from ("item", i).
pub struct EvalTeacherStage;
impl ItemStage for EvalTeacherStage {
    const KIND: &'static str = "eval_teacher";
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Conditions>("conditions"),
        Slot::one::<Teacher>("teacher"),
    ];
    const DOC: &'static str =
        "a frozen teacher evaluated on a condition set (table per family x size)";
    type Params = EvalTeacherParams;
    type Prepared = (World, Conditions, Teacher);
    type Item = EvalRow;
    type Output = Evaluation;

    fn numerics() -> Vec<Numerics> {
        policy_numerics()
    }
    fn prepare(&self, ctx: &Ctx<'_, EvalTeacherParams>) -> Result<Self::Prepared, StageError> {
        let mut teacher: Teacher = ctx.input("teacher")?;
        teacher.task = with_dr(&teacher.task, &ctx.params.dr);
        Ok((
            ctx.input::<WorldArtifact>("world")?.world()?,
            ctx.sharded("conditions")?,
            teacher,
        ))
    }
    fn n_items(&self, _: &Ctx<'_, EvalTeacherParams>, p: &Self::Prepared) -> usize {
        p.1.items.len()
    }
    fn run_item(
        &self,
        _: &Ctx<'_, EvalTeacherParams>,
        (world, conditions, teacher): &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<EvalRow, StageError> {
        Ok(EvalRow::of(rollout(
            world,
            &teacher.task,
            &teacher.agent,
            conditions.items[index].clone(),
            rng.clone(),
        )))
    }
    fn merge(
        &self,
        _: &Ctx<'_, EvalTeacherParams>,
        _: Self::Prepared,
        rows: Vec<EvalRow>,
    ) -> Result<Evaluation, StageError> {
        Ok(Evaluation { rows })
    }
}

/// One row of the Table I analog.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TeacherTableRow {
    pub policy: String,
    pub rollouts: usize,
    pub completion_rate: f64,
    pub success_rate: f64,
    /// Means over catch completions, as in the paper.
    pub contact_speed_mps: Option<f64>,
    pub max_force_n: Option<f64>,
    pub follow_through_m: Option<f64>,
}

/// Table I analog: the scripted prior, the catching-only teacher and the teacher on the same
/// held-out conditions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TeacherTable {
    pub rows: Vec<TeacherTableRow>,
}

impl Artifact for TeacherTable {
    const TYPE_TAG: &'static str = "policy.teacher_table";
    const SCHEMA_VERSION: u16 = 1;
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map(|x| format!("{x:.digits$}"))
        .unwrap_or_else(|| "-".into())
}

impl TeacherTable {
    pub fn markdown(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "| policy | n | catch completion | task success | v_rel (m/s) | f_max (N) | l_max (m) |"
        );
        let _ = writeln!(out, "|---|---:|---:|---:|---:|---:|---:|");
        for r in &self.rows {
            let _ = writeln!(
                out,
                "| {} | {} | {:.1}% | {:.1}% | {} | {} | {} |",
                r.policy,
                r.rollouts,
                100.0 * r.completion_rate,
                100.0 * r.success_rate,
                opt(r.contact_speed_mps, 2),
                opt(r.max_force_n, 1),
                opt(r.follow_through_m, 3)
            );
        }
        let _ = writeln!(
            out,
            "\nImpact metrics are means over catch completions. Paper (Table I): catching-only \
             92.5% / 0.4% / 160 N; teacher 90.7% / 85.2% / 40.8 N."
        );
        out
    }

    pub fn csv(&self) -> String {
        let mut out = String::from(
            "policy,rollouts,completion_rate,success_rate,contact_speed_mps,max_force_n,follow_through_m\n",
        );
        let o = |v: Option<f64>| v.map(|x| x.to_string()).unwrap_or_default();
        for r in &self.rows {
            let _ = writeln!(
                out,
                "{},{},{},{},{},{},{}",
                r.policy,
                r.rollouts,
                r.completion_rate,
                r.success_rate,
                o(r.contact_speed_mps),
                o(r.max_force_n),
                o(r.follow_through_m)
            );
        }
        out
    }
}

impl Summarize for TeacherTable {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(&self.rows).unwrap_or_default()
    }
    fn text(&self) -> Option<String> {
        Some(self.markdown())
    }
    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let json = serde_json::to_string_pretty(&self.rows).unwrap_or_default() + "\n";
        vec![
            ("table1.md".into(), self.markdown().into_bytes()),
            ("table1.csv".into(), self.csv().into_bytes()),
            ("table1.json".into(), json.into_bytes()),
        ]
    }
}

fn row(policy: &str, eval: &Evaluation) -> TeacherTableRow {
    let all: Option<TableLine> = eval.table().pop();
    TeacherTableRow {
        policy: policy.to_string(),
        rollouts: eval.rows.len(),
        completion_rate: all.as_ref().map_or(0.0, |l| l.completion_rate),
        success_rate: all.as_ref().map_or(0.0, |l| l.success_rate),
        contact_speed_mps: all.as_ref().and_then(|l| l.contact_speed_mps),
        max_force_n: all.as_ref().and_then(|l| l.max_force_n),
        follow_through_m: all.as_ref().and_then(|l| l.follow_through_m),
    }
}

pub struct TeacherTableStage;
impl Stage for TeacherTableStage {
    const KIND: &'static str = "teacher_table";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Evaluation>("scripted"),
        Slot::one::<Evaluation>("catch_only"),
        Slot::one::<Evaluation>("teacher"),
    ];
    const DOC: &'static str =
        "Table I analog: scripted prior, catching-only teacher and teacher on held-out conditions";
    type Params = NoParams;
    type Output = TeacherTable;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<TeacherTable, StageError> {
        let scripted: Evaluation = ctx.sharded("scripted")?;
        let catch_only: Evaluation = ctx.sharded("catch_only")?;
        let teacher: Evaluation = ctx.sharded("teacher")?;
        Ok(TeacherTable {
            rows: vec![
                row("scripted prior", &scripted),
                row("catching-only teacher", &catch_only),
                row("teacher", &teacher),
            ],
        })
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollectParams {
    /// How many rollouts the dataset keeps.
    pub n: u32,
    /// Keep only successes (D_M, D_E): each item retries fresh conditions until one succeeds.
    #[serde(default)]
    pub successes_only: bool,
    /// The dataset's role in the method (`d_m`, `d_e`, `d_r`): stages that take a dataset
    /// accept only the roles they are meant for, checked before anything runs.
    #[serde(default)]
    pub role: Option<DatasetRole>,
    /// Attempts an item may take before the stage gives up on a teacher that rarely succeeds.
    #[serde(default = "default_max_attempts")]
    pub max_attempts: u32,
    #[serde(default)]
    pub osw: OswSpec,
    /// Domain randomisation of the collected rollouts (a preset name or a table); absent: the
    /// teacher's training setting. Each rollout's draws are recorded with it and enter ω̄.
    #[serde(default)]
    pub dr: Option<DrSpec>,
}

fn default_max_attempts() -> u32 {
    100
}

/// Teacher rollouts. Item `i` draws its conditions in turn from stream ("item", i) and the
/// domain randomisation of attempt `a` from ("attempt", i · max_attempts + a). Different
/// stages draw from different streams, so datasets never share a condition draw.
pub struct CollectStage;
impl ItemStage for CollectStage {
    const KIND: &'static str = "collect";
    /// 3: ω̄ carries the arm's servo targets; 4: the DR stream and the task spec are kept.
    const CODE_VERSION: u32 = 4;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Teacher>("teacher"),
    ];
    const DOC: &'static str =
        "teacher rollouts with OSW alignment (D_M / D_E: successes only; D_R: mixed)";
    type Params = CollectParams;
    type Prepared = (World, Teacher);
    type Item = DatasetItem;
    type Output = Dataset;

    fn numerics() -> Vec<Numerics> {
        policy_numerics()
    }

    /// `n` rollouts.
    fn scale(params: &CollectParams, _: &[(&str, f64)]) -> Scale {
        Scale::items(params.n as f64)
    }
    fn output_role(params: &CollectParams) -> Option<&'static str> {
        params.role.map(DatasetRole::name)
    }
    fn prepare(&self, ctx: &Ctx<'_, CollectParams>) -> Result<Self::Prepared, StageError> {
        if let Some(role) = ctx.params.role
            && role.successes_only() != ctx.params.successes_only
        {
            return Err(format!(
                "params: a `{}` dataset has successes_only = {}\nhint: set successes_only = {} or change the role",
                role.name(),
                role.successes_only(),
                role.successes_only()
            )
            .into());
        }
        if ctx.params.max_attempts == 0 {
            return Err("params.max_attempts must be at least 1".into());
        }
        if ctx.params.osw.h_os == 0 {
            return Err("params.osw.h_os must be at least 1".into());
        }
        let mut teacher: Teacher = ctx.input("teacher")?;
        teacher.task = with_dr(&teacher.task, &ctx.params.dr);
        // The OSW conditioning ω̄ needs the privileged state at the window's start.
        teacher.task.rollout.record_privileged = true;
        Ok((ctx.input::<WorldArtifact>("world")?.world()?, teacher))
    }
    fn n_items(&self, ctx: &Ctx<'_, CollectParams>, _: &Self::Prepared) -> usize {
        ctx.params.n as usize
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, CollectParams>,
        (world, teacher): &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<DatasetItem, StageError> {
        let p = ctx.params;
        let mut discarded_failures: BTreeMap<String, u32> = BTreeMap::new();
        for attempt in 0..p.max_attempts {
            let condition = sample(&teacher.task.conditions, world.home_palm_pos, rng)?;
            let dr_stream = ctx.stream_id(
                "attempt",
                index as u64 * u64::from(p.max_attempts) + u64::from(attempt),
            );
            let record = rollout(
                world,
                &teacher.task,
                &teacher.agent,
                condition,
                dr_stream.rng(),
            );
            if p.successes_only && !record.outcome.success() {
                for f in &record.outcome.failures {
                    *discarded_failures.entry(f.name().to_string()).or_default() += 1;
                }
                continue;
            }
            let osw = OswWindow::extract(&record, &p.osw)?;
            return Ok(DatasetItem {
                rollout: DemoRollout {
                    item: index as u32,
                    attempt,
                    dr_stream,
                    record,
                    osw,
                },
                attempts: attempt + 1,
                discarded_failures,
            });
        }
        Err(format!(
            "item {index}: the teacher failed {} attempts in a row\nhint: raise params.max_attempts, or train the teacher longer (its success rate is too low for a successes-only dataset)",
            p.max_attempts
        )
        .into())
    }
    fn merge(
        &self,
        ctx: &Ctx<'_, CollectParams>,
        (_, teacher): Self::Prepared,
        items: Vec<DatasetItem>,
    ) -> Result<Dataset, StageError> {
        Ok(Dataset {
            successes_only: ctx.params.successes_only,
            osw: ctx.params.osw.clone(),
            task: teacher.task,
            items,
        })
    }
}

/// One rollout's outcome-sensitive window and conditioning, without the rest of its record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OswSample {
    /// Which draw of the dataset's condition stream the rollout came from: (item, attempt).
    pub item: u32,
    pub attempt: u32,
    pub variant: String,
    pub success: bool,
    /// Whether the window has all H_OS steps.
    pub complete: bool,
    /// ζ_org, step-major (`[step][arm channel]`).
    pub zeta_org: Vec<f32>,
    /// ω̄: ω's features, the DR draws and the privileged state at the window's start.
    pub omega_bar: Vec<f32>,
}

/// The OSW windows of a dataset: what the manifold and the candidate search read, a small
/// fraction of the dataset's bytes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OswSet {
    pub osw: OswSpec,
    pub windows: Vec<OswSample>,
}

impl Artifact for OswSet {
    const TYPE_TAG: &'static str = "policy.osw_set";
    /// 2: ω̄ ends with the arm's servo targets.
    const SCHEMA_VERSION: u16 = 2;
}

impl Summarize for OswSet {
    fn summary(&self) -> serde_json::Value {
        serde_json::json!({
            "windows": self.windows.len(),
            "complete": self.windows.iter().filter(|w| w.complete).count(),
            "successes": self.windows.iter().filter(|w| w.success).count(),
            "h_os": self.osw.h_os,
            "omega_bar_len": self.windows.first().map_or(0, |w| w.omega_bar.len()),
        })
    }
}

/// A projection: streams a dataset shard by shard and keeps each rollout's OSW window and
/// ω̄, so later stages never decode full records.
pub struct OswWindowsStage;
impl Stage for OswWindowsStage {
    const KIND: &'static str = "osw_windows";
    /// 2: ω̄ carries the arm's servo targets.
    const CODE_VERSION: u32 = 2;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Dataset>("data")];
    const DOC: &'static str = "the OSW windows ζ_org and conditioning ω̄ of a dataset (projection)";
    type Params = NoParams;
    type Output = OswSet;

    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<OswSet, StageError> {
        let head: Dataset = ctx.head("data")?;
        let mut windows = Vec::new();
        for item in ctx.items::<Dataset>("data")? {
            let r = item?.rollout;
            windows.push(OswSample {
                item: r.item,
                attempt: r.attempt,
                variant: r.record.condition.variant.to_string(),
                success: r.record.outcome.success(),
                complete: r.osw.complete,
                zeta_org: r.osw.zeta_org,
                omega_bar: r.osw.omega_bar,
            });
        }
        Ok(OswSet {
            osw: head.osw,
            windows,
        })
    }
}

/// Registers the policy stage kinds.
pub fn register(registry: &mut osms_make::Registry) {
    registry
        .register(TeacherStage)
        .register_itemised(EvalTeacherStage)
        .register(TeacherTableStage)
        .register_itemised(CollectStage)
        .register(OswWindowsStage);
    crate::student_stages::register(registry);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table1_files_agree_with_the_rows() {
        let table = TeacherTable {
            rows: vec![
                TeacherTableRow {
                    policy: "teacher".into(),
                    rollouts: 40,
                    completion_rate: 0.7,
                    success_rate: 0.475,
                    contact_speed_mps: Some(3.9),
                    max_force_n: Some(33.72),
                    follow_through_m: Some(0.215),
                },
                TeacherTableRow {
                    policy: "nothing caught".into(),
                    rollouts: 3,
                    completion_rate: 0.0,
                    success_rate: 0.0,
                    contact_speed_mps: None,
                    max_force_n: None,
                    follow_through_m: None,
                },
            ],
        };
        let files: BTreeMap<String, Vec<u8>> = table.files().into_iter().collect();
        let names: Vec<&str> = files.keys().map(String::as_str).collect();
        assert_eq!(names, ["table1.csv", "table1.json", "table1.md"]);
        let md = String::from_utf8_lossy(&files["table1.md"]).to_string();
        assert!(
            md.contains("| teacher | 40 | 70.0% | 47.5% | 3.90 | 33.7 | 0.215 |"),
            "{md}"
        );
        assert!(
            md.contains("| nothing caught | 3 | 0.0% | 0.0% | - | - | - |"),
            "{md}"
        );
        let csv = String::from_utf8_lossy(&files["table1.csv"]).to_string();
        assert_eq!(
            csv.lines().nth(1),
            Some("teacher,40,0.7,0.475,3.9,33.72,0.215")
        );
        assert_eq!(csv.lines().nth(2), Some("nothing caught,3,0,0,,,"));
        let back: Vec<TeacherTableRow> =
            serde_json::from_slice(&files["table1.json"]).expect("json");
        assert_eq!(back, table.rows);
    }
}
