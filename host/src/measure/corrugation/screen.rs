//! Points no surface can carry, found before any fit: each point against
//! the median of its neighbours along its line.
//!
//! The joint fit's own rejection (residuals beyond `REJECT_SIGMA` robust σ
//! of a first fit) misses a point that the fit bends to: a stripe taken
//! in the wrong place (a glint, a spurious peak, another line) reads a
//! height millimetres off, and an inclined laser plane also sets that
//! point millimetres across (the height moves the line sideways by `tan
//! α` of it), where the crown's `u³, u⁴` pass through it alone. Under
//! real light one such row in a frame left 0.6 mm RMS of residual and
//! carried the fit. A point's height against the median of the
//! [`HALF_WINDOW`] points either side along its line needs no model:
//! a smooth surface's median over ±1 mm differs from the point by its
//! curvature over that length (under 5 µm for 100 µm at 12 mm), far
//! below [`SCREEN_SIGMA`] × the spread of those differences.

use super::Line;

/// Neighbours either side of a point whose median it is set against: ±1 mm
/// at the reference head's 0.144 mm spacing, and more points than a glint
/// or a ghost spans there (a few rows).
pub const HALF_WINDOW: usize = 7;

/// A point farther from its neighbours' median than this many robust σ
/// (1.4826 × the median of those distances over the line) is left out:
/// far beyond noise (Gaussian noise passes 8σ once in 10¹⁵ points) and
/// still well under a misplaced stripe (millimetres against 0.1 mm of
/// speckle).
pub const SCREEN_SIGMA: f64 = 8.0;

/// Distances under this are never screened, mm (as the joint rejection's
/// floor: on near-exact data the median distance is rounding).
pub const SCREEN_FLOOR_MM: f64 = 1e-3;

/// `lines` without the points no surface can carry (module docs), and how
/// many were left out. A line under `4 HALF_WINDOW` points is kept whole.
pub fn screen(lines: &[Line]) -> (Vec<Line>, usize) {
    let mut dropped = 0;
    let out = lines
        .iter()
        .map(|l| {
            let keep = keep(&l.points);
            dropped += keep.iter().filter(|k| !**k).count();
            Line { laser: l.laser, points: l.points.iter().zip(&keep).filter(|(_, k)| **k).map(|(p, _)| *p).collect() }
        })
        .collect();
    (out, dropped)
}

/// Which of a line's points (`[u, v, h]`, in their order along it) to keep.
fn keep(points: &[[f64; 3]]) -> Vec<bool> {
    let n = points.len();
    if n < 4 * HALF_WINDOW {
        return vec![true; n];
    }
    let mut window = Vec::with_capacity(2 * HALF_WINDOW);
    let d: Vec<f64> = (0..n)
        .map(|i| {
            let (lo, hi) = (i.saturating_sub(HALF_WINDOW), (i + HALF_WINDOW + 1).min(n));
            window.clear();
            window.extend((lo..hi).filter(|&j| j != i).map(|j| points[j][2]));
            let mid = window.len() / 2;
            let (_, m, _) = window.select_nth_unstable_by(mid, f64::total_cmp);
            (points[i][2] - *m).abs()
        })
        .collect();
    let mut sorted = d.clone();
    let mid = sorted.len() / 2;
    let (_, med, _) = sorted.select_nth_unstable_by(mid, f64::total_cmp);
    let limit = (SCREEN_SIGMA * 1.4826 * *med).max(SCREEN_FLOOR_MM);
    // A non-finite height is kept for the fit to name.
    d.iter().map(|v| v.is_nan() || *v <= limit).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 12 mm × 30 µm wave under 0.1 mm of noise-like structure, with one
    /// row read 23 mm high and 16 mm across: that row alone goes.
    #[test]
    fn a_misplaced_stripe_goes_and_nothing_else() {
        let mut pts: Vec<[f64; 3]> = (0..480)
            .map(|i| {
                let u = -34.3 + 0.144 * i as f64;
                let noise = 0.1 * ((7.3 * u).sin() + (13.1 * u + 1.0).cos()) / std::f64::consts::SQRT_2;
                [u, 0.0, 0.03 * (std::f64::consts::TAU * u / 12.0).sin() + noise]
            })
            .collect();
        pts[340] = [pts[340][0], 16.0, 23.6];
        let (out, dropped) = screen(&[Line { laser: 1, points: pts.clone() }]);
        assert_eq!(dropped, 1);
        assert_eq!(out[0].points.len(), 479);
        assert!(out[0].points.iter().all(|p| p[2] < 1.0));
        // Clean: a 100 µm wave at 12 mm with 1 µm of noise keeps every point.
        let clean: Vec<[f64; 3]> = pts
            .iter()
            .enumerate()
            .map(|(i, p)| {
                [p[0], 0.0, 0.1 * (std::f64::consts::TAU * p[0] / 12.0).sin() + 1e-3 * (i as f64 * 2.7).sin()]
            })
            .collect();
        assert_eq!(screen(&[Line { laser: 0, points: clean }]).1, 0);
    }
}
