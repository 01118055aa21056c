//! A survey from runs: chainage (track position as `km+m`), and recordings
//! of one survey joined into one profile per line.
//!
//! # Chainage
//!
//! Users locate rail by chainage — kilometres and metres along the line,
//! written `12+345.678` — not by an odometer that starts at zero. A run is
//! placed by its [`Placement`]: the chainage of its track position 0 (the
//! odometer's zero) and whether chainage runs up or down with it
//! ([`Heading`]). Every output position is chainage, in mm inside the
//! library (`x0_mm`) and as `km+m` or metres in what users read.
//!
//! # Joining runs
//!
//! Runs of one survey overlap (a trolley run stopped and restarted, a run
//! driven back over the last metres), and their nominal placements are
//! rarely exact: an odometer that crept, a start entered a few metres off,
//! a run entered as driven the wrong way. So each run after the first is
//! *registered* on what is joined so far:
//!
//! 1. Both headings (or the one given) are tried. For each, the run's
//!    profiles, turned round for a down run, are cross-correlated with the
//!    joined ones — masked, normalised, summed over the lines, on the
//!    band 2.5·dx–500 mm (the long-wave trend of a run is its own
//!    registration error, not the rail) — by FFT over every shift that
//!    leaves at least [`JoinOptions::min_overlap_mm`] of overlap, within
//!    [`JoinOptions::search_mm`] of the nominal start when one is given.
//! 2. The best shift is refined to a fraction of a sample: the RMS of run
//!    minus joined over the overlap, each line's offset and tilt removed,
//!    at the best whole shift and its neighbours; the parabola's minimum.
//! 3. The run is interpolated (linearly) at that shift, each line's offset
//!    and tilt over the overlap is subtracted, and the run is merged
//!    (overlapping samples averaged). The registration's residual, its
//!    shift from the nominal start and the heading chosen are reported
//!    ([`RunJoin`]); a run that overlaps nothing is placed where its
//!    placement says and the hole is a gap.
//!
//! Repetitive corrugation makes a correlation peak every wavelength; the
//! broadband roughness every real rail has, the ends of a corrugated zone
//! and the long overlap decide between them, and a second peak within 1 %
//! of the best is reported as an ambiguous registration.
//!
//! Cost: per run four FFT correlations per line and heading of the joined
//! length (`O(N log N)`), then `O(overlap)` per refinement step.

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

use super::profile;
use super::stitch::{Direction, Stitched, Stitching};
use crate::analyze::standards::en13231;

pub use crate::recording::survey_info::{Chainage, Heading, Placement};

/// Options of [`join`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JoinOptions {
    /// Shortest overlap that registers a run, mm.
    pub min_overlap_mm: f64,
    /// With a nominal start: how far from it the registration searches, mm.
    pub search_mm: f64,
}

impl Default for JoinOptions {
    fn default() -> Self {
        JoinOptions { min_overlap_mm: 2_000.0, search_mm: 25_000.0 }
    }
}

/// How one run was placed.
#[derive(Debug, Clone, PartialEq)]
pub struct RunJoin {
    pub run: usize,
    pub heading: Heading,
    /// Chainage of the run's track position 0, m, as used.
    pub start_m: f64,
    /// Used minus nominal start, mm (`None` without a nominal start).
    pub moved_mm: Option<f64>,
    /// Whether the heading was found by registration rather than given.
    pub heading_found: bool,
    /// The overlap it was registered on, mm (0: placed as given, not registered).
    pub overlap_mm: f64,
    /// RMS of run minus joined over the overlap after the correction, µm (mean over the lines).
    pub residual_um: Option<f64>,
    /// The correlation's best peak and the best peak at least a quarter of
    /// the search away from it (1 is perfect agreement).
    pub correlation: Option<(f64, f64)>,
}

impl RunJoin {
    /// Whether another placement matched nearly as well.
    pub fn ambiguous(&self) -> bool {
        self.correlation.is_some_and(|(best, second)| second > 0.99 * best)
    }
}

/// A run's lines, turned into chainage orientation: (line, x0 chainage mm
/// when its start is 0, values).
fn oriented(s: &Stitched, heading: Heading) -> (f64, Vec<f64>) {
    match heading {
        Heading::Up => (s.x0_mm, s.z_um.clone()),
        Heading::Down => {
            let last = s.x0_mm + (s.z_um.len() as f64 - 1.0) * s.dx_mm;
            (-last, s.z_um.iter().rev().copied().collect())
        }
    }
}

/// One line of the joined survey: sample `i` at chainage `(base + i)·dx` mm.
#[derive(Debug, Clone)]
struct JoinedLine {
    line: usize,
    base: i64,
    z: Vec<f64>,
    n: Vec<u32>,
}

impl JoinedLine {
    fn at(&self, i: i64) -> Option<f64> {
        let j = usize::try_from(i - self.base).ok()?;
        let (&s, &n) = (self.z.get(j)?, self.n.get(j)?);
        (n > 0).then(|| s / f64::from(n))
    }

    /// Adds `v` (chainage index `lo + j`); NaN adds nothing.
    fn add(&mut self, lo: i64, v: &[f64]) {
        let hi = lo + v.len() as i64;
        if self.z.is_empty() {
            self.base = lo;
        }
        let new_base = self.base.min(lo);
        let new_end = (self.base + self.z.len() as i64).max(hi);
        if new_base < self.base {
            let pad = (self.base - new_base) as usize;
            self.z.splice(0..0, std::iter::repeat_n(0.0, pad));
            self.n.splice(0..0, std::iter::repeat_n(0, pad));
            self.base = new_base;
        }
        let len = (new_end - self.base) as usize;
        self.z.resize(len, 0.0);
        self.n.resize(len, 0);
        for (j, x) in v.iter().enumerate() {
            if x.is_finite() {
                let k = (lo + j as i64 - self.base) as usize;
                self.z[k] += x;
                self.n[k] += 1;
            }
        }
    }

    fn values(&self) -> Vec<f64> {
        self.z.iter().zip(&self.n).map(|(&s, &n)| if n > 0 { s / f64::from(n) } else { f64::NAN }).collect()
    }
}

/// `v` sampled at `i + frac` (0 ≤ frac < 1), linearly; NaN where a neighbour is missing.
fn shifted(v: &[f64], frac: f64) -> Vec<f64> {
    if frac.abs() < 1e-9 {
        return v.to_vec();
    }
    (0..v.len()).map(|i| if i + 1 < v.len() { v[i] + frac * (v[i + 1] - v[i]) } else { f64::NAN }).collect()
}

/// Offset and tilt of `d(x)` by least squares: `(xm, a, b)` for `a + b (x − xm)`.
fn line_fit(pts: &[(f64, f64)]) -> (f64, f64, f64) {
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
fn differences(lines: &[JoinedLine], run: &[(usize, Vec<f64>)], lo: i64) -> Vec<Vec<(f64, f64)>> {
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
fn residual(diffs: &[Vec<(f64, f64)>]) -> Option<(f64, usize)> {
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
fn correlate(pairs: &[(Vec<f64>, Vec<f64>)]) -> Vec<(f64, f64)> {
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

/// Why runs could not be joined.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum JoinError {
    /// The runs were stitched at different spacings.
    #[error("run {run} is sampled every {dx_mm} mm, the first every {first_mm} mm")]
    Spacing { run: usize, dx_mm: f64, first_mm: f64 },
    /// A run overlaps nothing and has no start chainage.
    #[error(
        "run {run} overlaps no earlier run by {min_mm:.0} mm or more: give its start chainage (--chainage KM+M[:up|:down])"
    )]
    NoOverlap { run: usize, min_mm: f64 },
}

/// A run's position `x` (mm) on the line: chainage mm.
fn to_chainage(start_mm: f64, heading: Heading, x_mm: f64) -> f64 {
    match heading {
        Heading::Up => start_mm + x_mm,
        Heading::Down => start_mm - x_mm,
    }
}

/// A run's lines turned to `h`: (line, grid index of sample 0 when the
/// run's start is 0, values).
fn on_grid(run: &Stitching, h: Heading, g0: f64, dx: f64) -> Vec<(usize, i64, Vec<f64>)> {
    run.lasers
        .iter()
        .map(|l| {
            let (x0, v) = oriented(l, h);
            (l.laser, ((x0 - g0) / dx).round() as i64, v)
        })
        .collect()
}

/// The best placement of one run against the joined lines, for each of
/// `headings`: (correlation, heading, whole start index `lo`, best other
/// peak). `e` is the run's grid offset (fraction of a sample), `nominal`
/// the given start as a grid index.
fn search(
    joined: &[JoinedLine],
    run: &Stitching,
    headings: &[Heading],
    grid: (f64, f64),
    nominal: Option<f64>,
    opts: &JoinOptions,
) -> Option<(f64, Heading, i64, f64)> {
    let (g0, dx) = grid;
    let jlo = joined.iter().map(|l| l.base).min()?;
    let jhi = joined.iter().map(|l| l.base + l.z.len() as i64).max()?;
    let mut best: Option<(f64, Heading, i64, f64)> = None;
    for &h in headings {
        let lines = on_grid(run, h, g0, dx);
        let rx0 = lines.iter().map(|l| l.1).min()?;
        let rlen = lines.iter().map(|l| (l.1 - rx0) as usize + l.2.len()).max()?;
        let mut pairs = Vec::new();
        for (k, o, v) in &lines {
            let Some(j) = joined.iter().find(|j| j.line == *k) else { continue };
            let mut a = vec![f64::NAN; rlen];
            let off = (o - rx0) as usize;
            a[off..off + v.len()].copy_from_slice(&detrended(v, dx));
            let mut b = vec![f64::NAN; (jhi - jlo) as usize];
            let jo = (j.base - jlo) as usize;
            b[jo..jo + j.z.len()].copy_from_slice(&detrended(&j.values(), dx));
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
        if best.is_none_or(|b| ncc[t0].0 > b.0) {
            best = Some((ncc[t0].0, h, start(t0), second));
        }
    }
    best
}

/// Joins the runs' stitchings into one, on chainage: run 0 is placed as
/// its placement says (chainage 0 and up by default), each later one
/// registered on the runs before it (see the module docs). Lines are
/// matched by number. A single run placed at 0 and up is returned as it is.
pub fn join(
    runs: Vec<Stitching>,
    placements: &[Placement],
    opts: &JoinOptions,
) -> Result<(Stitching, Vec<RunJoin>), JoinError> {
    let Some(first) = runs.iter().flat_map(|r| r.lasers.first()).next() else {
        return Ok((Stitching { direction: Direction::Forward, auto_residuals_um: None, lasers: Vec::new() }, vec![]));
    };
    let dx = first.dx_mm;
    let p0 = placements.first().copied().unwrap_or_default();
    let (start0_mm, heading0) = (p0.start_m.unwrap_or(0.0) * 1000.0, p0.heading.unwrap_or(Heading::Up));
    // The grid: run 0's samples exactly on it.
    let g0 = (start0_mm + oriented(first, heading0).0).rem_euclid(dx);
    let mut joined: Vec<JoinedLine> = Vec::new();
    // Per line: frames, points, fits and joins of every run, on chainage.
    let mut meta: Vec<(usize, Stitched)> = Vec::new();
    let mut report = Vec::new();
    let (direction, auto_residuals_um) = (runs[0].direction, runs[0].auto_residuals_um);
    for (r, run) in runs.into_iter().enumerate() {
        if let Some(l) = run.lasers.iter().find(|l| (l.dx_mm - dx).abs() > 1e-9 * dx) {
            return Err(JoinError::Spacing { run: r, dx_mm: l.dx_mm, first_mm: dx });
        }
        let Some(any) = run.lasers.first() else { continue };
        let place = placements.get(r).copied().unwrap_or_default();
        let headings: Vec<Heading> = match (place.heading, r) {
            (Some(h), _) => vec![h],
            (None, 0) => vec![Heading::Up],
            (None, _) => vec![Heading::Up, Heading::Down],
        };
        // The run's lines lie a fraction `e(h)` of a sample off the grid.
        let e = |h: Heading| {
            let q = (oriented(any, h).0 - g0) / dx;
            q - q.round()
        };
        let nominal = |h: Heading| place.start_m.map(|m| m * 1000.0 / dx + e(h));
        let found = if r > 0 && !joined.is_empty() {
            // A nominal start applies to the heading it was given with; searched
            // headings share it.
            let n = place.start_m.map(|_| nominal(headings[0]));
            search(&joined, &run, &headings, (g0, dx), n.flatten(), opts)
        } else {
            None
        };
        let (heading, lo, frac, correlation) = match found {
            Some((c, h, lo, second)) => {
                let lines = on_grid(&run, h, g0, dx);
                let at = |d: i64| {
                    let per: Vec<Vec<(f64, f64)>> = lines
                        .iter()
                        .flat_map(|(k, o, v)| differences(&joined, &[(*k, v.clone())], lo + d + o))
                        .collect();
                    residual(&per).map(|r| r.0)
                };
                let frac = match (at(-1), at(0), at(1)) {
                    (Some(a), Some(b), Some(c)) => {
                        let (a, b, c) = (a * a, b * b, c * c);
                        let den = a - 2.0 * b + c;
                        if den > 0.0 { (0.5 * (a - c) / den).clamp(-0.5, 0.5) } else { 0.0 }
                    }
                    _ => 0.0,
                };
                // A negative fraction is the previous sample's positive one.
                let (lo, frac) = if frac < 0.0 { (lo - 1, 1.0 + frac) } else { (lo, frac) };
                (h, lo, frac, Some((c, second)))
            }
            None => {
                if r > 0 && !joined.is_empty() && place.start_m.is_none() {
                    return Err(JoinError::NoOverlap { run: r, min_mm: opts.min_overlap_mm });
                }
                let h = place.heading.unwrap_or(Heading::Up);
                let s = nominal(h).unwrap_or(e(h));
                let lo = s.round();
                // Run 0 is on the grid by construction; a placed run may not be.
                let frac = if (s - lo).abs() < 1e-6 { 0.0 } else { s - s.floor() };
                let lo = if frac == 0.0 { lo } else { s.floor() };
                (h, lo as i64, frac, None)
            }
        };
        let start_mm = (lo as f64 + frac - e(heading)) * dx;
        let (residual_sum, overlap_samples) =
            merge_run(&mut joined, &mut meta, &run, (heading, lo, frac, start_mm), (g0, dx));
        report.push(RunJoin {
            run: r,
            heading,
            start_m: start_mm / 1000.0,
            moved_mm: place.start_m.map(|m| start_mm - m * 1000.0),
            heading_found: place.heading.is_none() && r > 0,
            overlap_mm: overlap_samples as f64 * dx,
            residual_um: (residual_sum.1 > 0).then(|| residual_sum.0 / residual_sum.1 as f64),
            correlation,
        });
    }
    let lasers = joined_lines(joined, meta, g0, dx);
    Ok((Stitching { direction, auto_residuals_um, lasers }, report))
}

/// Merges one run's lines into the joined ones at grid index `lo` + `frac`
/// (`start_mm` its chainage, `heading` its direction): each line
/// interpolated at the fraction, offset and tilt removed over the overlap;
/// its frames, fits and joins kept on chainage in `meta`. Returns the sum
/// and count of the overlaps' residuals, and the longest overlap, samples.
fn merge_run(
    joined: &mut Vec<JoinedLine>,
    meta: &mut Vec<(usize, Stitched)>,
    run: &Stitching,
    (heading, lo, frac, start_mm): (Heading, i64, f64, f64),
    (g0, dx): (f64, f64),
) -> ((f64, usize), usize) {
    let mut residual_sum = (0.0, 0usize);
    let mut overlap_samples = 0usize;
    for l in &run.lasers {
        let (x0, v) = oriented(l, heading);
        let o = ((x0 - g0) / dx).round() as i64;
        // The run's sample j sits at grid index lo + frac + o + j: the grid
        // point lo + o + j takes the run `frac` of a sample earlier.
        let mut v = if frac > 0.0 {
            let mut w = vec![f64::NAN];
            w.extend(shifted(&v, 1.0 - frac).iter().take(v.len() - 1).copied());
            w
        } else {
            v
        };
        let at = lo + o;
        if let Some(j) = joined.iter().find(|j| j.line == l.laser) {
            let d = differences(std::slice::from_ref(j), &[(l.laser, v.clone())], at).remove(0);
            if d.len() >= 3 {
                let (xm, a, b) = line_fit(&d);
                let rss: f64 = d.iter().map(|&(x, y)| (y - a - b * (x - xm)).powi(2)).sum();
                residual_sum.0 += (rss / d.len() as f64).sqrt();
                residual_sum.1 += 1;
                overlap_samples = overlap_samples.max(d.len());
                for (jj, x) in v.iter_mut().enumerate() {
                    *x -= a + b * ((at + jj as i64) as f64 - xm);
                }
            }
        }
        match joined.iter_mut().find(|j| j.line == l.laser) {
            Some(j) => j.add(at, &v),
            None => {
                let mut j = JoinedLine { line: l.laser, base: 0, z: Vec::new(), n: Vec::new() };
                j.add(at, &v);
                joined.push(j);
            }
        }
        let m = match meta.iter_mut().find(|m| m.0 == l.laser) {
            Some(m) => m,
            None => {
                meta.push((l.laser, profile::stitched(l.laser, 0.0, dx, Vec::new())));
                meta.last_mut().expect("just pushed")
            }
        };
        m.1.frames += l.frames;
        m.1.fits.extend(
            l.fits
                .iter()
                .map(|f| super::stitch::FrameFit { centre_mm: to_chainage(start_mm, heading, f.centre_mm), ..*f }),
        );
        m.1.joins.extend(
            l.joins.iter().map(|j| super::stitch::Join { at_mm: to_chainage(start_mm, heading, j.at_mm), ..*j }),
        );
        m.1.points += l.points;
    }
    (residual_sum, overlap_samples)
}

/// The joined lines as stitched profiles on chainage, their ends without
/// data trimmed, with their runs' frames, fits and joins.
fn joined_lines(mut joined: Vec<JoinedLine>, mut meta: Vec<(usize, Stitched)>, g0: f64, dx: f64) -> Vec<Stitched> {
    joined.sort_by_key(|l| l.line);
    joined
        .into_iter()
        .map(|l| {
            let z = l.values();
            // Trim the ends without data.
            let first = z.iter().position(|v| v.is_finite()).unwrap_or(0);
            let last = z.iter().rposition(|v| v.is_finite()).map_or(0, |i| i + 1);
            let z = z[first..last.max(first)].to_vec();
            let mut s = profile::stitched(l.line, g0 + (l.base + first as i64) as f64 * dx, dx, z);
            if let Some((_, m)) = meta.iter_mut().find(|m| m.0 == l.line) {
                s.frames = m.frames;
                s.points = m.points;
                s.fits = std::mem::take(&mut m.fits);
                s.joins = std::mem::take(&mut m.joins);
            }
            s
        })
        .collect()
}
