//! `osms exp plot`: metrics against a knob over experiments' points, as a figure (SVG and PNG)
//! beside the CSV of its numbers: a data curve (`--x d_e.n`), a regime map (`--x
//! validate.deviation_scale --by validate.kappa`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context as _, Result, bail};
use osms_core::stats::{MeanSd, normal_quantile, wilson_bounds};
use osms_core::table::{Unit, csv_field as field};
use osms_make::experiment;
use osms_report::plot::{Figure, Mark, Panel, Point, Series, Style};
use serde::Serialize;

use super::rows::{Row, point_spec, row_named, rows_of, unit_of};
use super::unknown_experiment;
use crate::cli::ExpPlotArgs;
use crate::commands::print_json;
use crate::context::Context;

/// What to draw, read from the command line.
#[derive(Debug, Clone)]
pub(super) struct PlotSpec {
    pub x: String,
    pub by: Option<String>,
    pub metrics: Vec<String>,
    pub id: String,
    pub title: String,
    /// `--label NAME=TEXT`: a target, metric or knob as the figure names it.
    pub labels: BTreeMap<String, String>,
}

impl PlotSpec {
    fn label<'a>(&'a self, name: &'a str) -> &'a str {
        self.labels.get(name).map_or(name, String::as_str)
    }
}

/// One drawn point: the rows that share its x (and `by`) value, pooled.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(super) struct PlotPoint {
    /// The knob's value, as the experiments recorded it.
    pub x: String,
    /// Mean over the values (one per run seed and point), in the metric's unit (percent for
    /// rates).
    pub y: f64,
    /// A rate's 95 % Wilson interval over the rollouts pooled across the values; another
    /// metric's mean ± sd over them (none from one value).
    pub low: Option<f64>,
    pub high: Option<f64>,
    /// Values behind the mean (run seeds × points sharing x).
    pub values: usize,
    /// Rollouts pooled into a rate's interval (0 for other metrics).
    pub rollouts: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub(super) struct PlotSeries {
    pub metric: String,
    /// The metric's column (`success (dev_student)` when the points have several targets)
    /// and, with `--by`, the knob's value.
    pub name: String,
    pub points: Vec<PlotPoint>,
    /// With `--by`, a color per column and a dash per value, so a stage's lines share a color.
    #[serde(skip)]
    pub style: Style,
}

/// The data of the figure: what `--json` prints and the CSV holds.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(super) struct PlotData {
    pub x: String,
    pub by: Option<String>,
    /// The x axis' categories in order.
    pub categories: Vec<String>,
    pub series: Vec<PlotSeries>,
}

pub(super) fn plot(ctx: &Context, args: &ExpPlotArgs) -> Result<ExitCode> {
    let store = ctx.store()?;
    let mut rows = Vec::new();
    for spec in &args.names {
        match point_spec(spec)? {
            (name, None) => {
                let exp = experiment::load(&store, name)?
                    .ok_or_else(|| unknown_experiment(&store, name))?;
                rows.extend(rows_of(ctx, &store, &exp, &args.metrics)?);
            }
            (_, Some(_)) => rows.push(row_named(ctx, &store, spec, &args.metrics)?),
        }
    }
    for r in &rows {
        for why in &r.unreadable {
            say!(ctx, "warning: {}: {why}", r.label());
        }
        if !r.failed.is_empty() {
            say!(
                ctx,
                "warning: {}: incomplete ({} failed), its metrics are partial",
                r.label(),
                r.failed.join(", ")
            );
        }
    }
    let spec = PlotSpec {
        x: args.x.clone(),
        by: args.by.clone(),
        metrics: args.metrics.clone(),
        id: args.id.clone().unwrap_or_else(|| {
            let first = args.names[0].replace('/', "-");
            format!("exp-{first}-{}", args.x)
        }),
        title: args
            .title
            .clone()
            .unwrap_or_else(|| format!("{} against {}", args.metrics.join(", "), args.x)),
        labels: labels(&args.label)?,
    };
    let data = plot_data(&rows, &spec)?;
    let figure = figure(&data, &spec, &args.names);
    let mut files = Vec::new();
    for (name, bytes) in [
        (format!("{}.svg", spec.id), figure.svg()?.into_bytes()),
        (format!("{}.png", spec.id), figure.png()?),
        (format!("{}.csv", spec.id), csv(&data).into_bytes()),
    ] {
        files.push(write_file(&args.out, &name, &bytes)?);
    }
    if args.json {
        print_json(&serde_json::json!({ "files": files, "plot": data }))?;
    } else {
        for f in &files {
            say!(ctx, "wrote {}", f.display());
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// Writes `dir/name` through a temporary sibling, so an interrupted write leaves the previous
/// file whole.
fn write_file(dir: &Path, name: &str, bytes: &[u8]) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join(name);
    let partial = dir.join(format!(".{name}.partial"));
    std::fs::write(&partial, bytes)
        .with_context(|| format!("cannot write {}", partial.display()))?;
    std::fs::rename(&partial, &path)
        .with_context(|| format!("cannot move {} to {}", partial.display(), path.display()))?;
    Ok(path)
}

/// `--label NAME=TEXT` flags as a map; a flag without `=` or with an empty side is an error
/// that quotes it.
fn labels(flags: &[String]) -> Result<BTreeMap<String, String>> {
    let mut out = BTreeMap::new();
    for flag in flags {
        match flag.split_once('=') {
            Some((name, text)) if !name.trim().is_empty() && !text.trim().is_empty() => {
                out.insert(name.trim().to_string(), text.trim().to_string());
            }
            _ => bail!(
                "--label `{flag}`: expected NAME=TEXT, NAME a target stage, metric or knob of the plot (e.g. `--label dev_student=Ours-IL` or `--label validate.kappa=κ`)"
            ),
        }
    }
    Ok(out)
}

/// The target stage in a metric's column name: `dev_student` in `success (dev_student)`.
fn target_of<'a>(column: &'a str, metric: &str) -> Option<&'a str> {
    column
        .strip_prefix(metric)?
        .strip_prefix(" (")?
        .strip_suffix(')')
}

/// Values in order: by number when every one is a number, else as first seen.
fn ordered(values: Vec<String>) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for v in values {
        if !out.contains(&v) {
            out.push(v);
        }
    }
    let numbers: Option<Vec<f64>> = out.iter().map(|v| v.parse::<f64>().ok()).collect();
    if let Some(n) = numbers {
        let mut pairs: Vec<(f64, String)> = n.into_iter().zip(out).collect();
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        out = pairs.into_iter().map(|(_, v)| v).collect();
    }
    out
}

/// The knob's value in `row`, or a clear error: which point lacks it and which knobs it has.
fn knob<'a>(row: &'a Row, name: &str, flag: &str) -> Result<&'a String> {
    row.params.get(name).ok_or_else(|| {
        let knobs: Vec<&str> = row.params.keys().map(String::as_str).collect();
        anyhow::anyhow!(
            "{}: {flag} `{name}` is not a knob of this point (its knobs: {})\nhint: a point that ran on the pipeline's value records no knob; run it again with `--set {name}=VALUE` (nothing new is built if pipeline.toml writes that value; a knob it leaves unset, like `validate.kappa`, keys the builds anew)",
            row.label(),
            if knobs.is_empty() {
                "none".to_string()
            } else {
                knobs.join(", ")
            }
        )
    })
}

/// Pools the rows into series: one per metric column and `by` value, a point per x value.
pub(super) fn plot_data(rows: &[Row], spec: &PlotSpec) -> Result<PlotData> {
    if rows.is_empty() {
        bail!("nothing to plot: the experiments have no points");
    }
    let mut xs = Vec::new();
    let mut bys = Vec::new();
    for r in rows {
        xs.push(knob(r, &spec.x, "--x")?.clone());
        if let Some(by) = &spec.by {
            bys.push(knob(r, by, "--by")?.clone());
        }
    }
    let categories = ordered(xs);
    let by_values = ordered(bys);
    #[derive(Default)]
    struct Pool {
        values: Vec<f64>,
        counts: (u64, u64),
    }
    let mut series = Vec::new();
    let mut named: Vec<String> = vec![spec.x.clone()];
    named.extend(spec.by.clone());
    named.extend(spec.metrics.iter().cloned());
    for metric in &spec.metrics {
        let mut columns: Vec<&String> = Vec::new();
        for r in rows {
            for c in r.metrics.keys() {
                let matches = c == metric || c.starts_with(&format!("{metric} ("));
                if matches && !columns.contains(&c) {
                    columns.push(c);
                }
            }
        }
        if columns.is_empty() {
            bail!(
                "no point has the metric `{metric}`\nhint: `osms exp show NAME --metrics {metric}` shows what the targets' summaries hold (`osms show STAGE --json` lists their fields)"
            );
        }
        named.extend(
            columns
                .iter()
                .filter_map(|c| target_of(c, metric))
                .map(str::to_string),
        );
        let groups: Vec<Option<&String>> = if spec.by.is_some() {
            by_values.iter().map(Some).collect()
        } else {
            vec![None]
        };
        for (c, column) in columns.into_iter().enumerate() {
            let percent = unit_of(column) == Unit::Percent;
            for (dash, group) in groups.iter().enumerate() {
                let mut pools: BTreeMap<usize, Pool> = BTreeMap::new();
                for r in rows {
                    if let (Some(by), Some(g)) = (&spec.by, group)
                        && r.params.get(by) != Some(*g)
                    {
                        continue;
                    }
                    let Some(values) = r.metrics.get(column) else {
                        continue;
                    };
                    // Every row has x (checked above), so every row finds its category.
                    let Some(k) = r
                        .params
                        .get(&spec.x)
                        .and_then(|x| categories.iter().position(|c| c == x))
                    else {
                        continue;
                    };
                    let pool = pools.entry(k).or_default();
                    pool.values.extend(values);
                    if let Some(&(s, n)) = r.counts.get(column) {
                        pool.counts.0 += s;
                        pool.counts.1 += n;
                    }
                }
                if pools.is_empty() {
                    continue;
                }
                let scale = if percent { 100.0 } else { 1.0 };
                let points = pools
                    .into_iter()
                    .filter_map(|(k, pool)| {
                        let m = MeanSd::of(&pool.values)?;
                        let (s, n) = pool.counts;
                        let band = if percent && n > 0 {
                            wilson_bounds(s as usize, n as usize, normal_quantile(0.975))
                        } else {
                            m.sd.map(|sd| (m.mean - sd, m.mean + sd))
                        };
                        Some(PlotPoint {
                            x: categories[k].clone(),
                            y: scale * m.mean,
                            low: band.map(|b| scale * b.0),
                            high: band.map(|b| scale * b.1),
                            values: m.n,
                            rollouts: if percent { n } else { 0 },
                        })
                    })
                    .collect();
                let base = match target_of(column, metric).and_then(|t| spec.labels.get(t)) {
                    Some(label) => label.clone(),
                    None => format!("{}{}", spec.label(metric), &column[metric.len()..]),
                };
                let (name, style) = match (&spec.by, group) {
                    (Some(by), Some(v)) => (
                        format!("{base}, {}={v}", spec.label(by)),
                        Style {
                            color: Some(c),
                            dash,
                        },
                    ),
                    _ => (base, Style::default()),
                };
                series.push(PlotSeries {
                    metric: metric.clone(),
                    name,
                    points,
                    style,
                });
            }
        }
    }
    if let Some(unknown) = spec.labels.keys().find(|k| !named.contains(k)) {
        named.sort();
        named.dedup();
        bail!(
            "--label `{unknown}=…`: `{unknown}` is not a target, metric or knob of this plot (it names: {})",
            named.join(", ")
        );
    }
    Ok(PlotData {
        x: spec.x.clone(),
        by: spec.by.clone(),
        categories,
        series,
    })
}

/// One panel per metric, the x axis categorical (data sizes and scales are read as steps,
/// not distances).
pub(super) fn figure(data: &PlotData, spec: &PlotSpec, names: &[String]) -> Figure {
    let panels = spec
        .metrics
        .iter()
        .map(|metric| {
            let percent = unit_of(metric) == Unit::Percent;
            let series = data
                .series
                .iter()
                .filter(|s| &s.metric == metric)
                .map(|s| Series {
                    style: s.style,
                    name: s.name.clone(),
                    mark: if data.categories.len() > 1 {
                        Mark::Line
                    } else {
                        Mark::Points
                    },
                    points: s
                        .points
                        .iter()
                        .map(|p| Point {
                            x: data.categories.iter().position(|c| *c == p.x).unwrap_or(0) as f64,
                            y: p.y,
                            band: p.low.zip(p.high),
                            highlight: true,
                        })
                        .collect(),
                })
                .collect();
            let title = spec.label(metric).to_string();
            Panel {
                x_label: spec.label(&data.x).to_string(),
                y_label: if percent {
                    format!("{title} (%)")
                } else {
                    title.clone()
                },
                title,
                x_categories: data.categories.clone(),
                x_marker: None,
                x_range: None,
                series,
            }
        })
        .collect();
    Figure {
        id: spec.id.clone(),
        title: spec.title.clone(),
        caption: format!(
            "Experiments {}: each point the mean over its run seeds and the points sharing its {}; rates with their 95 % Wilson interval over the rollouts pooled across those (rollout noise only), other metrics mean ± sd.",
            names.join(", "),
            data.x
        ),
        panels,
    }
}

/// `metric,series,x,y,low,high,values,rollouts`, a line per point.
pub(super) fn csv(data: &PlotData) -> String {
    let opt = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
    let mut out = String::from("metric,series,x,y,low,high,values,rollouts\n");
    for s in &data.series {
        for p in &s.points {
            out.push_str(&format!(
                "{},{},{},{},{},{},{},{}\n",
                field(&s.metric),
                field(&s.name),
                field(&p.x),
                p.y,
                opt(p.low),
                opt(p.high),
                p.values,
                p.rollouts
            ));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::super::rows::tests::row;
    use super::*;

    fn spec(x: &str, by: Option<&str>, metrics: &[&str]) -> PlotSpec {
        PlotSpec {
            x: x.into(),
            by: by.map(Into::into),
            metrics: metrics.iter().map(|m| m.to_string()).collect(),
            id: "fig".into(),
            title: "t".into(),
            labels: BTreeMap::new(),
        }
    }

    /// Points that share x pool their seeds and rollouts; categories sort by number, not text.
    #[test]
    fn points_sharing_a_value_pool_and_numbers_sort_as_numbers() {
        let mut a = row(Some(0), &[("d_e.n", "2000")], &[("success", &[0.5, 0.7])]);
        a.counts.insert("success".into(), (120, 200));
        let mut b = row(Some(0), &[("d_e.n", "500")], &[("success", &[0.4])]);
        b.counts.insert("success".into(), (40, 100));
        let mut c = row(Some(1), &[("d_e.n", "500")], &[("success", &[0.6])]);
        c.counts.insert("success".into(), (60, 100));
        let data = plot_data(&[a, b, c], &spec("d_e.n", None, &["success"])).expect("data");
        assert_eq!(data.categories, ["500", "2000"]);
        assert_eq!(data.series.len(), 1);
        let p = &data.series[0].points;
        assert_eq!(
            (p[0].x.as_str(), p[0].values, p[0].rollouts),
            ("500", 2, 200)
        );
        assert!((p[0].y - 50.0).abs() < 1e-9);
        // Wilson 95 % of 100 of 200: 43.1–56.9 %.
        let (lo, hi) = (p[0].low.expect("low"), p[0].high.expect("high"));
        assert!(
            (lo - 43.13).abs() < 0.01 && (hi - 56.87).abs() < 0.01,
            "{lo} {hi}"
        );
        assert!((p[1].y - 60.0).abs() < 1e-9 && p[1].rollouts == 200);
        let csv = csv(&data);
        assert!(
            csv.starts_with("metric,series,x,y,low,high,values,rollouts\n"),
            "{csv}"
        );
        assert_eq!(csv.lines().count(), 3, "{csv}");
    }

    /// `--by` splits each column into a series per value; a non-rate gets mean ± sd.
    #[test]
    fn by_splits_the_series_and_other_metrics_get_their_spread() {
        let rows = [
            row(
                Some(0),
                &[("v.scale", "0.5"), ("v.kappa", "1")],
                &[("demonstrations (dstar)", &[10.0, 14.0])],
            ),
            row(
                Some(1),
                &[("v.scale", "0.5"), ("v.kappa", "1.5")],
                &[("demonstrations (dstar)", &[8.0])],
            ),
        ];
        let data = plot_data(
            &rows,
            &spec("v.scale", Some("v.kappa"), &["demonstrations"]),
        )
        .expect("data");
        let names: Vec<&str> = data.series.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "demonstrations (dstar), v.kappa=1",
                "demonstrations (dstar), v.kappa=1.5"
            ]
        );
        let p = &data.series[0].points[0];
        let sd = 8f64.sqrt();
        assert!((p.y - 12.0).abs() < 1e-9);
        assert!((p.low.expect("low") - (12.0 - sd)).abs() < 1e-9);
        assert_eq!(data.series[1].points[0].low, None, "one value: no spread");
        let f = figure(
            &data,
            &spec("v.scale", Some("v.kappa"), &["demonstrations"]),
            &[],
        );
        assert_eq!(f.panels.len(), 1);
        assert_eq!(f.panels[0].series.len(), 2);
        assert_eq!(f.panels[0].series[0].mark, Mark::Points, "one category");
    }

    /// `--label` names targets, metrics and knobs in series, titles and axes; with `--by` a
    /// column keeps its color across values and each value gets its dash.
    #[test]
    fn labels_name_the_series_and_by_values_share_a_color_per_target() {
        let rows = [
            row(
                Some(0),
                &[("v.scale", "0.5"), ("v.kappa", "1")],
                &[
                    ("success (dev_student)", &[0.4]),
                    ("success (dev_student_dart)", &[0.8]),
                ],
            ),
            row(
                Some(0),
                &[("v.scale", "0.5"), ("v.kappa", "1.5")],
                &[
                    ("success (dev_student)", &[0.5]),
                    ("success (dev_student_dart)", &[0.7]),
                ],
            ),
        ];
        let mut s = spec("v.scale", Some("v.kappa"), &["success"]);
        s.labels = labels(&[
            "dev_student=Ours-IL".into(),
            "v.kappa=κ".into(),
            "v.scale = deviation scale".into(),
        ])
        .expect("labels");
        let data = plot_data(&rows, &s).expect("data");
        let named: Vec<(&str, Style)> = data
            .series
            .iter()
            .map(|x| (x.name.as_str(), x.style))
            .collect();
        let style = |color, dash| Style {
            color: Some(color),
            dash,
        };
        assert_eq!(
            named,
            [
                ("Ours-IL, κ=1", style(0, 0)),
                ("Ours-IL, κ=1.5", style(0, 1)),
                ("success (dev_student_dart), κ=1", style(1, 0)),
                ("success (dev_student_dart), κ=1.5", style(1, 1)),
            ]
        );
        assert!(csv(&data).contains("success,\"Ours-IL, κ=1.5\",0.5,50,"));
        let f = figure(&data, &s, &[]);
        assert_eq!(f.panels[0].x_label, "deviation scale");
        assert_eq!(f.panels[0].series[1].style, style(0, 1));
        // Without --by every series is plain.
        let plain = plot_data(&rows, &spec("v.scale", None, &["success"])).expect("data");
        assert!(plain.series.iter().all(|x| x.style == Style::default()));

        s.labels = labels(&["dev_stduent=Ours-IL".into()]).expect("labels");
        let e = format!("{:#}", plot_data(&rows, &s).expect_err("a typo"));
        assert!(
            e.contains("`dev_stduent` is not a target, metric or knob of this plot")
                && e.contains("dev_student, dev_student_dart, success, v.kappa, v.scale"),
            "{e}"
        );
        let e = format!("{:#}", labels(&["Ours-IL".into()]).expect_err("no ="));
        assert!(e.contains("--label `Ours-IL`: expected NAME=TEXT"), "{e}");
        assert!(labels(&["dev_student=".into()]).is_err(), "an empty text");
    }

    #[test]
    fn a_point_without_the_knob_or_a_missing_metric_is_a_clear_error() {
        let rows = [row(Some(0), &[("a.b", "1")], &[("success", &[0.5])])];
        let e = plot_data(&rows, &spec("c.d", None, &["success"])).expect_err("an error");
        let e = format!("{e:#}");
        assert!(
            e.contains("e/0: --x `c.d` is not a knob of this point (its knobs: a.b)"),
            "{e}"
        );
        assert!(e.contains("--set c.d=VALUE"), "{e}");
        let e = plot_data(&rows, &spec("a.b", None, &["f_max"])).expect_err("an error");
        assert!(
            format!("{e}").contains("no point has the metric `f_max`"),
            "{e}"
        );
    }
}
