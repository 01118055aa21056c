//! `cms-host view RECORDING…`: a recording in the browser, after the run —
//! the stitched profile along the track with zoom, the bands' zones and
//! the blocks, the frames to scrub through, and the figures of the
//! analysis.
//!
//! What it shows is `cms-host analyze`'s: the inputs go through
//! [`crate::analyze::runs::run`] with the same options, and the page's
//! figures are [`crate::report::json::to_json`] of that analysis, the
//! object `analyze --json` prints. The profile plot asks the server for
//! the stretch it shows (`GET /api/profile?from_mm=…&to_mm=…&bins=…`): each
//! bin's lowest and highest height per line, so a zoom on a kilometre
//! shows every peak and a zoom on a metre every sample; heights are
//! relative to each line's median, as in the report's plot.
//!
//! Frames: up to [`MAX_FRAMES_KEPT`] of the recording's, evenly spaced
//! (every frame of a short run), each line's points thinned to at most
//! [`MAX_FRAME_POINTS`] (`GET /api/frame?i=…`); memory is set by those
//! limits and by the analysis, not by the number of frames.
//!
//! The server is the live view's (the refusals and headers of `serve`'s HTTP side):
//! loopback unless an address is given, off loopback only with the run's
//! token ([`super::access`]), read-only (GET and HEAD), every asset
//! embedded, every malformed query a 400 naming the parameter.

use std::fmt::Write as _;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use axum::Router;
use axum::extract::{Request, State};
use axum::http::{StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use serde_json::json;

use super::ServeError;
use super::access::{Token, page_url, token_for};
use super::tls::Tls;
use crate::Error;
use crate::analyze::runs::{self, Request as AnalysisRequest};
use crate::analyze::store::{Samples, ScratchError};
use crate::analyze::{self, Analysis, Options, Source};
use crate::progress::Progress;

/// Most frames kept for scrubbing.
pub const MAX_FRAMES_KEPT: usize = 4000;
/// Most points per line of a kept frame.
pub const MAX_FRAME_POINTS: usize = 480;
/// Most bins a profile request may ask for.
pub const MAX_BINS: usize = 8000;

const VIEW_HTML: &str = include_str!("page/view.html");
const VIEW_JS: &str = include_str!("page/view.js");
const APP_CSS: &str = include_str!("page/app.css");

/// One kept frame: its sequence number, odometer (mm) and points per line
/// (along the line, mm; height, µm), thinned.
#[derive(Debug, Clone)]
struct KeptFrame {
    seq: u32,
    odometer_mm: f64,
    lasers: Vec<Vec<[f32; 2]>>,
}

/// One stitched line as the plot reads it.
#[derive(Debug, Clone)]
struct PlotLine {
    laser: usize,
    section: usize,
    x0_mm: f64,
    dx_mm: f64,
    /// Heights, µm (NaN in gaps), read a stretch at a time.
    z: Samples,
    /// The line's median height (of at most 10⁵ samples spread along it), µm: taken off.
    median_um: f64,
}

/// Samples read at a time when a request spans a long line.
const READ_SAMPLES: usize = 1 << 20;

/// What the viewer serves: the analysis and the kept frames.
#[derive(Debug)]
pub struct View {
    /// `analyze --json` of the inputs.
    analysis_json: serde_json::Value,
    lines: Vec<PlotLine>,
    frames: Vec<KeptFrame>,
    /// Frames in the recordings.
    frames_total: usize,
    /// Kept: every this many.
    frame_every: usize,
    /// Why there are no frames to scrub, where there should be.
    frames_note: Option<String>,
}

impl View {
    /// Analyses `req` as `cms-host analyze` does and keeps the frames to
    /// scrub through (a second pass over each recording).
    pub fn open(req: &AnalysisRequest, opts: &Options, progress: &dyn Progress) -> Result<View, Error> {
        let (source, a) = runs::run(req, opts, progress)?;
        let analysis_json = crate::report::json::to_json(&source, &a);
        let lines = plot_lines(&a)?;
        let (frames, frames_total, frame_every) = match &source {
            Source::Recordings(recs) => {
                let total: usize = recs.iter().map(|(_, r)| r.frames).sum();
                let paths: Vec<&Path> = recs.iter().map(|(p, _)| p.as_path()).collect();
                keep_frames(&paths, total, progress)?
            }
            Source::Profile(..) => (Vec::new(), 0, 1),
        };
        let frames_note = None;
        Ok(View { analysis_json, lines, frames, frames_total, frame_every, frames_note })
    }

    /// A report folder (`analyze --report DIR`) as the viewer shows it: its
    /// `analysis.json` (the analysis, as `analyze --json` printed it), its
    /// `profile.parquet` (the stitched lines), and the frames of its
    /// recordings where they still are at the paths it names.
    pub fn open_report(dir: &Path, progress: &dyn Progress) -> Result<View, Error> {
        let name = dir.display();
        let json_path = dir.join("analysis.json");
        let text = std::fs::read_to_string(&json_path).map_err(|e| {
            Error::Input(format!(
                "{name}: no analysis.json ({e}): not a report folder of this cms-host (analyze --report)"
            ))
        })?;
        let analysis_json: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| Error::Input(format!("{}: not the analysis of a report: {e}", json_path.display())))?;
        let dx_mm = analysis_json["dx_mm"]
            .as_f64()
            .filter(|d| *d > 0.0 && d.is_finite())
            .ok_or_else(|| Error::Input(format!("{}: no sample spacing (dx_mm)", json_path.display())))?;
        let lines = report_lines(&dir.join("profile.parquet"), dx_mm)?;
        let runs = analysis_json["runs"].as_array().cloned().unwrap_or_default();
        let total = runs.iter().filter_map(|r| r["frames"].as_u64()).sum::<u64>() as usize;
        let paths: Vec<PathBuf> = runs.iter().filter_map(|r| r["recording"].as_str().map(PathBuf::from)).collect();
        let missing: Vec<String> = paths
            .iter()
            .filter(|p| !runs::is_recording(p).unwrap_or(false))
            .map(|p| crate::output::printable(&p.display().to_string()).into_owned())
            .collect();
        let (frames, frames_total, frame_every, frames_note) = if paths.is_empty() {
            (Vec::new(), 0, 1, None)
        } else if missing.is_empty() {
            let refs: Vec<&Path> = paths.iter().map(PathBuf::as_path).collect();
            let (f, t, e) = keep_frames(&refs, total, progress)?;
            (f, t, e, None)
        } else {
            let note = format!("no frames: the recording {} is not at the path the report names", missing.join(", "));
            (Vec::new(), total, 1, Some(note))
        };
        Ok(View { analysis_json, lines, frames, frames_total, frame_every, frames_note })
    }

    /// The chainage span of the stitched lines, mm.
    fn span_mm(&self) -> Option<(f64, f64)> {
        let lo = self.lines.iter().map(|l| l.x0_mm).fold(f64::INFINITY, f64::min);
        let hi = self.lines.iter().map(|l| l.x0_mm + l.z.len() as f64 * l.dx_mm).fold(f64::NEG_INFINITY, f64::max);
        (lo.is_finite() && hi > lo).then_some((lo, hi))
    }

    /// `GET /api/analysis`: the figures and what the plots can ask for.
    fn summary(&self) -> serde_json::Value {
        json!({
            "analysis": self.analysis_json,
            "span_mm": self.span_mm().map(|(lo, hi)| [lo, hi]),
            "lines": self.lines.iter().map(|l| json!({"laser": l.laser, "section": l.section})).collect::<Vec<_>>(),
            "frames_total": self.frames_total,
            "frames_kept": self.frames.len(),
            "frame_every": self.frame_every,
            "frames_note": self.frames_note,
        })
    }

    /// Each line's lowest and highest height in `bins` equal bins over
    /// `[from_mm, to_mm)` (null where a bin holds no sample of it).
    fn profile(&self, from_mm: f64, to_mm: f64, bins: usize) -> Result<serde_json::Value, Error> {
        let width = (to_mm - from_mm) / bins as f64;
        let lines: Vec<_> = self
            .lines
            .iter()
            .map(|l| {
                let mut lo = vec![f64::INFINITY; bins];
                let mut hi = vec![f64::NEG_INFINITY; bins];
                // Only the samples inside the stretch are read.
                let first = ((from_mm - l.x0_mm) / l.dx_mm).floor().max(0.0) as usize;
                let last = (((to_mm - l.x0_mm) / l.dx_mm).ceil().max(0.0) as usize).min(l.z.len());
                let mut at = first;
                while at < last {
                    let end = (at + READ_SAMPLES).min(last);
                    let z = l.z.read(at..end).map_err(ScratchError)?;
                    for (j, z) in z.iter().map(|z| z - l.median_um).enumerate() {
                        let x = l.x0_mm + (at + j) as f64 * l.dx_mm;
                        let b = ((x - from_mm) / width).floor();
                        if z.is_finite() && b >= 0.0 && (b as usize) < bins {
                            lo[b as usize] = lo[b as usize].min(z);
                            hi[b as usize] = hi[b as usize].max(z);
                        }
                    }
                    at = end;
                }
                let num = |v: f64| if v.is_finite() { json!((v * 1e3).round() / 1e3) } else { serde_json::Value::Null };
                Ok(json!({
                    "laser": l.laser,
                    "section": l.section,
                    "min_um": lo.into_iter().map(num).collect::<Vec<_>>(),
                    "max_um": hi.into_iter().map(num).collect::<Vec<_>>(),
                }))
            })
            .collect::<Result<_, Error>>()?;
        Ok(json!({ "from_mm": from_mm, "to_mm": to_mm, "bins": bins, "lines": lines }))
    }

    /// `GET /api/frame?i=…`: kept frame `i`.
    fn frame(&self, i: usize) -> Option<serde_json::Value> {
        let f = self.frames.get(i)?;
        Some(json!({
            "index": i,
            "frame": i * self.frame_every,
            "seq": f.seq,
            "odometer_mm": f.odometer_mm,
            // f32 widened with its own digits, not the binary expansion.
            "lasers": f.lasers.iter().map(|pts| pts.iter().map(|&[a, h]| {
                let r = |v: f32| (f64::from(v) * 1e3).round() / 1e3;
                [r(a), r(h)]
            }).collect::<Vec<_>>()).collect::<Vec<_>>(),
        }))
    }
}

/// The median of the finite values (0 without any).
fn median(z: &[f64]) -> f64 {
    let mut finite: Vec<f64> = z.iter().copied().filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return 0.0;
    }
    let mid = finite.len() / 2;
    *finite.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The median of at most 10⁵ samples spread evenly along a line (read a
/// stretch at a time), µm.
fn spread_median(z: &Samples) -> Result<f64, Error> {
    let stride = z.len() / 100_000 + 1;
    let mut picked = Vec::new();
    let mut at = 0;
    while at < z.len() {
        let end = (at + READ_SAMPLES).min(z.len());
        let v = z.read(at..end).map_err(ScratchError)?;
        // `READ_SAMPLES` is a multiple of any stride up to 2²⁰: the picks stay evenly spaced.
        picked.extend(v.iter().step_by(stride));
        at = end;
    }
    Ok(median(&picked))
}

/// The stitched lines, each less its median (as the report plots them).
fn plot_lines(a: &Analysis) -> Result<Vec<PlotLine>, Error> {
    a.lasers
        .iter()
        .map(|l| {
            let s = &l.stitched;
            Ok(PlotLine {
                laser: s.laser,
                section: s.section,
                x0_mm: s.x0_mm,
                dx_mm: s.dx_mm,
                median_um: spread_median(&s.z)?,
                z: s.z.clone(),
            })
        })
        .collect()
}

/// The lines of a report's `profile.parquet` (`chainage_mm`,
/// `height_um_K`): a section ends where the chainage jumps by more than
/// one and a half spacings (the file has no rows between sections); each
/// line of each section less its median.
fn report_lines(path: &Path, dx_mm: f64) -> Result<Vec<PlotLine>, Error> {
    use parquet::file::reader::{FileReader, SerializedFileReader};
    use parquet::record::Field;
    let name = path.display();
    let bad = |e: &dyn std::fmt::Display| Error::Input(format!("{name}: {e}"));
    let file = std::fs::File::open(path).map_err(|e| bad(&e))?;
    let reader = SerializedFileReader::new(file).map_err(|e| bad(&e))?;
    let schema = reader.metadata().file_metadata().schema_descr_ptr();
    let columns: Vec<String> = schema.columns().iter().map(|c| c.name().to_string()).collect();
    let chainage = columns.iter().position(|c| c == "chainage_mm").ok_or_else(|| bad(&"no chainage_mm column"))?;
    let lasers: Vec<(usize, usize)> = columns
        .iter()
        .enumerate()
        .filter_map(|(i, c)| c.strip_prefix("height_um_").and_then(|k| k.parse().ok()).map(|k| (i, k)))
        .collect();
    // (laser, section, x0, heights) while the file is read.
    let mut lines: Vec<(usize, usize, f64, Vec<f64>)> = Vec::new();
    let (mut section, mut last) = (0usize, f64::NEG_INFINITY);
    for row in reader.get_row_iter(None).map_err(|e| bad(&e))? {
        let row = row.map_err(|e| bad(&e))?;
        let fields: Vec<&Field> = row.get_column_iter().map(|(_, f)| f).collect();
        let Some(Field::Double(x)) = fields.get(chainage).copied() else {
            return Err(bad(&"a chainage_mm not a number"));
        };
        // The first row (after -inf), or a jump: a new section.
        if x - last > 1.5 * dx_mm {
            section += 1;
            lines.extend(lasers.iter().map(|&(_, k)| (k, section, *x, Vec::new())));
        }
        last = *x;
        let at = lines.len() - lasers.len();
        for (l, &(i, _)) in lines[at..].iter_mut().zip(&lasers) {
            l.3.push(match fields.get(i) {
                Some(Field::Double(z)) => *z,
                _ => f64::NAN,
            });
        }
    }
    // A line absent from a section is not a line of it.
    lines.retain(|l| l.3.iter().any(|z| z.is_finite()));
    Ok(lines
        .into_iter()
        .map(|(laser, section, x0_mm, z)| PlotLine {
            laser,
            section,
            x0_mm,
            dx_mm,
            median_um: median(&z),
            z: Samples::from_vec(z),
        })
        .collect())
}

/// Up to [`MAX_FRAMES_KEPT`] of the `total` frames of the recordings at
/// `paths`, evenly spaced: the frames, the total, the spacing.
fn keep_frames(
    paths: &[&Path],
    total: usize,
    progress: &dyn Progress,
) -> Result<(Vec<KeptFrame>, usize, usize), Error> {
    let every = total.div_ceil(MAX_FRAMES_KEPT).max(1);
    let mut kept = Vec::new();
    let mut n = 0usize;
    for path in paths {
        analyze::read_recording(path, progress, |_, f| {
            if n.is_multiple_of(every) {
                kept.push(thin(&f));
            }
            n += 1;
            Ok(())
        })?;
    }
    Ok((kept, total, every))
}

/// A frame's lines thinned to [`MAX_FRAME_POINTS`] each (every k-th point).
fn thin(f: &analyze::stitch::FramePoints) -> KeptFrame {
    let lasers = f
        .lasers
        .iter()
        .map(|pts| {
            let every = pts.len().div_ceil(MAX_FRAME_POINTS).max(1);
            pts.iter().step_by(every).map(|&(a, h)| [a as f32, h as f32]).collect()
        })
        .collect();
    KeptFrame { seq: f.seq, odometer_mm: f.odometer_mm, lasers }
}

/// A parameter of a query string, or why it cannot be used.
fn param<T: std::str::FromStr>(query: Option<&str>, name: &str) -> Result<T, String> {
    let value = query
        .unwrap_or("")
        .split('&')
        .filter_map(|kv| kv.split_once('='))
        .find(|(k, _)| *k == name)
        .map(|(_, v)| v)
        .ok_or_else(|| format!("missing query parameter {name}\n"))?;
    value.parse().map_err(|_| format!("query parameter {name}: not a number: {}\n", crate::output::printable(value)))
}

/// A running viewer.
pub struct Viewer {
    addr: SocketAddr,
    token: Option<Token>,
    https: bool,
    thread: std::thread::JoinHandle<()>,
}

impl Viewer {
    /// Serves `view` on `addr` (port 0: any free one), to whoever holds
    /// `token` where one is given, and off loopback to whoever holds a
    /// random one ([`super::access`]); over HTTPS where `tls` is given
    /// ([`super::tls`]).
    pub fn start(view: View, addr: SocketAddr, token: Option<Token>, tls: Option<Tls>) -> Result<Viewer, ServeError> {
        let token = token_for(addr, token)?;
        let listener = std::net::TcpListener::bind(addr).map_err(|source| ServeError::Bind { addr, source })?;
        let local = listener.local_addr().map_err(ServeError::Start)?;
        listener.set_nonblocking(true).map_err(ServeError::Start)?;
        let https = tls.is_some();
        let ctx = Ctx { view: Arc::new(view), local, token: token.clone(), https };
        let thread = std::thread::Builder::new()
            .name("cms-view".into())
            .spawn(move || {
                let Ok(rt) = tokio::runtime::Builder::new_current_thread().enable_io().enable_time().build() else {
                    return;
                };
                rt.block_on(async move {
                    let Ok(listener) = tokio::net::TcpListener::from_std(listener) else { return };
                    super::tls::serve(listener, router(ctx), tls, Arc::new(|| {})).await;
                });
            })
            .map_err(ServeError::Start)?;
        Ok(Viewer { addr: local, token, https, thread })
    }

    /// The address served.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The page's address, with the token where the viewer asks for one.
    pub fn url(&self) -> String {
        page_url(self.addr, self.token.as_ref(), self.https)
    }

    /// Serves until the process ends (Ctrl-C: the viewer writes nothing).
    pub fn wait(self) {
        let _ = self.thread.join();
    }
}

#[derive(Clone)]
struct Ctx {
    view: Arc<View>,
    local: SocketAddr,
    token: Option<Token>,
    https: bool,
}

fn router(ctx: Ctx) -> Router {
    let asset = |body: &'static str, mime: &'static str| ([(header::CONTENT_TYPE, mime)], body).into_response();
    Router::new()
        .route("/", get(move || async move { asset(VIEW_HTML, "text/html; charset=utf-8") }))
        .route("/view.js", get(move || async move { asset(VIEW_JS, "text/javascript; charset=utf-8") }))
        .route("/app.css", get(move || async move { asset(APP_CSS, "text/css; charset=utf-8") }))
        .route("/api/analysis", get(analysis))
        .route("/api/profile", get(profile))
        .route("/api/frame", get(frame))
        .fallback(|| async { (StatusCode::NOT_FOUND, "not found\n") })
        .layer(middleware::from_fn_with_state(ctx.clone(), guard))
        .with_state(ctx)
}

fn json_response(v: &serde_json::Value) -> Response {
    ([(header::CONTENT_TYPE, "application/json")], v.to_string()).into_response()
}

async fn analysis(State(ctx): State<Ctx>) -> Response {
    json_response(&ctx.view.summary())
}

async fn profile(State(ctx): State<Ctx>, req: Request) -> Response {
    let q = req.uri().query();
    let parsed = (|| -> Result<(f64, f64, usize), String> {
        let (from, to, bins) = (param::<f64>(q, "from_mm")?, param::<f64>(q, "to_mm")?, param::<usize>(q, "bins")?);
        if !(from.is_finite() && to.is_finite() && to > from) {
            return Err("from_mm and to_mm: finite, from_mm below to_mm\n".into());
        }
        if !(1..=MAX_BINS).contains(&bins) {
            return Err(format!("bins: 1 to {MAX_BINS}\n"));
        }
        Ok((from, to, bins))
    })();
    match parsed {
        Ok((from, to, bins)) => match ctx.view.profile(from, to, bins) {
            Ok(v) => json_response(&v),
            Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, format!("{e}\n")).into_response(),
        },
        Err(why) => (StatusCode::BAD_REQUEST, why).into_response(),
    }
}

async fn frame(State(ctx): State<Ctx>, req: Request) -> Response {
    let i = match param::<usize>(req.uri().query(), "i") {
        Ok(i) => i,
        Err(why) => return (StatusCode::BAD_REQUEST, why).into_response(),
    };
    match ctx.view.frame(i) {
        Some(v) => json_response(&v),
        None => {
            let mut why = String::new();
            let _ = writeln!(why, "i: {i} is past the {} frames kept", ctx.view.frames.len());
            (StatusCode::NOT_FOUND, why).into_response()
        }
    }
}

/// The live view's refusals: another host name on loopback, a method
/// other than GET or HEAD; and its headers on every response.
async fn guard(State(ctx): State<Ctx>, req: Request, next: Next) -> Response {
    let mut resp = match super::http::checked(&ctx.local, ctx.token.as_ref(), ctx.https, &req) {
        Err(r) => *r,
        Ok(_) if req.method() != axum::http::Method::GET && req.method() != axum::http::Method::HEAD => {
            (StatusCode::METHOD_NOT_ALLOWED, "the viewer is read-only\n").into_response()
        }
        Ok(cookie) => {
            let mut r = next.run(req).await;
            if let Some(c) = cookie {
                r.headers_mut().insert(header::SET_COOKIE, c);
            }
            r
        }
    };
    super::http::harden(resp.headers_mut());
    resp
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view() -> View {
        let line = |laser, x0_mm: f64, z: Vec<f64>| PlotLine {
            laser,
            section: 1,
            x0_mm,
            dx_mm: 1.0,
            z: Samples::from_vec(z),
            median_um: 0.0,
        };
        View {
            analysis_json: json!({}),
            lines: vec![line(0, 0.0, (0..100).map(f64::from).collect()), line(1, 50.0, vec![f64::NAN, 5.0, -5.0])],
            frames: Vec::new(),
            frames_total: 0,
            frame_every: 1,
            frames_note: None,
        }
    }

    #[test]
    fn profile_bins_hold_each_lines_lowest_and_highest_sample() {
        let p = view().profile(0.0, 100.0, 10).unwrap();
        let l0 = &p["lines"][0];
        assert_eq!(l0["min_um"][0], 0.0);
        assert_eq!(l0["max_um"][0], 9.0);
        assert_eq!(l0["max_um"][9], 99.0);
        let l1 = &p["lines"][1];
        // Line 1 covers 50–53 mm: bin 5 only, its NaN left out.
        assert_eq!(l1["min_um"][5], -5.0);
        assert_eq!(l1["max_um"][5], 5.0);
        assert!(l1["min_um"][4].is_null() && l1["min_um"][6].is_null());
    }

    #[test]
    fn a_zoom_past_the_data_is_empty_bins() {
        let p = view().profile(1000.0, 2000.0, 4).unwrap();
        assert!(p["lines"][0]["min_um"].as_array().unwrap().iter().all(|v| v.is_null()));
    }

    #[test]
    fn query_parameters_are_named_when_wrong() {
        assert_eq!(param::<f64>(Some("from_mm=1.5&to_mm=2"), "to_mm"), Ok(2.0));
        assert!(param::<f64>(Some("from_mm=x"), "from_mm").unwrap_err().contains("from_mm: not a number"));
        assert!(param::<usize>(None, "bins").unwrap_err().contains("missing query parameter bins"));
    }

    #[test]
    fn frames_are_thinned_to_the_limit() {
        let mut f = analyze::stitch::FramePoints { seq: 7, odometer_mm: 3.0, lasers: Default::default() };
        f.lasers[0] = (0..1440).map(|i| (f64::from(i), 1.0)).collect();
        let k = thin(&f);
        assert!(k.lasers[0].len() <= MAX_FRAME_POINTS && k.lasers[0].len() >= MAX_FRAME_POINTS / 2);
        assert!(k.lasers[1].is_empty());
    }
}
