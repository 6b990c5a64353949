//! One table model for every table osms prints, rendered three ways that say the same thing:
//! Markdown for people, a tidy CSV (one line per cell) and JSON for programs; tables that
//! export one line per row (Table I, the construction and candidate tables) also render as a
//! wide CSV.
//!
//! A [`Table`] is data (it is stored as Tables II and III); how it reads in Markdown, which
//! header its label column has and whether the report's legend follows, is a [`Layout`] the
//! table's owner chooses when it renders.

use std::fmt::Write;

use serde::{Deserialize, Serialize};

use crate::Artifact;
use crate::stats::MeanSd;

/// How a column's numbers read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Unit {
    /// A fraction shown as a percentage with one decimal.
    Percent,
    /// A number with this many decimals.
    Number(u8),
    /// A whole number.
    Count,
    /// Text, left-aligned (cells hold [`Value::Text`]).
    Text,
    /// A number in scientific notation with this many decimals (`1.50e-3`).
    Scientific(u8),
}

impl Unit {
    /// Text reads from the left, numbers from the right.
    pub fn align(self) -> Align {
        match self {
            Unit::Text => Align::Left,
            _ => Align::Right,
        }
    }
}

/// How a column lines up in Markdown.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Align {
    Left,
    Right,
}

impl Align {
    fn rule(self) -> &'static str {
        match self {
            Align::Left => "---|",
            Align::Right => "---:|",
        }
    }
}

/// How a table reads in Markdown: the header of its label column, how that column lines up,
/// and whether the report's legend (ours first, the paper in parentheses, mean ± sd over
/// seeds) follows the rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout<'a> {
    pub label: &'a str,
    pub label_align: Align,
    pub legend: bool,
}

impl Layout<'static> {
    /// The report's tables: an unlabelled first column and the legend.
    pub const REPORT: Layout<'static> = Layout {
        label: "",
        label_align: Align::Left,
        legend: true,
    };
}

impl<'a> Layout<'a> {
    /// A table of this run's values alone: its first column headed `label`, no legend.
    pub fn plain(label: &'a str) -> Layout<'a> {
        Layout {
            label,
            label_align: Align::Left,
            legend: false,
        }
    }

    /// The same with the label column right-aligned (a column of step numbers).
    pub fn numbered(label: &'a str) -> Layout<'a> {
        Layout {
            label_align: Align::Right,
            ..Layout::plain(label)
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Column {
    pub name: String,
    pub unit: Unit,
}

/// Our value of a cell: one number (built once), or one per run seed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Value {
    Missing,
    One(f64),
    Seeds(Vec<f64>),
    /// Text shown as it is, whatever the column's unit (e.g. `3 / 5`, a pair of counts).
    Text(String),
}

impl Value {
    pub fn of(v: Option<f64>) -> Value {
        v.map_or(Value::Missing, Value::One)
    }

    /// Per-seed values; seeds without a value (e.g. no catch completion, so no mean force)
    /// are left out, and the count says so.
    pub fn seeds(values: impl IntoIterator<Item = Option<f64>>) -> Value {
        let v: Vec<f64> = values.into_iter().flatten().collect();
        if v.is_empty() {
            Value::Missing
        } else {
            Value::Seeds(v)
        }
    }

    /// A number, or [`Value::Missing`] for none.
    pub fn opt(v: Option<f64>) -> Value {
        Value::of(v)
    }

    pub fn stats(&self) -> Option<MeanSd> {
        match self {
            Value::Missing | Value::Text(_) => None,
            Value::One(v) => MeanSd::of(&[*v]),
            Value::Seeds(v) => MeanSd::of(v),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Cell {
    pub ours: Value,
    /// The paper's value as printed, if it reports one.
    pub paper: Option<String>,
}

impl Cell {
    pub fn new(ours: Value, paper: Option<&str>) -> Cell {
        Cell {
            ours,
            paper: paper.map(str::to_string),
        }
    }

    /// Our value alone.
    pub fn ours(ours: Value) -> Cell {
        Cell { ours, paper: None }
    }

    /// One number of ours.
    pub fn one(v: f64) -> Cell {
        Cell::ours(Value::One(v))
    }

    /// One number of ours, or none.
    pub fn opt(v: Option<f64>) -> Cell {
        Cell::ours(Value::of(v))
    }

    /// Text shown as it is.
    pub fn text(s: impl Into<String>) -> Cell {
        Cell::ours(Value::Text(s.into()))
    }
}

impl Column {
    pub fn new(name: impl Into<String>, unit: Unit) -> Column {
        Column {
            name: name.into(),
            unit,
        }
    }
}

impl Row {
    pub fn new(label: impl Into<String>, cells: Vec<Cell>) -> Row {
        Row {
            label: label.into(),
            cells,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Row {
    pub label: String,
    pub cells: Vec<Cell>,
}

/// A table with the paper's values beside ours.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Table {
    /// File stem of its exports, e.g. `table2`.
    pub id: String,
    pub title: String,
    pub columns: Vec<Column>,
    pub rows: Vec<Row>,
    pub notes: Vec<String>,
}

/// A table is stored as itself: Tables II and III are stage outputs.
impl Artifact for Table {
    const TYPE_TAG: &'static str = "report.table";
    const SCHEMA_VERSION: u16 = 1;
}

fn number(v: f64, unit: Unit) -> String {
    match unit {
        Unit::Percent => format!("{:.1}%", 100.0 * v),
        Unit::Number(d) => format!("{v:.*}", d as usize),
        Unit::Count => format!("{v:.0}"),
        Unit::Scientific(d) => format!("{v:.*e}", d as usize),
        // A number in a text column reads as it would with no unit at all.
        Unit::Text => v.to_string(),
    }
}

/// `90.3% ± 0.8%` for several seeds, `90.3%` for one value, `41.1 (1 seed)` when only one
/// seed has a value, `-` for none.
pub fn format_value(value: &Value, unit: Unit) -> String {
    match (value, value.stats()) {
        (Value::Text(s), _) => s.clone(),
        (_, None) => "-".into(),
        (
            Value::Seeds(_),
            Some(MeanSd {
                mean, sd: Some(sd), ..
            }),
        ) => {
            format!("{} ± {}", number(mean, unit), number(sd, unit))
        }
        (Value::Seeds(_), Some(m)) => format!("{} (1 seed)", number(m.mean, unit)),
        (_, Some(m)) => number(m.mean, unit),
    }
}

impl Table {
    /// An empty table with these columns, to fill with [`Table::push`].
    pub fn new(id: impl Into<String>, title: impl Into<String>, columns: Vec<Column>) -> Table {
        Table {
            id: id.into(),
            title: title.into(),
            columns,
            rows: Vec::new(),
            notes: Vec::new(),
        }
    }

    /// Appends a row.
    pub fn push(&mut self, label: impl Into<String>, cells: Vec<Cell>) {
        self.rows.push(Row::new(label, cells));
    }

    /// The table with a note after its rows.
    pub fn with_note(mut self, note: impl Into<String>) -> Table {
        self.notes.push(note.into());
        self
    }

    /// The row labelled `label`, if any.
    pub fn row(&self, label: &str) -> Option<&Row> {
        self.rows.iter().find(|r| r.label == label)
    }

    /// The cell of row `label`, column `column`.
    pub fn cell(&self, label: &str, column: &str) -> Option<&Cell> {
        let c = self.columns.iter().position(|c| c.name == column)?;
        self.row(label)?.cells.get(c)
    }

    /// The table as the report shows it ([`Layout::REPORT`]).
    pub fn markdown(&self) -> String {
        self.markdown_with(Layout::REPORT)
    }

    /// The table in Markdown, laid out as `layout` says, its notes after the rows.
    pub fn markdown_with(&self, layout: Layout<'_>) -> String {
        let mut out = String::new();
        if layout.label.is_empty() {
            out.push_str("| |");
        } else {
            let _ = write!(out, "| {} |", layout.label);
        }
        for c in &self.columns {
            let _ = write!(out, " {} |", c.name);
        }
        let _ = write!(out, "\n|{}", layout.label_align.rule());
        for c in &self.columns {
            out.push_str(c.unit.align().rule());
        }
        out.push('\n');
        for r in &self.rows {
            let _ = write!(out, "| {} |", r.label);
            for (c, cell) in self.columns.iter().zip(&r.cells) {
                let ours = format_value(&cell.ours, c.unit);
                match &cell.paper {
                    Some(p) => {
                        let _ = write!(out, " {ours} ({p}) |");
                    }
                    None => {
                        let _ = write!(out, " {ours} |");
                    }
                }
            }
            out.push('\n');
        }
        if layout.legend {
            let _ = writeln!(
                out,
                "\nOurs first, the paper's value in parentheses; `a ± b` is the mean and sample standard deviation over run seeds."
            );
        }
        for n in &self.notes {
            let _ = writeln!(out, "\n{n}");
        }
        out
    }

    /// One line per row: `label_key` and the column names as the header, each number as Rust
    /// prints it (full precision), nothing for a missing value, per-seed values separated by
    /// `;`. Its columns are what a program reads, so their names are keys
    /// (`success_rate`), unlike the Markdown's headers.
    pub fn wide_csv(&self, label_key: &str) -> String {
        let mut out = csv_field(label_key);
        for c in &self.columns {
            out.push(',');
            out.push_str(&csv_field(&c.name));
        }
        out.push('\n');
        for r in &self.rows {
            out.push_str(&csv_field(&r.label));
            for cell in &r.cells {
                out.push(',');
                match &cell.ours {
                    Value::Missing => {}
                    Value::One(v) => out.push_str(&v.to_string()),
                    Value::Seeds(v) => {
                        out.push_str(&v.iter().map(f64::to_string).collect::<Vec<_>>().join(";"))
                    }
                    Value::Text(t) => out.push_str(&csv_field(t)),
                }
            }
            out.push('\n');
        }
        out
    }

    /// One line per cell: `row,column,mean,sd,n,values,paper`; `values` lists the per-seed
    /// values separated by `;`.
    pub fn csv(&self) -> String {
        let mut out = String::from("row,column,mean,sd,n,values,paper\n");
        for r in &self.rows {
            for (c, cell) in self.columns.iter().zip(&r.cells) {
                let stats = cell.ours.stats();
                let values = match &cell.ours {
                    Value::Missing => String::new(),
                    Value::Text(t) => csv_field(t),
                    Value::One(v) => v.to_string(),
                    Value::Seeds(v) => v.iter().map(f64::to_string).collect::<Vec<_>>().join(";"),
                };
                let _ = writeln!(
                    out,
                    "{},{},{},{},{},{},{}",
                    csv_field(&r.label),
                    csv_field(&c.name),
                    stats.map(|s| s.mean.to_string()).unwrap_or_default(),
                    stats
                        .and_then(|s| s.sd)
                        .map(|s| s.to_string())
                        .unwrap_or_default(),
                    stats.map_or(0, |s| s.n),
                    values,
                    csv_field(cell.paper.as_deref().unwrap_or_default())
                );
            }
        }
        out
    }

    /// The table with each cell's mean, sd and n spelled out.
    pub fn json(&self) -> serde_json::Value {
        let rows: Vec<serde_json::Value> = self
            .rows
            .iter()
            .map(|r| {
                let cells: serde_json::Map<String, serde_json::Value> = self
                    .columns
                    .iter()
                    .zip(&r.cells)
                    .map(|(c, cell)| {
                        let s = cell.ours.stats();
                        (
                            c.name.clone(),
                            serde_json::json!({
                                "mean": s.map(|s| s.mean),
                                "sd": s.and_then(|s| s.sd),
                                "n": s.map_or(0, |s| s.n),
                                "value": cell.ours,
                                "paper": cell.paper,
                            }),
                        )
                    })
                    .collect();
                serde_json::json!({ "row": r.label, "cells": cells })
            })
            .collect();
        serde_json::json!({
            "id": self.id,
            "title": self.title,
            "columns": self.columns,
            "rows": rows,
            "notes": self.notes,
        })
    }

    /// The table as a section of a report page, linking its CSV and JSON.
    pub fn section(&self) -> String {
        format!(
            "## {}\n\n{}\nFiles: [{id}.csv]({id}.csv), [{id}.json]({id}.json)\n\n",
            self.title,
            self.markdown(),
            id = self.id
        )
    }

    /// `<id>.md`, `<id>.csv`, `<id>.json`.
    pub fn files(&self) -> Vec<(String, Vec<u8>)> {
        let json = serde_json::to_string_pretty(&self.json()).unwrap_or_default() + "\n";
        files(
            &self.id,
            format!("# {}\n\n{}", self.title, self.markdown()),
            self.csv(),
            json.into_bytes(),
        )
    }
}

/// A column read two ways: `label` heads it in Markdown, `key` names it in the wide CSV. A
/// column with only a label is for people (two counts read as `3 / 5`); one with only a key is
/// for programs (the counts behind a rate, the paper's value as a number).
#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    pub label: Option<String>,
    pub key: Option<String>,
    pub unit: Unit,
}

impl Field {
    /// A column people and programs both read.
    pub fn new(label: impl Into<String>, key: impl Into<String>, unit: Unit) -> Field {
        Field {
            label: Some(label.into()),
            key: Some(key.into()),
            unit,
        }
    }

    /// A column only the Markdown shows.
    pub fn markdown(label: impl Into<String>, unit: Unit) -> Field {
        Field {
            label: Some(label.into()),
            key: None,
            unit,
        }
    }

    /// A column only the wide CSV has.
    pub fn csv(key: impl Into<String>, unit: Unit) -> Field {
        Field {
            label: None,
            key: Some(key.into()),
            unit,
        }
    }
}

/// A table built once, one cell per [`Field`] in each row, and rendered for people
/// ([`Sheet::markdown_with`]: the labelled columns, with the paper's values in parentheses)
/// and for programs ([`Sheet::wide_csv`]: the keyed columns, full precision).
#[derive(Debug, Clone, PartialEq)]
pub struct Sheet {
    pub fields: Vec<Field>,
    pub rows: Vec<Row>,
    pub notes: Vec<String>,
}

impl Sheet {
    pub fn new(fields: Vec<Field>) -> Sheet {
        Sheet {
            fields,
            rows: Vec::new(),
            notes: Vec::new(),
        }
    }

    /// Appends a row: one cell per field, in the fields' order.
    pub fn push(&mut self, label: impl Into<String>, cells: Vec<Cell>) {
        assert_eq!(
            cells.len(),
            self.fields.len(),
            "a sheet's row has a cell per field"
        );
        self.rows.push(Row::new(label, cells));
    }

    /// The sheet with a note after its rows (Markdown only).
    pub fn with_note(mut self, note: impl Into<String>) -> Sheet {
        self.notes.push(note.into());
        self
    }

    /// The columns whose field has a name in `name`, as a [`Table`].
    fn table(&self, name: impl Fn(&Field) -> Option<&String>) -> Table {
        let picked: Vec<(usize, &String, Unit)> = self
            .fields
            .iter()
            .enumerate()
            .filter_map(|(i, f)| name(f).map(|n| (i, n, f.unit)))
            .collect();
        Table {
            id: String::new(),
            title: String::new(),
            columns: picked
                .iter()
                .map(|(_, n, unit)| Column::new(n.as_str(), *unit))
                .collect(),
            rows: self
                .rows
                .iter()
                .map(|r| Row {
                    label: r.label.clone(),
                    cells: picked.iter().map(|(i, _, _)| r.cells[*i].clone()).collect(),
                })
                .collect(),
            notes: self.notes.clone(),
        }
    }

    /// The labelled columns in Markdown, laid out as `layout` says, the notes after the rows.
    pub fn markdown_with(&self, layout: Layout<'_>) -> String {
        self.table(|f| f.label.as_ref()).markdown_with(layout)
    }

    /// The keyed columns, one line per row ([`Table::wide_csv`]).
    pub fn wide_csv(&self, label_key: &str) -> String {
        self.table(|f| f.key.as_ref()).wide_csv(label_key)
    }
}

/// The export files of a table: `<stem>.md`, `<stem>.csv` and `<stem>.json`.
pub fn files(stem: &str, markdown: String, csv: String, json: Vec<u8>) -> Vec<(String, Vec<u8>)> {
    vec![
        (format!("{stem}.md"), markdown.into_bytes()),
        (format!("{stem}.csv"), csv.into_bytes()),
        (format!("{stem}.json"), json),
    ]
}

/// A CSV field, quoted where it holds a comma, a quote or a newline.
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// A byte count for people: `512 B`, `1.5 KiB`, `2.0 GiB`.
pub fn human_bytes(n: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = n as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{n} B")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table() -> Table {
        Table {
            id: "t".into(),
            title: "T".into(),
            columns: vec![
                Column {
                    name: "task success".into(),
                    unit: Unit::Percent,
                },
                Column {
                    name: "f_max (N)".into(),
                    unit: Unit::Number(1),
                },
            ],
            rows: vec![
                Row {
                    label: "Ours-IL".into(),
                    cells: vec![
                        Cell::new(Value::Seeds(vec![0.9, 0.8, 0.85]), Some("90.3% ± 0.8%")),
                        Cell::new(Value::seeds([Some(30.0), None, Some(40.0)]), None),
                    ],
                },
                Row {
                    label: "teacher, once".into(),
                    cells: vec![
                        Cell::new(Value::One(0.5), None),
                        Cell::new(Value::Missing, Some("40.8")),
                    ],
                },
                Row {
                    label: "one seed".into(),
                    cells: vec![
                        Cell::new(Value::seeds([None, Some(0.25), None]), None),
                        Cell::new(Value::seeds([None, None]), None),
                    ],
                },
            ],
            notes: vec![],
        }
    }

    #[test]
    fn markdown_csv_and_json_agree() {
        let t = table();
        let md = t.markdown();
        assert!(
            md.contains("| Ours-IL | 85.0% ± 5.0% (90.3% ± 0.8%) | 35.0 ± 7.1 |"),
            "{md}"
        );
        assert!(md.contains("| teacher, once | 50.0% | - (40.8) |"), "{md}");
        let csv = t.csv();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 7);
        assert!(md.contains("| one seed | 25.0% (1 seed) | - |"), "{md}");
        let first: Vec<&str> = lines[1].split(',').collect();
        assert_eq!(first[0], "Ours-IL");
        let mean: f64 = first[2].parse().expect("mean");
        let sd: f64 = first[3].parse().expect("sd");
        assert!((mean - 0.85).abs() < 1e-12 && (sd - 0.05).abs() < 1e-12);
        assert_eq!(first[4], "3");
        assert!(
            lines[2].starts_with("Ours-IL,f_max (N),35,"),
            "{}",
            lines[2]
        );
        assert!(lines[2].contains(",2,30;40,"), "{}", lines[2]);
        assert_eq!(lines[3], "\"teacher, once\",task success,0.5,,1,0.5,");
        let j = t.json();
        let cell = &j["rows"][0]["cells"]["task success"];
        assert_eq!(cell["mean"].as_f64(), Some(mean));
        assert_eq!(cell["sd"].as_f64(), Some(sd));
        assert_eq!(cell["paper"], "90.3% ± 0.8%");
        assert_eq!(j["rows"][1]["cells"]["f_max (N)"]["n"], 0);
    }

    #[test]
    fn plain_layouts_text_cells_and_the_wide_csv() {
        let mut t = Table::new(
            "t",
            "T",
            vec![
                Column::new("window", Unit::Text),
                Column::new("n", Unit::Count),
                Column::new("refine / repair", Unit::Count),
                Column::new("lr", Unit::Scientific(2)),
            ],
        );
        t.push(
            "-8, x",
            vec![
                Cell::text("k_e-8 … k_e-1"),
                Cell::one(40.0),
                Cell::text("3 / 5"),
                Cell::one(0.0015),
            ],
        );
        t.push(
            "0",
            vec![
                Cell::text("a"),
                Cell::opt(None),
                Cell::text("0 / 0"),
                Cell::opt(None),
            ],
        );
        t.notes.push("A note.".into());
        let md = t.markdown_with(Layout::numbered("offset"));
        assert_eq!(
            md,
            "| offset | window | n | refine / repair | lr |\n\
             |---:|---|---:|---:|---:|\n\
             | -8, x | k_e-8 … k_e-1 | 40 | 3 / 5 | 1.50e-3 |\n\
             | 0 | a | - | 0 / 0 | - |\n\
             \nA note.\n"
        );
        assert!(
            t.markdown_with(Layout::plain("p"))
                .starts_with("| p | window | n | refine / repair | lr |\n|---|---|")
        );
        assert_eq!(
            t.wide_csv("offset"),
            "offset,window,n,refine / repair,lr\n\
             \"-8, x\",k_e-8 … k_e-1,40,3 / 5,0.0015\n\
             0,a,,0 / 0,\n"
        );
        // The report's layout of the same table: no label header, the legend, then the note.
        let report = t.markdown();
        assert!(report.starts_with("| | window |"), "{report}");
        assert!(report.contains("\nOurs first, the paper's value in parentheses;"));
        assert!(report.ends_with("\nA note.\n"), "{report}");
    }

    #[test]
    fn a_sheet_shows_people_its_labels_and_programs_its_keys() {
        let mut s = Sheet::new(vec![
            Field::new("sets", "sets", Unit::Count),
            Field::markdown("refine / repair", Unit::Text),
            Field::csv("refine", Unit::Count),
            Field::csv("repair", Unit::Count),
            Field::new("coverage", "coverage", Unit::Percent),
            Field::csv("paper_coverage", Unit::Percent),
        ]);
        s.push(
            "geodesic",
            vec![
                Cell::one(4.0),
                Cell::text("3 / 1"),
                Cell::one(3.0),
                Cell::one(1.0),
                Cell::new(Value::One(0.5), Some("91.8%")),
                Cell::one(0.918),
            ],
        );
        let s = s.with_note("a note");
        assert_eq!(
            s.markdown_with(Layout::plain("generator")),
            "| generator | sets | refine / repair | coverage |\n|---|---:|---|---:|\n\
             | geodesic | 4 | 3 / 1 | 50.0% (91.8%) |\n\na note\n"
        );
        assert_eq!(
            s.wide_csv("generator"),
            "generator,sets,refine,repair,coverage,paper_coverage\ngeodesic,4,3,1,0.5,0.918\n"
        );
    }
}
