//! Rail-standard analysis (`cms_host::analyze::standards`): the EN 15610 check value
//! of docs/reference.md §2, spike removal, curvature processing, the
//! EN 13231-3 band split and peak-to-peak criteria, short-record errors, and
//! no panic on any finite profile.

use std::f64::consts::PI;

use cms_host::analyze::standards::{StandardsError, en13231, en15610, segments};
use proptest::prelude::*;

/// `amp_um · sin(2π x / wavelength + phase)` sampled every `dx_mm` over `len_mm`.
fn sine(len_mm: f64, dx_mm: f64, wavelength_mm: f64, amp_um: f64, phase: f64) -> Vec<f64> {
    let n = (len_mm / dx_mm).round() as usize;
    (0..n).map(|i| amp_um * (2.0 * PI * i as f64 * dx_mm / wavelength_mm + phase).sin()).collect()
}

fn band(a: &en13231::BandAnalysis, lo_mm: f64) -> &en13231::BandStats {
    let b = a.bands.iter().find(|b| b.band.lo_mm == lo_mm).expect("band");
    b.outcome.as_ref().expect("band evaluated")
}

/// Notes §2: a 3 µm-amplitude sine at 1 cm wavelength reads 10·lg 4.5 =
/// 6.53 dB in the 1 cm band (the spectrum's check value: without the
/// wheel, which on this sine (curvature 0.44/R) moves the band by −0.30 dB
/// at 1 mm sampling and −0.22 dB at 0.1 mm).
#[test]
fn en15610_check_value_3um_at_1cm_is_6_53_db() {
    let expected = 10.0 * 4.5f64.log10();
    for (dx_mm, phase) in [(1.0, 0.0), (0.5, 0.7), (0.1, 2.0)] {
        let z = sine(5000.0, dx_mm, 10.0, 3.0, phase);
        let wheel = en15610::analyze(&z, dx_mm, &en15610::Options::default()).unwrap();
        let b = wheel.spectrum.bands.iter().find(|b| b.nominal_wavelength_mm == 10.0).unwrap();
        println!("dx {dx_mm} mm, with the wheel: 10 mm band {:.4} dB", b.level_db);
        assert!((b.level_db - expected).abs() < 0.4, "{} dB", b.level_db);
        let opts = en15610::Options { curvature: false, ..en15610::Options::default() };
        let r = en15610::analyze(&z, dx_mm, &opts).unwrap();
        assert_eq!(r.spikes_removed, 0);
        let b = r.spectrum.bands.iter().find(|b| b.nominal_wavelength_mm == 10.0).unwrap();
        println!("dx {dx_mm} mm: 10 mm band {:.4} dB (expected {expected:.4})", b.level_db);
        assert!((b.level_db - expected).abs() < 0.1, "{} dB", b.level_db);
        assert_eq!(b.iso3095_limit_db, Some(-8.0));
        assert_eq!(b.verdict(), Some(cms_host::analyze::standards::detection::Verdict::Exceeds));
        // Its neighbours hold only the Hann window's far side lobes.
        for nb in r.spectrum.bands.iter().filter(|b| b.nominal_wavelength_mm == 8.0 || b.nominal_wavelength_mm == 12.5)
        {
            assert!(nb.level_db < expected - 40.0, "{} mm band {} dB", nb.nominal_wavelength_mm, nb.level_db);
        }
    }
}

#[test]
fn en15610_bands_are_base_ten_third_octaves_up_to_a_quarter_segment() {
    let z = sine(3000.0, 1.0, 40.0, 1.0, 0.0);
    let s = en15610::third_octave_spectrum(&z, 1.0, 1000.0).unwrap();
    assert_eq!(s.segments, 5, "3 m in 1 m segments with 50 % overlap");
    let first = s.bands.first().unwrap();
    let last = s.bands.last().unwrap();
    assert_eq!(first.nominal_wavelength_mm, 250.0, "longest: a quarter of 1 m");
    assert_eq!(last.nominal_wavelength_mm, 2.5, "shortest: upper band edge below Nyquist (2 mm)");
    for b in &s.bands {
        assert!((b.centre_per_m - 10f64.powf(b.k as f64 / 10.0)).abs() < 1e-9);
        assert!((b.wavelength_mm * b.centre_per_m - 1000.0).abs() < 1e-9);
        assert!((b.nominal_wavelength_mm / b.wavelength_mm - 1.0).abs() < 0.02);
    }
    let csv = en15610::spectrum_csv(&s);
    assert!(csv.starts_with("k,centre_per_m,wavelength_mm,nominal_wavelength_mm,level_db,iso3095_limit_db"));
    assert_eq!(csv.lines().count(), s.bands.len() + 1);
    assert!(csv.contains(",40,"), "{csv}");
}

#[test]
fn spike_removal_removes_an_injected_spike_and_leaves_a_sine_alone() {
    let dx_mm = 0.5;
    let clean = sine(2000.0, dx_mm, 10.0, 3.0, 0.3);
    let mut smooth = clean.clone();
    assert_eq!(en15610::remove_spikes(&mut smooth, dx_mm), 0);
    assert_eq!(smooth, clean);

    let mut z = clean.clone();
    z[1000] += 20.0; // one sample, 20 µm
    z[2001] += 8.0; // two samples wide
    z[2002] += 9.0;
    let n = en15610::remove_spikes(&mut z, dx_mm);
    assert_eq!(n, 2);
    let worst = z.iter().zip(&clean).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    println!("after spike removal: largest difference from the clean sine {worst:.4} µm");
    // Linear interpolation over ≤ 2 mm of a 3 µm, 10 mm sine.
    assert!(worst < 1.0, "{worst}");

    // A small bump whose second derivative stays above the threshold is not a spike.
    let mut gentle = vec![0.0; 100];
    gentle[50] = 0.2; // d2 = -0.4 µm / (0.5 mm)^2 = -1.6e6 µm/m², above the threshold
    assert_eq!(en15610::remove_spikes(&mut gentle, dx_mm), 0);
}

/// The wheel centre's path over a smooth profile is, to second order in
/// the slope, the profile raised by `R·z′²/(2(1 − R·z″))` (the wheel
/// touches `R·z′/(1 − R·z″)` beside the sample); derivatives here by
/// central differences.
fn raised_by_the_wheel(z: &[f64], dx_mm: f64) -> Vec<f64> {
    let r_um = en15610::WHEEL_RADIUS_MM * 1000.0;
    let dx_um = dx_mm * 1000.0;
    (1..z.len() - 1)
        .map(|i| {
            let slope = (z[i + 1] - z[i - 1]) / (2.0 * dx_um);
            let curv = (z[i + 1] - 2.0 * z[i] + z[i - 1]) / (dx_um * dx_um);
            z[i] + r_um * slope * slope / (2.0 * (1.0 - r_um * curv))
        })
        .collect()
}

#[test]
fn curvature_processing_is_the_wheel_centres_path_and_bridges_a_narrow_dip() {
    let dx_mm = 0.1;
    let z = sine(1000.0, dx_mm, 200.0, 20.0, 0.0);
    // A slope too: the wheel's contact moves with it.
    let z: Vec<f64> = z.iter().enumerate().map(|(i, v)| v + 2.0 * i as f64 * dx_mm).collect();
    let c = en15610::curvature_process(&z, dx_mm, en15610::WHEEL_RADIUS_MM);
    let want = raised_by_the_wheel(&z, dx_mm);
    // Away from the ends, where the wheel would rest on the rail beyond the
    // record (`want` starts at sample 1).
    let inner = 200..z.len() - 200;
    let worst = c[inner.clone()].iter().zip(&want[199..]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    let lift = c[inner.clone()].iter().zip(&z[inner.clone()]).map(|(a, b)| a - b).fold(0.0, f64::max);
    println!(
        "curvature: 200 mm, 20 µm sine on a 2 mm/m slope raised by up to {lift:.3} µm, {worst:.2e} µm from R·z′²/2"
    );
    assert!(lift > 0.5 && worst < 0.01, "{lift} {worst}");
    // A 10 mm, 3 µm sine (curvature 1.2 /m < 1/R = 2.7 /m) at 0.1 mm sampling:
    // its second harmonic, R·z′²/2 = 0.33 µm at 5 mm, is what the wheel adds.
    let z = sine(1000.0, dx_mm, 10.0, 3.0, 0.2);
    let c = en15610::curvature_process(&z, dx_mm, en15610::WHEEL_RADIUS_MM);
    let want = raised_by_the_wheel(&z, dx_mm);
    let worst = c[inner].iter().zip(&want[199..]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    println!("curvature: 10 mm, 3 µm sine at 0.1 mm sampling: {worst:.2e} µm from R·z′²/2");
    // R·z″ reaches 0.44 on this sine: the third-order terms are ~7 % of the 0.67 µm lift.
    assert!(worst < 0.1, "{worst}");
    assert!(c.iter().zip(&z).all(|(c, z)| c - z > -1e-9), "the wheel never goes below the rail");

    // A 2 mm wide, 50 µm deep dip in a flat rail.
    let mut d = vec![0.0; 2000];
    for v in &mut d[1000..1020] {
        *v = -50.0;
    }
    let c = en15610::curvature_process(&d, dx_mm, en15610::WHEEL_RADIUS_MM);
    let bottom = c.iter().copied().fold(f64::INFINITY, f64::min);
    // The wheel's sagitta over a half-width of 1 mm: 1²/(2·375) mm = 1.33 µm.
    println!("curvature: 2 mm × 50 µm dip seen {bottom:.3} µm deep");
    assert!(bottom > -1.5 && bottom < -1.0, "{bottom}");
    assert_eq!(c[..990], d[..990]);
}

#[test]
fn band_filter_puts_a_50_mm_sine_in_30_100_mm() {
    let dx_mm = 1.0;
    let amp_um = 15.0;
    // 9 m: the 300–1000 mm band needs its 5 m window and 2 m edge zones.
    let z = sine(9500.0, dx_mm, 50.0, amp_um, 0.4);
    let a = en13231::analyze(&z, dx_mm).unwrap();
    let pp = |lo| band(&a, lo).worst_max_pp_mm * 1000.0 / (2.0 * amp_um);
    let (b10, b30, b100, b300) = (pp(10.0), pp(30.0), pp(100.0), pp(300.0));
    println!(
        "50 mm sine, worst window max-min / true p-p: 10–30 {b10:.5}, 30–100 {b30:.5}, 100–300 {b100:.5}, 300–1000 {b300:.5}"
    );
    assert!((0.99..1.01).contains(&b30), "{b30}");
    assert!(b10 < 0.01, "{b10}");
    assert!(b100 < 0.01, "{b100}");
    assert!(b300 < 0.01, "{b300}");
    // Without the edge zones the ends would count: the filter cannot know how the rail goes on.
    let (_, traces) = en13231::analyze_traced(&z, dx_mm).unwrap();
    let y = &traces[2].as_ref().unwrap().band_mm;
    let near_end = y[..300].iter().fold(0.0f64, |m, v| m.max(v.abs())) * 1000.0 / amp_um;
    println!("50 mm sine in 100–300 mm within 300 mm of the start: {near_end:.3} of its amplitude");
}

#[test]
fn band_edges_are_minus_3_db_and_a_sine_in_the_middle_passes() {
    // At 30 mm the 10–30 and 30–100 bands each keep 1/√2 of the amplitude.
    let z = sine(4000.0, 0.5, 30.0, 10.0, 0.0);
    for (lo, hi) in [(10.0, 30.0), (30.0, 100.0)] {
        let y = en13231::band_pass(&z, 0.5, lo, hi).unwrap();
        let rms = (y[2000..6000].iter().map(|v| v * v).sum::<f64>() / 4000.0).sqrt();
        let gain = rms * 2f64.sqrt() / 10.0;
        println!("30 mm sine in {lo}–{hi} mm: gain {gain:.4}");
        assert!((gain - 0.5f64.sqrt()).abs() < 0.01, "{gain}");
    }
}

#[test]
fn peak_to_peak_of_a_0_015_mm_50_mm_sine_is_0_030_mm_and_exceeds_everywhere() {
    let z = sine(3000.0, 0.5, 50.0, 15.0, 0.0);
    let (a, traces) = en13231::analyze_traced(&z, 0.5).unwrap();
    let b = band(&a, 30.0);
    println!(
        "0.015 mm, 50 mm sine: mean p-p {:.5} mm (worst {:.5}), {} windows, {:.1} % exceeding",
        b.average_mean_pp_mm, b.worst_mean_pp_mm, b.windows, b.exceeding_percent
    );
    assert!((b.average_mean_pp_mm - 0.030).abs() < 0.0003, "{}", b.average_mean_pp_mm);
    assert_eq!(b.exceeding_percent, 100.0);
    assert!(!b.passes);
    // 2012 Class 1 (±0.010 mm): the sine is beyond it over 2/π·acos(10/15)… of its length.
    let expected = 100.0 * (1.0 - 2.0 / PI * (10.0f64 / 15.0).asin());
    let got = b.abs_exceeding_percent.unwrap();
    assert!((got - expected).abs() < 2.0, "{got} vs {expected}");
    // The windows: one per sample where a whole 600 mm window fits between the edge zones.
    assert_eq!(b.windows, 6000 - 2 * 400 - 1200 + 1, "600 mm windows between 200 mm edge zones");
    assert_eq!(traces[1].as_ref().unwrap().mean_pp_mm.iter().filter(|v| v.is_finite()).count(), b.windows);
    // Other bands quiet and passing.
    assert!(band(&a, 10.0).passes && band(&a, 100.0).passes);
    let table = en13231::band_table(&a);
    println!("{table}");
    assert!(table.contains("30-100"), "{table}");
    assert!(table.contains("NO"), "{table}");
    assert!(table.contains("record 3000 mm is too short for the 5000 mm window of the 300–1000 mm band (plus 2000 mm of filter settling at each end)"), "{table}");
    let csv = en13231::bands_csv(&a, &traces);
    assert_eq!(csv.lines().count(), 6001);
    assert!(csv.starts_with("x_mm,band_10_30_mm,band_30_100_mm,band_100_300_mm,band_300_1000_mm\n"));
}

#[test]
fn short_records_are_clear_errors() {
    let z = sine(450.0, 1.0, 50.0, 10.0, 0.0);
    let a = en13231::analyze(&z, 1.0).unwrap();
    assert_eq!(a.record_mm, 450.0);
    for b in &a.bands {
        let e = b.outcome.as_ref().unwrap_err();
        assert!(matches!(e, StandardsError::TooShort { .. }));
    }
    assert_eq!(
        a.bands[0].outcome.as_ref().unwrap_err().to_string(),
        "record 450 mm is too short for the 600 mm window of the 10–30 mm band (plus 60 mm of filter settling at each end)"
    );
    let e = en15610::analyze(&z, 1.0, &en15610::Options::default()).unwrap_err();
    assert_eq!(
        e.to_string(),
        "record 450 mm is too short for the 1000 mm window of the EN 15610 roughness spectrum (segments of at least 1 m)"
    );
    // Gaps: two 800 mm runs are not one 1600 mm record.
    let mut z = sine(1600.0, 1.0, 50.0, 10.0, 0.0);
    z[800] = f64::NAN;
    assert_eq!(segments(&z).len(), 2);
    assert!(matches!(en15610::analyze(&z, 1.0, &Default::default()), Err(StandardsError::TooShort { .. })));
    let (a, traces) = en13231::analyze_traced(&z, 1.0).unwrap();
    assert_eq!(a.runs, 2);
    assert!(traces[0].as_ref().unwrap().band_mm[800].is_nan());
    assert!(matches!(a.bands[1].outcome, Err(StandardsError::TooShort { .. })), "30–100 needs 1000 mm");
    assert!(band(&a, 10.0).windows > 0);
    // Sampling.
    assert!(matches!(en15610::analyze(&z, 2.0, &Default::default()), Err(StandardsError::SamplingTooCoarse { .. })));
    assert!(matches!(en13231::analyze(&z, 0.0), Err(StandardsError::BadSampling { .. })));
    assert!(matches!(en13231::analyze(&[f64::NAN; 4], 1.0), Err(StandardsError::NoData)));
    let a = en13231::analyze(&vec![0.0; 2000], 6.0).unwrap();
    assert!(matches!(a.bands[0].outcome, Err(StandardsError::SamplingTooCoarse { .. })));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Any finite profile (with gaps) and any finite spacing: results or errors, never a panic.
    #[test]
    fn arbitrary_finite_profiles_never_panic(
        z in prop::collection::vec(prop_oneof![
            8 => -1e6f64..1e6,
            1 => prop::num::f64::NORMAL | prop::num::f64::SUBNORMAL | prop::num::f64::ZERO,
            1 => Just(f64::NAN),
        ], 0..1500),
        dx_mm in prop_oneof![0.05f64..3.0, prop::num::f64::ANY.prop_filter("finite", |v| v.is_finite())],
    ) {
        let _ = en13231::analyze_traced(&z, dx_mm).map(|(a, t)| (en13231::band_table(&a), en13231::bands_csv(&a, &t)));
        let opt = en15610::Options { segment_mm: 1000.0, ..Default::default() };
        if let Ok(r) = en15610::analyze(&z, dx_mm, &opt) {
            let _ = en15610::spectrum_csv(&r.spectrum);
            let _ = en15610::spectrum_table(&r);
        }
        let mut y = z.clone();
        en15610::remove_spikes(&mut y, dx_mm);
        let _ = en15610::curvature_process(&z, dx_mm, 375.0);
    }
}

/// The band filter against scipy's `butter` + `sosfiltfilt` of the same design
/// (`tests/scripts/standards_reference.py`), away from the ends where the two
/// pad differently.
#[test]
fn band_filter_matches_scipy_in_the_interior() {
    let text = include_str!("../data/standards/band_30_100.csv");
    let (mut z, mut reference) = (Vec::new(), Vec::new());
    for line in text.lines().filter(|l| !l.starts_with('#') && !l.starts_with('x')) {
        let f: Vec<&str> = line.split(',').collect();
        z.push(f[1].parse::<f64>().unwrap());
        reference.push(f[2].parse::<f64>().ok());
    }
    let y = en13231::band_pass(&z, 1.0, 30.0, 100.0).unwrap();
    let mut worst = 0.0f64;
    let mut compared = 0;
    for (got, want) in y.iter().zip(&reference) {
        if let Some(want) = want {
            worst = worst.max((got - want).abs());
            compared += 1;
        }
    }
    println!("30–100 mm band vs scipy over {compared} samples: largest difference {worst:.2e} µm");
    assert_eq!(compared, 1000);
    assert!(worst < 1e-5, "{worst}");
}
