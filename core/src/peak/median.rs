//! Exact k-th smallest of non-negative samples by a log-binned histogram.
//!
//! The front end takes two medians per row (the pixel noise and the coarse
//! response's noise, [`super::coarse`]). `select_nth_unstable` on 250
//! samples costs about 36 instructions per sample on thumbv7em; this costs
//! about a third, and gives the same value, bit for bit, for every input.
//!
//! # How
//! Each sample is counted in one of [`BINS`] bins as it is produced: values
//! below 16 have a bin each, larger ones share a bin with the values of the
//! same leading bit and the same next three bits (`bin = (v >> sh) + 8·sh`,
//! `sh = max(⌊log2 v⌋ − 3, 0)`; a bin spans at most 1/8 of its values, and
//! the bins are in the order of the values). A scan of the counts finds the
//! bin that holds the k-th sample and its rank within the bin. A bin below
//! 16 is one value: done. Otherwise the samples of that bin (for noise, a
//! few percent of them) are gathered and `select_nth_unstable` picks the
//! rank among them, so the result is exact whatever the distribution; a
//! row whose samples all share one bin costs what it cost before.
//!
//! Cost per sample: a `clz`, a shift, an add and a counter increment when
//! counted; a compare when gathered. Memory: [`BINS`] × u16 on the stack.

/// Bins of the histogram (the largest `i32` falls in bin 231).
pub const BINS: usize = 256;

/// The bin of a non-negative value (monotonic in the value).
#[inline(always)]
pub fn bin(v: u32) -> usize {
    let sh = (31 - (v | 1).leading_zeros()).saturating_sub(3);
    ((v >> sh) + 8 * sh) as usize
}

/// The values `[lo, hi)` of bin `b` (`hi` as `u64`: the last bin ends at 2³¹).
fn bin_range(b: usize) -> (u32, u64) {
    if b < 16 {
        return (b as u32, b as u64 + 1);
    }
    let sh = (b / 8 - 1) as u32;
    let mant = b as u64 - 8 * sh as u64;
    ((mant << sh) as u32, (mant + 1) << sh)
}

/// Counts of non-negative samples per [`bin`].
pub struct Histogram {
    counts: [u16; BINS],
    total: usize,
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

impl Histogram {
    /// An empty histogram.
    pub const fn new() -> Self {
        Histogram { counts: [0; BINS], total: 0 }
    }

    /// Counts the non-negative sample `v`.
    #[inline(always)]
    pub fn add(&mut self, v: i32) {
        let b = bin(v as u32) & (BINS - 1);
        self.counts[b] = self.counts[b].wrapping_add(1);
    }

    /// Declares how many samples were counted (see [`Histogram::kth`]).
    pub fn set_total(&mut self, total: usize) {
        self.total = total;
    }

    /// The `k`-th smallest (from 0) of `samples`, which must be exactly the
    /// values counted (non-negative, `samples.len()` of them, `k` below
    /// that), as `*samples.select_nth_unstable(k).1` would return it.
    /// `samples` is reordered. A histogram whose counts may have wrapped
    /// (more than 65 535 samples) is not used: the samples are selected
    /// directly.
    pub fn kth(&self, samples: &mut [i32], k: usize) -> i32 {
        let m = samples.len();
        if k >= m {
            return 0;
        }
        if m > u16::MAX as usize || self.total != m {
            return *samples.select_nth_unstable(k).1;
        }
        let mut below = 0usize;
        let mut target = BINS - 1;
        for (b, &c) in self.counts.iter().enumerate() {
            if below + c as usize > k {
                target = b;
                break;
            }
            below += c as usize;
        }
        if target < 16 {
            return target as i32;
        }
        let (lo, hi) = bin_range(target);
        let width = (hi - lo as u64) as u32;
        // Gather the bin's samples to the front (the write index never
        // passes the read index).
        let mut g = 0;
        for i in 0..m {
            let v = samples[i];
            if (v as u32).wrapping_sub(lo) < width {
                samples[g] = v;
                g += 1;
            }
        }
        *samples[..g].select_nth_unstable(k - below).1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_are_monotonic_and_ranges_match() {
        let edges = (0..31).flat_map(|e| [(1u32 << e) - 1, 1 << e, (1 << e) + 1]);
        for v in (0..5000u32).chain(edges).chain([i32::MAX as u32]) {
            let b = bin(v);
            assert!(b < 232, "{v}");
            let (lo, hi) = bin_range(b);
            assert!(lo <= v && (v as u64) < hi, "{v} in bin {b} [{lo}, {hi})");
        }
        for v in 0..70_000u32 {
            assert!(bin(v + 1) >= bin(v), "{v}");
        }
        assert_eq!(bin(i32::MAX as u32), 231);
    }

    #[test]
    fn kth_matches_select() {
        let sets: [&[i32]; 5] = [
            &[0],
            &[5, 5, 5, 5],
            &[100, 3, 7, 1000, 40_000, 2, 2, 99],
            &[i32::MAX, 0, i32::MAX],
            &[17, 18, 19, 20, 21, 22, 23, 24, 25, 26],
        ];
        for s in sets {
            for k in 0..s.len() {
                let mut h = Histogram::new();
                for &v in s {
                    h.add(v);
                }
                h.set_total(s.len());
                let mut a: heapless::Vec<i32, 16> = heapless::Vec::from_slice(s).unwrap();
                let mut b = a.clone();
                assert_eq!(h.kth(&mut a, k), *b.select_nth_unstable(k).1, "{s:?} k {k}");
            }
        }
    }
}
