//! `cms-host export`: a recording's profiles as JSON lines or CSV.

use std::fs::File;
use std::io::{Read, Write};
use std::path::Path;

use cms_core::protocol::DeviceMsg;

use super::{
    CSV_HEADER, HEADER_LEN, Header, RecordError, ScanStats, parse_header, read_block, scan_file_with_progress,
    write_csv, write_json_line,
};
use crate::progress::Progress;

/// What [`export_to`] writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    /// One line per point: `seq,part,timestamp_us,odometer_mm,laser,row,position_px,strength,width_px,flags,along_mm,height_um`.
    Csv,
    /// One JSON object per profile message, as `listen --json`.
    Jsonl,
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
    if format == ExportFormat::Csv {
        writeln!(out, "{CSV_HEADER}").map_err(RecordError::Output)?;
    }
    let stats = scan_file_with_progress(path, progress, |msg| match msg {
        DeviceMsg::Profile(p) => match format {
            ExportFormat::Csv => write_csv(out, p),
            ExportFormat::Jsonl => write_json_line(out, p),
        },
        _ => Ok(()),
    })?;
    out.flush().map_err(RecordError::Output)?;
    Ok(stats)
}
