//! `cms-host export`: a recording's profiles as JSON lines or CSV.

use std::fs::File;
use std::io::{Read, Write};
use std::path::Path;

use cms_core::protocol::DeviceMsg;

use super::{
    CSV_HEADER, HEADER_LEN, Header, HostRecord, Item, RecordError, ScanStats, parse_header, read_block,
    scan_file_with_progress, write_csv, write_json_line,
};
use crate::progress::Progress;

/// What [`export_to`] writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    /// One line per point: `seq,part,timestamp_us,odometer_mm,laser,row,position_px,strength,width_px,flags,along_mm,height_um`.
    Csv,
    /// One JSON object per profile message, as `listen --json`.
    Jsonl,
    /// The run's GNSS track as GeoJSON (RFC 7946): a `LineString` of the
    /// fixes from satellites, and a `Point` for every fix with its time,
    /// odometer and quality.
    Geojson,
    /// The event marks as CSV: [`crate::recording::mark::CSV_HEADER`].
    Marks,
}

/// Opens a recording and checks its header (before an export creates its
/// output, say).
pub fn check_header(path: &Path) -> Result<Header, RecordError> {
    let f = File::open(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        what: "cannot open recording",
        source,
    })?;
    let mut h = Vec::new();
    f.take(HEADER_LEN as u64).read_to_end(&mut h).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        what: "cannot read",
        source,
    })?;
    parse_header(&h).map_err(|why| RecordError::Format { path: path.to_path_buf(), why: why.to_string() })
}

/// The survey block of a recording, as stored (`None`: version 1, or none
/// given); a damaged block is an error naming the damage.
pub fn survey_of(path: &Path) -> Result<Option<String>, RecordError> {
    let f = File::open(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        what: "cannot open recording",
        source,
    })?;
    survey_from(path, f)
}

/// [`survey_of`] the recording read from `r` (its header first); `path`
/// names it in errors.
pub fn survey_from(path: &Path, mut r: impl Read) -> Result<Option<String>, RecordError> {
    let io_err = |source| RecordError::Io { path: path.to_path_buf(), what: "cannot read", source };
    let mut raw = Vec::with_capacity(HEADER_LEN);
    (&mut r).take(HEADER_LEN as u64).read_to_end(&mut raw).map_err(io_err)?;
    let header =
        parse_header(&raw).map_err(|why| RecordError::Format { path: path.to_path_buf(), why: why.to_string() })?;
    let block = read_block(&mut r, &raw, &header).map_err(io_err)?;
    match block.damage {
        Some((why, _)) => Err(RecordError::Format { path: path.to_path_buf(), why: format!("survey block: {why}") }),
        None => Ok(block.survey),
    }
}

/// Whether two paths name the same existing file.
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt as _;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
        _ => false,
    }
}

/// Exports the profiles of a recording to `out`; returns what reading found.
pub fn export_to(
    path: &Path,
    format: ExportFormat,
    out: &mut dyn Write,
    progress: &dyn Progress,
) -> Result<ScanStats, RecordError> {
    if format == ExportFormat::Geojson {
        return export_geojson(path, out, progress);
    }
    if format == ExportFormat::Marks {
        writeln!(out, "{}", super::mark::CSV_HEADER).map_err(RecordError::Output)?;
        let stats = super::reader::scan_file_records_with_progress(path, progress, |item| match item {
            Item::Host(HostRecord::Mark(m)) => writeln!(out, "{}", super::mark::csv_row(m)),
            _ => Ok(()),
        })?;
        out.flush().map_err(RecordError::Output)?;
        return Ok(stats);
    }
    if format == ExportFormat::Csv {
        writeln!(out, "{CSV_HEADER}").map_err(RecordError::Output)?;
    }
    let stats = scan_file_with_progress(path, progress, |msg| match msg {
        DeviceMsg::Profile(p) => match format {
            ExportFormat::Csv => write_csv(out, p),
            ExportFormat::Jsonl => write_json_line(out, p),
            ExportFormat::Geojson | ExportFormat::Marks => Ok(()),
        },
        _ => Ok(()),
    })?;
    out.flush().map_err(RecordError::Output)?;
    Ok(stats)
}

/// The run's fixes as one GeoJSON `FeatureCollection` (see [`ExportFormat::Geojson`]).
fn export_geojson(path: &Path, out: &mut dyn Write, progress: &dyn Progress) -> Result<ScanStats, RecordError> {
    use serde_json::{Value, json};
    let mut line: Vec<Value> = Vec::new();
    let mut points: Vec<Value> = Vec::new();
    let stats = super::reader::scan_file_records_with_progress(path, progress, |item| {
        if let Item::Host(HostRecord::Fix(p)) = item {
            let f = &p.fix;
            // RFC 7946: longitude, latitude, height; 1e-9 degrees is 0.1 mm.
            let round = |v: f64| (v * 1e9).round() / 1e9;
            let mut at = vec![json!(round(f.lon_deg)), json!(round(f.lat_deg))];
            if let Some(h) = f.altitude_m {
                at.push(json!((h * 1000.0).round() / 1000.0));
            }
            if f.quality.is_measured() {
                line.push(Value::Array(at.clone()));
            }
            points.push(json!({
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": at},
                "properties": {
                    "host_us": p.host_us,
                    "head_us": p.head_us,
                    "odometer_mm": p.odometer_um.map(|u| u as f64 / 1000.0),
                    "utc_ms_of_day": f.utc_ms_of_day,
                    "date": f.date.map(|(y, m, d)| format!("{y:04}-{m:02}-{d:02}")),
                    "quality": f.quality.name(),
                    "quality_code": f.quality.digit(),
                    "satellites": f.satellites,
                    "hdop": f.hdop,
                    "speed_mm_s": f.speed_mm_s,
                    "course_deg": f.course_deg,
                    "sigma_m": f.sigma_m(),
                }
            }));
        }
        Ok(())
    })?;
    let mut features = Vec::with_capacity(points.len() + 1);
    if line.len() >= 2 {
        features.push(json!({
            "type": "Feature",
            "geometry": {"type": "LineString", "coordinates": line},
            "properties": {"what": "the run's track: its fixes from satellites, in time order"}
        }));
    }
    features.extend(points);
    let doc = json!({"type": "FeatureCollection", "features": features});
    serde_json::to_writer(&mut *out, &doc).map_err(|e| RecordError::Output(e.into()))?;
    writeln!(out).map_err(RecordError::Output)?;
    out.flush().map_err(RecordError::Output)?;
    Ok(stats)
}
