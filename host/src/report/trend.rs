//! The trend's report ([`crate::analyze::trend`]): `trend.html` (the
//! surveys, the registrations, the blocks nearest to exceeding and the
//! whole table), `trend.svg` / `trend.png` (the growth per year of every
//! block, per band, with ±2 u error bars, against chainage), `trend.csv`
//! (one row per block and band), `trend_iso3095.csv` (one row per block
//! and ISO 3095 third octave) and `summary.txt` — written as one output
//! set ([`crate::output::set`]), each file atomically.

use std::fmt::Write as _;
use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::Error;
use crate::analyze::chainage;
use crate::analyze::standards::detection;
use crate::analyze::trend::iso3095::{BlockIso3095, SHOWN_UNDER_LIMIT_DB, ThirdOctaveTrend};
use crate::analyze::trend::{BlockTrend, Crossing, SurveyRun, Trend};
use crate::plot::{self, Figure, err};
use crate::recording::survey_info::SurveyDate;
use crate::report::exports::{Column, Table, Values};

/// Whether a file of this name is one the trend report writes.
pub fn owns(name: &str) -> bool {
    ["trend.html", "trend.svg", "trend.png", "trend.csv", "trend_iso3095.csv", "summary.txt"].contains(&name)
}

/// The text table: surveys, registrations, the blocks nearest to exceeding.
pub fn summary(t: &Trend) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "trend over {} surveys, {} limits, blocks of {:.0} m",
        t.surveys.len(),
        t.edition.name(),
        t.block_mm / 1e3
    );
    for (i, (name, date)) in t.surveys.iter().enumerate() {
        let reg = t.registrations.iter().find(|r| r.survey == i);
        let check = match reg {
            None => "the reference".to_string(),
            Some(r) => match r.shift_mm {
                None => "not registered (no overlap of 2 m)".into(),
                Some(d) => format!(
                    "registered {:+.1} mm from its chainage (correlation {:.3}){}",
                    d,
                    r.correlation,
                    if r.disputed { ": CHAINAGE DISPUTED" } else { "" }
                ),
            },
        };
        let _ = writeln!(s, "  {} {}  {}", date, crate::output::printable(name), check);
        for p in t.placings.get(i).into_iter().flatten() {
            let _ = writeln!(s, "    {p}");
        }
    }
    let near = t.nearest();
    if near.is_empty() {
        let _ = writeln!(s, "no block crosses a limit within the horizon");
    } else {
        let _ = writeln!(s, "\nblocks nearest to exceeding:");
        let _ = writeln!(
            s,
            "  {:<24} {:<11} {:>9} {:>9} {:>18} crossing (±2u)",
            "block", "band", "limit µm", "last µm", "growth µm/yr ± u"
        );
        for b in near {
            let _ = writeln!(s, "  {}", row(b));
        }
    }
    s.push_str(&iso3095_summary(t));
    s
}

/// The ISO 3095 part of the text: the block third octaves whose verdict
/// changed or whose latest judged rail level stands near the limit.
fn iso3095_summary(t: &Trend) -> String {
    let mut s = String::new();
    let mut shown: Vec<(&BlockIso3095, &ThirdOctaveTrend)> =
        t.iso3095.iter().flat_map(|b| b.third_octaves.iter().filter(|o| o.shown()).map(move |o| (b, o))).collect();
    // The changes first, then the highest over (or nearest under) the limit.
    let over = |o: &ThirdOctaveTrend| o.latest_figure().map_or(f64::NEG_INFINITY, |f| f.0 - o.limit_db);
    shown.sort_by(|a, b| b.1.changed().is_some().cmp(&a.1.changed().is_some()).then(over(b.1).total_cmp(&over(a.1))));
    let more = shown.len().saturating_sub(MAX_SHOWN);
    shown.truncate(MAX_SHOWN);
    let what = format!(
        "ISO 3095 third octaves (the lines' EN 15610 energy average) whose verdict changed from the first to the last \
         survey, or whose latest judged rail level stands within {SHOWN_UNDER_LIMIT_DB:.0} dB of the limit or over; \
         changes first, then the highest against the limit"
    );
    if shown.is_empty() {
        let _ = writeln!(s, "\nno {what}");
        return s;
    }
    let _ = writeln!(s, "\n{what}:");
    let _ = writeln!(
        s,
        "  {:<24} {:>7} {:>8}  {:<36} {:>22} {:>16}",
        "block",
        "λ mm",
        "limit dB",
        "verdict per survey",
        format!("rail dB [{}%]", detection::CONFIDENCE_PERCENT),
        "growth dB/yr ± u"
    );
    for (b, o) in shown {
        let verdicts: Vec<&str> = o.readings.iter().map(|r| r.map_or("-", |r| r.verdict.name())).collect();
        let rail = o.readings.iter().rev().flatten().next().map_or("-".into(), |r| r.rail.to_string());
        let _ = writeln!(
            s,
            "  {:<24} {:>7} {:>8.1}  {:<36} {:>22} {:>16}",
            format!("{} – {}", chainage(b.start_mm), chainage(b.end_mm)),
            o.wavelength_mm,
            o.limit_db,
            verdicts.join(" → "),
            rail,
            o.growth.map_or("-".into(), |(g, u)| format!("{g:+.2} ± {u:.2}")),
        );
    }
    if more > 0 {
        let _ = writeln!(s, "  … and {more} more (every block and third octave: --json, trend_iso3095.csv)");
    }
    s
}

/// The most block third octaves the text lists.
const MAX_SHOWN: usize = 20;

/// "30–100 mm".
fn label(band: &crate::analyze::standards::en13231::Band) -> String {
    format!("{}–{} mm", band.lo_mm, band.hi_mm)
}

fn row(b: &BlockTrend) -> String {
    let last = b.figures.iter().rev().flatten().next().map_or("-".into(), |f| format!("{:.1}", f.1 * 1e3));
    let growth = b.growth.map_or("-".into(), |(g, u)| format!("{:+.2} ± {:.2}", g * 1e3, u * 1e3));
    format!(
        "{:<24} {:<11} {:>9} {:>9} {:>18} {}",
        format!("{} – {}", chainage(b.start_mm), chainage(b.end_mm)),
        label(&b.band),
        b.limit_mm.map_or("-".into(), |l| format!("{:.0}", l * 1e3)),
        last,
        growth,
        b.crossing
    )
}

/// The CSV table: one row per block and band.
pub fn csv(t: &Trend) -> String {
    let mut s = String::from("start_mm,end_mm,band,limit_mm");
    for (name, date) in &t.surveys {
        let _ = write!(s, ",figure_mm_{date},u_mm_{date}");
        let _ = name;
    }
    s.push_str(",growth_mm_per_year,u_growth_mm_per_year,chi2_reduced,crossing,crossing_earliest,crossing_latest\n");
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.6}"));
    for b in &t.blocks {
        let _ = write!(s, "{:.3},{:.3},{},{}", b.start_mm, b.end_mm, label(&b.band), opt(b.limit_mm));
        for f in &b.figures {
            let _ = write!(s, ",{},{}", opt(f.map(|f| f.1)), opt(f.map(|f| f.2)));
        }
        let (cross, lo, hi) = match &b.crossing {
            Crossing::AlreadyOver => ("already over".to_string(), String::new(), String::new()),
            Crossing::On { date, earliest, latest } => (
                date.to_string(),
                earliest.map_or(String::new(), |d| d.to_string()),
                latest.map_or(String::new(), |d| d.to_string()),
            ),
            c => (c.to_string(), String::new(), String::new()),
        };
        let _ = writeln!(
            s,
            ",{},{},{},{cross},{lo},{hi}",
            opt(b.growth.map(|g| g.0)),
            opt(b.growth.map(|g| g.1)),
            opt(b.chi2_reduced)
        );
    }
    s
}

/// The ISO 3095 CSV table: one row per block and third octave, each
/// survey's verdict, reading, floor and rail level with its interval (dB
/// re 1 µm; empty where the survey has no spectrum of the block or the
/// figure is not known), the change of verdict (`within → EXCEEDS`) and
/// the growth of the rail's level.
pub fn iso3095_csv(t: &Trend) -> String {
    let mut s = String::from("start_mm,end_mm,wavelength_mm,limit_db");
    for (_, date) in &t.surveys {
        for c in ["verdict", "level_db", "floor_db", "rail_db", "rail_lo_db", "rail_hi_db"] {
            let _ = write!(s, ",{c}_{date}");
        }
    }
    s.push_str(",changed,growth_db_per_year,u_growth_db_per_year,chi2_reduced\n");
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.3}"));
    for b in &t.iso3095 {
        for o in &b.third_octaves {
            let _ = write!(s, "{:.3},{:.3},{},{:.1}", b.start_mm, b.end_mm, o.wavelength_mm, o.limit_db);
            for r in &o.readings {
                let _ = write!(
                    s,
                    ",{},{},{},{},{},{}",
                    r.map_or("", |r| r.verdict.name()),
                    opt(r.map(|r| r.level_db)),
                    opt(r.and_then(|r| r.floor_db)),
                    opt(r.and_then(|r| r.rail.db)),
                    opt(r.and_then(|r| r.rail.lo_db)),
                    opt(r.and_then(|r| r.rail.hi_db)),
                );
            }
            let changed = o.changed().map_or(String::new(), |(a, b)| format!("{a} → {b}"));
            let _ = writeln!(
                s,
                ",{changed},{},{},{}",
                opt(o.growth.map(|g| g.0)),
                opt(o.growth.map(|g| g.1)),
                opt(o.chi2_reduced)
            );
        }
    }
    s
}

/// Growth per block against chainage, one panel per band.
struct GrowthFig<'a>(&'a Trend);

impl Figure for GrowthFig<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        root.fill(&WHITE).map_err(err)?;
        let root = root
            .titled("Growth of each block's figure per year (µm/year, ±2u), per EN 13231-3 band", ("sans-serif", 18))
            .map_err(err)?;
        let bands = crate::analyze::standards::en13231::BANDS;
        for (panel, band) in root.split_evenly((bands.len(), 1)).iter().zip(bands.iter()) {
            let pts: Vec<(f64, f64, f64)> = self
                .0
                .blocks
                .iter()
                .filter(|b| b.band == *band)
                .filter_map(|b| b.growth.map(|(g, u)| (0.5 * (b.start_mm + b.end_mm) / 1e3, g * 1e3, u * 1e3)))
                .collect();
            if pts.is_empty() {
                continue;
            }
            let x0 = self.0.blocks.iter().map(|b| b.start_mm / 1e3).fold(f64::INFINITY, f64::min);
            let x1 = self.0.blocks.iter().map(|b| b.end_mm / 1e3).fold(f64::NEG_INFINITY, f64::max);
            let y0 = pts.iter().map(|p| p.1 - 2.0 * p.2).fold(0.0, f64::min);
            let y1 = pts.iter().map(|p| p.1 + 2.0 * p.2).fold(0.0, f64::max);
            let pad = 0.1 * (y1 - y0).max(0.1);
            let mut chart = ChartBuilder::on(panel)
                .caption(label(band), ("sans-serif", 14))
                .margin(8)
                .x_label_area_size(30)
                .y_label_area_size(60)
                .build_cartesian_2d(x0..x1.max(x0 + 1.0), (y0 - pad)..(y1 + pad))
                .map_err(err)?;
            chart.configure_mesh().x_desc("chainage, m").y_desc("µm/year").draw().map_err(err)?;
            chart
                .draw_series(
                    pts.iter().map(|&(x, g, u)| {
                        PathElement::new(vec![(x, g - 2.0 * u), (x, g + 2.0 * u)], BLUE.stroke_width(2))
                    }),
                )
                .map_err(err)?;
            chart.draw_series(pts.iter().map(|&(x, g, _)| Circle::new((x, g), 4, BLUE.filled()))).map_err(err)?;
            chart.draw_series(LineSeries::new([(x0, 0.0), (x1, 0.0)], BLACK.stroke_width(1))).map_err(err)?;
        }
        Ok(())
    }
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// The HTML page (the plot's SVG embedded).
pub fn html(t: &Trend, svg: &str) -> String {
    let mut h = String::from(
        "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>Corrugation trend</title>\
         <style>body{font-family:sans-serif}td,th{padding:2px 8px;text-align:right}</style></head><body>\n\
         <h1>Corrugation trend</h1>\n",
    );
    let _ = writeln!(h, "<pre>{}</pre>", escape(&summary(t)));
    let _ = writeln!(h, "<h2>Growth per block</h2>\n{svg}");
    let _ = writeln!(
        h,
        "<h2>All blocks</h2>\n<table><tr><th>block</th><th>band</th><th>limit µm</th><th>growth µm/yr</th><th>u µm/yr</th><th>crossing</th></tr>"
    );
    for b in &t.blocks {
        let (g, u) =
            b.growth.map_or(("-".into(), "-".into()), |(g, u)| (format!("{:+.2}", g * 1e3), format!("{:.2}", u * 1e3)));
        let _ = writeln!(
            h,
            "<tr><td>{} – {}</td><td>{}</td><td>{}</td><td>{g}</td><td>{u}</td><td>{}</td></tr>",
            chainage(b.start_mm),
            chainage(b.end_mm),
            escape(&label(&b.band)),
            b.limit_mm.map_or("-".into(), |l| format!("{:.0}", l * 1e3)),
            escape(&b.crossing.to_string())
        );
    }
    h.push_str("</table>\n<p>Model, uncertainty and crossing: docs/trend.md.</p>\n</body></html>\n");
    h
}

/// The trend as one JSON object (mm, mm/year, dates as `YYYY-MM-DD`).
pub fn json(t: &Trend) -> String {
    use serde_json::json;
    let crossing = |c: &Crossing| match c {
        Crossing::AlreadyOver => json!({"kind": "already_over"}),
        Crossing::On { date, earliest, latest } => json!({
            "kind": "on",
            "date": date.to_string(),
            "earliest": earliest.map(|d| d.to_string()),
            "latest": latest.map(|d| d.to_string()),
        }),
        Crossing::NotWithin(y) => json!({"kind": "not_within", "years": y}),
        Crossing::NotJudged => json!({"kind": "not_judged"}),
        Crossing::AtTheFloor(x) => json!({"kind": "at_the_floor", "floor_mm": x}),
    };
    let v = json!({
        "edition": t.edition.name(),
        "block_mm": t.block_mm,
        "surveys": t.surveys.iter().enumerate().map(|(i, (n, d))| json!({
            "name": n,
            "date": d.to_string(),
            "gnss_placing": t.placings.get(i).map(|p| p.iter().map(super::json::placing_json).collect::<Vec<_>>()),
        })).collect::<Vec<_>>(),
        "registrations": t.registrations.iter().map(|r| json!({
            "survey": r.survey + 1,
            "shift_mm": r.shift_mm,
            "correlation": r.correlation,
            "disputed": r.disputed,
        })).collect::<Vec<_>>(),
        "blocks": t.blocks.iter().map(|b| json!({
            "start_mm": b.start_mm,
            "end_mm": b.end_mm,
            "band": label(&b.band),
            "lo_mm": b.band.lo_mm,
            "hi_mm": b.band.hi_mm,
            "limit_mm": b.limit_mm,
            "figures": b.figures.iter().map(|f| f.map(|(t, y, u)| json!({"years": t, "figure_mm": y, "u_mm": u}))).collect::<Vec<_>>(),
            "growth_mm_per_year": b.growth.map(|g| g.0),
            "u_growth_mm_per_year": b.growth.map(|g| g.1),
            "chi2_reduced": b.chi2_reduced,
            "crossing": crossing(&b.crossing),
        })).collect::<Vec<_>>(),
        "iso3095": t.iso3095.iter().map(iso3095_json).collect::<Vec<_>>(),
    });
    v.to_string()
}

/// One block's ISO 3095 third octaves over the surveys as JSON (dB re 1
/// µm, dB/year).
fn iso3095_json(b: &BlockIso3095) -> serde_json::Value {
    use serde_json::json;
    let reading = |r: &crate::analyze::trend::iso3095::Reading| {
        json!({
            "verdict": r.verdict.name(),
            "level_db": r.level_db,
            "floor_db": r.floor_db,
            "rail_db": r.rail.db,
            "rail_lo_db": r.rail.lo_db,
            "rail_hi_db": r.rail.hi_db,
            "figure_db": r.figure().map(|f| f.0),
            "u_db": r.figure().map(|f| f.1),
        })
    };
    json!({
        "start_mm": b.start_mm,
        "end_mm": b.end_mm,
        "third_octaves": b.third_octaves.iter().map(|o| json!({
            "wavelength_mm": o.wavelength_mm,
            "limit_db": o.limit_db,
            "readings": o.readings.iter().map(|r| r.as_ref().map(reading)).collect::<Vec<_>>(),
            "changed": o.changed().map(|(a, b)| json!({"from": a.name(), "to": b.name()})),
            "growth_db_per_year": o.growth.map(|g| g.0),
            "u_growth_db_per_year": o.growth.map(|g| g.1),
            "chi2_reduced": o.chi2_reduced,
            "shown": o.shown(),
        })).collect::<Vec<_>>(),
    })
}

/// Writes the trend report into `dir` as one output set.
pub fn write(dir: &Path, t: &Trend) -> Result<(), Error> {
    crate::output::set::write_set(dir, owns, |d| {
        let put = |name: &str, text: &str| -> Result<(), Error> {
            Ok(crate::output::write_atomically(&d.join(name), |w| w.write_all(text.as_bytes()))?)
        };
        put("summary.txt", &summary(t))?;
        put("trend.csv", &csv(t))?;
        put("trend_iso3095.csv", &iso3095_csv(t))?;
        let svg = plot::svg_and_png(&d.join("trend"), (1400, 1000), &GrowthFig(t)).map_err(Error::from)?;
        put("trend.html", &html(t, &svg))
    })
}

/// The surveys of `cms-host trend INPUTS…`: each recording analysed as
/// `cms-host analyze` analyses one (placed by `chainage[i]` or its survey
/// block), dated by `dates[i]` or its survey block's `date`. Shared by the
/// command and the Python package, so both follow the same surveys.
pub fn survey_runs(
    inputs: &[std::path::PathBuf],
    chainage: &[crate::analyze::survey::Placement],
    dates: &[SurveyDate],
    track_register: Option<&Path>,
    opts: &crate::analyze::Options,
    progress: &dyn crate::progress::Progress,
) -> Result<Vec<SurveyRun>, Error> {
    let n = inputs.len();
    for (flag, given) in [("--chainage", chainage.len()), ("--date", dates.len())] {
        if given > n {
            return Err(Error::Input(format!(
                "{given} {flag} for {n} recording(s): give at most one per recording, in order"
            )));
        }
    }
    let mut surveys = Vec::new();
    for (i, path) in inputs.iter().enumerate() {
        let name = path.display().to_string();
        // The date first: a survey without one is refused before its work.
        let date = match dates.get(i) {
            Some(d) => *d,
            None => survey_date(path)?,
        };
        let req = crate::analyze::runs::Request {
            inputs: vec![path.clone()],
            placements: chainage.get(i).copied().into_iter().collect(),
            search_mm: 25_000.0,
            track_register: track_register.map(Path::to_path_buf),
            ..crate::analyze::runs::Request::default()
        };
        let (_, analysis) = crate::analyze::runs::run(&req, opts, progress)?;
        surveys.push(SurveyRun { name, date, analysis });
    }
    Ok(surveys)
}

/// A recording's survey date, from its survey block.
fn survey_date(path: &Path) -> Result<SurveyDate, Error> {
    use crate::recording::survey_info::Survey;
    let name = path.display();
    let text = crate::recording::survey_of(path)?;
    let survey = match text {
        Some(t) => Survey::parse(&t).map_err(|e| Error::Input(format!("{name}: survey block: {e}")))?,
        None => Survey::default(),
    };
    survey.date().map_err(|e| Error::Input(format!("{name}: survey block: {e}")))?.ok_or_else(|| {
        Error::Input(format!("{name}: the survey has no date: give --date YYYY-MM-DD for it (in order)"))
    })
}

/// 1970-01-01 as [`SurveyDate::day_number`] counts (days since 0001-01-01):
/// Arrow's and Parquet's dates count days from the Unix epoch.
const UNIX_EPOCH_DAY: i64 = 719_163;

/// A date as days since 1970-01-01 (`None` past `i32`, years beyond 5 million).
fn epoch_days(d: SurveyDate) -> Option<i32> {
    i32::try_from(d.day_number() - UNIX_EPOCH_DAY).ok()
}

/// The trend as a table, one row per block and band (the rows of
/// `trend.csv`, typed): `start_chainage_mm`, `end_chainage_mm`,
/// `band_lo_mm`, `band_hi_mm`, `limit_mm` (null: the band is not judged),
/// `surveys` (those with a figure of the block), `first_date`,
/// `last_date` (the first and last of those), `last_figure_mm`,
/// `last_u_mm`, `growth_mm_per_year`, `u_growth_mm_per_year`,
/// `chi2_reduced`, `crossing` (`already_over`, `on`, `not_within`,
/// `not_judged`: the JSON's `kind`), `crossing_date`,
/// `crossing_earliest_date`, `crossing_latest_date` (null: open or not
/// `on`), `not_within_years`. The `*_date` columns are INT32 days since
/// 1970-01-01 (Arrow's `date32`).
pub fn trend_table(t: &Trend) -> Table {
    let b = &t.blocks;
    let f = |v: Vec<Option<f64>>| Values::F64(v);
    let d = |v: Vec<Option<SurveyDate>>| Values::I32(v.into_iter().map(|d| d.and_then(epoch_days)).collect());
    let col = |name: &str, nullable: bool, values: Values| Column { name: name.into(), nullable, values };
    let dated = |b: &BlockTrend| -> Vec<SurveyDate> {
        b.figures.iter().zip(&t.surveys).filter(|(f, _)| f.is_some()).map(|(_, s)| s.1).collect()
    };
    let last = |b: &BlockTrend| b.figures.iter().rev().flatten().next().copied();
    let on = |b: &BlockTrend, k: usize| match &b.crossing {
        Crossing::On { date, earliest, latest } => [Some(*date), *earliest, *latest][k],
        _ => None,
    };
    let kind = |c: &Crossing| match c {
        Crossing::AlreadyOver => "already_over",
        Crossing::On { .. } => "on",
        Crossing::NotWithin(_) => "not_within",
        Crossing::NotJudged => "not_judged",
        Crossing::AtTheFloor(_) => "at_the_floor",
    };
    Table {
        columns: vec![
            col("start_chainage_mm", false, f(b.iter().map(|b| Some(b.start_mm)).collect())),
            col("end_chainage_mm", false, f(b.iter().map(|b| Some(b.end_mm)).collect())),
            col("band_lo_mm", false, f(b.iter().map(|b| Some(b.band.lo_mm)).collect())),
            col("band_hi_mm", false, f(b.iter().map(|b| Some(b.band.hi_mm)).collect())),
            col("limit_mm", true, f(b.iter().map(|b| b.limit_mm).collect())),
            col(
                "surveys",
                false,
                Values::I32(b.iter().map(|b| Some(i32::try_from(dated(b).len()).unwrap_or(i32::MAX))).collect()),
            ),
            col("first_date", true, d(b.iter().map(|b| dated(b).first().copied()).collect())),
            col("last_date", true, d(b.iter().map(|b| dated(b).last().copied()).collect())),
            col("last_figure_mm", true, f(b.iter().map(|b| last(b).map(|x| x.1)).collect())),
            col("last_u_mm", true, f(b.iter().map(|b| last(b).map(|x| x.2)).collect())),
            col("growth_mm_per_year", true, f(b.iter().map(|b| b.growth.map(|g| g.0)).collect())),
            col("u_growth_mm_per_year", true, f(b.iter().map(|b| b.growth.map(|g| g.1)).collect())),
            col("chi2_reduced", true, f(b.iter().map(|b| b.chi2_reduced).collect())),
            col("crossing", false, Values::Str(b.iter().map(|b| Some(kind(&b.crossing).to_string())).collect())),
            col("crossing_date", true, d(b.iter().map(|b| on(b, 0)).collect())),
            col("crossing_earliest_date", true, d(b.iter().map(|b| on(b, 1)).collect())),
            col("crossing_latest_date", true, d(b.iter().map(|b| on(b, 2)).collect())),
            col(
                "not_within_years",
                true,
                f(b.iter()
                    .map(|b| match b.crossing {
                        Crossing::NotWithin(y) => Some(y),
                        _ => None,
                    })
                    .collect()),
            ),
        ],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_count_days_from_the_unix_epoch() {
        let day = |s: &str| epoch_days(s.parse().expect("a date"));
        assert_eq!(day("1970-01-01"), Some(0));
        assert_eq!(day("2026-05-02"), Some(20_575));
        assert_eq!(day("1969-12-31"), Some(-1));
    }
}
