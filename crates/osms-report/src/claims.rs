//! The claims check: each qualitative claim of the paper, decided by 95 % confidence intervals
//! on differences between this run's policies (docs/report.md, "Claims check").
//!
//! Success is compared rollout by rollout on the same held-out conditions, over the run seeds
//! ([`paired_difference`]); f_max over catch completions, which differ between policies, without
//! pairing ([`unpaired_difference`]); demonstration coverage and repair as two proportions
//! ([`proportion_difference`]). A claim **holds** when its interval excludes 0 in the paper's
//! direction, is **contradicted** when it excludes 0 the other way and is **unresolved** when it
//! spans 0; each says the smallest difference this run could have resolved.

use serde::{Deserialize, Serialize};

use crate::tables::TABLE3_ROWS;
use osms_core::stats::{
    Decision, Difference, Method, bootstrap_difference, paired_difference, proportion_difference,
    unpaired_difference,
};
use osms_core::table::{Cell, Column, Layout, Table, Unit};
use osms_method::error_model::{ErrorVariant, Table3Bootstrap, Table3Metrics};
use osms_policy::artifacts::ConstructionStats;
use osms_sim::artifacts::Evaluation;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Every interval behind the claim excludes 0 in the paper's direction.
    Holds,
    /// An interval excludes 0 against the paper.
    Contradicted,
    /// The intervals span 0: this run cannot tell.
    Unresolved,
    /// The data this claim needs are not part of this report (e.g. the ablations).
    NotChecked,
}

impl Verdict {
    pub fn text(self) -> &'static str {
        match self {
            Verdict::Holds => "holds",
            Verdict::Contradicted => "contradicted",
            Verdict::Unresolved => "unresolved",
            Verdict::NotChecked => "not checked",
        }
    }
}

impl From<Decision> for Verdict {
    fn from(d: Decision) -> Self {
        match d {
            Decision::Holds => Verdict::Holds,
            Decision::Contradicted => Verdict::Contradicted,
            Decision::Unresolved => Verdict::Unresolved,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Claim {
    pub claim: String,
    pub verdict: Verdict,
    pub evidence: String,
    /// The differences behind the verdict (none for claims checked by means or not checked).
    #[serde(default)]
    pub comparisons: Vec<Comparison>,
}

/// `a − b` in one metric, with its interval.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Comparison {
    pub a: String,
    pub b: String,
    pub metric: String,
    pub unit: Unit,
    pub difference: Difference,
    /// The paper's difference between the same two rows (success only).
    #[serde(default)]
    pub paper: Option<f64>,
    /// Run seeds per student at which the paper's difference would be resolved on this many
    /// conditions, with this run's variance components (`None`: not within
    /// [`MAX_SEEDS`], or not a paired difference).
    #[serde(default)]
    pub seeds_for_paper: Option<usize>,
}

/// The largest seed count [`Comparison::seeds_for_paper`] looks at.
pub const MAX_SEEDS: usize = 100;

/// The paper's task success per row (Tables II and III).
fn paper_success(row: &str) -> Option<f64> {
    let [unperturbed, global, independent, correlated] = TABLE3_ROWS;
    [
        (TEACHER, 0.852),
        (NAIVE, 0.838),
        (NORMAL, 0.817),
        (OURS, 0.903),
        (unperturbed, 0.817),
        (global, 0.822),
        (independent, 0.868),
        (correlated, 0.903),
    ]
    .iter()
    .find(|(r, _)| *r == row)
    .map(|(_, v)| *v)
}

impl Comparison {
    /// `+2.1 pts [−1.0, +5.2]` (percentage points for rates).
    pub fn text(&self) -> String {
        let d = &self.difference;
        format!(
            "{} − {}: {} [{}, {}]",
            self.a,
            self.b,
            signed(d.estimate, self.unit),
            signed(d.low, self.unit),
            signed(d.high, self.unit)
        )
    }

    fn resolvable(&self) -> String {
        magnitude(self.difference.resolvable, self.unit)
    }
}

fn signed(x: f64, unit: Unit) -> String {
    let sign = if x < 0.0 { "−" } else { "+" };
    format!("{sign}{}", magnitude(x.abs(), unit))
}

/// Rates in percentage points, forces (one decimal) in newtons, fit metrics as numbers.
fn magnitude(x: f64, unit: Unit) -> String {
    match unit {
        Unit::Percent => format!("{:.1} pts", 100.0 * x),
        Unit::Number(1) => format!("{x:.1} N"),
        Unit::Number(d) => format!("{x:.*}", usize::from(d)),
        _ => format!("{x}"),
    }
}

/// What the claims check reads: every policy's per-rollout evaluations, the construction
/// statistics and Table III's fit metrics with their bootstrap.
pub struct ClaimData<'a> {
    pub teacher: &'a Evaluation,
    pub naive: &'a [Evaluation],
    pub normal: &'a [Evaluation],
    pub ours: &'a [Evaluation],
    pub global_iid: &'a [Evaluation],
    pub phase_independent: &'a [Evaluation],
    /// Naive, Normal and ours (D_*), in that order.
    pub stats: [&'a ConstructionStats; 3],
    /// The fitted models' Table III metrics on the held-out D_E rollouts and on resamples of
    /// them, in [`FITTED`]'s order.
    pub fits: &'a Table3Bootstrap,
    /// The held-out D_E rollouts behind `fits`.
    pub fit_rollouts: usize,
}

/// Table III's fitted models' rows, in the order of [`ClaimData::fits`].
pub const FITTED: [&str; 3] = [TABLE3_ROWS[1], TABLE3_ROWS[2], TABLE3_ROWS[3]];
/// The models behind [`FITTED`]'s rows.
pub const FITTED_VARIANTS: [ErrorVariant; 3] = [
    ErrorVariant::GlobalIid,
    ErrorVariant::PhaseIndependent,
    ErrorVariant::PhaseCorrelated,
];

const TEACHER: &str = "RL teacher";
const NAIVE: &str = "Naive-IL";
const NORMAL: &str = "Normal-IL";
const OURS: &str = "Ours-IL";
const SUCCESS: &str = "task success";
const F_MAX: &str = "policy f_max";

/// Per seed, per condition: 1 for a success.
fn successes(evals: &[Evaluation]) -> Vec<Vec<f64>> {
    evals
        .iter()
        .map(|e| {
            e.rows
                .iter()
                .map(|r| f64::from(u8::from(r.outcome.success())))
                .collect()
        })
        .collect()
}

/// Per seed: f_max of every catch completion.
fn forces(evals: &[Evaluation]) -> Vec<Vec<f64>> {
    evals
        .iter()
        .map(|e| {
            e.rows
                .iter()
                .filter(|r| r.outcome.completion())
                .map(|r| r.metrics.max_force_n)
                .collect()
        })
        .collect()
}

/// A policy's name and its per-rollout values, read once from its evaluations.
#[derive(Clone)]
pub(crate) struct Policy<'a> {
    pub(crate) name: &'a str,
    success: Vec<Vec<f64>>,
    force: Vec<Vec<f64>>,
}

impl<'a> Policy<'a> {
    pub(crate) fn of(name: &'a str, evals: &[Evaluation]) -> Self {
        Policy {
            name,
            success: successes(evals),
            force: forces(evals),
        }
    }

    /// The same rollouts under another row's name (Table III's rows are Table II's students).
    fn named(&self, name: &'a str) -> Self {
        Policy {
            name,
            ..self.clone()
        }
    }
}

fn success_comparison(a: &Policy<'_>, b: &Policy<'_>) -> Option<Comparison> {
    let paper = paper_success(a.name)
        .zip(paper_success(b.name))
        .map(|(x, y)| x - y);
    success_comparison_with(a, b, paper)
}

/// The paired success difference `a − b`, next to the paper's difference between the same rows.
pub(crate) fn success_comparison_with(
    a: &Policy<'_>,
    b: &Policy<'_>,
    paper: Option<f64>,
) -> Option<Comparison> {
    let difference = paired_difference(&a.success, &b.success)?;
    let seeds_for_paper = paper
        .zip(difference.parts)
        .and_then(|(p, parts)| parts.seeds_to_resolve(p, difference.n[0], MAX_SEEDS));
    Some(Comparison {
        a: a.name.into(),
        b: b.name.into(),
        metric: SUCCESS.into(),
        unit: Unit::Percent,
        difference,
        paper,
        seeds_for_paper,
    })
}

pub(crate) fn force_comparison(a: &Policy<'_>, b: &Policy<'_>) -> Option<Comparison> {
    Some(Comparison {
        a: a.name.into(),
        b: b.name.into(),
        metric: F_MAX.into(),
        unit: Unit::Number(1),
        difference: unpaired_difference(&a.force, &b.force)?,
        paper: None,
        seeds_for_paper: None,
    })
}

/// A claim that holds when every comparison's interval favours `a_higher`, is contradicted
/// when any goes against it, and is unresolved otherwise.
pub(crate) fn all_of(claim: &str, comparisons: Vec<Option<Comparison>>, a_higher: bool) -> Claim {
    decided(claim, comparisons, a_higher, true)
}

/// A claim that holds when some comparison's interval favours `a_higher`, is contradicted
/// when every one goes against it, and is unresolved otherwise.
fn any_of(claim: &str, comparisons: Vec<Option<Comparison>>, a_higher: bool) -> Claim {
    decided(claim, comparisons, a_higher, false)
}

/// The verdict over several comparisons: `every` one must favour the claim (and any one
/// contradicts it), or any one suffices (and every one must go against it).
fn decided(
    claim: &str,
    comparisons: Vec<Option<Comparison>>,
    a_higher: bool,
    every: bool,
) -> Claim {
    let Some(comparisons) = comparisons.into_iter().collect::<Option<Vec<_>>>() else {
        return Claim {
            claim: claim.into(),
            verdict: Verdict::NotChecked,
            evidence: "an evaluation has no value to compare (no catch completion, or \
                       different held-out condition counts)"
                .into(),
            comparisons: vec![],
        };
    };
    let decisions: Vec<Decision> = comparisons
        .iter()
        .map(|c| c.difference.decide(a_higher))
        .collect();
    let (favour, against) = (Decision::Holds, Decision::Contradicted);
    let (holds, contradicted) = if every {
        (
            decisions.iter().all(|d| *d == favour),
            decisions.contains(&against),
        )
    } else {
        (
            decisions.contains(&favour),
            decisions.iter().all(|d| *d == against),
        )
    };
    let verdict = if holds {
        Verdict::Holds
    } else if contradicted {
        Verdict::Contradicted
    } else {
        Verdict::Unresolved
    };
    Claim {
        claim: claim.into(),
        verdict,
        evidence: evidence(&comparisons),
        comparisons,
    }
}

fn evidence(comparisons: &[Comparison]) -> String {
    comparisons
        .iter()
        .map(|c| {
            let d = &c.difference;
            let spread = match (d.seeds, d.method) {
                (_, Method::Proportions) => {
                    format!("{} vs {} conditions", d.n[0], d.n[1])
                }
                ([sa, sb], Method::Paired) => {
                    format!("{} paired conditions, {sa} vs {sb} run seed(s)", d.n[0])
                }
                ([sa, sb], Method::Unpaired) => format!(
                    "{} vs {} catch completions, {sa} vs {sb} run seed(s)",
                    d.n[0], d.n[1]
                ),
                (_, Method::Bootstrap) => {
                    format!("{} held-out D_E rollouts resampled, fits fixed", d.n[0])
                }
            };
            format!("{} ({spread})", c.metric)
        })
        .collect::<Vec<_>>()
        .join("; ")
}

fn count(fraction: f64, of: usize) -> usize {
    (fraction * of as f64).round() as usize
}

fn coverage(s: &ConstructionStats, name: &str) -> (String, usize, usize) {
    (name.into(), count(s.coverage, s.conditions), s.conditions)
}

pub(crate) fn proportion(
    claim_metric: &str,
    a: &(String, usize, usize),
    b: &(String, usize, usize),
) -> Option<Comparison> {
    Some(Comparison {
        a: a.0.clone(),
        b: b.0.clone(),
        metric: claim_metric.into(),
        unit: Unit::Percent,
        difference: proportion_difference(a.1, a.2, b.1, b.2)?,
        paper: None,
        seeds_for_paper: None,
    })
}

/// A Table III fit metric of the fitted model `a` against each of `others` (indices into
/// [`FITTED`]): the differences on the held-out D_E rollouts with percentile intervals over
/// the bootstrap resamples of those rollouts (the fits held fixed; docs/report.md). The claim
/// is that `a`'s error is lower than every other's.
fn fit_metric(
    d: &ClaimData<'_>,
    a: usize,
    others: &[usize],
    column: &str,
    metric: fn(&Table3Metrics) -> f64,
    claim: &str,
) -> Claim {
    let comparisons = others
        .iter()
        .map(|&b| {
            let (fa, fb) = (d.fits.full.get(a)?, d.fits.full.get(b)?);
            let replicates = d
                .fits
                .resamples
                .iter()
                .map(|r| Some(metric(r.get(a)?) - metric(r.get(b)?)))
                .collect::<Option<Vec<f64>>>()?;
            Some(Comparison {
                a: FITTED[a].into(),
                b: FITTED[b].into(),
                metric: column.into(),
                unit: Unit::Number(3),
                difference: bootstrap_difference(
                    metric(fa) - metric(fb),
                    &replicates,
                    d.fit_rollouts,
                )?,
                paper: None,
                seeds_for_paper: None,
            })
        })
        .collect();
    all_of(claim, comparisons, false)
}

/// The claims of the default report.
pub fn check(d: &ClaimData<'_>) -> Vec<Claim> {
    let teacher = Policy::of(TEACHER, std::slice::from_ref(d.teacher));
    let naive = Policy::of(NAIVE, d.naive);
    let normal = Policy::of(NORMAL, d.normal);
    let ours = Policy::of(OURS, d.ours);
    let [unperturbed, global, independent, correlated] = TABLE3_ROWS;
    let global_iid = Policy::of(global, d.global_iid);
    let phase_independent = Policy::of(independent, d.phase_independent);
    let t3_unperturbed = normal.named(unperturbed);
    let t3_correlated = ours.named(correlated);
    let [s_naive, s_normal, s_ours] = d.stats;
    let cov = [
        coverage(s_naive, NAIVE),
        coverage(s_normal, NORMAL),
        coverage(s_ours, OURS),
    ];
    let failed = |s: &ConstructionStats| s.conditions.saturating_sub(s.original_successes);
    let repair = |s: &ConstructionStats, name: &str| (name.to_string(), s.repaired, failed(s));
    let mut claims = vec![
        all_of(
            "Ours-IL succeeds more often than the RL teacher",
            vec![success_comparison(&ours, &teacher)],
            true,
        ),
        all_of(
            "Ours-IL succeeds more often than Naive-IL",
            vec![success_comparison(&ours, &naive)],
            true,
        ),
        all_of(
            "Ours-IL succeeds more often than Normal-IL",
            vec![success_comparison(&ours, &normal)],
            true,
        ),
        all_of(
            "Ours-IL has the lowest policy f_max (teacher and students)",
            [&teacher, &naive, &normal]
                .iter()
                .map(|p| force_comparison(&ours, p))
                .collect(),
            false,
        ),
        all_of(
            "Unperturbed-only validation (Normal) has the highest demonstration coverage",
            vec![
                proportion("demo coverage", &cov[1], &cov[0]),
                proportion("demo coverage", &cov[1], &cov[2]),
            ],
            true,
        ),
    ];
    // Normal-IL is not the best student: some other student beats it.
    claims.push(any_of(
        "Normal-IL is not the best student despite that coverage",
        [&naive, &ours]
            .iter()
            .map(|p| success_comparison(p, &normal))
            .collect(),
        true,
    ));
    claims.push(all_of(
        "Normal-IL trails Naive-IL",
        vec![success_comparison(&normal, &naive)],
        false,
    ));
    claims.push(all_of(
        "The full (phase-wise correlated) error model gives the most successful student",
        [&t3_unperturbed, &global_iid, &phase_independent]
            .iter()
            .map(|p| success_comparison(&t3_correlated, p))
            .collect(),
        true,
    ));
    let [fit_global, fit_independent, fit_correlated] = [0, 1, 2];
    claims.push(fit_metric(
        d,
        fit_independent,
        &[fit_global],
        "moment err.",
        |m| m.moment_error,
        "Phase conditioning improves moment matching (phase-wise independent below global i.i.d.)",
    ));
    claims.push(fit_metric(
        d,
        fit_correlated,
        &[fit_global, fit_independent],
        "lag-1 err.",
        |m| m.lag1_error,
        "Temporal correlation gives the lowest lag-1 error",
    ));
    claims.push(all_of(
        "Unperturbed-only validation repairs more than the full model (a lower repair rate for a better student)",
        vec![proportion(
            "repair rate",
            &repair(s_normal, unperturbed),
            &repair(s_ours, correlated),
        )],
        true,
    ));
    for (claim, why) in [
        (
            "Refinement mainly lowers force, repair mainly adds success",
            "needs the refine-only / repair-only ablation: `osms make ablations`",
        ),
        (
            "Candidate generation: geodesic > Euclidean > unconditional > direct",
            "needs the candidate-generation ablation: `osms make ablations`",
        ),
        (
            "Beyond the paper: Ours-IL succeeds more often than DART-IL and than DAgger-IL (1 and 3 rounds)",
            "needs the standard baselines: `osms make baselines` decides it in baselines/index.md",
        ),
    ] {
        claims.push(Claim {
            claim: claim.into(),
            verdict: Verdict::NotChecked,
            evidence: why.into(),
            comparisons: vec![],
        });
    }
    claims
}

/// For every success comparison whose claim this run left unresolved: the paper's difference
/// and the run seeds per student that would resolve it on the same conditions, with this
/// run's variance components (docs/report.md, "What would decide").
pub fn sizes_markdown(claims: &[Claim]) -> String {
    let mut t = Table::new(
        "claims_sizes",
        "What would decide the unresolved claims",
        vec![
            Column::new("ours", Unit::Text),
            Column::new("resolvable now", Unit::Text),
            Column::new("paper's difference", Unit::Text),
            Column::new("paper's difference in our 95 % CI", Unit::Text),
            Column::new("seeds per student to resolve it", Unit::Text),
        ],
    );
    for c in claims.iter().filter(|c| c.verdict == Verdict::Unresolved) {
        for x in c.comparisons.iter().filter(|x| x.paper.is_some()) {
            let d = &x.difference;
            t.push(
                format!("{} − {} ({})", x.a, x.b, c.claim),
                vec![
                    Cell::text(signed(d.estimate, x.unit)),
                    Cell::text(format!("± {}", magnitude(d.resolvable, x.unit))),
                    Cell::text(x.paper.map_or_else(|| "-".into(), |p| signed(p, x.unit))),
                    Cell::text(x.paper.map_or("-", |p| {
                        // Outside: this run already tells the paper's effect apart, so more
                        // seeds would not be expected to confirm it.
                        if (d.low..=d.high).contains(&p) {
                            "yes"
                        } else {
                            "no: excluded"
                        }
                    })),
                    Cell::text(x.seeds_for_paper.map_or_else(
                        || format!("more than {MAX_SEEDS} at {} conditions", d.n[0]),
                        |s| format!("{s} at {} conditions", d.n[0]),
                    )),
                ],
            );
        }
    }
    if t.rows.is_empty() {
        return String::new();
    }
    t.markdown_with(Layout::plain("comparison"))
}

/// The claims as a Markdown table.
pub fn markdown(claims: &[Claim]) -> String {
    let mut t = Table::new(
        "claims",
        "Claims check",
        vec![
            Column::new("in this run", Unit::Text),
            Column::new("difference [95 % CI]", Unit::Text),
            Column::new("resolvable", Unit::Text),
            Column::new("evidence", Unit::Text),
        ],
    );
    for c in claims {
        let join = |f: &dyn Fn(&Comparison) -> String| {
            if c.comparisons.is_empty() {
                "-".to_string()
            } else {
                c.comparisons.iter().map(f).collect::<Vec<_>>().join("; ")
            }
        };
        t.push(
            &c.claim,
            vec![
                Cell::text(c.verdict.text()),
                Cell::text(join(&Comparison::text)),
                Cell::text(join(&|x: &Comparison| format!("≥ {}", x.resolvable()))),
                Cell::text(&c.evidence),
            ],
        );
    }
    t.markdown_with(Layout::plain("claim (paper)"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tables::testing::{scrambled as policy, stats};

    /// A comparison whose interval is [low, high].
    fn comparison(low: f64, high: f64) -> Option<Comparison> {
        Some(Comparison {
            a: "a".into(),
            b: "b".into(),
            metric: SUCCESS.into(),
            unit: Unit::Percent,
            difference: osms_core::stats::Difference {
                estimate: 0.5 * (low + high),
                low,
                high,
                resolvable: 0.5 * (high - low),
                df: None,
                seeds: [1, 1],
                n: [10, 10],
                method: osms_core::stats::Method::Proportions,
                parts: None,
            },
            paper: None,
            seeds_for_paper: None,
        })
    }

    /// `all_of` needs every interval in favour and is contradicted by any one against;
    /// `any_of` needs one in favour and is contradicted only when every one is against; a
    /// missing comparison leaves either unchecked. Mixed verdicts, for a claim that `a` is
    /// higher.
    #[test]
    fn all_of_and_any_of_with_mixed_verdicts() {
        let holds = || comparison(0.1, 0.3);
        let against = || comparison(-0.3, -0.1);
        let open = || comparison(-0.1, 0.1);
        for (comparisons, all, any) in [
            (vec![holds(), holds()], Verdict::Holds, Verdict::Holds),
            (vec![holds(), open()], Verdict::Unresolved, Verdict::Holds),
            (
                vec![holds(), against()],
                Verdict::Contradicted,
                Verdict::Holds,
            ),
            (
                vec![open(), against()],
                Verdict::Contradicted,
                Verdict::Unresolved,
            ),
            (
                vec![against(), against()],
                Verdict::Contradicted,
                Verdict::Contradicted,
            ),
            (
                vec![open(), open()],
                Verdict::Unresolved,
                Verdict::Unresolved,
            ),
            (
                vec![holds(), None],
                Verdict::NotChecked,
                Verdict::NotChecked,
            ),
        ] {
            let shown: Vec<String> = comparisons
                .iter()
                .map(|c| {
                    format!(
                        "{:?}",
                        c.as_ref().map(|c| (c.difference.low, c.difference.high))
                    )
                })
                .collect();
            assert_eq!(
                all_of("c", comparisons.clone(), true).verdict,
                all,
                "all_of {shown:?}"
            );
            assert_eq!(
                any_of("c", comparisons, true).verdict,
                any,
                "any_of {shown:?}"
            );
        }
        // In the other direction the roles swap.
        assert_eq!(
            all_of("c", vec![against(), against()], false).verdict,
            Verdict::Holds
        );
    }

    fn verdict_of(claims: &[Claim], prefix: &str) -> Verdict {
        claims
            .iter()
            .find(|c| c.claim.starts_with(prefix))
            .map(|c| c.verdict)
            .expect(prefix)
    }

    /// Fit metrics of global i.i.d., phase-wise independent and phase-wise correlated, on
    /// the full sample and on 400 resamples that jitter each model by `jitter` (sd).
    fn fits(moment: [f64; 3], lag1: [f64; 3], jitter: f64) -> Table3Bootstrap {
        let metrics = |m: f64, l: f64| Table3Metrics {
            moment_error: m,
            lag1_error: l,
            moment_cells: 10,
            lag1_cells: 10,
        };
        let mut rng = osms_core::rng::stream(3, "claims", "fits", 0);
        let mut draw = |x: f64| x + jitter * osms_core::rng::normal(&mut rng);
        Table3Bootstrap {
            full: (0..3).map(|i| metrics(moment[i], lag1[i])).collect(),
            resamples: (0..400)
                .map(|_| {
                    (0..3)
                        .map(|i| metrics(draw(moment[i]), draw(lag1[i])))
                        .collect()
                })
                .collect(),
        }
    }

    #[test]
    fn intervals_decide_the_verdicts_in_both_directions() {
        let n = 600;
        let teacher = policy(0.95, 1, n, 40.0).remove(0);
        let naive = policy(0.5, 3, n, 40.0);
        let normal = policy(0.5, 3, n, 40.0);
        let ours = policy(0.8, 3, n, 30.0);
        // Our run's Table III pattern: the independent model's moment error far below the
        // global one's, the correlated model's lag-1 error far below both; jitter 0.01.
        let f = fits([2.754, 0.066, 0.103], [0.812, 0.587, 0.042], 0.01);
        let s = stats(0.5, 0.5);
        let claims = check(&ClaimData {
            teacher: &teacher,
            naive: &naive,
            normal: &normal,
            ours: &ours,
            global_iid: &naive,
            phase_independent: &normal,
            stats: [&s, &s, &s],
            fits: &f,
            fit_rollouts: 500,
        });
        let verdict = |prefix: &str| {
            claims
                .iter()
                .find(|c| c.claim.starts_with(prefix))
                .map(|c| c.verdict)
                .expect(prefix)
        };
        // 80 % against the teacher's 95 %: the interval lies below 0.
        assert_eq!(
            verdict("Ours-IL succeeds more often than the RL teacher"),
            Verdict::Contradicted
        );
        assert_eq!(
            verdict("Ours-IL succeeds more often than Naive-IL"),
            Verdict::Holds
        );
        assert_eq!(
            verdict("Ours-IL has the lowest policy f_max"),
            Verdict::Holds
        );
        // The same success pattern: no difference to decide.
        assert_eq!(verdict("Normal-IL trails Naive-IL"), Verdict::Unresolved);
        assert_eq!(verdict("Normal-IL is not the best student"), Verdict::Holds);
        // Equal coverage counts.
        assert_eq!(
            verdict("Unperturbed-only validation (Normal) has the highest"),
            Verdict::Unresolved
        );
        assert_eq!(verdict("The full (phase-wise correlated)"), Verdict::Holds);
        assert_eq!(verdict("Phase conditioning"), Verdict::Holds);
        assert_eq!(verdict("Temporal correlation"), Verdict::Holds);
        let lag = claims
            .iter()
            .find(|c| c.claim.starts_with("Temporal correlation"))
            .expect("claim");
        assert_eq!(lag.comparisons.len(), 2);
        let x = &lag.comparisons[1].difference;
        assert!((x.estimate - (0.042 - 0.587)).abs() < 1e-12, "{x:?}");
        // Two jitters of sd 0.01: the difference's sd is 0.014, its 95 % half-width ≈ 0.028.
        assert!((0.02..0.036).contains(&x.resolvable), "{x:?}");
        assert_eq!(x.method, Method::Bootstrap);
        assert_eq!(x.n, [500, 500]);
        let ours_naive = &claims[1].comparisons[0];
        assert!(
            (ours_naive.difference.estimate - 0.3).abs() < 0.02,
            "{ours_naive:?}"
        );
        assert_eq!(ours_naive.difference.seeds, [3, 3]);
        assert_eq!(ours_naive.difference.n, [n, n]);
        let md = markdown(&claims);
        assert!(md.contains("| contradicted |"), "{md}");
        assert!(md.contains("Ours-IL − Naive-IL: +"), "{md}");
        assert!(md.contains("resolvable"), "{md}");
        // The unresolved "Normal-IL trails Naive-IL" (identical students here) gets a size.
        let trails = claims
            .iter()
            .find(|c| c.claim == "Normal-IL trails Naive-IL")
            .expect("claim");
        let x = &trails.comparisons[0];
        assert!((x.paper.expect("paper") + 0.021).abs() < 1e-9);
        let parts = x.difference.parts.expect("paired");
        match x.seeds_for_paper {
            Some(s) => assert!(parts.resolvable_with([s, s], n) <= 0.021),
            None => assert!(parts.resolvable_with([MAX_SEEDS, MAX_SEEDS], n) > 0.021),
        }
        let sizes = sizes_markdown(&claims);
        assert!(
            sizes.contains("Normal-IL − Naive-IL (Normal-IL trails Naive-IL)"),
            "{sizes}"
        );
        assert!(sizes.contains("at 600 conditions"), "{sizes}");
        let inside = (x.difference.low..=x.difference.high).contains(&-0.021);
        let row = sizes
            .lines()
            .find(|l| l.contains("(Normal-IL trails Naive-IL)"))
            .expect("row");
        assert!(
            row.contains(if inside {
                "| yes |"
            } else {
                "| no: excluded |"
            }),
            "{row}"
        );
    }

    #[test]
    fn evaluations_on_different_condition_sets_are_not_compared() {
        let teacher = policy(0.9, 1, 50, 40.0).remove(0);
        let students = policy(0.5, 2, 60, 40.0);
        // Fit metrics the other way round (the paper contradicted), and overlapping ones.
        let f = fits([0.1, 0.3, 0.2], [0.50, 0.51, 0.505], 0.05);
        let s = stats(0.5, 0.5);
        let data = ClaimData {
            teacher: &teacher,
            naive: &students,
            normal: &students,
            ours: &students,
            global_iid: &students,
            phase_independent: &students,
            stats: [&s, &s, &s],
            fits: &f,
            fit_rollouts: 50,
        };
        let claims = check(&data);
        assert_eq!(claims[0].verdict, Verdict::NotChecked, "{:?}", claims[0]);
        assert_eq!(claims[1].verdict, Verdict::Unresolved, "{:?}", claims[1]);
        assert_eq!(
            verdict_of(&claims, "Phase conditioning"),
            Verdict::Contradicted
        );
        assert_eq!(
            verdict_of(&claims, "Temporal correlation"),
            Verdict::Unresolved
        );
        // No resamples: nothing to decide by.
        let none = Table3Bootstrap {
            full: f.full.clone(),
            resamples: vec![],
        };
        let claims = check(&ClaimData {
            fits: &none,
            ..data
        });
        assert_eq!(
            verdict_of(&claims, "Phase conditioning"),
            Verdict::NotChecked
        );
    }
}
