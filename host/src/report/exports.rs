//! `analyze --parquet DIR` (and `--report DIR`): the survey as Parquet
//! files that DuckDB, Polars or Spark read without our code —
//! `profile.parquet` (the stitched profile, one row per sample),
//! `blocks.parquet` (block RMS and ISO 3095 per block) and
//! `zones.parquet` (the exceedance zones), `fixes.parquet` (the runs'
//! GNSS fixes, placed on the chainage), `third_octaves.parquet` (each
//! block's ISO 3095 third octaves, of each line and of their energy
//! average: level, floor, limit, rail level with its interval, verdict). The schema is documented in
//! docs/exports.md; every file of every survey has the same columns for
//! the same lines, and a `source` column naming the inputs, so a fleet's
//! files concatenate (`read_parquet('*/profile.parquet', union_by_name = true)`).
//!
//! # Why these choices
//!
//! - The `parquet` crate's low-level column writer, without its `arrow`
//!   feature and without compression codecs: the data are a few flat
//!   columns, and arrow's crates would add build time for nothing
//!   (docs/exports.md has the measured cost). Version 59, not 60: 60 marks
//!   DOUBLE columns with the IEEE 754 total order, whose footer older
//!   readers refuse.
//! - Dictionary encoding (the writer's default) keeps the `source` column,
//!   the same string on every row, to a few bytes per page; plain
//!   encoding elsewhere. Data pages v1, the most widely read.
//! - Gaps are nulls (definition level 0), never NaN: `AVG`, `COUNT` and
//!   `IS NULL` then mean what an analyst expects.
//! - Each file is built in memory and written through
//!   [`crate::output::write_atomically`], the three as one output set
//!   ([`crate::output::set`]): the folder holds the old files or the new
//!   ones, never a mix. Nothing here panics on any analysis.
//!
//! # Cost
//!
//! One pass over the stitched samples; the profile file is 8 bytes per
//! sample and line plus chainage and coverage (~40 bytes a sample for
//! three lines: a 340 m survey at 1 mm is ~14 MB, held in memory once
//! while it is written, beside the analysis itself).

use std::path::Path;
use std::sync::Arc;

use parquet::basic::Compression;
use parquet::column::writer::ColumnWriter;
use parquet::data_type::ByteArray;
use parquet::file::metadata::KeyValue;
use parquet::file::properties::{WriterProperties, WriterVersion};
use parquet::file::writer::SerializedFileWriter;
use parquet::schema::types::Type;

use crate::Error;
use crate::analyze::pieces::Piece;
use crate::analyze::standards::{detection, en13231, en15610};
use crate::analyze::{Analysis, Source, reprofiling};
use crate::output::AtomicFile;

/// Version of the schema below, in each file's key-value metadata as `cms.schema`.
pub const SCHEMA_VERSION: &str = "cms-host analyze exports 4";

/// One column's values.
#[derive(Debug, Clone, PartialEq)]
pub enum Values {
    /// `DOUBLE`, `None` a null.
    F64(Vec<Option<f64>>),
    /// `INT32`.
    I32(Vec<Option<i32>>),
    /// `BOOLEAN`.
    Bool(Vec<Option<bool>>),
    /// `BYTE_ARRAY` annotated `STRING` (UTF-8).
    Str(Vec<Option<String>>),
    /// A `STRING` column of one value on every one of so many rows (the
    /// profile's `source`: one copy in memory, not one per sample).
    Repeat(String, usize),
    /// `LIST` of `DOUBLE` (the elements never null), `None` a null list
    /// (not the empty one).
    ListF64(Vec<Option<Vec<f64>>>),
}

impl Values {
    /// Appends another column's values of the same type (a mismatch is
    /// left out: the tables built here never mix them).
    fn append(&mut self, other: Values) {
        match (self, other) {
            (Values::F64(a), Values::F64(b)) => a.extend(b),
            (Values::I32(a), Values::I32(b)) => a.extend(b),
            (Values::Bool(a), Values::Bool(b)) => a.extend(b),
            (Values::Str(a), Values::Str(b)) => a.extend(b),
            (Values::Repeat(_, n), Values::Repeat(_, m)) => *n += m,
            (Values::ListF64(a), Values::ListF64(b)) => a.extend(b),
            _ => {}
        }
    }

    fn len(&self) -> usize {
        match self {
            Values::F64(v) => v.len(),
            Values::I32(v) => v.len(),
            Values::Bool(v) => v.len(),
            Values::Str(v) => v.len(),
            Values::Repeat(_, n) => *n,
            Values::ListF64(v) => v.len(),
        }
    }
}

/// A column: name, whether it may hold nulls, values.
#[derive(Debug, Clone, PartialEq)]
pub struct Column {
    pub name: String,
    pub nullable: bool,
    pub values: Values,
}

fn col(name: impl Into<String>, nullable: bool, values: Values) -> Column {
    Column { name: name.into(), nullable, values }
}

/// A table: columns of one length.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Table {
    pub columns: Vec<Column>,
}

impl Table {
    /// Rows (the first column's length; all are equal).
    pub fn rows(&self) -> usize {
        self.columns.first().map_or(0, |c| c.values.len())
    }
}

/// The column name of a band: `10_30` for 10–30 mm.
pub fn band_key(b: &en13231::Band) -> String {
    format!("{}_{}", b.lo_mm, b.hi_mm)
}

/// The lines of a survey line's sections, in number order.
fn line_numbers(a: &Analysis) -> Vec<usize> {
    let mut lines: Vec<usize> = a.lasers.iter().map(|l| l.stitched.laser).collect();
    lines.sort_unstable();
    lines.dedup();
    lines
}

/// The rows of [`profile_table`] of one piece of the line.
fn profile_rows(source: &str, lines: &[usize], p: &Piece) -> Table {
    let rows = p.core.len();
    let chainage_mm: Vec<Option<f64>> = p.core.clone().map(|i| Some(p.grid.chainage_mm(i))).collect();
    let mut coverage = vec![0i32; rows];
    let mut columns = vec![
        col("source", false, Values::Repeat(source.to_string(), rows)),
        col("chainage_mm", false, Values::F64(chainage_mm)),
    ];
    for k in lines {
        let l = p.lines.iter().find(|l| l.laser == *k);
        let h: Vec<Option<f64>> = (0..rows).map(|i| l.map(|l| l.z_um[i]).filter(|v| v.is_finite())).collect();
        for (c, v) in coverage.iter_mut().zip(&h) {
            *c += i32::from(v.is_some());
        }
        columns.push(col(format!("height_um_{k}"), true, Values::F64(h)));
    }
    columns.push(col("coverage", false, Values::I32(coverage.into_iter().map(Some).collect())));
    Table { columns }
}

/// The stitched profile on one grid per section, the sections one after
/// the other (the stretches between them, never measured, have no rows):
/// `source`, `chainage_mm`, `height_um_K` per line (null in gaps),
/// `coverage` (lines with data at the sample). Whole in memory: files
/// are written piece by piece ([`write()`]).
pub fn profile_table(source: &Source, a: &Analysis) -> Result<Table, Error> {
    let (name, lines) = (source.name(), line_numbers(a));
    let mut t: Option<Table> = None;
    a.for_each_piece(|p| {
        let rows = profile_rows(&name, &lines, p);
        match &mut t {
            None => t = Some(rows),
            Some(t) => {
                for (c, r) in t.columns.iter_mut().zip(rows.columns) {
                    c.values.append(r.values);
                }
            }
        }
        Ok(())
    })?;
    Ok(t.unwrap_or_else(|| profile_rows(&name, &lines, &Piece::empty())))
}

/// The ISO 3095 columns of one spectrum per block, named `PREFIX…SUFFIX`:
/// `iso3095_verdict` ("within", "EXCEEDS", "not judged"), and the
/// third octaves of each verdict, `iso3095_within_mm`,
/// `iso3095_exceeded_mm`, `iso3095_not_judged_mm` (all null without a spectrum).
fn iso3095_columns(suffix: &str, of: Vec<Option<&reprofiling::Iso3095>>) -> [Column; 4] {
    let list = |f: fn(&reprofiling::Iso3095) -> &Vec<f64>| {
        Values::ListF64(of.iter().map(|i| i.map(|i| f(i).clone())).collect())
    };
    let verdict = of.iter().map(|i| i.and_then(|i| i.verdict()).map(|v| v.name().to_string())).collect();
    [
        col(format!("iso3095_verdict{suffix}"), true, Values::Str(verdict)),
        col(format!("iso3095_within_mm{suffix}"), true, list(|i| &i.within_mm)),
        col(format!("iso3095_exceeded_mm{suffix}"), true, list(|i| &i.exceeded_mm)),
        col(format!("iso3095_not_judged_mm{suffix}"), true, list(|i| &i.not_judged_mm)),
    ]
}

/// The blocks: `source`, `start_chainage_mm`, `end_chainage_mm`,
/// `rms_um_LO_HI` per band (largest line; null where not evaluated),
/// `floor_rms_um_LO_HI` per band (one line's noise floor; null where not
/// known); the ISO 3095 verdict of the lines' EN 15610 spectra
/// energy-averaged (`iso3095_columns`, [`crate::analyze::standards::detection`])
/// and of each line K against its own floor (the same columns, `_K` after
/// the name; null where the line has no spectrum in the block).
pub fn blocks_table(source: &Source, a: &Analysis) -> Table {
    let b = &a.verdict.blocks;
    let n = b.len();
    let f = |v: Vec<f64>| Values::F64(v.into_iter().map(Some).collect());
    let s = |v: Vec<String>| Values::Str(v.into_iter().map(Some).collect());
    let mut columns = vec![
        col("source", false, s(vec![source.name(); n])),
        col("start_chainage_mm", false, f(b.iter().map(|b| b.start_mm).collect())),
        col("end_chainage_mm", false, f(b.iter().map(|b| b.end_mm).collect())),
    ];
    for (k, band) in en13231::BANDS.iter().enumerate() {
        let v = b.iter().map(|b| b.rms_mm.get(k).copied().flatten().map(|v| v * 1000.0)).collect();
        columns.push(col(format!("rms_um_{}", band_key(band)), true, Values::F64(v)));
    }
    for (k, band) in en13231::BANDS.iter().enumerate() {
        let v = b.iter().map(|b| b.floor_rms_mm.get(k).copied().flatten().map(|v| v * 1000.0)).collect();
        columns.push(col(format!("floor_rms_um_{}", band_key(band)), true, Values::F64(v)));
    }
    columns.extend(iso3095_columns("", b.iter().map(|b| b.iso3095.as_ref()).collect()));
    for k in line_numbers(a) {
        let line = b.iter().map(|b| b.iso3095_lines.iter().find(|(l, _)| *l == k).map(|(_, i)| i)).collect();
        columns.extend(iso3095_columns(&format!("_{k}"), line));
    }
    Table { columns }
}

/// A row of [`third_octaves_table`]: the block, the line (`None`: the
/// energy average), the third octave and its decision.
type OctaveRow<'a> = (&'a reprofiling::Block, Option<i32>, &'a en15610::ThirdOctave, detection::Decision);

/// Each block's ISO 3095 third octaves, one row per (block, spectrum,
/// third octave), blocks in chainage order, the lines' energy average
/// first and then each line, long wavelengths first: `source`,
/// `start_chainage_mm`, `end_chainage_mm`, `laser` (the line, numbered
/// as `--json`'s `laser`; null: the energy average — not `line`, which
/// names the railway line in a survey block and a fleet's dataset),
/// `wavelength_mm` (nominal), `level_db` (the reading, noise included;
/// null where it is no finite level), `floor_db` (null: not known), `limit_db`, `rail_db`,
/// `rail_lo_db`, `rail_hi_db` (the rail's level with the floor's power
/// taken out and its interval; null where the reading is at or under the
/// floor, or the bound is open), `verdict` ("within", "EXCEEDS", "not
/// judged"), all in dB re 1 µm — the figures of `--json`'s
/// `verdict.blocks[].iso3095.bands` and `lines[].iso3095.bands`.
pub fn third_octaves_table(source: &Source, a: &Analysis) -> Table {
    let mut rows: Vec<OctaveRow> = Vec::new();
    for b in &a.verdict.blocks {
        let lines = b.iso3095_lines.iter().map(|(k, i)| (i32::try_from(*k).ok(), i));
        for (line, iso) in b.iso3095.as_ref().map(|i| (None, i)).into_iter().chain(lines) {
            rows.extend(iso.bands.iter().filter_map(|t| Some((b, line, t, t.decision()?))));
        }
    }
    let f = |g: &dyn Fn(&OctaveRow) -> Option<f64>| Values::F64(rows.iter().map(g).collect());
    Table {
        columns: vec![
            col("source", false, Values::Str(vec![Some(source.name()); rows.len()])),
            col("start_chainage_mm", false, f(&|r| Some(r.0.start_mm))),
            col("end_chainage_mm", false, f(&|r| Some(r.0.end_mm))),
            col("laser", true, Values::I32(rows.iter().map(|r| r.1).collect())),
            col("wavelength_mm", false, f(&|r| Some(r.2.nominal_wavelength_mm))),
            col("level_db", true, f(&|r| Some(r.3.level_db).filter(|v| v.is_finite()))),
            col("floor_db", true, f(&|r| r.3.floor_db.filter(|v| v.is_finite()))),
            col("limit_db", false, f(&|r| Some(r.3.limit_db))),
            col("rail_db", true, f(&|r| r.3.rail.db)),
            col("rail_lo_db", true, f(&|r| r.3.rail.lo_db)),
            col("rail_hi_db", true, f(&|r| r.3.rail.hi_db)),
            col("verdict", false, Values::Str(rows.iter().map(|r| Some(r.3.verdict.name().to_string())).collect())),
        ],
    }
}

/// The zones: `source`, `edition`, `band_lo_mm`, `band_hi_mm`,
/// `start_chainage_mm`, `end_chainage_mm`, `exceeding_mm`, `worst_pp_mm`.
pub fn zones_table(source: &Source, a: &Analysis) -> Table {
    let z = &a.verdict.zones;
    let n = z.len();
    let f = |v: Vec<f64>| Values::F64(v.into_iter().map(Some).collect());
    let s = |v: Vec<String>| Values::Str(v.into_iter().map(Some).collect());
    Table {
        columns: vec![
            col("source", false, s(vec![source.name(); n])),
            col("edition", false, s(vec![a.verdict.options.edition.name().to_string(); n])),
            col("band_lo_mm", false, f(z.iter().map(|z| z.band.lo_mm).collect())),
            col("band_hi_mm", false, f(z.iter().map(|z| z.band.hi_mm).collect())),
            col("start_chainage_mm", false, f(z.iter().map(|z| z.start_mm).collect())),
            col("end_chainage_mm", false, f(z.iter().map(|z| z.end_mm).collect())),
            col("exceeding_mm", false, f(z.iter().map(|z| z.exceeding_mm).collect())),
            col("worst_pp_mm", false, f(z.iter().map(|z| z.worst_pp_mm).collect())),
        ],
    }
}

/// The runs' GNSS fixes (`listen --gnss`), run by run in file order, one
/// row each: `source`, `run` (from 1), `host_time_s` (host arrival since
/// the listener started), `head_time_s`, `odometer_mm` (of the frame before
/// the fix; null before any), `chainage_mm` (that odometer placed as the
/// run was joined), `utc_date` (`YYYY-MM-DD`), `utc_time_of_day_s`,
/// `lat_deg`, `lon_deg` (WGS 84), `altitude_m`, `quality`, `satellites`,
/// `hdop`, `sigma_m` (the horizontal uncertainty assumed), `speed_mm_s`,
/// `course_deg`. No rows without fixes (or for a profile file).
pub fn fixes_table(source: &Source, a: &Analysis) -> Table {
    let fixes: Vec<(usize, &crate::gnss::Placed)> = match source {
        Source::Recordings(recs) => {
            recs.iter().enumerate().flat_map(|(k, (_, r))| r.fixes.iter().map(move |p| (k + 1, p))).collect()
        }
        Source::Profile(..) => Vec::new(),
    };
    let n = fixes.len();
    let f = |g: &dyn Fn(&(usize, &crate::gnss::Placed)) -> Option<f64>| Values::F64(fixes.iter().map(g).collect());
    let odometer_mm = |p: &crate::gnss::Placed| p.odometer_um.map(|o| o as f64 / 1000.0);
    let join = |run: usize| a.joins.iter().find(|j| j.run == run);
    Table {
        columns: vec![
            col("source", false, Values::Str(vec![Some(source.name()); n])),
            col("run", false, Values::I32(fixes.iter().map(|(k, _)| i32::try_from(*k).ok()).collect())),
            col("host_time_s", false, f(&|(_, p)| Some(p.host_us as f64 / 1e6))),
            col("head_time_s", true, f(&|(_, p)| p.head_us.map(|t| t as f64 / 1e6))),
            col("odometer_mm", true, f(&|(_, p)| odometer_mm(p))),
            col("chainage_mm", true, f(&|(k, p)| Some(join(*k)?.chainage_mm(odometer_mm(p)?)))),
            col(
                "utc_date",
                true,
                Values::Str(
                    fixes.iter().map(|(_, p)| p.fix.date.map(|(y, m, d)| format!("{y:04}-{m:02}-{d:02}"))).collect(),
                ),
            ),
            col("utc_time_of_day_s", true, f(&|(_, p)| p.fix.utc_ms_of_day.map(|t| f64::from(t) / 1e3))),
            col("lat_deg", false, f(&|(_, p)| Some(p.fix.lat_deg))),
            col("lon_deg", false, f(&|(_, p)| Some(p.fix.lon_deg))),
            col("altitude_m", true, f(&|(_, p)| p.fix.altitude_m)),
            col("quality", false, Values::Str(fixes.iter().map(|(_, p)| Some(p.fix.quality.name().into())).collect())),
            col("satellites", true, Values::I32(fixes.iter().map(|(_, p)| p.fix.satellites.map(i32::from)).collect())),
            col("hdop", true, f(&|(_, p)| p.fix.hdop)),
            col("sigma_m", false, f(&|(_, p)| Some(p.fix.sigma_m()))),
            col("speed_mm_s", true, f(&|(_, p)| p.fix.speed_mm_s)),
            col("course_deg", true, f(&|(_, p)| p.fix.course_deg)),
        ],
    }
}

fn perr(e: parquet::errors::ParquetError) -> std::io::Error {
    std::io::Error::other(format!("parquet: {e}"))
}

/// The Parquet schema of a table (`message cms_NAME { … }`).
fn schema(name: &str, t: &Table) -> Result<Type, std::io::Error> {
    use parquet::basic::{LogicalType, Repetition, Type as Physical};
    let mut fields = Vec::new();
    for c in &t.columns {
        let rep = if c.nullable { Repetition::OPTIONAL } else { Repetition::REQUIRED };
        if let Values::ListF64(_) = c.values {
            // The three-level LIST of the format's spec, elements required.
            let element =
                Type::primitive_type_builder("element", Physical::DOUBLE).with_repetition(Repetition::REQUIRED).build();
            let list = Type::group_type_builder("list")
                .with_repetition(Repetition::REPEATED)
                .with_fields(vec![Arc::new(element.map_err(perr)?)])
                .build()
                .map_err(perr)?;
            let f = Type::group_type_builder(&c.name)
                .with_repetition(rep)
                .with_logical_type(Some(LogicalType::List))
                .with_fields(vec![Arc::new(list)])
                .build()
                .map_err(perr)?;
            fields.push(Arc::new(f));
            continue;
        }
        let (physical, logical) = match c.values {
            Values::F64(_) | Values::ListF64(_) => (Physical::DOUBLE, None),
            Values::I32(_) => (Physical::INT32, None),
            Values::Bool(_) => (Physical::BOOLEAN, None),
            Values::Str(_) | Values::Repeat(..) => (Physical::BYTE_ARRAY, Some(LogicalType::String)),
        };
        let f = Type::primitive_type_builder(&c.name, physical)
            .with_repetition(rep)
            .with_logical_type(logical)
            .build()
            .map_err(perr)?;
        fields.push(Arc::new(f));
    }
    Type::group_type_builder(&format!("cms_{name}")).with_fields(fields).build().map_err(perr)
}

/// Splits optional values into the present ones and definition levels.
fn levels<T: Clone>(v: &[Option<T>], nullable: bool) -> Result<(Vec<T>, Option<Vec<i16>>), std::io::Error> {
    let present: Vec<T> = v.iter().flatten().cloned().collect();
    if nullable {
        Ok((present, Some(v.iter().map(|x| i16::from(x.is_some())).collect())))
    } else if present.len() == v.len() {
        Ok((present, None))
    } else {
        Err(std::io::Error::other("a null in a required column"))
    }
}

/// A list column's elements, definition levels and repetition levels.
type ListLevels = (Vec<f64>, Vec<i16>, Vec<i16>);

/// A list column's elements with their definition and repetition levels:
/// per row, a null list is (0, 0), an empty one (1, 0) in a nullable
/// column; each element is one level above, its first repetition 0 and
/// the others 1.
fn list_levels(v: &[Option<Vec<f64>>], nullable: bool) -> Result<ListLevels, std::io::Error> {
    let base = i16::from(nullable);
    let (mut p, mut d, mut r) = (Vec::new(), Vec::new(), Vec::new());
    for row in v {
        match row {
            None if !nullable => return Err(std::io::Error::other("a null in a required column")),
            None => {
                d.push(0);
                r.push(0);
            }
            Some(e) if e.is_empty() => {
                d.push(base);
                r.push(0);
            }
            Some(e) => {
                for (i, x) in e.iter().enumerate() {
                    p.push(*x);
                    d.push(base + 1);
                    r.push(i16::from(i > 0));
                }
            }
        }
    }
    Ok((p, d, r))
}

/// The writer properties of every file: `cms.schema` and `meta` as key-value metadata.
fn properties(meta: &[(&str, String)]) -> WriterProperties {
    let mut kv = vec![KeyValue::new("cms.schema".into(), SCHEMA_VERSION.to_string())];
    kv.extend(meta.iter().map(|(k, v)| KeyValue::new((*k).into(), v.clone())));
    WriterProperties::builder()
        .set_writer_version(WriterVersion::PARQUET_1_0)
        .set_compression(Compression::UNCOMPRESSED)
        .set_created_by(format!("cms-host {}", env!("CARGO_PKG_VERSION")))
        .set_key_value_metadata(Some(kv))
        .build()
}

/// A table as the bytes of a Parquet file (one row group), with `meta` as
/// key-value metadata besides `cms.schema`.
pub fn to_parquet(name: &str, t: &Table, meta: &[(&str, String)]) -> Result<Vec<u8>, std::io::Error> {
    let mut buf = Vec::new();
    let mut w =
        SerializedFileWriter::new(&mut buf, Arc::new(schema(name, t)?), Arc::new(properties(meta))).map_err(perr)?;
    row_group(&mut w, t)?;
    w.close().map_err(perr)?;
    Ok(buf)
}

/// Writes a table as one row group of `w` (the schema's columns in order).
fn row_group<W: std::io::Write + Send>(w: &mut SerializedFileWriter<W>, t: &Table) -> Result<(), std::io::Error> {
    let rows = t.rows();
    if let Some(c) = t.columns.iter().find(|c| c.values.len() != rows) {
        return Err(std::io::Error::other(format!("column {} has {} rows of {rows}", c.name, c.values.len())));
    }
    let mut rg = w.next_row_group().map_err(perr)?;
    for c in &t.columns {
        let Some(mut cw) = rg.next_column().map_err(perr)? else {
            return Err(std::io::Error::other("fewer columns in the schema than in the table"));
        };
        let written = match (cw.untyped(), &c.values) {
            (ColumnWriter::DoubleColumnWriter(w), Values::F64(v)) => {
                let (p, d) = levels(v, c.nullable)?;
                w.write_batch(&p, d.as_deref(), None)
            }
            (ColumnWriter::Int32ColumnWriter(w), Values::I32(v)) => {
                let (p, d) = levels(v, c.nullable)?;
                w.write_batch(&p, d.as_deref(), None)
            }
            (ColumnWriter::DoubleColumnWriter(w), Values::ListF64(v)) => {
                let (p, d, r) = list_levels(v, c.nullable)?;
                w.write_batch(&p, Some(&d), Some(&r))
            }
            (ColumnWriter::BoolColumnWriter(w), Values::Bool(v)) => {
                let (p, d) = levels(v, c.nullable)?;
                w.write_batch(&p, d.as_deref(), None)
            }
            (ColumnWriter::ByteArrayColumnWriter(w), Values::Str(v)) => {
                let (p, d) = levels(v, c.nullable)?;
                let p: Vec<ByteArray> = p.iter().map(|s| ByteArray::from(s.as_str())).collect();
                w.write_batch(&p, d.as_deref(), None)
            }
            (ColumnWriter::ByteArrayColumnWriter(w), Values::Repeat(text, n)) => {
                // Batches of clones of one buffer (a reference count each).
                let chunk = vec![ByteArray::from(text.as_str()); (*n).min(1 << 16)];
                let mut left = *n;
                let mut r = Ok(0);
                while left > 0 && r.is_ok() {
                    let k = left.min(chunk.len());
                    r = w.write_batch(&chunk[..k], None, None);
                    left -= k;
                }
                r
            }
            _ => return Err(std::io::Error::other(format!("column {}: writer of another type", c.name))),
        };
        written.map_err(perr)?;
        cw.close().map_err(perr)?;
    }
    rg.close().map_err(perr)?;
    Ok(())
}

/// `profile.parquet` written a row group per piece of the line (never
/// whole in memory), from a walk along the line ([`Analysis::for_each_piece`])
/// that may write other files too.
pub(crate) struct ProfileParquet {
    w: SerializedFileWriter<AtomicFile>,
    path: std::path::PathBuf,
    name: String,
    lines: Vec<usize>,
}

impl ProfileParquet {
    /// Starts `dir/profile.parquet` for `a`'s lines.
    pub(crate) fn create(dir: &Path, source: &Source, a: &Analysis) -> Result<ProfileParquet, Error> {
        let path = dir.join(FILES[0]);
        let (name, lines) = (source.name(), line_numbers(a));
        let empty = profile_rows(&name, &lines, &Piece::empty());
        let file = AtomicFile::create(&path)?;
        let schema = schema("profile", &empty).map_err(|e| file.failed(e))?;
        let w = SerializedFileWriter::new(file, Arc::new(schema), Arc::new(properties(&meta(source, a))))
            .map_err(|e| Error::Output(std::io::Error::other(format!("{}: {e}", path.display()))))?;
        Ok(ProfileParquet { w, path, name, lines })
    }

    fn failed(&self, e: impl std::fmt::Display) -> Error {
        Error::Output(std::io::Error::other(format!("{}: {e}", self.path.display())))
    }

    /// Writes one piece's rows as a row group.
    pub(crate) fn piece(&mut self, p: &Piece) -> Result<(), Error> {
        let rows = profile_rows(&self.name, &self.lines, p);
        row_group(&mut self.w, &rows).map_err(|e| self.failed(e))
    }

    /// Writes the footer and puts the file in place.
    pub(crate) fn commit(self) -> Result<(), Error> {
        let failed = |e: parquet::errors::ParquetError| {
            Error::Output(std::io::Error::other(format!("{}: {e}", self.path.display())))
        };
        let file = self.w.into_inner().map_err(failed)?;
        Ok(file.commit()?)
    }
}

/// Every file's key-value metadata.
fn meta(source: &Source, a: &Analysis) -> Vec<(&'static str, String)> {
    vec![
        ("cms.source", source.name()),
        ("cms.dx_mm", a.options.stitch.dx_mm.to_string()),
        ("cms.edition", a.verdict.options.edition.name().to_string()),
        ("cms.block_mm", a.verdict.options.block_mm.to_string()),
    ]
}

/// The file names written by [`write()`].
pub const FILES: [&str; 5] =
    ["profile.parquet", "blocks.parquet", "zones.parquet", "fixes.parquet", "third_octaves.parquet"];

/// Whether a file of this name is one of [`FILES`].
pub fn owns(name: &str) -> bool {
    FILES.contains(&name)
}

/// Writes `profile.parquet`, `blocks.parquet`, `zones.parquet`, `fixes.parquet` and
/// `third_octaves.parquet` into
/// `dir` (created if missing) as one output set ([`crate::output::set`]):
/// the folder then holds these files and nothing else, or — on any
/// failure, or a crash — what it held before. Any failure is an error
/// naming the file.
pub fn write(dir: &Path, source: &Source, a: &Analysis) -> Result<(), Error> {
    crate::output::set::write_set(dir, owns, |d| write_files(d, source, a))
}

/// Writes the five files into `dir` (one file at a time, each whole).
pub(crate) fn write_files(dir: &Path, source: &Source, a: &Analysis) -> Result<(), Error> {
    let mut profile = ProfileParquet::create(dir, source, a)?;
    a.for_each_piece(|p| profile.piece(p))?;
    profile.commit()?;
    write_tables(dir, source, a)
}

/// Writes `blocks.parquet`, `zones.parquet`, `fixes.parquet` and `third_octaves.parquet` into `dir`.
pub(crate) fn write_tables(dir: &Path, source: &Source, a: &Analysis) -> Result<(), Error> {
    let meta = meta(source, a);
    let tables = [
        ("blocks", blocks_table(source, a)),
        ("zones", zones_table(source, a)),
        ("fixes", fixes_table(source, a)),
        ("third_octaves", third_octaves_table(source, a)),
    ];
    for ((name, t), file) in tables.iter().zip(&FILES[1..]) {
        let path = dir.join(file);
        let bytes = to_parquet(name, t, &meta)
            .map_err(|e| Error::Output(std::io::Error::other(format!("{}: {e}", path.display()))))?;
        crate::output::write_atomically(&path, |w| w.write_all(&bytes)).map_err(|e| match e {
            // A directory that cannot take the file is an output failure here.
            crate::output::OutputError::NotRegular { .. } => Error::from(e),
            e => Error::Output(std::io::Error::other(e.to_string())),
        })?;
    }
    Ok(())
}
