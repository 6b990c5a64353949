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
            let root = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
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
        title.draw(&Text::new(
            self.title.clone(),
            (12, 12),
            ("sans-serif", 20).into_font(),
        ))?;
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

fn field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Data range with 5 % padding; a flat or empty range gets a unit width.
fn padded(lo: f64, hi: f64) -> Range<f64> {
    if !(lo.is_finite() && hi.is_finite()) || lo > hi {
        return 0.0..1.0;
    }
    let span = if hi - lo > 1e-12 { hi - lo } else { 1.0 };
    (lo - 0.05 * span)..(hi + 0.05 * span)
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

fn draw_panel<DB: DrawingBackend>(
    panel: &Panel,
    area: &DrawingArea<DB, Shift>,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let (xr, yr) = ranges(panel);
    let (y_lo, y_hi) = (yr.start, yr.end);
    let mut chart = ChartBuilder::on(area)
        .caption(panel.title.as_str(), ("sans-serif", 15))
        .margin(10)
        .x_label_area_size(if panel.x_categories.is_empty() {
            36
        } else {
            60
        })
        .y_label_area_size(56)
        .build_cartesian_2d(xr, yr)?;
    let categories = panel.x_categories.clone();
    let format_x = move |x: &f64| -> String {
        if categories.is_empty() {
            format!("{x}")
        } else {
            let i = x.round();
            if (x - i).abs() < 1e-6 && i >= 0.0 {
                categories.get(i as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        }
    };
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(panel.x_label.as_str())
        .y_desc(panel.y_label.as_str())
        .label_style(("sans-serif", 11))
        .axis_desc_style(("sans-serif", 13))
        .light_line_style(RGBColor(235, 235, 235));
    if !panel.x_categories.is_empty() {
        mesh.x_labels(panel.x_categories.len() * 2 + 1)
            .x_label_formatter(&format_x);
    }
    mesh.draw()?;

    let bar_series: Vec<usize> = panel
        .series
        .iter()
        .enumerate()
        .filter(|(_, s)| s.mark == Mark::Bars)
        .map(|(i, _)| i)
        .collect();
    // A lone series is named by the panel's title; a legend would only cover data.
    let legend_wanted = panel.series.len() > 1;
    let mut labelled = false;
    for (i, s) in panel.series.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
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
        let legend =
            move |(x, y): (i32, i32)| Rectangle::new([(x, y - 4), (x + 16, y + 4)], color.filled());
        let drawn = match s.mark {
            Mark::Line => chart.draw_series(LineSeries::new(
                s.points.iter().map(|p| (p.x, p.y)),
                color.stroke_width(2),
            ))?,
            Mark::Points => {
                for p in s.points.iter().filter(|p| p.band.is_some()) {
                    let (lo, hi) = p.band.unwrap_or((p.y, p.y));
                    chart.draw_series(std::iter::once(PathElement::new(
                        vec![(p.x, lo), (p.x, hi)],
                        color.stroke_width(1),
                    )))?;
                }
                chart.draw_series(s.points.iter().map(|p| {
                    let style = if p.highlight {
                        color.filled()
                    } else {
                        color.mix(0.55).stroke_width(1)
                    };
                    Circle::new((p.x, p.y), if p.highlight { 5 } else { 3 }, style)
                }))?
            }
            Mark::Bars => {
                let k = bar_series.len().max(1) as f64;
                let j = bar_series.iter().position(|&b| b == i).unwrap_or(0) as f64;
                let w = 0.8 / k;
                chart.draw_series(s.points.iter().map(|p| {
                    let left = p.x - 0.4 + j * w;
                    Rectangle::new([(left, 0.0), (left + w * 0.92, p.y)], color.filled())
                }))?
            }
        };
        if legend_wanted && !s.name.is_empty() {
            drawn.label(s.name.as_str()).legend(legend);
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
            .position(SeriesLabelPosition::UpperRight)
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
        };
        let bars = Series {
            name: "gain".into(),
            mark: Mark::Bars,
            points: vec![Point::new(0.0, 0.3), Point::new(1.0, -0.1)],
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
