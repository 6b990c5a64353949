//! The `validate` and `dstar` stage kinds (paper 4.4, Alg. 1 steps 3–4): every D_R rollout's
//! candidates validated under the action-error model and the decision, then D_* built from the
//! decisions as student demonstrations.

use std::collections::BTreeMap;
use std::fmt::Write;

use osms_core::Artifact;
use osms_core::rng::StreamRng;
use osms_make::{Ctx, ItemStage, Numerics, Scale, Slot, StageError, Summarize};
use osms_policy::Agent;
use osms_policy::artifacts::Teacher;
use osms_policy::artifacts::{Dataset, DemoRollout};
use osms_policy::artifacts::{DemoEntry, DemoGroup, DemoSet, Execution, Origin};
use osms_policy::catch::CatchTaskSpec;
use osms_policy::stages::numerics as policy_numerics;
use osms_policy::student::Demo;
use osms_sim::World;
use osms_sim::artifacts::WorldArtifact;
use serde::{Deserialize, Serialize};

use crate::candidates::Candidate;
use crate::error_model::ErrorModel;
use crate::error_stages::{ErrorModelArtifact, variant_name};
use crate::intervene::{Errors, Snippet, execute};
use crate::select::Decision;
use crate::stages::CandidateSets;
use crate::validate::{
    Case, Cost, Robustness, Unperturbed, ValidateParams, ValidationItem, validate,
};

/// Every D_R rollout's validation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Validation {
    pub params: ValidateParams,
    /// The error model validated under.
    pub error_model: String,
    /// The candidate generator of the sets validated.
    pub generator: String,
    /// Where the perturbed rollouts' innovations came from, so D_* repeats them.
    pub streams: ErrorStreams,
    pub items: Vec<ValidationItem>,
}

/// The innovations of perturbed rollout q of D_R item i: stream ("errors-q", i) of the
/// validation stage, the same for every candidate of the item (common random numbers).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorStreams {
    pub seed: u64,
    pub stage: String,
}

impl ErrorStreams {
    pub fn rng(&self, item: u32, q: usize) -> StreamRng {
        osms_core::rng::stream(
            self.seed,
            &self.stage,
            &format!("errors-{q}"),
            u64::from(item),
        )
    }
}

impl Artifact for Validation {
    const TYPE_TAG: &'static str = "method.validation";
    /// 2: its params name the D_R subset (`rollouts`).
    const SCHEMA_VERSION: u16 = 2;
}

impl osms_make::Sharded for Validation {
    type Item = ValidationItem;
    fn take_items(&mut self) -> Vec<ValidationItem> {
        std::mem::take(&mut self.items)
    }
    fn set_items(&mut self, items: Vec<ValidationItem>) {
        self.items = items;
    }
}

/// Counts behind `osms show` on a validation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValidationStats {
    pub rollouts: usize,
    pub validated: usize,
    pub original_successes: usize,
    pub decisions: BTreeMap<String, usize>,
    pub candidates: usize,
    pub unperturbed_successes: usize,
    /// Candidates that got perturbed rollouts, and of those how many reached the threshold.
    pub perturbed: usize,
    pub qualified: usize,
    /// Mean SR_org over the originals whose SR was needed.
    pub mean_sr_org: Option<f64>,
    /// Mean SR of the selected candidates.
    pub mean_sr_selected: Option<f64>,
}

impl Validation {
    pub fn stats(&self) -> ValidationStats {
        let q = self.params.q;
        let mut decisions = BTreeMap::new();
        for i in &self.items {
            *decisions.entry(i.decision.name().to_string()).or_default() += 1;
        }
        let cands = || self.items.iter().flat_map(|i| &i.candidates);
        let mean = |v: Vec<f64>| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        ValidationStats {
            rollouts: self.items.len(),
            validated: self.items.iter().filter(|i| i.validated).count(),
            original_successes: self.items.iter().filter(|i| i.original.success).count(),
            decisions,
            candidates: cands().count(),
            unperturbed_successes: cands().filter(|c| c.unperturbed.success()).count(),
            perturbed: cands()
                .filter(|c| c.robustness != Robustness::NotRun)
                .count(),
            qualified: cands()
                .filter(|c| matches!(c.robustness, Robustness::Full { .. }))
                .count(),
            mean_sr_org: mean(
                self.items
                    .iter()
                    .filter_map(|i| i.original.robustness.sr(q))
                    .collect(),
            ),
            mean_sr_selected: mean(
                self.items
                    .iter()
                    .filter_map(|i| {
                        i.decision
                            .selected()
                            .and_then(|k| i.candidates[k].robustness.sr(q))
                    })
                    .collect(),
            ),
        }
    }
}

impl Summarize for Validation {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(self.stats()).unwrap_or_default()
    }

    fn text(&self) -> Option<String> {
        let s = self.stats();
        let p = &self.params;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "validation of {} candidate sets under the {} error model: Q = {}, δ_SR = {}, λ_f = {}, λ_d = {}, {}{}",
            self.generator,
            self.error_model,
            p.q,
            p.delta_sr,
            p.lambda_f,
            p.lambda_d,
            p.construction.name(),
            if p.exhaustive { ", exhaustive" } else { "" }
        );
        let _ = writeln!(
            out,
            "{} D_R rollouts ({} teacher successes), {} validated; {} candidates, {} succeed unperturbed, {} got perturbed rollouts, {} reached the threshold",
            s.rollouts,
            s.original_successes,
            s.validated,
            s.candidates,
            s.unperturbed_successes,
            s.perturbed,
            s.qualified
        );
        let fmt = |v: Option<f64>| v.map_or_else(|| "-".into(), |v| format!("{v:.3}"));
        let _ = writeln!(
            out,
            "mean SR_org {} (where needed), mean SR of the selected {}",
            fmt(s.mean_sr_org),
            fmt(s.mean_sr_selected)
        );
        let _ = writeln!(out, "\n| decision | rollouts |\n|---|---:|");
        for (d, n) in &s.decisions {
            let _ = writeln!(out, "| {d} | {n} |");
        }
        Some(out)
    }

    fn files(&self) -> Vec<(String, Vec<u8>)> {
        let mut csv = String::from(
            "item,attempt,variant,original_success,original_max_force_n,original_sr,candidate,unperturbed_success,max_force_n,j,deviation,distance,robustness,successes,evaluated,selected\n",
        );
        let q = self.params.q;
        for i in &self.items {
            let org_sr = i
                .original
                .robustness
                .sr(q)
                .map(|v| v.to_string())
                .unwrap_or_default();
            for (k, c) in i.candidates.iter().enumerate() {
                let (f, j) = match c.unperturbed {
                    Unperturbed::Succeeded { max_force_n, j } => {
                        (max_force_n.to_string(), j.to_string())
                    }
                    Unperturbed::Failed => (String::new(), String::new()),
                };
                let (kind, s, e) = match c.robustness {
                    Robustness::NotRun => ("not_run", String::new(), String::new()),
                    Robustness::Insufficient {
                        successes,
                        evaluated,
                    } => ("insufficient", successes.to_string(), evaluated.to_string()),
                    Robustness::Full { successes } => {
                        ("full", successes.to_string(), q.to_string())
                    }
                };
                let _ = writeln!(
                    csv,
                    "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                    i.item,
                    i.attempt,
                    i.variant,
                    i.original.success,
                    i.original.max_force_n,
                    org_sr,
                    k,
                    c.unperturbed.success(),
                    f,
                    j,
                    c.deviation,
                    c.distance,
                    kind,
                    s,
                    e,
                    i.decision.selected() == Some(k)
                );
            }
        }
        vec![("validation.csv".into(), csv.into_bytes())]
    }
}

/// What validation and D_* read: the world, the teacher, the D_R rollouts with their task,
/// their candidate sets and the error model.
pub struct Inputs {
    pub(crate) world: World,
    pub(crate) agent: Agent,
    pub(crate) task: CatchTaskSpec,
    pub(crate) rollouts: Vec<DemoRollout>,
    pub(crate) sets: Vec<Vec<Candidate>>,
    pub(crate) generator: String,
    pub(crate) model: ErrorModel,
}

impl Inputs {
    pub(crate) fn load<P>(ctx: &Ctx<'_, P>, params: &ValidateParams) -> Result<Inputs, StageError> {
        params.check()?;
        let teacher: Teacher = ctx.input("teacher")?;
        let data: Dataset = ctx.sharded("data")?;
        let candidates: CandidateSets = ctx.sharded("candidates")?;
        if candidates.items.len() != data.items.len()
            || candidates
                .items
                .iter()
                .zip(&data.items)
                .any(|(c, d)| (c.item, c.attempt) != (d.rollout.item, d.rollout.attempt))
        {
            return Err(
                "input `candidates`: the sets were built for other rollouts than `data`\nhint: wire `candidates` to a candidates stage on the windows of the same D_R dataset".into(),
            );
        }
        let errors: ErrorModelArtifact = ctx.input("error_model")?;
        let model = match params.error_model {
            None => errors.model,
            Some(v) => errors
                .variants
                .into_iter()
                .find(|f| f.model.variant == v)
                .map(|f| f.model)
                .ok_or_else(|| {
                    format!(
                        "params.error_model = `{}`: the error-model artifact has no such fit",
                        variant_name(v)
                    )
                })?,
        };
        model
            .validate()
            .map_err(|e| format!("input `error_model`: {e}"))?;
        let mut task = data.task.clone();
        // Validation reads outcomes and commanded actions; the privileged frames were for ω̄.
        task.rollout.record_privileged = false;
        let n = match params.rollouts {
            0 => data.items.len(),
            n if n <= data.items.len() => n,
            n => {
                return Err(format!(
                    "params.rollouts = {n}, but `data` holds {} rollouts\nhint: use at most {} (0 validates all)",
                    data.items.len(),
                    data.items.len()
                )
                .into());
            }
        };
        Ok(Inputs {
            world: ctx.input::<WorldArtifact>("world")?.world()?,
            agent: teacher.agent,
            task,
            sets: candidates
                .items
                .iter()
                .take(n)
                .map(|i| {
                    i.set
                        .as_ref()
                        .map(|s| s.candidates.clone())
                        .unwrap_or_default()
                })
                .collect(),
            generator: candidates.params.generator.name().to_string(),
            rollouts: data.items.into_iter().take(n).map(|i| i.rollout).collect(),
            model,
        })
    }

    /// Refuses a validation of other rollouts or other candidate sets than these.
    pub(crate) fn check_validation(&self, v: &Validation) -> Result<(), StageError> {
        if v.items.len() != self.rollouts.len()
            || v.items
                .iter()
                .zip(&self.rollouts)
                .any(|(v, r)| (v.item, v.attempt) != (r.item, r.attempt))
        {
            return Err("input `validation` was run on other rollouts than `data`".into());
        }
        if v.generator != self.generator
            || v.items
                .iter()
                .zip(&self.sets)
                .any(|(v, set)| v.validated && v.candidates.len() != set.len())
        {
            return Err(format!(
                "input `validation` was run on other candidate sets ({}) than `candidates` ({})",
                v.generator, self.generator
            )
            .into());
        }
        Ok(())
    }

    pub(crate) fn case<'a>(
        &'a self,
        index: usize,
        errors: &'a dyn Fn(usize) -> StreamRng,
    ) -> Case<'a> {
        Case {
            world: &self.world,
            task: &self.task,
            agent: &self.agent,
            rollout: &self.rollouts[index],
            candidates: &self.sets[index],
            model: &self.model,
            errors,
        }
    }
}

const VALIDATE_INPUTS: &[Slot] = &[
    Slot::one::<WorldArtifact>("world"),
    Slot::one::<Teacher>("teacher"),
    Slot::one::<Dataset>("data").roles(&["d_r"]),
    Slot::one::<CandidateSets>("candidates"),
    Slot::one::<ErrorModelArtifact>("error_model"),
];

/// Alg. 1 steps 3–4 for every D_R rollout: one unperturbed and Q perturbed rollouts per
/// candidate and for ζ_org, common random numbers per condition (perturbed rollout q of item i
/// draws from stream ("errors-q", i)), and the decision.
pub struct ValidateStage;
impl ItemStage for ValidateStage {
    const KIND: &'static str = "validate";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = VALIDATE_INPUTS;
    const DOC: &'static str = "candidate validation under the action-error model (paper 4.4, Eqs. 8-9): SR, J and the refine / repair decision per D_R rollout";
    type Params = ValidateParams;
    type Prepared = Inputs;
    type Item = ValidationItem;
    type Output = Validation;

    fn numerics() -> Vec<Numerics> {
        policy_numerics()
    }

    /// The D_R rollouts validated (`rollouts`, 0: all of `data`).
    fn scale(params: &ValidateParams, inputs: &[(&str, f64)]) -> Scale {
        let data = Scale::input(inputs, "data");
        Scale::items(match params.rollouts {
            0 => data,
            n => data.min(n as f64),
        })
    }
    fn prepare(&self, ctx: &Ctx<'_, ValidateParams>) -> Result<Inputs, StageError> {
        Inputs::load(ctx, ctx.params)
    }
    fn n_items(&self, _: &Ctx<'_, ValidateParams>, p: &Inputs) -> usize {
        p.rollouts.len()
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, ValidateParams>,
        inputs: &Inputs,
        index: usize,
        _: &mut StreamRng,
    ) -> Result<ValidationItem, StageError> {
        let (item, cost) = validate_with_cost(ctx, inputs, index)?;
        tracing::debug!(
            index,
            rollouts = cost.rollouts,
            steps = cost.steps,
            "validated"
        );
        Ok(item)
    }
    fn merge(
        &self,
        ctx: &Ctx<'_, ValidateParams>,
        inputs: Inputs,
        items: Vec<ValidationItem>,
    ) -> Result<Validation, StageError> {
        Ok(Validation {
            // Both evaluations give the same artifact; the flag is not part of it.
            params: ValidateParams {
                exhaustive: false,
                ..ctx.params.clone()
            },
            error_model: variant_name(inputs.model.variant).to_string(),
            generator: inputs.generator,
            streams: streams(ctx),
            items,
        })
    }
}

fn streams(ctx: &Ctx<'_, ValidateParams>) -> ErrorStreams {
    ErrorStreams {
        seed: ctx.seed().unwrap_or_default(),
        stage: ctx.stage().to_string(),
    }
}

/// One D_R rollout's validation and what it simulated (the benchmark's measure).
pub fn validate_with_cost(
    ctx: &Ctx<'_, ValidateParams>,
    inputs: &Inputs,
    index: usize,
) -> Result<(ValidationItem, Cost), String> {
    let streams = streams(ctx);
    let item = inputs.rollouts[index].item;
    let errors = move |q| streams.rng(item, q);
    validate(&inputs.case(index, &errors), ctx.params)
}

pub(crate) fn entry(
    execution: Execution,
    record: &osms_sim::RolloutRecord,
    actions: Vec<f32>,
) -> DemoEntry {
    DemoEntry {
        execution,
        max_force_n: record.metrics.max_force_n,
        demo: Demo {
            steps: record.steps,
            deployable: record.deployable.clone(),
            actions,
        },
    }
}

/// D_* (Alg. 1 step 4): for a refined or repaired rollout the selected ζ*'s unperturbed
/// rollout and every successful perturbed one (labels: the commanded actions, modelled
/// perturbations included); a kept original as it ran; nothing for a dropped one. The
/// rollouts are re-run with the validation's streams and checked against its outcomes.
pub struct DstarStage;
impl ItemStage for DstarStage {
    const KIND: &'static str = "dstar";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<WorldArtifact>("world"),
        Slot::one::<Teacher>("teacher"),
        Slot::one::<Dataset>("data").roles(&["d_r"]),
        Slot::one::<CandidateSets>("candidates"),
        Slot::one::<ErrorModelArtifact>("error_model"),
        Slot::one::<Validation>("validation"),
    ];
    const DOC: &'static str = "D_*: the selected candidates' successful unperturbed and perturbed rollouts and the kept originals, as student demonstrations";
    type Params = DstarParams;
    type Prepared = (Inputs, Validation);
    type Item = DemoGroup;
    type Output = DemoSet;

    fn numerics() -> Vec<Numerics> {
        policy_numerics()
    }
    fn prepare(&self, ctx: &Ctx<'_, DstarParams>) -> Result<Self::Prepared, StageError> {
        let validation: Validation = ctx.sharded("validation")?;
        let inputs = Inputs::load(ctx, &validation.params)?;
        inputs.check_validation(&validation)?;
        if variant_name(inputs.model.variant) != validation.error_model {
            return Err(format!(
                "input `validation` ran under the {} error model, but `error_model` gives {}",
                validation.error_model,
                variant_name(inputs.model.variant)
            )
            .into());
        }
        Ok((inputs, validation))
    }
    fn n_items(&self, _: &Ctx<'_, DstarParams>, p: &Self::Prepared) -> usize {
        p.0.rollouts.len()
    }
    fn run_item(
        &self,
        _: &Ctx<'_, DstarParams>,
        (inputs, validation): &Self::Prepared,
        index: usize,
        _: &mut StreamRng,
    ) -> Result<DemoGroup, StageError> {
        let v = &validation.items[index];
        let r = &inputs.rollouts[index];
        let mut group = DemoGroup {
            extension: false,
            item: r.item,
            attempt: r.attempt,
            condition: r.record.condition.clone(),
            original_success: v.original.success,
            origin: Origin::Dropped,
            demos: Vec::new(),
        };
        let (origin, k) = match v.decision {
            Decision::Drop => return Ok(group),
            Decision::KeepOriginal => {
                group.origin = Origin::Kept;
                group.demos.push(entry(
                    Execution::Original,
                    &r.record,
                    r.record.intended.clone(),
                ));
                return Ok(group);
            }
            Decision::Refine { index: k } => (Origin::Refined, k),
            Decision::Repair { index: k } => (Origin::Repaired, k),
        };
        group.origin = origin;
        let zeta = &inputs.sets[index][k].zeta;
        let run = |errors: Option<Errors<'_>>| {
            execute(
                &inputs.world,
                &inputs.task,
                &inputs.agent,
                r.record.condition.clone(),
                r.dr_stream.rng(),
                Some(Snippet {
                    start: r.osw.start,
                    zeta,
                }),
                errors,
            )
        };
        let mismatch = |what: &str| -> StageError {
            format!(
                "D_R item {}: the selected candidate's {what} does not repeat its validation\nhint: the validation was built from other inputs; rebuild it",
                r.item
            )
            .into()
        };
        let u = run(None);
        if !u.record.outcome.success() {
            return Err(mismatch("unperturbed rollout"));
        }
        group
            .demos
            .push(entry(Execution::Unperturbed, &u.record, u.commanded));
        let mut successes = 0u32;
        for q in 0..validation.params.q {
            let e = run(Some(Errors {
                perturber: crate::error_model::Perturber::new(&inputs.model),
                rng: validation.streams.rng(r.item, q),
            }));
            if e.record.outcome.success() {
                successes += 1;
                group.demos.push(entry(
                    Execution::Perturbed { q: q as u32 },
                    &e.record,
                    e.commanded,
                ));
            }
        }
        if v.candidates[k].robustness != (Robustness::Full { successes }) {
            return Err(mismatch("perturbed rollouts"));
        }
        Ok(group)
    }
    fn merge(
        &self,
        _: &Ctx<'_, DstarParams>,
        _: Self::Prepared,
        groups: Vec<DemoGroup>,
    ) -> Result<DemoSet, StageError> {
        Ok(DemoSet {
            construction: "ours".into(),
            target: None,
            used: None,
            groups,
        })
    }
}

/// D_* takes no settings of its own: the validation's are used.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DstarParams {}

/// Registers the validation kinds.
pub fn register(registry: &mut osms_make::Registry) {
    registry
        .register_itemised(ValidateStage)
        .register_itemised(DstarStage)
        .register_itemised(crate::baselines::NaiveStage)
        .register_itemised(crate::baselines::NormalStage)
        .register(crate::baselines::ConstructionTableStage)
        .register_itemised(crate::ios::IosProfileStage);
}
