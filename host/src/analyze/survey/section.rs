//! The joined survey line as sections: contiguous measured stretches, each
//! dense on the grid. A stretch without data longer than
//! [`super::JoinOptions::section_gap_mm`] is never held in memory: it lies
//! between two sections.

use std::io;
use std::ops::Range;
use std::sync::Mutex;

use super::resample::{LOBES, shifted};
use super::{Heading, read_oriented, to_chainage};
use crate::analyze::stitch::{FrameFit, Join, Stitched, Stitching, gaps_in};
use crate::analyze::store::{Cells, STRETCH, Samples};

/// A least-squares line `d ≈ a + b (x − xm)` fitted as points come
/// (sums about the first point, so that grid indices of millions keep
/// their precision).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct LineAcc {
    n: usize,
    origin: (f64, f64),
    sx: f64,
    sd: f64,
    sxx: f64,
    sxd: f64,
    sdd: f64,
}

impl LineAcc {
    pub fn push(&mut self, x: f64, d: f64) {
        if self.n == 0 {
            self.origin = (x, d);
        }
        let (x, d) = (x - self.origin.0, d - self.origin.1);
        self.n += 1;
        self.sx += x;
        self.sd += d;
        self.sxx += x * x;
        self.sxd += x * d;
        self.sdd += d * d;
    }

    /// Points taken.
    pub fn len(&self) -> usize {
        self.n
    }

    /// `(xm, a, b, rms)`: the line (tilt 0 when the points do not spread)
    /// and the RMS of the points about it.
    pub fn fit(&self) -> Option<(f64, f64, f64, f64)> {
        if self.n == 0 {
            return None;
        }
        let n = self.n as f64;
        let (mx, md) = (self.sx / n, self.sd / n);
        let sxx = self.sxx - self.sx * mx;
        let sxd = self.sxd - self.sx * md;
        let sdd = self.sdd - self.sd * md;
        let b = if sxx > 0.0 { sxd / sxx } else { 0.0 };
        let rss = (sdd - b * sxd).max(0.0);
        Some((self.origin.0 + mx, self.origin.1 + md, b, (rss / n).sqrt()))
    }
}

/// One line of a section: sample `i` at chainage `g0 + i·dx` mm for `i`
/// in `base..end` (sums and counts in a cell store, so that runs average
/// where they overlap).
#[derive(Debug)]
pub(super) struct JoinedLine {
    pub line: usize,
    pub base: i64,
    end: i64,
    /// Behind a lock so that registration reads it through `&self`.
    cells: Mutex<Cells>,
}

impl JoinedLine {
    fn new(line: usize) -> JoinedLine {
        JoinedLine { line, base: 0, end: 0, cells: Mutex::new(Cells::default()) }
    }

    fn cells(&self) -> std::sync::MutexGuard<'_, Cells> {
        self.cells.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Grid index past the last sample.
    pub fn end(&self) -> i64 {
        self.end
    }

    /// The values of grid indices `range` (NaN where nothing was measured,
    /// and outside the line).
    pub fn values(&self, range: Range<i64>) -> io::Result<Vec<f64>> {
        self.cells().values(range)
    }

    /// The line fit of a run's line minus this line over their overlap,
    /// the run's `n` samples (read by `read`, in stretches) from grid index
    /// `at`: points (grid index, run − joined).
    pub fn overlap_fit(
        &self,
        n: usize,
        at: i64,
        read: impl Fn(Range<usize>) -> io::Result<Vec<f64>>,
    ) -> io::Result<LineAcc> {
        let mut acc = LineAcc::default();
        let lo = usize::try_from(self.base - at).unwrap_or(0).min(n);
        let hi = usize::try_from(self.end - at).unwrap_or(0).min(n);
        let mut from = lo;
        while from < hi {
            let to = (from + STRETCH).min(hi);
            let v = read(from..to)?;
            let y = self.values(at + from as i64..at + to as i64)?;
            for (k, (x, y)) in v.iter().zip(&y).enumerate() {
                if x.is_finite() && y.is_finite() {
                    acc.push((at + (from + k) as i64) as f64, x - y);
                }
            }
            from = to;
        }
        Ok(acc)
    }

    /// The harmonic mean, over the samples of `range` with a value, of the
    /// runs averaged in each (a run adds weight 1 to each of its samples):
    /// the factor by which noise independent from run to run falls in
    /// power (1 where nothing was measured).
    fn runs_averaged(&self, range: Range<i64>) -> io::Result<f64> {
        let (mut samples, mut inverse) = (0u64, 0.0);
        self.cells().for_stretch(range, |_, _, w| {
            for &w in w.iter().filter(|&&w| w > 0) {
                samples += 1;
                inverse += 1.0 / f64::from(w);
            }
        })?;
        Ok(if inverse > 0.0 { samples as f64 / inverse } else { 1.0 })
    }

    /// Grows the line to cover grid indices `lo..hi`.
    fn cover(&mut self, lo: i64, hi: i64) {
        if self.base == self.end {
            (self.base, self.end) = (lo, lo);
        }
        self.base = self.base.min(lo);
        self.end = self.end.max(hi);
    }

    /// Adds `v` (grid index `lo + j`); NaN adds nothing.
    fn add(&mut self, lo: i64, v: &[f64]) -> io::Result<()> {
        self.cover(lo, lo + v.len() as i64);
        let cells = self.cells.get_mut().unwrap_or_else(|e| e.into_inner());
        for (j, x) in v.iter().enumerate() {
            if x.is_finite() {
                cells.add(lo + j as i64, *x, 1)?;
            }
        }
        Ok(())
    }

    /// Adds another section's line (its sums and counts), a tile at a time.
    fn absorb(&mut self, other: JoinedLine) -> io::Result<()> {
        if other.base == other.end {
            return Ok(());
        }
        self.cover(other.base, other.end);
        let mine = self.cells.get_mut().unwrap_or_else(|e| e.into_inner());
        let mut theirs = other.cells.into_inner().unwrap_or_else(|e| e.into_inner());
        let mut failed = Ok(());
        theirs.for_stretch(other.base..other.end, |c0, s, w| {
            for (k, (&s, &w)) in s.iter().zip(w).enumerate() {
                if failed.is_ok() {
                    failed = mine.add(c0 + k as i64, s, w);
                }
            }
        })?;
        failed
    }

    /// The first and past the last grid index with a value (`None`: none).
    fn measured(&self) -> io::Result<Option<(i64, i64)>> {
        let mut first = None;
        let mut at = self.base;
        while at < self.end && first.is_none() {
            let hi = (at + STRETCH as i64).min(self.end);
            first = self.values(at..hi)?.iter().position(|v| v.is_finite()).map(|k| at + k as i64);
            at = hi;
        }
        let Some(first) = first else { return Ok(None) };
        let mut at = self.end;
        while at > first {
            let lo = (at - STRETCH as i64).max(first);
            if let Some(k) = self.values(lo..at)?.iter().rposition(|v| v.is_finite()) {
                return Ok(Some((first, lo + k as i64 + 1)));
            }
            at = lo;
        }
        Ok(Some((first, first + 1)))
    }
}

/// Samples `range` of a run's line as merged at a fraction `frac` of a
/// sample (see [`Section::merge_run`]): turned to `heading`, then, with a
/// fraction, sample `j` is the line resampled at `j − frac` by the
/// windowed sinc (the first is NaN). Reads the range and the kernel's
/// margin only.
pub(super) fn placed(l: &Stitched, heading: Heading, frac: f64, range: Range<usize>) -> io::Result<Vec<f64>> {
    let n = l.z.len();
    let (a, b) = (range.start.min(n), range.end.min(n));
    if frac <= 0.0 {
        return read_oriented(l, heading, a..b);
    }
    // Output j is the shifted sample j − 1, whose kernel reads samples
    // j − LOBES ..= j + LOBES − 1: within a − LOBES .. b + LOBES.
    let c0 = a.saturating_sub(LOBES);
    let c1 = (b + LOBES).min(n);
    let sh = shifted(&read_oriented(l, heading, c0..c1)?, 1.0 - frac);
    Ok((a..b).map(|j| if j == 0 { f64::NAN } else { sh[j - 1 - c0] }).collect())
}

/// A contiguous stretch of the survey line: its lines, the frames, points,
/// fits and joins of the runs on it (per line, on chainage), and those
/// runs (indices in input order).
#[derive(Debug, Default)]
pub(super) struct Section {
    pub lines: Vec<JoinedLine>,
    meta: Vec<(usize, Stitched)>,
    pub runs: Vec<usize>,
}

impl Section {
    /// Grid indices `lo..hi` its lines cover.
    pub fn span(&self) -> Option<(i64, i64)> {
        let lo = self.lines.iter().map(|l| l.base).min()?;
        let hi = self.lines.iter().map(JoinedLine::end).max()?;
        Some((lo, hi))
    }

    /// Takes in another section (the run just placed bridges them).
    pub fn absorb(&mut self, other: Section) -> io::Result<()> {
        for l in other.lines {
            match self.lines.iter_mut().find(|j| j.line == l.line) {
                Some(j) => j.absorb(l)?,
                None => self.lines.push(l),
            }
        }
        for (k, m) in other.meta {
            let mine = self.meta_of(k, m.dx_mm);
            mine.frames += m.frames;
            mine.points += m.points;
            mine.fits.append(&m.fits, |f| f)?;
            mine.joins.extend(m.joins);
        }
        self.runs.extend(other.runs);
        Ok(())
    }

    fn meta_of(&mut self, line: usize, dx: f64) -> &mut Stitched {
        let at = match self.meta.iter().position(|m| m.0 == line) {
            Some(i) => i,
            None => {
                self.meta.push((line, crate::analyze::profile::stitched(line, 0.0, dx, Vec::new())));
                self.meta.len() - 1
            }
        };
        &mut self.meta[at].1
    }

    /// Merges run `r`'s lines into the section at grid index `lo` + `frac`
    /// (`start_mm` its chainage, `heading` its direction): each line
    /// resampled at the fraction by the windowed sinc ([`placed`]), offset
    /// and tilt removed over the overlap; its frames, fits and joins kept
    /// on chainage. Each line is read twice in stretches (the overlap's
    /// fit, then the merge). Returns the sum and count of the overlaps'
    /// residuals, and the longest overlap, samples.
    pub fn merge_run(
        &mut self,
        r: usize,
        run: &Stitching,
        (heading, lo, frac, start_mm): (Heading, i64, f64, f64),
        (g0, dx): (f64, f64),
    ) -> io::Result<((f64, usize), usize)> {
        let mut residual_sum = (0.0, 0usize);
        let mut overlap_samples = 0usize;
        for l in &run.lasers {
            let o = ((super::origin(l, heading) - g0) / dx).round() as i64;
            // The run's sample j sits at grid index lo + frac + o + j: the grid
            // point lo + o + j takes the run `frac` of a sample earlier.
            let at = lo + o;
            let mut correction = (0.0, 0.0, 0.0);
            if let Some(j) = self.lines.iter().find(|j| j.line == l.laser) {
                let acc = j.overlap_fit(l.z.len(), at, |range| placed(l, heading, frac, range))?;
                if let Some((xm, a, b, rms)) = acc.fit().filter(|_| acc.len() >= 3) {
                    residual_sum.0 += rms;
                    residual_sum.1 += 1;
                    overlap_samples = overlap_samples.max(acc.len());
                    correction = (xm, a, b);
                }
            }
            let k = match self.lines.iter().position(|j| j.line == l.laser) {
                Some(k) => k,
                None => {
                    self.lines.push(JoinedLine::new(l.laser));
                    self.lines.len() - 1
                }
            };
            let (xm, a, b) = correction;
            let mut from = 0;
            while from < l.z.len() {
                let mut v = placed(l, heading, frac, from..from + STRETCH)?;
                for (jj, x) in v.iter_mut().enumerate() {
                    *x -= a + b * ((at + (from + jj) as i64) as f64 - xm);
                }
                self.lines[k].add(at + from as i64, &v)?;
                from += v.len().max(1);
            }
            if l.z.is_empty() {
                self.lines[k].cover(at, at);
            }
            let m = self.meta_of(l.laser, dx);
            m.frames += l.frames;
            m.points += l.points;
            m.fits.append(&l.fits, |f| FrameFit { centre_mm: to_chainage(start_mm, heading, f.centre_mm), ..f })?;
            m.joins.extend(l.joins.iter().map(|j| Join { at_mm: to_chainage(start_mm, heading, j.at_mm), ..*j }));
        }
        self.runs.push(r);
        Ok((residual_sum, overlap_samples))
    }

    /// The section's lines as stitched profiles on chainage (section
    /// `number`), their ends without data trimmed (found by reading
    /// stretches; the cells are handed over, not copied), with their runs'
    /// frames, fits and joins.
    pub fn into_stitched(mut self, number: usize, g0: f64, dx: f64) -> io::Result<Vec<Stitched>> {
        self.lines.sort_by_key(|l| l.line);
        let mut meta = std::mem::take(&mut self.meta);
        let mut out = Vec::with_capacity(self.lines.len());
        for l in self.lines {
            let (first, last) = l.measured()?.unwrap_or((l.base, l.base));
            let x0_mm = g0 + first as f64 * dx;
            let runs_averaged = l.runs_averaged(first..last)?;
            let cells = l.cells.into_inner().unwrap_or_else(|e| e.into_inner());
            let z = Samples::from_cells(cells, first, (last - first) as usize, 0);
            let (gaps, finite) = gaps_in(x0_mm, dx, &z)?;
            let mut s = Stitched {
                laser: l.line,
                section: number,
                x0_mm,
                dx_mm: dx,
                z: z.counted(finite),
                frames: 0,
                points: finite,
                runs_averaged,
                fits: Default::default(),
                joins: Vec::new(),
                gaps,
            };
            if let Some((_, m)) = meta.iter_mut().find(|m| m.0 == l.line) {
                s.frames = m.frames;
                s.points = m.points;
                s.fits = std::mem::take(&mut m.fits);
                s.joins = std::mem::take(&mut m.joins);
            }
            out.push(s);
        }
        Ok(out)
    }
}
