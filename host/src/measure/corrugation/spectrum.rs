//! The lines' joint periodogram: starts for the joint fit that do not
//! depend on any one line finding the wave alone.
//!
//! Each line's own start (`fit`'s sine on what a quartic detrend leaves)
//! fails in two ways the joint fit cannot recover from. A quartic along a
//! short frame takes most of a long wave (a 50 mm wave over a 68.6 mm
//! frame is 1.4 periods, which a quartic nearly is), and under speckle a
//! point's height error (60–115 µm RMS) is several times a small
//! corrugation's amplitude, so one line's highest peak is often noise
//! (seen at 1–3 mm: the scale of a speckle plus the travel in the
//! exposure). Here every line is detrended by a straight line only, and
//! the power a sine at ω takes from each line is summed over the lines:
//! the lines share the wave, not its phase (their lateral offsets and the
//! yaw shift it), so powers add where amplitudes would not, and three
//! lines see the wave with three times one line's power. The highest
//! local maxima over the wavelengths the verdict trusts
//! ([`verdict::MIN_WAVELENGTH_MM`] to twice the frame) are further starts;
//! the lowest residual still wins.

use nalgebra::{Matrix4, Vector4};

use super::surface::Surface;
use crate::measure::verdict;

/// How many of the periodogram's highest peaks become starts.
pub(super) const PEAKS: usize = 3;

/// Grid points per Fourier bin (`2π/span`): a quarter bin between points
/// keeps a peak's interpolated position within the basin of the
/// refinement.
const OVERSAMPLE: f64 = 4.0;

/// The periodogram's grid step, rad/mm, over a frame of `span_mm`.
pub(super) fn step(span_mm: f64) -> f64 {
    std::f64::consts::TAU / (OVERSAMPLE * span_mm)
}

/// The ω of the [`PEAKS`] highest local maxima of the joint periodogram of
/// `s`'s lines (module docs), highest first; empty when the frame is
/// shorter than the shortest wavelength trusted.
pub(super) fn periodogram_starts(s: &Surface) -> Vec<f64> {
    let nl = s.line.iter().copied().max().map_or(0, |m| m + 1);
    let lines: Vec<(Vec<f64>, Vec<f64>)> = (0..nl)
        .map(|l| {
            let idx = (0..s.x.len()).filter(|&k| s.line[k] == l);
            idx.map(|k| (s.x[k], s.z[k])).unzip()
        })
        .filter(|(x, _): &(Vec<f64>, Vec<f64>)| x.len() >= 8)
        .collect();
    let (lo, hi) = s.x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    let span = hi - lo;
    if span.is_nan() || span <= verdict::MIN_WAVELENGTH_MM {
        return Vec::new();
    }
    let d = step(span);
    let (w_lo, w_hi) = (std::f64::consts::TAU / (2.0 * span), std::f64::consts::TAU / verdict::MIN_WAVELENGTH_MM);
    let grid: Vec<f64> = (0..).map(|i| w_lo + d * i as f64).take_while(|w| *w <= w_hi).collect();
    let power: Vec<f64> = grid.iter().map(|&w| lines.iter().map(|(x, z)| sine_power(x, z, w)).sum()).collect();
    let mut peaks: Vec<(f64, f64)> = (1..grid.len().saturating_sub(1))
        .filter(|&i| power[i] > power[i - 1] && power[i] >= power[i + 1])
        .map(|i| {
            // The parabola through the peak and its neighbours.
            let (a, b, c) = (power[i - 1], power[i], power[i + 1]);
            let den = a - 2.0 * b + c;
            let shift = if den < 0.0 { (0.5 * (a - c) / den).clamp(-0.5, 0.5) } else { 0.0 };
            (grid[i] + shift * d, b)
        })
        .filter(|(w, p)| w.is_finite() && p.is_finite())
        .collect();
    peaks.sort_by(|a, b| b.1.total_cmp(&a.1));
    peaks.into_iter().take(PEAKS).map(|p| p.0).collect()
}

/// The residual sum a sine at `omega` removes from `z` over `x` beyond a
/// straight line: `rss([1, x]) − rss([1, x, sin ωx, cos ωx])`.
fn sine_power(x: &[f64], z: &[f64], omega: f64) -> f64 {
    let mut ata = Matrix4::zeros();
    let mut atb = Vector4::zeros();
    for (&x, &z) in x.iter().zip(z) {
        let (sn, cs) = (omega * x).sin_cos();
        let row = Vector4::new(1.0, x, sn, cs);
        ata += row * row.transpose();
        atb += row * z;
    }
    // The straight line alone, from the same sums.
    let (n, sx, sxx, sz, sxz) = (ata[(0, 0)], ata[(0, 1)], ata[(1, 1)], atb[0], atb[1]);
    let det = n * sxx - sx * sx;
    if det.abs() <= 0.0 || !det.is_finite() {
        return 0.0;
    }
    let (c0, c1) = ((sxx * sz - sx * sxz) / det, (n * sxz - sx * sz) / det);
    let line = c0 * sz + c1 * sxz;
    match ata.cholesky() {
        Some(ch) => {
            let sol = ch.solve(&atb);
            (sol.dot(&atb) - line).max(0.0)
        }
        None => 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn surface(lines: &[(f64, f64)], f: impl Fn(usize, f64) -> f64) -> Surface {
        let mut s =
            Surface { normal: [0.0, 0.0, 1.0], pitch: 0.0, roll: 0.0, x: vec![], y: vec![], z: vec![], line: vec![] };
        for (l, &(y, _)) in lines.iter().enumerate() {
            for i in 0..480 {
                let x = -34.3 + 0.144 * i as f64;
                s.x.push(x);
                s.y.push(y);
                s.z.push(f(l, x));
                s.line.push(l);
            }
        }
        s
    }

    /// A 50 mm wave over 68.6 mm under noise three times its amplitude
    /// (deterministic, not white: a sum of short waves standing for
    /// speckle), on a slope: the highest peak is the wave, within a
    /// quarter of a Fourier bin.
    #[test]
    fn the_highest_peak_is_the_shared_wave() {
        let lines = [(-15.0, 0.3), (0.0, 1.1), (15.0, 2.0)];
        let s = surface(&lines, |l, x| {
            let ph = lines[l].1;
            let noise = 0.17 * (2.1 * x + 7.0 * ph).sin() * (5.3 * x + ph).cos() + 0.1 * (3.7 * x * x + ph).sin();
            0.002 * x + 0.08 * (std::f64::consts::TAU * x / 50.0 + ph).sin() + noise
        });
        let starts = periodogram_starts(&s);
        assert_eq!(starts.len(), PEAKS);
        let w = std::f64::consts::TAU / 50.0;
        assert!((starts[0] - w).abs() < step(68.6), "{starts:?} against {w}");
    }

    #[test]
    fn a_short_frame_gives_no_start() {
        let mut s = surface(&[(0.0, 0.0)], |_, x| (x * 0.5).sin());
        s.x.iter_mut().for_each(|x| *x *= 0.1);
        assert!(periodogram_starts(&s).is_empty());
    }
}
