//! Registration of a run on a section: the masked normalised
//! cross-correlation that finds its shift and heading, and the residual
//! that refines the shift and judges the overlap.

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

use super::section::JoinedLine;
use super::{Heading, JoinOptions, oriented};
use crate::analyze::standards::en13231;
use crate::analyze::stitch::Stitching;

/// Offset and tilt of `d(x)` by least squares: `(xm, a, b)` for `a + b (x − xm)`.
pub(super) fn line_fit(pts: &[(f64, f64)]) -> (f64, f64, f64) {
    let n = pts.len() as f64;
    let xm = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let dm = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let (mut sxx, mut sxd) = (0.0, 0.0);
    for &(x, d) in pts {
        sxx += (x - xm) * (x - xm);
        sxd += (x - xm) * (d - dm);
    }
    (xm, dm, if sxx > 0.0 { sxd / sxx } else { 0.0 })
}

/// The run's differences from the joined lines over the overlap when its
/// sample 0 sits at chainage index `lo`: per line, the points (index, run −
/// joined), empty when the line does not overlap.
pub(super) fn differences(lines: &[JoinedLine], run: &[(usize, Vec<f64>)], lo: i64) -> Vec<Vec<(f64, f64)>> {
    run.iter()
        .map(|(k, v)| {
            let Some(l) = lines.iter().find(|l| l.line == *k) else { return Vec::new() };
            v.iter()
                .enumerate()
                .filter_map(|(j, x)| {
                    let i = lo + j as i64;
                    let y = l.at(i)?;
                    x.is_finite().then(|| (i as f64, x - y))
                })
                .collect()
        })
        .collect()
}

/// Mean over the overlapping lines of the RMS after offset and tilt, and
/// the overlap's length in samples (of the longest line's).
pub(super) fn residual(diffs: &[Vec<(f64, f64)>]) -> Option<(f64, usize)> {
    let mut sum = 0.0;
    let mut lines = 0;
    let mut overlap = 0;
    for d in diffs.iter().filter(|d| d.len() >= 3) {
        let (xm, a, b) = line_fit(d);
        let rss: f64 = d.iter().map(|&(x, v)| (v - a - b * (x - xm)).powi(2)).sum();
        sum += (rss / d.len() as f64).sqrt();
        lines += 1;
        overlap = overlap.max(d.len());
    }
    (lines > 0).then(|| (sum / lines as f64, overlap))
}

/// Masked normalised cross-correlation of `a` (the run) against `b` (the
/// joined), summed over line pairs: for every shift `d` (run sample `j` at
/// joined sample `j + d`), `(ncc, overlap samples)`, `d` from
/// `−(len a − 1)` to `len b − 1`.
pub(super) fn correlate(pairs: &[(Vec<f64>, Vec<f64>)]) -> Vec<(f64, f64)> {
    let (la, lb) = (pairs[0].0.len(), pairs[0].1.len());
    let n = (la + lb).next_power_of_two();
    let mut planner = FftPlanner::<f64>::new();
    let fwd = planner.plan_fft_forward(n);
    let inv = planner.plan_fft_inverse(n);
    let spectrum = |v: &dyn Fn(usize) -> f64, len: usize, reverse: bool| {
        let mut buf = vec![Complex::new(0.0, 0.0); n];
        for i in 0..len {
            // The run reversed, so that the convolution is the correlation.
            let at = if reverse { len - 1 - i } else { i };
            buf[at] = Complex::new(v(i), 0.0);
        }
        fwd.process(&mut buf);
        buf
    };
    let conv = |x: &[Complex<f64>], y: &[Complex<f64>]| {
        let mut p: Vec<Complex<f64>> = x.iter().zip(y).map(|(a, b)| a * b).collect();
        inv.process(&mut p);
        p.iter().map(|c| c.re / n as f64).collect::<Vec<f64>>()
    };
    let mut num = vec![0.0; la + lb - 1];
    let mut ea = vec![0.0; la + lb - 1];
    let mut eb = vec![0.0; la + lb - 1];
    let mut count = vec![0.0; la + lb - 1];
    for (a, b) in pairs {
        let ma = |i: usize| f64::from(u8::from(a[i].is_finite()));
        let mb = |i: usize| f64::from(u8::from(b[i].is_finite()));
        let va = |i: usize| if a[i].is_finite() { a[i] } else { 0.0 };
        let vb = |i: usize| if b[i].is_finite() { b[i] } else { 0.0 };
        let fa = spectrum(&va, la, true);
        let fa2 = spectrum(&|i| va(i) * va(i), la, true);
        let fma = spectrum(&ma, la, true);
        let fb = spectrum(&vb, lb, false);
        let fb2 = spectrum(&|i| vb(i) * vb(i), lb, false);
        let fmb = spectrum(&mb, lb, false);
        for (acc, v) in [(&mut num, conv(&fa, &fb)), (&mut ea, conv(&fa2, &fmb)), (&mut eb, conv(&fma, &fb2))] {
            acc.iter_mut().zip(&v).for_each(|(s, x)| *s += x);
        }
        count.iter_mut().zip(&conv(&fma, &fmb)).for_each(|(s, x)| *s += x);
    }
    // Index t of the convolution of reversed a with b is shift d = t − (la − 1).
    num.iter()
        .zip(&ea)
        .zip(&eb)
        .zip(&count)
        .map(|(((&c, &x), &y), &m)| {
            let den = (x * y).sqrt();
            (if den > 1e-12 { c / den } else { 0.0 }, m / pairs.len() as f64)
        })
        .collect()
}

/// The high-passed copy a registration correlates: 2.5·dx to 500 mm.
fn detrended(z: &[f64], dx_mm: f64) -> Vec<f64> {
    en13231::band_pass(z, dx_mm, 2.5 * dx_mm, 500.0).unwrap_or_else(|_| z.to_vec())
}

/// A run's lines turned to `h`: (line, grid index of sample 0 when the
/// run's start is 0, values).
pub(super) fn on_grid(run: &Stitching, h: Heading, g0: f64, dx: f64) -> Vec<(usize, i64, Vec<f64>)> {
    run.lasers
        .iter()
        .map(|l| {
            let (x0, v) = oriented(l, h);
            (l.laser, ((x0 - g0) / dx).round() as i64, v)
        })
        .collect()
}

/// One heading's best placement of a run against a section.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Match {
    pub correlation: f64,
    pub heading: Heading,
    /// Whole grid index of the run's start.
    pub lo: i64,
    /// The best peak outside the main lobe.
    pub second: f64,
}

/// The best placement of one run against a section's lines, for each of
/// `headings` that has one. `nominal` is the given start as a grid index:
/// the search stays within [`JoinOptions::search_mm`] of it.
pub(super) fn search(
    joined: &[JoinedLine],
    run: &Stitching,
    headings: &[Heading],
    grid: (f64, f64),
    nominal: Option<f64>,
    opts: &JoinOptions,
) -> Vec<Match> {
    let (g0, dx) = grid;
    let (Some(jlo), Some(jhi)) = (joined.iter().map(|l| l.base).min(), joined.iter().map(JoinedLine::end).max()) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for &h in headings {
        let lines = on_grid(run, h, g0, dx);
        let (Some(rx0), Some(rend)) =
            (lines.iter().map(|l| l.1).min(), lines.iter().map(|l| l.1 + l.2.len() as i64).max())
        else {
            continue;
        };
        let rlen = (rend - rx0) as usize;
        let mut pairs = Vec::new();
        for (k, o, v) in &lines {
            let Some(j) = joined.iter().find(|j| j.line == *k) else { continue };
            let mut a = vec![f64::NAN; rlen];
            let off = (o - rx0) as usize;
            a[off..off + v.len()].copy_from_slice(&detrended(v, dx));
            let mut b = vec![f64::NAN; (jhi - jlo) as usize];
            let jo = (j.base - jlo) as usize;
            let jv = j.values();
            b[jo..jo + jv.len()].copy_from_slice(&detrended(&jv, dx));
            pairs.push((a, b));
        }
        if pairs.is_empty() {
            continue;
        }
        let ncc = correlate(&pairs);
        let min_overlap = opts.min_overlap_mm / dx;
        let window = opts.search_mm / dx;
        // Shift d puts the run's first sample (grid index rx0 when its
        // start is 0) at joined index jlo + d: its start at jlo + d − rx0.
        let start = |t: usize| jlo + (t as i64 - (rlen as i64 - 1)) - rx0;
        let allowed =
            |t: usize| ncc[t].1 >= min_overlap && nominal.is_none_or(|n| (start(t) as f64 - n).abs() <= window);
        let Some(t0) = (0..ncc.len()).filter(|&t| allowed(t)).max_by(|&a, &b| ncc[a].0.total_cmp(&ncc[b].0)) else {
            continue;
        };
        // The best other peak: beyond the main lobe (where the correlation
        // stops falling away from the best).
        let (mut l, mut u) = (t0, t0);
        while l > 0 && ncc[l - 1].0 < ncc[l].0 {
            l -= 1;
        }
        while u + 1 < ncc.len() && ncc[u + 1].0 < ncc[u].0 {
            u += 1;
        }
        let second =
            (0..ncc.len()).filter(|&t| (t < l || t > u) && allowed(t)).map(|t| ncc[t].0).fold(0.0f64, f64::max);
        out.push(Match { correlation: ncc[t0].0, heading: h, lo: start(t0), second });
    }
    out
}
