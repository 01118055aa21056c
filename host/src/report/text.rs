//! An analysis as text: the summary `cms-host analyze` prints, and the
//! descriptions the reports reuse.

use std::fmt::Write as _;
use std::path::Path;

use crate::analyze::standards::{StandardsError, en13231, en15610};
use crate::analyze::stitch::{Direction, Registration, Stitched};
use crate::analyze::{
    Analysis, Recording, Source, chainage, fmt_len, iso3095_not_evaluated, reprofiling, spectrum_peak, survey,
};
use crate::recording;

pub(super) fn direction_name(d: Direction) -> &'static str {
    match d {
        Direction::Forward => "x = odometer + along",
        Direction::Reverse => "x = odometer − along",
        Direction::Auto => "auto",
    }
}

pub(super) fn registration_name(r: Registration) -> &'static str {
    match r {
        Registration::OffsetTilt => "offset and tilt",
        Registration::Offset => "offset",
        Registration::None => "none",
        Registration::Joint => "joint offset",
        Registration::JointPitch => "joint offset and pitch",
    }
}

fn opt_um(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.2} µm"))
}

/// The input's and the stitching's description (a few lines).
pub fn describe(source: &Source, a: &Analysis) -> String {
    let mut s = String::new();
    match source {
        Source::Recordings(runs) => {
            for (path, rec) in runs {
                describe_recording(&mut s, path, rec);
            }
            let st = &a.stitching;
            let check = match (st.direction_residuals_um, st.direction_given) {
                (Some((f, r)), false) => format!(
                    " (chosen from the data: median overlap residual forward {}, reverse {})",
                    opt_um(f),
                    opt_um(r)
                ),
                (Some((f, r)), true) => {
                    format!(" (as given; median overlap residual forward {}, reverse {})", opt_um(f), opt_um(r))
                }
                (None, _) => String::new(),
            };
            let _ = writeln!(
                s,
                "stitching: {}{check}; registration: {}; samples every {} mm",
                direction_name(st.direction),
                registration_name(a.options.stitch.registration),
                fmt_len(a.options.stitch.dx_mm)
            );
        }
        Source::Profile(path, p) => {
            let _ = writeln!(
                s,
                "profile {}: {} rows, {} line(s) ({}), {}; samples every {} mm{}",
                path.display(),
                p.rows,
                p.columns.len(),
                p.columns.join(", "),
                if p.has_x {
                    format!("positions every {} mm (median step)", fmt_len(p.data_dx_mm))
                } else {
                    "no position column".into()
                },
                fmt_len(a.options.stitch.dx_mm),
                if p.resampled { " (interpolated onto that grid; never across a gap)" } else { "" }
            );
        }
    }
    // One run where the user put it by default needs no placement line
    // (unless something about it is disputed).
    let placed = a.joins.len() > 1
        || a.joins.iter().any(|j| {
            j.start_m != 0.0
                || j.heading == survey::Heading::Down
                || j.direction_disputed.is_some()
                || j.heading_disputed.is_some()
                || j.elsewhere.is_some()
        });
    if placed {
        for j in &a.joins {
            let _ = writeln!(s, "{}", describe_join(j));
        }
    }
    for p in &a.gnss_placing {
        let _ = writeln!(s, "{p}");
    }
    s.push_str(&describe_sections(a));
    s
}

/// The survey line's sections and the gaps between them (nothing for one
/// section).
pub fn describe_sections(a: &Analysis) -> String {
    let sections = a.sections();
    let mut s = String::new();
    if sections.len() < 2 {
        return s;
    }
    let _ = writeln!(
        s,
        "survey line in {} sections (a stretch without data longer than {} m separates two):",
        sections.len(),
        fmt_len(survey::section_gap_mm(&a.options.verdict) / 1000.0)
    );
    let mut last: Option<f64> = None;
    for sec in &sections {
        let (x0, x1) = sec.span_mm();
        if let Some(end) = last {
            let _ = writeln!(s, "  not measured: {} to {} ({:.3} m)", chainage(end), chainage(x0), (x0 - end) / 1000.0);
        }
        let _ =
            writeln!(s, "  section {}: {} to {} ({:.3} m)", sec.number, chainage(x0), chainage(x1), (x1 - x0) / 1000.0);
        last = Some(x1);
    }
    s
}

/// One run's placement on the line, in a line (runs numbered from 1).
pub fn describe_join(j: &survey::RunJoin) -> String {
    let mut s = format!(
        "run {}: position 0 at chainage {} ({:.3} m), chainage {} with track position{}",
        j.run,
        survey::Chainage(j.start_m),
        j.start_m,
        j.heading.name(),
        if j.heading_found { " (found by registration)" } else { "" }
    );
    if j.registered() {
        if let Some(m) = j.moved_mm {
            let _ = write!(s, "; registered {:+.1} mm from its given start", m);
        }
        let _ = write!(s, "; overlap {:.1} m, residual {}", j.overlap_mm / 1000.0, opt_um(j.residual_um));
    } else if j.run > 1 {
        s.push_str("; placed as given: where its chainage puts it, it overlaps no earlier run enough to register");
        if j.overlap_mm > 0.0 {
            let _ = write!(s, " (overlap {:.1} m averaged, its offset removed)", j.overlap_mm / 1000.0);
        }
    }
    if let Some((moved, c)) = j.elsewhere {
        let _ = write!(
            s,
            "; CHAINAGE DISPUTED: its rail matches the earlier runs {:+.3} m from its given start (correlation {c:.2}), not taken (check its --chainage)",
            moved / 1000.0
        );
    }
    let _ = write!(s, "; section {}", j.section);
    if j.ambiguous() {
        s.push_str("; AMBIGUOUS: another placement matched nearly as well (give its start chainage)");
    }
    if let Some((given, other)) = j.heading_disputed {
        let _ = write!(
            s,
            "; HEADING DISPUTED: chainage {} as given registers with residual {}, the other heading with {} (check its --chainage)",
            j.heading.name(),
            opt_um(Some(given)),
            opt_um(Some(other))
        );
    }
    if let Some((other, used)) = j.direction_disputed {
        let _ = write!(
            s,
            "; DIRECTION DISPUTED: its frames stitched {} as given register with median residual {}, the other way with {} (check --direction)",
            match j.direction {
                Direction::Reverse => "reverse",
                _ => "forward",
            },
            opt_um(Some(used)),
            opt_um(Some(other))
        );
    }
    s
}

fn describe_recording(s: &mut String, path: &Path, rec: &Recording) {
    let (smin, smax) = rec.seq_range.unwrap_or((0, 0));
    let (olo, ohi) = rec.odometer_range_mm.unwrap_or((0.0, 0.0));
    let _ = writeln!(
        s,
        "recording {}: {} frames with calibrated points (seq {smin}–{smax}), {} points, odometer {olo:.3}–{ohi:.3} mm{}",
        path.display(),
        rec.frames,
        rec.calibrated_points,
        match rec.calibration_id {
            Some(id) => format!(", calibration {id:#010x}"),
            None => String::new(),
        }
    );
    if let Some(sv) = &rec.survey {
        let _ = writeln!(s, "  survey: {}", sv.describe());
    }
    if let Some(k) = rec.repeats {
        let _ = writeln!(s, "  the same recording as run {k}, joined as asked (--allow-repeated-runs)");
    }
    if let Some((k, how)) = &rec.other_head {
        let _ = writeln!(s, "  recorded by another head than run {k} ({how}), joined as asked (--allow-mixed-heads)");
    }
    if rec.uncalibrated_points > 0 {
        let _ = writeln!(s, "  {} points without a calibrated position were left out", rec.uncalibrated_points);
    }
    match &rec.slid_across {
        Some((n, cal)) => {
            let _ = writeln!(
                s,
                "  heights slid across the rail head's lateral slope with {} ({n} of {} frames)",
                cal.display(),
                rec.frames
            );
        }
        None => {
            let _ = writeln!(
                s,
                "  heights as the head measured them (no --calibration: the outer lines keep their lateral-slope scale)"
            );
        }
    }
    for w in recording::warnings(path, &rec.stats) {
        let _ = writeln!(s, "  {w}");
    }
}

/// `, N runs averaged` on a line that averages runs (nothing for one run).
fn runs_averaged(l: &Stitched) -> String {
    if l.runs_averaged > 1.0 + 1e-9 { format!(", {:.2} runs averaged", l.runs_averaged) } else { String::new() }
}

/// One laser's stitching in a few lines.
pub fn describe_stitched(l: &Stitched) -> String {
    let mut s = String::new();
    let overlap = l.fits.median_overlap_mm();
    let _ = writeln!(
        s,
        "laser {}: {:.0} mm of track from chainage {} ({:.0} mm covered{}), {} frames, {} points; {} registered \
         (median overlap {}, residual median {}, offsets RMS {:.2} µm, tilts RMS {:.4} µm/mm), {} unregistered join(s), {} gap(s)",
        l.laser,
        l.length_mm(),
        chainage(l.x0_mm),
        l.covered_mm(),
        runs_averaged(l),
        l.frames,
        l.points,
        l.fits.len(),
        overlap.map_or("-".into(), |v| format!("{v:.0} mm")),
        opt_um(l.median_residual_um()),
        l.fits.offset_rms_um(),
        l.fits.tilt_rms_um_per_mm(),
        l.joins.len(),
        l.gaps.len()
    );
    for g in l.gaps.iter().take(20) {
        let _ = writeln!(s, "  gap at {}, {} mm long", chainage(g.start_mm), fmt_len(g.length_mm));
    }
    if l.gaps.len() > 20 {
        let _ = writeln!(s, "  … and {} more gaps (see the report)", l.gaps.len() - 20);
    }
    for j in l.joins.iter().take(10) {
        let _ = writeln!(
            s,
            "  frame {} joined unregistered at {} (overlap {:.1} mm)",
            j.seq,
            chainage(j.at_mm),
            j.overlap_mm
        );
    }
    if l.joins.len() > 10 {
        let _ = writeln!(s, "  … and {} more unregistered joins", l.joins.len() - 10);
    }
    s
}

/// One laser's EN 15610 outcome: the table, the wavelengths not evaluated,
/// the peak; or why there is none.
pub fn describe_roughness(r: &Result<en15610::Roughness, StandardsError>) -> String {
    let mut s = String::new();
    match r {
        Ok(r) => {
            s.push_str(&en15610::spectrum_table(r));
            let missing = iso3095_not_evaluated(r);
            if !missing.is_empty() {
                let list: Vec<String> = missing.iter().map(|(w, why)| format!("{} mm ({why})", fmt_len(*w))).collect();
                let _ = writeln!(s, "ISO 3095 wavelengths not evaluated: {}", list.join("; "));
            }
            if let Some(p) = spectrum_peak(r) {
                let (exceeds, within, not_judged) = crate::analyze::verdict_counts(&r.spectrum);
                let _ = writeln!(
                    s,
                    "spectrum peak: {} mm one-third octave ({}); ISO 3095: {exceeds} third octave(s) exceed, {within} within, {not_judged} not judged",
                    fmt_len(p.nominal_wavelength_mm),
                    crate::analyze::peak_words(p),
                );
            }
        }
        Err(e) => {
            let _ = writeln!(s, "EN 15610 roughness not evaluated: {e}");
        }
    }
    s
}

/// One profile's EN 13231-3 outcome, each band with its noise floor
/// and whether the floor allows a verdict (`judgements` in band order;
/// empty: the floor is not known).
pub fn describe_bands(
    b: &Result<en13231::BandAnalysis, StandardsError>,
    judgements: &[crate::analyze::floor::BandJudgement],
) -> String {
    let a = match b {
        Ok(a) => a,
        Err(e) => return format!("EN 13231-3 bands not evaluated: {e}\n"),
    };
    let mut s = format!(
        "EN 13231-3 wavelength bands: record {} mm, spacing {} mm, {} run(s)\n",
        fmt_len(a.record_mm),
        a.dx_mm,
        a.runs
    );
    let _ = writeln!(
        s,
        "{:<10} {:>8} {:>10} {:>11} {:>10} {:>8} {:>12} {:>12} {:>10}  verdict",
        "band_mm",
        "limit_mm",
        "avg_pp_mm",
        "worst_pp_mm",
        "max_pp_mm",
        "rms_mm",
        "exceeding_%",
        "floor_pp_mm",
        "floor_rms"
    );
    for (k, r) in a.bands.iter().enumerate() {
        let name = format!("{}-{}", fmt_len(r.band.lo_mm), fmt_len(r.band.hi_mm));
        let j = judgements.get(k);
        let floor = j.and_then(|j| j.floor);
        let (fpp, frms) = floor
            .map_or(("-".into(), "-".into()), |f| (format!("{:.4}", f.average_mean_pp_mm), format!("{:.4}", f.rms_mm)));
        match &r.outcome {
            Ok(st) => {
                let verdict = match j.and_then(|j| j.not_judged.as_ref()) {
                    Some(why) => why.clone(),
                    None if st.passes => "pass".into(),
                    None => "FAILS".into(),
                };
                let _ = writeln!(
                    s,
                    "{:<10} {:>8.3} {:>10.4} {:>11.4} {:>10.4} {:>8.4} {:>12.1} {:>12} {:>10}  {}",
                    name,
                    r.band.mean_pp_limit_mm,
                    st.average_mean_pp_mm,
                    st.worst_mean_pp_mm,
                    st.worst_max_pp_mm,
                    st.rms_mm,
                    st.exceeding_percent,
                    fpp,
                    frms,
                    verdict
                );
            }
            Err(e) => {
                let _ = writeln!(s, "{name:<10} {:>8.3}  not evaluated: {e}", r.band.mean_pp_limit_mm);
            }
        }
    }
    if judgements.iter().all(|j| j.floor.is_none()) {
        let _ = writeln!(s, "noise floor: not known here (one line, or the lines' common runs too short for the band)");
    }
    s
}

/// The survey's noise floor and each section's running band (the
/// profile the verdict judges).
pub fn describe_floor(a: &Analysis) -> String {
    let mut s = String::new();
    let Some(f) = &a.floor else {
        let _ = writeln!(
            s,
            "noise floor: not known (no section has two lines to tell rail from noise): verdicts as measured"
        );
        s.push_str(&super::optics::describe(a));
        return s;
    };
    let _ = writeln!(
        s,
        "noise floor of one line, from the {} lines' null combinations over {:.1} m (docs/noise-floor.md):",
        f.lines,
        f.measured_mm / 1000.0
    );
    for (b, band) in en13231::BANDS.iter().enumerate() {
        match f.band(b) {
            Some(x) => {
                let _ = writeln!(
                    s,
                    "  {:>4}–{:<4} mm: RMS {:.1} µm, mean peak-to-peak {:.1} µm (limit {:.0}), coherence of the lines {:.2}",
                    fmt_len(band.lo_mm),
                    fmt_len(band.hi_mm),
                    x.rms_mm * 1000.0,
                    x.average_mean_pp_mm * 1000.0,
                    band.mean_pp_limit_mm * 1000.0,
                    x.coherence
                );
            }
            None => {
                let _ = writeln!(
                    s,
                    "  {:>4}–{:<4} mm: not measured (runs too short)",
                    fmt_len(band.lo_mm),
                    fmt_len(band.hi_mm)
                );
            }
        }
    }
    s.push_str(&describe_line_floors(f));
    if let Some(share) = &a.stitching.share {
        let list: Vec<String> = en13231::BANDS
            .iter()
            .enumerate()
            .map(|(b, band)| {
                let v = share.rms_mm(b).map_or("not measured".into(), |v| format!("{:.2} µm", v * 1000.0));
                format!("{}–{} mm {v}", fmt_len(band.lo_mm), fmt_len(band.hi_mm))
            })
            .collect();
        let _ = writeln!(
            s,
            "  the stitch's own share (the joint registration's error, common to all lines, propagated; added above): RMS {}",
            list.join(", ")
        );
    }
    if let Some(sp) = &f.spectrum {
        let list: Vec<String> =
            sp.bands.iter().map(|b| format!("{} mm {:.1}", fmt_len(b.nominal_wavelength_mm), b.level_db)).collect();
        let _ = writeln!(s, "  EN 15610 floor (dB re 1 µm): {}", list.join(", "));
        let _ = writeln!(s, "  spike removal takes {:.1} \"spikes\" per metre out of noise alone", f.spikes_per_m);
    }
    s.push_str(&super::optics::describe(a));
    for rb in &a.running_bands {
        let _ = writeln!(
            s,
            "\nrunning band of section {} (the mean of {} lines; what the verdict judges):",
            rb.section, rb.lines
        );
        for line in describe_bands(&rb.bands, &rb.judgements).lines() {
            let _ = writeln!(s, "  {line}");
        }
        if let Some(sp) = &rb.roughness {
            let r = en15610::Roughness { spectrum: sp.clone(), spikes_removed: 0 };
            let _ = writeln!(s, "  EN 15610, the {} lines' spectra energy-averaged:", rb.lines);
            for line in en15610::spectrum_table(&r).lines().skip(1) {
                let _ = writeln!(s, "  {line}");
            }
        }
    }
    s
}

/// Each line's own floor, and the line whose floor stands out over the
/// others' with the likely causes; empty when the lines cannot be told apart.
pub fn describe_line_floors(f: &crate::analyze::floor::Floor) -> String {
    use crate::analyze::line_floor::{LIKELY_CAUSES, MIN_SHARE};
    let mut s = String::new();
    if f.lines_own.is_empty() {
        return s;
    }
    let _ = writeln!(s, "  each line's own floor, from the pairs of lines (RMS, µm):");
    for l in &f.lines_own {
        let list: Vec<String> = en13231::BANDS
            .iter()
            .zip(&l.bands)
            .map(|(band, b)| {
                let v = b.map_or("-".into(), |b| format!("{:.2}", b.rms_mm * 1000.0));
                format!("{}–{} mm {v}", fmt_len(band.lo_mm), fmt_len(band.hi_mm))
            })
            .collect();
        let _ = writeln!(s, "    line {}: {}", l.laser, list.join(", "));
        if !l.clipped.is_empty() {
            let _ = writeln!(
                s,
                "      its estimate fell under {:.0} dB of the lines' mean and was clipped there in {}",
                10.0 * MIN_SHARE.log10(),
                l.clipped.join(", ")
            );
        }
    }
    if let Some((laser, db)) = f.standing_out() {
        let _ = writeln!(
            s,
            "  line {laser}'s floor stands {db:.1} dB over the other lines' (median over the bands): likely {LIKELY_CAUSES}; each line is judged against its own floor"
        );
    }
    s
}

/// The printed summary.
pub fn summary(source: &Source, a: &Analysis) -> String {
    let mut s = describe(source, a);
    let sections = a.sections();
    for sec in &sections {
        if sections.len() > 1 {
            let (x0, x1) = sec.span_mm();
            let _ = writeln!(s, "\nsection {}: {} to {}", sec.number, chainage(x0), chainage(x1));
        }
        for l in sec.lasers {
            s.push('\n');
            s.push_str(&describe_stitched(&l.stitched));
            for part in [describe_bands(&l.bands, &l.judgements), describe_roughness(&l.roughness)] {
                for line in part.lines() {
                    let _ = writeln!(s, "  {line}");
                }
            }
        }
    }
    s.push('\n');
    s.push_str(&describe_floor(a));
    s.push('\n');
    s.push_str(&reprofiling::describe(&a.verdict));
    let marks = super::marks::summary(source, a);
    if !marks.is_empty() {
        s.push('\n');
        s.push_str(&marks);
    }
    s
}
