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
//! | `report.html` | self-contained (SVG inline): the survey header (inputs, how each run was placed, the chainage span), the verdict (edition and its limits' source, reprofiling table, zones, zone plot, blocks) as tables, then per line and the plots; prints cleanly (`@media print`: A4 landscape, each section on a new page, plots scaled to the page and kept whole, tables wrap with repeated headers) |
//! | `report.md` | the same in Markdown, plots linked as `*.svg` |
//! | `summary.txt` | the printed summary |
//! | `profile.svg/.png` | stitched profile of each laser (median removed), gaps blank |
//! | `bands_laserK.svg/.png` | per laser: the four EN 13231-3 band signals, the moving-window mean peak-to-peak and its limit |
//! | `spectrum.svg/.png` | EN 15610 one-third-octave levels per laser against the ISO 3095 limit |
//! | `zones.svg/.png` | per band, each line's criterion along chainage against the edition's limit, the exceedance zones shaded |
//! | `profile.csv` | `x_mm` and one height column per laser (µm), empty in gaps |
//! | `bands_laserK.csv` | `x_mm` and the four band signals (mm) |
//! | `spectrum_laserK.csv` | the spectrum (`en15610::spectrum_csv`) |
//! | `registration.csv` | per laser and frame: overlap, offset, tilt, residual |
//! | `gaps.csv` | per laser: start and length of every gap |
//! | `marks.csv` | the event marks at their chainage ([`marks`]) |
//! | `profile.parquet`, `blocks.parquet`, `zones.parquet` | the stitched profile, blocks and zones ([`exports`], docs/exports.md) |
//!
//! Long profiles are plotted through a min/max envelope of at most
//! [`MAX_PLOT_POINTS`] points per line (the CSVs keep every sample).

pub mod exports;
pub mod json;
pub mod marks;
pub mod text;

use std::fmt::Write as _;
use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::Error;
use crate::analyze::standards::{en13231, en15610};
use crate::analyze::{Analysis, Source, reprofiling};
use crate::plot::{self, Figure, err};

/// Most points of one plotted line.
pub const MAX_PLOT_POINTS: usize = 4000;

const COLOURS: [RGBColor; 3] = [RGBColor(214, 39, 40), RGBColor(44, 160, 44), RGBColor(31, 119, 180)];

fn colour(laser: usize) -> RGBColor {
    COLOURS[laser % COLOURS.len()]
}

/// Splits `(x, y)` at non-finite `y` into continuous pieces and thins each to
/// a min/max envelope so that all of them hold about `max` points.
pub fn plot_pieces(x0: f64, dx: f64, y: &[f64], max: usize) -> Vec<Vec<(f64, f64)>> {
    let finite = y.iter().filter(|v| v.is_finite()).count().max(1);
    // Samples per bucket (each bucket gives its min and max).
    let per = (2 * finite).div_ceil(max.max(2)).max(1);
    let mut out = Vec::new();
    for run in crate::analyze::standards::segments(y) {
        let mut piece = Vec::new();
        if per == 1 {
            piece.extend(run.map(|i| (x0 + i as f64 * dx, y[i])));
        } else {
            let idx: Vec<usize> = run.collect();
            for chunk in idx.chunks(per) {
                let (mut lo, mut hi) = (chunk[0], chunk[0]);
                for &i in chunk {
                    if y[i] < y[lo] {
                        lo = i;
                    }
                    if y[i] > y[hi] {
                        hi = i;
                    }
                }
                let (a, b) = if lo <= hi { (lo, hi) } else { (hi, lo) };
                piece.push((x0 + a as f64 * dx, y[a]));
                if b != a {
                    piece.push((x0 + b as f64 * dx, y[b]));
                }
            }
        }
        out.push(piece);
    }
    out
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
type Pieces = Vec<Vec<(f64, f64)>>;

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
            let to_um = |v: &[f64]| v.iter().map(|v| v * 1000.0).collect::<Vec<f64>>();
            let band = plot_pieces(self.x0, dx, &to_um(&st.band_mm), MAX_PLOT_POINTS);
            let pp = plot_pieces(self.x0, dx, &to_um(&st.mean_pp_mm), MAX_PLOT_POINTS);
            let limit_um = b.band.mean_pp_limit_mm * 1000.0;
            let ((_, _), (lo, hi)) = range(&band).unwrap_or(((0.0, 1.0), (-1.0, 1.0)));
            let top = hi.max(limit_um).max(range(&pp).map_or(0.0, |r| r.1.1));
            let (lo, top) = padded(lo.min(-limit_um * 0.1), top);
            let mut chart = ChartBuilder::on(panel)
                .caption(
                    format!(
                        "{name}: window {} mm, {:.1} % of length over the limit",
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
            for p in &band {
                chart.draw_series(LineSeries::new(p.iter().copied(), c.stroke_width(1))).map_err(err)?;
            }
            for p in &pp {
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
        let x1 = self.a.lasers.iter().map(|l| l.stitched.x_mm(l.stitched.z_um.len())).fold(f64::NEG_INFINITY, f64::max);
        if !(x0.is_finite() && x1 > x0) {
            return Ok(());
        }
        let (m0, m1) = (x0 / 1000.0, x1 / 1000.0);
        for (b, (panel, band)) in root.split_evenly((en13231::BANDS.len(), 1)).iter().zip(&en13231::BANDS).enumerate() {
            let mut lines: Vec<(usize, Pieces)> = Vec::new();
            for l in &self.a.lasers {
                let Some(Ok(st)) = l.bands.as_ref().ok().and_then(|a| a.bands.get(b)).map(|r| r.outcome.as_ref())
                else {
                    continue;
                };
                let y: Vec<f64> = match e {
                    reprofiling::Edition::En2006 => st.mean_pp_mm.iter().map(|v| v * 1000.0).collect(),
                    reprofiling::Edition::En2012 => st
                        .mean_pp_mm
                        .iter()
                        .zip(&st.band_mm)
                        .map(|(m, v)| if m.is_finite() { v.abs() * 1000.0 } else { f64::NAN })
                        .collect(),
                };
                let x0m = l.stitched.x0_mm / 1000.0;
                lines.push((l.stitched.laser, plot_pieces(x0m, l.stitched.dx_mm / 1000.0, &y, MAX_PLOT_POINTS / 2)));
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

/// A table: header cells and rows of cells (already escaped where needed).
fn html_table(class: &str, head: &[&str], rows: &[Vec<String>]) -> String {
    let mut s = format!("<table class=\"{class}\"><thead><tr>");
    for h in head {
        let _ = write!(s, "<th>{}</th>", html_escape(h));
    }
    s.push_str("</tr></thead><tbody>\n");
    for r in rows {
        s.push_str("<tr>");
        for c in r {
            let _ = write!(s, "<td>{}</td>", html_escape(c));
        }
        s.push_str("</tr>\n");
    }
    s.push_str("</tbody></table>\n");
    s
}

/// The survey header: the inputs, the runs and how each was placed, the
/// chainage span.
fn survey_html(source: &Source, a: &Analysis) -> String {
    let mut s = String::from("<section id=\"survey\"><h2>Survey</h2>\n");
    match source {
        Source::Recordings(runs) => {
            let rows: Vec<Vec<String>> = runs
                .iter()
                .enumerate()
                .map(|(i, (p, r))| {
                    let (olo, ohi) = r.odometer_range_mm.unwrap_or((0.0, 0.0));
                    let placed = a.joins.iter().find(|j| j.run == i + 1).map_or("-".into(), text::describe_join);
                    vec![
                        format!("{}", i + 1),
                        p.display().to_string(),
                        r.frames.to_string(),
                        format!("{olo:.0}–{ohi:.0} mm"),
                        r.calibration_id.map_or("-".into(), |id| format!("{id:#010x}")),
                        placed,
                    ]
                })
                .collect();
            s.push_str(&html_table(
                "inputs",
                &["run", "recording", "frames", "odometer", "calibration", "placed"],
                &rows,
            ));
        }
        Source::Profile(p, f) => {
            let rows = vec![vec![p.display().to_string(), f.rows.to_string(), f.columns.join(", ")]];
            s.push_str(&html_table("inputs", &["profile", "rows", "lines"], &rows));
            for j in &a.joins {
                let _ = writeln!(s, "<p>{}</p>", html_escape(&text::describe_join(j)));
            }
        }
    }
    let x0 = a.lasers.iter().map(|l| l.stitched.x0_mm).fold(f64::INFINITY, f64::min);
    let x1 = a.lasers.iter().map(|l| l.stitched.x_mm(l.stitched.z_um.len())).fold(f64::NEG_INFINITY, f64::max);
    if x0.is_finite() && x1 >= x0 {
        let _ = writeln!(
            s,
            "<p class=\"span\">Chainage {} to {} ({:.3} m); {} line(s), samples every {} mm.</p>",
            html_escape(&crate::analyze::chainage(x0)),
            html_escape(&crate::analyze::chainage(x1)),
            (x1 - x0) / 1000.0,
            a.lasers.iter().map(|l| l.stitched.laser).collect::<std::collections::BTreeSet<_>>().len(),
            crate::analyze::fmt_len(a.options.stitch.dx_mm)
        );
    }
    for line in text::describe_sections(a).lines() {
        let _ = writeln!(s, "<p class=\"span\">{}</p>", html_escape(line.trim()));
    }
    s.push_str("</section>\n");
    s
}

/// The verdict: the edition and its limits' source, the reprofiling table,
/// the zones and the blocks.
fn verdict_html(a: &Analysis, zone_svg: &str) -> String {
    let v = &a.verdict;
    let e = v.options.edition;
    let mut s = String::from("<section id=\"verdict\"><h2>Verdict</h2>\n");
    let _ = writeln!(s, "<p><strong>{}</strong> — limits: {}</p>", html_escape(e.name()), html_escape(e.source()));
    let pct = if v.measured_mm > 0.0 { 100.0 * v.reprofile_mm / v.measured_mm } else { 0.0 };
    let _ = writeln!(
        s,
        "<p class=\"reprofile\">{:.3} km of {:.3} km should be reprofiled ({pct:.1} %).</p>",
        v.reprofile_mm / 1e6,
        v.measured_mm / 1e6
    );
    s.push_str("<h3>Reprofiling table</h3>\n");
    let rows: Vec<Vec<String>> = v
        .rows
        .iter()
        .map(|r| {
            let band = format!("{}–{} mm", r.band.lo_mm, r.band.hi_mm);
            match (&r.not_evaluated, r.limit_mm) {
                (Some(why), _) => {
                    vec![band, "-".into(), "-".into(), "-".into(), "-".into(), format!("not evaluated: {why}")]
                }
                (None, None) => vec![
                    band,
                    "-".into(),
                    format!("{:.1}", r.measured_mm / 1000.0),
                    "-".into(),
                    "-".into(),
                    "not judged (no limit)".into(),
                ],
                (None, Some(lim)) => vec![
                    band,
                    format!("{lim:.3}"),
                    format!("{:.1}", r.measured_mm / 1000.0),
                    format!("{:.1}", r.exceeding_mm / 1000.0),
                    format!("{:.1}", r.exceeding_percent()),
                    match r.passes(e) {
                        Some(true) => "pass".into(),
                        Some(false) => "FAIL".into(),
                        None => "-".into(),
                    },
                ],
            }
        })
        .collect();
    s.push_str(&html_table(
        "reprofiling",
        &["band", "limit, mm", "measured, m", "exceeding, m", "exceeding, %", "verdict"],
        &rows,
    ));
    let _ = writeln!(s, "<h3>Exceedance zones ({})</h3>", v.zones.len());
    if v.zones.is_empty() {
        s.push_str("<p>None.</p>\n");
    } else {
        let rows: Vec<Vec<String>> = v
            .zones
            .iter()
            .map(|z| {
                vec![
                    format!("{}–{} mm", z.band.lo_mm, z.band.hi_mm),
                    crate::analyze::chainage(z.start_mm),
                    crate::analyze::chainage(z.end_mm),
                    format!("{:.1}", (z.end_mm - z.start_mm) / 1000.0),
                    format!("{:.1}", z.exceeding_mm / 1000.0),
                    format!("{:.3}", z.worst_pp_mm),
                ]
            })
            .collect();
        s.push_str(&html_table(
            "zones",
            &["band", "start", "end", "length, m", "exceeding, m", "largest peak-to-peak, mm"],
            &rows,
        ));
    }
    if !zone_svg.is_empty() {
        let _ = writeln!(s, "<figure class=\"plot\">{zone_svg}</figure>");
    }
    let _ = writeln!(
        s,
        "<h3>Blocks of {} m</h3>\n<p>RMS of each band's displacement (largest line, µm) and the EN 15610 spectrum against ISO 3095.</p>",
        crate::analyze::fmt_len(v.options.block_mm / 1000.0)
    );
    let mut head = vec!["start".to_string(), "end".to_string()];
    head.extend(en13231::BANDS.iter().map(|b| format!("{}–{} mm", b.lo_mm, b.hi_mm)));
    head.push("ISO 3095".into());
    let head: Vec<&str> = head.iter().map(String::as_str).collect();
    let rows: Vec<Vec<String>> = v
        .blocks
        .iter()
        .map(|b| {
            let mut r = vec![crate::analyze::chainage(b.start_mm), crate::analyze::chainage(b.end_mm)];
            r.extend(b.rms_mm.iter().map(|v| v.map_or("-".into(), |v| format!("{:.1}", v * 1000.0))));
            r.push(match &b.iso3095_exceeded {
                None => "no spectrum".into(),
                Some(e) if e.is_empty() => "pass".into(),
                Some(e) => format!("FAIL at {} mm", e.iter().map(|w| w.to_string()).collect::<Vec<_>>().join(", ")),
            });
            r
        })
        .collect();
    s.push_str(&html_table("blocks", &head, &rows));
    s.push_str("</section>\n");
    s
}

/// Screen and print styles: on paper every section starts a page, plots
/// are scaled to the page width and kept whole, tables and text wrap.
const STYLE: &str = "body{font-family:sans-serif;max-width:1450px;margin:auto;padding:0 8px}\
pre{background:#f6f6f6;padding:8px;overflow-x:auto}\
svg{max-width:100%;height:auto;display:block}\
figure{margin:8px 0}\
table{border-collapse:collapse;margin:8px 0;font-size:0.9em}\
th,td{border:1px solid #bbb;padding:2px 6px;text-align:left;vertical-align:top}\
th{background:#eee}\
@media print{\
@page{size:A4 landscape;margin:12mm}\
body{max-width:none;margin:0;padding:0;font-size:9pt}\
h2{break-before:page;page-break-before:always}\
section#survey h2{break-before:auto;page-break-before:auto}\
h2,h3{break-after:avoid;page-break-after:avoid}\
pre{white-space:pre-wrap;word-break:break-word;overflow:visible;background:none;border:1px solid #ccc}\
svg,figure,img{max-width:100%!important;height:auto!important;break-inside:avoid;page-break-inside:avoid}\
table{width:100%;table-layout:auto;break-inside:auto}\
thead{display:table-header-group}\
tr{break-inside:avoid;page-break-inside:avoid}\
td,th{word-break:break-word}\
}";

fn median_of(z: &[f64]) -> f64 {
    crate::analyze::stitch::median(z.to_vec()).unwrap_or(0.0)
}

/// The stitched profiles on one grid per section: `x_mm,laser_K_um…`,
/// the sections one after the other (the stretches between them, never
/// measured, have no rows).
fn profile_csv(a: &Analysis) -> String {
    let mut s = String::from("x_mm");
    let mut lines: Vec<usize> = a.lasers.iter().map(|l| l.stitched.laser).collect();
    lines.sort_unstable();
    lines.dedup();
    for k in &lines {
        let _ = write!(s, ",laser_{k}_um");
    }
    s.push('\n');
    for sec in a.sections() {
        let grid = sec.grid;
        for i in 0..grid.len as i64 {
            let _ = write!(s, "{}", grid.chainage_mm(i as usize));
            for k in &lines {
                let v = sec.lasers.iter().find(|l| l.stitched.laser == *k).and_then(|l| {
                    let j = i - grid.offset(&l.stitched) as i64;
                    usize::try_from(j).ok().and_then(|j| l.stitched.z_um.get(j)).filter(|v| v.is_finite())
                });
                match v {
                    Some(v) => {
                        let _ = write!(s, ",{v:.4}");
                    }
                    None => s.push(','),
                }
            }
            s.push('\n');
        }
    }
    s
}

fn registration_csv(a: &Analysis) -> String {
    let mut s = String::from("laser,seq,centre_mm,overlap_mm,offset_um,tilt_um_per_mm,residual_um\n");
    for l in &a.lasers {
        for f in &l.stitched.fits {
            let _ = writeln!(
                s,
                "{},{},{:.3},{:.3},{:.4},{:.6},{:.4}",
                l.stitched.laser, f.seq, f.centre_mm, f.overlap_mm, f.offset_um, f.tilt_um_per_mm, f.residual_um
            );
        }
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

fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// Whether a file of this name is one a report writes (the files of the
/// table above): a folder holding only such files can be replaced by a
/// new report ([`crate::output::set`]).
pub fn owns(name: &str) -> bool {
    const FIXED: [&str; 12] = [
        "report.html",
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
    ];
    // `PREFIXK.EXT` with K a line's number.
    let per_line = |prefix: &str, exts: &[&str]| {
        name.strip_prefix(prefix)
            .and_then(|rest| rest.split_once('.'))
            .is_some_and(|(k, ext)| !k.is_empty() && k.bytes().all(|b| b.is_ascii_digit()) && exts.contains(&ext))
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

/// Writes the report's files into the (new, empty) folder `dir`.
fn write_files(dir: &Path, source: &Source, a: &Analysis, summary: &str) -> Result<(), Error> {
    let out_err = |what: &str, e: crate::plot::PlotError| Error::Output(std::io::Error::other(format!("{what}: {e}")));
    // Each file whole or not at all, and never over a device or FIFO of that name.
    let put = |name: &str, text: &str| -> Result<(), Error> {
        Ok(crate::output::write_atomically(&dir.join(name), |w| w.write_all(text.as_bytes()))?)
    };
    put("summary.txt", summary)?;
    put("profile.csv", &profile_csv(a))?;
    put("registration.csv", &registration_csv(a))?;
    put("gaps.csv", &gaps_csv(a))?;
    exports::write_files(dir, source, a)?;

    // (title, svg file stem, svg text)
    let mut figures: Vec<(String, String, String)> = Vec::new();
    let lines = a
        .lasers
        .iter()
        .map(|l| {
            let s = &l.stitched;
            let m = median_of(&s.z_um);
            let z: Vec<f64> = s.z_um.iter().map(|v| v - m).collect();
            (s.laser, plot_pieces(s.x0_mm, s.dx_mm, &z, MAX_PLOT_POINTS))
        })
        .collect();
    let svg = plot::svg_and_png(&dir.join("profile"), (1400, 600), &ProfileFig { lines })
        .map_err(|e| out_err("profile plot", e))?;
    figures.push(("Stitched profiles".into(), "profile".into(), svg));
    let several = a.sections().len() > 1;
    for l in &a.lasers {
        let k = l.stitched.laser;
        let (name, title) = line_names(&l.stitched, several);
        if let Ok(b) = &l.bands {
            put(&format!("bands_{name}.csv"), &en13231::bands_csv_from(b, l.stitched.x0_mm))?;
            let stem = format!("bands_{name}");
            let svg =
                plot::svg_and_png(&dir.join(&stem), (1400, 1000), &BandsFig { laser: k, x0: l.stitched.x0_mm, a: b })
                    .map_err(|e| out_err("band plot", e))?;
            figures.push((format!("{title}: EN 13231-3 bands"), stem, svg));
        }
        if let Ok(r) = &l.roughness {
            put(&format!("spectrum_{name}.csv"), &en15610::spectrum_csv(&r.spectrum))?;
        }
    }
    let spectra: Vec<(usize, &en15610::Spectrum)> =
        a.lasers.iter().filter_map(|l| l.roughness.as_ref().ok().map(|r| (l.stitched.laser, &r.spectrum))).collect();
    if !spectra.is_empty() {
        let svg = plot::svg_and_png(&dir.join("spectrum"), (1100, 650), &SpectrumFig { spectra })
            .map_err(|e| out_err("spectrum plot", e))?;
        figures.push(("EN 15610 roughness spectrum".into(), "spectrum".into(), svg));
    }

    let zone_svg = if a.lasers.is_empty() {
        String::new()
    } else {
        plot::svg_and_png(&dir.join("zones"), (1400, 900), &ZoneFig { a }).map_err(|e| out_err("zone plot", e))?
    };

    let title = format!("Rail corrugation analysis: {}", source.name());
    let head = text::describe(source, a);
    let verdict_text = reprofiling::describe(&a.verdict);
    let mut md = format!("# {title}\n\n## Survey\n\n```text\n{head}```\n\n## Verdict\n\n```text\n{verdict_text}```\n");
    if !zone_svg.is_empty() {
        md.push_str("\n![Exceedance along chainage](zones.svg) ([PNG](zones.png))\n");
    }
    let mut html = format!(
        "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{t}</title>\n<style>{STYLE}</style></head><body>\n<h1>{t}</h1>\n",
        t = html_escape(&title),
    );
    html.push_str(&survey_html(source, a));
    let _ = writeln!(
        html,
        "<details open><summary>Inputs and stitching in detail</summary><pre>{}</pre></details>",
        html_escape(&head)
    );
    html.push_str(&verdict_html(a, &zone_svg));
    marks::add(dir, source, a, &mut md, &mut html)?;
    for l in &a.lasers {
        let (_, k) = line_names(&l.stitched, several);
        let text = format!(
            "{}\n{}\n{}",
            text::describe_stitched(&l.stitched),
            text::describe_bands(&l.bands),
            text::describe_roughness(&l.roughness)
        );
        let _ = write!(md, "\n## {k}\n\n```text\n{text}```\n");
        let _ = write!(html, "<h2>{k}</h2>\n<pre>{}</pre>\n", html_escape(&text));
    }
    md.push_str("\n## Plots\n");
    html.push_str("<h2>Plots</h2>\n");
    for (t, stem, svg) in &figures {
        let _ = write!(md, "\n### {t}\n\n![{t}]({stem}.svg) ([PNG]({stem}.png))\n");
        let _ = write!(html, "<h3>{}</h3>\n<figure class=\"plot\">{svg}</figure>\n", html_escape(t));
    }
    let files = "profile.csv (x_mm, one height column per laser, µm), bands_laserK.csv (band signals, mm), \
                 spectrum_laserK.csv (one-third octaves; bands_laserK_sectionN.csv and \
                 spectrum_laserK_sectionN.csv when the line is in several sections), registration.csv (per frame), gaps.csv, summary.txt; \
                 profile.parquet, blocks.parquet, zones.parquet (docs/exports.md)";
    let _ = write!(md, "\n## Data\n\n{files}\n");
    let _ = write!(html, "<h2>Data</h2>\n<p>{}</p>\n</body></html>\n", html_escape(files));
    put("report.md", &md)?;
    put("report.html", &html)?;
    Ok(())
}
