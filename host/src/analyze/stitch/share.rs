//! The stitch's own share of the noise: the joint registration's errors
//! ([`super::solve`]'s replicas) laid on the track as the profile lays its
//! frames — on each line each cell the mean of the errors of the frames
//! that cover it, weighted by their points as the cells are, then the
//! lines' mean, as the running band's profile takes it — and pushed
//! through the EN 13231-3 band filters, in stretches (a stretch's margins
//! let the filters settle, as the analysis's pieces do), so memory stays a
//! stretch's whatever the track's length.

use std::collections::BTreeMap;

use cms_core::protocol::LASERS;

use super::solve::{Committed, REPLICAS};
use crate::analyze::standards::en13231;

/// Samples a stretch's core holds, in band margins (the filters run over
/// `CORE_MARGINS + 2` margins for every `CORE_MARGINS` kept).
const CORE_MARGINS: usize = 4;

/// The stitch's share per EN 13231-3 band: sums over every replica's
/// band-filtered error, mergeable over runs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StitchShare {
    /// Per band ([`en13231::BANDS`] order): sum of squares, mm², and samples.
    pub sums: [(f64, usize); 4],
}

impl StitchShare {
    /// The RMS of the stitch's error in band `b`, mm (`None`: not measured).
    pub fn rms_mm(&self, b: usize) -> Option<f64> {
        let (sq, n) = self.sums.get(b).copied()?;
        (n > 0).then(|| (sq / n as f64).sqrt())
    }

    /// Adds another run's sums.
    pub fn merge(&mut self, o: &StitchShare) {
        for (a, b) in self.sums.iter_mut().zip(&o.sums) {
            a.0 += b.0;
            a.1 += b.1;
        }
    }
}

/// Builds the error profiles from committed frames and sums their bands.
#[derive(Debug)]
pub struct ShareBuilder {
    dx_mm: f64,
    /// Cells still open: per line, per replica the weighted sum of errors, and the weight.
    open: BTreeMap<i64, [([f64; REPLICAS], f64); LASERS]>,
    /// Closed samples not yet summed, per replica, in closing order (NaN: a gap).
    buf: [Vec<f64>; REPLICAS],
    /// Samples of `buf` already summed (the left margin).
    done: usize,
    last: Option<i64>,
    margin: usize,
    pub share: StitchShare,
}

impl ShareBuilder {
    pub fn new(dx_mm: f64) -> ShareBuilder {
        ShareBuilder {
            dx_mm,
            open: BTreeMap::new(),
            buf: Default::default(),
            done: 0,
            last: None,
            margin: (en13231::margin_mm() / dx_mm).ceil() as usize,
            share: StitchShare::default(),
        }
    }

    /// Lays a committed frame's errors on its cells; closes the cells it
    /// does not cover (every frame that covers them is committed: frames
    /// are committed in the order they came).
    pub fn add(&mut self, f: &Committed) {
        let (mut lo, mut hi) = (i64::MAX, i64::MIN);
        for (k, line) in f.cells.iter().enumerate() {
            for &(c, _, n) in line {
                let w = n as f64;
                let x = c as f64 * self.dx_mm - f.centre_mm;
                let cell = &mut self.open.entry(c).or_insert([([0.0; REPLICAS], 0.0); LASERS])[k];
                for (s, e) in cell.0.iter_mut().zip(&f.errors) {
                    *s += w * (e.0 + e.1 * x);
                }
                cell.1 += w;
                lo = lo.min(c);
                hi = hi.max(c);
            }
        }
        if lo <= hi {
            self.close(Some((lo, hi)));
        }
    }

    /// Closes every cell and sums what is left.
    pub fn finish(mut self) -> StitchShare {
        self.close(None);
        self.sum(self.buf[0].len());
        self.share
    }

    fn close(&mut self, keep: Option<(i64, i64)>) {
        let keys: Vec<i64> = match keep {
            Some((lo, hi)) => {
                self.open.range(..lo).map(|(&c, _)| c).chain(self.open.range(hi + 1..).rev().map(|(&c, _)| c)).collect()
            }
            None => self.open.keys().copied().collect(),
        };
        for c in keys {
            let Some(lines) = self.open.remove(&c) else { continue };
            let seen: Vec<&([f64; REPLICAS], f64)> = lines.iter().filter(|l| l.1 > 0.0).collect();
            let k = seen.len() as f64;
            let mean: [f64; REPLICAS] = std::array::from_fn(|r| seen.iter().map(|l| l.0[r] / l.1).sum::<f64>() / k);
            // A sample not next to the last one starts a new run.
            if self.last.is_some_and(|l| (c - l).abs() != 1) {
                self.buf.iter_mut().for_each(|b| b.push(f64::NAN));
            }
            self.last = Some(c);
            for (b, v) in self.buf.iter_mut().zip(mean) {
                b.push(v);
            }
        }
        if self.buf[0].len() >= self.done + (CORE_MARGINS + 1) * self.margin {
            self.sum(self.done + CORE_MARGINS * self.margin);
        }
    }

    /// Sums the band-filtered samples `done..to` of the buffer, then keeps
    /// a margin before `to`.
    fn sum(&mut self, to: usize) {
        for (b, band) in en13231::BANDS.iter().enumerate() {
            for z in &self.buf {
                let Ok(f) = en13231::band_pass(z, self.dx_mm, band.lo_mm, band.hi_mm) else { continue };
                for v in f[self.done..to].iter().filter(|v| v.is_finite()) {
                    self.share.sums[b].0 += (v / 1000.0).powi(2);
                    self.share.sums[b].1 += 1;
                }
            }
        }
        let drop = to.saturating_sub(self.margin);
        self.buf.iter_mut().for_each(|b| {
            b.drain(..drop);
        });
        self.done = to - drop;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(lo: i64, len: i64, errors: [(f64, f64); REPLICAS]) -> Committed {
        Committed {
            seq: 0,
            centre_mm: (lo + len / 2) as f64,
            cells: std::array::from_fn(|_| (lo..lo + len).map(|c| (c, 0.0, 5)).collect()),
            correction: (0.0, 0.0),
            errors,
            overlap_mm: [0.0; LASERS],
            registered: true,
            inv_var: [1.0; LASERS],
        }
    }

    /// Errors that alternate ±e frame to frame over frames 100 mm apart
    /// make a 200 mm square wave: it reads in 100–300 mm at about its RMS
    /// (its fundamental: 0.9 of it), little in 10–30 mm; in stretches
    /// as in one go.
    #[test]
    fn an_alternating_error_reads_in_its_band_the_same_in_stretches() {
        let run = |margin: Option<usize>| {
            let mut s = ShareBuilder::new(1.0);
            if let Some(m) = margin {
                s.margin = m;
            }
            for i in 0..600 {
                let e = if i % 2 == 0 { 0.001 } else { -0.001 };
                s.add(&frame(i * 100, 100, [(e * 1000.0, 0.0); REPLICAS]));
            }
            s.finish()
        };
        let whole = run(Some(1_000_000));
        // 8 m: eight of the longest band's wavelengths, transients down by e⁻¹³.
        let pieces = run(Some(8_000));
        let r = whole.rms_mm(2).unwrap() / 0.001;
        assert!((0.8..1.0).contains(&r), "{r}");
        assert!(whole.rms_mm(0).unwrap() < 0.3 * whole.rms_mm(2).unwrap(), "{whole:?}");
        for b in 0..4 {
            let (a, p) = (whole.rms_mm(b).unwrap(), pieces.rms_mm(b).unwrap());
            assert!((a / p - 1.0).abs() < 1e-3, "band {b}: {a} vs {p}");
            assert_eq!(whole.sums[b].1, pieces.sums[b].1);
        }
    }
}
