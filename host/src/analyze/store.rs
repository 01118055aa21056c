//! What a stitched line holds that grows with the track: its samples
//! ([`Samples`]) and its frames' registrations ([`FitLog`]). Everything
//! downstream reads them in stretches, never whole, so that the analysis
//! of a line of any length runs in bounded memory.

use std::ops::Range;
use std::sync::Arc;

use super::stitch::{FrameFit, median};

/// A line's samples along the track (µm; NaN where nothing was measured),
/// read in stretches.
#[derive(Debug, Clone, Default)]
pub struct Samples {
    values: Arc<Vec<f64>>,
}

impl Samples {
    /// Samples holding `values`.
    pub fn from_vec(values: Vec<f64>) -> Samples {
        Samples { values: Arc::new(values) }
    }

    pub fn len(&self) -> usize {
        self.values.len()
    }

    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// The samples of `range`, clipped to the line.
    pub fn read(&self, range: Range<usize>) -> std::io::Result<Vec<f64>> {
        let end = range.end.min(self.values.len());
        let start = range.start.min(end);
        Ok(self.values[start..end].to_vec())
    }

    /// Every sample: for lines known to be short (tests, a profile file's
    /// small cases); the analysis reads stretches.
    pub fn to_vec(&self) -> std::io::Result<Vec<f64>> {
        self.read(0..self.len())
    }

    /// Samples with a value.
    pub fn finite(&self) -> usize {
        self.values.iter().filter(|v| v.is_finite()).count()
    }
}

/// The registrations of a line's frames, in the order they were made, and
/// their summary figures.
#[derive(Debug, Clone, Default)]
pub struct FitLog {
    fits: Vec<FrameFit>,
}

impl FitLog {
    pub fn push(&mut self, f: FrameFit) {
        self.fits.push(f);
    }

    /// Registered frames.
    pub fn len(&self) -> usize {
        self.fits.len()
    }

    pub fn is_empty(&self) -> bool {
        self.fits.is_empty()
    }

    /// Median overlap, mm (`None` without registrations).
    pub fn median_overlap_mm(&self) -> Option<f64> {
        median(self.fits.iter().map(|f| f.overlap_mm).collect())
    }

    /// Median residual, µm (`None` without registrations).
    pub fn median_residual_um(&self) -> Option<f64> {
        median(self.fits.iter().map(|f| f.residual_um).collect())
    }

    /// RMS of the offsets subtracted, µm (0 without registrations).
    pub fn offset_rms_um(&self) -> f64 {
        rms(self.fits.iter().map(|f| f.offset_um))
    }

    /// RMS of the tilts subtracted, µm/mm (0 without registrations).
    pub fn tilt_rms_um_per_mm(&self) -> f64 {
        rms(self.fits.iter().map(|f| f.tilt_um_per_mm))
    }

    /// Appends `other`'s fits, each as `map` makes it (a run's fits put on
    /// chainage).
    pub fn append(&mut self, other: &FitLog, map: impl Fn(FrameFit) -> FrameFit) -> std::io::Result<()> {
        self.fits.extend(other.fits.iter().map(|f| map(*f)));
        Ok(())
    }

    /// Every fit, in order.
    pub fn for_each(&self, mut f: impl FnMut(&FrameFit)) -> std::io::Result<()> {
        self.fits.iter().for_each(&mut f);
        Ok(())
    }
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    if n == 0 { 0.0 } else { (s / n as f64).sqrt() }
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
