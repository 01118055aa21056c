//! Three-line profiles of known rail and known noise analysed as
//! `cms-host analyze PROFILE.csv` does (the CSV parsed, the lines judged):
//! the verdicts a rail can earn, and each line's own floor.

use std::fmt::Write as _;

use super::*;
use crate::analyze::standards::detection::Verdict;
use crate::analyze::{Analysis, judge, profile, runs};

use crate::analyze::seeded_gauss as gauss;

/// A sine at the exact centre of the one-third octave `k` at `level_db`.
#[derive(Clone, Copy)]
struct Tone {
    k: i32,
    level_db: f64,
}

/// The rail's height at `x_mm`, µm: the sum of its tones.
fn rail_um(tones: &[Tone], x_mm: f64) -> f64 {
    tones
        .iter()
        .enumerate()
        .map(|(j, t)| {
            let per_mm = 10f64.powf(t.k as f64 / 10.0) / 1000.0;
            let a = std::f64::consts::SQRT_2 * 10f64.powf(t.level_db / 20.0);
            a * (std::f64::consts::TAU * per_mm * x_mm + j as f64).sin()
        })
        .sum()
}

/// The profile CSV `x_mm,height_um_0,height_um_1,height_um_2` of `length_m`
/// at 0.5 mm: the rail (`tones`, the same on each line) plus each line's
/// own white noise `sigma_um` a sample — analysed as the CLI does.
fn analyse(length_m: f64, sigma_um: [f64; 3], tones: &[Tone], seed: u64) -> Analysis {
    analyse_with(length_m, sigma_um, tones, seed, &runs::Settings::default())
}

/// [`analyse`] under `settings`.
fn analyse_with(length_m: f64, sigma_um: [f64; 3], tones: &[Tone], seed: u64, settings: &runs::Settings) -> Analysis {
    let dx = 0.5;
    let n = (length_m * 1000.0 / dx) as usize;
    let mut g = gauss(seed);
    let mut text = String::from("x_mm,height_um_0,height_um_1,height_um_2\n");
    for i in 0..n {
        let x = i as f64 * dx;
        let rail = rail_um(tones, x);
        let _ = write!(text, "{x}");
        for s in sigma_um {
            let _ = write!(text, ",{:.5}", rail + s * g());
        }
        text.push('\n');
    }
    let (_, stitching) = profile::parse(&text, None).unwrap();
    judge(stitching, Vec::new(), &settings.options(), &crate::progress::Silent).unwrap()
}

/// Every spectrum the survey judges: each line's, each running band's, and each block's verdicts.
fn spectra(a: &Analysis) -> Vec<(String, &en15610::Spectrum)> {
    let mut out: Vec<(String, &en15610::Spectrum)> = a
        .lasers
        .iter()
        .map(|l| (format!("line {}", l.stitched.laser), &l.roughness.as_ref().unwrap().spectrum))
        .collect();
    out.extend(a.running_bands.iter().filter_map(|rb| Some(("running band".into(), rb.roughness.as_ref()?))));
    out
}

/// A smooth rail read with 0.1 µm of noise a sample: every ISO 3095
/// third octave from 5 to 250 mm of every line, and of their average,
/// within — however close the reading is to its floor.
#[test]
fn a_smooth_rail_is_within_in_every_third_octave() {
    let a = analyse(12.0, [0.1; 3], &[], 1);
    for (what, s) in spectra(&a) {
        for b in s.bands.iter().filter(|b| (5.0..=250.0).contains(&b.nominal_wavelength_mm)) {
            assert_eq!(b.verdict(), Some(Verdict::Within), "{what}: {b:?} {:?}", b.decision());
        }
    }
    // Each block within, its energy average and each line.
    for b in &a.verdict.blocks {
        let lines = b.iso3095_lines.iter().map(|(_, i)| i);
        assert!(b.iso3095.iter().chain(lines).all(|i| i.verdict() == Some(Verdict::Within)), "{b:?}");
        assert_eq!(b.iso3095_lines.len(), 3, "{b:?}");
    }
}

/// One line's RMS in `band` of white noise of `sigma_um` a sample `dx_mm`
/// apart, mm: the one-sided density `2σ²·dx` through the band filter.
fn white_band_rms_mm(sigma_um: f64, dx_mm: f64, band: &en13231::Band) -> f64 {
    let (lo, hi) = (0.1 / band.hi_mm, (10.0 / band.lo_mm).min(0.5 / dx_mm));
    let steps = 4000;
    let r = (hi / lo).ln() / steps as f64;
    let sum: f64 = (0..steps)
        .map(|i| {
            let f = lo * ((i as f64 + 0.5) * r).exp();
            crate::analyze::optics_floor::band_power_gain(band, f) * f * r
        })
        .sum();
    sigma_um * (2.0 * dx_mm * sum).sqrt() / 1000.0
}

/// Lines of unequal noise (20, 5 and 5 µm a sample) on a smooth rail:
/// no band fails, no third octave exceeds, and each line's own floor is
/// within a factor 2 of its truth in every EN 13231-3 band (the white
/// noise through the band filter) and, where noise passes the processing
/// linearly, every ISO 3095 third octave (what the line, pure noise,
/// reads); the noisy line is named.
#[test]
fn unequal_lines_each_carry_their_own_floor() {
    let sigma = [20.0, 5.0, 5.0];
    let a = analyse(12.0, sigma, &[], 2);
    let v = &a.verdict;
    assert!(v.rows.iter().all(|r| r.passes(v.options.edition) != Some(false)), "{:?}", v.rows);
    for l in &a.lasers {
        for (r, j) in l.bands.as_ref().unwrap().bands.iter().zip(&l.judgements) {
            if let Ok(st) = &r.outcome {
                assert!(st.passes || j.not_judged.is_some(), "line {} fails {}", l.stitched.laser, r.band.name());
            }
        }
    }
    for (what, s) in spectra(&a) {
        for b in &s.bands {
            assert_ne!(b.verdict(), Some(Verdict::Exceeds), "{what}: {b:?}");
        }
    }
    // No block's energy average or line exceeds.
    for b in &v.blocks {
        let lines = b.iso3095_lines.iter().map(|(_, i)| i);
        assert!(b.iso3095.iter().chain(lines).all(|i| i.exceeded_mm.is_empty()), "{b:?}");
    }
    let f = a.floor.as_ref().unwrap();
    assert_eq!(f.lines_own.len(), 3);
    for own in &f.lines_own {
        for (band, fl) in en13231::BANDS.iter().zip(&own.bands) {
            let Some(fl) = fl else { continue };
            let ratio = fl.rms_mm / white_band_rms_mm(sigma[own.laser], 0.5, band);
            assert!((0.5..2.0).contains(&ratio), "line {} {}: floor {ratio}× its truth", own.laser, band.name());
        }
    }
    let (laser, db) = f.standing_out().expect("the noisy line stands out");
    assert_eq!(laser, 0);
    assert!((9.0..15.0).contains(&db), "{db} dB over the others (12 dB true)");

    // The third octaves, noise passed linearly (no spike removal, no wheel).
    let linear = runs::Settings { remove_spikes: false, curvature: false, ..runs::Settings::default() };
    let a = analyse_with(12.0, sigma, &[], 2, &linear);
    for l in &a.lasers {
        let read = &l.roughness.as_ref().unwrap().spectrum;
        for b in read.bands.iter().filter(|b| b.iso3095_limit_db.is_some()) {
            let fl = b.floor_db.unwrap();
            assert!((fl - b.level_db).abs() < 6.02, "line {}: {b:?}", l.stitched.laser);
        }
    }
}

/// Rails with known third-octave levels over, near and under the limit
/// under several noises: 3 dB or more over never "within", 3 dB or more
/// under never "EXCEEDS", and — where noise passes the processing
/// linearly (no spike removal, no wheel: with them, noise of a few µm a
/// sample takes up to 3 dB off a short tone, which the interval does not
/// hold) — the rail's level inside its interval: the level EN 15610 reads
/// on the rail alone.
#[test]
fn known_levels_earn_the_verdicts_they_should() {
    // Nominal 250, 125, 63, 31.5, 16, 8 mm, at the limit plus an offset.
    let offsets = [(6, 6.0), (9, -6.0), (12, 3.0), (15, -3.0), (18, 0.0), (21, 10.0)];
    let tones: Vec<Tone> = offsets
        .iter()
        .map(|&(k, off)| Tone {
            k,
            level_db: en15610::iso3095_limit_db(en15610::nominal_wavelength_mm(k)).unwrap() + off,
        })
        .collect();
    let length_m = 12.0;
    let rail: Vec<f64> = (0..(length_m * 2000.0) as usize).map(|i| rail_um(&tones, i as f64 * 0.5)).collect();
    let linear = runs::Settings { remove_spikes: false, curvature: false, ..runs::Settings::default() };
    for (settings, interval) in [(runs::Settings::default(), false), (linear, true)] {
        let opts = settings.options().roughness;
        let alone = en15610::analyze(&rail, 0.5, &opts).unwrap().spectrum;
        for (n, sigma) in [0.5, 3.0, 8.0].into_iter().enumerate() {
            let a = analyse_with(length_m, [sigma; 3], &tones, 10 + n as u64, &settings);
            for (what, s) in spectra(&a) {
                for (t, &(_, off)) in tones.iter().zip(&offsets) {
                    let b = s.bands.iter().find(|b| b.k == t.k).unwrap();
                    let truth = alone.bands.iter().find(|b| b.k == t.k).unwrap().level_db;
                    let d = b.decision().unwrap();
                    let at = format!(
                        "{what}, σ {sigma} µm, {} mm at {off:+} dB ({truth:.2} dB; linear {interval}): {d:?}",
                        b.nominal_wavelength_mm
                    );
                    if off >= 3.0 {
                        assert_ne!(d.verdict, Verdict::Within, "{at}");
                    }
                    if off <= -3.0 {
                        assert_ne!(d.verdict, Verdict::Exceeds, "{at}");
                    }
                    if interval {
                        assert!(d.rail.lo_db.is_none_or(|lo| lo <= truth), "{at}");
                        assert!(d.rail.hi_db.is_none_or(|hi| hi >= truth), "{at}");
                    }
                }
            }
        }
    }
}
