//! Exact k-th smallest of non-negative samples by a log-binned histogram.
//!
//! The front end takes two medians per row (the pixel noise and the coarse
//! response's noise, [`super::coarse`]). `select_nth_unstable` on 250
//! samples costs about 36 instructions per sample on thumbv7em; this costs
//! about a third, and gives the same value, bit for bit, for every input.
//!
//! # How
//! Each sample is counted in one of [`BINS`] bins as it is produced: with
//! `u = v + 16`, the bins are `u`'s leading bit and the four bits after it
//! (see [`bin`]), so values below 16 have a bin each and a larger value
//! shares its bin with at most 1/16 of its magnitude; the bins are in the
//! order of the values. A scan of the counts finds the bin that holds the
//! k-th sample and its rank within the bin. A bin of one value: done. Otherwise the samples of that bin (for noise, a
//! few percent of them) are gathered and `select_nth_unstable` picks the
//! rank among them, so the result is exact whatever the distribution; a
//! row whose samples all share one bin costs what it cost before.
//!
//! Cost per sample: a `clz`, a shift, an add and a counter increment when
//! counted; a compare when gathered. Memory: [`BINS`] × u16 (1 KB) on the stack.

/// Bins of the histogram (the largest `i32` falls in bin 448).
pub const BINS: usize = 512;

/// The bin of a non-negative value (monotonic in the value): with `u = v +
/// 16` (so that `⌊log2 u⌋ ≥ 4`), `sh = ⌊log2 u⌋ − 4` and `bin = (u >> sh) +
/// 16·sh` — a `clz`, a subtract, a shift and an add on the Cortex-M4.
#[inline(always)]
pub fn bin(v: u32) -> usize {
    let u = v.wrapping_add(16);
    let sh = 27 - u.leading_zeros();
    (((u >> sh) + 16 * sh) as usize) & (BINS - 1)
}

/// The values `[lo, lo + width)` of bin `b` (16..=448).
fn bin_range(b: usize) -> (u32, u32) {
    let sh = (b / 16 - 1) as u32;
    let mant = (b - 16 * (b / 16 - 1)) as u32;
    ((mant << sh) - 16, 1 << sh)
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
        let (lo, width) = bin_range(target);
        if width == 1 {
            return lo as i32;
        }
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
        let edges = (0..32).flat_map(|e| [17, 16, 15, 1, 0].map(|d| (1u32 << e).wrapping_sub(d)));
        for v in (0..5000u32).chain(edges).filter(|&v| v <= i32::MAX as u32) {
            let b = bin(v);
            assert!((16..=448).contains(&b), "{v}");
            let (lo, width) = bin_range(b);
            assert!(lo <= v && (v - lo) < width, "{v} in bin {b} [{lo}, +{width})");
        }
        for v in 0..70_000u32 {
            assert!(bin(v + 1) >= bin(v), "{v}");
        }
        assert_eq!(bin(i32::MAX as u32), 448);
        assert!((0..16).all(|v| bin_range(bin(v)) == (v, 1)));
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
