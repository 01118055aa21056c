//! The noise floor against what the optics predict
//! ([`crate::analyze::optics_floor`]), as the text summary, `--json`
//! (`noise.predicted`) and `report.html` carry it. It says how the floor
//! stands to speckle and sensor noise, never anything of the rail.

use std::fmt::Write as _;

use serde_json::{Value, json};

use super::table::{escape, table};
use crate::analyze::optics_floor::{Agreement, OctaveChecks, OpticsCheck, OpticsSource};
use crate::analyze::standards::en13231;
use crate::analyze::{Analysis, fmt_len};

/// What is said when the optics are not known.
pub const NOT_RECORDED: &str =
    "optics not recorded: the floor is not checked against them (analyze --optics F_NUMBER@WAVELENGTH_NM gives them)";

/// The check's heading line: the optics, where they come from, the
/// geometry and motion taken.
fn heading(c: &OpticsCheck) -> String {
    match c {
        OpticsCheck::NotRecorded => NOT_RECORDED.to_string(),
        OpticsCheck::Mixed(why) => format!("optics: {why}: the floor is not checked against them"),
        OpticsCheck::Checked { optics, source, head, motion, budget, .. } => format!(
            "the floor against what the optics predict ({optics}, {}; {}: a {:.1} mm lens at {:.0} mm, {:.0}°, {} µm pixels; {:.0} µs exposures at {:.2} m/s, {:.2} mm of travel; docs/noise-floor.md): a point {:.1} µm ({} × the Dorsch bound {:.1} µm), a speckle {:.2} px, correlated over {:.2} mm of rail{}",
            match source {
                OpticsSource::Recorded => "recorded",
                OpticsSource::Given => "given with --optics",
            },
            head.source.name(),
            head.focal_mm(),
            head.standoff_mm(),
            head.triangulation_deg(),
            head.pixel_um,
            motion.exposure_us,
            motion.speed_mm_s / 1000.0,
            budget.travel_mm,
            budget.point_um,
            crate::analyze::optics_floor::DETECTOR_OVER_DORSCH,
            budget.dorsch_um,
            budget.speckle_px,
            budget.correlation_mm,
            if budget.runs_averaged > 1.0 + 1e-9 {
                format!(
                    "; {:.2} runs averaged (their noise independent: power / {:.2})",
                    budget.runs_averaged, budget.runs_averaged
                )
            } else {
                String::new()
            },
        ),
    }
}

/// The text lines (the summary's and report.md's noise floor section).
pub fn describe(a: &Analysis) -> String {
    let mut s = format!("{}\n", heading(&a.optics));
    let OpticsCheck::Checked { bands, .. } = &a.optics else { return s };
    for (band, c) in en13231::BANDS.iter().zip(bands) {
        let name = format!("{:>4}–{:<4} mm", fmt_len(band.lo_mm), fmt_len(band.hi_mm));
        match c {
            Some(c) => {
                let _ = writeln!(
                    s,
                    "  {name}: predicted RMS {:.1} µm, measured {:.1} µm: {}",
                    c.predicted_rms_mm * 1000.0,
                    c.measured_rms_mm * 1000.0,
                    c.says()
                );
            }
            None => {
                let _ = writeln!(s, "  {name}: floor not measured, not checked");
            }
        }
    }
    if let OpticsCheck::Checked { lines, .. } = &a.optics {
        for (laser, checks) in lines {
            let list: Vec<String> = en13231::BANDS
                .iter()
                .zip(checks)
                .map(|(band, c)| {
                    let v = c.map_or("-".into(), |c| format!("{:+.1} dB", c.ratio_db));
                    format!("{}–{} mm {v}", fmt_len(band.lo_mm), fmt_len(band.hi_mm))
                })
                .collect();
            let _ = writeln!(s, "  line {laser}'s own floor against the prediction: {}", list.join(", "));
        }
    }
    if let OpticsCheck::Checked { octaves, line_octaves, .. } = &a.optics {
        if !octaves.is_empty() {
            let _ = writeln!(s, "  EN 15610 one-third octaves, one line's floor: {}", octave_summary(octaves));
        }
        for (laser, checks) in line_octaves.iter().filter(|(_, c)| !c.is_empty()) {
            let _ = writeln!(s, "  line {laser}'s own third-octave floor: {}", octave_summary(checks));
        }
    }
    s
}

/// A third-octave check in one line: how many agree, the spread, and
/// every one that does not.
fn octave_summary(checks: &OctaveChecks) -> String {
    use crate::analyze::standards::fmt_nominal_mm;
    let agree = checks.iter().filter(|(_, c)| c.agreement == Agreement::Agrees).count();
    let (lo, hi) = checks
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (_, c)| (lo.min(c.ratio_db), hi.max(c.ratio_db)));
    let mut out = format!(
        "{agree} of {} agree with the optics ({:+.1} to {:+.1} dB, {}–{} mm)",
        checks.len(),
        lo,
        hi,
        fmt_nominal_mm(checks.last().map_or(0.0, |c| c.0)),
        fmt_nominal_mm(checks.first().map_or(0.0, |c| c.0)),
    );
    for (mm, c) in checks.iter().filter(|(_, c)| c.agreement != Agreement::Agrees) {
        let _ = write!(out, "; {} mm: {}", fmt_nominal_mm(*mm), c.says());
    }
    out
}

/// `noise.predicted` of `--json`.
pub fn json(a: &Analysis) -> Value {
    let OpticsCheck::Checked { optics, source, head, motion, budget, bands, lines, octaves, line_octaves } = &a.optics
    else {
        return json!({ "checked": false, "why": heading(&a.optics) });
    };
    json!({
        "checked": true,
        "f_number": optics.f_number(),
        "wavelength_nm": optics.wavelength_nm(),
        "source": match source { OpticsSource::Recorded => "recorded", OpticsSource::Given => "given" },
        "geometry": {
            "focal_mm": head.focal_mm(),
            "standoff_mm": head.standoff_mm(),
            "triangulation_deg": head.triangulation_deg(),
            "pixel_um": head.pixel_um,
            "speckle_patterns": head.speckle_patterns,
            "from": head.source.name(),
        },
        "exposure_us": motion.exposure_us,
        "speed_mm_s": motion.speed_mm_s,
        "dorsch_um": budget.dorsch_um,
        "point_um": budget.point_um,
        "speckle_px": budget.speckle_px,
        "correlation_mm": budget.correlation_mm,
        "travel_mm": budget.travel_mm,
        "runs_averaged": budget.runs_averaged,
        "agrees_within_db": crate::analyze::optics_floor::AGREES_DB,
        "bands": en13231::BANDS.iter().zip(bands).map(|(band, c)| json!({
            "lo_mm": band.lo_mm,
            "hi_mm": band.hi_mm,
            "predicted_rms_mm": c.map(|c| c.predicted_rms_mm),
            "measured_rms_mm": c.map(|c| c.measured_rms_mm),
            "ratio_db": c.map(|c| c.ratio_db),
            "agreement": c.map(|c| c.agreement.name()),
            "says": c.map(|c| c.says()),
        })).collect::<Vec<_>>(),
        "lines": lines.iter().map(|(laser, checks)| json!({
            "laser": laser,
            "ratio_db": checks.iter().map(|c| c.map(|c| c.ratio_db)).collect::<Vec<_>>(),
            "agreement": checks.iter().map(|c| c.map(|c| c.agreement.name())).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "third_octaves": octaves_json(octaves),
        "lines_third_octaves": line_octaves.iter().map(|(laser, checks)| json!({
            "laser": laser,
            "third_octaves": octaves_json(checks),
        })).collect::<Vec<_>>(),
    })
}

/// Third-octave checks in `--json`: levels in dB re 1 µm.
fn octaves_json(checks: &OctaveChecks) -> Value {
    let db = |rms_mm: f64| 20.0 * (rms_mm * 1e3).log10();
    Value::Array(
        checks
            .iter()
            .map(|(mm, c)| {
                json!({
                    "wavelength_mm": mm,
                    "predicted_db": db(c.predicted_rms_mm),
                    "measured_db": db(c.measured_rms_mm),
                    "ratio_db": c.ratio_db,
                    "agreement": c.agreement.name(),
                })
            })
            .collect(),
    )
}

/// The check in report.html.
pub fn html(a: &Analysis) -> String {
    let mut s = format!("<p>{}.</p>\n", escape(&heading(&a.optics)));
    let OpticsCheck::Checked { bands, .. } = &a.optics else { return s };
    let dash = || "-".to_string();
    let rows: Vec<Vec<String>> = en13231::BANDS
        .iter()
        .zip(bands)
        .map(|(band, c)| {
            let name = format!("{}–{} mm", fmt_len(band.lo_mm), fmt_len(band.hi_mm));
            match c {
                Some(c) => vec![
                    name,
                    format!("{:.1}", c.predicted_rms_mm * 1000.0),
                    format!("{:.1}", c.measured_rms_mm * 1000.0),
                    format!("{:+.1}", c.ratio_db),
                    c.says(),
                ],
                None => vec![name, dash(), dash(), dash(), "not measured".into()],
            }
        })
        .collect();
    s.push_str(&table(
        "optics",
        &["band", "predicted by the optics, RMS µm", "one line's floor, RMS µm", "ratio, dB", "the floor"],
        &rows,
    ));
    if let OpticsCheck::Checked { octaves, .. } = &a.optics
        && !octaves.is_empty()
    {
        let _ =
            writeln!(s, "<p>EN 15610 one-third octaves, one line's floor: {}.</p>", escape(&octave_summary(octaves)));
    }
    s
}
