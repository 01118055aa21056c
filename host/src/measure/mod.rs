//! `cms-host measure`: the corrugation of each image or recorded frame.
//!
//! ```text
//! cms-host measure --calibration cal.toml INPUT... [--json] [--plot DIR]
//! ```
//!
//! INPUT is an image (PNG, TIFF, JPEG or CSV rows, as `detect` reads them)
//! or a recording (`.cmsrec`). An image's rows go through the head's own
//! detector (`cms_core::peak`, with the scale range of the calibration's
//! `[head]` optics), its method chosen by the light the image shows — the
//! centroid for a speckled laser line, the CWT otherwise — unless
//! `--method` names one; each row's stripes go to the lasers whose lines
//! they continue, so a row where one line is missing keeps the others
//! ([`image`]; rows with no stripe and rows with a line missing are
//! counted). A recording's complete frames (every part of a
//! sequence number) give their points' `metric` (triangulated by the head),
//! or, for frames recorded without a calibration, the raw peaks
//! triangulated here with the calibration.
//!
//! Per image or frame and per laser: the profile `(along_mm, height_mm)` in
//! that laser's profile frame and its rotated-sine fit (`fit`), the joint
//! result of the lines with the surface-normal correction (`corrugation`),
//! and each line's sine on its corrected profile (along the rail, the joint
//! surface removed). The lines' own-frame fits have no surface (a crowned
//! rail crossed obliquely bends them), so with a joint result they are
//! diagnostics: printed without an uncertainty, and left out of the level
//! `--strict` goes by; the fits along the rail carry one.
//! Text by default; `--json`: one JSON object per image/frame per line, with
//! the profiles. `--plot DIR`: per image/frame `NAME.svg` and `NAME.png`, the
//! corrected profiles with the joint sine and, below, the residuals.
//!
//! A bad input (unreadable, not an image or recording, no calibration
//! section needed) stops the run with a one-line error and exit status 2; an
//! image or frame whose lines cannot be fitted is reported as such and the
//! run goes on.
//!
//! **Inputs that must belong together** are checked before anything is
//! measured: an image of another size than the calibration's camera, a
//! recording whose `Hello` names another calibration id or sensor size, or
//! whose points lie outside the camera's image, is refused
//! ([`CalibrationFile::check_image`], [`CalibrationFile::check_recording`],
//! the same check `analyze --calibration` makes). That costs one extra read
//! of a recording (decoding only, ~2 000 frames/s) so that a wrong pairing
//! fails at once rather than after the whole measurement. Damaged frames and
//! profile messages present twice are skipped and said on stderr
//! ([`recording::warnings`]).

pub mod corrugation;
pub mod fit;
pub mod image;
pub mod verdict;

use std::io::{self, Write};
use std::path::Path;

use cms_core::pipeline::triangulator;
use cms_core::protocol::{DeviceMsg, LASERS, Profile};
use cms_core::triangulation::Triangulator;
use serde::Serialize;

use crate::Error;
use crate::calib::file::{CalibrationFile, RecordedHeads};
use crate::input;
use crate::input::detect::MAX_ROW;
use crate::progress::Progress;
use crate::recording::{self, FrameCounter};
use corrugation::{Corrected, HeadFrame, Joint, Line, LineFit, joint_fit_from};
use fit::{Fit, Options};
use verdict::{Evidence, Level, Verdict};

/// Per laser, its profile points `(along_mm, height_mm)`.
pub type Profiles = [Vec<(f64, f64)>; LASERS];

/// One laser's profile and fit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LaserResult {
    /// Laser index.
    pub laser: usize,
    /// Positions along the laser line, mm.
    pub along_mm: Vec<f64>,
    /// Heights above the datum, mm.
    pub height_mm: Vec<f64>,
    /// Its rotated-sine fit.
    pub fit: Option<Fit>,
    /// Why there is no fit.
    pub error: Option<String>,
    /// Whether to believe the fit ([`crate::measure::verdict`]): one line's model
    /// has no surface (a crowned rail crossed obliquely shows as misfit).
    pub verdict: Option<Verdict>,
    /// The line's sine on its corrected profile (along the rail, the joint
    /// surface removed: the model holds), when there is a joint result.
    pub surface_fit: Option<LineFit>,
    /// Whether to believe `surface_fit`.
    pub surface_verdict: Option<Verdict>,
}

/// The result of one image or frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Measurement {
    /// The input it came from.
    pub source: String,
    /// Frame sequence number (recordings).
    pub seq: Option<u32>,
    /// Odometer at exposure, mm (recordings).
    pub odometer_mm: Option<f64>,
    /// Image rows without one stripe per laser (images).
    pub rows_skipped: Option<usize>,
    /// How an image's stripes were found: the sub-pixel method and the
    /// light the image showed (images).
    pub detection: Option<ImageDetection>,
    /// Per laser.
    pub lasers: Vec<LaserResult>,
    /// The joint result of the lines.
    pub joint: Option<Joint>,
    /// The surface-normal corrected profiles (skipped in JSON: derivable).
    #[serde(skip)]
    pub corrected: Vec<Corrected>,
    /// Why there is no joint result.
    pub joint_error: Option<String>,
}

/// How an image's stripes were found ([`image`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ImageDetection {
    /// The sub-pixel method (its name).
    pub method: &'static str,
    /// The light test, when the method was chosen by it.
    pub light: Option<image::LightJudgement>,
    /// Rows where some laser had no point (the others kept theirs).
    pub rows_partial: usize,
}

/// The calibration, ready to measure with.
pub struct Measurer {
    /// The file, for the checks of what it is paired with.
    file: CalibrationFile,
    tri: Triangulator,
    frame: HeadFrame,
    /// Detector scale range (images), if the file has `[head]`.
    scales: Option<cms_core::optics::ScaleRange>,
}

/// Why a calibration cannot measure, or an image's rows cannot be measured.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MeasureError {
    /// The calibration file cannot give the head's calibration.
    #[error(transparent)]
    File(#[from] crate::calib::file::FileError),
    /// The head's own check of the calibration refused it.
    #[error("{0}")]
    Calibration(String),
    /// The laser planes give no profile frame.
    #[error("the laser planes give no profile frame")]
    NoFrame,
    /// The `[head]` section's optics give no detector scale range.
    #[error("[head]: {0}")]
    Head(String),
    /// No `[head]` section: no detector scale range for images.
    #[error("the calibration has no [head] section (the detector's scale range)")]
    NoHead,
    /// Rows wider than the detector takes.
    #[error("rows of {0} px exceed the detector's {MAX_ROW} px")]
    TooWide(usize),
    /// The detector refused its configuration.
    #[error("detector: {0}")]
    Detector(cms_core::peak::Error),
    /// The detector failed on a row.
    #[error("row {row}: {source}")]
    Row {
        /// The row.
        row: usize,
        /// The detector's error.
        source: cms_core::peak::Error,
    },
}

impl Measurer {
    /// From a calibration file: needs `[camera]`, `[datum]` and three
    /// `[[laser]]`s.
    pub fn new(cal: &CalibrationFile) -> Result<Measurer, MeasureError> {
        let head = cal.to_head()?;
        let tri = triangulator(&head).map_err(|e| MeasureError::Calibration(e.to_string()))?;
        let frame = HeadFrame::new(&tri).ok_or(MeasureError::NoFrame)?;
        let scales = cal
            .head
            .map(|h| tri.scale_range(h.laser_diameter_mm, (h.range_min_mm, h.range_max_mm)))
            .transpose()
            .map_err(|e| MeasureError::Head(e.to_string()))?;
        Ok(Measurer { file: cal.clone(), tri, frame, scales })
    }

    /// The triangulator of the calibration.
    pub fn triangulator(&self) -> &Triangulator {
        &self.tri
    }

    /// Per-laser profiles of a recorded frame (its parts in order): the
    /// head's metric points, or the raw peaks triangulated here. Points the
    /// head's line pass rejected (a glint, a ghost, off the line:
    /// [`Flags::rejected`](cms_core::peak::Flags::rejected)) are left out;
    /// `info` and `export` count them.
    pub fn frame_profiles(&self, parts: &[Profile]) -> Profiles {
        let mut out: Profiles = Default::default();
        for p in parts {
            for l in &p.lasers {
                let k = usize::from(l.laser);
                if k >= LASERS {
                    continue;
                }
                for q in l.points.iter().filter(|q| !q.flags.rejected()) {
                    let pt = match q.metric {
                        Some(m) => Some((f64::from(m.along_um) * 1e-3, f64::from(m.height_nm) * 1e-6)),
                        None => self
                            .tri
                            .profile(k, q.position, q.row)
                            .map(|p| (f64::from(p.along_mm), f64::from(p.height_mm))),
                    };
                    out[k].extend(pt);
                }
            }
        }
        out
    }

    /// The profiles as lines in the head frame, for [`crate::measure::corrugation::joint_fit`].
    pub fn lines(&self, profiles: &Profiles) -> Vec<Line> {
        (0..LASERS)
            .map(|k| Line {
                laser: k,
                points: profiles[k].iter().filter_map(|&(a, h)| self.frame.point(k, a, h)).collect(),
            })
            .collect()
    }

    /// Fits the profiles: each laser alone (rotated sine), then jointly
    /// with the surface-normal correction.
    pub fn measure(&self, source: &str, profiles: &Profiles) -> Measurement {
        self.measure_near(source, profiles, None)
    }

    /// [`Measurer::measure`] with the joint fit also started at `near_mm`
    /// (the previous frame's wavelength: [`joint_fit_from`]).
    pub fn measure_near(&self, source: &str, profiles: &Profiles, near_mm: Option<f64>) -> Measurement {
        let mut lasers = Vec::new();
        for (k, prof) in profiles.iter().enumerate() {
            let (along_mm, height_mm): (Vec<f64>, Vec<f64>) = prof.iter().copied().unzip();
            let (fit, error) = match fit::fit(&along_mm, &height_mm, &Options::default()) {
                Ok(f) => (Some(f), None),
                Err(e) => (None, Some(e.to_string())),
            };
            let verdict = fit.as_ref().map(|f| line_verdict(f, prof));
            lasers.push(LaserResult {
                laser: k,
                along_mm,
                height_mm,
                fit,
                error,
                verdict,
                surface_fit: None,
                surface_verdict: None,
            });
        }
        let lines = self.lines(profiles);
        let (joint, corrected, joint_error) = match joint_fit_from(&lines, near_mm) {
            Ok((j, c)) => (Some(j), c, None),
            Err(e) => (None, Vec::new(), Some(e.to_string())),
        };
        for f in joint.iter().flat_map(|j| j.per_line.iter()) {
            let (Some(l), Some(c)) = (lasers.get_mut(f.laser), corrected.iter().find(|c| c.laser == f.laser)) else {
                continue;
            };
            l.surface_verdict = Some(surface_verdict(f, c, &profiles[f.laser]));
            l.surface_fit = Some(f.clone());
        }
        Measurement {
            source: source.to_string(),
            seq: None,
            odometer_mm: None,
            rows_skipped: None,
            detection: None,
            lasers,
            joint,
            corrected,
            joint_error,
        }
    }
}

/// Every complete frame of a recording, measured (`name` labels the
/// results), and the warnings of reading it (damaged frames, duplicates).
/// A recording of another head than the calibration's (`cal_name`) is
/// refused ([`CalibrationFile::check_recording`], as `analyze` does).
pub fn measure_recording(
    m: &Measurer,
    path: &Path,
    name: &str,
    cal_name: &str,
    progress: &dyn Progress,
) -> Result<(Vec<Measurement>, Vec<String>), Error> {
    // The head first: measuring a whole recording with the wrong
    // calibration, to refuse it at the end, would waste its time.
    let mut heads = RecordedHeads::default();
    recording::scan_file(path, |msg| {
        match msg {
            DeviceMsg::Hello(info) => heads.hello(info),
            DeviceMsg::Profile(p) => heads.profile(p),
            _ => {}
        }
        Ok(())
    })?; // the recording's errors name it already
    m.file.check_recording(cal_name, name, &heads)?;
    let mut parts: Vec<Profile> = Vec::new();
    let mut counter = FrameCounter::default();
    let mut results = Vec::new();
    let mut near_mm: Option<f64> = None;
    // The recording's errors name it already.
    let stats = recording::scan_file_with_progress(path, progress, |msg| {
        if let DeviceMsg::Profile(p) = msg {
            if p.part == 0 {
                parts.clear();
            }
            parts.push(p.clone());
            if counter.profile(p) {
                // The last good frame's wavelength is one more start: along
                // one rail it changes slowly, and a frame whose own starts
                // miss it then still finds it.
                let mut r = m.measure_near(name, &m.frame_profiles(&parts), near_mm);
                if let Some(j) = r.joint.as_ref().filter(|j| j.verdict.level == Level::Good) {
                    near_mm = Some(j.wavelength_mm);
                }
                r.seq = Some(p.seq);
                r.odometer_mm = Some(parts[0].odometer_um as f64 * 1e-3);
                results.push(r);
                parts.clear();
            }
        }
        Ok(())
    })?;
    let warnings = recording::warnings(path, &stats);
    if results.is_empty() {
        let why = warnings.iter().map(|w| w.trim_start_matches("warning: ")).collect::<Vec<_>>().join("; ");
        let why = if why.is_empty() { String::new() } else { format!(" ({why})") };
        return Err(Error::Input(format!("{name}: no complete frame in the recording{why}")));
    }
    Ok((results, warnings))
}

/// An image (or CSV rows) measured, or a recording's frames: whichever the
/// file is (a recording is known by its header, or by its `.cmsrec` name:
/// a damaged or empty recording is then reported as such, not as an
/// unknown image type); with the warnings of reading it. An image of
/// another size than the calibration's (`cal_name`) camera is refused.
pub fn measure_file(
    m: &Measurer,
    path: &Path,
    cal_name: &str,
    method: image::MethodChoice,
    progress: &dyn Progress,
) -> Result<(Vec<Measurement>, Vec<String>), Error> {
    let name = path.display().to_string();
    if recording::taken_for_recording(path).unwrap_or(false) {
        return measure_recording(m, path, &name, cal_name, progress);
    }
    let rows = input::read_rows(path)?;
    m.file.check_image(cal_name, &name, rows.width(), rows.height())?;
    let found = m.image_profiles(&rows, method).map_err(|e| Error::Input(format!("{name}: {e}")))?;
    let mut r = m.measure(&name, &found.profiles);
    r.rows_skipped = Some(found.rows_skipped);
    r.detection =
        Some(ImageDetection { method: found.method.name(), light: found.light, rows_partial: found.rows_partial });
    Ok((vec![r], Vec::new()))
}

/// The verdict on one laser's own fit (no yaw: the line's own axis).
fn line_verdict(f: &Fit, profile: &[(f64, f64)]) -> Verdict {
    let (lo, hi) = profile.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.0), b.max(p.0)));
    verdict::judge(&Evidence {
        rms_residual_mm: f.rms_residual_mm,
        noise_mm: verdict::point_noise(profile),
        wavelength_mm: f.wavelength_mm,
        span_mm: hi - lo,
        spacing_mm: (hi - lo) / profile.len().saturating_sub(1).max(1) as f64,
        yaw_rad: 0.0,
        converged: f.converged,
        rejected: 0,
        points: profile.len(),
        alternative_wavelength_mm: None,
        birge: None,
        sigma_mm: (f.wavelength_sigma_mm, f.amplitude_sigma_mm),
        amplitude_mm: f.amplitude_mm,
    })
}

/// The verdict on one line's sine on its corrected profile.
fn surface_verdict(f: &LineFit, c: &Corrected, profile: &[(f64, f64)]) -> Verdict {
    let (lo, hi) = c.s_mm.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &s| (a.min(s), b.max(s)));
    verdict::judge(&Evidence {
        rms_residual_mm: f.rms_residual_mm,
        noise_mm: verdict::point_noise(profile),
        wavelength_mm: f.wavelength_mm,
        span_mm: hi - lo,
        spacing_mm: (hi - lo) / c.s_mm.len().saturating_sub(1).max(1) as f64,
        yaw_rad: 0.0,
        converged: f.converged,
        rejected: 0,
        points: f.points,
        alternative_wavelength_mm: None,
        birge: None,
        sigma_mm: (f.wavelength_sigma_mm, f.amplitude_sigma_mm),
        amplitude_mm: f.amplitude_mm,
    })
}

impl Measurement {
    /// The worst verdict of its results (failed without any result): the
    /// joint one and the lines' on their corrected profiles; a line's fit
    /// in its own frame only where there is no joint result (otherwise it
    /// is a diagnostic).
    pub fn level(&self) -> Level {
        let joint = self.joint.as_ref().map_or(Level::Failed, |j| j.verdict.level);
        self.lasers
            .iter()
            .filter_map(|l| if self.joint.is_some() { l.surface_verdict.as_ref() } else { l.verdict.as_ref() })
            .map(|v| v.level)
            .fold(joint, Level::max)
    }
}

/// The text report of one measurement.
pub fn write_text(out: &mut impl Write, r: &Measurement) -> io::Result<()> {
    let mut head = r.source.clone();
    if let Some(seq) = r.seq {
        head += &format!(" frame {seq}");
    }
    if let Some(o) = r.odometer_mm {
        head += &format!(" at {o:.3} mm");
    }
    if let Some(s) = r.rows_skipped {
        head += &format!(" ({s} rows without a stripe skipped");
        if let Some(d) = &r.detection {
            head += &format!(", {} with a line missing", d.rows_partial);
        }
        head += ")";
    }
    if let Some(d) = &r.detection {
        head += &format!("; detector {}", d.method);
        if let Some(l) = &d.light {
            let light = if l.speckled { "speckled" } else { "incoherent" };
            head += &format!(
                " (light {light}: the lines' strength changes {:.0} % from sample to sample, noise {:.0} %)",
                l.change * 100.0,
                l.noise_share * 100.0
            );
        }
    }
    writeln!(out, "{head}")?;
    let pm = |s: Option<f64>, k: f64| s.map_or_else(String::new, |s| format!(" ± {:.4}", s * k));
    // `N points, wavelength …, amplitude …`, with the uncertainties given.
    let sine = |points: usize, wl_mm: f64, wl_sigma: Option<f64>, amp_mm: f64, amp_sigma: Option<f64>| {
        format!(
            "{points} points, wavelength {wl_mm:.4} mm{}, amplitude {:.2} µm{}",
            pm(wl_sigma, 1.0),
            amp_mm * 1e3,
            pm(amp_sigma, 1e3)
        )
    };
    for l in &r.lasers {
        if let (Some(f), Some(v)) = (&l.surface_fit, &l.surface_verdict) {
            writeln!(
                out,
                "  laser {} along the rail: {}, rms {:.2} µm; {v}",
                l.laser,
                sine(f.points, f.wavelength_mm, f.wavelength_sigma_mm, f.amplitude_mm, f.amplitude_sigma_mm),
                f.rms_residual_mm * 1e3,
            )?;
        }
        match &l.fit {
            Some(f) => {
                // An uncertainty only where the model fits and there is no
                // joint surface to fit it on: otherwise a diagnostic (one
                // line's own model has no surface, and a misfit's σ does
                // not cover its error).
                let good = r.joint.is_none() && l.verdict.as_ref().is_some_and(|v| v.level == Level::Good);
                let given = |s: Option<f64>| s.filter(|_| good);
                writeln!(
                    out,
                    "  laser {} own frame: {}, rotation {:.4}°, rms {:.2} µm; {}",
                    l.laser,
                    sine(
                        f.points,
                        f.wavelength_mm,
                        given(f.wavelength_sigma_mm),
                        f.amplitude_mm,
                        given(f.amplitude_sigma_mm)
                    ),
                    f.rotation_rad.to_degrees(),
                    f.rms_residual_mm * 1e3,
                    if r.joint.is_some() {
                        "a diagnostic (one line's model has no surface)".to_string()
                    } else {
                        l.verdict.as_ref().map_or_else(String::new, |v| v.to_string())
                    }
                )?
            }
            None => writeln!(
                out,
                "  laser {}: {} points, no fit: {}",
                l.laser,
                l.along_mm.len(),
                l.error.as_deref().unwrap_or("")
            )?,
        }
    }
    match &r.joint {
        Some(j) => writeln!(
            out,
            "  joint ({} lines, {} points{}): wavelength {:.4} mm{}, amplitude {:.2} µm{}, yaw {:.3}°, pitch {:.3}°, \
             roll {:.3}°, rms {:.2} µm; {}",
            j.lines,
            j.points,
            if j.rejected > 0 { format!(", {} outliers left out", j.rejected) } else { String::new() },
            j.wavelength_mm,
            pm(j.wavelength_sigma_mm, 1.0),
            j.amplitude_mm * 1e3,
            pm(j.amplitude_sigma_mm, 1e3),
            j.yaw_rad.to_degrees(),
            j.pitch_rad.to_degrees(),
            j.roll_rad.to_degrees(),
            j.rms_residual_mm * 1e3,
            j.verdict
        ),
        None => writeln!(out, "  joint: no result: {}", r.joint_error.as_deref().unwrap_or("")),
    }
}

const COLOURS: [(u8, u8, u8); 3] = [(31, 119, 180), (214, 39, 40), (44, 160, 44)];

/// Writes `BASE.svg` and `BASE.png`: the corrected profiles (µm, each line's
/// offset removed) with the joint sine, and the residuals below.
pub fn plot(base: &Path, r: &Measurement) -> Result<(), crate::plot::PlotError> {
    crate::plot::svg_and_png(base, (1400, 900), &Plot(r)).map(|_| ())
}

struct Plot<'a>(&'a Measurement);

impl crate::plot::Figure for Plot<'_> {
    fn draw<DB: plotters::prelude::DrawingBackend>(
        &self,
        root: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    ) -> Result<(), String> {
        draw(root, self.0).map_err(crate::plot::err)
    }
}

fn draw<DB: plotters::prelude::DrawingBackend>(
    root: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    r: &Measurement,
) -> Result<(), plotters::drawing::DrawingAreaErrorKind<DB::ErrorType>> {
    let text = true;
    use plotters::prelude::*;
    root.fill(&WHITE)?;
    let Some(j) = &r.joint else {
        return Ok(());
    };
    let model = |s: f64| j.amplitude_mm * 1e3 * (std::f64::consts::TAU * s / j.wavelength_mm + j.phase_rad).sin();
    type Series = (usize, Vec<(f64, f64)>, Vec<(f64, f64)>);
    let series: Vec<Series> = r
        .corrected
        .iter()
        .map(|c| {
            let pts: Vec<(f64, f64)> =
                c.s_mm.iter().zip(&c.z_mm).map(|(&s, &z)| (s, (z - c.offset_mm) * 1e3)).collect();
            let res = pts.iter().map(|&(s, z)| (s, z - model(s))).collect();
            (c.laser, pts, res)
        })
        .collect();
    let all = series.iter().flat_map(|s| s.1.iter());
    let (s0, s1) = all.clone().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let zmax = all.fold(0.0f64, |m, p| m.max(p.1.abs())).max(1e-3) * 1.1;
    let rmax = series.iter().flat_map(|s| s.2.iter()).fold(0.0f64, |m, p| m.max(p.1.abs())).max(1e-3) * 1.1;
    let (top, bottom) = root.split_vertically(600);
    let title = format!(
        "{}{}: λ = {:.3} mm, A = {:.2} µm ({} lines, yaw {:.2}°)",
        r.source,
        r.seq.map_or_else(String::new, |s| format!(" frame {s}")),
        j.wavelength_mm,
        j.amplitude_mm * 1e3,
        j.lines,
        j.yaw_rad.to_degrees()
    );
    for (area, range, what) in [(&top, zmax, 0), (&bottom, rmax, 1)] {
        let mut b = ChartBuilder::on(area);
        b.margin(15).x_label_area_size(if text { 40 } else { 0 }).y_label_area_size(if text { 70 } else { 0 });
        if text {
            let cap = if what == 0 { title.clone() } else { "residuals".to_string() };
            b.caption(cap, ("sans-serif", 18));
        }
        let mut chart = b.build_cartesian_2d(s0..s1, -range..range)?;
        let mut mesh = chart.configure_mesh();
        if text {
            mesh.x_desc("along the rail, mm (surface-normal corrected)").y_desc(if what == 0 {
                "height, µm"
            } else {
                "residual, µm"
            });
        } else {
            mesh.x_labels(0).y_labels(0);
        }
        mesh.draw()?;
        for (laser, pts, res) in &series {
            let (cr, cg, cb) = COLOURS[laser % COLOURS.len()];
            let colour = RGBColor(cr, cg, cb).mix(0.6);
            let data = if what == 0 { pts } else { res };
            let step = (data.len() / 2000).max(1);
            let dots = chart.draw_series(data.iter().step_by(step).map(|&p| Circle::new(p, 1, colour.filled())))?;
            if text {
                dots.label(format!("laser {laser}")).legend(move |(x, y)| Circle::new((x, y), 3, colour.filled()));
            }
        }
        if what == 0 {
            let n = 2000;
            let line = (0..=n).map(|i| {
                let s = s0 + (s1 - s0) * f64::from(i) / f64::from(n);
                (s, model(s))
            });
            let l = chart.draw_series(LineSeries::new(line, BLACK.stroke_width(2)))?;
            if text {
                l.label("joint sine").legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK));
                chart
                    .configure_series_labels()
                    .position(SeriesLabelPosition::UpperRight)
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK)
                    .draw()?;
            }
        }
    }
    Ok(())
}
