//! Figures as data (what the store keeps and the CSV beside each picture holds) and their
//! rendering to SVG and PNG with `plotters`. Rendering happens on export, never inside an
//! artifact: the bytes a stage stores are the numbers, so a font or rasteriser change cannot
//! change a key.

use std::fmt::Write;
use std::ops::Range;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;
use serde::{Deserialize, Serialize};

use crate::glyphs::Baseline;
use crate::{Error, Result};

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Mark {
    /// A line; points with a band get a shaded band (e.g. mean ± one sd).
    Line,
    /// Markers; highlighted points are drawn larger and filled.
    Points,
    /// Bars from zero, grouped side by side with the panel's other bar series.
    Bars,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    /// (low, high) of a band or interval around y.
    pub band: Option<(f64, f64)>,
    pub highlight: bool,
}

impl Point {
    pub fn new(x: f64, y: f64) -> Point {
        Point {
            x,
            y,
            band: None,
            highlight: false,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Series {
    pub name: String,
    pub mark: Mark,
    pub points: Vec<Point>,
    /// How it looks: chosen where the figure is drawn and never stored (`serde(skip)`), so a
    /// figure in an artifact stays its numbers and its bytes do not change with a look.
    #[serde(skip)]
    pub style: Style,
}

/// A series' color and dash, for figures whose series come in families (a stage's line per
/// value of a knob: one color per stage, one dash per value).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Style {
    /// Index into the palette; `None`: the series' position in its panel.
    pub color: Option<usize>,
    /// 0 solid with filled markers; 1 dashed, 2 dotted, each with hollow markers (cycling).
    pub dash: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    /// Names of the integer x positions 0, 1, … for a categorical axis (empty: numeric).
    pub x_categories: Vec<String>,
    /// A dashed vertical line (e.g. t_c).
    pub x_marker: Option<f64>,
    /// A fixed x range (e.g. [0, 1] for a rate); absent: the data's.
    pub x_range: Option<(f64, f64)>,
    pub series: Vec<Series>,
}

/// A figure: panels side by side (three per row).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Figure {
    /// File stem of its exports, e.g. `fig_impact_profiles`.
    pub id: String,
    pub title: String,
    /// What the figure shows and how it was computed, for the report.
    pub caption: String,
    pub panels: Vec<Panel>,
}

const PANEL_W: u32 = 520;
const PANEL_H: u32 = 380;
const TITLE_H: u32 = 44;
const PER_ROW: usize = 3;

/// Dash patterns (on, off in pixels) by [`Style::dash`]: solid, dashed, dotted.
const DASHES: [Option<(u32, u32)>; 3] = [None, Some((8, 4)), Some((2, 3))];

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
];

static FONT: Once = Once::new();

/// Text is set in DejaVu Sans, shipped inside the binary, so a machine without system fonts
/// renders the same pictures.
fn register_font() {
    FONT.call_once(|| {
        for style in [FontStyle::Normal, FontStyle::Bold] {
            // The bytes are a valid font; a failure would only leave the default.
            let _ = plotters::style::register_font("sans-serif", style, dejavu::sans::regular());
        }
    });
}

impl Figure {
    /// Size in pixels of the rendered figure.
    pub fn size(&self) -> (u32, u32) {
        let n = self.panels.len().max(1);
        let cols = n.min(PER_ROW) as u32;
        let rows = n.div_ceil(PER_ROW) as u32;
        (cols * PANEL_W, TITLE_H + rows * PANEL_H)
    }

    /// The data, one line per point: `panel,series,x,y,low,high,highlight`.
    pub fn csv(&self) -> String {
        let mut out = String::from("panel,series,x,y,low,high,highlight\n");
        for p in &self.panels {
            for s in &p.series {
                for pt in &s.points {
                    let (lo, hi) = pt
                        .band
                        .map(|(l, h)| (l.to_string(), h.to_string()))
                        .unwrap_or_default();
                    let _ = writeln!(
                        out,
                        "{},{},{},{},{},{},{}",
                        field(&p.title),
                        field(&s.name),
                        pt.x,
                        pt.y,
                        lo,
                        hi,
                        pt.highlight
                    );
                }
            }
        }
        out
    }

    pub fn svg(&self) -> Result<String> {
        register_font();
        let mut s = String::new();
        {
            let root = SVGBackend::with_string(&mut s, self.size()).into_drawing_area();
            self.draw(&root).map_err(|e| self.draw_error(e))?;
            root.present().map_err(|e| self.draw_error(e))?;
        }
        Ok(s)
    }

    pub fn png(&self) -> Result<Vec<u8>> {
        register_font();
        let (w, h) = self.size();
        let mut rgb = vec![0u8; (w * h * 3) as usize];
        {
            let bitmap = BitMapBackend::with_buffer(&mut rgb, (w, h));
            let root = Baseline::new(bitmap)
                .ok_or_else(|| self.draw_error("the bundled DejaVu Sans does not parse"))?
                .into_drawing_area();
            self.draw(&root).map_err(|e| self.draw_error(e))?;
            root.present().map_err(|e| self.draw_error(e))?;
        }
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, w, h);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let png = |source| Error::Png {
                figure: self.id.clone(),
                source,
            };
            let mut writer = enc.write_header().map_err(png)?;
            writer.write_image_data(&rgb).map_err(png)?;
        }
        Ok(out)
    }

    /// `<id>.svg`, `<id>.png` and `<id>.csv`.
    pub fn files(&self) -> Result<Vec<(String, Vec<u8>)>> {
        Ok(vec![
            (format!("{}.svg", self.id), self.svg()?.into_bytes()),
            (format!("{}.png", self.id), self.png()?),
            (format!("{}.csv", self.id), self.csv().into_bytes()),
        ])
    }

    fn draw_error(&self, e: impl std::fmt::Display) -> Error {
        Error::Draw {
            figure: self.id.clone(),
            message: e.to_string(),
        }
    }

    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        root.fill(&WHITE)?;
        let (title, body) = root.split_vertically(TITLE_H);
        let (lines, size) = title_lines(&self.title, self.size().0 - 2 * TITLE_X_PX);
        let top = if lines.len() == 1 { 12 } else { 4 };
        for (i, line) in lines.iter().enumerate() {
            title.draw(&Text::new(
                line.clone(),
                (TITLE_X_PX as i32, top + i as i32 * (size as i32 + 3)),
                ("sans-serif", size).into_font(),
            ))?;
        }
        let n = self.panels.len().max(1);
        let cols = n.min(PER_ROW);
        let rows = n.div_ceil(PER_ROW);
        let areas = body.split_evenly((rows, cols));
        for (panel, area) in self.panels.iter().zip(areas) {
            draw_panel(panel, &area)?;
        }
        Ok(())
    }
}

/// Left margin of the figure's title, in pixels.
const TITLE_X_PX: u32 = 12;

/// Width in pixels of `text` in the title's font at `size`.
fn text_width(text: &str, size: u32) -> u32 {
    let font: TextStyle = ("sans-serif", size).into_font().into();
    let mut t = MultiLineText::<(i32, i32), &str>::new((0, 0), &font);
    t.push_line(text);
    t.estimate_dimension()
        .map(|(w, _)| u32::try_from(w).unwrap_or(0))
        .unwrap_or(u32::MAX)
}

/// The title's lines and font size: one line at the largest size from 20 px down to 13 that
/// fits `width`, else two lines split at the space that balances them, at the largest size from
/// 16 px down that fits (12 px at least): a long `--title` on a one-panel figure must not run
/// off the image.
fn title_lines(title: &str, width: u32) -> (Vec<String>, u32) {
    for size in (13..=20).rev() {
        if text_width(title, size) <= width {
            return (vec![title.to_string()], size);
        }
    }
    let split = title
        .match_indices(' ')
        .map(|(i, _)| (title[..i].trim_end(), title[i..].trim_start()))
        .min_by_key(|(a, b)| text_width(a, 12).abs_diff(text_width(b, 12)));
    let Some((a, b)) = split else {
        return (vec![title.to_string()], 12);
    };
    let size = (12..=16)
        .rev()
        .find(|&size| text_width(a, size).max(text_width(b, size)) <= width)
        .unwrap_or(12);
    (vec![a.to_string(), b.to_string()], size)
}

fn field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Data range with 5 % padding; a flat range gets a tenth of its value as width (a unit width
/// around 9,655 demonstrations would tick in hundredths), an empty or zero one a unit width.
fn padded(lo: f64, hi: f64) -> Range<f64> {
    if !(lo.is_finite() && hi.is_finite()) || lo > hi {
        return 0.0..1.0;
    }
    let span = if hi - lo > 1e-12 {
        hi - lo
    } else if hi.abs() > 1e-12 {
        0.1 * hi.abs()
    } else {
        1.0
    };
    (lo - 0.05 * span)..(hi + 0.05 * span)
}

/// A tick label: whole numbers without a fractional part ("800", not "800.0"), others with
/// at most six decimals and no trailing zeros (0.1 + 0.2 reads "0.3").
fn tick(v: f64) -> String {
    let text = format!("{v:.6}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    if text == "-0" {
        "0".to_string()
    } else {
        text.to_string()
    }
}

/// The chart's outer margin and its y-label strip, in pixels (`draw_panel`'s layout).
const MARGIN_PX: u32 = 10;
const Y_LABEL_PX: u32 = 56;
/// plotters' series-label box: the labels inside a 10 px margin, a 30 px legend swatch, placed
/// 5 px from the plot's top and right edges.
const LEGEND_MARGIN_PX: f64 = 10.0;
const LEGEND_SWATCH_PX: f64 = 30.0;
const LEGEND_OFFSET_PX: f64 = 5.0;
/// Clearance kept between the legend box and a marker's centre (the largest marker's radius
/// and a pixel).
const MARKER_PX: f64 = 6.0;

/// Width and height in pixels of the legend box plotters draws for these labels.
fn legend_box(labels: &[&str]) -> Option<(f64, f64)> {
    if labels.is_empty() {
        return None;
    }
    let font: TextStyle = ("sans-serif", 11).into_font().into();
    let mut text = MultiLineText::<(i32, i32), &str>::new((0, 0), &font);
    for l in labels {
        text.push_line(*l);
    }
    let (w, h) = text.estimate_dimension().ok()?;
    Some((
        f64::from(w) + LEGEND_SWATCH_PX + 2.0 * LEGEND_MARGIN_PX,
        f64::from(h) + 2.0 * LEGEND_MARGIN_PX,
    ))
}

/// The corners a legend tries, in order: plotters' usual top right first.
const CORNERS: [SeriesLabelPosition; 4] = [
    SeriesLabelPosition::UpperRight,
    SeriesLabelPosition::UpperLeft,
    SeriesLabelPosition::LowerRight,
    SeriesLabelPosition::LowerLeft,
];

/// Whether any point, or the end of its band, falls under the legend box in `corner` of the
/// plot (`plot` the plotting area's size in pixels). A band's ends suffice: the box touches
/// the plot's edge, so a band that crosses it has an end inside.
fn under_legend(
    panel: &Panel,
    x: &Range<f64>,
    y: &Range<f64>,
    plot: (f64, f64),
    legend: (f64, f64),
    corner: &SeriesLabelPosition,
) -> bool {
    let (right, upper) = match corner {
        SeriesLabelPosition::UpperLeft => (false, true),
        SeriesLabelPosition::LowerRight => (true, false),
        SeriesLabelPosition::LowerLeft => (false, false),
        _ => (true, true),
    };
    let reach_x = LEGEND_OFFSET_PX + legend.0 + MARKER_PX;
    let reach_y = LEGEND_OFFSET_PX + legend.1 + MARKER_PX;
    let px = |v: f64| (v - x.start) / (x.end - x.start) * plot.0;
    let py = |v: f64| (y.end - v) / (y.end - y.start) * plot.1;
    panel.series.iter().any(|s| {
        let half = if s.mark == Mark::Bars { 0.4 } else { 0.0 };
        s.points.iter().any(|p| {
            let (lo, hi) = p.band.unwrap_or((p.y, p.y));
            let in_x = if right {
                px(p.x + half) >= plot.0 - reach_x
            } else {
                px(p.x - half) <= reach_x
            };
            in_x && [p.y, lo, hi].iter().any(|&v| {
                if upper {
                    py(v) <= reach_y
                } else {
                    py(v) >= plot.1 - reach_y
                }
            })
        })
    })
}

/// The y range stretched upward so that a plot `plot_px` high keeps its top `reserved_px`
/// free of data: the old top maps to `reserved_px` below the new one.
fn with_headroom(y: Range<f64>, plot_px: f64, reserved_px: f64) -> Range<f64> {
    // A legend taller than half the plot would squeeze the data flat; it covers some instead.
    let reserved = reserved_px.clamp(0.0, 0.5 * plot_px);
    let top = y.start + (y.end - y.start) * plot_px / (plot_px - reserved);
    y.start..top
}

fn ranges(panel: &Panel) -> (Range<f64>, Range<f64>) {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    let mut bars = false;
    for s in &panel.series {
        bars |= s.mark == Mark::Bars;
        for p in &s.points {
            x0 = x0.min(p.x);
            x1 = x1.max(p.x);
            let (lo, hi) = p.band.unwrap_or((p.y, p.y));
            y0 = y0.min(p.y.min(lo));
            y1 = y1.max(p.y.max(hi));
        }
    }
    if let Some(m) = panel.x_marker {
        x0 = x0.min(m);
        x1 = x1.max(m);
    }
    if bars {
        y0 = y0.min(0.0);
        y1 = y1.max(0.0);
    }
    let x = if let Some((lo, hi)) = panel.x_range {
        lo..hi
    } else if !panel.x_categories.is_empty() {
        -0.5..(panel.x_categories.len() as f64 - 0.5)
    } else if bars {
        (x0 - 0.5)..(x1 + 0.5)
    } else {
        padded(x0, x1)
    };
    (x, padded(y0, y1))
}

/// The panel's axes and its legend's corner: the first corner clear of data, else the top
/// right with the y range raised until the data pass under the box.
fn chart_ranges(
    panel: &Panel,
    plot: (f64, f64),
    legend: Option<(f64, f64)>,
) -> (Range<f64>, Range<f64>, SeriesLabelPosition) {
    let (x, y) = ranges(panel);
    let Some(size) = legend else {
        return (x, y, SeriesLabelPosition::UpperRight);
    };
    match CORNERS
        .into_iter()
        .find(|c| !under_legend(panel, &x, &y, plot, size, c))
    {
        Some(corner) => (x, y, corner),
        None => {
            let y = with_headroom(y, plot.1, LEGEND_OFFSET_PX + size.1 + MARKER_PX);
            (x, y, SeriesLabelPosition::UpperRight)
        }
    }
}

fn draw_panel<DB: DrawingBackend>(
    panel: &Panel,
    area: &DrawingArea<DB, Shift>,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    // The caption as ChartBuilder::caption draws it, so the plotting area's size is known
    // before the y range is fixed.
    let titled = area.titled(panel.title.as_str(), ("sans-serif", 15).into_font())?;
    let x_label_px = if panel.x_categories.is_empty() {
        36
    } else {
        60
    };
    let (w, h) = titled.dim_in_pixel();
    let plot = (
        f64::from(w.saturating_sub(2 * MARGIN_PX + Y_LABEL_PX)),
        f64::from(h.saturating_sub(2 * MARGIN_PX + x_label_px)),
    );
    // A lone series is named by the panel's title; a legend would only cover data.
    let labels: Vec<&str> = if panel.series.len() > 1 {
        panel
            .series
            .iter()
            .filter(|s| !s.name.is_empty())
            .map(|s| s.name.as_str())
            .collect()
    } else {
        Vec::new()
    };
    let (xr, yr, corner) = chart_ranges(panel, plot, legend_box(&labels));
    let (y_lo, y_hi) = (yr.start, yr.end);
    let mut chart = ChartBuilder::on(&titled)
        .margin(MARGIN_PX)
        .x_label_area_size(x_label_px)
        .y_label_area_size(Y_LABEL_PX)
        .build_cartesian_2d(xr, yr)?;
    let categories = panel.x_categories.clone();
    let format_x = move |x: &f64| -> String {
        if categories.is_empty() {
            tick(*x)
        } else {
            let i = x.round();
            if (x - i).abs() < 1e-6 && i >= 0.0 {
                categories.get(i as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        }
    };
    let format_y = |y: &f64| tick(*y);
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(panel.x_label.as_str())
        .y_desc(panel.y_label.as_str())
        .label_style(("sans-serif", 11))
        .axis_desc_style(("sans-serif", 13))
        .light_line_style(RGBColor(235, 235, 235));
    if !panel.x_categories.is_empty() {
        mesh.x_labels(panel.x_categories.len() * 2 + 1);
    }
    mesh.x_label_formatter(&format_x)
        .y_label_formatter(&format_y);
    mesh.draw()?;

    let bar_series: Vec<usize> = panel
        .series
        .iter()
        .enumerate()
        .filter(|(_, s)| s.mark == Mark::Bars)
        .map(|(i, _)| i)
        .collect();
    let mut labelled = false;
    for (i, s) in panel.series.iter().enumerate() {
        let color = PALETTE[s.style.color.unwrap_or(i) % PALETTE.len()];
        let dash = DASHES[s.style.dash % DASHES.len()];
        let band: Vec<(f64, f64, f64)> = s
            .points
            .iter()
            .filter_map(|p| p.band.map(|(lo, hi)| (p.x, lo, hi)))
            .collect();
        if s.mark == Mark::Line && band.len() > 1 {
            let mut outline: Vec<(f64, f64)> = band.iter().map(|&(x, lo, _)| (x, lo)).collect();
            outline.extend(band.iter().rev().map(|&(x, _, hi)| (x, hi)));
            chart.draw_series(std::iter::once(Polygon::new(
                outline,
                color.mix(0.18).filled(),
            )))?;
        }
        // A line through one point draws nothing: such a series (a knob value with one point
        // on an axis of several) is drawn as a marker with its interval.
        let mark = match s.mark {
            Mark::Line if s.points.len() < 2 => Mark::Points,
            m => m,
        };
        let drawn = match (mark, dash) {
            (Mark::Line, None) => chart.draw_series(LineSeries::new(
                s.points.iter().map(|p| (p.x, p.y)),
                color.stroke_width(2),
            ))?,
            (Mark::Line, Some((on, off))) => chart.draw_series(DashedLineSeries::new(
                s.points.iter().map(|p| (p.x, p.y)),
                on,
                off,
                color.stroke_width(2),
            ))?,
            (Mark::Points, _) => {
                for p in s.points.iter().filter(|p| p.band.is_some()) {
                    let (lo, hi) = p.band.unwrap_or((p.y, p.y));
                    chart.draw_series(std::iter::once(PathElement::new(
                        vec![(p.x, lo), (p.x, hi)],
                        color.stroke_width(1),
                    )))?;
                }
                chart.draw_series(s.points.iter().map(|p| {
                    let style = if dash.is_some() {
                        color.stroke_width(2)
                    } else if p.highlight || s.mark == Mark::Line {
                        color.filled()
                    } else {
                        color.mix(0.55).stroke_width(1)
                    };
                    Circle::new((p.x, p.y), if p.highlight { 5 } else { 3 }, style)
                }))?
            }
            (Mark::Bars, _) => {
                let k = bar_series.len().max(1) as f64;
                let j = bar_series.iter().position(|&b| b == i).unwrap_or(0) as f64;
                let w = 0.8 / k;
                chart.draw_series(s.points.iter().map(|p| {
                    let left = p.x - 0.4 + j * w;
                    Rectangle::new([(left, 0.0), (left + w * 0.92, p.y)], color.filled())
                }))?
            }
        };
        if !labels.is_empty() && !s.name.is_empty() {
            let drawn = drawn.label(s.name.as_str());
            // A styled series' swatch is its line, so the legend tells the dashes apart.
            match (s.style == Style::default(), dash) {
                (true, _) => drawn.legend(move |(x, y)| {
                    Rectangle::new([(x, y - 4), (x + 16, y + 4)], color.filled())
                }),
                (false, None) => drawn.legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2))
                }),
                (false, Some((on, off))) => drawn.legend(move |(x, y)| {
                    let (on, off) = (on as i32, off as i32);
                    EmptyElement::at((x, y))
                        + PathElement::new(vec![(0, 0), (on, 0)], color.stroke_width(2))
                        + PathElement::new(
                            vec![(on + off, 0), ((2 * on + off).min(16), 0)],
                            color.stroke_width(2),
                        )
                }),
            };
            labelled = true;
        }
    }
    if let Some(m) = panel.x_marker {
        chart.draw_series(DashedLineSeries::new(
            vec![(m, y_lo), (m, y_hi)],
            6,
            4,
            BLACK.stroke_width(1),
        ))?;
    }
    if labelled {
        chart
            .configure_series_labels()
            .label_font(("sans-serif", 11))
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .position(corner)
            .draw()?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn figure() -> Figure {
        let line = Series {
            name: "teacher".into(),
            mark: Mark::Line,
            points: (0..20)
                .map(|i| {
                    let y = (i as f64 * 0.3).sin();
                    Point {
                        x: i as f64 - 5.0,
                        y,
                        band: Some((y - 0.2, y + 0.2)),
                        highlight: false,
                    }
                })
                .collect(),
            style: Style::default(),
        };
        let bars = Series {
            name: "gain".into(),
            mark: Mark::Bars,
            points: vec![Point::new(0.0, 0.3), Point::new(1.0, -0.1)],
            style: Style::default(),
        };
        let scatter = Series {
            name: "candidates".into(),
            mark: Mark::Points,
            points: vec![
                Point::new(0.1, 0.5),
                Point {
                    highlight: true,
                    ..Point::new(0.4, 0.9)
                },
            ],
            style: Style::default(),
        };
        Figure {
            id: "fig_test".into(),
            title: "A test figure".into(),
            caption: String::new(),
            panels: vec![
                Panel {
                    title: "lines, band, marker".into(),
                    x_label: "step from t_c".into(),
                    y_label: "force (N)".into(),
                    x_categories: vec![],
                    x_marker: Some(0.0),
                    x_range: None,
                    series: vec![line],
                },
                Panel {
                    title: "bars".into(),
                    x_label: String::new(),
                    y_label: "pp".into(),
                    x_categories: vec!["box-large".into(), "box-small".into()],
                    x_marker: None,
                    x_range: None,
                    series: vec![bars],
                },
                Panel {
                    title: "points".into(),
                    x_label: "SR".into(),
                    y_label: "J".into(),
                    x_categories: vec![],
                    x_marker: None,
                    x_range: None,
                    series: vec![scatter],
                },
            ],
        }
    }

    #[test]
    fn renders_svg_and_png_of_the_stated_size_deterministically() {
        let f = figure();
        let svg = f.svg().expect("svg");
        assert!(
            svg.starts_with("<svg") && svg.contains("A test figure"),
            "{svg:.200}"
        );
        assert_eq!(svg, f.svg().expect("svg again"));
        let png = f.png().expect("png");
        assert_eq!(&png[1..4], b"PNG");
        let (w, h) = f.size();
        // IHDR: width and height, big-endian, after the 8-byte signature and chunk header.
        assert_eq!(u32::from_be_bytes(png[16..20].try_into().expect("w")), w);
        assert_eq!(u32::from_be_bytes(png[20..24].try_into().expect("h")), h);
        assert_eq!((w, h), (3 * PANEL_W, TITLE_H + PANEL_H));
        assert_eq!(png, f.png().expect("png again"));
    }

    fn two_series(top_right: Point) -> Panel {
        let series = |name: &str, points: Vec<Point>| Series {
            name: name.into(),
            mark: Mark::Points,
            points,
            style: Style::default(),
        };
        Panel {
            title: "p".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            x_categories: vec![],
            x_marker: None,
            x_range: None,
            series: vec![
                series("dev_student, validate.kappa=1", vec![Point::new(0.0, 0.0)]),
                series("dev_student_dart, validate.kappa=1", vec![top_right]),
            ],
        }
    }

    #[test]
    fn a_title_too_wide_for_one_panel_shrinks_then_wraps_to_fit() {
        register_font();
        let width = PANEL_W - 2 * TITLE_X_PX;
        assert_eq!(
            title_lines("Where does it pay?", width),
            (vec!["Where does it pay?".to_string()], 20)
        );
        let long = "Naive-IL against its demonstrations (dev, construction without DR)";
        assert!(
            text_width(long, 20) > width,
            "the case under test: too wide at 20 px"
        );
        let (lines, size) = title_lines(long, width);
        assert!((12..20).contains(&size), "{size}");
        assert!(
            lines.iter().all(|l| text_width(l, size) <= width),
            "{lines:?} at {size}"
        );
        assert_eq!(lines.join(" "), long);
        let longer = long.repeat(2);
        let (lines, size) = title_lines(&longer, width);
        assert_eq!((lines.len(), lines.join(" ")), (2, longer.clone()));
        assert!(size <= 16 && lines.iter().all(|l| l.len() < longer.len()));
        let one_word = "x".repeat(200);
        assert_eq!(title_lines(&one_word, width), (vec![one_word.clone()], 12));
    }

    #[test]
    fn the_legend_box_grows_with_its_labels() {
        register_font();
        let one = legend_box(&["a"]).expect("one label");
        let two = legend_box(&["a", "a much longer label"]).expect("two labels");
        assert!(two.0 > one.0 && two.1 > one.1, "{one:?} {two:?}");
        assert!(
            one.1 > 2.0 * LEGEND_MARGIN_PX && one.0 > LEGEND_SWATCH_PX,
            "{one:?}"
        );
        assert_eq!(legend_box(&[]), None);
    }

    #[test]
    fn headroom_puts_the_old_top_the_reserved_pixels_below_the_new_one() {
        let y = with_headroom(10.0..30.0, 300.0, 60.0);
        assert_eq!(y.start, 10.0);
        // On a 300 px axis the old top (30) sits 60 px below the new top: 60/300 of the span.
        let from_top = (y.end - 30.0) / (y.end - y.start) * 300.0;
        assert!((from_top - 60.0).abs() < 1e-9, "{y:?}");
        // A reservation beyond half the plot is capped there.
        let capped = with_headroom(0.0..1.0, 100.0, 90.0);
        assert!((capped.end - 2.0).abs() < 1e-12, "{capped:?}");
    }

    /// A 448 × 290 px plotting area and the legend box of [`two_series`]' labels.
    fn two_series_legend() -> ((f64, f64), Option<(f64, f64)>) {
        register_font();
        let legend = legend_box(&[
            "dev_student, validate.kappa=1",
            "dev_student_dart, validate.kappa=1",
        ]);
        ((448.0, 290.0), legend)
    }

    #[test]
    fn the_legend_takes_the_first_corner_clear_of_data() {
        let (plot, legend) = two_series_legend();
        let (w, h) = legend.expect("legend");
        let up_right = SeriesLabelPosition::UpperRight;
        // Bottom right and top left leave the top right clear: the axis is the data's.
        for p in [Point::new(1.0, -1.0), Point::new(-1.0, 1.0)] {
            let clear = two_series(p);
            let (x, y) = ranges(&clear);
            assert_eq!(chart_ranges(&clear, plot, legend), (x, y, up_right.clone()));
        }
        // Top right: the second series' point is the data's largest x and y; the legend moves
        // to the top left, where the first series' point (the smallest) sits at the bottom.
        let covered = two_series(Point::new(1.0, 1.0));
        let (x, y) = ranges(&covered);
        assert!(under_legend(&covered, &x, &y, plot, (w, h), &up_right));
        let left = SeriesLabelPosition::UpperLeft;
        assert!(!under_legend(&covered, &x, &y, plot, (w, h), &left));
        assert_eq!(chart_ranges(&covered, plot, legend), (x, y, left));
        // An interval's end under the box counts like a point.
        let band = two_series(Point {
            band: Some((-1.0, 1.0)),
            ..Point::new(1.0, -1.0)
        });
        let (x, y) = ranges(&band);
        assert!(under_legend(&band, &x, &y, plot, (w, h), &up_right));
        // Three corners taken: the bottom left.
        let mut three = two_series(Point::new(1.0, 1.0));
        three.series[0].points = vec![Point::new(0.0, 1.0), Point::new(1.0, 0.0)];
        let (x, y) = ranges(&three);
        assert_eq!(
            chart_ranges(&three, plot, legend),
            (x, y, SeriesLabelPosition::LowerLeft)
        );
    }

    #[test]
    fn data_in_every_corner_raise_the_y_axis_under_a_top_right_legend() {
        let (plot, legend) = two_series_legend();
        let (w, h) = legend.expect("legend");
        let mut full = two_series(Point::new(1.0, 1.0));
        full.series[0].points = vec![
            Point::new(0.0, 0.0),
            Point::new(0.0, 1.0),
            Point::new(1.0, 0.0),
        ];
        let (x, y) = ranges(&full);
        for c in &CORNERS {
            assert!(under_legend(&full, &x, &y, plot, (w, h), c), "{c:?}");
        }
        let (x2, y2, corner) = chart_ranges(&full, plot, legend);
        assert_eq!(corner, SeriesLabelPosition::UpperRight);
        assert_eq!(x2, x);
        assert!(y2.end > y.end && y2.start == y.start, "{y:?} -> {y2:?}");
        // In pixels, the top point now sits below the box with a marker's clearance.
        let from_top = (y2.end - 1.0) / (y2.end - y2.start) * plot.1;
        assert!(
            from_top >= LEGEND_OFFSET_PX + h + MARKER_PX - 1e-9,
            "{from_top} {h}"
        );
        assert!(!under_legend(&full, &x2, &y2, plot, (w, h), &corner));
    }

    #[test]
    fn a_line_through_one_point_is_drawn_as_a_marker() {
        let panel = |points: Vec<Point>| Panel {
            title: "p".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            x_categories: vec!["0.25".into(), "0.5".into()],
            x_marker: None,
            x_range: None,
            series: vec![Series {
                name: "kappa=1.5".into(),
                mark: Mark::Line,
                points,
                style: Style::default(),
            }],
        };
        let circles = |points: Vec<Point>| {
            let f = Figure {
                id: "one".into(),
                title: "t".into(),
                caption: String::new(),
                panels: vec![panel(points)],
            };
            f.svg().expect("svg").matches("<circle").count()
        };
        let one = Point {
            band: Some((0.8, 1.2)),
            ..Point::new(0.0, 1.0)
        };
        assert_eq!(circles(vec![one]), 1);
        assert_eq!(circles(vec![one, Point::new(1.0, 2.0)]), 0, "a line of two");
    }

    /// A figure of one line series with `style`, on two categories or a numeric axis.
    fn one_series(style: Style, points: Vec<Point>, categories: bool) -> Figure {
        Figure {
            id: "styled".into(),
            title: "t".into(),
            caption: String::new(),
            panels: vec![Panel {
                title: "p".into(),
                x_label: "x".into(),
                y_label: "y".into(),
                x_categories: if categories {
                    vec!["a".into(), "b".into()]
                } else {
                    vec![]
                },
                x_marker: None,
                x_range: None,
                series: vec![Series {
                    name: "s".into(),
                    mark: Mark::Line,
                    points,
                    style,
                }],
            }],
        }
    }

    /// A style's dash breaks the line into pieces and leaves its markers hollow; its color
    /// comes from the style, not the series' position; none of it is in the stored bytes.
    #[test]
    fn a_style_sets_the_color_and_dash_and_is_not_stored() {
        let svg = |color, dash, n: usize| {
            let points = (0..n).map(|i| Point::new(i as f64, i as f64)).collect();
            one_series(Style { color, dash }, points, true)
                .svg()
                .expect("svg")
        };
        let solid = svg(None, 0, 2);
        let dashed = svg(None, 1, 2);
        let pieces = |s: &str| s.matches("<polyline").count();
        assert!(
            pieces(&dashed) > pieces(&solid) + 2,
            "{} vs {}",
            pieces(&dashed),
            pieces(&solid)
        );
        let circle = |s: &str| {
            let at = s.find("<circle").expect("a marker");
            s[at..at + s[at..].find("/>").expect("closed")].to_string()
        };
        let (filled, hollow) = (svg(None, 0, 1), svg(None, 1, 1));
        assert!(
            circle(&hollow).contains("fill=\"none\""),
            "{}",
            circle(&hollow)
        );
        assert!(
            !circle(&filled).contains("fill=\"none\""),
            "{}",
            circle(&filled)
        );
        // The palette's third color (44, 160, 44) instead of the first.
        assert!(svg(Some(2), 0, 2).contains("#2CA02C") && !solid.contains("#2CA02C"));
        // An artifact's bytes (the store's codec) are the same with or without a style.
        let figure = |style| one_series(style, vec![Point::new(0.0, 1.0)], false);
        let styled = figure(Style {
            color: Some(3),
            dash: 2,
        });
        let bytes = osms_core::encode(&styled).expect("encode");
        assert_eq!(
            bytes,
            osms_core::encode(&figure(Style::default())).expect("encode")
        );
        let back: Figure = osms_core::decode(&bytes).expect("decode");
        assert_eq!(back, figure(Style::default()));
    }

    #[test]
    fn a_flat_range_is_padded_by_a_tenth_of_its_value() {
        assert_eq!(padded(9655.0, 9655.0), (9655.0 - 48.275)..(9655.0 + 48.275));
        assert_eq!(padded(0.0, 0.0), -0.05..0.05);
        assert_eq!(padded(f64::NAN, 1.0), 0.0..1.0);
    }

    #[test]
    fn tick_labels_drop_a_whole_numbers_fraction() {
        assert_eq!(tick(800.0), "800");
        assert_eq!(tick(0.0), "0");
        assert_eq!(tick(-0.0), "0");
        assert_eq!(tick(0.1 + 0.2), "0.3");
        assert_eq!(tick(-2.5), "-2.5");
        assert_eq!(tick(42.45), "42.45");
        assert_eq!(tick(1e-7), "0");
        assert_eq!(tick(9650.0), "9650");
    }

    #[test]
    fn csv_holds_every_point() {
        let f = figure();
        let csv = f.csv();
        assert_eq!(csv.lines().count(), 1 + 20 + 2 + 2);
        assert!(csv.contains("bars,gain,1,-0.1,,,false"), "{csv}");
        assert!(csv.contains("points,candidates,0.4,0.9,,,true"), "{csv}");
        assert!(
            csv.contains("\"lines, band, marker\",teacher,-5,0,-0.2,0.2,false"),
            "{csv}"
        );
    }
}
