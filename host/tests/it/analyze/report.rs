//! The HTML report as a reader gets it: every section tables and figures
//! (no preformatted text), every table well-formed, nothing fetched; the
//! GNSS track of a recording with fixes, and the note of one without.

use super::frames;
use super::recordings::write_recording_with;
use crate::common::run;
use cms_host::gnss::register::{Geodetic, offset};
use cms_host::gnss::{Fix, Placed, Quality};
use cms_host::recording::HostRecord;
use std::path::Path;

const ORIGIN: Geodetic = Geodetic { lat_deg: 52.091_15, lon_deg: 5.122_66 };

/// Heading of the simulated run, degrees from north.
const HEADING_DEG: f64 = 60.0;

/// 7.2 m of rail (frames every 17 mm from odometer 100 mm) with a fix
/// after every 10th frame, where that frame's odometer puts it on a straight
/// line heading 60° from north: the first without a position, frames
/// 200–249 RTK float, the rest RTK fixed.
fn recording_with_fixes(dir: &Path) -> (std::path::PathBuf, Vec<Placed>) {
    let rec = dir.join("gnss.cmsrec");
    let mut fixes = Vec::new();
    write_recording_with(&rec, &frames(17.0, 420, &[], 0.5, 7), true, |f| {
        if f.seq % 10 != 0 {
            return Vec::new();
        }
        let d = f.odometer_mm / 1000.0;
        let (e, n) = (d * HEADING_DEG.to_radians().sin(), d * HEADING_DEG.to_radians().cos());
        let g = offset(ORIGIN, e, n);
        let quality = match f.seq {
            0 => Quality::Invalid,
            200..250 => Quality::RtkFloat,
            _ => Quality::RtkFixed,
        };
        let p = Placed {
            host_us: 33_333 * u64::from(f.seq),
            head_us: Some(33_333 * u64::from(f.seq)),
            odometer_um: Some((f.odometer_mm * 1000.0).round() as i64),
            fix: Fix {
                utc_ms_of_day: Some(36_000_000 + 33 * f.seq),
                date: Some((2026, 12, 4)),
                lat_deg: g.lat_deg,
                lon_deg: g.lon_deg,
                altitude_m: Some(3.0),
                quality,
                satellites: Some(14),
                hdop: Some(0.7),
                speed_mm_s: Some(510.0),
                course_deg: Some(HEADING_DEG),
                receiver_sigma_m: None,
            },
        };
        fixes.push(p.clone());
        HostRecord::Fix(p).frame()
    });
    (rec, fixes)
}

/// The report of `rec` (with `args`), its HTML and the `--json` output.
fn report(dir: &Path, rec: &Path, args: &[&str]) -> (std::path::PathBuf, String, serde_json::Value) {
    let out = dir.join("report");
    let mut a = vec!["analyze", rec.to_str().unwrap(), "--json", "--report", out.to_str().unwrap()];
    a.extend_from_slice(args);
    let o = run(&a);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    (out, html, serde_json::from_slice(&o.stdout).unwrap())
}

/// The HTML elements outside the SVGs: every one opened is closed, in order.
fn assert_well_formed(html: &str) {
    let mut stack: Vec<String> = Vec::new();
    let mut rest = html;
    while let Some(at) = rest.find('<') {
        let end = rest[at..].find('>').map(|e| at + e).unwrap_or_else(|| panic!("unclosed tag: {}", &rest[at..]));
        let tag = &rest[at + 1..end];
        rest = &rest[end + 1..];
        if tag.starts_with('!') || tag.ends_with('/') {
            continue;
        }
        let name: String = tag.trim_start_matches('/').chars().take_while(|c| c.is_ascii_alphanumeric()).collect();
        if name == "meta" {
            continue;
        }
        if let Some(closing) = tag.strip_prefix('/') {
            let open = stack.pop().unwrap_or_else(|| panic!("</{closing}> closes nothing"));
            assert_eq!(open, name, "<{open}> closed by </{name}>");
        } else {
            stack.push(name);
        }
    }
    assert!(stack.is_empty(), "never closed: {stack:?}");
}

/// Every table's rows as their cells' text, by class; each row as wide as
/// the first (the header).
fn tables_of(html: &str) -> Vec<(String, Vec<Vec<String>>)> {
    let mut out = Vec::new();
    for part in html.split("<table").skip(1) {
        let body = &part[..part.find("</table>").expect("a closed table")];
        assert!(!body.contains("<table"), "a table inside a table");
        let class = body.split('"').nth(1).unwrap_or("").to_string();
        let rows: Vec<Vec<String>> = body
            .split("<tr>")
            .skip(1)
            .map(|row| {
                let row = &row[..row.find("</tr>").expect("a closed row")];
                row.split("<t")
                    .skip(1)
                    .filter(|c| c.starts_with("d") || c.starts_with("h>") || c.starts_with("h "))
                    .map(|c| {
                        let text = &c[c.find('>').unwrap() + 1..];
                        text[..text.find("</t").expect("a closed cell")].to_string()
                    })
                    .collect()
            })
            .collect();
        assert!(!rows.is_empty(), "table {class} has no rows");
        let width = rows[0].len();
        for r in &rows {
            assert_eq!(r.len(), width, "table {class}: {r:?} against {:?}", rows[0]);
        }
        out.push((class, rows));
    }
    out
}

/// What every report must be: no preformatted text, well-formed, nothing
/// from elsewhere, printable; returns its tables.
fn assert_real_report(html: &str) -> Vec<(String, Vec<Vec<String>>)> {
    assert!(!html.contains("<pre"), "preformatted text in the report");
    assert_well_formed(html);
    // Offline: the SVGs' namespace is a name, not a fetch; nothing else points out.
    let bare = html.replace("xmlns=\"http://www.w3.org/2000/svg\"", "");
    for outside in ["http:", "https:", "<script", "<link", "<img", "src=", "href=", "@import", "url("] {
        assert!(!bare.contains(outside), "{outside} in the report");
    }
    let style = &html[html.find("<style>").unwrap()..html.find("</style>").unwrap()];
    let print = &style[style.find("@media print").expect("a print stylesheet")..];
    for rule in [
        "@page{size:A4",
        "margin:12mm",
        "h2{break-before:page",
        "tr{break-inside:avoid",
        "thead{display:table-header-group}",
        "figure,img{max-width:100%!important;break-inside:avoid",
        "svg{max-width:100%!important;max-height:165mm",
        "print-color-adjust:exact",
    ] {
        assert!(print.contains(rule), "{rule}: {print}");
    }
    assert_eq!(html.matches("<svg").count(), html.matches("<figure class=\"plot\"><svg").count());
    // Every section's heading is in a section.
    assert_eq!(html.matches("<h2>").count(), html.matches("<section id=").count());
    tables_of(html)
}

fn section<'a>(html: &'a str, id: &str) -> &'a str {
    let start = html.find(&format!("<section id=\"{id}\">")).unwrap_or_else(|| panic!("no section {id}"));
    &html[start..start + html[start..].find("</section>").unwrap()]
}

fn table<'a>(tables: &'a [(String, Vec<Vec<String>>)], in_html: &str, class: &str) -> &'a [Vec<String>] {
    let n = in_html.matches(&format!("<table class=\"{class}\">")).count();
    assert!(n >= 1, "no table {class}");
    &tables.iter().find(|(c, _)| c == class).unwrap().1
}

/// A recording with GNSS fixes: the report plots its track (equal scales,
/// by quality) and tabulates its fixes, their quality and span; each line
/// has its stitching, its four EN 13231-3 bands and its spectrum as tables
/// that say what the JSON says.
#[test]
fn the_report_is_tables_and_figures_and_plots_the_gnss_track() {
    let dir = tempfile::tempdir().unwrap();
    let (rec, fixes) = recording_with_fixes(dir.path());
    let (out, html, v) = report(dir.path(), &rec, &["--chainage", "41+100"]);
    let tables = assert_real_report(&html);

    let track = section(&html, "track");
    assert!(track.contains("<figure class=\"plot\"><svg"), "{track}");
    for f in ["track.svg", "track.png"] {
        assert!(out.join(f).metadata().unwrap().len() > 1000, "{f}");
    }
    // The first fix with a position: frame 10, odometer 270 mm.
    let origin = offset(ORIGIN, 0.27 * HEADING_DEG.to_radians().sin(), 0.27 * HEADING_DEG.to_radians().cos());
    assert!(track.contains(&format!("{:.7}° N {:.7}° E", origin.lat_deg, origin.lon_deg)), "{track}");
    let rows = table(&tables, track, "track");
    assert_eq!(rows.len(), 2, "one run: {rows:?}");
    let (head, row) = (&rows[0], &rows[1]);
    let cell =
        |name: &str| row[head.iter().position(|h| h.starts_with(name)).unwrap_or_else(|| panic!("{name}"))].as_str();
    assert_eq!(cell("fixes"), fixes.len().to_string());
    assert_eq!(cell("quality"), "1 invalid, 36 RTK fixed, 5 RTK float");
    assert_eq!(cell("placed"), fixes.len().to_string());
    // From the fix at frame 10 (odometer 270 mm) to the one at 410 (7 070 mm).
    let path: f64 = cell("path").parse().unwrap();
    assert!((path - 6.8).abs() < 0.01, "{path}");
    assert_eq!(cell("chainage"), "41+100.270 to 41+107.070");
    assert_eq!(cell("first fix"), "2026-12-04 10:00:00.0");
    let svg = std::fs::read_to_string(out.join("track.svg")).unwrap();
    for text in ["start", "end", "RTK fixed (36)", "RTK float (5)", "41+102.000", "east, m", "north, m"] {
        assert!(svg.contains(&format!("\n{text}\n")), "{text}");
    }

    // Each line: its stitching, bands and spectrum, the JSON's figures.
    for l in v["lasers"].as_array().unwrap() {
        let k = l["laser"].as_u64().unwrap();
        let sec = section(&html, &format!("laser{k}"));
        let t = tables_of(sec);
        let facts = table(&t, sec, "stitched");
        let fact = |name: &str| facts.iter().find(|r| r[0] == name).unwrap_or_else(|| panic!("{name}"))[1].clone();
        assert_eq!(fact("frames"), l["frames"].to_string());
        assert_eq!(fact("gaps"), l["gaps"].as_array().unwrap().len().to_string());
        let bands = table(&t, sec, "bands");
        assert_eq!(bands.len(), 5, "header and four bands");
        for (row, b) in bands[1..].iter().zip(l["en13231"]["bands"].as_array().unwrap()) {
            match b["average_mean_pp_mm"].as_f64() {
                Some(pp) => assert_eq!(row[3], format!("{pp:.4}"), "{b}"),
                None => assert!(row[9].contains("too short"), "{row:?}"),
            }
        }
        let spectrum = table(&t, sec, "spectrum");
        let bands = l["en15610"]["bands"].as_array().unwrap();
        assert_eq!(spectrum.len(), bands.len() + 1);
        for (row, b) in spectrum[1..].iter().zip(bands) {
            assert_eq!(row[1], format!("{:.1}", b["level_db"].as_f64().unwrap()), "{b}");
        }
        assert!(sec.contains("<table class=\"peak\">"), "the spectrum's peak");
    }
    // The inputs in detail: the run, its counts and what reading found.
    let inputs = section(&html, "inputs");
    let runs = table(&tables, inputs, "runs");
    assert_eq!(runs[1][2], v["frames"].to_string());
    assert!(inputs.contains("<table class=\"stitching\">"), "{inputs}");
    // The Markdown has the track too.
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("## GNSS track") && md.contains("![GNSS track](track.svg)"), "{md}");
    assert!(md.contains("| 1 | 42 | 1 invalid, 36 RTK fixed, 5 RTK float |"), "{md}");
}

/// Without fixes the report says so and plots no track.
#[test]
fn a_report_without_fixes_says_there_are_none() {
    let dir = tempfile::tempdir().unwrap();
    let rec = super::parquet::gappy_recording(dir.path());
    let (out, html, _) = report(dir.path(), &rec, &["--block-m", "2"]);
    let tables = assert_real_report(&html);
    let track = section(&html, "track");
    assert!(track.contains("No GNSS fixes in the recording."), "{track}");
    assert!(!track.contains("<figure") && !out.join("track.svg").exists() && !out.join("track.png").exists());
    // The gaps the recording has are a table, the line without the 6 frames
    // of line 2 has its own.
    let sec = section(&html, "laser2");
    let line_tables = tables_of(sec);
    let gaps = table(&line_tables, sec, "gaps");
    assert_eq!(gaps[0], ["gap at", "length, mm"]);
    assert!(gaps.len() >= 3, "{gaps:?}");
    assert!(tables.iter().any(|(c, _)| c == "zones"));
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("No GNSS fixes in the recording."), "{md}");
}
