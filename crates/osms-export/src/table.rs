//! A flat table of nullable scalar columns, written as CSV and as one Parquet file: what
//! per-rollout results need (the LeRobot writer's columns hold lists and never a null).
//!
//! CSV: a header of column names, then one line per row; a null is an empty cell, booleans
//! are `true` / `false`, floats are Rust's shortest representation that reads back to the same
//! `f64`. Parquet: every column `OPTIONAL` (a null is definition level 0), one row group,
//! Snappy-compressed pages. Both are pure functions of the table.

use std::sync::Arc;

use parquet::basic::{Compression, LogicalType, Repetition, Type as PhysicalType};
use parquet::data_type::{BoolType, ByteArray, ByteArrayType, DataType, DoubleType, Int64Type};
use parquet::errors::ParquetError;
use parquet::file::properties::WriterProperties;
use parquet::file::writer::{SerializedColumnWriter, SerializedFileWriter};
use parquet::schema::types::Type;

use crate::Error;

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
        let err = |e: ParquetError| Error::Format(format!("cannot write Parquet: {e}"));
        let fields = self
            .columns
            .iter()
            .map(|c| field(c).map(Arc::new))
            .collect::<Result<Vec<_>, _>>()
            .map_err(err)?;
        let schema = Type::group_type_builder("schema")
            .with_fields(fields)
            .build()
            .map_err(err)?;
        let props = WriterProperties::builder()
            .set_compression(Compression::SNAPPY)
            .build();
        let mut writer = SerializedFileWriter::new(Vec::new(), Arc::new(schema), Arc::new(props))
            .map_err(err)?;
        let mut rg = writer.next_row_group().map_err(err)?;
        for col in &self.columns {
            let mut cw = rg.next_column().map_err(err)?.ok_or_else(|| {
                Error::Format(format!("no Parquet column left for `{}`", col.name))
            })?;
            write_column(&mut cw, &col.cells).map_err(err)?;
            cw.close().map_err(err)?;
        }
        rg.close().map_err(err)?;
        writer.into_inner().map_err(err)
    }
}

/// The column's `OPTIONAL` Parquet field.
fn field(col: &Column) -> Result<Type, ParquetError> {
    let (physical, logical) = match col.cells {
        Cells::Int(_) => (PhysicalType::INT64, None),
        Cells::Float(_) => (PhysicalType::DOUBLE, None),
        Cells::Bool(_) => (PhysicalType::BOOLEAN, None),
        Cells::Text(_) => (PhysicalType::BYTE_ARRAY, Some(LogicalType::String)),
    };
    Type::primitive_type_builder(&col.name, physical)
        .with_repetition(Repetition::OPTIONAL)
        .with_logical_type(logical)
        .build()
}

/// The defined values and the definition levels (1 defined, 0 null) of `cells`.
fn levels<T: Clone>(cells: &[Option<T>]) -> (Vec<T>, Vec<i16>) {
    let values = cells.iter().flatten().cloned().collect();
    let def = cells.iter().map(|c| i16::from(c.is_some())).collect();
    (values, def)
}

fn write_typed<D: DataType>(
    cw: &mut SerializedColumnWriter<'_>,
    values: &[D::T],
    def: &[i16],
) -> Result<(), ParquetError> {
    cw.typed::<D>().write_batch(values, Some(def), None)?;
    Ok(())
}

fn write_column(cw: &mut SerializedColumnWriter<'_>, cells: &Cells) -> Result<(), ParquetError> {
    match cells {
        Cells::Int(v) => {
            let (values, def) = levels(v);
            write_typed::<Int64Type>(cw, &values, &def)
        }
        Cells::Float(v) => {
            let (values, def) = levels(v);
            write_typed::<DoubleType>(cw, &values, &def)
        }
        Cells::Bool(v) => {
            let (values, def) = levels(v);
            write_typed::<BoolType>(cw, &values, &def)
        }
        Cells::Text(v) => {
            let (values, def) = levels(v);
            let values: Vec<ByteArray> =
                values.iter().map(|s| ByteArray::from(s.as_str())).collect();
            write_typed::<ByteArrayType>(cw, &values, &def)
        }
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
