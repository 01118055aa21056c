//! `cms-host trend`: three synthetic surveys of one site a year apart,
//! the corrugation of one zone growing by a known amount, the growth and
//! the crossing recovered within their stated uncertainty; and the
//! surveys a trend refuses.

use std::path::{Path, PathBuf};

use cms_host::analyze::reprofiling::Edition;
use cms_host::analyze::standards::en13231;
use cms_host::analyze::trend::figure_of;
use cms_host::sim::synthetic::{self, Rail, survey_rail_um};

use crate::common::{one_line_error, run};

/// The corrugated zone, track position mm; its amplitude per survey, µm
/// (peak-to-peak 8 → 12 → 16 µm: 4 µm a year, the 20 µm limit of
/// 30–100 mm a year after the last survey).
const ZONE_MM: (f64, f64) = (50_000.0, 100_000.0);
const AMPLITUDES_UM: [f64; 3] = [4.0, 6.0, 8.0];
const DATES: [&str; 3] = ["2024-05-02", "2025-05-02", "2026-05-02"];
const SITE_MM: f64 = 150_000.0;

/// The surveys of a site `site_mm` long whose zone `zone_mm` grows.
fn surveys(dir: &Path, site_mm: f64, zone_mm: (f64, f64)) -> Vec<PathBuf> {
    let frames = (site_mm / 17.0) as u32;
    AMPLITUDES_UM
        .iter()
        .zip(DATES)
        .enumerate()
        .map(|(i, (&a, date))| {
            let rail = Rail::Survey { zone_mm, wavelength_mm: 50.0, amplitude_um: a };
            let survey = format!("start_chainage = \"0+000\"\nchainage = \"up\"\ndate = \"{date}\"\n");
            let o = synthetic::Options {
                frames,
                points_per_line: 240,
                rail,
                seed: 10 + i as u64,
                survey: Some(survey),
                ..synthetic::Options::default()
            };
            let p = dir.join(format!("survey{}.cmsrec", i + 1));
            synthetic::write(&p, &o, &cms_host::progress::Silent).unwrap();
            p
        })
        .collect()
}

/// The true figure of a block in 30–100 mm: the same statistic on the
/// rail itself (no head, no noise), per survey.
fn true_figures(lo_mm: f64, hi_mm: f64) -> Vec<f64> {
    AMPLITUDES_UM
        .iter()
        .map(|&a| {
            let z: Vec<f64> = (0..SITE_MM as usize).map(|x| survey_rail_um(x as f64, ZONE_MM, 50.0, a)).collect();
            let (_, traces) = en13231::analyze_traced(&z, 1.0).unwrap();
            let st = traces[1].as_ref().unwrap();
            let v: Vec<f64> =
                (lo_mm.round() as usize..(hi_mm.round() as usize).min(z.len())).map(|i| st.mean_pp_mm[i]).collect();
            figure_of(&v, Edition::En2006).unwrap()
        })
        .collect()
}

#[test]
fn a_trend_over_three_surveys_recovers_the_growth() {
    let dir = tempfile::tempdir().unwrap();
    let files = surveys(dir.path(), SITE_MM, ZONE_MM);
    let names: Vec<&str> = files.iter().map(|p| p.to_str().unwrap()).collect();
    let report = dir.path().join("trend-report");
    let mut args = vec!["trend"];
    args.extend(&names);
    args.extend(["--json", "--report", report.to_str().unwrap()]);
    let o = run(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["surveys"].as_array().unwrap().len(), 3);
    for r in v["registrations"].as_array().unwrap() {
        println!("registration: {r}");
        assert!(r["shift_mm"].as_f64().unwrap().abs() < 2.0, "{r}");
        assert_eq!(r["disputed"], false);
    }
    let mut grown = 0;
    for b in v["blocks"].as_array().unwrap().iter().filter(|b| b["lo_mm"] == 30.0) {
        let (lo, hi) = (b["start_mm"].as_f64().unwrap(), b["end_mm"].as_f64().unwrap());
        if b["growth_mm_per_year"].is_null() {
            // Only a block the surveys did not measure over half its length
            // (the site's end, inside the band's filter settling) has none.
            println!("block {lo:.0}–{hi:.0} mm: no growth ({})", b["figures"]);
            assert!(lo >= SITE_MM - 1000.0, "{b}");
            assert!(b["figures"].as_array().unwrap().iter().all(|f| f.is_null()), "{b}");
            continue;
        }
        let g = b["growth_mm_per_year"].as_f64().unwrap() * 1e3;
        let u = b["u_growth_mm_per_year"].as_f64().unwrap() * 1e3;
        let truth = true_figures(lo, hi);
        let true_growth = (truth[2] - truth[0]) / 2.0 * 1e3;
        println!(
            "block {lo:.0}–{hi:.0} mm: growth {g:+.3} ± {u:.3} µm/yr, truth {true_growth:+.3} (true figures {:?} µm), crossing {}",
            truth.iter().map(|t| (t * 1e4).round() / 10.0).collect::<Vec<_>>(),
            b["crossing"]
        );
        // Within 3 u of the truth, and the uncertainty is not so wide as to say nothing.
        assert!((g - true_growth).abs() <= 3.0 * u.max(0.05), "{lo}: {g} ± {u} against {true_growth}");
        assert!(u < 0.5, "{lo}: u {u}");
        let inside = lo >= ZONE_MM.0 - 1000.0 && hi <= ZONE_MM.1 + 1000.0;
        let outside = hi <= ZONE_MM.0 - 1000.0 || lo >= ZONE_MM.1 + 1000.0;
        if inside {
            grown += 1;
            assert!((true_growth - 4.0).abs() < 0.6, "{true_growth}");
            // The crossing: truth's line reaches 20 µm at t*; the interval holds it.
            let (a, slope) = (truth[1] * 1e3, true_growth);
            let t_star = 1.0 + (20.0 - a) / slope;
            let c = &b["crossing"];
            assert_eq!(c["kind"], "on", "{b}");
            let day =
                |s: &serde_json::Value| s.as_str().unwrap().parse::<cms_host::recording::survey_info::SurveyDate>();
            let first = DATES[0].parse::<cms_host::recording::survey_info::SurveyDate>().unwrap();
            let (lo_t, hi_t) =
                (day(&c["earliest"]).unwrap().years_since(first), day(&c["latest"]).unwrap().years_since(first));
            println!("  true crossing {t_star:.3} years after the first survey; interval {lo_t:.3} to {hi_t:.3}");
            assert!(lo_t <= t_star && t_star <= hi_t, "{t_star} not in {lo_t}..{hi_t}");
        } else if outside {
            assert!(g.abs() <= 3.0 * u.max(0.05), "{lo}: {g} ± {u} outside the zone");
            assert!(true_growth.abs() < 1e-9, "{true_growth}");
        }
    }
    assert_eq!(grown, 1, "one block inside the zone");
    iso3095_follows_the_rail(&v);
    for f in ["trend.html", "trend.svg", "trend.png", "trend.csv", "trend_iso3095.csv", "summary.txt"] {
        assert!(report.join(f).is_file(), "{f}");
    }
    let csv = std::fs::read_to_string(report.join("trend.csv")).unwrap();
    assert!(csv.starts_with("start_mm,end_mm,band,limit_mm,figure_mm_2024-05-02"), "{csv}");

    // The text table: the grown block first, with its date.
    let mut args = vec!["trend"];
    args.extend(&names);
    let o = run(&args);
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    println!("{text}");
    assert!(text.contains("blocks nearest to exceeding") && text.contains("0+050"), "{text}");
    // The corrugated block's 50 mm third octave, over the limit in every survey, is shown.
    let iso = text.split("ISO 3095 third octaves").nth(1).unwrap_or_default();
    assert!(
        iso.lines().any(|l| l.contains("0+050") && l.contains(" 50 ") && l.contains("EXCEEDS → EXCEEDS → EXCEEDS")),
        "{text}"
    );
    let csv = std::fs::read_to_string(report.join("trend_iso3095.csv")).unwrap();
    assert!(csv.starts_with("start_mm,end_mm,wavelength_mm,limit_db,verdict_2024-05-02,level_db_2024-05-02"), "{csv}");
    assert_eq!(
        csv.lines().count(),
        1 + v["iso3095"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| b["third_octaves"].as_array().unwrap().len())
            .sum::<usize>()
    );
}

/// The rail's level in a third octave over a block, per survey: the EN 15610
/// spectrum of the rail itself (no head, no noise), dB re 1 µm.
fn true_levels_db(lo_mm: f64, hi_mm: f64, wavelength_mm: f64) -> Vec<f64> {
    use cms_host::analyze::standards::en15610;
    AMPLITUDES_UM
        .iter()
        .map(|&a| {
            let z: Vec<f64> = (lo_mm.round() as usize..hi_mm.round() as usize)
                .map(|x| survey_rail_um(x as f64, ZONE_MM, 50.0, a))
                .collect();
            let r = en15610::analyze(&z, 1.0, &en15610::Options::default()).unwrap();
            r.spectrum.bands.iter().find(|b| b.nominal_wavelength_mm == wavelength_mm).unwrap().level_db
        })
        .collect()
}

/// The trend's ISO 3095 part: every block, every survey read; the
/// corrugated block's 50 mm third octave EXCEEDS in every survey and its
/// rail level grows as the true rail's does (within 3 u), the blocks
/// outside the zone never over the limit and, where followed, not growing.
fn iso3095_follows_the_rail(v: &serde_json::Value) {
    use cms_host::recording::survey_info::SurveyDate;
    let first: SurveyDate = DATES[0].parse().unwrap();
    let years: Vec<f64> = DATES.iter().map(|d| d.parse::<SurveyDate>().unwrap().years_since(first)).collect();
    let blocks = v["iso3095"].as_array().unwrap();
    let starts: std::collections::BTreeSet<i64> =
        v["blocks"].as_array().unwrap().iter().map(|b| b["start_mm"].as_f64().unwrap() as i64).collect();
    assert_eq!(blocks.len(), starts.len());
    let (mut zone, mut flat, mut judged_outside) = (0, 0, 0);
    for b in blocks {
        let (lo, hi) = (b["start_mm"].as_f64().unwrap(), b["end_mm"].as_f64().unwrap());
        let inside = lo >= ZONE_MM.0 - 1000.0 && hi <= ZONE_MM.1 + 1000.0;
        // A block's spectrum is of its own length alone: no filter reaches past its ends.
        let outside = hi <= ZONE_MM.0 || lo >= ZONE_MM.1;
        for o in b["third_octaves"].as_array().unwrap() {
            let w = o["wavelength_mm"].as_f64().unwrap();
            let readings = o["readings"].as_array().unwrap();
            assert_eq!(readings.len(), 3, "{o}");
            let growth = o["growth_db_per_year"].as_f64().map(|g| (g, o["u_growth_db_per_year"].as_f64().unwrap()));
            let judged = readings.iter().filter(|r| !r["figure_db"].is_null()).count();
            assert_eq!(growth.is_some(), judged >= 2, "{o}");
            if inside && w == 50.0 {
                assert!(readings.iter().all(|r| r["verdict"] == "EXCEEDS"), "{o}");
                let (g, u) = growth.unwrap();
                let truth = true_levels_db(lo, hi, w);
                let pts: Vec<(f64, f64, f64)> = readings
                    .iter()
                    .zip(&truth)
                    .zip(&years)
                    .map(|((r, &l), &t)| (t, l, r["u_db"].as_f64().unwrap()))
                    .collect();
                let want = cms_host::analyze::trend::weighted_fit(&pts).unwrap().b;
                println!(
                    "block {lo:.0}–{hi:.0} mm, 50 mm: growth {g:+.3} ± {u:.3} dB/yr, truth {want:+.3} (true levels {truth:.2?} dB)"
                );
                assert!((g - want).abs() <= 3.0 * u && u < 1.0, "{g} ± {u} against {want}");
                zone += 1;
            } else if outside {
                // The same rail every year, well under the limit: never over it, not growing.
                assert!(readings.iter().all(|r| r["verdict"] != "EXCEEDS"), "{lo} {w} mm: {o}");
                if let Some((g, u)) = growth {
                    assert!(g.abs() <= 3.0 * u, "{lo} {w} mm: {g} ± {u}");
                    flat += 1;
                }
                judged_outside += judged;
            }
        }
    }
    println!("ISO 3095 outside the zone: {judged_outside} figures, {flat} third octaves followed, none growing");
    assert!(zone == 1 && flat >= 10, "{zone} {flat}");
}

#[test]
fn surveys_a_trend_cannot_follow_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    // Refusals need no long site: 40 m, a 20 m zone (the 1 m shift is
    // still found by registration).
    let files = surveys(dir.path(), 40_000.0, (10_000.0, 30_000.0));
    let n: Vec<&str> = files.iter().map(|p| p.to_str().unwrap()).collect();
    let e = one_line_error(&run(&["trend", n[0]]));
    assert!(e.contains("at least two dates"), "{e}");
    let e = one_line_error(&run(&["trend", n[0], n[1], "--date", "2024-05-02", "--date", "2024-05-02"]));
    assert!(e.contains("both of 2024-05-02") && e.contains("survey1") && e.contains("survey2"), "{e}");
    let o = run(&["trend", n[0], n[1], "--date", "2024-02-30"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("`2024-02-30` is not a date"), "{o:?}");
    // Placed 10 km away: no block of the first is covered.
    let e = one_line_error(&run(&["trend", n[0], n[1], "--chainage", "0+000", "--chainage", "10+000"]));
    assert!(e.contains("does not overlap") && e.contains("survey2"), "{e}");
    // A survey given 1 m off: registration finds it and says so.
    let o = run(&["trend", n[0], n[1], "--chainage", "0+000", "--chainage", "0+001", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let r = &v["registrations"][0];
    println!("1 m off: {r}");
    assert!((r["shift_mm"].as_f64().unwrap() + 1000.0).abs() < 5.0, "{r}");
    assert_eq!(r["disputed"], true);
    // A recording without a date in its survey block, and no --date.
    let plain = dir.path().join("undated.cmsrec");
    let o = synthetic::Options { frames: 200, points_per_line: 60, ..synthetic::Options::default() };
    synthetic::write(&plain, &o, &cms_host::progress::Silent).unwrap();
    let e = one_line_error(&run(&["trend", n[0], plain.to_str().unwrap()]));
    assert!(e.contains("undated.cmsrec") && e.contains("no date"), "{e}");
}
