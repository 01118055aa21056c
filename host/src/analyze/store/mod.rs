//! What a stitched line holds that grows with the track: its samples
//! ([`Samples`]) and its frames' registrations ([`FitLog`]). Everything
//! downstream reads them in stretches, never whole, so that the analysis
//! of a line of any length runs in bounded memory.
//!
//! Both keep a bounded part in memory and the rest in an unlinked
//! temporary file, made only when the memory part overflows: samples in
//! tiles of [`cells::TILE_CELLS`] cells, [`cells::CACHE_TILES`] of them
//! cached (≈ 1 MB a line); fits in a buffer of [`FIT_BUFFER`] records,
//! with what their summaries need (count, sums of squares, histograms of
//! overlap and residual) kept aside.

pub mod cells;
mod fits;

use std::io;
use std::ops::Range;
use std::sync::{Arc, Mutex, MutexGuard};

pub use cells::Cells;
pub use fits::{FIT_BUFFER, FitLog};

/// Samples a reader of a whole line takes at a time (512 KB of `f64`).
pub const STRETCH: usize = 1 << 16;

/// A line's samples along the track (µm; NaN where nothing was measured),
/// read in stretches: a view of `len` cells from lattice index `base` of a
/// cell store (value = sum / weight), shared by its clones.
#[derive(Clone, Default)]
pub struct Samples {
    cells: Arc<Mutex<Cells>>,
    base: i64,
    len: usize,
    finite: usize,
    /// Why the samples could not be stored (reads return it).
    error: Option<Arc<str>>,
}

impl std::fmt::Debug for Samples {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Samples").field("len", &self.len).field("finite", &self.finite).finish()
    }
}

fn lock(cells: &Mutex<Cells>) -> MutexGuard<'_, Cells> {
    // A panic elsewhere while holding the lock leaves whole tiles: the
    // store stays usable.
    cells.lock().unwrap_or_else(|e| e.into_inner())
}

impl Samples {
    /// Samples holding `values`.
    pub fn from_vec(values: Vec<f64>) -> Samples {
        let mut cells = Cells::default();
        let mut finite = 0;
        let mut error = None;
        for (i, v) in values.iter().enumerate() {
            if v.is_finite() {
                finite += 1;
                if let Err(e) = cells.add(i as i64, *v, 1) {
                    error = Some(Arc::from(e.to_string()));
                    break;
                }
            }
        }
        Samples { cells: Arc::new(Mutex::new(cells)), base: 0, len: values.len(), finite, error }
    }

    /// The `len` cells of `cells` from lattice index `base`, `finite` of
    /// them with a weight.
    pub fn from_cells(cells: Cells, base: i64, len: usize, finite: usize) -> Samples {
        Samples { cells: Arc::new(Mutex::new(cells)), base, len, finite, error: None }
    }

    /// The same samples, `finite` of them with a value (counted by the
    /// maker while it read them anyway).
    pub fn counted(mut self, finite: usize) -> Samples {
        self.finite = finite;
        self
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The samples of `range`, clipped to the line.
    pub fn read(&self, range: Range<usize>) -> io::Result<Vec<f64>> {
        if let Some(e) = &self.error {
            return Err(io::Error::other(e.to_string()));
        }
        let end = range.end.min(self.len);
        let start = range.start.min(end);
        lock(&self.cells).values(self.base + start as i64..self.base + end as i64)
    }

    /// Every sample: for lines known to be short (tests, a profile file's
    /// small cases); the analysis reads stretches.
    pub fn to_vec(&self) -> io::Result<Vec<f64>> {
        self.read(0..self.len())
    }

    /// Samples with a value.
    pub fn finite(&self) -> usize {
        self.finite
    }
}

/// A stretch of track no frame covered.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gap {
    /// Track position of the first missing sample, mm.
    pub start_mm: f64,
    /// Length, mm (missing samples × spacing).
    pub length_mm: f64,
}

/// The runs of missing samples of a profile read in stretches, and the
/// samples with a value.
pub fn gaps_in(x0_mm: f64, dx_mm: f64, z: &Samples) -> io::Result<(Vec<Gap>, usize)> {
    let mut out = Vec::new();
    let mut finite = 0;
    // The first missing sample of the run being read.
    let mut open: Option<usize> = None;
    let mut at = 0;
    while at < z.len() {
        let part = z.read(at..at + STRETCH)?;
        for (k, v) in part.iter().enumerate() {
            match (v.is_finite(), open) {
                (true, Some(s)) => {
                    out.push(Gap { start_mm: x0_mm + s as f64 * dx_mm, length_mm: (at + k - s) as f64 * dx_mm });
                    open = None;
                    finite += 1;
                }
                (true, None) => finite += 1,
                (false, None) => open = Some(at + k),
                (false, Some(_)) => {}
            }
        }
        at += part.len().max(1);
    }
    if let Some(s) = open {
        out.push(Gap { start_mm: x0_mm + s as f64 * dx_mm, length_mm: (z.len() - s) as f64 * dx_mm });
    }
    Ok((out, finite))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_read_back_what_they_hold() {
        let v: Vec<f64> = (0..50_000).map(|i| if i % 7 == 3 { f64::NAN } else { i as f64 * 0.25 - 3.0 }).collect();
        let s = Samples::from_vec(v.clone());
        assert_eq!((s.len(), s.finite()), (v.len(), v.iter().filter(|x| x.is_finite()).count()));
        let back = s.clone().to_vec().unwrap();
        assert!(back.iter().zip(&v).all(|(a, b)| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())));
        assert_eq!(s.read(49_990..60_000).unwrap().len(), 10);
        assert!(s.read(70_000..80_000).unwrap().is_empty());
        assert!(Samples::default().to_vec().unwrap().is_empty());
    }
}

/// The temporary storage behind a line failed (a full or failing disk
/// under the temporary directory).
#[derive(Debug, thiserror::Error)]
#[error("temporary storage of a stitched line: {0}")]
pub struct ScratchError(#[source] pub std::io::Error);

impl crate::error::Classify for ScratchError {
    fn class(&self) -> crate::error::Class {
        crate::error::Class::Other
    }
}
