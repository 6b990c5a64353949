//! The Parquet files: nullable fields (primitives or three-level `LIST` groups), one row group
//! per episode, Snappy-compressed pages, and osms's key-value metadata.

use std::fs;
use std::io;
use std::ops::Range;
use std::path::Path;
use std::sync::Arc;

use parquet::basic::{Compression, LogicalType, Repetition, Type as PhysicalType};
use parquet::data_type::{BoolType, ByteArray, ByteArrayType, DoubleType, FloatType, Int64Type};
use parquet::errors::ParquetError;
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;
use parquet::file::writer::{SerializedColumnWriter, SerializedFileWriter};
use parquet::schema::types::Type;

use super::columns::{Column, Values};
use crate::Error;

/// The nullable Parquet field of a column: a primitive, or a three-level `LIST` group.
pub(super) fn schema_field(col: &Column) -> Result<Type, ParquetError> {
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

/// Writes `columns` as one Parquet file, one row group per range of rows in `groups`.
pub(super) fn write_parquet(
    path: &Path,
    columns: &[&Column],
    groups: &[Range<usize>],
    metadata: Vec<KeyValue>,
) -> Result<(), Error> {
    let err = |e: ParquetError| Error::io(path, io::Error::other(e));
    let fields = columns
        .iter()
        .map(|c| schema_field(c).map(Arc::new))
        .collect::<Result<Vec<_>, _>>()
        .map_err(err)?;
    let schema = Type::group_type_builder("schema")
        .with_fields(fields)
        .build()
        .map_err(err)?;
    let props = WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .set_key_value_metadata(Some(metadata))
        .build();
    let file = fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut writer =
        SerializedFileWriter::new(file, Arc::new(schema), Arc::new(props)).map_err(err)?;
    for group in groups {
        let mut rg = writer.next_row_group().map_err(err)?;
        for col in columns {
            let Some(mut cw) = rg.next_column().map_err(err)? else {
                return Err(Error::Format(format!(
                    "{}: no Parquet column left for {}",
                    path.display(),
                    col.name
                )));
            };
            write_column(&mut cw, col, group.clone()).map_err(err)?;
            cw.close().map_err(err)?;
        }
        rg.close().map_err(err)?;
    }
    writer.close().map_err(err)?;
    Ok(())
}

/// Writes the rows `rows` of one column with its definition and repetition levels: a
/// scalar is defined at level 1; a list's values at level 3 (list, repeated group, element),
/// an empty list at level 1, each list starting at repetition level 0.
pub(super) fn write_column(
    cw: &mut SerializedColumnWriter<'_>,
    col: &Column,
    rows: Range<usize>,
) -> Result<(), ParquetError> {
    let (values, def, rep) = match &col.offsets {
        None => (rows.clone(), vec![1i16; rows.len()], None),
        Some(off) => {
            let (Some(&a), Some(&b)) = (off.get(rows.start), off.get(rows.end)) else {
                return Err(ParquetError::General(format!(
                    "{}: rows {rows:?} out of range",
                    col.name
                )));
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
            (a..b, def, Some(rep))
        }
    };
    let rep = rep.as_deref();
    let out_of_range = || ParquetError::General(format!("{}: values out of range", col.name));
    match &col.values {
        Values::F32(v) => {
            let v = v.get(values).ok_or_else(out_of_range)?;
            cw.typed::<FloatType>().write_batch(v, Some(&def), rep)?;
        }
        Values::F64(v) => {
            let v = v.get(values).ok_or_else(out_of_range)?;
            cw.typed::<DoubleType>().write_batch(v, Some(&def), rep)?;
        }
        Values::I64(v) => {
            let v = v.get(values).ok_or_else(out_of_range)?;
            cw.typed::<Int64Type>().write_batch(v, Some(&def), rep)?;
        }
        Values::Bool(v) => {
            let v = v.get(values).ok_or_else(out_of_range)?;
            cw.typed::<BoolType>().write_batch(v, Some(&def), rep)?;
        }
        Values::Str(v) => {
            let v: Vec<ByteArray> = v
                .get(values)
                .ok_or_else(out_of_range)?
                .iter()
                .map(|s| ByteArray::from(s.as_str()))
                .collect();
            cw.typed::<ByteArrayType>()
                .write_batch(&v, Some(&def), rep)?;
        }
    }
    Ok(())
}
