//! A flat table of nullable scalar columns, written as CSV and as one Parquet file: what
//! per-rollout results need (LeRobot's columns hold lists and never a null; both go through
//! the crate's one Parquet writer).
//!
//! CSV: a header of column names, then one line per row; a null is an empty cell, booleans
//! are `true` / `false`, floats are Rust's shortest representation that reads back to the same
//! `f64`. Parquet: every column `OPTIONAL` (a null is definition level 0), one row group,
//! Snappy-compressed pages. Both are pure functions of the table.

use crate::Error;
use crate::parquet_file::{self, Values};

/// The cells of one column, `None` where the value is undefined.
#[derive(Debug, Clone, PartialEq)]
pub enum Cells {
    Int(Vec<Option<i64>>),
    Float(Vec<Option<f64>>),
    Bool(Vec<Option<bool>>),
    Text(Vec<Option<String>>),
}

impl Cells {
    fn len(&self) -> usize {
        match self {
            Cells::Int(v) => v.len(),
            Cells::Float(v) => v.len(),
            Cells::Bool(v) => v.len(),
            Cells::Text(v) => v.len(),
        }
    }

    /// Row `r` as a CSV cell (empty for a null).
    fn csv(&self, r: usize) -> String {
        match self {
            Cells::Int(v) => v[r].map(|x| x.to_string()),
            Cells::Float(v) => v[r].map(|x| x.to_string()),
            Cells::Bool(v) => v[r].map(|x| x.to_string()),
            Cells::Text(v) => v[r].as_deref().map(csv_text),
        }
        .unwrap_or_default()
    }
}

/// One named column.
#[derive(Debug, Clone, PartialEq)]
pub struct Column {
    pub name: String,
    pub cells: Cells,
}

impl Column {
    pub fn new(name: &str, cells: Cells) -> Self {
        Column {
            name: name.to_string(),
            cells,
        }
    }
}

/// Columns of equal length.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Table {
    pub columns: Vec<Column>,
}

impl Table {
    /// The number of rows: every column's length (checked by [`Table::check`]).
    pub fn rows(&self) -> usize {
        self.columns.first().map_or(0, |c| c.cells.len())
    }

    /// Column names, in order.
    pub fn names(&self) -> Vec<&str> {
        self.columns.iter().map(|c| c.name.as_str()).collect()
    }

    /// Every column has [`Table::rows`] cells and a name of its own.
    pub fn check(&self) -> Result<(), Error> {
        let rows = self.rows();
        for (i, c) in self.columns.iter().enumerate() {
            if c.cells.len() != rows {
                return Err(Error::Format(format!(
                    "column `{}` has {} cells, the table {rows} rows",
                    c.name,
                    c.cells.len()
                )));
            }
            if self.columns[..i].iter().any(|o| o.name == c.name) {
                return Err(Error::Format(format!("column `{}` appears twice", c.name)));
            }
        }
        Ok(())
    }

    /// The table as CSV (RFC 4180 quoting, `\n` line ends).
    pub fn csv(&self) -> Result<String, Error> {
        self.check()?;
        let line = |cells: Vec<String>| cells.join(",") + "\n";
        let mut out = line(self.columns.iter().map(|c| csv_text(&c.name)).collect());
        for r in 0..self.rows() {
            out.push_str(&line(self.columns.iter().map(|c| c.cells.csv(r)).collect()));
        }
        Ok(out)
    }

    /// The table as the bytes of one Parquet file.
    pub fn parquet(&self) -> Result<Vec<u8>, Error> {
        self.check()?;
        let columns: Vec<parquet_file::Column> = self.columns.iter().map(Column::parquet).collect();
        let refs: Vec<&parquet_file::Column> = columns.iter().collect();
        // One row group holding every row (`write` takes a list of row ranges).
        let one_group = 0..self.rows();
        parquet_file::write(Vec::new(), &refs, std::slice::from_ref(&one_group), None)
            .map_err(|e| Error::Format(format!("cannot write Parquet: {e}")))
    }
}

impl Column {
    /// The column as a nullable Parquet column (a null's slot holds a placeholder).
    fn parquet(&self) -> parquet_file::Column {
        fn values<T: Clone + Default>(cells: &[Option<T>]) -> Vec<T> {
            cells
                .iter()
                .map(|c| c.clone().unwrap_or_default())
                .collect()
        }
        fn defined<T>(cells: &[Option<T>]) -> Vec<bool> {
            cells.iter().map(Option::is_some).collect()
        }
        let (values, defined) = match &self.cells {
            Cells::Int(v) => (Values::I64(values(v)), defined(v)),
            Cells::Float(v) => (Values::F64(values(v)), defined(v)),
            Cells::Bool(v) => (Values::Bool(values(v)), defined(v)),
            Cells::Text(v) => (Values::Str(values(v)), defined(v)),
        };
        parquet_file::Column::nullable(&self.name, values, defined)
    }
}

/// A text cell, quoted when it holds a comma, a quote or a line break.
fn csv_text(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_of_unequal_length_or_a_repeated_name_are_refused() {
        let t = Table {
            columns: vec![
                Column::new("a", Cells::Int(vec![Some(1), None])),
                Column::new("b", Cells::Bool(vec![Some(true)])),
            ],
        };
        assert!(t.csv().is_err());
        let t = Table {
            columns: vec![
                Column::new("a", Cells::Int(vec![Some(1)])),
                Column::new("a", Cells::Int(vec![Some(2)])),
            ],
        };
        assert!(t.parquet().is_err());
    }

    #[test]
    fn text_with_commas_and_quotes_is_quoted() {
        let t = Table {
            columns: vec![
                Column::new("x,y", Cells::Text(vec![Some("say \"hi\"".into()), None])),
                Column::new("n", Cells::Float(vec![Some(0.1), Some(-2.5e-7)])),
            ],
        };
        assert_eq!(
            t.csv().expect("csv"),
            "\"x,y\",n\n\"say \"\"hi\"\"\",0.1\n,-0.00000025\n"
        );
    }
}
