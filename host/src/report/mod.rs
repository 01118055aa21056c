//! The `analyze --report DIR` report: what the summary says, with plots and
//! the data behind them.
//!
//! Files written into `DIR`, as one output set ([`crate::output::set`]: a
//! hidden folder beside `DIR` put in its place whole, so `DIR` holds the
//! old report or the new one, never a mix; a `DIR` holding anything else
//! is refused):
//!
//! | file | what |
//! |---|---|
//! | `report.html` | self-contained and offline (style and SVG inline, nothing fetched), every section as tables and figures ([`html`]): the survey header (inputs, how each run was placed, the chainage span), the verdict (edition and its limits' source, reprofiling table, zones, zone plot, blocks), the inputs and stitching in detail, the GNSS track ([`track`]), per line its stitching, EN 13231-3 bands and EN 15610 spectrum, then the plots; prints cleanly (`@media print`: A4 landscape with margins, each section on a new page, plots scaled to the page and kept whole, table rows never split and headers repeated, colours printed) |
//! | `report.md` | the same in Markdown, plots linked as `*.svg` |
//! | `summary.txt` | the printed summary |
//! | `profile.svg/.png` | stitched profile of each laser (median removed), gaps blank |
//! | `bands_laserK.svg/.png` | per laser: the four EN 13231-3 band signals, the moving-window mean peak-to-peak and its limit |
//! | `spectrum.svg/.png` | EN 15610 one-third-octave levels per laser against the ISO 3095 limit |
//! | `zones.svg/.png` | per band, each line's criterion along chainage against the edition's limit, the exceedance zones shaded |
//! | `track.svg/.png` | when the recordings hold GNSS fixes: the runs' track east and north of the first fix, m, equal scales, by fix quality, start and end marked, chainage ticks ([`track`]) |
//! | `profile.csv` | `x_mm` and one height column per laser (µm), empty in gaps |
//! | `bands_laserK.csv` | `x_mm` and the four band signals (mm) |
//! | `spectrum_laserK.csv` | the spectrum (`en15610::spectrum_csv`) |
//! | `registration.csv` | per laser and frame: overlap, offset, tilt, residual |
//! | `gaps.csv` | per laser: start and length of every gap |
//! | `marks.csv` | the event marks at their chainage ([`marks`]) |
//! | `profile.parquet`, `blocks.parquet`, `zones.parquet`, `fixes.parquet`, `third_octaves.parquet` | the stitched profile, blocks, zones, GNSS fixes and each block's ISO 3095 third octaves ([`exports`], docs/exports.md) |
//!
//! Long profiles are plotted through a min/max envelope of at most
//! [`MAX_PLOT_POINTS`] points per line (the CSVs keep every sample),
//! gathered as the line is walked piece by piece ([`traces`]); the
//! per-sample files are written in the same walk, so a report of any
//! length of track is written in the memory of one piece, and each
//! piece's bands are worked out once.

pub mod exports;
pub mod html;
pub mod json;
pub mod marks;
pub mod optics;
pub mod table;
pub mod text;
pub mod traces;
pub mod track;
pub mod trend;

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::Error;
use crate::analyze::pieces::Piece;
use crate::analyze::standards::{en13231, en15610};
use crate::analyze::{Analysis, LaserAnalysis, Source, reprofiling};
use crate::output::AtomicFile;
use crate::plot::{self, Figure, err};

/// Most points of one plotted line.
pub const MAX_PLOT_POINTS: usize = 4000;

const COLOURS: [RGBColor; 3] = [RGBColor(214, 39, 40), RGBColor(44, 160, 44), RGBColor(31, 119, 180)];

fn colour(laser: usize) -> RGBColor {
    COLOURS[laser % COLOURS.len()]
}

fn range(pieces: &[Vec<(f64, f64)>]) -> Option<((f64, f64), (f64, f64))> {
    let pts = pieces.iter().flatten();
    let mut r: Option<((f64, f64), (f64, f64))> = None;
    for &(x, y) in pts {
        r = Some(match r {
            None => ((x, x), (y, y)),
            Some(((x0, x1), (y0, y1))) => ((x0.min(x), x1.max(x)), (y0.min(y), y1.max(y))),
        });
    }
    r
}

/// Pads a value range so that it is never empty.
fn padded(lo: f64, hi: f64) -> (f64, f64) {
    let span = (hi - lo).max(1e-9);
    (lo - 0.05 * span, hi + 0.05 * span)
}

/// Continuous pieces of a plotted line.
use traces::Pieces;

/// The stitched profiles.
struct ProfileFig {
    /// Per laser, its pieces.
    lines: Vec<(usize, Pieces)>,
}

impl Figure for ProfileFig {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        root.fill(&WHITE).map_err(err)?;
        let all: Vec<Vec<(f64, f64)>> = self.lines.iter().flat_map(|(_, p)| p.clone()).collect();
        let Some(((x0, x1), (y0, y1))) = range(&all) else { return Ok(()) };
        let (x0, x1) = padded(x0, x1);
        let (y0, y1) = padded(y0, y1);
        let mut chart = ChartBuilder::on(root)
            .caption("Stitched longitudinal profile per laser line (median removed)", ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(err)?;
        chart.configure_mesh().x_desc("track position x, mm").y_desc("height, µm").draw().map_err(err)?;
        for (laser, pieces) in &self.lines {
            let c = colour(*laser);
            for (i, p) in pieces.iter().enumerate() {
                let s = chart.draw_series(LineSeries::new(p.iter().copied(), c.stroke_width(1))).map_err(err)?;
                if i == 0 {
                    s.label(format!("laser {laser}"))
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
                }
            }
        }
        chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(err)?;
        Ok(())
    }
}

/// One laser's EN 13231-3 bands.
struct BandsFig<'a> {
    laser: usize,
    x0: f64,
    a: &'a en13231::BandAnalysis,
    traces: &'a traces::LineTraces,
}

impl Figure for BandsFig<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        root.fill(&WHITE).map_err(err)?;
        let root = root
            .titled(
                &format!(
                    "Laser {}: EN 13231-3 bands (µm), moving-window mean peak-to-peak (black) and its limit (dashed)",
                    self.laser
                ),
                ("sans-serif", 18),
            )
            .map_err(err)?;
        let dx = self.a.dx_mm;
        let x_end = self.x0 + self.a.samples as f64 * dx;
        for (panel, b) in root.split_evenly((self.a.bands.len().max(1), 1)).iter().zip(&self.a.bands) {
            let name = b.band.name();
            let st = match &b.outcome {
                Ok(st) => st,
                Err(e) => {
                    panel
                        .draw(&Text::new(
                            format!("{name}: not evaluated: {e}"),
                            (20, 30),
                            ("sans-serif", 15).into_font().color(&BLACK),
                        ))
                        .map_err(err)?;
                    continue;
                }
            };
            let k = en13231::BANDS.iter().position(|x| *x == b.band).unwrap_or(0);
            let empty = Pieces::new();
            let band = self.traces.band.get(k).unwrap_or(&empty);
            let pp = self.traces.mean_pp.get(k).unwrap_or(&empty);
            let limit_um = b.band.mean_pp_limit_mm * 1000.0;
            let ((_, _), (lo, hi)) = range(band).unwrap_or(((0.0, 1.0), (-1.0, 1.0)));
            let top = hi.max(limit_um).max(range(pp).map_or(0.0, |r| r.1.1));
            let (lo, top) = padded(lo.min(-limit_um * 0.1), top);
            let mut chart = ChartBuilder::on(panel)
                .caption(
                    format!(
                        "{name}: window {} mm, {:.1} % of length exceeding",
                        b.band.window_mm, st.exceeding_percent
                    ),
                    ("sans-serif", 15),
                )
                .margin(8)
                .x_label_area_size(28)
                .y_label_area_size(60)
                .build_cartesian_2d(self.x0..x_end.max(self.x0 + dx), lo..top)
                .map_err(err)?;
            chart.configure_mesh().y_desc("µm").max_light_lines(2).draw().map_err(err)?;
            let c = colour(self.laser);
            for p in band {
                chart.draw_series(LineSeries::new(p.iter().copied(), c.stroke_width(1))).map_err(err)?;
            }
            for p in pp {
                chart.draw_series(LineSeries::new(p.iter().copied(), BLACK.stroke_width(2))).map_err(err)?;
            }
            chart
                .draw_series(DashedLineSeries::new(
                    [(self.x0, limit_um), (x_end, limit_um)],
                    8,
                    5,
                    BLACK.stroke_width(1),
                ))
                .map_err(err)?;
        }
        Ok(())
    }
}

/// The roughness spectra against the ISO 3095 limit.
struct SpectrumFig<'a> {
    spectra: Vec<(usize, &'a en15610::Spectrum)>,
}

impl Figure for SpectrumFig<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        root.fill(&WHITE).map_err(err)?;
        let levels = self.spectra.iter().flat_map(|(_, s)| s.bands.iter().map(|b| b.level_db));
        let lim = en15610::ISO3095_LIMIT.iter().map(|l| l.1);
        let (lo, hi) = levels.chain(lim).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            if v.is_finite() { (a.min(v), b.max(v)) } else { (a, b) }
        });
        let (lo, hi) = if lo <= hi { padded(lo.max(-60.0), hi) } else { (-20.0, 20.0) };
        let mut chart = ChartBuilder::on(root)
            .caption("EN 15610 roughness, one-third octaves, against the ISO 3095 limit (black)", ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d((2.5f64..500.0).log_scale(), lo..hi)
            .map_err(err)?;
        chart.configure_mesh().x_desc("wavelength, mm").y_desc("roughness level, dB re 1 µm").draw().map_err(err)?;
        let mut limit: Vec<(f64, f64)> = en15610::ISO3095_LIMIT.to_vec();
        limit.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart
            .draw_series(LineSeries::new(limit.iter().copied(), BLACK.stroke_width(2)))
            .map_err(err)?
            .label("ISO 3095 limit")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(2)));
        for (laser, s) in &self.spectra {
            let c = colour(*laser);
            let mut pts: Vec<(f64, f64)> = s
                .bands
                .iter()
                .filter(|b| b.level_db.is_finite())
                .map(|b| (b.nominal_wavelength_mm, b.level_db))
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            chart
                .draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))
                .map_err(err)?
                .label(format!("laser {laser}"))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
            chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled()))).map_err(err)?;
        }
        chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(err)?;
        Ok(())
    }
}

/// Per band, each line's criterion along chainage (the edition's: the
/// moving-window mean peak-to-peak, or |band displacement| for 2012),
/// the limit (dashed) and the exceedance zones (shaded).
struct ZoneFig<'a> {
    a: &'a Analysis,
    traces: &'a [traces::LineTraces],
}

impl Figure for ZoneFig<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        root.fill(&WHITE).map_err(err)?;
        let v = &self.a.verdict;
        let e = v.options.edition;
        let what = match e {
            reprofiling::Edition::En2006 => "moving-window mean peak-to-peak",
            reprofiling::Edition::En2012 => "|band displacement| (isolated points)",
        };
        let root = root
            .titled(
                &format!("{}: {what} per line (µm) along chainage, limit dashed, zones shaded", e.name()),
                ("sans-serif", 18),
            )
            .map_err(err)?;
        let x0 = self.a.lasers.iter().map(|l| l.stitched.x0_mm).fold(f64::INFINITY, f64::min);
        let x1 = self.a.lasers.iter().map(|l| l.stitched.x_mm(l.stitched.z.len())).fold(f64::NEG_INFINITY, f64::max);
        if !(x0.is_finite() && x1 > x0) {
            return Ok(());
        }
        let (m0, m1) = (x0 / 1000.0, x1 / 1000.0);
        for (b, (panel, band)) in root.split_evenly((en13231::BANDS.len(), 1)).iter().zip(&en13231::BANDS).enumerate() {
            let mut lines: Vec<(usize, Pieces)> = Vec::new();
            for (l, t) in self.a.lasers.iter().zip(self.traces) {
                let Some(Ok(_)) = l.bands.as_ref().ok().and_then(|a| a.bands.get(b)).map(|r| r.outcome.as_ref()) else {
                    continue;
                };
                lines.push((l.stitched.laser, t.criterion.get(b).cloned().unwrap_or_default()));
            }
            let limit_um = e.limit_mm(band).map(|v| v * 1000.0);
            let all: Pieces = lines.iter().flat_map(|(_, p)| p.clone()).collect();
            let top = range(&all).map_or(0.0, |r| r.1.1).max(limit_um.unwrap_or(0.0)).max(1e-3) * 1.1;
            let zones: Vec<&reprofiling::Zone> = v.zones.iter().filter(|z| z.band == *band).collect();
            let caption = match (limit_um, lines.is_empty()) {
                (_, true) => format!("{}: not evaluated", band.name()),
                (None, false) => format!("{}: no {} limit known, not judged", band.name(), e.name()),
                (Some(_), false) => format!("{}: {} zone(s)", band.name(), zones.len()),
            };
            let mut chart = ChartBuilder::on(panel)
                .caption(caption, ("sans-serif", 15))
                .margin(8)
                .x_label_area_size(28)
                .y_label_area_size(60)
                .build_cartesian_2d(m0..m1, 0.0..top)
                .map_err(err)?;
            chart
                .configure_mesh()
                .y_desc("µm")
                .x_label_formatter(&|m| crate::analyze::chainage(m * 1000.0))
                .max_light_lines(2)
                .draw()
                .map_err(err)?;
            let shade = RGBColor(255, 200, 200).filled();
            chart
                .draw_series(zones.iter().map(|z| {
                    // A zone of one sample still shows.
                    let (a, b) = (z.start_mm / 1000.0, (z.end_mm / 1000.0).max(z.start_mm / 1000.0 + (m1 - m0) * 2e-3));
                    Rectangle::new([(a, 0.0), (b, top)], shade)
                }))
                .map_err(err)?;
            for (laser, pieces) in &lines {
                let c = colour(*laser);
                for p in pieces {
                    chart.draw_series(LineSeries::new(p.iter().copied(), c.stroke_width(1))).map_err(err)?;
                }
            }
            if let Some(lim) = limit_um {
                chart
                    .draw_series(DashedLineSeries::new([(m0, lim), (m1, lim)], 8, 5, BLACK.stroke_width(1)))
                    .map_err(err)?;
            }
        }
        Ok(())
    }
}

/// The lines of `profile.csv`'s columns, in order.
fn profile_lines(a: &Analysis) -> Vec<usize> {
    let mut lines: Vec<usize> = a.lasers.iter().map(|l| l.stitched.laser).collect();
    lines.sort_unstable();
    lines.dedup();
    lines
}

/// The header of `profile.csv`: `x_mm,laser_K_um…`.
fn profile_csv_header(lines: &[usize]) -> String {
    let mut s = String::from("x_mm");
    for k in lines {
        let _ = write!(s, ",laser_{k}_um");
    }
    s.push('\n');
    s
}

/// One piece's rows of `profile.csv`: the stitched profiles on one grid
/// per section, the sections one after the other (the stretches between
/// them, never measured, have no rows).
fn profile_csv_rows(s: &mut String, lines: &[usize], p: &Piece) {
    for i in 0..p.core.len() {
        let _ = write!(s, "{}", p.grid.chainage_mm(p.core.start + i));
        for k in lines {
            match p.lines.iter().find(|l| l.laser == *k).map(|l| l.z_um[i]).filter(|v| v.is_finite()) {
                Some(v) => {
                    let _ = write!(s, ",{v:.4}");
                }
                None => s.push(','),
            }
        }
        s.push('\n');
    }
}

/// One piece's rows of a line's band signals (`bands_laserK.csv`).
fn bands_csv_rows(s: &mut String, l: &LaserAnalysis, p: &Piece) {
    if p.section != l.stitched.section {
        return;
    }
    let Some(pl) = p.lines.iter().find(|pl| pl.laser == l.stitched.laser) else { return };
    let x0 = p.grid.chainage_mm(p.core.start);
    // The line's own extent only, as its samples run.
    let (lo, hi) = (l.stitched.x0_mm, l.stitched.x_mm(l.stitched.z.len()));
    let keep: Vec<usize> =
        (0..p.core.len()).filter(|&i| (lo - 1e-6..hi - 1e-6).contains(&p.grid.chainage_mm(p.core.start + i))).collect();
    let (Some(&f), Some(&e)) = (keep.first(), keep.last()) else { return };
    let n = e + 1 - f;
    let all: Vec<Option<en13231::BandTrace>> = pl
        .bands
        .iter()
        .map(|t| {
            Some(match t {
                Some(t) => en13231::BandTrace {
                    band_mm: t.band_mm[f..=e].to_vec(),
                    mean_pp_mm: Vec::new(),
                    max_pp_mm: Vec::new(),
                },
                // A band not evaluated still has its (empty) column.
                None => en13231::BandTrace { band_mm: vec![f64::NAN; n], ..Default::default() },
            })
        })
        .collect();
    en13231::bands_csv_rows(s, x0 + f as f64 * p.grid.dx_mm, p.grid.dx_mm, &all);
}

/// Everything the report writes per sample, filled in one walk along the
/// line ([`Analysis::for_each_piece`]): `profile.csv`, each line's
/// `bands_…csv`, `profile.parquet` and the plots' traces. The band
/// filters and windows of every piece are worked out once for them all.
struct Walk<'a> {
    a: &'a Analysis,
    lines: Vec<usize>,
    profile: AtomicFile,
    /// Per line with bands: its index in `a.lasers` and its file.
    bands: Vec<(usize, AtomicFile)>,
    parquet: exports::ProfileParquet,
    traces: traces::Gather,
    /// Text of the piece being written.
    text: String,
}

impl<'a> Walk<'a> {
    fn begin(dir: &Path, source: &Source, a: &'a Analysis) -> Result<Walk<'a>, Error> {
        let lines = profile_lines(a);
        let mut profile = AtomicFile::create(&dir.join("profile.csv"))?;
        profile.write_all(profile_csv_header(&lines).as_bytes()).map_err(|e| profile.failed(e))?;
        let several = a.sections().len() > 1;
        let mut bands = Vec::new();
        for (k, l) in a.lasers.iter().enumerate() {
            if let Ok(b) = &l.bands {
                let (name, _) = line_names(&l.stitched, several);
                let mut f = AtomicFile::create(&dir.join(format!("bands_{name}.csv")))?;
                f.write_all(en13231::bands_csv_header(b).as_bytes()).map_err(|e| f.failed(e))?;
                bands.push((k, f));
            }
        }
        let parquet = exports::ProfileParquet::create(dir, source, a)?;
        let traces = traces::Gather::new(a, MAX_PLOT_POINTS);
        Ok(Walk { a, lines, profile, bands, parquet, traces, text: String::new() })
    }

    fn piece(&mut self, p: &Piece) -> Result<(), Error> {
        self.text.clear();
        profile_csv_rows(&mut self.text, &self.lines, p);
        self.profile.write_all(self.text.as_bytes()).map_err(|e| self.profile.failed(e))?;
        for (k, f) in &mut self.bands {
            self.text.clear();
            bands_csv_rows(&mut self.text, &self.a.lasers[*k], p);
            f.write_all(self.text.as_bytes()).map_err(|e| f.failed(e))?;
        }
        self.parquet.piece(p)?;
        self.traces.piece(p);
        Ok(())
    }

    /// Puts every file in place; the traces for the plots.
    fn finish(self) -> Result<Vec<traces::LineTraces>, Error> {
        self.profile.commit()?;
        for (_, f) in self.bands {
            f.commit()?;
        }
        self.parquet.commit()?;
        Ok(self.traces.finish())
    }
}

fn registration_csv(a: &Analysis) -> String {
    let mut s = String::from("laser,seq,centre_mm,overlap_mm,offset_um,tilt_um_per_mm,residual_um\n");
    for l in &a.lasers {
        let _ = l.stitched.fits.for_each(|f| {
            let _ = writeln!(
                s,
                "{},{},{:.3},{:.3},{:.4},{:.6},{:.4}",
                l.stitched.laser, f.seq, f.centre_mm, f.overlap_mm, f.offset_um, f.tilt_um_per_mm, f.residual_um
            );
        });
    }
    s
}

fn gaps_csv(a: &Analysis) -> String {
    let mut s = String::from("laser,start_mm,length_mm\n");
    for l in &a.lasers {
        for g in &l.stitched.gaps {
            let _ = writeln!(s, "{},{:.3},{:.3}", l.stitched.laser, g.start_mm, g.length_mm);
        }
    }
    s
}

/// A line's file-name part and title: `laser1` and "Laser 1", with its
/// section when the survey line has several (`laser1_section2`).
fn line_names(l: &crate::analyze::stitch::Stitched, several: bool) -> (String, String) {
    if several {
        (format!("laser{}_section{}", l.laser, l.section), format!("Laser {}, section {}", l.laser, l.section))
    } else {
        (format!("laser{}", l.laser), format!("Laser {}", l.laser))
    }
}

/// Whether a file of this name is one a report writes (the files of the
/// table above): a folder holding only such files can be replaced by a
/// new report ([`crate::output::set`]).
pub fn owns(name: &str) -> bool {
    const FIXED: [&str; 15] = [
        "report.html",
        "analysis.json",
        "report.md",
        "summary.txt",
        "profile.svg",
        "profile.png",
        "profile.csv",
        "spectrum.svg",
        "spectrum.png",
        "zones.svg",
        "zones.png",
        "registration.csv",
        "gaps.csv",
        "track.svg",
        "track.png",
    ];
    // `PREFIXK.EXT` or `PREFIXK_sectionN.EXT` with K a line's number, N a section's.
    let number = |k: &str| !k.is_empty() && k.bytes().all(|b| b.is_ascii_digit());
    let per_line = |prefix: &str, exts: &[&str]| {
        name.strip_prefix(prefix).and_then(|rest| rest.split_once('.')).is_some_and(|(k, ext)| {
            let line = match k.split_once("_section") {
                Some((k, n)) => number(k) && number(n),
                None => number(k),
            };
            line && exts.contains(&ext)
        })
    };
    FIXED.contains(&name)
        || name == marks::CSV_FILE
        || exports::owns(name)
        || per_line("bands_laser", &["csv", "svg", "png"])
        || per_line("spectrum_laser", &["csv"])
}

/// Writes the report into `dir` as one output set
/// ([`crate::output::set`]): the folder then holds this report and nothing
/// else, or — on any failure, or a crash — what it held before.
pub fn write(dir: &Path, source: &Source, a: &Analysis, summary: &str) -> Result<(), Error> {
    crate::output::set::write_set(dir, owns, |d| write_files(d, source, a, summary))
}

/// The data files the report's last section lists.
const FILES: &str = "profile.csv (x_mm, one height column per laser, µm), bands_laserK.csv (band signals, mm), \
    spectrum_laserK.csv (one-third octaves; bands_laserK_sectionN.csv and \
    spectrum_laserK_sectionN.csv when the line is in several sections), registration.csv (per frame), gaps.csv, summary.txt; \
    profile.parquet, blocks.parquet, zones.parquet, fixes.parquet, third_octaves.parquet (docs/exports.md); track.svg/.png when the recordings hold GNSS fixes";

/// A plot's error as the report's output error.
fn out_err(what: &str, e: crate::plot::PlotError) -> Error {
    Error::Output(std::io::Error::other(format!("{what}: {e}")))
}

/// Writes the report's files into the (new, empty) folder `dir`.
fn write_files(dir: &Path, source: &Source, a: &Analysis, summary: &str) -> Result<(), Error> {
    // Each file whole or not at all, and never over a device or FIFO of that name.
    let put = |name: &str, text: &str| -> Result<(), Error> {
        Ok(crate::output::write_atomically(&dir.join(name), |w| w.write_all(text.as_bytes()))?)
    };
    put("summary.txt", summary)?;
    // `analyze --json`'s object: what `cms-host view DIR` shows.
    put("analysis.json", &format!("{:#}\n", json::to_json(source, a)))?;
    put("registration.csv", &registration_csv(a))?;
    put("gaps.csv", &gaps_csv(a))?;
    exports::write_tables(dir, source, a)?;
    let several = a.sections().len() > 1;
    for l in &a.lasers {
        let (name, _) = line_names(&l.stitched, several);
        if let Ok(r) = &l.roughness {
            put(&format!("spectrum_{name}.csv"), &en15610::spectrum_csv(&r.spectrum))?;
        }
    }
    // One walk for every per-sample file and the plots' traces.
    let mut walk = Walk::begin(dir, source, a)?;
    a.for_each_piece(|p| walk.piece(p))?;
    let traces = walk.finish()?;
    let plots = plots(dir, a, &traces)?;
    let zone_svg = if a.lasers.is_empty() {
        String::new()
    } else {
        plot::svg_and_png(&dir.join("zones"), (1400, 900), &ZoneFig { a, traces: &traces })
            .map_err(|e| out_err("zone plot", e))?
    };
    let track = track::Track::of(source, a);
    let track_svg = match track.as_ref().filter(|t| t.plottable()) {
        Some(t) => Some(
            plot::svg_and_png(&dir.join("track"), (1000, 800), &track::TrackFig { track: t })
                .map_err(|e| out_err("track plot", e))?,
        ),
        None => None,
    };
    let title = format!("Rail corrugation analysis: {}", source.name());
    put(marks::CSV_FILE, &marks::csv(&marks::of(source, a)))?;
    put("report.md", &markdown(&title, source, a, track.as_ref(), &plots, !zone_svg.is_empty()))?;
    let figs = html::Figures { zones: &zone_svg, plots: &plots, track: track_svg.as_deref() };
    put("report.html", &html::page(&title, source, a, track.as_ref(), &figs))?;
    Ok(())
}

/// The plots of the plots section, written as SVG and PNG: (title, file
/// stem, SVG text).
fn plots(dir: &Path, a: &Analysis, traces: &[traces::LineTraces]) -> Result<Vec<(String, String, String)>, Error> {
    let mut figures = Vec::new();
    let lines = a.lasers.iter().zip(traces).map(|(l, t)| (l.stitched.laser, t.profile.clone())).collect();
    let svg = plot::svg_and_png(&dir.join("profile"), (1400, 600), &ProfileFig { lines })
        .map_err(|e| out_err("profile plot", e))?;
    figures.push(("Stitched profiles".into(), "profile".into(), svg));
    let several = a.sections().len() > 1;
    for (l, t) in a.lasers.iter().zip(traces) {
        let (name, title) = line_names(&l.stitched, several);
        if let Ok(b) = &l.bands {
            let stem = format!("bands_{name}");
            let fig = BandsFig { laser: l.stitched.laser, x0: l.stitched.x0_mm, a: b, traces: t };
            let svg = plot::svg_and_png(&dir.join(&stem), (1400, 1000), &fig).map_err(|e| out_err("band plot", e))?;
            figures.push((format!("{title}: EN 13231-3 bands"), stem, svg));
        }
    }
    let spectra: Vec<(usize, &en15610::Spectrum)> =
        a.lasers.iter().filter_map(|l| l.roughness.as_ref().ok().map(|r| (l.stitched.laser, &r.spectrum))).collect();
    if !spectra.is_empty() {
        let svg = plot::svg_and_png(&dir.join("spectrum"), (1100, 650), &SpectrumFig { spectra })
            .map_err(|e| out_err("spectrum plot", e))?;
        figures.push(("EN 15610 roughness spectrum".into(), "spectrum".into(), svg));
    }
    Ok(figures)
}

/// A Markdown table of plain-text cells.
fn md_table(head: &[String], rows: &[Vec<String>]) -> String {
    let cell = |c: &str| c.replace('|', "\\|");
    let mut s = format!(
        "| {} |\n|{}\n",
        head.iter().map(|h| cell(h)).collect::<Vec<_>>().join(" | "),
        "---|".repeat(head.len())
    );
    for r in rows {
        let _ = writeln!(s, "| {} |", r.iter().map(|c| cell(c)).collect::<Vec<_>>().join(" | "));
    }
    s
}

/// `report.md`: the summary's text per section, the track's table, the
/// plots linked.
fn markdown(
    title: &str,
    source: &Source,
    a: &Analysis,
    track: Option<&track::Track>,
    plots: &[(String, String, String)],
    zones: bool,
) -> String {
    let head = text::describe(source, a);
    let verdict_text = reprofiling::describe(&a.verdict);
    let floor_text = text::describe_floor(a);
    let mut md = format!(
        "# {title}\n\n## Survey\n\n```text\n{head}```\n\n## Verdict\n\n```text\n{verdict_text}```\n\n\
         ## Noise floor and the running band\n\n```text\n{floor_text}```\n"
    );
    if zones {
        md.push_str("\n![Exceedance along chainage](zones.svg) ([PNG](zones.png))\n");
    }
    md.push_str("\n## GNSS track\n\n");
    match track {
        Some(t) => {
            let (head, rows) = t.table();
            let _ = writeln!(md, "{}\n\n{}", t.describe_origin(), md_table(&head, &rows));
            if t.plottable() {
                md.push_str("![GNSS track](track.svg) ([PNG](track.png))\n\n");
            }
            let _ = writeln!(md, "{}", track::HOW);
        }
        None if matches!(source, Source::Profile(..)) => {
            md.push_str("No GNSS fixes: the input is a profile file, not a recording.\n");
        }
        None => md.push_str("No GNSS fixes in the recording.\n"),
    }
    md.push_str(&marks::markdown(&marks::of(source, a)));
    let several = a.sections().len() > 1;
    for l in &a.lasers {
        let (_, k) = line_names(&l.stitched, several);
        let text = format!(
            "{}\n{}\n{}",
            text::describe_stitched(&l.stitched),
            text::describe_bands(&l.bands, &l.judgements),
            text::describe_roughness(&l.roughness)
        );
        let _ = write!(md, "\n## {k}\n\n```text\n{text}```\n");
    }
    md.push_str("\n## Plots\n");
    for (t, stem, _) in plots {
        let _ = write!(md, "\n### {t}\n\n![{t}]({stem}.svg) ([PNG]({stem}.png))\n");
    }
    let _ = write!(md, "\n## Data\n\n{FILES}\n");
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A report's folder holds only what a report writes, the per-section
    /// files of a line in several sections and the track included.
    #[test]
    fn a_report_owns_its_files_and_nothing_else() {
        for name in [
            "report.html",
            "track.svg",
            "track.png",
            "bands_laser1.csv",
            "bands_laser1_section2.png",
            "spectrum_laser0_section12.csv",
            "profile.parquet",
        ] {
            assert!(owns(name), "{name}");
        }
        for name in [
            "notes.txt",
            "bands_laser.csv",
            "bands_laser1_section.csv",
            "bands_laserx.csv",
            "spectrum_laser1.svg",
            "bands_laser1_section2_x.csv",
        ] {
            assert!(!owns(name), "{name}");
        }
    }
}
