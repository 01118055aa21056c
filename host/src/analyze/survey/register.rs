//! Registration of a run on a section: the masked normalised
//! cross-correlation that finds its shift and heading, and the residual
//! that refines the shift and judges the overlap.

use std::io;
use std::ops::Range;

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

use super::section::JoinedLine;
use super::{Heading, JoinOptions, origin, read_oriented};
use crate::analyze::standards::en13231;
use crate::analyze::stitch::{Stitched, Stitching};

/// Most of a run a registration correlates, mm: the stretch of the run
/// nearest its start that the shifts searched can lay on the section (see
/// the module docs of [`super`]).
pub(super) const MAX_CORRELATED_MM: f64 = 100_000.0;

/// Mean over the overlapping lines of the RMS after offset and tilt, and
/// the overlap's length in samples (of the longest line's), with the run
/// turned to `h` and its start at grid index `start`.
pub(super) fn residual(
    joined: &[JoinedLine],
    run: &Stitching,
    h: Heading,
    start: i64,
    (g0, dx): (f64, f64),
) -> io::Result<Option<(f64, usize)>> {
    let mut sum = 0.0;
    let mut lines = 0;
    let mut overlap = 0;
    for (l, o) in on_grid(run, h, g0, dx) {
        let Some(j) = joined.iter().find(|j| j.line == l.laser) else { continue };
        let acc = j.overlap_fit(l.z.len(), start + o, |r| read_oriented(l, h, r))?;
        if let Some((_, _, _, rms)) = acc.fit().filter(|_| acc.len() >= 3) {
            sum += rms;
            lines += 1;
            overlap = overlap.max(acc.len());
        }
    }
    Ok((lines > 0).then(|| (sum / lines as f64, overlap)))
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

/// Samples either side of a stretch the band-pass reads as well, so that
/// the stretch is filtered as it is in the whole line (four of the longest
/// wavelength passed).
fn filter_margin(dx_mm: f64) -> i64 {
    (2000.0 / dx_mm).ceil() as i64
}

/// `len` values of grid indices `from..` high-passed, NaN where `read`
/// (values of grid indices `lo..hi` of a line covering `line`) has none.
fn filtered(
    read: impl Fn(Range<i64>) -> io::Result<Vec<f64>>,
    line: Range<i64>,
    from: i64,
    len: usize,
    dx: f64,
) -> io::Result<Vec<f64>> {
    let mut out = vec![f64::NAN; len];
    let m = filter_margin(dx);
    let (lo, hi) = ((from - m).max(line.start), (from + len as i64 + m).min(line.end));
    if hi <= lo {
        return Ok(out);
    }
    let v = detrended(&read(lo..hi)?, dx);
    for (i, x) in v.iter().enumerate() {
        let at = lo + i as i64 - from;
        if (0..len as i64).contains(&at) {
            out[at as usize] = *x;
        }
    }
    Ok(out)
}

/// A run's lines turned to `h`, with the grid index of each one's sample 0
/// when the run's start is 0.
pub(super) fn on_grid(run: &Stitching, h: Heading, g0: f64, dx: f64) -> Vec<(&Stitched, i64)> {
    run.lasers.iter().map(|l| (l, ((origin(l, h) - g0) / dx).round() as i64)).collect()
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
) -> io::Result<Vec<Match>> {
    let (g0, dx) = grid;
    let (Some(jlo), Some(jhi)) = (joined.iter().map(|l| l.base).min(), joined.iter().map(JoinedLine::end).max()) else {
        return Ok(Vec::new());
    };
    let window = opts.search_mm / dx;
    let cap = (MAX_CORRELATED_MM / dx).ceil().max(1.0) as i64;
    let mut out = Vec::new();
    for &h in headings {
        let lines = on_grid(run, h, g0, dx);
        let (Some(rx0), Some(rend)) =
            (lines.iter().map(|l| l.1).min(), lines.iter().map(|l| l.1 + l.0.z.len() as i64).max())
        else {
            continue;
        };
        // The run's grid indices `p..q` (start 0) correlated, on the
        // section's `bl..bh`: with a nominal start, what the shifts allowed
        // can lay on the section; then at most `cap` of it, nearest the start.
        let (mut p, mut q, mut bl, mut bh) = (rx0, rend, jlo, jhi);
        if let Some(n) = nominal {
            let (lo_s, hi_s) = ((n - window).floor() as i64, (n + window).ceil() as i64);
            (p, q) = (p.max(jlo - hi_s), q.min(jhi - lo_s));
        }
        if q - p > cap {
            p = (-cap / 2).clamp(p, q - cap);
            q = p + cap;
        }
        if let Some(n) = nominal {
            let (lo_s, hi_s) = ((n - window).floor() as i64, (n + window).ceil() as i64);
            (bl, bh) = (bl.max(lo_s + p), bh.min(hi_s + q));
        }
        if q <= p || bh <= bl {
            continue;
        }
        let rlen = (q - p) as usize;
        // The section side in chunks (without a start it is the whole
        // section): each chunk overlaps the next by the run's window, so
        // every shift that lays the window whole on the section lies whole
        // in some chunk; a shift hanging over a chunk's inner edge is left
        // to the chunk that holds it (or to none, when it hangs over the
        // section's own end: then the chunk edge is the section's).
        let chunk = (CHUNK_WINDOWS * rlen as i64).max(cap);
        let mut best: Option<(f64, i64, f64)> = None;
        let mut peaks: Vec<(f64, i64, f64)> = Vec::new();
        let mut cl = bl;
        loop {
            let ch = (cl + chunk).min(bh);
            let inner = (cl > bl, ch < bh);
            if let Some(m) = chunk_peak(&lines, joined, h, (p, rlen), (cl, ch), inner, nominal, opts, dx)? {
                if best.is_none_or(|b| m.0 > b.0) {
                    best = Some(m);
                }
                peaks.push(m);
            }
            if ch >= bh {
                break;
            }
            cl = ch - rlen as i64;
        }
        let Some((correlation, lo, _)) = best else { continue };
        // Another chunk's best is another peak, unless it found this one.
        let second = peaks.iter().map(|&(c, l, s)| if l == lo { s } else { c }).fold(0.0f64, f64::max);
        out.push(Match { correlation, heading: h, lo, second });
    }
    Ok(out)
}

/// Section samples correlated at once, in run windows: without a start,
/// a long section is searched in chunks of this many windows (at least
/// [`MAX_CORRELATED_MM`]), so that the correlation's memory is bounded
/// however long the section.
const CHUNK_WINDOWS: i64 = 2;

/// The best placement of the run's window (grid indices `p..p + rlen`
/// with its start at 0) on the section's chunk `cl..ch`: (correlation,
/// start, best other peak), shifts the search allows only. `inner` says
/// which chunk edges are not the section's: a window hanging over one is
/// left to the neighbouring chunk.
#[allow(clippy::too_many_arguments)]
fn chunk_peak(
    lines: &[(&Stitched, i64)],
    joined: &[JoinedLine],
    h: Heading,
    (p, rlen): (i64, usize),
    (cl, ch): (i64, i64),
    inner: (bool, bool),
    nominal: Option<f64>,
    opts: &JoinOptions,
    dx: f64,
) -> io::Result<Option<(f64, i64, f64)>> {
    let min_overlap = opts.min_overlap_mm / dx;
    let window = opts.search_mm / dx;
    let mut pairs = Vec::new();
    for (l, o) in lines {
        let Some(j) = joined.iter().find(|j| j.line == l.laser) else { continue };
        let a = filtered(
            |r| read_oriented(l, h, (r.start - o) as usize..(r.end - o) as usize),
            *o..o + l.z.len() as i64,
            p,
            rlen,
            dx,
        )?;
        let b = filtered(|r| j.values(r), j.base..j.end(), cl, (ch - cl) as usize, dx)?;
        pairs.push((a, b));
    }
    if pairs.is_empty() {
        return Ok(None);
    }
    let ncc = correlate(&pairs);
    // Shift t puts the window's first sample (grid index p when the
    // run's start is 0) at joined index cl + t − (rlen − 1): its start there minus p.
    let at = |t: usize| cl + (t as i64 - (rlen as i64 - 1));
    let start = |t: usize| at(t) - p;
    let whole = |t: usize| (!inner.0 || at(t) >= cl) && (!inner.1 || at(t) + rlen as i64 <= ch);
    let allowed =
        |t: usize| ncc[t].1 >= min_overlap && whole(t) && nominal.is_none_or(|n| (start(t) as f64 - n).abs() <= window);
    let Some(t0) = (0..ncc.len()).filter(|&t| allowed(t)).max_by(|&a, &b| ncc[a].0.total_cmp(&ncc[b].0)) else {
        return Ok(None);
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
    let second = (0..ncc.len()).filter(|&t| (t < l || t > u) && allowed(t)).map(|t| ncc[t].0).fold(0.0f64, f64::max);
    Ok(Some((ncc[t0].0, start(t0), second)))
}

#[cfg(test)]
mod tests {
    use super::super::{JoinOptions, Placement, join};
    use crate::analyze::profile;
    use crate::analyze::stitch::{Direction, Stitching};

    /// Broadband roughness (a smoothed random walk's steps), µm per mm.
    fn rail(n: usize, seed: u64) -> Vec<f64> {
        let mut s = seed;
        let mut white = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let w: Vec<f64> = (0..n + 8).map(|_| white()).collect();
        (0..n).map(|i| 10.0 * w[i..i + 8].iter().sum::<f64>() / 8.0).collect()
    }

    fn run(z: Vec<f64>) -> Stitching {
        let line = profile::stitched(1, 0.0, 1.0, z);
        Stitching {
            direction: Direction::Forward,
            direction_residuals_um: None,
            direction_given: true,
            lasers: vec![line],
            share: None,
        }
    }

    /// A run without a start is found far along a section many times
    /// longer than the chunks the section is correlated in.
    #[test]
    fn a_run_without_a_start_is_found_along_a_long_section() {
        let rail = rail(700_000, 3);
        let second = rail[520_000..580_000].to_vec();
        let runs = vec![run(rail), run(second)];
        let placements = [Placement { start_m: Some(0.0), heading: None }, Placement::default()];
        let (_, joins) = join(runs, &placements, &JoinOptions::default()).unwrap();
        let j = &joins[1];
        let (best, other) = j.correlation.unwrap();
        assert!((j.start_m - 520.0).abs() < 1e-3, "{j:?}");
        assert!(best > 0.99 && other < 0.5, "{j:?}");
    }
}
