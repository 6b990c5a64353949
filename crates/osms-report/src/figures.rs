//! The paper's figures as stages whose artifacts are the figure data: (a) impact profiles,
//! (b, c) performance across task conditions, (e) the IOS profile and (f) learning curves.

use std::collections::BTreeMap;

use osms_method::artifacts::{IosProfile, Validation};
use osms_policy::artifacts::StudentArtifact;
use osms_policy::artifacts::Teacher;
use osms_sim::artifacts::{EvalRow, Evaluation, ImpactTrace};
use osms_sim::spec::ObjectVariant;

use crate::plot::{Figure, Mark, Panel, Point, Series, Style};
use osms_core::stats::MeanSd;

/// Mean ± one sample sd across rollouts at each offset from the contact step, for one signal.
fn profile(rows: &[&EvalRow], signal: impl Fn((f32, f32, f32)) -> f32, name: &str) -> Series {
    let mut points = Vec::new();
    let from = -(ImpactTrace::BEFORE as i32);
    for offset in from..=ImpactTrace::AFTER as i32 {
        let v: Vec<f64> = rows
            .iter()
            .filter_map(|r| r.trace.as_ref()?.at(offset))
            .map(|s| f64::from(signal(s)))
            .collect();
        // A band needs a spread: at least two rollouts still running at this offset.
        if let Some(MeanSd {
            mean, sd: Some(sd), ..
        }) = MeanSd::of(&v)
        {
            points.push(Point {
                x: f64::from(offset),
                y: mean,
                band: Some((mean - sd, mean + sd)),
                highlight: false,
            });
        }
    }
    Series {
        name: name.into(),
        mark: Mark::Line,
        points,
        style: Style::default(),
    }
}

/// The rows with a trace: rollouts in which the hand touched the object.
fn traced<'a>(evals: &[&'a Evaluation]) -> Vec<&'a EvalRow> {
    evals
        .iter()
        .flat_map(|e| e.rows.iter())
        .filter(|r| r.trace.is_some())
        .collect()
}

const SIGNALS: [(&str, &str); 3] = [
    ("(a) aggregate normal force", "force (N)"),
    ("(b) object–palm relative speed", "speed (m/s)"),
    (
        "(c) object velocity along the incoming direction",
        "velocity (m/s)",
    ),
];

fn profile_panels(group: &str, policies: &[(&str, Vec<&EvalRow>)]) -> Vec<Panel> {
    SIGNALS
        .iter()
        .enumerate()
        .map(|(k, (title, unit))| Panel {
            title: format!("{group}: {title}"),
            x_label: "control steps from the contact step (20 ms)".into(),
            y_label: (*unit).into(),
            x_categories: vec![],
            x_marker: Some(0.0),
            x_range: None,
            series: policies
                .iter()
                .map(|(name, rows)| {
                    profile(
                        rows,
                        |s| match k {
                            0 => s.0,
                            1 => s.1,
                            _ => s.2,
                        },
                        name,
                    )
                })
                .collect(),
        })
        .collect()
}

fn pooled(evals: &[Evaluation]) -> Vec<&Evaluation> {
    evals.iter().collect()
}

/// Figure (a): impact profiles aligned at t_c.
pub fn impact_profiles(
    catch_only: &Evaluation,
    teacher: &Evaluation,
    students: [&[Evaluation]; 3],
) -> Figure {
    let left = [
        ("catching-only RL", traced(&[catch_only])),
        ("RL teacher", traced(&[teacher])),
    ];
    let right = [
        ("RL teacher", traced(&[teacher])),
        ("Naive-IL", traced(&pooled(students[0]))),
        ("Normal-IL", traced(&pooled(students[1]))),
        ("Ours-IL", traced(&pooled(students[2]))),
    ];
    let count = |v: &[(&str, Vec<&EvalRow>)]| {
        v.iter()
            .map(|(n, r)| format!("{n} {}", r.len()))
            .collect::<Vec<_>>()
            .join(", ")
    };
    Figure {
        id: "fig_impact_profiles".into(),
        title: "Impact-mitigation profiles aligned at t_c".into(),
        caption: format!(
            "Top: catching-only RL vs the impact-mitigating RL teacher; bottom: the RL teacher vs \
             the final students (rollouts of all run seeds pooled). Each held-out rollout in \
             which the hand touched the object contributes its per-control-step signals; lines \
             are means, bands ± one sample sd across rollouts at each step; the dashed line is \
             the contact step (the step holding t_c). Force is the step's largest summed \
             admissible normal force; speeds are at the step's start. Rollouts: {}; {}.",
            count(&left),
            count(&right)
        ),
        panels: [
            profile_panels("catching-only vs teacher", &left),
            profile_panels("teacher vs students", &right),
        ]
        .concat(),
    }
}

fn success_rate<'a>(rows: impl Iterator<Item = &'a EvalRow>) -> Option<f64> {
    let (mut n, mut s) = (0usize, 0usize);
    for r in rows {
        n += 1;
        s += usize::from(r.outcome.success());
    }
    (n > 0).then(|| s as f64 / n as f64)
}

/// Bins of absolute lateral target offset for figure (c).
pub const OFFSET_BINS: usize = 5;

/// The upper edge of the absolute lateral offsets (the bins split [0, edge] evenly).
fn offset_edge(evals: &[&Evaluation]) -> f64 {
    evals
        .iter()
        .flat_map(|e| e.rows.iter())
        .map(|r| r.lateral_offset_m.abs())
        .fold(0.0, f64::max)
}

fn bin_of(offset: f64, edge: f64) -> usize {
    if edge <= 0.0 {
        return 0;
    }
    ((offset.abs() / edge * OFFSET_BINS as f64) as usize).min(OFFSET_BINS - 1)
}

/// Success per offset bin of one evaluation.
fn by_offset(eval: &Evaluation, edge: f64) -> Vec<Option<f64>> {
    (0..OFFSET_BINS)
        .map(|b| {
            success_rate(
                eval.rows
                    .iter()
                    .filter(|r| bin_of(r.lateral_offset_m, edge) == b),
            )
        })
        .collect()
}

/// A series over the offset bins: one evaluation, or the seeds' mean with ± one sd.
fn offset_series(name: &str, evals: &[&Evaluation], edge: f64) -> Series {
    let per: Vec<Vec<Option<f64>>> = evals.iter().map(|e| by_offset(e, edge)).collect();
    let width = edge / OFFSET_BINS as f64;
    let points = (0..OFFSET_BINS)
        .filter_map(|b| {
            let v: Vec<f64> = per.iter().filter_map(|p| p[b]).collect();
            let m = MeanSd::of(&v)?;
            Some(Point {
                x: (b as f64 + 0.5) * width,
                y: m.mean,
                band: m.sd.map(|sd| (m.mean - sd, m.mean + sd)),
                highlight: false,
            })
        })
        .collect();
    Series {
        name: name.into(),
        mark: Mark::Line,
        points,
        style: Style::default(),
    }
}

/// Figures (b) and (c): teacher success per object family × size, Ours-IL's gain over the
/// teacher, and every policy's success against the absolute lateral target offset.
pub fn task_conditions(teacher: &Evaluation, students: [&[Evaluation]; 3]) -> Figure {
    let variants = ObjectVariant::all();
    // Short enough for ten labels under one panel: `box L`, `sph S`, ….
    let names: Vec<String> = variants
        .iter()
        .map(|v| {
            let (family, size) = (v.family.name(), v.size.name());
            format!(
                "{} {}",
                &family[..family.len().min(3)],
                size.chars().next().unwrap_or('?').to_ascii_uppercase()
            )
        })
        .collect();
    let of_variant =
        |e: &Evaluation, v: ObjectVariant| success_rate(e.rows.iter().filter(|r| r.variant == v));
    let teacher_bars = Series {
        name: "RL teacher".into(),
        mark: Mark::Bars,
        points: variants
            .iter()
            .enumerate()
            .filter_map(|(i, &v)| Some(Point::new(i as f64, of_variant(teacher, v)?)))
            .collect(),
        style: Style::default(),
    };
    let ours = pooled(students[2]);
    let gain = Series {
        name: "Ours-IL − teacher".into(),
        mark: Mark::Bars,
        points: variants
            .iter()
            .enumerate()
            .filter_map(|(i, &v)| {
                let t = of_variant(teacher, v)?;
                let g: Vec<f64> = ours
                    .iter()
                    .filter_map(|e| of_variant(e, v))
                    .map(|s| 100.0 * (s - t))
                    .collect();
                let m = MeanSd::of(&g)?;
                Some(Point {
                    band: m.sd.map(|sd| (m.mean - sd, m.mean + sd)),
                    ..Point::new(i as f64, m.mean)
                })
            })
            .collect(),
        style: Style::default(),
    };
    let all: Vec<&Evaluation> = std::iter::once(teacher)
        .chain(students.iter().flat_map(|s| s.iter()))
        .collect();
    let edge = offset_edge(&all);
    let offsets = vec![
        offset_series("RL teacher", &[teacher], edge),
        offset_series("Naive-IL", &pooled(students[0]), edge),
        offset_series("Normal-IL", &pooled(students[1]), edge),
        offset_series("Ours-IL", &ours, edge),
    ];
    Figure {
        id: "fig_task_conditions".into(),
        title: "Performance across task conditions".into(),
        caption: format!(
            "(a) RL teacher task success by object family and size; (b) Ours-IL's gain over the \
             RL teacher in percentage points (mean over run seeds; the CSV's low/high hold ± one \
             sd). Object variants are family (box, sphere, ellipsoid, cylinder, capsule) and \
             size (L large, S small); (c) task success against the absolute lateral target offset in {OFFSET_BINS} \
             equal bins up to {edge:.3} m (students: mean ± one sd over run seeds). All on the \
             held-out conditions."
        ),
        panels: vec![
            Panel {
                title: "(a) RL teacher success".into(),
                x_label: String::new(),
                y_label: "task success".into(),
                x_categories: names.clone(),
                x_marker: None,
                x_range: None,
                series: vec![teacher_bars],
            },
            Panel {
                title: "(b) Ours-IL gain over the teacher".into(),
                x_label: String::new(),
                y_label: "percentage points".into(),
                x_categories: names,
                x_marker: None,
                x_range: None,
                series: vec![gain],
            },
            Panel {
                title: "(c) success vs lateral offset".into(),
                x_label: "absolute lateral target offset (m)".into(),
                y_label: "task success".into(),
                x_categories: vec![],
                x_marker: None,
                x_range: None,
                series: offsets,
            },
        ],
    }
}

/// Figure (e): S_IOS per window offset with its 95 % interval.
pub fn ios_figure(profile: &IosProfile) -> Figure {
    let rows = profile.rows();
    let points = rows
        .iter()
        .filter(|r| r.n > 0)
        .map(|r| Point {
            x: r.offset as f64,
            y: r.sensitivity,
            band: Some((r.ci_low, r.ci_high)),
            highlight: r.offset == -8,
        })
        .collect();
    Figure {
        id: "fig_ios_profile".into(),
        title: "Interventional outcome sensitivity around k_e (Eq. 1)".into(),
        caption: format!(
            "S_IOS of an 8-step arm window starting k_e + offset, with 95 % intervals; the \
             filled marker is the paper's OSW (offset −8). {} D_R rollouts, {} draws of ‖Δζ‖ = \
             {} per offset (`osms show ios_profile`).",
            profile.params.rollouts, profile.params.draws, profile.params.size
        ),
        panels: vec![Panel {
            title: "S_IOS by window offset".into(),
            x_label: "window start − k_e (control steps)".into(),
            y_label: "S_IOS".into(),
            x_categories: vec![],
            x_marker: Some(0.0),
            x_range: None,
            series: vec![Series {
                name: "S_IOS".into(),
                mark: Mark::Points,
                points,
                style: Style::default(),
            }],
        }],
    }
}

/// Mean ± sd over seeds of a per-step curve, on the steps every seed logged.
fn seed_curve(name: &str, curves: &[Vec<(f64, f64)>]) -> Series {
    let mut at: BTreeMap<u64, Vec<f64>> = BTreeMap::new();
    for c in curves {
        for &(x, y) in c {
            at.entry(x as u64).or_default().push(y);
        }
    }
    let points = at
        .into_iter()
        .filter(|(_, v)| v.len() == curves.len())
        .filter_map(|(x, v)| {
            let m = MeanSd::of(&v)?;
            Some(Point {
                x: x as f64,
                y: m.mean,
                band: m.sd.map(|sd| (m.mean - sd, m.mean + sd)),
                highlight: false,
            })
        })
        .collect();
    Series {
        name: name.into(),
        mark: Mark::Line,
        points,
        style: Style::default(),
    }
}

/// Figure (f): the teachers' PPO curves and the final students' flow-matching curves.
pub fn learning_curves(
    teachers: [(&str, &Teacher); 2],
    students: [(&str, &[StudentArtifact]); 3],
) -> Figure {
    let teacher_series = |f: fn(&osms_policy::ppo::IterationStats) -> f64| -> Vec<Series> {
        teachers
            .iter()
            .map(|(name, t)| Series {
                name: (*name).into(),
                mark: Mark::Line,
                points: t
                    .agent
                    .curve
                    .iter()
                    .map(|c| Point::new(f64::from(c.iteration), f(c)))
                    .collect(),
                style: Style::default(),
            })
            .collect()
    };
    let student_series = |validation: bool| -> Vec<Series> {
        students
            .iter()
            .map(|(name, seeds)| {
                let curves: Vec<Vec<(f64, f64)>> = seeds
                    .iter()
                    .map(|s| {
                        s.student
                            .curve
                            .iter()
                            .filter_map(|c| {
                                let y = if validation {
                                    c.validation_loss?
                                } else {
                                    c.train_loss
                                };
                                Some((f64::from(c.step), f64::from(y)))
                            })
                            .collect()
                    })
                    .collect();
                seed_curve(name, &curves)
            })
            .collect()
    };
    Figure {
        id: "fig_learning_curves".into(),
        title: "Learning curves".into(),
        caption: "(1, 2) Both PPO teachers' training success rate and mean return per \
                  iteration (training episodes, under training DR). (3, 4) The final students' \
                  flow-matching loss per element of the standardised action chunk, on training \
                  batches and on the held-out demonstrations, mean ± one sd over run seeds."
            .into(),
        panels: vec![
            Panel {
                title: "(1) teachers: training success".into(),
                x_label: "PPO iteration".into(),
                y_label: "success rate".into(),
                x_categories: vec![],
                x_marker: None,
                x_range: None,
                series: teacher_series(|c| c.success_rate),
            },
            Panel {
                title: "(2) teachers: mean return".into(),
                x_label: "PPO iteration".into(),
                y_label: "return".into(),
                x_categories: vec![],
                x_marker: None,
                x_range: None,
                series: teacher_series(|c| c.mean_return),
            },
            Panel {
                title: "(3) students: training loss".into(),
                x_label: "gradient step".into(),
                y_label: "flow-matching loss".into(),
                x_categories: vec![],
                x_marker: None,
                x_range: None,
                series: student_series(false),
            },
            Panel {
                title: "(4) students: validation loss".into(),
                x_label: "gradient step".into(),
                y_label: "flow-matching loss".into(),
                x_categories: vec![],
                x_marker: None,
                x_range: None,
                series: student_series(true),
            },
        ],
    }
}

/// Figure (d): candidate selection, J against SR for the candidates of successful originals
/// (refinement) and failed ones (repair), the selected candidates highlighted.
pub fn candidate_selection(v: &Validation) -> Figure {
    use osms_method::validate::Robustness;
    let q = v.params.q;
    let threshold = v.params.delta_sr;
    let mut panels = Vec::new();
    let mut counts = Vec::new();
    for (refine, title) in [(true, "(a) refinement"), (false, "(b) repair")] {
        let mut known = Vec::new();
        let mut bounded = Vec::new();
        let mut originals = Vec::new();
        let (mut not_run, mut failed) = (0usize, 0usize);
        for item in v
            .items
            .iter()
            .filter(|i| i.validated && i.original.success == refine)
        {
            if let (Some(j), Some(sr)) = (item.original.j, item.original.robustness.sr(q)) {
                originals.push(Point::new(sr, j));
            }
            let selected = item.decision.selected();
            for (k, c) in item.candidates.iter().enumerate() {
                let Some(j) = c.unperturbed.j() else {
                    failed += 1;
                    continue;
                };
                match c.robustness {
                    Robustness::Full { successes } => known.push(Point {
                        highlight: selected == Some(k),
                        ..Point::new(f64::from(successes) / q as f64, j)
                    }),
                    // Every later rollout a success: the most SR could have been.
                    Robustness::Insufficient {
                        successes,
                        evaluated,
                    } => bounded.push(Point::new(
                        f64::from(successes + q as u32 - evaluated) / q as f64,
                        j,
                    )),
                    Robustness::NotRun => not_run += 1,
                }
            }
        }
        counts.push(format!(
            "{title}: {} candidates with SR from all Q rollouts ({} selected), {} stopped below \
             the threshold (drawn at their largest possible SR), {} not perturbed (the \
             decision did not need them), {} failed unperturbed",
            known.len(),
            known.iter().filter(|p| p.highlight).count(),
            bounded.len(),
            not_run,
            failed
        ));
        // Refinement needs SR ≥ SR_org, repair SR ≥ δ_SR: the fast path stops a candidate once
        // its own bar is out of reach.
        let bar = if refine { "SR_org" } else { "δ_SR" };
        let mut series = vec![
            Series {
                name: "SR from all Q rollouts (filled: selected)".into(),
                mark: Mark::Points,
                points: known,
                style: Style::default(),
            },
            Series {
                name: format!("stopped below {bar} (upper bound)"),
                mark: Mark::Points,
                points: bounded,
                style: Style::default(),
            },
        ];
        if refine {
            series.push(Series {
                name: "originals (SR_org, J_org)".into(),
                mark: Mark::Points,
                points: originals,
                style: Style::default(),
            });
        }
        panels.push(Panel {
            title: title.into(),
            x_label: "SR (Eq. 8)".into(),
            y_label: "J (Eq. 9)".into(),
            x_categories: vec![],
            x_marker: (!refine).then_some(threshold),
            x_range: Some((-0.02, 1.02)),
            series,
        });
    }
    Figure {
        id: "fig_candidate_selection".into(),
        title: "Student-aware candidate selection".into(),
        caption: format!(
            "J (Eq. 9, lower is better) against SR (Eq. 8) of every validated candidate that \
             succeeded unperturbed, under the {} error model with Q = {q}. A refinement needs \
             J < J_org and SR ≥ SR_org, a repair SR ≥ δ_SR = {threshold} (dashed line). The \
             fast path stops a candidate's perturbed rollouts once its bar is out of reach, so \
             SR is exact only where all Q ran. {}.",
            v.error_model,
            counts.join("; ")
        ),
        panels,
    }
}
