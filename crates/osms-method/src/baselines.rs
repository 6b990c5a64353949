//! The Naive and Normal baselines (paper 6, "Baselines"), each extended to D_*'s number of
//! demonstrations as the paper does, from condition streams of their own:
//!
//! - `naive`: success-only filtering of D_R, extended with further successful teacher
//!   rollouts;
//! - `normal`: unperturbed-only validation of the same candidate sets (the lowest-J candidate
//!   that succeeds unperturbed and, refining, beats J_org), extended with further mixed teacher
//!   rollouts put through the same construction (window, geodesic search, unperturbed
//!   validation).
//!
//! Extension item j of a baseline stage draws its condition from the stage's stream
//! ("item", n_R + j) and its domain randomisation from ("attempt", …): stage names differ, so
//! no extension shares a condition draw with D_M, D_E, D_R, the held-out set or the other
//! baseline.

use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Numerics, Slot, StageError};
use osms_policy::artifacts::Teacher;
use osms_policy::artifacts::{Dataset, DemoRollout};
use osms_policy::artifacts::{DemoGroup, DemoSet, Execution, Origin};
use osms_policy::catch::rollout;
use osms_policy::osw::OswWindow;
use osms_policy::stages::numerics as policy_numerics;
use osms_sim::artifacts::WorldArtifact;
use osms_sim::conditions::sample;
use serde::{Deserialize, Serialize};

use crate::candidates::{Candidate, SearchParams, candidate_set};
use crate::cvae::Cvae;
use crate::error_stages::ErrorModelArtifact;
use crate::intervene::{Snippet, execute};
use crate::stages::CandidateSets;
use crate::validate::{
    CandidateReport, Construction, Cost, ValidateParams, select_unperturbed, unperturbed_reports,
};
use crate::validate_stages::{Inputs, Validation, entry};

/// Settings of both baselines. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BaselineParams {
    /// Extend to the `target` set's number of demonstrations (false: D_R only).
    pub extend: bool,
    /// Attempts an extension item of `naive` may take to find a teacher success.
    pub max_attempts: u32,
    /// `normal` runs this many times the extension conditions its D_R yield predicts, and
    /// keeps the first ones that reach the target.
    pub margin: f64,
}

impl Default for BaselineParams {
    fn default() -> Self {
        BaselineParams {
            extend: true,
            max_attempts: 100,
            margin: 1.15,
        }
    }
}

impl BaselineParams {
    /// `has_target`: whether the `target` input is wired.
    fn check(&self, has_target: bool) -> Result<(), String> {
        if self.extend && !has_target {
            return Err("`extend = true` needs the `target` input (D_*)\nhint: wire `target = \"dstar\"` or set params.extend = false".into());
        }
        if self.max_attempts == 0 {
            return Err("params.max_attempts must be at least 1".into());
        }
        if !(self.margin >= 1.0 && self.margin <= 10.0) {
            return Err(format!(
                "params.margin = {} must be within [1, 10]",
                self.margin
            ));
        }
        Ok(())
    }
}

/// How many demonstrations the extension has to add.
fn deficit(
    ctx: &Ctx<'_, BaselineParams>,
    base: usize,
) -> Result<(Option<usize>, usize), StageError> {
    if !ctx.params.extend {
        return Ok((None, 0));
    }
    let n = ctx.sharded::<DemoSet>("target")?.len();
    Ok((Some(n), n.saturating_sub(base)))
}

/// How many leading groups reach `target` demonstrations: every D_R group, then extension
/// groups up to the first one that reaches it.
fn used(groups: &[DemoGroup], target: Option<usize>) -> Option<usize> {
    let target = target?;
    let mut count = 0;
    for (i, g) in groups.iter().enumerate() {
        if g.extension && count >= target {
            return Some(i);
        }
        count += g.demos.len();
    }
    Some(groups.len())
}

/// The Naive set: D_R's successes, then successful teacher rollouts on the stage's own
/// conditions until D_*'s count.
pub struct NaiveStage;
impl ItemStage for NaiveStage {
    const KIND: &'static str = "naive";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Teacher>("teacher"),
        Slot::one::<Dataset>("data").roles(&["d_r"]),
        Slot::one::<DemoSet>("target").optional(),
    ];
    const DOC: &'static str = "the Naive baseline: success-only filtering of D_R, extended with successful teacher rollouts to the target set's size";
    type Params = BaselineParams;
    type Prepared = (osms_sim::World, Teacher, Dataset, Option<usize>, usize);
    type Item = DemoGroup;
    type Output = DemoSet;

    fn numerics() -> Vec<Numerics> {
        policy_numerics()
    }
    fn prepare(&self, ctx: &Ctx<'_, BaselineParams>) -> Result<Self::Prepared, StageError> {
        ctx.params.check(ctx.has_input("target"))?;
        let data: Dataset = ctx.sharded("data")?;
        let base = data
            .rollouts()
            .filter(|r| r.record.outcome.success())
            .count();
        let (target, extra) = deficit(ctx, base)?;
        let mut teacher: Teacher = ctx.input("teacher")?;
        teacher.task = data.task.clone();
        teacher.task.rollout.record_privileged = false;
        Ok((
            ctx.input::<WorldArtifact>("world")?.world()?,
            teacher,
            data,
            target,
            extra,
        ))
    }
    fn n_items(&self, _: &Ctx<'_, BaselineParams>, p: &Self::Prepared) -> usize {
        p.2.items.len() + p.4
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, BaselineParams>,
        (world, teacher, data, _, _): &Self::Prepared,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<DemoGroup, StageError> {
        if let Some(item) = data.items.get(index) {
            let r = &item.rollout;
            let success = r.record.outcome.success();
            return Ok(DemoGroup {
                extension: false,
                item: r.item,
                attempt: r.attempt,
                condition: r.record.condition.clone(),
                original_success: success,
                origin: if success {
                    Origin::Kept
                } else {
                    Origin::Dropped
                },
                demos: if success {
                    vec![entry(
                        Execution::Original,
                        &r.record,
                        r.record.intended.clone(),
                    )]
                } else {
                    Vec::new()
                },
            });
        }
        let p = ctx.params;
        for attempt in 0..p.max_attempts {
            let condition = sample(&teacher.task.conditions, world.home_palm_pos, rng)?;
            let dr = ctx.rng(
                "attempt",
                index as u64 * u64::from(p.max_attempts) + u64::from(attempt),
            );
            let record = rollout(world, &teacher.task, &teacher.agent, condition, dr);
            if record.outcome.success() {
                return Ok(DemoGroup {
                    extension: true,
                    item: index as u32,
                    attempt,
                    condition: record.condition.clone(),
                    original_success: true,
                    origin: Origin::Kept,
                    demos: vec![entry(Execution::Original, &record, record.intended.clone())],
                });
            }
        }
        Err(format!(
            "extension item {index}: the teacher failed {} attempts in a row\nhint: raise params.max_attempts",
            p.max_attempts
        )
        .into())
    }
    fn merge(
        &self,
        _: &Ctx<'_, BaselineParams>,
        (.., target, _): Self::Prepared,
        groups: Vec<DemoGroup>,
    ) -> Result<DemoSet, StageError> {
        Ok(DemoSet {
            construction: "naive".into(),
            target,
            used: used(&groups, target),
            groups,
        })
    }
}

/// What `normal` reads.
pub struct NormalInputs {
    inputs: Inputs,
    validation: Validation,
    manifold: Cvae,
    search: SearchParams,
    /// The task with privileged frames recorded (the extension's windows need ω̄).
    collect_task: osms_policy::catch::CatchTaskSpec,
    target: Option<usize>,
    extension: usize,
}

/// One condition through unperturbed-only validation: the selected candidate's unperturbed
/// rollout, the kept original, or nothing.
fn normal_group(
    inputs: &Inputs,
    p: &ValidateParams,
    rollout: &DemoRollout,
    candidates: &[Candidate],
    reports: &[CandidateReport],
    extension: bool,
) -> Result<DemoGroup, String> {
    let success = rollout.record.outcome.success();
    let j_org = p.j_org(success, rollout.record.metrics.max_force_n);
    let mut group = DemoGroup {
        extension,
        item: rollout.item,
        attempt: rollout.attempt,
        condition: rollout.record.condition.clone(),
        original_success: success,
        origin: Origin::Dropped,
        demos: Vec::new(),
    };
    match select_unperturbed(j_org, reports) {
        Some(k) => {
            let e = execute(
                &inputs.world,
                &inputs.task,
                &inputs.agent,
                rollout.record.condition.clone(),
                rollout.dr_stream.rng(),
                Some(Snippet {
                    start: rollout.osw.start,
                    zeta: &candidates[k].zeta,
                }),
                None,
            );
            if !e.record.outcome.success() {
                return Err(format!(
                    "condition {} ({}): the selected candidate's unperturbed rollout does not repeat its validation",
                    rollout.item,
                    if extension { "extension" } else { "D_R" }
                ));
            }
            group.origin = if success {
                Origin::Refined
            } else {
                Origin::Repaired
            };
            group
                .demos
                .push(entry(Execution::Unperturbed, &e.record, e.commanded));
        }
        None if success => {
            group.origin = Origin::Kept;
            group.demos.push(entry(
                Execution::Original,
                &rollout.record,
                rollout.record.intended.clone(),
            ));
        }
        None => {}
    }
    Ok(group)
}

/// The Normal set: unperturbed-only validation of D_R's candidate sets (read from the
/// validation, whose unperturbed outcomes are exactly these), extended with mixed teacher
/// rollouts on the stage's own conditions put through the same construction.
pub struct NormalStage;
impl ItemStage for NormalStage {
    const KIND: &'static str = "normal";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Teacher>("teacher"),
        Slot::one::<Dataset>("data").roles(&["d_r"]),
        Slot::one::<CandidateSets>("candidates"),
        Slot::one::<ErrorModelArtifact>("error_model"),
        Slot::one::<Validation>("validation"),
        Slot::one::<Cvae>("manifold"),
        Slot::one::<DemoSet>("target").optional(),
    ];
    const DOC: &'static str = "the Normal baseline: unperturbed-only validation of the same candidate sets, extended with mixed teacher rollouts through the same construction";
    type Params = BaselineParams;
    type Prepared = NormalInputs;
    type Item = DemoGroup;
    type Output = DemoSet;

    fn numerics() -> Vec<Numerics> {
        policy_numerics()
    }
    fn prepare(&self, ctx: &Ctx<'_, BaselineParams>) -> Result<NormalInputs, StageError> {
        ctx.params.check(ctx.has_input("target"))?;
        let validation: Validation = ctx.sharded("validation")?;
        if validation.params.construction != Construction::Both {
            return Err(format!(
                "input `validation` ran `{}`; the Normal baseline reads a validation that refines and repairs",
                validation.params.construction.name()
            )
            .into());
        }
        let inputs = Inputs::load(ctx, &validation.params)?;
        inputs.check_validation(&validation)?;
        let candidates: CandidateSets = ctx.head("candidates")?;
        // The extension searches the way the geodesic stage does; the ablation generators are
        // matched to a geodesic reference the extension's conditions do not have.
        if candidates.params.generator != crate::candidates::Generator::Geodesic {
            return Err(format!(
                "input `candidates` holds `{}` sets; the Normal baseline takes the geodesic ones (its extension repeats their search)",
                candidates.params.generator.name()
            )
            .into());
        }
        let manifold: Cvae = ctx.input("manifold")?;
        if let Some(r) = inputs.rollouts.iter().find(|r| r.osw.complete)
            && r.osw.zeta_org.len() != manifold.h_os * osms_sim::N_ARM
        {
            return Err(format!(
                "input `manifold` has H_OS = {}, the D_R windows {}",
                manifold.h_os,
                r.osw.zeta_org.len() / osms_sim::N_ARM
            )
            .into());
        }
        // The D_R part's yield predicts how many extension conditions reach the target.
        let mut base = 0usize;
        for (v, r) in validation.items.iter().zip(&inputs.rollouts) {
            let j_org = validation
                .params
                .j_org(r.record.outcome.success(), r.record.metrics.max_force_n);
            if r.record.outcome.success() || select_unperturbed(j_org, &v.candidates).is_some() {
                base += 1;
            }
        }
        let (target, extra) = deficit(ctx, base)?;
        let yield_r = base as f64 / inputs.rollouts.len().max(1) as f64;
        let extension = if extra == 0 {
            0
        } else {
            ((extra as f64 / yield_r.max(0.05)) * ctx.params.margin).ceil() as usize
        };
        let mut collect_task = inputs.task.clone();
        collect_task.rollout.record_privileged = true;
        Ok(NormalInputs {
            search: candidates.params,
            inputs,
            validation,
            manifold,
            collect_task,
            target,
            extension,
        })
    }
    fn n_items(&self, _: &Ctx<'_, BaselineParams>, p: &NormalInputs) -> usize {
        p.inputs.rollouts.len() + p.extension
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, BaselineParams>,
        n: &NormalInputs,
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<DemoGroup, StageError> {
        let vp = &n.validation.params;
        if let Some(r) = n.inputs.rollouts.get(index) {
            return Ok(normal_group(
                &n.inputs,
                vp,
                r,
                &n.inputs.sets[index],
                &n.validation.items[index].candidates,
                false,
            )?);
        }
        let world = &n.inputs.world;
        let condition = sample(&n.collect_task.conditions, world.home_palm_pos, rng)?;
        let dr_stream = ctx.stream_id("attempt", index as u64);
        let record = rollout(
            world,
            &n.collect_task,
            &n.inputs.agent,
            condition,
            dr_stream.rng(),
        );
        let osw = OswWindow::extract(&record, &n.validation_osw())
            .map_err(|e| format!("extension item {index}: {e}"))?;
        let r = DemoRollout {
            item: index as u32,
            attempt: 0,
            dr_stream,
            record,
            osw,
        };
        let candidates = if r.osw.complete {
            candidate_set(
                &n.manifold,
                &r.osw.zeta_org,
                &r.osw.omega_bar,
                None,
                &n.search,
                &mut ctx.rng("projection", index as u64),
            )
            .map_err(|e| format!("extension item {index}: {e}"))?
            .candidates
        } else {
            Vec::new()
        };
        let never =
            |_: usize| -> StreamRng { unreachable!("unperturbed validation draws no errors") };
        let case = crate::validate::Case {
            world,
            task: &n.inputs.task,
            agent: &n.inputs.agent,
            rollout: &r,
            candidates: &candidates,
            model: &n.inputs.model,
            errors: &never,
        };
        let reports = unperturbed_reports(&case, vp, &mut Cost::default())?;
        Ok(normal_group(
            &n.inputs,
            vp,
            &r,
            &candidates,
            &reports,
            true,
        )?)
    }
    fn merge(
        &self,
        _: &Ctx<'_, BaselineParams>,
        n: NormalInputs,
        groups: Vec<DemoGroup>,
    ) -> Result<DemoSet, StageError> {
        let set = DemoSet {
            construction: "normal".into(),
            target: n.target,
            used: used(&groups, n.target),
            groups,
        };
        if let Some(t) = set.target
            && set.len() < t
        {
            tracing::warn!(
                "normal: the extension's {} conditions gave {} of D_*'s {t} demonstrations; raise params.margin to close the gap",
                n.extension,
                set.len()
            );
        }
        Ok(set)
    }
}

impl NormalInputs {
    fn validation_osw(&self) -> osms_policy::osw::OswSpec {
        osms_policy::osw::OswSpec {
            h_os: self.manifold.h_os,
        }
    }
}

/// The paper's construction columns of Table II: coverage, repair rate, refinement rate,
/// unperturbed f_max (N).
const PAPER_TABLE2: [(&str, f64, f64, f64, f64); 3] = [
    ("naive", 0.852, 0.0, 0.0, 40.6),
    ("normal", 0.949, 0.655, 0.842, 35.9),
    ("ours", 0.918, 0.443, 0.598, 36.5),
];

/// One row of the construction table with the paper's values beside ours.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConstructionRow {
    pub construction: String,
    pub stats: osms_policy::artifacts::ConstructionStats,
    pub paper_coverage: f64,
    pub paper_repair_rate: f64,
    pub paper_refinement_rate: f64,
    pub paper_unperturbed_max_force_n: f64,
}

/// Table II's left half (demonstration construction) for Naive, Normal and ours.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConstructionTable {
    pub rows: Vec<ConstructionRow>,
}

impl osms_core::Artifact for ConstructionTable {
    const TYPE_TAG: &'static str = "method.construction_table";
    const SCHEMA_VERSION: u16 = 1;
}

impl ConstructionTable {
    pub fn markdown(&self) -> String {
        use std::fmt::Write;
        let mut out = String::from(
            "| construction | demos | coverage | repair rate | refinement rate | unperturbed f_max (N) |\n|---|---:|---:|---:|---:|---:|\n",
        );
        let pct = |v: f64| format!("{:.1}%", 100.0 * v);
        for r in &self.rows {
            let s = &r.stats;
            let _ = writeln!(
                out,
                "| {} | {} | {} ({}) | {} ({}) | {} ({}) | {} ({:.1}) |",
                r.construction,
                s.demonstrations,
                pct(s.coverage),
                pct(r.paper_coverage),
                pct(s.repair_rate),
                pct(r.paper_repair_rate),
                pct(s.refinement_rate),
                pct(r.paper_refinement_rate),
                s.unperturbed_max_force_n
                    .map_or_else(|| "-".into(), |f| format!("{f:.1}")),
                r.paper_unperturbed_max_force_n
            );
        }
        out.push_str("\nIn parentheses: the paper's Table II. Coverage, repair and refinement rates are over the D_R conditions; demos count every demonstration, extension included.\n");
        out
    }

    pub fn csv(&self) -> String {
        use std::fmt::Write;
        let mut out = String::from(
            "construction,demonstrations,conditions,kept,refined,repaired,dropped,coverage,repair_rate,refinement_rate,unperturbed_max_force_n,extension_conditions,extension_demonstrations,paper_coverage,paper_repair_rate,paper_refinement_rate,paper_unperturbed_max_force_n\n",
        );
        for r in &self.rows {
            let s = &r.stats;
            let _ = writeln!(
                out,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                r.construction,
                s.demonstrations,
                s.conditions,
                s.kept,
                s.refined,
                s.repaired,
                s.dropped,
                s.coverage,
                s.repair_rate,
                s.refinement_rate,
                s.unperturbed_max_force_n
                    .map(|f| f.to_string())
                    .unwrap_or_default(),
                s.extension_conditions,
                s.extension_demonstrations,
                r.paper_coverage,
                r.paper_repair_rate,
                r.paper_refinement_rate,
                r.paper_unperturbed_max_force_n
            );
        }
        out
    }
}

impl osms_make::Summarize for ConstructionTable {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(&self.rows).unwrap_or_default()
    }
    fn text(&self) -> Option<String> {
        Some(self.markdown())
    }
    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let json = serde_json::to_string_pretty(&self.rows).unwrap_or_default() + "\n";
        vec![
            ("construction_table.md".into(), self.markdown().into_bytes()),
            ("construction_table.csv".into(), self.csv().into_bytes()),
            ("construction_table.json".into(), json.into_bytes()),
        ]
    }
}

/// Table II's construction columns from the three demonstration sets.
pub struct ConstructionTableStage;
impl osms_make::Stage for ConstructionTableStage {
    const KIND: &'static str = "construction_table";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<DemoSet>("naive"),
        Slot::one::<DemoSet>("normal"),
        Slot::one::<DemoSet>("ours"),
    ];
    const DOC: &'static str = "Table II's demonstration-construction columns for Naive, Normal and ours, with the paper's values";
    type Params = osms_core::NoParams;
    type Output = ConstructionTable;

    fn run(&self, ctx: &Ctx<'_, Self::Params>) -> Result<ConstructionTable, StageError> {
        let mut rows = Vec::new();
        for (slot, paper) in ["naive", "normal", "ours"].iter().zip(PAPER_TABLE2) {
            let set: DemoSet = ctx.sharded(slot)?;
            rows.push(ConstructionRow {
                construction: (*slot).to_string(),
                stats: set.stats(),
                paper_coverage: paper.1,
                paper_repair_rate: paper.2,
                paper_refinement_rate: paper.3,
                paper_unperturbed_max_force_n: paper.4,
            });
        }
        Ok(ConstructionTable { rows })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use osms_policy::student::Demo;

    fn group(extension: bool, demos: usize) -> DemoGroup {
        DemoGroup {
            extension,
            item: 0,
            attempt: 0,
            condition: osms_sim::conditions::sample(
                &osms_sim::ConditionSpec::default(),
                [0.0, 0.0, 1.0],
                &mut osms_core::rng::stream(0, "test", "omega", 0),
            )
            .expect("ω"),
            original_success: true,
            origin: Origin::Kept,
            demos: (0..demos)
                .map(|_| osms_policy::artifacts::DemoEntry {
                    execution: Execution::Original,
                    max_force_n: 0.0,
                    demo: Demo {
                        steps: 0,
                        deployable: Vec::new(),
                        actions: Vec::new(),
                    },
                })
                .collect(),
        }
    }

    #[test]
    fn an_extension_stops_at_the_group_that_reaches_the_target() {
        let groups = [
            group(false, 1),
            group(false, 0),
            group(true, 1),
            group(true, 0),
            group(true, 1),
            group(true, 1),
        ];
        // D_R gives 1; the extension reaches 3 with its third group (index 4).
        assert_eq!(used(&groups, Some(3)), Some(5));
        assert_eq!(used(&groups, Some(1)), Some(2));
        // D_R groups are never cut, even past the target.
        assert_eq!(used(&groups[..2], Some(0)), Some(2));
        assert_eq!(used(&groups, Some(9)), Some(6));
        assert_eq!(used(&groups, None), None);
    }
}
