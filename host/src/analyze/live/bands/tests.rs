use super::*;
use crate::analyze::{self, Analysis};

/// Frames of three lines over `length_mm` of rail `rail(x)` (µm), `step_mm`
/// apart, 480 points each over 68.6 mm, 2 µm of noise per point.
fn frames(length_mm: f64, step_mm: f64, rail: &dyn Fn(f64) -> f64) -> Vec<FramePoints> {
    frames_noisy(length_mm, step_mm, rail, [2.0; 3])
}

/// [`frames`] with `sigma_um[k]` of noise per point on line `k`.
fn frames_noisy(length_mm: f64, step_mm: f64, rail: &dyn Fn(f64) -> f64, sigma_um: [f64; 3]) -> Vec<FramePoints> {
    let mut rng = cms_study::Rng::new(11);
    let n = (length_mm / step_mm) as u32;
    (0..n)
        .map(|i| {
            let o = step_mm * f64::from(i);
            let mut f = FramePoints { seq: i, odometer_mm: o, ..FramePoints::default() };
            for (k, pts) in f.lasers.iter_mut().enumerate() {
                *pts = (0..480)
                    .map(|r| -34.3 + 0.143 * f64::from(r))
                    .map(|a| (a, rail(o + a) + 50.0 * k as f64 + sigma_um[k] * rng.normal()))
                    .collect();
            }
            f
        })
        .collect()
}

fn rail(x: f64) -> f64 {
    use std::f64::consts::TAU;
    30.0 * (TAU * x / 50.0).sin() + 20.0 * (TAU * x / 200.0 + 1.0).sin() + 3.0 * (TAU * x / 17.0).sin()
}

fn live(frames: &[FramePoints]) -> BandsReport {
    let mut l = LiveBands::default();
    for f in frames {
        l.add(f);
    }
    l.report().cloned().expect("a report")
}

/// Each line's live figures since the start are analyze's of the same
/// frames within their stated uncertainty, and so is the state.
fn agree(r: &BandsReport, a: &Analysis) {
    for la in &a.lasers {
        let line = r.lines.iter().find(|l| l.laser == Some(la.stitched.laser)).expect("the laser's bands");
        let bands = la.bands.as_ref().unwrap();
        for b in 0..4 {
            let got = &line.bands[b];
            let Ok(want) = &bands.bands[b].outcome else {
                assert_eq!(got.state, "not evaluated", "band {b}: {got:?}");
                continue;
            };
            let f = got.since.expect("figures where analyze has them");
            let (pp, rms) = (want.average_mean_pp_mm * 1000.0, want.rms_mm * 1000.0);
            assert!((f.mean_pp_um - pp).abs() <= f.mean_pp_u_um, "laser {} band {b}: {f:?} vs {pp}", la.stitched.laser);
            assert!((f.rms_um - rms).abs() <= f.rms_u_um, "laser {} band {b}: {f:?} vs {rms}", la.stitched.laser);
            let state = match (&la.judgements[b].not_judged, want.passes) {
                (Some(_), _) => "not judged",
                (None, true) => "within",
                (None, false) => "over",
            };
            assert_eq!(got.state, state, "laser {} band {b}: {got:?}", la.stitched.laser);
        }
    }
    let rb = r.lines.iter().find(|l| l.laser.is_none()).expect("the running band");
    for (b, row) in a.verdict.rows.iter().enumerate().take(4) {
        let want = match (&row.judgement.not_judged, row.passes(a.verdict.options.edition)) {
            (Some(_), _) => "not judged",
            (None, Some(true)) => "within",
            (None, Some(false)) => "over",
            (None, None) => "not evaluated",
        };
        assert_eq!(rb.bands[b].state, want, "running band {b}: {:?}", rb.bands[b]);
    }
}

/// 7 m of a rail of three wavelengths (two stretches and a part):
/// the live figures are analyze's, the run's length too, less the frames
/// the joint registration has not yet committed.
#[test]
fn live_bands_are_what_analyze_finds() {
    let step_mm = 16.7;
    let f = frames(7_000.0, step_mm, &rail);
    let r = live(&f);
    let a = analyze::analyze(&f, &analyze::Options::default()).unwrap();
    agree(&r, &a);
    let covered = a.lasers[0].stitched.length_mm();
    let pending = crate::analyze::stitch::solve::LAG_FRAMES as f64 * step_mm;
    assert!((r.since_mm + pending - covered).abs() < 80.0, "{} of {covered}", r.since_mm);
    assert_eq!(r.unstitched, 0);
    // Every window counted once: the stretches' cores tile the run.
    let rb = &r.lines[0].bands[0];
    let windows = a.lasers[0].bands.as_ref().unwrap().bands[0].outcome.as_ref().unwrap().windows;
    let got = rb.since.unwrap().windows;
    // The windows of 1 mm the uncommitted frames would add.
    let missing = (pending / a.lasers[0].stitched.dx_mm).round() as usize;
    assert!((got + missing).abs_diff(windows) <= 2, "{got} windows vs {windows}");
    assert!(r.status().contains("30–100 L0"), "{}", r.status());
}

/// One line 4× noisier than the others: each line's live floor is its
/// own and the running band's is that of its lines weighted by their
/// noise, as analyze finds on the same frames (the stitch's share left
/// out) — not the plain mean's (twice as high for noises of 4 : 1 : 1).
#[test]
fn the_live_floor_weights_the_lines_as_analyze_does() {
    let f = frames_noisy(5_000.0, 16.7, &rail, [8.0, 2.0, 2.0]);
    let r = live(&f);
    let a = analyze::analyze(&f, &analyze::Options::default()).unwrap();
    let shared = a.floor.as_ref().expect("analyze's floor");
    let edition = a.verdict.options.edition;
    // analyze's floors without the stitch's share (the live floor leaves it out: module docs).
    let own = |f: BandFloor| f.scaled((f.rms_mm.powi(2) - f.stitch_rms_mm.powi(2)).max(0.0).sqrt());
    let pp = |f: Option<BandFloor>| f.map(|f| own(f).judged_quantity_mm(edition) * 1000.0);
    let rb = r.lines.iter().find(|l| l.laser.is_none()).expect("the running band");
    let mut compared = 0;
    for b in 0..SHORT_BANDS {
        let (Some(got), Some(want)) = (rb.bands[b].floor_um, pp(a.running_bands[0].judgements[b].floor)) else {
            continue;
        };
        let plain = pp(shared.band(b).map(|f| f.of_mean(3))).unwrap();
        eprintln!("running band {b}: live floor {got:.3} µm, analyze {want:.3} µm, the plain mean's {plain:.3} µm");
        assert!((got / want - 1.0).abs() < 0.15, "band {b}: live {got} vs analyze {want}");
        assert!(plain > 1.5 * want, "band {b}: the plain mean's {plain} vs {want}");
        for la in &a.lasers {
            let line = r.lines.iter().find(|l| l.laser == Some(la.stitched.laser)).unwrap();
            let (got, want) = (line.bands[b].floor_um.unwrap(), pp(la.judgements[b].floor).unwrap());
            eprintln!("  laser {} floor: live {got:.3} µm, analyze {want:.3} µm", la.stitched.laser);
            assert!(
                (got / want - 1.0).abs() < 0.15,
                "laser {} band {b}: live {got} vs analyze {want}",
                la.stitched.laser
            );
        }
        compared += 1;
    }
    assert!(compared >= 2, "{r:?}");
}

/// The 300–1000 mm band: not evaluated yet while the run is under its 9 m,
/// then, on 20 m of a rail with a 600 mm wave, what analyze finds (its
/// figures within their uncertainty, its state) beside the shorter bands.
#[test]
fn the_300_1000_mm_band_is_live_once_the_run_is_long_enough() {
    use std::f64::consts::TAU;
    let long_wave = |x: f64| rail(x) + 40.0 * (TAU * x / 600.0).sin();
    let f = frames(20_000.0, 33.3, &long_wave);
    let mut l = LiveBands::default();
    let mut seen_short = false;
    for fr in &f {
        l.add(fr);
        if fr.odometer_mm > 6_000.0 && !seen_short {
            seen_short = true;
            let r = l.report().unwrap();
            let b = &r.lines[0].bands[3];
            assert_eq!(b.state, "not evaluated", "{b:?}");
            assert!(b.why.contains("not evaluated yet: it needs 9000 mm"), "{}", b.why);
            assert!(!r.status().contains("300–1000"), "{}", r.status());
        }
    }
    let r = l.judge_open().cloned().unwrap();
    let a = analyze::analyze(&f, &analyze::Options::default()).unwrap();
    agree(&r, &a);
    for line in &r.lines {
        let b = &line.bands[3];
        assert!(b.since.is_some_and(|f| f.windows > 0), "{b:?}");
        assert_ne!(b.state, "not evaluated", "{b:?}");
    }
    assert!(r.status().contains("300–1000 L0"), "{}", r.status());
}

/// Noise the floor does not allow a verdict on is not judged, named with
/// the floor and the limit; never over.
#[test]
fn noise_is_not_judged() {
    let mut rng = cms_study::Rng::new(5);
    let mut f = frames(3_000.0, 16.7, &|_| 0.0);
    for fr in &mut f {
        for pts in &mut fr.lasers {
            for p in pts.iter_mut() {
                p.1 += 400.0 * rng.normal();
            }
        }
    }
    let r = live(&f);
    for l in &r.lines {
        let b = &l.bands[0];
        assert_eq!(b.state, "not judged", "{b:?}");
        assert!(b.why.contains("noise floor") && b.why.contains("20 µm limit"), "{}", b.why);
    }
    assert!(r.lines.iter().all(|l| l.bands.iter().all(|b| b.state != "over")), "{r:?}");
}

/// Frames too far apart to overlap are flagged where they are, as the
/// joins analyze reports.
#[test]
fn frames_that_would_not_stitch_are_flagged() {
    let mut f = frames(1_500.0, 16.7, &rail);
    // A jump of 100 mm: the frame after it overlaps nothing.
    for fr in f.iter_mut().skip(40) {
        fr.odometer_mm += 100.0;
    }
    let r = live(&f);
    assert_eq!(r.unstitched, 3, "{:?}", r.latest_unstitched);
    assert!(r.latest_unstitched.iter().all(|u| u.seq == 40 && u.kind == "gap"), "{:?}", r.latest_unstitched);
    assert!(r.status().contains("3 frame(s) not stitched (last seq 40"), "{}", r.status());
}

/// Under 2012 only 30–100 mm has a limit (±10 µm of band displacement):
/// the 30 µm wave is over it, the other bands not judged for want of one.
#[test]
fn the_2012_edition_judges_isolated_points() {
    let f = frames(3_000.0, 16.7, &rail);
    let mut l = LiveBands::new(LiveOptions { edition: Edition::En2012, ..LiveOptions::default() });
    for fr in &f {
        l.add(fr);
    }
    let r = l.report().unwrap();
    assert_eq!(r.edition, "EN 13231-3:2012");
    let states: Vec<&str> = r.lines[0].bands.iter().map(|b| b.state).collect();
    assert_eq!(states, ["not judged", "over", "not judged", "not evaluated"], "{r:?}");
    assert!(r.lines[0].bands[1].why.contains("±10 µm"), "{:?}", r.lines[0].bands[1]);
}
