//! The joined survey line as sections: contiguous measured stretches, each
//! dense on the grid. A stretch without data longer than
//! [`super::JoinOptions::section_gap_mm`] is never held in memory: it lies
//! between two sections.

use super::register::{differences, line_fit};
use super::resample::shifted;
use super::{Heading, oriented, to_chainage};
use crate::analyze::profile;
use crate::analyze::stitch::{FrameFit, Join, Stitched, Stitching};

/// One line of a section: sample `i` at chainage `g0 + (base + i)·dx` mm
/// (sums and counts, so that runs average where they overlap).
#[derive(Debug, Clone)]
pub(super) struct JoinedLine {
    pub line: usize,
    pub base: i64,
    z: Vec<f64>,
    n: Vec<u32>,
}

impl JoinedLine {
    fn new(line: usize) -> JoinedLine {
        JoinedLine { line, base: 0, z: Vec::new(), n: Vec::new() }
    }

    /// Grid index past the last sample.
    pub fn end(&self) -> i64 {
        self.base + self.z.len() as i64
    }

    pub fn at(&self, i: i64) -> Option<f64> {
        let j = usize::try_from(i - self.base).ok()?;
        let (&s, &n) = (self.z.get(j)?, self.n.get(j)?);
        (n > 0).then(|| s / f64::from(n))
    }

    /// Grows the line to cover grid indices `lo..hi`.
    fn cover(&mut self, lo: i64, hi: i64) {
        if self.z.is_empty() {
            self.base = lo;
        }
        let new_base = self.base.min(lo);
        let new_end = self.end().max(hi);
        if new_base < self.base {
            let pad = (self.base - new_base) as usize;
            self.z.splice(0..0, std::iter::repeat_n(0.0, pad));
            self.n.splice(0..0, std::iter::repeat_n(0, pad));
            self.base = new_base;
        }
        let len = (new_end - self.base) as usize;
        self.z.resize(len, 0.0);
        self.n.resize(len, 0);
    }

    /// Adds `v` (grid index `lo + j`); NaN adds nothing.
    fn add(&mut self, lo: i64, v: &[f64]) {
        self.cover(lo, lo + v.len() as i64);
        for (j, x) in v.iter().enumerate() {
            if x.is_finite() {
                let k = (lo + j as i64 - self.base) as usize;
                self.z[k] += x;
                self.n[k] += 1;
            }
        }
    }

    /// Adds another section's line (its sums and counts).
    fn absorb(&mut self, other: JoinedLine) {
        if other.z.is_empty() {
            return;
        }
        self.cover(other.base, other.end());
        let off = (other.base - self.base) as usize;
        for (j, (s, n)) in other.z.into_iter().zip(other.n).enumerate() {
            self.z[off + j] += s;
            self.n[off + j] += n;
        }
    }

    pub fn values(&self) -> Vec<f64> {
        self.z.iter().zip(&self.n).map(|(&s, &n)| if n > 0 { s / f64::from(n) } else { f64::NAN }).collect()
    }
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
    pub fn absorb(&mut self, other: Section) {
        for l in other.lines {
            match self.lines.iter_mut().find(|j| j.line == l.line) {
                Some(j) => j.absorb(l),
                None => self.lines.push(l),
            }
        }
        for (k, m) in other.meta {
            let mine = self.meta_of(k, m.dx_mm);
            mine.frames += m.frames;
            mine.points += m.points;
            let _ = mine.fits.append(&m.fits, |f| f);
            mine.joins.extend(m.joins);
        }
        self.runs.extend(other.runs);
    }

    fn meta_of(&mut self, line: usize, dx: f64) -> &mut Stitched {
        let at = match self.meta.iter().position(|m| m.0 == line) {
            Some(i) => i,
            None => {
                self.meta.push((line, profile::stitched(line, 0.0, dx, Vec::new())));
                self.meta.len() - 1
            }
        };
        &mut self.meta[at].1
    }

    /// Merges run `r`'s lines into the section at grid index `lo` + `frac`
    /// (`start_mm` its chainage, `heading` its direction): each line
    /// resampled at the fraction by the windowed sinc ([`shifted`]), offset and tilt removed over the
    /// overlap; its frames, fits and joins kept on chainage. Returns the
    /// sum and count of the overlaps' residuals, and the longest overlap,
    /// samples.
    pub fn merge_run(
        &mut self,
        r: usize,
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
            if let Some(j) = self.lines.iter().find(|j| j.line == l.laser) {
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
            match self.lines.iter_mut().find(|j| j.line == l.laser) {
                Some(j) => j.add(at, &v),
                None => {
                    let mut j = JoinedLine::new(l.laser);
                    j.add(at, &v);
                    self.lines.push(j);
                }
            }
            let m = self.meta_of(l.laser, dx);
            m.frames += l.frames;
            m.points += l.points;
            let _ =
                m.fits.append(&l.fits, |f| FrameFit { centre_mm: to_chainage(start_mm, heading, f.centre_mm), ..f });
            m.joins.extend(l.joins.iter().map(|j| Join { at_mm: to_chainage(start_mm, heading, j.at_mm), ..*j }));
        }
        self.runs.push(r);
        (residual_sum, overlap_samples)
    }

    /// The section's lines as stitched profiles on chainage (section
    /// `number`), their ends without data trimmed, with their runs'
    /// frames, fits and joins.
    pub fn into_stitched(mut self, number: usize, g0: f64, dx: f64) -> Vec<Stitched> {
        self.lines.sort_by_key(|l| l.line);
        let mut meta = std::mem::take(&mut self.meta);
        self.lines
            .into_iter()
            .map(|l| {
                let z = l.values();
                let first = z.iter().position(|v| v.is_finite()).unwrap_or(0);
                let last = z.iter().rposition(|v| v.is_finite()).map_or(0, |i| i + 1);
                let z = z[first..last.max(first)].to_vec();
                let mut s = profile::stitched(l.line, g0 + (l.base + first as i64) as f64 * dx, dx, z);
                s.section = number;
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
}
