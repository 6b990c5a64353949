//! The one Parquet writer of every export: `OPTIONAL` fields (primitives, or three-level
//! `LIST` groups), row groups at the ranges of rows the caller gives, Snappy-compressed pages
//! and optional key-value metadata. A pure function of its columns, so a file is the same
//! bytes wherever it is written.
//!
//! Levels: a scalar is defined at level 1 and a null at 0; a list's values at level 3 (list,
//! repeated group, element), an empty list at level 1, each list starting at repetition
//! level 0.

use std::io::Write;
use std::ops::Range;
use std::sync::Arc;

use parquet::basic::{Compression, LogicalType, Repetition, Type as PhysicalType};
use parquet::data_type::{
    BoolType, ByteArray, ByteArrayType, DataType, DoubleType, FloatType, Int64Type,
};
use parquet::errors::ParquetError;
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;
use parquet::file::writer::{SerializedColumnWriter, SerializedFileWriter};
use parquet::schema::types::Type;

/// A column's values, flattened row-major.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Values {
    F32(Vec<f32>),
    F64(Vec<f64>),
    I64(Vec<i64>),
    Bool(Vec<bool>),
    Str(Vec<String>),
}

/// One Parquet column: a scalar per row (null where `defined` says so), or a list per row
/// (`offsets` has rows + 1 entries).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Column {
    pub(crate) name: String,
    pub(crate) values: Values,
    pub(crate) offsets: Option<Vec<usize>>,
    /// Which rows of a scalar column hold a value; `None`: every row. A null row's slot in
    /// `values` is a placeholder that is never written.
    pub(crate) defined: Option<Vec<bool>>,
}

impl Column {
    /// A value per row.
    pub(crate) fn scalar(name: &str, values: Values) -> Column {
        Column {
            name: name.into(),
            values,
            offsets: None,
            defined: None,
        }
    }

    /// A value per row where `defined` holds, null elsewhere.
    pub(crate) fn nullable(name: &str, values: Values, defined: Vec<bool>) -> Column {
        Column {
            defined: Some(defined),
            ..Column::scalar(name, values)
        }
    }

    /// A list per row: row `r` holds `values[offsets[r] .. offsets[r + 1]]`.
    pub(crate) fn list(name: &str, values: Values, offsets: Vec<usize>) -> Column {
        Column {
            offsets: Some(offsets),
            ..Column::scalar(name, values)
        }
    }
}

/// The column's `OPTIONAL` field: a primitive, or a three-level `LIST` group.
fn field(col: &Column) -> Result<Type, ParquetError> {
    let (physical, logical) = match col.values {
        Values::F32(_) => (PhysicalType::FLOAT, None),
        Values::F64(_) => (PhysicalType::DOUBLE, None),
        Values::I64(_) => (PhysicalType::INT64, None),
        Values::Bool(_) => (PhysicalType::BOOLEAN, None),
        Values::Str(_) => (PhysicalType::BYTE_ARRAY, Some(LogicalType::String)),
    };
    let primitive = |name: &str| {
        Type::primitive_type_builder(name, physical)
            .with_repetition(Repetition::OPTIONAL)
            .with_logical_type(logical.clone())
            .build()
    };
    if col.offsets.is_none() {
        return primitive(&col.name);
    }
    let list = Type::group_type_builder("list")
        .with_repetition(Repetition::REPEATED)
        .with_fields(vec![Arc::new(primitive("element")?)])
        .build()?;
    Type::group_type_builder(&col.name)
        .with_repetition(Repetition::OPTIONAL)
        .with_logical_type(Some(LogicalType::List))
        .with_fields(vec![Arc::new(list)])
        .build()
}

/// Writes `columns` as one Parquet file into `out`, one row group per range of rows in
/// `groups`; returns `out`.
pub(crate) fn write<W: Write + Send>(
    out: W,
    columns: &[&Column],
    groups: &[Range<usize>],
    metadata: Option<Vec<KeyValue>>,
) -> Result<W, ParquetError> {
    let fields = columns
        .iter()
        .map(|c| field(c).map(Arc::new))
        .collect::<Result<Vec<_>, _>>()?;
    let schema = Type::group_type_builder("schema")
        .with_fields(fields)
        .build()?;
    let props = WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .set_key_value_metadata(metadata)
        .build();
    let mut writer = SerializedFileWriter::new(out, Arc::new(schema), Arc::new(props))?;
    for group in groups {
        let mut rg = writer.next_row_group()?;
        for col in columns {
            let Some(mut cw) = rg.next_column()? else {
                return Err(ParquetError::General(format!(
                    "no Parquet column left for `{}`",
                    col.name
                )));
            };
            write_column(&mut cw, col, group.clone())?;
            cw.close()?;
        }
        rg.close()?;
    }
    writer.into_inner()
}

/// Which of a column's values a row group writes.
enum Picked {
    /// A run of consecutive values (every row defined, or lists).
    Run(Range<usize>),
    /// The values of the defined rows.
    Rows(Vec<usize>),
}

impl Picked {
    fn of<'a, T>(&self, v: &'a [T]) -> Option<std::borrow::Cow<'a, [T]>>
    where
        T: Clone,
    {
        match self {
            Picked::Run(r) => v.get(r.clone()).map(std::borrow::Cow::Borrowed),
            Picked::Rows(rows) => rows
                .iter()
                .map(|&r| v.get(r).cloned())
                .collect::<Option<Vec<T>>>()
                .map(std::borrow::Cow::Owned),
        }
    }
}

/// Writes the rows `rows` of one column with its definition and repetition levels (see the
/// module's rules).
fn write_column(
    cw: &mut SerializedColumnWriter<'_>,
    col: &Column,
    rows: Range<usize>,
) -> Result<(), ParquetError> {
    let out_of_range =
        || ParquetError::General(format!("{}: rows {rows:?} out of range", col.name));
    let (picked, def, rep) = match (&col.offsets, &col.defined) {
        (None, None) => (Picked::Run(rows.clone()), vec![1i16; rows.len()], None),
        (None, Some(defined)) => {
            let defined = defined.get(rows.clone()).ok_or_else(out_of_range)?;
            let def = defined.iter().map(|&d| i16::from(d)).collect();
            let picked = rows
                .clone()
                .zip(defined)
                .filter(|(_, d)| **d)
                .map(|(r, _)| r);
            (Picked::Rows(picked.collect()), def, None)
        }
        (Some(off), _) => {
            let (Some(&a), Some(&b)) = (off.get(rows.start), off.get(rows.end)) else {
                return Err(out_of_range());
            };
            let mut def = Vec::with_capacity(b - a + rows.len());
            let mut rep = Vec::with_capacity(b - a + rows.len());
            for r in rows.clone() {
                let n = off[r + 1].saturating_sub(off[r]);
                if n == 0 {
                    def.push(1);
                    rep.push(0);
                }
                for k in 0..n {
                    def.push(3);
                    rep.push(i16::from(k > 0));
                }
            }
            (Picked::Run(a..b), def, Some(rep))
        }
    };
    let rep = rep.as_deref();
    fn put<D: DataType>(
        cw: &mut SerializedColumnWriter<'_>,
        values: &[D::T],
        def: &[i16],
        rep: Option<&[i16]>,
    ) -> Result<(), ParquetError> {
        cw.typed::<D>().write_batch(values, Some(def), rep)?;
        Ok(())
    }
    match &col.values {
        Values::F32(v) => put::<FloatType>(cw, &picked.of(v).ok_or_else(out_of_range)?, &def, rep),
        Values::F64(v) => put::<DoubleType>(cw, &picked.of(v).ok_or_else(out_of_range)?, &def, rep),
        Values::I64(v) => put::<Int64Type>(cw, &picked.of(v).ok_or_else(out_of_range)?, &def, rep),
        Values::Bool(v) => put::<BoolType>(cw, &picked.of(v).ok_or_else(out_of_range)?, &def, rep),
        Values::Str(v) => {
            let v: Vec<ByteArray> = picked
                .of(v)
                .ok_or_else(out_of_range)?
                .iter()
                .map(|s| ByteArray::from(s.as_str()))
                .collect();
            put::<ByteArrayType>(cw, &v, &def, rep)
        }
    }
}
