use super::*;
use crate::analyze::standards::detection::Verdict;

/// Frames of three lines over `length_mm` of rail `rail(x)` (µm),
/// `step_mm` apart, `points` points each over 68.6 mm, `sigma_um` of
/// noise per point.
fn frames(length_mm: f64, step_mm: f64, points: u32, sigma_um: f64, rail: &dyn Fn(f64) -> f64) -> Vec<FramePoints> {
    let mut rng = cms_study::Rng::new(23);
    let n = (length_mm / step_mm) as u32;
    let pitch = 68.6 / f64::from(points);
    (0..n)
        .map(|i| {
            let o = step_mm * f64::from(i);
            let mut f = FramePoints { seq: i, odometer_mm: o, ..FramePoints::default() };
            for (k, pts) in f.lasers.iter_mut().enumerate() {
                *pts = (0..points)
                    .map(|r| -34.3 + pitch * f64::from(r))
                    .map(|a| (a, rail(o + a) + 50.0 * k as f64 + sigma_um * rng.normal()))
                    .collect();
            }
            f
        })
        .collect()
}

/// 30 µm at 50 mm, 20 µm at 200 mm, 3 µm at 17 mm: far over the ISO 3095
/// limit in their third octaves, nothing elsewhere.
fn rail(x: f64) -> f64 {
    use std::f64::consts::TAU;
    30.0 * (TAU * x / 50.0).sin() + 20.0 * (TAU * x / 200.0 + 1.0).sin() + 3.0 * (TAU * x / 17.0).sin()
}

/// Until 5 m without a gap nothing is judged, and the panel says what
/// it needs; then every line's and the energy average's third octaves
/// are `analyze`'s of the same frames: the same verdicts, the levels and
/// floors within what the uncommitted last frames and the stitch's share
/// can move them.
#[test]
fn live_iso3095_verdicts_are_what_analyze_finds() {
    let f = frames(7_000.0, 33.3, 480, 2.0, &rail);
    let mut live = LiveIso3095::new(analyze::Options::default());
    let mut waited = false;
    for fr in &f {
        live.add(fr);
        if fr.odometer_mm > 3_000.0 && !waited {
            waited = true;
            let r = live.report().expect("a report once frames are in");
            assert_eq!(r.state, "not evaluated yet", "{r:?}");
            let why = r.why.as_deref().unwrap();
            assert!(why.starts_with("not evaluated yet: it needs 5000 mm of track without a gap ("), "{why}");
            assert!(r.lines.is_empty() && r.gapless_mm > 2_000.0 && r.gapless_mm < 5_000.0, "{r:?}");
        }
    }
    let r = live.judge_now().cloned().expect("a report");
    assert_eq!(r.state, "evaluated", "{r:?}");
    let a = analyze::analyze(&f, &analyze::Options::default()).unwrap();
    let mut want: Vec<(Option<usize>, &en15610::Spectrum)> =
        a.lasers.iter().map(|l| (Some(l.stitched.laser), &l.roughness.as_ref().unwrap().spectrum)).collect();
    want.push((None, a.running_bands[0].roughness.as_ref().unwrap()));
    assert_eq!(r.lines.len(), 4, "{r:?}");
    let mut exceeds = 0;
    for (laser, s) in want {
        let line = r.lines.iter().find(|l| l.laser == laser).expect("every line and the energy average");
        let judged: Vec<_> = s.bands.iter().filter(|b| b.decision().is_some()).collect();
        assert_eq!(line.bands.len(), judged.len(), "{laser:?}");
        // 5–250 mm at least.
        assert!(
            line.bands.iter().any(|b| b.wavelength_mm == 250.0) && line.bands.iter().any(|b| b.wavelength_mm == 5.0)
        );
        for (got, b) in line.bands.iter().zip(judged) {
            let d = b.decision().unwrap();
            let floor = |v: Option<f64>| v.unwrap_or(f64::NAN);
            eprintln!(
                "{laser:?} {:>5} mm: level {:6.2} / {:6.2} dB, floor {:6.2} / {:6.2} dB, {} / {}",
                got.wavelength_mm,
                got.level_db,
                b.level_db,
                floor(got.floor_db),
                floor(b.floor_db),
                got.verdict,
                d.verdict
            );
            assert_eq!(got.wavelength_mm, b.nominal_wavelength_mm);
            assert_eq!(got.limit_db, d.limit_db);
            assert_eq!(got.verdict, d.verdict.name(), "{laser:?} {} mm: {got:?} vs {d:?}", got.wavelength_mm);
            assert!((got.level_db - b.level_db).abs() < 0.5, "{laser:?} {} mm: {got:?} vs {b:?}", got.wavelength_mm);
            assert!(
                (floor(got.floor_db) - floor(b.floor_db)).abs() < 1.0,
                "{laser:?} {} mm: {got:?} vs {b:?}",
                got.wavelength_mm
            );
            assert!(got.words.starts_with(got.verdict), "{got:?}");
            if got.verdict == Verdict::Exceeds.name() {
                exceeds += 1;
                assert!(got.rail_lo_db.is_some_and(|lo| lo > got.limit_db), "{got:?}");
            }
        }
        // The rail's three waves: EXCEEDS at 200, 50 and 16 mm.
        for w in [200.0, 50.0, 16.0] {
            let b = line.bands.iter().find(|b| b.wavelength_mm == w).unwrap();
            assert_eq!(b.verdict, "EXCEEDS", "{laser:?} {w} mm: {b:?}");
        }
        assert!(line.verdict.starts_with("EXCEEDS at "), "{line:?}");
    }
    assert!(exceeds >= 12, "{r:?}");
    assert!(r.cost_ms.is_some_and(|c| c > 0.0), "{r:?}");
}

/// The stretch stays bounded: past 30 m of travel the oldest stitcher
/// is dropped, and the stretch taken is the last 15 to 30 m.
#[test]
fn the_stretch_judged_is_the_latest_15_to_30_m() {
    let f = frames(40_000.0, 33.3, 120, 2.0, &rail);
    let mut live = LiveIso3095::new(analyze::Options::default());
    for fr in &f {
        live.add(fr);
    }
    assert_eq!(live.open.len(), 2);
    let t = live.take().unwrap();
    let newest = f.last().unwrap().odometer_mm;
    assert_eq!(t.to_odometer_mm, newest);
    let span = newest - t.from_odometer_mm;
    assert!((STRETCH_MM / 2.0..STRETCH_MM).contains(&span), "{span} mm");
    // The last eight frames not yet committed by the joint registration.
    assert!((span - 400.0..span + 100.0).contains(&t.stretch_mm), "{} of {span} mm", t.stretch_mm);
}
