//! `report.html`: every section as HTML tables and inline SVG figures, built
//! from the [`Analysis`] itself (the text summary is its own rendering of
//! the same facts, [`super::text`]).
//!
//! Self-contained and offline: the style is inline, the plots are inline
//! SVG, nothing is fetched (no link, font, script or image from elsewhere).
//! On paper (`@media print`): A4 landscape with margins, each section
//! (`<h2>`) on a new page, plots scaled to the page width and kept whole,
//! table rows never split across pages and headers repeated, colours
//! printed as on screen (`print-color-adjust: exact`).

use std::fmt::Write as _;

use crate::analyze::marks::PlacedMark;
use crate::analyze::standards::{StandardsError, en13231, en15610, fmt_mm, fmt_nominal_mm};
use crate::analyze::stitch::Stitched;
use crate::analyze::{Analysis, LaserAnalysis, Recording, Source, chainage, fmt_len, reprofiling};

use super::table::{escape, facts, table};
use super::text;
use super::track::Track;
use crate::analyze::floor::BandJudgement;

/// Screen and print styles (see the module docs).
pub const STYLE: &str = "body{font-family:sans-serif;max-width:1450px;margin:auto;padding:0 8px}\
svg{max-width:100%;height:auto;display:block}\
figure{margin:8px 0}\
table{border-collapse:collapse;margin:8px 0;font-size:0.9em}\
th,td{border:1px solid #bbb;padding:2px 6px;text-align:left;vertical-align:top}\
th{background:#eee}\
td.num{text-align:right;font-variant-numeric:tabular-nums}\
td.good{background:#dff0d8}\
td.bad{background:#f8d7da;font-weight:bold}\
p.note{color:#444;font-size:0.9em}\
@media print{\
@page{size:A4 landscape;margin:12mm}\
*{-webkit-print-color-adjust:exact;print-color-adjust:exact}\
body{max-width:none;margin:0;padding:0;font-size:9pt}\
h2{break-before:page;page-break-before:always}\
section#survey h2{break-before:auto;page-break-before:auto}\
h2,h3{break-after:avoid;page-break-after:avoid}\
figure,img{max-width:100%!important;break-inside:avoid;page-break-inside:avoid}\
svg{max-width:100%!important;max-height:165mm!important;width:auto!important;height:auto!important;margin:auto}\
table{width:auto;max-width:100%;break-inside:auto}\
thead{display:table-header-group}\
tr{break-inside:avoid;page-break-inside:avoid}\
td{overflow-wrap:break-word}\
td.num{white-space:nowrap}\
}";

fn opt_um(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.2} µm"))
}

fn band_name(b: &en13231::Band) -> String {
    format!("{}–{} mm", fmt_mm(b.lo_mm), fmt_mm(b.hi_mm))
}

/// The figures the page embeds.
pub struct Figures<'a> {
    /// The zone plot's SVG (empty without lines).
    pub zones: &'a str,
    /// (title, file stem, SVG) of the plots section.
    pub plots: &'a [(String, String, String)],
    /// The GNSS track's SVG, when the recordings hold fixes to plot.
    pub track: Option<&'a str>,
}

/// The whole page.
pub fn page(title: &str, source: &Source, a: &Analysis, track: Option<&Track>, figs: &Figures<'_>) -> String {
    let mut html = format!(
        "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{t}</title>\n<style>{STYLE}</style></head><body>\n<h1>{t}</h1>\n",
        t = escape(title),
    );
    html.push_str(&survey(source, a));
    html.push_str(&verdict(a, figs.zones));
    html.push_str(&marks(&super::marks::of(source, a)));
    html.push_str(&inputs(source, a));
    html.push_str(&gnss_track(source, track, figs.track));
    let several = a.sections().len() > 1;
    for l in &a.lasers {
        html.push_str(&line(l, several));
    }
    html.push_str(&plots(figs.plots));
    let _ = write!(
        html,
        "<section id=\"data\"><h2>Data</h2>\n<p>{}</p>\n</section>\n</body></html>\n",
        escape(super::FILES)
    );
    html
}

/// The survey header: the inputs, the runs and how each was placed, the
/// chainage span and the sections.
fn survey(source: &Source, a: &Analysis) -> String {
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
            s.push_str(&table("inputs", &["run", "recording", "frames", "odometer", "calibration", "placed"], &rows));
        }
        Source::Profile(p, f) => {
            let rows = vec![vec![p.display().to_string(), f.rows.to_string(), f.columns.join(", ")]];
            s.push_str(&table("inputs", &["profile", "rows", "lines"], &rows));
            if !a.joins.is_empty() {
                let rows: Vec<Vec<String>> =
                    a.joins.iter().map(|j| vec![j.run.to_string(), text::describe_join(j)]).collect();
                s.push_str(&table("placement", &["run", "placed"], &rows));
            }
        }
    }
    let x0 = a.lasers.iter().map(|l| l.stitched.x0_mm).fold(f64::INFINITY, f64::min);
    let x1 = a.lasers.iter().map(|l| l.stitched.x_mm(l.stitched.z.len())).fold(f64::NEG_INFINITY, f64::max);
    if x0.is_finite() && x1 >= x0 {
        let _ = writeln!(
            s,
            "<p class=\"span\">Chainage {} to {} ({:.3} m); {} line(s), samples every {} mm.</p>",
            escape(&chainage(x0)),
            escape(&chainage(x1)),
            (x1 - x0) / 1000.0,
            a.lasers.iter().map(|l| l.stitched.laser).collect::<std::collections::BTreeSet<_>>().len(),
            fmt_len(a.options.stitch.dx_mm)
        );
    }
    s.push_str(&sections(a));
    s.push_str("</section>\n");
    s
}

/// The survey line's sections and the stretches between them (nothing for
/// one section).
fn sections(a: &Analysis) -> String {
    let sections = a.sections();
    if sections.len() < 2 {
        return String::new();
    }
    let mut s = format!(
        "<p class=\"span\">Survey line in {} sections (a stretch without data longer than {} m separates two).</p>\n",
        sections.len(),
        fmt_len(crate::analyze::survey::section_gap_mm(&a.options.verdict) / 1000.0)
    );
    let mut rows = Vec::new();
    let mut last: Option<f64> = None;
    for sec in &sections {
        let (x0, x1) = sec.span_mm();
        if let Some(end) = last {
            rows.push(vec!["not measured".into(), chainage(end), chainage(x0), format!("{:.3}", (x0 - end) / 1000.0)]);
        }
        rows.push(vec![
            format!("section {}", sec.number),
            chainage(x0),
            chainage(x1),
            format!("{:.3}", (x1 - x0) / 1000.0),
        ]);
        last = Some(x1);
    }
    s.push_str(&table("sections", &["stretch", "from", "to", "length, m"], &rows));
    s
}

/// The reprofiling table's rows.
fn reprofiling_rows(v: &reprofiling::ReprofilingVerdict) -> Vec<Vec<String>> {
    let e = v.options.edition;
    let dash = || "-".to_string();
    v.rows
        .iter()
        .map(|r| {
            let band = band_name(&r.band);
            let floor = r.judgement.floor.map_or(dash(), |f| format!("{:.4}", f.judged_quantity_mm(e)));
            let mut row = match (&r.not_evaluated, r.limit_mm) {
                (Some(why), _) => vec![band, dash(), dash(), dash(), dash(), format!("not evaluated: {why}")],
                (None, _) if r.judgement.not_judged.is_some() => vec![
                    band,
                    r.limit_mm.map_or(dash(), |l| format!("{l:.3}")),
                    format!("{:.1}", r.measured_mm / 1000.0),
                    dash(),
                    dash(),
                    r.judgement.not_judged.clone().unwrap_or_default(),
                ],
                (None, None) => vec![
                    band,
                    dash(),
                    format!("{:.1}", r.measured_mm / 1000.0),
                    dash(),
                    dash(),
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
                        None => dash(),
                    },
                ],
            };
            row.push(floor);
            row
        })
        .collect()
}

/// The blocks table.
fn blocks(v: &reprofiling::ReprofilingVerdict) -> String {
    let mut head = vec!["start".to_string(), "end".to_string()];
    head.extend(en13231::BANDS.iter().map(band_name));
    head.push("ISO 3095".into());
    let head: Vec<&str> = head.iter().map(String::as_str).collect();
    let rows: Vec<Vec<String>> = v
        .blocks
        .iter()
        .map(|b| {
            let mut r = vec![chainage(b.start_mm), chainage(b.end_mm)];
            r.extend(b.rms_mm.iter().map(|v| v.map_or("-".into(), |v| format!("{:.1}", v * 1000.0))));
            r.push(reprofiling::block_iso3095_words(b));
            r
        })
        .collect();
    table("blocks", &head, &rows)
}

/// The verdict: the edition and its limits' source, the reprofiling table,
/// the zones and the blocks.
fn verdict(a: &Analysis, zone_svg: &str) -> String {
    let v = &a.verdict;
    let e = v.options.edition;
    let mut s = String::from("<section id=\"verdict\"><h2>Verdict</h2>\n");
    let _ = writeln!(s, "<p><strong>{}</strong> — limits: {}</p>", escape(e.name()), escape(e.source()));
    let pct = if v.measured_mm > 0.0 { 100.0 * v.reprofile_mm / v.measured_mm } else { 0.0 };
    if v.rows.iter().all(|r| r.limit_mm.is_none() || r.judgement.not_judged.is_some()) {
        let _ = writeln!(
            s,
            "<p class=\"reprofile\">Not judged: no band's noise floor allows a verdict ({:.3} km measured).</p>",
            v.measured_mm / 1e6
        );
    } else {
        let _ = writeln!(
            s,
            "<p class=\"reprofile\">{:.3} km of {:.3} km should be reprofiled ({pct:.1} %).</p>",
            v.reprofile_mm / 1e6,
            v.measured_mm / 1e6
        );
    }
    s.push_str("<h3>Reprofiling table</h3>\n");
    s.push_str(&table(
        "reprofiling",
        &["band", "limit, mm", "measured, m", "exceeding, m", "exceeding, %", "verdict", "noise floor, mm"],
        &reprofiling_rows(v),
    ));
    s.push_str(&floor(a));
    let _ = writeln!(s, "<h3>Exceedance zones ({})</h3>", v.zones.len());
    if v.zones.is_empty() {
        s.push_str("<p>None.</p>\n");
    } else {
        let rows: Vec<Vec<String>> = v
            .zones
            .iter()
            .map(|z| {
                vec![
                    band_name(&z.band),
                    chainage(z.start_mm),
                    chainage(z.end_mm),
                    format!("{:.1}", (z.end_mm - z.start_mm) / 1000.0),
                    format!("{:.1}", z.exceeding_mm / 1000.0),
                    format!("{:.3}", z.worst_pp_mm),
                ]
            })
            .collect();
        s.push_str(&table(
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
        fmt_len(v.options.block_mm / 1000.0)
    );
    s.push_str(&blocks(v));
    s.push_str("</section>\n");
    s
}

/// The inputs and the stitching in detail: per run what the recording held
/// and what reading it found, how the frames were stitched.
fn inputs(source: &Source, a: &Analysis) -> String {
    let mut s = String::from("<section id=\"inputs\"><h2>Inputs and stitching</h2>\n");
    match source {
        Source::Recordings(runs) => {
            s.push_str(&runs_table(runs));
            let notes: Vec<Vec<String>> = runs
                .iter()
                .enumerate()
                .flat_map(|(i, (p, r))| run_notes(p, r).into_iter().map(move |n| vec![(i + 1).to_string(), n]))
                .collect();
            if !notes.is_empty() {
                s.push_str("<h3>What each run says</h3>\n");
                s.push_str(&table("run-notes", &["run", "note"], &notes));
            }
            let st = &a.stitching;
            let how = match (st.direction_residuals_um, st.direction_given) {
                (Some(_), false) => " (chosen from the data)",
                (Some(_), true) => " (as given)",
                (None, _) => "",
            };
            let mut rows = vec![("direction", format!("{}{how}", text::direction_name(st.direction)))];
            if let Some((f, r)) = st.direction_residuals_um {
                rows.push(("median overlap residual, forward", opt_um(f)));
                rows.push(("median overlap residual, reverse", opt_um(r)));
            }
            rows.push(("registration", text::registration_name(a.options.stitch.registration).into()));
            rows.push(("samples every", format!("{} mm", fmt_len(a.options.stitch.dx_mm))));
            s.push_str("<h3>Stitching</h3>\n");
            s.push_str(&facts("stitching", &rows));
        }
        Source::Profile(path, p) => {
            let rows = vec![
                ("profile", path.display().to_string()),
                ("rows", p.rows.to_string()),
                ("lines", format!("{} ({})", p.columns.len(), p.columns.join(", "))),
                (
                    "positions",
                    if p.has_x {
                        format!("every {} mm (median step)", fmt_len(p.data_dx_mm))
                    } else {
                        "no position column".into()
                    },
                ),
                (
                    "samples every",
                    format!(
                        "{} mm{}",
                        fmt_len(a.options.stitch.dx_mm),
                        if p.resampled { " (interpolated onto that grid; never across a gap)" } else { "" }
                    ),
                ),
            ];
            s.push_str(&facts("profile", &rows));
        }
    }
    s.push_str("</section>\n");
    s
}

/// One row per run: what its recording held.
fn runs_table(runs: &[(std::path::PathBuf, Recording)]) -> String {
    let rows: Vec<Vec<String>> = runs
        .iter()
        .enumerate()
        .map(|(i, (p, r))| {
            let (smin, smax) = r.seq_range.unwrap_or((0, 0));
            let (olo, ohi) = r.odometer_range_mm.unwrap_or((0.0, 0.0));
            vec![
                (i + 1).to_string(),
                p.display().to_string(),
                r.frames.to_string(),
                format!("{smin}–{smax}"),
                r.calibrated_points.to_string(),
                r.uncalibrated_points.to_string(),
                format!("{olo:.3}–{ohi:.3}"),
                r.calibration_id.map_or("-".into(), |id| format!("{id:#010x}")),
                match &r.slid_across {
                    Some((n, _)) => format!("{n} of {}", r.frames),
                    None => "no (no --calibration)".into(),
                },
            ]
        })
        .collect();
    table(
        "runs",
        &[
            "run",
            "recording",
            "frames with calibrated points",
            "seq",
            "points",
            "points left out (uncalibrated)",
            "odometer, mm",
            "calibration",
            "slid across the lateral slope",
        ],
        &rows,
    )
}

/// What a run's recording says besides its counts: its survey, how it was
/// joined, the calibration it was slid with, what reading skipped.
fn run_notes(path: &std::path::Path, r: &Recording) -> Vec<String> {
    let mut notes = Vec::new();
    if let Some(sv) = &r.survey {
        notes.push(format!("survey: {}", sv.describe()));
    }
    if let Some(k) = r.repeats {
        notes.push(format!("the same recording as run {k}, joined as asked (--allow-repeated-runs)"));
    }
    if let Some((k, how)) = &r.other_head {
        notes.push(format!("recorded by another head than run {k} ({how}), joined as asked (--allow-mixed-heads)"));
    }
    match &r.slid_across {
        Some((n, cal)) => notes.push(format!(
            "heights slid across the rail head's lateral slope with {} ({n} of {} frames)",
            cal.display(),
            r.frames
        )),
        None => notes.push(
            "heights as the head measured them (no --calibration: the outer lines keep their lateral-slope scale)"
                .into(),
        ),
    }
    notes.extend(crate::recording::warnings(path, &r.stats));
    notes
}

/// The GNSS track: its table and plot, or that there is none.
fn gnss_track(source: &Source, track: Option<&Track>, svg: Option<&str>) -> String {
    let mut s = String::from("<section id=\"track\"><h2>GNSS track</h2>\n");
    match (source, track) {
        (Source::Profile(..), _) => s.push_str("<p>No GNSS fixes: the input is a profile file, not a recording.</p>\n"),
        (Source::Recordings(runs), None) => {
            let _ = writeln!(s, "<p>No GNSS fixes in the recording{}.</p>", if runs.len() > 1 { "s" } else { "" });
        }
        (_, Some(t)) => {
            let _ = writeln!(s, "<p>{}</p>", escape(&t.describe_origin()));
            let (head, rows) = t.table();
            let head: Vec<&str> = head.iter().map(String::as_str).collect();
            s.push_str(&table("track", &head, &rows));
            if let Some(svg) = svg {
                let _ = writeln!(s, "<figure class=\"plot\">{svg}</figure>");
            }
            let _ = writeln!(s, "<p class=\"note\">{}</p>", escape(super::track::HOW));
        }
    }
    s.push_str("</section>\n");
    s
}

/// The noise floor (one line's, from the lines' null combinations) and
/// each section's running band: the profile the verdict judges.
fn floor(a: &Analysis) -> String {
    let mut s = String::from("<h3>Noise floor and the running band</h3>\n");
    let Some(f) = &a.floor else {
        s.push_str("<p>The noise floor is not known (no section has two lines to tell rail from noise): the verdict is as measured.</p>\n");
        return s;
    };
    let _ = writeln!(
        s,
        "<p>One line's noise floor, from the {} lines' null combinations over {:.1} m (what the lines do not have in common: speckle, sensor noise, the stitch's per-line errors; see docs/noise-floor.md). EN 15610's spike removal takes {:.1} \"spikes\" a metre out of noise alone.</p>",
        f.lines,
        f.measured_mm / 1000.0,
        f.spikes_per_m
    );
    let dash = || "-".to_string();
    let rows: Vec<Vec<String>> = en13231::BANDS
        .iter()
        .enumerate()
        .map(|(b, band)| match f.band(b) {
            Some(x) => vec![
                band_name(band),
                format!("{:.1}", x.rms_mm * 1000.0),
                format!("{:.1}", x.average_mean_pp_mm * 1000.0),
                format!("{:.1}", x.of_mean(f.lines).average_mean_pp_mm * 1000.0),
                format!("{:.0}", band.mean_pp_limit_mm * 1000.0),
                format!("{:.2}", x.coherence),
            ],
            None => vec![band_name(band), dash(), dash(), dash(), dash(), "runs too short".into()],
        })
        .collect();
    s.push_str(&table(
        "floor",
        &[
            "band",
            "one line's floor, RMS µm",
            "one line's floor, mean peak-to-peak µm",
            "running band's floor, mean peak-to-peak µm",
            "2006 limit, µm",
            "coherence of the lines",
        ],
        &rows,
    ));
    s.push_str(&line_floors(f));
    s.push_str(&super::optics::html(a));
    for rb in &a.running_bands {
        let _ = writeln!(s, "<h4>Running band of section {}: the mean of {} lines</h4>", rb.section, rb.lines);
        s.push_str(&bands(&rb.bands, &rb.judgements));
        if let Some(sp) = &rb.roughness {
            let _ = writeln!(s, "<p>EN 15610: the {} lines' spectra energy-averaged.</p>", rb.lines);
            s.push_str(&roughness(&Ok(en15610::Roughness { spectrum: sp.clone(), spikes_removed: 0 })));
        }
    }
    s
}

/// Each line's own floor (from the pairs of lines) and the line whose
/// floor stands out, with its likely causes.
fn line_floors(f: &crate::analyze::floor::Floor) -> String {
    use crate::analyze::line_floor::{LIKELY_CAUSES, MIN_SHARE};
    let mut s = String::new();
    if f.lines_own.is_empty() {
        return s;
    }
    let mut head = vec!["line".to_string()];
    head.extend(en13231::BANDS.iter().map(|b| format!("{}, RMS µm", band_name(b))));
    head.push(format!("clipped at {:.0} dB of the mean", 10.0 * MIN_SHARE.log10()));
    let head: Vec<&str> = head.iter().map(String::as_str).collect();
    let rows: Vec<Vec<String>> = f
        .lines_own
        .iter()
        .map(|l| {
            let mut r = vec![l.laser.to_string()];
            r.extend(l.bands.iter().map(|b| b.map_or("-".into(), |b| format!("{:.2}", b.rms_mm * 1000.0))));
            r.push(if l.clipped.is_empty() { "-".into() } else { l.clipped.join(", ") });
            r
        })
        .collect();
    s.push_str("<p>Each line's own floor, from the pairs of lines (each line is judged against its own):</p>\n");
    s.push_str(&table("line-floors", &head, &rows));
    if let Some((laser, db)) = f.standing_out() {
        let _ = writeln!(
            s,
            "<p class=\"note\">Line {laser}'s floor stands {db:.1} dB over the other lines' (median over the bands): likely {}.</p>",
            escape(LIKELY_CAUSES)
        );
    }
    s
}

/// One line's section: its stitching, the EN 13231-3 bands and the EN
/// 15610 roughness.
fn line(l: &LaserAnalysis, several: bool) -> String {
    let (name, title) = super::line_names(&l.stitched, several);
    let mut s = format!("<section id=\"{name}\"><h2>{}</h2>\n", escape(&title));
    s.push_str("<h3>Stitched line</h3>\n");
    s.push_str(&stitched(&l.stitched));
    s.push_str("<h3>EN 13231-3 bands</h3>\n");
    s.push_str(&bands(&l.bands, &l.judgements));
    s.push_str("<h3>EN 15610 roughness</h3>\n");
    s.push_str(&roughness(&l.roughness));
    s.push_str("</section>\n");
    s
}

/// Most gap and unregistered-join rows of a line shown (the CSVs have all).
const MAX_ROWS: usize = 20;

/// A line's stitching: its facts, gaps and unregistered joins.
fn stitched(l: &Stitched) -> String {
    let overlap = l.fits.median_overlap_mm();
    let rows = vec![
        ("laser", l.laser.to_string()),
        ("section", l.section.to_string()),
        ("track", format!("{:.0} mm from chainage {}", l.length_mm(), chainage(l.x0_mm))),
        ("covered", format!("{:.0} mm", l.covered_mm())),
        ("runs averaged", format!("{:.2}", l.runs_averaged)),
        ("frames", l.frames.to_string()),
        ("points", l.points.to_string()),
        ("registered frames", l.fits.len().to_string()),
        ("median overlap", overlap.map_or("-".into(), |v| format!("{v:.0} mm"))),
        ("registration residual, median", opt_um(l.median_residual_um())),
        ("offsets, RMS", format!("{:.2} µm", l.fits.offset_rms_um())),
        ("tilts, RMS", format!("{:.4} µm/mm", l.fits.tilt_rms_um_per_mm())),
        ("unregistered joins", l.joins.len().to_string()),
        ("gaps", l.gaps.len().to_string()),
    ];
    let mut s = facts("stitched", &rows);
    if !l.gaps.is_empty() {
        let rows: Vec<Vec<String>> =
            l.gaps.iter().take(MAX_ROWS).map(|g| vec![chainage(g.start_mm), fmt_len(g.length_mm)]).collect();
        s.push_str(&table("gaps", &["gap at", "length, mm"], &rows));
        if l.gaps.len() > MAX_ROWS {
            let _ = writeln!(s, "<p class=\"note\">… and {} more gaps (gaps.csv).</p>", l.gaps.len() - MAX_ROWS);
        }
    }
    if !l.joins.is_empty() {
        let rows: Vec<Vec<String>> = l
            .joins
            .iter()
            .take(MAX_ROWS)
            .map(|j| vec![j.seq.to_string(), chainage(j.at_mm), format!("{:.1}", j.overlap_mm)])
            .collect();
        s.push_str(&table("joins", &["frame joined unregistered", "at", "overlap, mm"], &rows));
        if l.joins.len() > MAX_ROWS {
            let _ = writeln!(s, "<p class=\"note\">… and {} more unregistered joins.</p>", l.joins.len() - MAX_ROWS);
        }
    }
    s
}

/// One line's EN 13231-3 outcome: a row per band.
fn bands(b: &Result<en13231::BandAnalysis, StandardsError>, judgements: &[BandJudgement]) -> String {
    let a = match b {
        Ok(a) => a,
        Err(e) => return format!("<p>EN 13231-3 bands not evaluated: {}</p>\n", escape(&e.to_string())),
    };
    let mut s = format!(
        "<p>2006-style criteria (secondary source); record {} mm in {} run(s), sampling {} mm.</p>\n",
        fmt_mm(a.record_mm),
        a.runs,
        a.dx_mm
    );
    let dash = || "-".to_string();
    let rows: Vec<Vec<String>> = a
        .bands
        .iter()
        .enumerate()
        .map(|(k, b)| {
            let j = judgements.get(k);
            let floor = j.and_then(|j| j.floor).map_or(dash(), |f| format!("{:.4}", f.average_mean_pp_mm));
            let head = vec![band_name(&b.band), fmt_mm(b.band.window_mm), format!("{:.3}", b.band.mean_pp_limit_mm)];
            let verdict = match j.and_then(|j| j.not_judged.clone()) {
                Some(why) => why,
                None if b.outcome.as_ref().is_ok_and(|st| st.passes) => "yes".into(),
                None => "NO".into(),
            };
            let mut rest = match &b.outcome {
                Ok(st) => vec![
                    format!("{:.4}", st.average_mean_pp_mm),
                    format!("{:.4}", st.worst_mean_pp_mm),
                    format!("{:.4}", st.worst_max_pp_mm),
                    format!("{:.4}", st.rms_mm),
                    format!("{:.1}", st.exceeding_percent),
                    verdict,
                    match (b.band.abs_limit_mm, st.abs_exceeding_percent) {
                        (Some(lim), Some(p)) => format!("2012 Class 1 ±{lim:.3} mm: {p:.1} % of length over"),
                        _ => String::new(),
                    },
                ],
                Err(e) => vec![dash(), dash(), dash(), dash(), dash(), dash(), e.to_string()],
            };
            rest.push(floor);
            head.into_iter().chain(rest).collect()
        })
        .collect();
    s.push_str(&table(
        "bands",
        &[
            "band",
            "window, mm",
            "limit, mm",
            "average mean peak-to-peak, mm",
            "worst mean peak-to-peak, mm",
            "worst max peak-to-peak, mm",
            "RMS, mm",
            "exceeding, %",
            "pass",
            "note",
            "noise floor, mean peak-to-peak, mm",
        ],
        &rows,
    ));
    s
}

/// One line's EN 15610 outcome: the spectrum against ISO 3095, the
/// wavelengths not evaluated, the peak.
fn roughness(r: &Result<en15610::Roughness, StandardsError>) -> String {
    let r = match r {
        Ok(r) => r,
        Err(e) => return format!("<p>EN 15610 roughness not evaluated: {}</p>\n", escape(&e.to_string())),
    };
    let sp = &r.spectrum;
    let mut s = format!(
        "<p>One-third octaves, dB re 1 µm: {} segment(s) of {} mm, sampling {} mm, {} spike(s) removed.</p>\n",
        sp.segments,
        fmt_mm(sp.segment_mm),
        sp.dx_mm,
        r.spikes_removed
    );
    let rows: Vec<Vec<String>> = sp
        .bands
        .iter()
        .map(|b| {
            let dash = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.1}"));
            let d = b.decision();
            vec![
                fmt_nominal_mm(b.nominal_wavelength_mm),
                format!("{:.1}", b.level_db),
                dash(b.floor_db),
                d.as_ref().map_or("-".into(), |d| d.rail.to_string()),
                dash(b.iso3095_limit_db),
                d.map_or("-".into(), |d| d.words()),
            ]
        })
        .collect();
    let rail_head = format!("rail, dB [{} % interval]", crate::analyze::standards::detection::CONFIDENCE_PERCENT);
    s.push_str(&table(
        "spectrum",
        &["wavelength, mm", "level, dB", "noise floor, dB", &rail_head, "ISO 3095 limit, dB", "verdict"],
        &rows,
    ));
    let missing = crate::analyze::iso3095_not_evaluated(r);
    if !missing.is_empty() {
        let rows: Vec<Vec<String>> = missing.iter().map(|(w, why)| vec![fmt_len(*w), why.clone()]).collect();
        s.push_str(&table("iso3095-missing", &["ISO 3095 wavelength not evaluated, mm", "why"], &rows));
    }
    if let Some(p) = crate::analyze::spectrum_peak(r) {
        let (exceeds, within, not_judged) = crate::analyze::verdict_counts(sp);
        let mut rows = vec![
            ("spectrum peak", format!("{} mm one-third octave", fmt_len(p.nominal_wavelength_mm))),
            ("measured level", format!("{:.1} dB", p.level_db)),
        ];
        if let Some(d) = p.decision() {
            rows.push(("rail's own level", format!("{} dB", d.rail)));
            rows.push(("ISO 3095 limit there", format!("{:.1} dB", d.limit_db)));
            rows.push(("its verdict", d.words()));
        }
        rows.push(("ISO 3095 third octaves", format!("{exceeds} exceed, {within} within, {not_judged} not judged")));
        s.push_str(&facts("peak", &rows));
    }
    s
}

/// The HTML report's "Marks" section: a table in chainage order.
fn marks(marks: &[PlacedMark]) -> String {
    let mut s = String::from("<section id=\"marks\"><h2>Marks</h2>\n");
    if marks.is_empty() {
        s.push_str("<p>No event marks were recorded.</p>\n");
    } else {
        s.push_str(&table("marks", &super::marks::HEAD, &super::marks::rows(marks)));
        let _ = writeln!(
            s,
            "<p>Each mark at the odometer of the frame before it (to within one frame's travel); also in {}.</p>",
            super::marks::CSV_FILE
        );
    }
    s.push_str("</section>\n");
    s
}

/// The plots section.
fn plots(figures: &[(String, String, String)]) -> String {
    let mut s = String::from("<section id=\"plots\"><h2>Plots</h2>\n");
    for (t, _, svg) in figures {
        let _ = write!(s, "<h3>{}</h3>\n<figure class=\"plot\">{svg}</figure>\n", escape(t));
    }
    s.push_str("</section>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_marks_section_holds_every_mark_escaped() {
        let h = marks(&super::super::marks::tests::marks());
        assert!(
            h.contains("<table class=\"marks\">") && h.contains("<td>12+345.250</td><td>kilometre post</td>"),
            "{h}"
        );
        assert!(h.contains("a &lt;b&gt;") && !h.contains("<b>"), "{h}");
        assert!(marks(&[]).contains("No event marks"));
    }
}
