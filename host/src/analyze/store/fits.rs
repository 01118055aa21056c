//! [`FitLog`]: a line's registrations, appended to a small buffer that
//! spills to an unlinked temporary file, with the figures the summaries
//! need kept aside.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, Read, Seek, SeekFrom, Write};
use std::sync::{Arc, Mutex, MutexGuard};

use crate::analyze::stitch::{FrameFit, median};

/// Fits a log buffers in memory before writing them out.
pub const FIT_BUFFER: usize = 512;

/// Up to this many fits, the medians are exact (their values are kept).
const EXACT_MEDIANS: usize = 1024;

/// Bytes of a fit on the disk: seq, then five f64.
const RECORD: usize = 4 + 5 * 8;

/// Relative width of a histogram bin: its value, the bin's geometric
/// centre, is within half of it (0.5 %) of every value in the bin.
const BIN_RATIO: f64 = 1.01;

/// The records, shared by a log's clones: a clone that appends after
/// another did takes its own copy first.
#[derive(Default)]
struct Records {
    file: Option<File>,
    on_disk: usize,
    buffer: Vec<FrameFit>,
}

impl Records {
    fn total(&self) -> usize {
        self.on_disk + self.buffer.len()
    }

    fn push(&mut self, f: FrameFit) -> io::Result<()> {
        self.buffer.push(f);
        if self.buffer.len() >= FIT_BUFFER {
            self.flush()?;
        }
        Ok(())
    }

    fn flush(&mut self) -> io::Result<()> {
        if self.buffer.is_empty() {
            return Ok(());
        }
        let file = match &mut self.file {
            Some(f) => f,
            None => self.file.insert(tempfile::tempfile()?),
        };
        let mut bytes = Vec::with_capacity(self.buffer.len() * RECORD);
        for f in &self.buffer {
            bytes.extend_from_slice(&f.seq.to_le_bytes());
            for x in [f.centre_mm, f.overlap_mm, f.offset_um, f.tilt_um_per_mm, f.residual_um] {
                bytes.extend_from_slice(&x.to_le_bytes());
            }
        }
        file.seek(SeekFrom::Start((self.on_disk * RECORD) as u64))?;
        file.write_all(&bytes)?;
        self.on_disk += self.buffer.len();
        self.buffer.clear();
        Ok(())
    }

    /// Calls `f` on the first `n` records in order.
    fn for_each(&mut self, n: usize, f: &mut dyn FnMut(&FrameFit)) -> io::Result<()> {
        let from_disk = n.min(self.on_disk);
        if let (Some(file), true) = (&mut self.file, from_disk > 0) {
            file.seek(SeekFrom::Start(0))?;
            let mut bytes = vec![0u8; FIT_BUFFER * RECORD];
            let mut done = 0;
            while done < from_disk {
                let k = (from_disk - done).min(FIT_BUFFER);
                file.read_exact(&mut bytes[..k * RECORD])?;
                for r in bytes[..k * RECORD].chunks_exact(RECORD) {
                    let x = |i: usize| f64::from_le_bytes(r[4 + 8 * i..12 + 8 * i].try_into().unwrap_or_default());
                    f(&FrameFit {
                        seq: u32::from_le_bytes(r[..4].try_into().unwrap_or_default()),
                        centre_mm: x(0),
                        overlap_mm: x(1),
                        offset_um: x(2),
                        tilt_um_per_mm: x(3),
                        residual_um: x(4),
                    });
                }
                done += k;
            }
        }
        self.buffer.iter().take(n - from_disk).for_each(f);
        Ok(())
    }
}

/// A log-spaced histogram of values, for a median within half a bin.
#[derive(Debug, Clone, Default)]
struct Histogram {
    /// Bins of positive values by `floor(log(v) / log(BIN_RATIO))`.
    positive: BTreeMap<i32, u64>,
    /// Bins of negative values by the same of `−v`.
    negative: BTreeMap<i32, u64>,
    zeros: u64,
    count: u64,
    /// The values themselves while there are few.
    exact: Option<Vec<f64>>,
}

fn bin(v: f64) -> i32 {
    // `as` saturates: the largest and smallest doubles land in the end bins.
    (v.ln() / BIN_RATIO.ln()).floor() as i32
}

fn centre(k: i32) -> f64 {
    BIN_RATIO.powf(f64::from(k) + 0.5)
}

impl Histogram {
    fn new() -> Histogram {
        Histogram { exact: Some(Vec::new()), ..Histogram::default() }
    }

    fn add(&mut self, v: f64) {
        if !v.is_finite() {
            return;
        }
        if v > 0.0 {
            *self.positive.entry(bin(v)).or_default() += 1;
        } else if v < 0.0 {
            *self.negative.entry(bin(-v)).or_default() += 1;
        } else {
            self.zeros += 1;
        }
        self.count += 1;
        if let Some(e) = &mut self.exact {
            if e.len() < EXACT_MEDIANS {
                e.push(v);
            } else {
                self.exact = None;
            }
        }
    }

    /// The value of rank `r` (from 0, ascending), to half a bin.
    fn rank(&self, mut r: u64) -> f64 {
        for (&k, &n) in self.negative.iter().rev() {
            if r < n {
                return -centre(k);
            }
            r -= n;
        }
        if r < self.zeros {
            return 0.0;
        }
        r -= self.zeros;
        for (&k, &n) in &self.positive {
            if r < n {
                return centre(k);
            }
            r -= n;
        }
        f64::NAN
    }

    fn median(&self) -> Option<f64> {
        if let Some(e) = &self.exact {
            return median(e.clone());
        }
        let n = self.count;
        if n == 0 {
            return None;
        }
        Some(if n % 2 == 1 { self.rank(n / 2) } else { 0.5 * (self.rank(n / 2 - 1) + self.rank(n / 2)) })
    }
}

/// The registrations of a line's frames, in the order they were made, and
/// their summary figures.
#[derive(Clone)]
pub struct FitLog {
    records: Arc<Mutex<Records>>,
    /// Records of `records` that are this log's.
    count: usize,
    squares: (f64, f64),
    overlap: Histogram,
    residual: Histogram,
    /// Why a record could not be stored (reads return it).
    error: Option<Arc<str>>,
}

impl Default for FitLog {
    fn default() -> Self {
        FitLog {
            records: Arc::default(),
            count: 0,
            squares: (0.0, 0.0),
            overlap: Histogram::new(),
            residual: Histogram::new(),
            error: None,
        }
    }
}

impl std::fmt::Debug for FitLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FitLog").field("len", &self.count).finish()
    }
}

fn lock(r: &Mutex<Records>) -> MutexGuard<'_, Records> {
    r.lock().unwrap_or_else(|e| e.into_inner())
}

impl FitLog {
    pub fn push(&mut self, f: FrameFit) {
        self.count += 1;
        self.squares.0 += f.offset_um * f.offset_um;
        self.squares.1 += f.tilt_um_per_mm * f.tilt_um_per_mm;
        self.overlap.add(f.overlap_mm);
        self.residual.add(f.residual_um);
        if self.error.is_some() {
            return;
        }
        if let Err(e) = self.store(f) {
            self.error = Some(Arc::from(e.to_string()));
        }
    }

    fn store(&mut self, f: FrameFit) -> io::Result<()> {
        let shared = lock(&self.records).total() != self.count - 1;
        if shared {
            // A clone appended after this log's last record: this log goes
            // on in records of its own.
            let mut own = Records::default();
            let mut failed = None;
            lock(&self.records).for_each(self.count - 1, &mut |r| {
                if failed.is_none()
                    && let Err(e) = own.push(*r)
                {
                    failed = Some(e);
                }
            })?;
            if let Some(e) = failed {
                return Err(e);
            }
            self.records = Arc::new(Mutex::new(own));
        }
        lock(&self.records).push(f)
    }

    /// Why the records could not be stored, if they could not: a spill
    /// file that failed. The summaries stay right; [`FitLog::for_each`]
    /// returns the error.
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    /// Registered frames.
    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Median overlap, mm (`None` without registrations): exact up to
    /// 1024 registrations, beyond within 0.5 % (a log-spaced histogram of
    /// 1 % bins; zero and negative values counted apart, exactly).
    pub fn median_overlap_mm(&self) -> Option<f64> {
        self.overlap.median()
    }

    /// Median residual, µm (`None` without registrations): exact up to
    /// 1024 registrations, beyond within 0.5 % (as
    /// [`FitLog::median_overlap_mm`]).
    pub fn median_residual_um(&self) -> Option<f64> {
        self.residual.median()
    }

    /// RMS of the offsets subtracted, µm (0 without registrations).
    pub fn offset_rms_um(&self) -> f64 {
        if self.count == 0 { 0.0 } else { (self.squares.0 / self.count as f64).sqrt() }
    }

    /// RMS of the tilts subtracted, µm/mm (0 without registrations).
    pub fn tilt_rms_um_per_mm(&self) -> f64 {
        if self.count == 0 { 0.0 } else { (self.squares.1 / self.count as f64).sqrt() }
    }

    /// Appends `other`'s fits, each as `map` makes it (a run's fits put on
    /// chainage).
    pub fn append(&mut self, other: &FitLog, map: impl Fn(FrameFit) -> FrameFit) -> io::Result<()> {
        if Arc::ptr_eq(&self.records, &other.records) {
            // Records shared with `other` are locked while it reads them.
            let mut fits = Vec::with_capacity(other.len());
            other.for_each(|f| fits.push(map(*f)))?;
            fits.into_iter().for_each(|f| self.push(f));
        } else {
            other.for_each(|f| self.push(map(*f)))?;
        }
        match &self.error {
            Some(e) => Err(io::Error::other(e.to_string())),
            None => Ok(()),
        }
    }

    /// Every fit, in order.
    pub fn for_each(&self, mut f: impl FnMut(&FrameFit)) -> io::Result<()> {
        if let Some(e) = &self.error {
            return Err(io::Error::other(e.to_string()));
        }
        if self.count == 0 {
            return Ok(());
        }
        lock(&self.records).for_each(self.count, &mut f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fit(i: usize, overlap_mm: f64, residual_um: f64) -> FrameFit {
        FrameFit {
            seq: i as u32,
            centre_mm: i as f64 * 30.0,
            overlap_mm,
            offset_um: (i % 7) as f64 - 3.0,
            tilt_um_per_mm: 0.01 * (i % 3) as f64,
            residual_um,
        }
    }

    #[test]
    fn fits_come_back_in_order_through_the_file() {
        let mut log = FitLog::default();
        let n = 3 * FIT_BUFFER + 17;
        for i in 0..n {
            log.push(fit(i, 35.0, 0.5));
        }
        let mut seen = Vec::new();
        log.for_each(|f| seen.push(*f)).unwrap();
        assert_eq!(seen, (0..n).map(|i| fit(i, 35.0, 0.5)).collect::<Vec<_>>());
        // A clone goes its own way without touching the original's records.
        let mut other = log.clone();
        log.push(fit(n, 1.0, 1.0));
        other.push(fit(n + 1, 2.0, 2.0));
        let last = |l: &FitLog| {
            let mut v = Vec::new();
            l.for_each(|f| v.push(f.seq)).unwrap();
            (v.len(), v[v.len() - 1])
        };
        assert_eq!((last(&log), last(&other)), ((n + 1, n as u32), (n + 1, n as u32 + 1)));
        let mut joined = FitLog::default();
        joined.append(&other, |f| FrameFit { centre_mm: -f.centre_mm, ..f }).unwrap();
        assert_eq!(joined.len(), n + 1);
        let squares: f64 = (0..n).chain([n + 1]).map(|i| ((i % 7) as f64 - 3.0).powi(2)).sum();
        let rms = squares / (n + 1) as f64;
        assert!((joined.offset_rms_um() - rms.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn medians_are_within_the_stated_resolution() {
        for (n, scale) in [(10usize, 1.0), (1023, 3.0), (1024, 0.01), (5000, 40.0), (20_001, 1e-3)] {
            let mut log = FitLog::default();
            let mut exact = (Vec::new(), Vec::new());
            for i in 0..n {
                // Spread over decades, with zeros and negatives among them.
                let r = scale * ((i * 7919 % 1000) as f64 / 100.0).exp() / 1000.0;
                let r = if i % 11 == 0 {
                    0.0
                } else if i % 13 == 0 {
                    -r
                } else {
                    r
                };
                let o = 2.0 + (i * 104_729 % 997) as f64;
                log.push(fit(i, o, r));
                exact.0.push(o);
                exact.1.push(r);
            }
            let (o, r) = (median(exact.0).unwrap(), median(exact.1).unwrap());
            let (go, gr) = (log.median_overlap_mm().unwrap(), log.median_residual_um().unwrap());
            let tol = if n <= EXACT_MEDIANS { 0.0 } else { 0.005 };
            assert!((go - o).abs() <= tol * o.abs(), "{n}: overlap {go} against {o}");
            assert!((gr - r).abs() <= tol * r.abs(), "{n}: residual {gr} against {r}");
        }
        assert_eq!(FitLog::default().median_residual_um(), None);
    }
}
