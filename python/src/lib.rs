//! `cms`, the host library's analysis for Python: recordings read and
//! analysed exactly as `cms-host analyze` does ([`cms_host::analyze::runs`]),
//! the tables of its Parquet exports ([`cms_host::report::exports`]) handed
//! to pyarrow, and the report's JSON as the summary.
//!
//! # Zero-copy
//!
//! The exports' columns are Rust vectors of optional values, not Arrow's
//! layout, so one pass is needed whatever the route. That pass writes each
//! Arrow buffer (values, validity bitmap, string offsets and bytes)
//! straight into a Python `bytes` object allocated at its final size
//! ([`PyBytes::new_with`]); the Python side wraps those objects as Arrow
//! buffers (`pa.py_buffer`, `pa.Array.from_buffers`) without copying them.
//! So each value is written once, by Rust, into the memory the Arrow table
//! then uses. The analysis runs with the GIL released (a Dask worker's
//! other threads go on).
//!
//! The arrow crates are not used: the columns are flat, and the buffers
//! above are all Arrow needs (the same reason the exports use the
//! low-level Parquet writer).

use std::path::PathBuf;

use cms_host::analyze::RunsAllowed;
use cms_host::analyze::reprofiling::Edition;
use cms_host::analyze::runs::{self, Range, Request, Settings};
use cms_host::analyze::stitch::{Direction, Registration};
use cms_host::analyze::survey::Placement;
use cms_host::report::exports::{self, Table, Values};
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyList};

pyo3::create_exception!(
    _cms,
    Error,
    PyException,
    "A failure of the analysis, with the one-line message `cms-host analyze` prints after `error: `."
);

/// The error's chain as one line, as the command line prints it: each
/// cause's text, skipping a cause its outer message already quotes.
fn message(e: &(dyn std::error::Error + 'static)) -> String {
    let mut line = String::new();
    let mut cause = Some(e);
    while let Some(c) = cause {
        let text = c.to_string();
        if !line.contains(&text) {
            if !line.is_empty() {
                line.push_str(": ");
            }
            line.push_str(&text);
        }
        cause = c.source();
    }
    cms_host::input::one_line(&line, 2000)
}

fn py_err(e: cms_host::Error) -> PyErr {
    Error::new_err(message(&e))
}

/// A flag's error as the command line words it (`--block-m 0: …`).
fn flag_err(flag: &str, value: &str, e: cms_host::Error) -> PyErr {
    Error::new_err(format!("invalid value '{value}' for '{flag}': {e}"))
}

fn checked(range: Range, flag: &str, v: f64) -> PyResult<f64> {
    range.check(v).map_err(|e| flag_err(flag, &v.to_string(), e))
}

/// One column for Python: (name, kind, nullable, rows, null count,
/// buffers). `kind` and the buffers: `f64`/`i32`/`bool` — [validity or
/// None, values]; `str` — [validity or None, int32 offsets, UTF-8 bytes];
/// `repeat` — [the one string's bytes] (a dictionary of one value);
/// `list_f64` — [validity or None, int32 offsets, the elements' f64s].
type PyColumn<'py> = (String, &'static str, bool, usize, usize, Vec<Option<Bound<'py, PyBytes>>>);

/// A Python bytes object of `len` bytes, filled by `fill` (zeroed first).
fn buffer<'py>(py: Python<'py>, len: usize, fill: impl FnOnce(&mut [u8])) -> PyResult<Bound<'py, PyBytes>> {
    PyBytes::new_with(py, len, |b| {
        fill(b);
        Ok(())
    })
}

/// Arrow's validity bitmap (bit i of byte i/8, least significant first),
/// `None` when no value is null; and the null count.
fn validity<'py, T>(py: Python<'py>, v: &[Option<T>]) -> PyResult<(Option<Bound<'py, PyBytes>>, usize)> {
    let nulls = v.iter().filter(|x| x.is_none()).count();
    if nulls == 0 {
        return Ok((None, 0));
    }
    let bits = buffer(py, v.len().div_ceil(8), |b| {
        for (i, x) in v.iter().enumerate() {
            if x.is_some() {
                b[i / 8] |= 1 << (i % 8);
            }
        }
    })?;
    Ok((Some(bits), nulls))
}

/// Fixed-width values, a null's slot zero.
fn fixed<'py, T: Copy + Default, const N: usize>(
    py: Python<'py>,
    v: &[Option<T>],
    bytes: fn(T) -> [u8; N],
) -> PyResult<Bound<'py, PyBytes>> {
    buffer(py, v.len() * N, |b| {
        for (chunk, x) in b.chunks_exact_mut(N).zip(v) {
            chunk.copy_from_slice(&bytes(x.unwrap_or_default()));
        }
    })
}

/// Arrow's int32 offsets of variable-length values (strings, lists): a
/// null's length zero. The caller has checked that the lengths sum within
/// `i32`.
fn offsets<'py, T>(py: Python<'py>, v: &[Option<T>], len: fn(&T) -> usize) -> PyResult<Bound<'py, PyBytes>> {
    buffer(py, (v.len() + 1) * 4, |b| {
        let mut at = 0i32;
        b[..4].copy_from_slice(&at.to_le_bytes());
        for (chunk, x) in b[4..].chunks_exact_mut(4).zip(v) {
            at += x.as_ref().map_or(0, |x| len(x) as i32);
            chunk.copy_from_slice(&at.to_le_bytes());
        }
    })
}

fn column<'py>(py: Python<'py>, c: &exports::Column) -> PyResult<PyColumn<'py>> {
    let name = c.name.clone();
    let too_long = || Error::new_err(format!("column {name}: over 2 GiB of text (Arrow's 32-bit offsets)"));
    Ok(match &c.values {
        Values::F64(v) => {
            let (valid, nulls) = validity(py, v)?;
            (name, "f64", c.nullable, v.len(), nulls, vec![valid, Some(fixed(py, v, f64::to_le_bytes)?)])
        }
        Values::I32(v) => {
            let (valid, nulls) = validity(py, v)?;
            (name, "i32", c.nullable, v.len(), nulls, vec![valid, Some(fixed(py, v, i32::to_le_bytes)?)])
        }
        Values::Bool(v) => {
            let (valid, nulls) = validity(py, v)?;
            let bits = buffer(py, v.len().div_ceil(8), |b| {
                for (i, x) in v.iter().enumerate() {
                    if *x == Some(true) {
                        b[i / 8] |= 1 << (i % 8);
                    }
                }
            })?;
            (name, "bool", c.nullable, v.len(), nulls, vec![valid, Some(bits)])
        }
        Values::Str(v) => {
            let (valid, nulls) = validity(py, v)?;
            let total: usize = v.iter().flatten().map(String::len).sum();
            if i32::try_from(total).is_err() {
                return Err(too_long());
            }
            let offsets = offsets(py, v, String::len)?;
            let data = buffer(py, total, |b| {
                let mut at = 0;
                for s in v.iter().flatten() {
                    b[at..at + s.len()].copy_from_slice(s.as_bytes());
                    at += s.len();
                }
            })?;
            (name, "str", c.nullable, v.len(), nulls, vec![valid, Some(offsets), Some(data)])
        }
        Values::ListF64(v) => {
            let (valid, nulls) = validity(py, v)?;
            let total: usize = v.iter().flatten().map(Vec::len).sum();
            if i32::try_from(total).is_err() {
                return Err(Error::new_err(format!("column {name}: over 2³¹ list elements (Arrow's 32-bit offsets)")));
            }
            let offsets = offsets(py, v, Vec::len)?;
            let data = buffer(py, total * 8, |b| {
                for (chunk, x) in b.chunks_exact_mut(8).zip(v.iter().flatten().flatten()) {
                    chunk.copy_from_slice(&x.to_le_bytes());
                }
            })?;
            (name, "list_f64", c.nullable, v.len(), nulls, vec![valid, Some(offsets), Some(data)])
        }
        Values::Repeat(text, n) => (
            name,
            "repeat",
            c.nullable,
            *n,
            0,
            vec![Some(buffer(py, text.len(), |b| b.copy_from_slice(text.as_bytes()))?)],
        ),
    })
}

fn table<'py>(py: Python<'py>, t: &Table) -> PyResult<Bound<'py, PyList>> {
    let cols = t.columns.iter().map(|c| column(py, c)).collect::<PyResult<Vec<_>>>()?;
    PyList::new(py, cols)
}

fn edition(s: &str) -> PyResult<Edition> {
    match s {
        "2006" => Ok(Edition::En2006),
        "2012" => Ok(Edition::En2012),
        _ => {
            Err(Error::new_err(format!("invalid value '{s}' for '--edition <EDITION>' [possible values: 2006, 2012]")))
        }
    }
}

fn direction(s: Option<&str>) -> PyResult<Direction> {
    match s {
        None | Some("auto") => Ok(Direction::Auto),
        Some("forward") => Ok(Direction::Forward),
        Some("reverse") => Ok(Direction::Reverse),
        Some(o) => Err(Error::new_err(format!(
            "invalid value '{o}' for '--direction <DIRECTION>' [possible values: auto, forward, reverse]"
        ))),
    }
}

fn registration(s: Option<&str>) -> PyResult<Registration> {
    match s {
        None | Some("joint") => Ok(Registration::Joint),
        Some("joint-pitch") => Ok(Registration::JointPitch),
        Some("offset") => Ok(Registration::Offset),
        Some("offset-tilt") => Ok(Registration::OffsetTilt),
        Some("none") => Ok(Registration::None),
        Some(o) => Err(Error::new_err(format!(
            "invalid value '{o}' for '--register <REGISTER>' [possible values: joint, joint-pitch, offset-tilt, offset, none]"
        ))),
    }
}

/// The four tables (profile, blocks, zones, third octaves) as lists of
/// columns (the profile `None` when not asked for), and the report's JSON text.
type Analysed<'py> = (Option<Bound<'py, PyList>>, Bound<'py, PyList>, Bound<'py, PyList>, Bound<'py, PyList>, String);

/// `cms-host analyze PATHS… --json --parquet`: the tables (profile,
/// blocks, zones, third octaves) as lists of columns and the report's JSON text.
#[pyfunction]
#[pyo3(signature = (
    paths, chainage=None, edition="2006", block_m=50.0, search_m=25.0, dx_mm=None, direction=None,
    register=None, segment_mm=1000.0, spike_removal=true, curvature=true, calibration=None,
    allow_repeated_runs=false, allow_mixed_heads=false, profile=true, track_register=None
))]
#[allow(clippy::too_many_arguments)]
fn analyze<'py>(
    py: Python<'py>,
    paths: Vec<PathBuf>,
    chainage: Option<Vec<String>>,
    edition: &str,
    block_m: f64,
    search_m: f64,
    dx_mm: Option<f64>,
    direction: Option<&str>,
    register: Option<&str>,
    segment_mm: f64,
    spike_removal: bool,
    curvature: bool,
    calibration: Option<PathBuf>,
    allow_repeated_runs: bool,
    allow_mixed_heads: bool,
    profile: bool,
    track_register: Option<PathBuf>,
) -> PyResult<Analysed<'py>> {
    if paths.is_empty() {
        return Err(Error::new_err("the following required arguments were not provided: <RECORDING|PROFILE.csv>..."));
    }
    let placements = placements(chainage)?;
    let settings = Settings {
        edition: self::edition(edition)?,
        block_m: checked(Range::BlockM, "--block-m <M>", block_m)?,
        dx_mm: dx_mm.map(|v| checked(Range::DxMm, "--dx-mm <MM>", v)).transpose()?,
        direction: self::direction(direction)?,
        registration: registration(register)?,
        segment_mm: checked(Range::SegmentMm, "--segment-mm <MM>", segment_mm)?,
        remove_spikes: spike_removal,
        curvature,
    };
    let search_m = checked(Range::SearchM, "--search-m <M>", search_m)?;
    let only_recordings = [
        ("--calibration", calibration.is_some()),
        ("--direction", direction.is_some()),
        ("--register", register.is_some()),
        ("--allow-repeated-runs", allow_repeated_runs),
        ("--allow-mixed-heads", allow_mixed_heads),
        ("--track-register", track_register.is_some()),
    ];
    let req = Request {
        inputs: paths,
        placements,
        calibration,
        allowed: RunsAllowed { repeats: allow_repeated_runs, mixed_heads: allow_mixed_heads },
        search_mm: search_m * 1000.0,
        dx_mm,
        recording_only: only_recordings.iter().filter(|(_, given)| *given).map(|(f, _)| f.to_string()).collect(),
        track_register,
        optics: None,
    };
    let opts = settings.options();
    let (source, a) = py.detach(|| runs::run(&req, &opts, &cms_host::progress::Silent)).map_err(py_err)?;
    let summary = cms_host::report::json::to_json(&source, &a).to_string();
    // One row per sample: only when asked (a fleet's job has no use for it).
    let profile = match profile {
        true => Some(table(py, &py.detach(|| exports::profile_table(&source, &a)).map_err(py_err)?)?),
        false => None,
    };
    Ok((
        profile,
        table(py, &exports::blocks_table(&source, &a))?,
        table(py, &exports::zones_table(&source, &a))?,
        table(py, &exports::third_octaves_table(&source, &a))?,
        summary,
    ))
}

/// The trend's table (as lists of columns, its `*_date` columns as Arrow
/// `date32`) and the JSON text of `cms-host trend --json`.
type Trended<'py> = (Bound<'py, PyList>, String);

/// `cms-host trend PATHS… --json`: the surveys read and analysed by the
/// command's own code ([`cms_host::report::trend::survey_runs`]), the
/// trend of [`cms_host::analyze::trend::trend`].
#[pyfunction]
#[pyo3(signature = (paths, dates=None, chainage=None, edition="2006", block_m=50.0, search_m=2.0, horizon_years=10.0, track_register=None))]
#[allow(clippy::too_many_arguments)]
fn trend<'py>(
    py: Python<'py>,
    paths: Vec<PathBuf>,
    dates: Option<Vec<String>>,
    chainage: Option<Vec<String>>,
    edition: &str,
    block_m: f64,
    search_m: f64,
    horizon_years: f64,
    track_register: Option<PathBuf>,
) -> PyResult<Trended<'py>> {
    use cms_host::analyze::trend as tr;
    use cms_host::recording::survey_info::SurveyDate;
    if paths.is_empty() {
        return Err(Error::new_err("the following required arguments were not provided: <RECORDING>..."));
    }
    let placements = placements(chainage)?;
    let dates = dates
        .unwrap_or_default()
        .iter()
        .map(|d| {
            d.parse::<SurveyDate>()
                .map_err(|e| Error::new_err(format!("invalid value '{d}' for '--date <YYYY-MM-DD>': {e}")))
        })
        .collect::<PyResult<Vec<_>>>()?;
    let in_range = |flag: &str, v: f64, lo: f64, hi: f64, open: bool, what: &str| {
        if v.is_finite() && (v > lo || (!open && v == lo)) && v <= hi {
            Ok(v)
        } else {
            let above = if open { "above " } else { "" };
            Err(Error::new_err(format!("invalid value '{v}' for '{flag}': `{v}` is not {what} ({above}{lo} to {hi})")))
        }
    };
    let block_m = in_range("--block-m <M>", block_m, 1.0, 1000.0, false, "a block length in m")?;
    let search_m = in_range("--search-m <M>", search_m, 0.0, 100.0, true, "a search distance in m")?;
    let horizon_years = in_range("--horizon-years <Y>", horizon_years, 1.0, 100.0, false, "a horizon in years")?;
    let opts = cms_host::analyze::Options {
        verdict: cms_host::analyze::reprofiling::Options {
            edition: self::edition(edition)?,
            block_mm: block_m * 1000.0,
        },
        ..cms_host::analyze::Options::default()
    };
    let topts = tr::Options { search_mm: search_m * 1000.0, horizon_years, ..tr::Options::default() };
    let t = py
        .detach(|| -> Result<tr::Trend, cms_host::Error> {
            let surveys = cms_host::report::trend::survey_runs(
                &paths,
                &placements,
                &dates,
                track_register.as_deref(),
                &opts,
                &cms_host::progress::Silent,
            )?;
            Ok(tr::trend(&surveys, &topts)?)
        })
        .map_err(py_err)?;
    let mut cols = Vec::new();
    for c in &cms_host::report::trend::trend_table(&t).columns {
        let mut c = column(py, c)?;
        if c.0.ends_with("_date") {
            c.1 = "date32";
        }
        cols.push(c);
    }
    Ok((PyList::new(py, cols)?, cms_host::report::trend::json(&t)))
}

fn placements(chainage: Option<Vec<String>>) -> PyResult<Vec<Placement>> {
    chainage
        .unwrap_or_default()
        .iter()
        .map(|c| {
            c.parse::<Placement>()
                .map_err(|e| Error::new_err(format!("invalid value '{c}' for '--chainage <KM+M[:up|:down]>': {e}")))
        })
        .collect()
}

/// The survey block of a recording as JSON text (`null`: none), checked
/// as `analyze` checks it; with its `date` as `year` besides.
#[pyfunction]
fn read_survey(py: Python<'_>, path: PathBuf) -> PyResult<String> {
    let text = py.detach(|| runs::survey(&path)).map_err(py_err)?;
    Ok(match text {
        Some(s) => {
            let year = s.date().ok().flatten().map(|d| d.year());
            let mut v = serde_json::to_value(&s).map_err(|e| Error::new_err(e.to_string()))?;
            v["year"] = serde_json::json!(year);
            v.to_string()
        }
        None => "null".into(),
    })
}

#[pymodule]
fn _cms(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(analyze, m)?)?;
    m.add_function(wrap_pyfunction!(read_survey, m)?)?;
    m.add_function(wrap_pyfunction!(trend, m)?)?;
    m.add("Error", m.py().get_type::<Error>())?;
    m.add("SCHEMA_VERSION", exports::SCHEMA_VERSION)?;
    Ok(())
}
