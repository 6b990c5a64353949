//! Candidate validation (paper 4.4, Eqs. 8–9, Alg. 1 steps 3–4): every candidate of a D_R
//! rollout is judged by one unperturbed and Q perturbed complete rollouts under the action-error
//! model, with common random numbers, and the decision of [`crate::select`] follows.
//!
//! Two evaluations give the same [`ValidationItem`] bit for bit:
//!
//! - **exhaustive** runs every rollout Alg. 1 names (ζ_org's replay and every candidate, one
//!   unperturbed and Q perturbed each) from step 0 to the end, then records what the decision
//!   depends on;
//! - **fast** runs the teacher's prefix up to the window's start once per q and branches every
//!   candidate from it (snapshot and restore), stops a rollout as soon as it has failed for good
//!   (`failure_decided`), gives perturbed rollouts only to candidates that succeed unperturbed
//!   and can still beat J_org, and stops a candidate's perturbed rollouts once its SR can no
//!   longer reach the threshold (SR_org for refinement, δ_SR for repair).
//!
//! What is recorded is what both know: an unperturbed failure without its metrics, SR exactly
//! where it was needed in full, and otherwise the prefix of perturbed rollouts after which the
//! threshold was out of reach ([`Robustness`]).

use osms_core::rng::StreamRng;
use osms_policy::Agent;
use osms_policy::artifacts::DemoRollout;
use osms_policy::catch::CatchTaskSpec;
use osms_sim::{N_ACTION, World};
use serde::{Deserialize, Serialize};

use crate::{Error, Result};

use crate::candidates::Candidate;
use crate::error_model::{ErrorModel, ErrorVariant, Perturber};
use crate::intervene::{Errors, Intervention, InterventionSnapshot, Snippet, execute};
use crate::select::{CandidateOutcome, Decision, OriginalOutcome, quality, select};

/// Which D_R rollouts the construction changes (the refine-only and repair-only ablations of
/// paper 6.4 leave the others as they are: a success kept, a failure dropped).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Construction {
    /// Refine successes and repair failures (the method).
    #[default]
    Both,
    RefineOnly,
    RepairOnly,
}

impl Construction {
    pub fn name(self) -> &'static str {
        match self {
            Construction::Both => "refine and repair",
            Construction::RefineOnly => "refine only",
            Construction::RepairOnly => "repair only",
        }
    }
}

/// Validation settings: the paper's Q and δ_SR as defaults. Every default lives here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ValidateParams {
    /// Q: perturbed rollouts per candidate (Eq. 8).
    pub q: usize,
    /// δ_SR: the robustness a repair needs.
    pub delta_sr: f64,
    /// λ_f of Eq. 9 (per N). The paper gives no value; 1/δ_f makes the force term the
    /// fraction of the force limit.
    pub lambda_f: f64,
    /// λ_d of Eq. 9 (per unit of ‖·‖_{W_a}). The paper gives no value; equal to λ_f, one unit
    /// of normalised deviation costs as much as 1 N of peak force.
    pub lambda_d: f64,
    pub construction: Construction,
    /// Which of the error-model artifact's Table III fits to validate under; absent: the one
    /// it applies (its `params.variant`).
    pub error_model: Option<ErrorVariant>,
    /// κ_ε of Eq. 7 instead of the error model's (the paper's 1.5): for studies of where the
    /// search pays (issue 74's regime map), not a knob to tune.
    pub kappa: Option<f64>,
    /// The error model's deviation (bias and residual; `ErrorModel::with_deviation_scale`)
    /// scaled by this factor, as [`ValidateParams::kappa`] a study's knob (issue 74).
    pub deviation_scale: Option<f64>,
    /// Run every rollout from step 0 to the end (the reference the fast path is tested and
    /// benchmarked against; same artifact).
    pub exhaustive: bool,
    /// Validate only the first this many D_R rollouts (0: all): the reduced subset the
    /// ablations may run on. D_* and the baselines follow their validation's subset.
    pub rollouts: usize,
}

impl Default for ValidateParams {
    fn default() -> Self {
        ValidateParams {
            q: 16,
            delta_sr: 0.75,
            lambda_f: 1.0 / 80.0,
            lambda_d: 1.0 / 80.0,
            construction: Construction::Both,
            error_model: None,
            kappa: None,
            deviation_scale: None,
            exhaustive: false,
            rollouts: 0,
        }
    }
}

impl ValidateParams {
    pub fn check(&self) -> Result<()> {
        <Self as osms_core::check::Check>::check(self).map_err(Error::from)
    }

    /// J_org of Eq. 9 for an original (it deviates by nothing); `None` for a failure.
    pub fn j_org(&self, success: bool, max_force_n: f64) -> Option<f64> {
        success.then(|| quality(max_force_n, 0.0, self.lambda_f, self.lambda_d))
    }

    /// The fewest successes of Q that give SR ≥ δ_SR (Q + 1 if none do).
    pub fn repair_successes(&self) -> u32 {
        (0..=self.q as u32)
            .find(|&s| f64::from(s) / self.q as f64 >= self.delta_sr)
            .unwrap_or(self.q as u32 + 1)
    }
}

/// A rollout's unperturbed outcome as the decision uses it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Unperturbed {
    Failed,
    Succeeded {
        max_force_n: f64,
        /// J of Eq. 9.
        j: f64,
    },
}

impl Unperturbed {
    pub fn success(self) -> bool {
        matches!(self, Unperturbed::Succeeded { .. })
    }
    pub fn j(self) -> Option<f64> {
        match self {
            Unperturbed::Succeeded { j, .. } => Some(j),
            Unperturbed::Failed => None,
        }
    }
}

/// The perturbed rollouts of Eq. 8, as far as the decision needed them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Robustness {
    /// Not needed: the rollout failed unperturbed, could not beat J_org, or no candidate
    /// needed the original's SR.
    NotRun,
    /// The threshold was out of reach after the first `evaluated` perturbed rollouts, of
    /// which `successes` succeeded.
    Insufficient { successes: u32, evaluated: u32 },
    /// All Q perturbed rollouts, `successes` of them successful: SR = successes / Q.
    Full { successes: u32 },
}

impl Robustness {
    /// SR of Eq. 8, where it is known.
    pub fn sr(self, q: usize) -> Option<f64> {
        match self {
            Robustness::Full { successes } => Some(f64::from(successes) / q as f64),
            _ => None,
        }
    }
}

/// One candidate's validation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CandidateReport {
    pub unperturbed: Unperturbed,
    /// ‖ζ − ζ_org‖_{W_a}.
    pub deviation: f64,
    /// The tie-break after SR: the geodesic's length, or ‖z − z⁰‖ for straight-line
    /// generators.
    pub distance: f64,
    pub robustness: Robustness,
}

/// The original rollout: its outcome, J and (replaying ζ_org under the errors) SR.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OriginalReport {
    pub success: bool,
    pub max_force_n: f64,
    /// J_org = λ_f f_max (a success only: ζ_org deviates by nothing).
    pub j: Option<f64>,
    pub robustness: Robustness,
}

/// One D_R rollout's validation and decision.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValidationItem {
    /// Which draw of D_R's condition stream: (item, attempt).
    pub item: u32,
    pub attempt: u32,
    pub variant: String,
    /// Whether the window has all H_OS steps (search and validation skip it otherwise).
    pub complete: bool,
    /// Whether its candidates were validated (a complete window the construction changes).
    pub validated: bool,
    pub original: OriginalReport,
    /// One per candidate of η, in η's order (empty when not validated).
    pub candidates: Vec<CandidateReport>,
    pub decision: Decision,
}

/// What a validation simulated: the measure of its cost (not part of the artifact, which is
/// the same for both evaluations).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Cost {
    /// Rollouts started or branched.
    pub rollouts: u64,
    /// Control steps simulated.
    pub steps: u64,
}

impl std::ops::AddAssign for Cost {
    fn add_assign(&mut self, o: Cost) {
        self.rollouts += o.rollouts;
        self.steps += o.steps;
    }
}

/// Everything one D_R rollout's validation reads.
pub struct Case<'a> {
    pub world: &'a World,
    /// The task as D_R ran it (its DR setting).
    pub task: &'a CatchTaskSpec,
    pub agent: &'a Agent,
    pub rollout: &'a DemoRollout,
    /// η (empty without a search).
    pub candidates: &'a [Candidate],
    pub model: &'a ErrorModel,
    /// The stream of perturbed rollout q's innovations: the same for every candidate.
    pub errors: &'a dyn Fn(usize) -> StreamRng,
}

impl<'a> Case<'a> {
    fn snippet<'z>(&self, zeta: &'z [f32]) -> Snippet<'z> {
        Snippet {
            start: self.rollout.osw.start,
            zeta,
        }
    }

    fn perturbed(&self, q: usize) -> Errors<'a> {
        Errors {
            perturber: Perturber::new(self.model),
            rng: (self.errors)(q),
        }
    }

    /// Whether the construction changes this rollout.
    fn validated(&self, p: &ValidateParams) -> bool {
        let success = self.rollout.record.outcome.success();
        self.rollout.osw.complete
            && !self.candidates.is_empty()
            && match p.construction {
                Construction::Both => true,
                Construction::RefineOnly => success,
                Construction::RepairOnly => !success,
            }
    }
}

fn distance(c: &Candidate) -> f64 {
    c.geodesic_length.unwrap_or(c.latent_displacement)
}

/// Counts perturbed successes in q order, stopping once `needed` is out of reach.
fn tally(q: usize, needed: u32, mut success: impl FnMut(usize) -> bool) -> Robustness {
    let mut s = 0u32;
    for m in 0..q {
        if s + ((q - m) as u32) < needed {
            return Robustness::Insufficient {
                successes: s,
                evaluated: m as u32,
            };
        }
        if success(m) {
            s += 1;
        }
    }
    if s >= needed {
        Robustness::Full { successes: s }
    } else {
        Robustness::Insufficient {
            successes: s,
            evaluated: q as u32,
        }
    }
}

/// The successes of Q a candidate needs: for a successful original SR_org's, from Q replays of
/// ζ_org (`replay(q)` says whether replay q succeeded; recorded in `original`), otherwise
/// δ_SR's.
fn threshold(
    original: &mut OriginalReport,
    p: &ValidateParams,
    replay: impl FnMut(usize) -> bool,
) -> u32 {
    if !original.success {
        return p.repair_successes();
    }
    original.robustness = tally(p.q, 0, replay);
    match original.robustness {
        Robustness::Full { successes } => successes,
        _ => unreachable!("a tally that needs nothing runs all Q"),
    }
}

/// The decision from the unperturbed outcomes and the robustness reports.
fn decide(
    original: &OriginalReport,
    candidates: &[CandidateReport],
    p: &ValidateParams,
) -> Decision {
    let org = OriginalOutcome {
        success: original.success,
        j: original.j.unwrap_or(f64::NAN),
        sr: original.robustness.sr(p.q).unwrap_or(0.0),
    };
    let outcomes: Vec<CandidateOutcome> = candidates
        .iter()
        .map(|c| CandidateOutcome {
            unperturbed_success: c.unperturbed.success(),
            j: c.unperturbed.j().unwrap_or(f64::INFINITY),
            sr: c.robustness.sr(p.q),
            distance: c.distance,
        })
        .collect();
    select(&org, &outcomes, p.delta_sr)
}

/// Unperturbed-only validation (the Normal baseline, paper 6): among the candidates that
/// succeed unperturbed (and, refining, beat J_org) the lowest J, then the shorter distance,
/// then the lower index.
pub fn select_unperturbed(j_org: Option<f64>, reports: &[CandidateReport]) -> Option<usize> {
    reports
        .iter()
        .enumerate()
        .filter(|(_, c)| needs_sr(c.unperturbed, j_org))
        .min_by(|(ia, a), (ib, b)| {
            let (ja, jb) = (a.unperturbed.j(), b.unperturbed.j());
            ja.unwrap_or(f64::INFINITY)
                .total_cmp(&jb.unwrap_or(f64::INFINITY))
                .then_with(|| a.distance.total_cmp(&b.distance))
                .then_with(|| ia.cmp(ib))
        })
        .map(|(i, _)| i)
}

/// Whether a candidate needs perturbed rollouts: it succeeds unperturbed and, refining, beats
/// J_org.
fn needs_sr(u: Unperturbed, j_org: Option<f64>) -> bool {
    match (u, j_org) {
        (Unperturbed::Failed, _) => false,
        (Unperturbed::Succeeded { j, .. }, Some(j_org)) => j < j_org,
        (Unperturbed::Succeeded { .. }, None) => true,
    }
}

fn unperturbed(success: bool, max_force_n: f64, deviation: f64, p: &ValidateParams) -> Unperturbed {
    if success {
        Unperturbed::Succeeded {
            max_force_n,
            j: quality(max_force_n, deviation, p.lambda_f, p.lambda_d),
        }
    } else {
        Unperturbed::Failed
    }
}

/// Validates one D_R rollout (Alg. 1 steps 3–4) the way `p.exhaustive` says.
pub fn validate(case: &Case<'_>, p: &ValidateParams) -> Result<(ValidationItem, Cost)> {
    let r = case.rollout;
    let mut item = ValidationItem {
        item: r.item,
        attempt: r.attempt,
        variant: r.record.condition.variant.to_string(),
        complete: r.osw.complete,
        validated: case.validated(p),
        original: OriginalReport {
            success: r.record.outcome.success(),
            max_force_n: r.record.metrics.max_force_n,
            j: None,
            robustness: Robustness::NotRun,
        },
        candidates: Vec::new(),
        decision: Decision::Drop,
    };
    let mut cost = Cost::default();
    if item.validated {
        if p.exhaustive {
            exhaustive(case, p, &mut item, &mut cost)?;
        } else {
            fast(case, p, &mut item, &mut cost)?;
        }
    }
    item.original.j = p.j_org(item.original.success, item.original.max_force_n);
    item.decision = decide(&item.original, &item.candidates, p);
    Ok((item, cost))
}

/// Every rollout from step 0 to the end; then the same reports the fast path gives.
fn exhaustive(
    case: &Case<'_>,
    p: &ValidateParams,
    item: &mut ValidationItem,
    cost: &mut Cost,
) -> Result<()> {
    let r = case.rollout;
    let run = |zeta: &[f32], errors: Option<Errors<'_>>, cost: &mut Cost| {
        let e = execute(
            case.world,
            case.task,
            case.agent,
            r.record.condition.clone(),
            r.dr_stream.rng(),
            Some(case.snippet(zeta)),
            errors,
        );
        cost.rollouts += 1;
        cost.steps += e.record.steps as u64;
        e.record
    };
    // ζ_org replayed: the original's outcome and J_org come from this replay.
    let replay = run(&r.osw.zeta_org, None, cost);
    item.original.success = replay.outcome.success();
    item.original.max_force_n = replay.metrics.max_force_n;
    let j_org = p.j_org(item.original.success, item.original.max_force_n);
    let org_perturbed: Vec<bool> = (0..p.q)
        .map(|q| {
            run(&r.osw.zeta_org, Some(case.perturbed(q)), cost)
                .outcome
                .success()
        })
        .collect();
    let mut perturbed = Vec::new();
    for c in case.candidates {
        let u = run(&c.zeta, None, cost);
        let report = CandidateReport {
            unperturbed: unperturbed(u.outcome.success(), u.metrics.max_force_n, c.deviation, p),
            deviation: c.deviation,
            distance: distance(c),
            robustness: Robustness::NotRun,
        };
        item.candidates.push(report);
        perturbed.push(
            (0..p.q)
                .map(|q| {
                    run(&c.zeta, Some(case.perturbed(q)), cost)
                        .outcome
                        .success()
                })
                .collect::<Vec<bool>>(),
        );
    }
    let any = item
        .candidates
        .iter()
        .any(|c| needs_sr(c.unperturbed, j_org));
    if !any {
        return Ok(());
    }
    let needed = threshold(&mut item.original, p, |q| org_perturbed[q]);
    for (c, outcomes) in item.candidates.iter_mut().zip(&perturbed) {
        if needs_sr(c.unperturbed, j_org) {
            c.robustness = tally(p.q, needed, |q| outcomes[q]);
        }
    }
    Ok(())
}

/// Runs `run` from where it is until the episode ends or has failed for good; returns whether
/// it succeeded and its f_max.
fn run_out(run: &mut Intervention<'_, '_, '_>, agent: &Agent, cost: &mut Cost) -> (bool, f64) {
    cost.rollouts += 1;
    let from = run.step_index();
    let mut decided = false;
    while !run.step(agent) {
        if run.failure_decided() {
            decided = true;
            break;
        }
    }
    cost.steps += (run.step_index() - from) as u64;
    let (outcome, metrics) = run.outcome();
    (
        !decided && !run.failure_decided() && outcome.success(),
        metrics.max_force_n,
    )
}

/// A rollout of `case` run up to its window's start.
fn prefix<'c>(
    case: &Case<'c>,
    errors: Option<Errors<'c>>,
    cost: &mut Cost,
) -> Intervention<'c, 'c, 'c> {
    let r = case.rollout;
    let mut run = Intervention::new(
        case.world,
        case.task,
        r.record.condition.clone(),
        r.dr_stream.rng(),
        errors,
    );
    run.run_until(case.agent, r.osw.start);
    cost.rollouts += 1;
    cost.steps += run.step_index() as u64;
    run
}

/// Whether `zeta` succeeds in branch `q`: restored to the window's start, run out.
fn branch<'c>(
    case: &Case<'c>,
    (run, snapshot): &mut (Intervention<'c, 'c, 'c>, InterventionSnapshot<'c, 'c>),
    zeta: &'c [f32],
    cost: &mut Cost,
) -> (bool, f64) {
    run.restore(snapshot);
    run.set_snippet(Some(case.snippet(zeta)));
    run_out(run, case.agent, cost)
}

/// Every candidate's unperturbed outcome (what unperturbed-only validation reads), branched
/// from the original rollout at the window's start; failures stop once decided. Fails if the
/// teacher's replay of the prefix is not the recorded rollout.
pub fn unperturbed_reports(
    case: &Case<'_>,
    p: &ValidateParams,
    cost: &mut Cost,
) -> Result<Vec<CandidateReport>> {
    let r = case.rollout;
    let start = r.osw.start;
    let base = prefix(case, None, cost);
    let recorded = base.record();
    let k = start.min(r.record.steps);
    let n = k * N_ACTION;
    if recorded.steps != k
        || recorded.intended[..n] != r.record.intended[..n]
        || recorded.executed[..n] != r.record.executed[..n]
    {
        return Err(Error::ReplayDiverged {
            item: r.item,
            until: format!("the window's start (step {start})"),
        });
    }
    let snapshot = base.snapshot();
    let mut base = (base, snapshot);
    Ok(case
        .candidates
        .iter()
        .map(|c| {
            let (success, f_max) = branch(case, &mut base, &c.zeta, cost);
            CandidateReport {
                unperturbed: unperturbed(success, f_max, c.deviation, p),
                deviation: c.deviation,
                distance: distance(c),
                robustness: Robustness::NotRun,
            }
        })
        .collect())
}

/// The shared prefixes, early stopping and Alg. 1's order.
fn fast<'c>(
    case: &Case<'c>,
    p: &ValidateParams,
    item: &mut ValidationItem,
    cost: &mut Cost,
) -> Result<()> {
    let r = case.rollout;
    let j_org = p.j_org(item.original.success, item.original.max_force_n);
    item.candidates = unperturbed_reports(case, p, cost)?;
    if !item
        .candidates
        .iter()
        .any(|c| needs_sr(c.unperturbed, j_org))
    {
        return Ok(());
    }

    // Perturbed: one prefix per q, shared by ζ_org and every candidate.
    let mut branches: Vec<_> = (0..p.q)
        .map(|q| {
            let run = prefix(case, Some(case.perturbed(q)), cost);
            let snapshot = run.snapshot();
            (run, snapshot)
        })
        .collect();
    let needed = threshold(&mut item.original, p, |q| {
        branch(case, &mut branches[q], &r.osw.zeta_org, cost).0
    });
    for (c, report) in case.candidates.iter().zip(item.candidates.iter_mut()) {
        if needs_sr(report.unperturbed, j_org) {
            report.robustness = tally(p.q, needed, |q| {
                branch(case, &mut branches[q], &c.zeta, cost).0
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tally_stops_once_the_threshold_is_out_of_reach() {
        let outcomes = [true, false, false, true, false, true, true, true];
        let q = outcomes.len();
        let mut asked = 0;
        let r = tally(q, 6, |m| {
            asked += 1;
            outcomes[m]
        });
        // After three rollouts (one success) at most 1 + 5 = 6 remain possible; after the
        // fifth (two successes) at most 2 + 3 = 5 < 6.
        assert_eq!(
            r,
            Robustness::Insufficient {
                successes: 2,
                evaluated: 5
            }
        );
        assert_eq!(asked, 5);
        assert_eq!(
            tally(q, 5, |m| outcomes[m]),
            Robustness::Full { successes: 5 }
        );
        assert_eq!(
            tally(q, 0, |m| outcomes[m]),
            Robustness::Full { successes: 5 }
        );
        // Nothing can reach Q + 1.
        assert_eq!(
            tally(q, q as u32 + 1, |_| unreachable!()),
            Robustness::Insufficient {
                successes: 0,
                evaluated: 0
            }
        );
    }

    #[test]
    fn repair_needs_the_fewest_successes_at_delta() {
        let p = ValidateParams::default();
        assert_eq!(p.repair_successes(), 12);
        let p = ValidateParams {
            q: 10,
            delta_sr: 0.75,
            ..ValidateParams::default()
        };
        assert_eq!(p.repair_successes(), 8);
        let p = ValidateParams {
            delta_sr: 0.0,
            ..ValidateParams::default()
        };
        assert_eq!(p.repair_successes(), 0);
    }

    #[test]
    fn a_refinement_must_beat_j_org_before_it_is_perturbed() {
        let ok = Unperturbed::Succeeded {
            max_force_n: 10.0,
            j: 1.0,
        };
        assert!(needs_sr(ok, Some(2.0)));
        assert!(!needs_sr(ok, Some(1.0)));
        assert!(needs_sr(ok, None));
        assert!(!needs_sr(Unperturbed::Failed, None));
    }
}
