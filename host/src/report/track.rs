//! The runs' GNSS track (`track.svg/.png` and its table): the fixes the
//! recordings hold (`listen --gnss`), east and north in metres of the first
//! fix in its local plane (WGS 84, [`crate::gnss::register::east_north`]),
//! drawn to equal scales on both axes, coloured by the fix's quality, with
//! each run's start and end and chainage ticks. No map: nothing is
//! fetched, the report stays offline.
//!
//! Chainage ticks come from the odometer each fix carries (the frame
//! received just before it, [`crate::gnss::Placed::odometer_um`]) and the
//! run's placement on the line ([`crate::analyze::survey::RunJoin`]): a tick
//! is put between the two fixes its chainage lies between, so it is as far
//! off as the vehicle travels in one frame interval plus the receiver's
//! output latency (docs/gnss.md).

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::analyze::{Analysis, Source, chainage};
use crate::gnss::register::{Geodetic, east_north};
use crate::gnss::{Placed, Quality};
use crate::plot::{Figure, err};

/// How the plot is made, for the reader of the report.
pub const HOW: &str = "East and north of the first fix in its local plane (WGS 84), metres, equal scales; \
    each fix coloured by its quality (fixes without a position left out), each run's start and end marked; \
    chainage ticks where the odometer the fix carries, placed on the line as the run is, puts them \
    (off by the travel of one frame interval and the receiver's latency). No map tiles: nothing is fetched.";

/// One fix with a position, in the plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    pub east_m: f64,
    pub north_m: f64,
    pub quality: Quality,
    /// Where the odometer it carries puts it on the line, mm.
    pub chainage_mm: Option<f64>,
}

/// One run's fixes.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunTrack {
    /// From 1.
    pub run: usize,
    /// Fixes recorded.
    pub fixes: usize,
    /// Of those, by the `GGA` quality digit (0 to 8).
    pub by_quality: [usize; 9],
    /// Of those, placed among the head's frames.
    pub placed: usize,
    /// The fixes with a position, in file order.
    pub points: Vec<Point>,
    /// Host time from the first fix to the last, s.
    pub duration_s: f64,
    /// UTC of the first and last fix.
    pub utc: (Option<String>, Option<String>),
    /// Median of the horizontal uncertainty assumed per fix ([`crate::gnss::Fix::sigma_m`]), m.
    pub median_sigma_m: Option<f64>,
}

/// The track of all runs.
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    /// The first fix with a position (none: no fix has one).
    pub origin: Option<Geodetic>,
    /// Runs that hold fixes.
    pub runs: Vec<RunTrack>,
}

/// Whether a fix has a position to plot.
fn positioned(p: &Placed) -> bool {
    let f = &p.fix;
    f.quality != Quality::Invalid && f.lat_deg.abs() <= 90.0 && f.lon_deg.abs() <= 180.0
}

fn utc(p: &Placed) -> Option<String> {
    let ms = p.fix.utc_ms_of_day?;
    let (h, m, s) = (ms / 3_600_000, ms / 60_000 % 60, f64::from(ms % 60_000) / 1000.0);
    let time = format!("{h:02}:{m:02}:{s:04.1}");
    Some(match p.fix.date {
        Some((y, mo, d)) => format!("{y:04}-{mo:02}-{d:02} {time}"),
        None => time,
    })
}

/// One run's fixes in the plane at `origin`, their chainage by `to_chainage`
/// (track position mm to chainage mm; `None`: the run was not placed).
pub fn run_track(run: usize, fixes: &[Placed], origin: Geodetic, to_chainage: Option<&dyn Fn(f64) -> f64>) -> RunTrack {
    let mut t = RunTrack { run, fixes: fixes.len(), ..RunTrack::default() };
    for p in fixes {
        t.by_quality[usize::from(p.fix.quality.digit()).min(8)] += 1;
        t.placed += usize::from(p.head_us.is_some());
    }
    t.points = fixes
        .iter()
        .filter(|p| positioned(p))
        .map(|p| {
            let (east_m, north_m) = east_north(origin, Geodetic { lat_deg: p.fix.lat_deg, lon_deg: p.fix.lon_deg });
            let chainage_mm = match (to_chainage, p.odometer_um) {
                (Some(f), Some(o)) => Some(f(o as f64 / 1000.0)),
                _ => None,
            };
            Point { east_m, north_m, quality: p.fix.quality, chainage_mm }
        })
        .collect();
    if let (Some(a), Some(b)) = (fixes.first(), fixes.last()) {
        t.duration_s = b.host_us.saturating_sub(a.host_us) as f64 / 1e6;
        t.utc = (utc(a), utc(b));
    }
    let sigmas: Vec<f64> = fixes.iter().filter(|p| positioned(p)).map(|p| p.fix.sigma_m()).collect();
    t.median_sigma_m = crate::analyze::stitch::median(sigmas);
    t
}

impl RunTrack {
    /// Length of the path through its fixes, m.
    pub fn path_m(&self) -> f64 {
        self.points.windows(2).map(|w| (w[1].east_m - w[0].east_m).hypot(w[1].north_m - w[0].north_m)).sum()
    }

    /// The chainage its fixes span, mm.
    pub fn chainage_span_mm(&self) -> Option<(f64, f64)> {
        self.points.iter().filter_map(|p| p.chainage_mm).fold(None, |r, c| match r {
            None => Some((c, c)),
            Some((lo, hi)) => Some((f64::min(lo, c), f64::max(hi, c))),
        })
    }

    /// "38 RTK fixed, 2 RTK float".
    pub fn qualities(&self) -> String {
        (0..9u8)
            .filter(|&d| self.by_quality[usize::from(d)] > 0)
            .map(|d| {
                format!("{} {}", self.by_quality[usize::from(d)], Quality::from_digit(d).map_or("?", |q| q.name()))
            })
            .collect::<Vec<_>>()
            .join(", ")
    }
}

impl Track {
    /// The runs' fixes (none: no recording holds a fix; a profile file has none).
    pub fn of(source: &Source, a: &Analysis) -> Option<Track> {
        let Source::Recordings(runs) = source else { return None };
        if runs.iter().all(|(_, r)| r.fixes.is_empty()) {
            return None;
        }
        let origin = runs
            .iter()
            .flat_map(|(_, r)| &r.fixes)
            .find(|p| positioned(p))
            .map(|p| Geodetic { lat_deg: p.fix.lat_deg, lon_deg: p.fix.lon_deg });
        let o = origin.unwrap_or(Geodetic { lat_deg: 0.0, lon_deg: 0.0 });
        let runs = runs
            .iter()
            .enumerate()
            .filter(|(_, (_, r))| !r.fixes.is_empty())
            .map(|(i, (_, r))| {
                let join = a.joins.iter().find(|j| j.run == i + 1);
                let f = join.map(|j| move |x: f64| j.chainage_mm(x));
                run_track(i + 1, &r.fixes, o, f.as_ref().map(|f| f as &dyn Fn(f64) -> f64))
            })
            .collect();
        Some(Track { origin, runs })
    }

    /// Whether any fix has a position to plot.
    pub fn plottable(&self) -> bool {
        self.runs.iter().any(|r| !r.points.is_empty())
    }

    /// Where the plane's origin is.
    pub fn describe_origin(&self) -> String {
        match self.origin {
            Some(g) => format!(
                "Origin of the plot: the first fix with a position, {:.7}° N {:.7}° E (WGS 84).",
                g.lat_deg, g.lon_deg
            ),
            None => "No fix has a position (every one is of quality invalid): nothing to plot.".into(),
        }
    }

    /// The table: its header and one row per run.
    pub fn table(&self) -> (Vec<String>, Vec<Vec<String>>) {
        let head = [
            "run",
            "fixes",
            "quality",
            "placed among the frames",
            "first fix, UTC",
            "last fix, UTC",
            "duration, s",
            "path through the fixes, m",
            "extent east × north, m",
            "chainage (odometer)",
            "median σ, m",
        ];
        let rows = self
            .runs
            .iter()
            .map(|r| {
                let ext = |f: fn(&Point) -> f64| {
                    let (lo, hi) = r
                        .points
                        .iter()
                        .map(f)
                        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
                    if lo <= hi { hi - lo } else { 0.0 }
                };
                vec![
                    r.run.to_string(),
                    r.fixes.to_string(),
                    r.qualities(),
                    r.placed.to_string(),
                    r.utc.0.clone().unwrap_or_else(|| "-".into()),
                    r.utc.1.clone().unwrap_or_else(|| "-".into()),
                    format!("{:.1}", r.duration_s),
                    format!("{:.2}", r.path_m()),
                    format!("{:.2} × {:.2}", ext(|p| p.east_m), ext(|p| p.north_m)),
                    r.chainage_span_mm().map_or("-".into(), |(a, b)| format!("{} to {}", chainage(a), chainage(b))),
                    r.median_sigma_m.map_or("-".into(), |s| format!("{s:.2}")),
                ]
            })
            .collect();
        (head.iter().map(|h| h.to_string()).collect(), rows)
    }
}

/// Ranges around `x` and `y` (padded, never empty) with the same metres per
/// pixel on a plotting area of `px` pixels.
pub fn equal_ranges(x: (f64, f64), y: (f64, f64), px: (u32, u32)) -> ((f64, f64), (f64, f64)) {
    let pad = |(lo, hi): (f64, f64)| {
        // Room for the labels of the points at the edges.
        let span = (hi - lo).max(1.0);
        ((lo + hi) / 2.0, span * 1.25)
    };
    let ((xc, xs), (yc, ys)) = (pad(x), pad(y));
    let (w, h) = (f64::from(px.0.max(1)), f64::from(px.1.max(1)));
    let per_px = (xs / w).max(ys / h);
    let (xs, ys) = (per_px * w, per_px * h);
    ((xc - xs / 2.0, xc + xs / 2.0), (yc - ys / 2.0, yc + ys / 2.0))
}

/// A round step for chainage ticks: at most `max` of them over `span_mm`.
fn tick_step_mm(span_mm: f64, max: usize) -> f64 {
    let mut step = 1000.0;
    let mut k = 0;
    while span_mm / step > max as f64 {
        step = [2.0, 5.0, 10.0][k % 3] * 1000.0 * 10f64.powi((k / 3) as i32);
        k += 1;
    }
    step
}

/// Chainage ticks along a run: `(east, north, chainage_mm)` where its path
/// first crosses each multiple of a round step.
pub fn chainage_ticks(points: &[Point], max: usize) -> Vec<(f64, f64, f64)> {
    let with: Vec<(f64, f64, f64)> =
        points.iter().filter_map(|p| p.chainage_mm.map(|c| (p.east_m, p.north_m, c))).collect();
    let (lo, hi) = with.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.2), b.max(p.2)));
    if with.is_empty() || hi <= lo {
        return Vec::new();
    }
    let step = tick_step_mm(hi - lo, max);
    let mut ticks = Vec::new();
    let mut c = (lo / step).ceil() * step;
    while c <= hi {
        let crossing = with.windows(2).find(|w| (w[0].2 - c) * (w[1].2 - c) <= 0.0 && w[0].2 != w[1].2);
        if let Some(w) = crossing {
            let t = (c - w[0].2) / (w[1].2 - w[0].2);
            ticks.push((w[0].0 + t * (w[1].0 - w[0].0), w[0].1 + t * (w[1].1 - w[0].1), c));
        }
        c += step;
    }
    ticks
}

/// A quality's colour: greener the better the solution.
fn quality_colour(q: Quality) -> RGBColor {
    match q {
        Quality::RtkFixed => RGBColor(44, 160, 44),
        Quality::RtkFloat => RGBColor(255, 127, 14),
        Quality::Differential => RGBColor(31, 119, 180),
        Quality::Autonomous | Quality::Pps => RGBColor(214, 39, 40),
        _ => RGBColor(127, 127, 127),
    }
}

/// Most fixes drawn as markers: an hour at 10 Hz would make an SVG of
/// megabytes that shows no more.
const MAX_MARKERS: usize = 4000;

/// Every `every`-th point, the last one, and every point whose quality
/// differs from the one before (a drop to float or autonomous always shows).
fn thinned(points: &[Point], every: usize) -> Vec<&Point> {
    points
        .iter()
        .enumerate()
        .filter(|&(i, p)| i % every == 0 || i + 1 == points.len() || (i > 0 && points[i - 1].quality != p.quality))
        .map(|(_, p)| p)
        .collect()
}

/// The track's figure.
pub struct TrackFig<'a> {
    pub track: &'a Track,
}

const MARGIN: u32 = 12;
const X_LABELS: u32 = 40;
const Y_LABELS: u32 = 70;

impl Figure for TrackFig<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        root.fill(&WHITE).map_err(err)?;
        let root = root
            .titled("GNSS track: east and north of the first fix, m (equal scales), by fix quality", ("sans-serif", 18))
            .map_err(err)?;
        let pts: Vec<&Point> = self.track.runs.iter().flat_map(|r| &r.points).collect();
        let span = |f: fn(&Point) -> f64| {
            pts.iter().map(|p| f(p)).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)))
        };
        let ((e0, e1), (n0, n1)) = (span(|p| p.east_m), span(|p| p.north_m));
        if !(e0 <= e1 && n0 <= n1) {
            return Ok(());
        }
        let (w, h) = root.dim_in_pixel();
        let area = (w.saturating_sub(2 * MARGIN + Y_LABELS), h.saturating_sub(2 * MARGIN + X_LABELS));
        let ((x0, x1), (y0, y1)) = equal_ranges((e0, e1), (n0, n1), area);
        let mut chart = ChartBuilder::on(&root)
            .margin(MARGIN)
            .x_label_area_size(X_LABELS)
            .y_label_area_size(Y_LABELS)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(err)?;
        chart.configure_mesh().x_desc("east, m").y_desc("north, m").draw().map_err(err)?;
        let grey = RGBColor(160, 160, 160);
        let every = pts.len().div_ceil(MAX_MARKERS).max(1);
        for r in &self.track.runs {
            let line = thinned(&r.points, every).into_iter().map(|p| (p.east_m, p.north_m));
            chart.draw_series(LineSeries::new(line, grey.stroke_width(1))).map_err(err)?;
        }
        for d in 0..9u8 {
            let Some(q) = Quality::from_digit(d) else { continue };
            let count = pts.iter().filter(|p| p.quality == q).count();
            if count == 0 {
                continue;
            }
            let of: Vec<(f64, f64)> = self
                .track
                .runs
                .iter()
                .flat_map(|r| thinned(&r.points, every))
                .filter(|p| p.quality == q)
                .map(|p| (p.east_m, p.north_m))
                .collect();
            let c = quality_colour(q);
            chart
                .draw_series(of.iter().map(|&p| Circle::new(p, 3, c.filled())))
                .map_err(err)?
                .label(format!("{} ({count})", q.name()))
                .legend(move |(x, y)| Circle::new((x + 10, y), 4, c.filled()));
        }
        let several = self.track.runs.len() > 1;
        let font = ("sans-serif", 14).into_font().color(&BLACK);
        for r in &self.track.runs {
            let (Some(a), Some(b)) = (r.points.first(), r.points.last()) else { continue };
            let name = |what: &str| if several { format!("{what} run {}", r.run) } else { what.to_string() };
            let start = EmptyElement::at((a.east_m, a.north_m))
                + TriangleMarker::new((0, 0), 9, BLACK.filled())
                + Text::new(name("start"), (10, -16), font.clone());
            let end = EmptyElement::at((b.east_m, b.north_m))
                + Rectangle::new([(-5, -5), (5, 5)], BLACK.filled())
                + Text::new(name("end"), (10, -20), font.clone());
            chart.draw_series(std::iter::once(start)).map_err(err)?;
            chart.draw_series(std::iter::once(end)).map_err(err)?;
            for (e, n, c) in chainage_ticks(&r.points, 8) {
                let tick = EmptyElement::at((e, n))
                    + Cross::new((0, 0), 5, BLACK.stroke_width(2))
                    + Text::new(chainage(c), (8, 6), ("sans-serif", 12).into_font().color(&BLACK));
                chart.draw_series(std::iter::once(tick)).map_err(err)?;
            }
        }
        chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(err)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gnss::Fix;
    use crate::gnss::register::offset;

    const ORIGIN: Geodetic = Geodetic { lat_deg: 52.09, lon_deg: 5.12 };

    /// Fixes every 100 mm of odometer along a line 30° north of east, the
    /// odometer starting at 1 m; the third without a position.
    fn fixes(n: usize) -> Vec<Placed> {
        (0..n)
            .map(|i| {
                let along = 0.1 * i as f64;
                let (e, nn) = (along * 30f64.to_radians().cos(), along * 30f64.to_radians().sin());
                let g = offset(ORIGIN, e, nn);
                Placed {
                    host_us: 1_000_000 + 100_000 * i as u64,
                    head_us: (i > 0).then_some(100_000 * i as u64),
                    odometer_um: Some(1_000_000 + 100_000 * i as i64),
                    fix: Fix {
                        utc_ms_of_day: Some(36_000_000 + 100 * i as u32),
                        date: Some((2026, 12, 4)),
                        lat_deg: g.lat_deg,
                        lon_deg: g.lon_deg,
                        altitude_m: None,
                        quality: if i == 2 {
                            Quality::Invalid
                        } else if i % 2 == 0 {
                            Quality::RtkFixed
                        } else {
                            Quality::RtkFloat
                        },
                        satellites: Some(12),
                        hdop: Some(0.9),
                        speed_mm_s: Some(1000.0),
                        course_deg: Some(60.0),
                        receiver_sigma_m: None,
                    },
                }
            })
            .collect()
    }

    #[test]
    fn a_run_is_put_in_metres_with_its_chainage() {
        let fs = fixes(51);
        // Down the line from 12+000: chainage = 12 000 m − odometer.
        let down = |x: f64| 12_000_000.0 - x;
        let t = run_track(1, &fs, ORIGIN, Some(&down));
        assert_eq!((t.fixes, t.placed, t.points.len()), (51, 50, 50));
        assert_eq!(t.qualities(), "1 invalid, 25 RTK fixed, 25 RTK float");
        // 5 m along the line, the invalid fix left out (its neighbours are 0.2 m apart).
        assert!((t.path_m() - 5.0).abs() < 1e-3, "{}", t.path_m());
        let last = t.points.last().unwrap();
        assert!((last.east_m - 5.0 * 30f64.to_radians().cos()).abs() < 1e-3, "{last:?}");
        assert!((last.north_m - 2.5).abs() < 1e-3, "{last:?}");
        assert_eq!(t.chainage_span_mm(), Some((11_994_000.0, 11_999_000.0)));
        assert!((t.duration_s - 5.0).abs() < 1e-9);
        assert_eq!(t.utc.0.as_deref(), Some("2026-12-04 10:00:00.0"));
        assert_eq!(t.utc.1.as_deref(), Some("2026-12-04 10:00:05.0"));
        // RTK fixed 0.02 m and float 0.3 m, HDOP under 1: the median between them.
        let s = t.median_sigma_m.unwrap();
        assert!((0.02..=0.3).contains(&s), "{s}");
        // Ticks every metre of chainage, where the path crosses them.
        let ticks = chainage_ticks(&t.points, 8);
        assert_eq!(ticks.len(), 6, "{ticks:?}");
        for (e, n, c) in ticks {
            let along = (11_999_000.0 - c) / 1000.0 + 0.0;
            assert!((e.hypot(n) - along).abs() < 1e-3 && (c % 1000.0).abs() < 1e-9, "{e} {n} {c}");
        }
        // Without a placement: no chainage.
        let t = run_track(1, &fs, ORIGIN, None);
        assert!(t.chainage_span_mm().is_none() && chainage_ticks(&t.points, 8).is_empty());
    }

    #[test]
    fn thinning_keeps_the_ends_and_every_change_of_quality() {
        let p = |q| Point { east_m: 0.0, north_m: 0.0, quality: q, chainage_mm: None };
        let mut pts = vec![p(Quality::RtkFixed); 100];
        pts[37] = p(Quality::Autonomous);
        let kept: Vec<usize> =
            thinned(&pts, 10).into_iter().map(|k| pts.iter().position(|q| std::ptr::eq(q, k)).unwrap()).collect();
        assert_eq!(kept, [0, 10, 20, 30, 37, 38, 40, 50, 60, 70, 80, 90, 99]);
        assert_eq!(thinned(&pts, 1).len(), 100);
    }

    #[test]
    fn both_axes_have_the_same_scale() {
        for (x, y, px) in [((0.0, 100.0), (0.0, 10.0), (800, 400)), ((5.0, 5.0), (-3.0, 40.0), (900, 700))] {
            let ((x0, x1), (y0, y1)) = equal_ranges(x, y, px);
            let (sx, sy) = ((x1 - x0) / f64::from(px.0), (y1 - y0) / f64::from(px.1));
            assert!((sx - sy).abs() < 1e-12 * sx, "{sx} {sy}");
            assert!(x0 < x.0 && x1 > x.1 && y0 < y.0 && y1 > y.1);
        }
        assert_eq!(tick_step_mm(7_000.0, 8), 1000.0);
        assert_eq!(tick_step_mm(9_000.0, 8), 2000.0);
        assert_eq!(tick_step_mm(300_000.0, 8), 50_000.0);
    }

    #[test]
    fn the_plot_marks_start_end_qualities_and_chainage() {
        let fs = fixes(51);
        let up = |x: f64| 41_100_000.0 + x;
        let track = Track { origin: Some(ORIGIN), runs: vec![run_track(1, &fs, ORIGIN, Some(&up))] };
        let dir = tempfile::tempdir().unwrap();
        let svg =
            crate::plot::svg_and_png(&dir.path().join("track"), (1000, 800), &TrackFig { track: &track }).unwrap();
        let _ =
            crate::plot::svg_and_png(std::path::Path::new("/tmp/h2track"), (1000, 800), &TrackFig { track: &track });
        for text in ["start", "end", "RTK fixed (25)", "RTK float (25)", "41+102.000", "east, m", "north, m"] {
            assert!(svg.contains(&format!("\n{text}\n")), "{text}");
        }
        assert!(!svg.contains("invalid ("), "fixes without a position are not plotted");
        assert!(dir.path().join("track.png").metadata().unwrap().len() > 1000);
    }
}
