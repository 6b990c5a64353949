//! The claims check: each qualitative claim of the paper, and whether this run's tables bear
//! it out, with the seed spread. Verdicts compare means; the evidence gives the numbers and,
//! for comparisons of students, in how many run seeds the order holds (seed by seed).

use serde::{Deserialize, Serialize};

use crate::tables::{COVERAGE, POLICY_F_MAX, REPAIR_RATE, TABLE2_ROWS, TABLE3_ROWS, TASK_SUCCESS};
use osms_core::table::{Cell, Column, Layout, Table, Unit, Value, format_value};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    Holds,
    DoesNotHold,
    /// The tables this claim needs are not part of this report (e.g. the ablations).
    NotChecked,
}

impl Verdict {
    pub fn text(self) -> &'static str {
        match self {
            Verdict::Holds => "holds",
            Verdict::DoesNotHold => "does not hold",
            Verdict::NotChecked => "not checked",
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Claim {
    pub claim: String,
    pub verdict: Verdict,
    pub evidence: String,
}

const TEACHER: &str = TABLE2_ROWS[0];
const NAIVE: &str = TABLE2_ROWS[1];
const NORMAL: &str = TABLE2_ROWS[2];
const OURS: &str = TABLE2_ROWS[3];

fn short(row: &str) -> &str {
    row.rsplit(" / ").next().unwrap_or(row)
}

fn value<'t>(t: &'t Table, row: &str, column: &str) -> Option<&'t Value> {
    Some(&t.cell(row, column)?.ours)
}

fn mean(v: &Value) -> Option<f64> {
    v.stats().map(|s| s.mean)
}

fn unit(t: &Table, column: &str) -> Unit {
    t.columns
        .iter()
        .find(|c| c.name == column)
        .map_or(Unit::Number(3), |c| c.unit)
}

/// In how many seeds `a` beats `b` (lower or higher is better), pairing values by position
/// (both are in run-seed order); a single value is compared with every seed.
fn seeds_where(a: &Value, b: &Value, higher: bool) -> Option<(usize, usize)> {
    let list = |v: &Value| match v {
        Value::Seeds(s) => Some(s.clone()),
        Value::One(x) => Some(vec![*x]),
        Value::Missing | Value::Text(_) => None,
    };
    let (a, b) = (list(a)?, list(b)?);
    let n = a.len().max(b.len());
    let at = |v: &[f64], i: usize| if v.len() == 1 { v[0] } else { v[i] };
    if (a.len() != 1 && a.len() != n) || (b.len() != 1 && b.len() != n) {
        return None;
    }
    let wins = (0..n)
        .filter(|&i| {
            let (x, y) = (at(&a, i), at(&b, i));
            if higher { x > y } else { x < y }
        })
        .count();
    Some((wins, n))
}

fn verdict(holds: Option<bool>) -> Verdict {
    match holds {
        Some(true) => Verdict::Holds,
        Some(false) => Verdict::DoesNotHold,
        None => Verdict::NotChecked,
    }
}

/// "`a` is higher (or lower) than `b` in `column`".
fn compare(t: &Table, a: &str, b: &str, column: &str, higher: bool, claim: &str) -> Claim {
    let u = unit(t, column);
    let (va, vb) = (value(t, a, column), value(t, b, column));
    let (holds, evidence) = match (va, vb) {
        (Some(va), Some(vb)) => match (mean(va), mean(vb)) {
            (Some(ma), Some(mb)) => {
                let by_seed = matches!(va, Value::Seeds(_)) || matches!(vb, Value::Seeds(_));
                let seeds = seeds_where(va, vb, higher)
                    .filter(|_| by_seed)
                    .map(|(w, n)| format!("; in {w} of {n} run seeds"))
                    .unwrap_or_default();
                (
                    Some(if higher { ma > mb } else { ma < mb }),
                    format!(
                        "{column}: {} {} vs {} {}{seeds}",
                        short(a),
                        format_value(va, u),
                        short(b),
                        format_value(vb, u)
                    ),
                )
            }
            _ => (
                None,
                format!("{column}: no value for {} or {}", short(a), short(b)),
            ),
        },
        _ => (None, format!("table {} lacks `{column}`", t.id)),
    };
    Claim {
        claim: claim.into(),
        verdict: verdict(holds),
        evidence,
    }
}

/// "`row` has the lowest (or highest) `column` among `rows`".
fn extreme(t: &Table, row: &str, rows: &[&str], column: &str, higher: bool, claim: &str) -> Claim {
    let u = unit(t, column);
    let values: Vec<(&str, Option<&Value>)> =
        rows.iter().map(|r| (*r, value(t, r, column))).collect();
    let means: Vec<(&str, Option<f64>)> =
        values.iter().map(|(r, v)| (*r, v.and_then(mean))).collect();
    // A competitor without a value cannot be ranked: the claim is then not checked.
    let holds = means
        .iter()
        .map(|(_, m)| *m)
        .collect::<Option<Vec<f64>>>()
        .and_then(|_| {
            let m = means.iter().find(|(r, _)| *r == row)?.1?;
            Some(
                means
                    .iter()
                    .filter(|(r, _)| *r != row)
                    .all(|(_, o)| o.is_some_and(|o| if higher { m > o } else { m < o })),
            )
        });
    let evidence = values
        .iter()
        .map(|(r, v)| {
            format!(
                "{} {}",
                short(r),
                v.map_or_else(|| "-".into(), |v| format_value(v, u))
            )
        })
        .collect::<Vec<_>>()
        .join(", ");
    Claim {
        claim: claim.into(),
        verdict: verdict(holds),
        evidence: format!("{column}: {evidence}"),
    }
}

/// The claims of the default report, from Table II and Table III.
pub fn check(table2: &Table, table3: &Table) -> Vec<Claim> {
    let policies = [TEACHER, NAIVE, NORMAL, OURS];
    let students = [NAIVE, NORMAL, OURS];
    let mut claims = vec![
        compare(
            table2,
            OURS,
            TEACHER,
            TASK_SUCCESS,
            true,
            "Ours-IL succeeds more often than the RL teacher",
        ),
        compare(
            table2,
            OURS,
            NAIVE,
            TASK_SUCCESS,
            true,
            "Ours-IL succeeds more often than Naive-IL",
        ),
        compare(
            table2,
            OURS,
            NORMAL,
            TASK_SUCCESS,
            true,
            "Ours-IL succeeds more often than Normal-IL",
        ),
        extreme(
            table2,
            OURS,
            &policies,
            POLICY_F_MAX,
            false,
            "Ours-IL has the lowest policy f_max (teacher and students)",
        ),
        extreme(
            table2,
            NORMAL,
            &students,
            COVERAGE,
            true,
            "Unperturbed-only validation (Normal) has the highest demonstration coverage",
        ),
    ];
    let normal_best = extreme(table2, NORMAL, &students, TASK_SUCCESS, true, "");
    claims.push(Claim {
        claim: "Normal-IL is not the best student despite that coverage".into(),
        verdict: match normal_best.verdict {
            Verdict::Holds => Verdict::DoesNotHold,
            Verdict::DoesNotHold => Verdict::Holds,
            Verdict::NotChecked => Verdict::NotChecked,
        },
        evidence: normal_best.evidence,
    });
    claims.push(compare(
        table2,
        NORMAL,
        NAIVE,
        TASK_SUCCESS,
        false,
        "Normal-IL trails Naive-IL",
    ));
    let [unperturbed, global, independent, correlated] = TABLE3_ROWS;
    claims.push(extreme(
        table3,
        correlated,
        &TABLE3_ROWS,
        "π_θ task success",
        true,
        "The full (phase-wise correlated) error model gives the most successful student",
    ));
    claims.push(compare(
        table3,
        independent,
        global,
        "moment err.",
        false,
        "Phase conditioning improves moment matching (phase-wise independent below global i.i.d.)",
    ));
    claims.push(extreme(
        table3,
        correlated,
        &[global, independent, correlated],
        "lag-1 err.",
        false,
        "Temporal correlation gives the lowest lag-1 error",
    ));
    claims.push(compare(
        table3,
        unperturbed,
        correlated,
        REPAIR_RATE,
        true,
        "Unperturbed-only validation repairs more than the full model (a lower repair rate for a better student)",
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
    ] {
        claims.push(Claim {
            claim: claim.into(),
            verdict: Verdict::NotChecked,
            evidence: why.into(),
        });
    }
    claims
}

/// The claims as a Markdown table.
pub fn markdown(claims: &[Claim]) -> String {
    let mut t = Table::new(
        "claims",
        "Claims check",
        vec![
            Column::new("in this run", Unit::Text),
            Column::new("evidence", Unit::Text),
        ],
    );
    for c in claims {
        t.push(
            &c.claim,
            vec![Cell::text(c.verdict.text()), Cell::text(&c.evidence)],
        );
    }
    t.markdown_with(Layout::plain("claim (paper)"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use osms_core::table::{Cell, Column, Row};

    fn t2(ours: Vec<f64>, naive: Vec<f64>) -> Table {
        let cols = [
            (TASK_SUCCESS, Unit::Percent),
            (POLICY_F_MAX, Unit::Number(1)),
            (COVERAGE, Unit::Percent),
        ];
        let row = |label: &str, s: Value, f: Value, c: Value| Row {
            label: label.into(),
            cells: vec![Cell::new(s, None), Cell::new(f, None), Cell::new(c, None)],
        };
        Table {
            id: "table2".into(),
            title: String::new(),
            columns: cols
                .iter()
                .map(|(n, u)| Column {
                    name: (*n).into(),
                    unit: *u,
                })
                .collect(),
            rows: vec![
                row(TEACHER, Value::One(0.5), Value::One(40.0), Value::Missing),
                row(
                    NAIVE,
                    Value::Seeds(naive),
                    Value::Seeds(vec![38.0, 39.0]),
                    Value::One(0.5),
                ),
                row(
                    NORMAL,
                    Value::Seeds(vec![0.40, 0.41]),
                    Value::Seeds(vec![30.0, 31.0]),
                    Value::One(0.7),
                ),
                row(
                    OURS,
                    Value::Seeds(ours),
                    Value::Seeds(vec![35.0, 36.0]),
                    Value::One(0.5),
                ),
            ],
            notes: vec![],
        }
    }

    #[test]
    fn comparisons_report_means_and_seed_counts() {
        let t = t2(vec![0.52, 0.47], vec![0.45, 0.50]);
        let c = compare(&t, OURS, TEACHER, TASK_SUCCESS, true, "x");
        // Mean 0.495 < 0.5: does not hold, though one seed beats the teacher.
        assert_eq!(c.verdict, Verdict::DoesNotHold);
        assert!(
            c.evidence.ends_with("in 1 of 2 run seeds"),
            "{}",
            c.evidence
        );
        let c = compare(&t, OURS, NAIVE, TASK_SUCCESS, true, "x");
        assert_eq!(c.verdict, Verdict::Holds);
        assert!(
            c.evidence
                .contains("Ours-IL 49.5% ± 3.5% vs Naive-IL 47.5% ± 3.5%"),
            "{}",
            c.evidence
        );
        let f = extreme(
            &t,
            OURS,
            &[TEACHER, NAIVE, NORMAL, OURS],
            POLICY_F_MAX,
            false,
            "x",
        );
        assert_eq!(f.verdict, Verdict::DoesNotHold, "{}", f.evidence);
        let cov = extreme(&t, NORMAL, &[NAIVE, NORMAL, OURS], COVERAGE, true, "x");
        assert_eq!(cov.verdict, Verdict::Holds);
    }

    #[test]
    fn a_missing_column_is_not_checked() {
        let t = t2(vec![0.5], vec![0.4]);
        let c = compare(&t, OURS, NAIVE, "lag-1 err.", false, "x");
        assert_eq!(c.verdict, Verdict::NotChecked);
    }
}
