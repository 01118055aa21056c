//! Sine fits against profiles of known parameters, and the profile CSV.

use super::*;

fn synth(lambda: f64, amp: f64, phase: f64, c: f64, theta: f64, n: usize, dx: f64) -> (Vec<f64>, Vec<f64>) {
    // Exact rotated sine, points taken along x' then rotated back.
    let w = std::f64::consts::TAU / lambda;
    let (si, co) = theta.sin_cos();
    (0..n)
        .map(|i| {
            let xr = 10.0 + dx * i as f64;
            let zr = amp * (w * xr + phase).sin() + c;
            (xr * co - zr * si, xr * si + zr * co)
        })
        .unzip()
}

#[test]
fn three_param_is_exact_on_a_noiseless_sine() {
    let x: Vec<f64> = (0..50).map(|i| i as f64 * 0.3).collect();
    let z: Vec<f64> = x.iter().map(|x| 2.0 * (0.7 * x).sin() - 0.5 * (0.7 * x).cos() + 1.0).collect();
    let l = three_param(&x, &z, 0.7).unwrap();
    assert!((l.sin - 2.0).abs() < 1e-12 && (l.cos + 0.5).abs() < 1e-12 && (l.offset - 1.0).abs() < 1e-12);
    assert!(l.rss < 1e-20);
}

#[test]
fn start_estimates_are_close_on_a_rotated_profile() {
    let (x, z) = synth(50.0, 0.1, 0.3, 0.0, 0.02, 300, 1.0);
    let w = std::f64::consts::TAU / 50.0;
    let dft = dft_omega(&x, &z).unwrap();
    assert!((dft / w - 1.0).abs() < 0.02, "dft {dft} vs {w}");
    let ell = ellipse_omega(&x, &z, dft).unwrap();
    assert!((ell / w - 1.0).abs() < 0.02, "ellipse {ell} vs {w}");
    // The scan on a trend would fit the trend: on the level profile.
    let (x, z) = synth(50.0, 0.1, 0.3, 0.0, 0.0, 300, 1.0);
    let (scan, _) = scan_omega(&x, &z, 0.01, 3.0).unwrap();
    assert!((scan / w - 1.0).abs() < 0.01, "scan {scan} vs {w}");
}

/// A short wavelength in a long record: its minimum of `S(ω)` is
/// 2π/span wide, under a twentieth of the 4 096-step grid the scan once
/// had for 20 000 points up to the Nyquist limit; every bin finds it,
/// on evenly and unevenly spaced points alike.
#[test]
fn the_scan_resolves_a_short_wavelength_in_a_long_record() {
    let w = std::f64::consts::TAU / 0.537;
    for jitter in [0.0, 0.3] {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let x: Vec<f64> = (0..20_000).map(|i| 0.01 * (i as f64 + jitter * next())).collect();
        let z: Vec<f64> = x.iter().map(|&x| 0.02 * (w * x + 0.4).sin() + 0.001 * next()).collect();
        let band = (std::f64::consts::PI / 200.0, std::f64::consts::PI * 19_999.0 / 200.0);
        let (scan, _) = scan_omega(&x, &z, band.0, band.1).unwrap();
        assert!((scan / w - 1.0).abs() < 1e-4, "jitter {jitter}: scan {scan} vs {w}");
    }
}

#[test]
fn jacquelin_is_close_on_a_sampled_sine() {
    // 50 points per period, uniform; step 2 removes most of step 1's
    // integration bias.
    let x: Vec<f64> = (0..300).map(|i| 3.0 + i as f64).collect();
    let w = std::f64::consts::TAU / 50.0;
    let z: Vec<f64> = x.iter().map(|x| 0.1 * (w * x + 0.4).sin() + 2.0).collect();
    let j = jacquelin(&x, &z).unwrap();
    assert!((j.omega / w - 1.0).abs() < 1e-3, "{j:?}");
    assert!((j.linear.offset - 2.0).abs() < 1e-3 && (j.linear.sin.hypot(j.linear.cos) - 0.1).abs() < 1e-3);
    // No oscillation: a straight line gives none or an error, never a panic.
    let line: Vec<f64> = x.iter().map(|x| 0.5 * x).collect();
    if let Some(j) = jacquelin(&x, &line) {
        assert!(j.omega.is_finite());
    }
    assert!(jacquelin(&x[..4], &z[..4]).is_none());
}

#[test]
fn rotated_fit_is_exact_on_exact_data() {
    let (x, z) = synth(100.0, 0.08, 1.0, 0.5, 0.05, 350, 0.9);
    let f = fit(&x, &z, &Options::default()).unwrap();
    assert!(f.converged);
    assert!((f.wavelength_mm - 100.0).abs() < 1e-8, "{f:?}");
    assert!((f.amplitude_mm - 0.08).abs() < 1e-10, "{f:?}");
    assert!((f.rotation_rad - 0.05).abs() < 1e-10, "{f:?}");
    assert!((f.offset_mm - 0.5).abs() < 1e-9, "{f:?}");
    assert!((f.phase_rad - 1.0).abs() < 1e-7, "{f:?}");
}

#[test]
fn two_components() {
    let x: Vec<f64> = (0..400).map(|i| i as f64).collect();
    let tau = std::f64::consts::TAU;
    let z: Vec<f64> =
        x.iter().map(|x| 0.1 * (tau * x / 50.0).sin() + 0.04 * (tau * x / 130.0 + 0.4).cos() + 0.01 * x).collect();
    let f = fit(&x, &z, &Options { model: Model::Rotated, components: 2 }).unwrap();
    assert!(f.converged);
    // 50 mm along x is 50·(cosθ + 0.01·sinθ) ≈ 50.0025 mm along the
    // rotated axis: a slope is a shear, not a rotation.
    assert!((f.components[0].wavelength_mm - 50.0025).abs() < 1e-3, "{f:?}");
    assert!((f.components[1].wavelength_mm - 130.0).abs() < 1e-2, "{f:?}");
    // A plain slope is only approximately a rotation: the exact model
    // still has to fit it to the noise-free level.
    assert!(f.rms_residual_mm < 1e-3, "{f:?}");
}

#[test]
fn parser() {
    let p = parse_profile("x_mm,z_mm\r\n1, 2\n\n# c\n3,4.5\n").unwrap();
    assert_eq!(p.x_mm, [1.0, 3.0]);
    assert_eq!(p.z_mm, [2.0, 4.5]);
    assert_eq!(
        parse_profile("1,2\n3,x\n"),
        Err(FitError::Line { line: 2, reason: "`x` is not a finite number".into() })
    );
    assert!(matches!(parse_profile("1,2,3"), Err(FitError::Line { line: 1, .. })));
    assert!(matches!(parse_profile("1,2\nx_mm,z_mm"), Err(FitError::Line { line: 2, .. })));
    assert!(matches!(parse_profile("1,inf"), Err(FitError::Line { line: 1, .. })));
}
