//! A candidate's window copied and repaired: the rare path of
//! [`Detector::candidate`] (a hot or stuck pixel in the window, a value above
//! saturation, a method that reads a filtered copy), out of line so that the
//! common path, reading the row in place, holds none of it.

use super::brightest::argmax;
use super::saturated::saturated_stripe;
use super::{Detector, MAX_CANDIDATES, Method, Pixel, RowView, Stripe, coarse, cwt, kernels, refine};
use crate::fixed::{Q24_8, Q48_16};
use heapless::Vec;

impl<const W: usize> Detector<W> {
    /// [`Detector::candidate`]'s window `lo..hi` copied and repaired (hot
    /// and stuck pixels; the rare path, out of line), the start sought
    /// again in the copy (`(a0, b0)`: where the screen responded, as row
    /// indices; `bright`: the brightest raw pixel there, `None` for an
    /// unscreened row; `first_window`: the wide window can still be asked
    /// for), and the stripe refined there; with the number of pixels
    /// repaired.
    #[inline(never)]
    pub(super) fn copied<P: Pixel>(
        &mut self,
        row: &[P],
        (lo, hi): (usize, usize),
        (a0, b0): (usize, usize),
        bright: Option<usize>,
        first_window: bool,
        runs_used: &mut Vec<(usize, usize), MAX_CANDIDATES>,
    ) -> (Result<Option<Stripe>, cwt::Wider>, u16) {
        let mut hits: Vec<usize, { coarse::MAX_SPIKES }> = Vec::new();
        let (n, w) = (row.len(), hi - lo);
        let sat = self.cfg.saturation as i32;
        let screened = bright.is_some();
        let bright = bright.unwrap_or(n / 2);
        let lb = self.plan.block_log2;
        let near = (1usize << lb) + 1;
        let noise_q8 = self.detect_noise_q8;
        let level = self.spike_level;
        let needs_g = matches!(self.cfg.method, Method::CogFiltered | Method::FirZero);
        let x = &mut self.x[..w];
        coarse::load_window(&row[lo..hi], sat, level, x, &mut hits);
        // Within a speckled line a speckle is as peaked as a hot pixel
        // (its grain is the lens's Airy disc, 0.3–0.5 px at F/4–F/8): no
        // test on one row tells them apart, and repairing speckles moved
        // the centroid's points by a quarter of their error. The centroid
        // reads the pixels as they are.
        let spikes = if self.cfg.method == Method::Centroid {
            0
        } else {
            coarse::repair_spikes(x, &hits, Q24_8(noise_q8), Q48_16(self.plan.spike_k_q16))
        };
        if needs_g {
            let rung = &kernels::RUNGS[self.plan.k_coarse];
            coarse::response(x, &mut self.r[..w], &mut self.s[..w], &mut self.g[..w], rung);
        }
        let x = &self.x[..w];
        // The brightest pixel where the screen responded (after the
        // repair, so a stuck pixel does not pull the start away from
        // a stripe beside it).
        // The stripe the repaired window shows nearest to the
        // brightest raw pixel, where a pixel was repaired: its
        // response can have hidden a stripe beside it from the
        // screen (the stripe's block response then only a shoulder
        // of the spike's, no candidate of its own), and this
        // candidate is then the stripe's. Not found in the first
        // window: the wide one is asked for, which has room.
        let hidden = if screened && spikes > 0 {
            hidden_candidate(x, 1 << lb, self.screen_threshold, bright.clamp(lo, hi - 1) - lo)
        } else {
            None
        };
        let start = if screened && spikes == 0 && (lo..hi).contains(&bright) {
            // Nothing repaired: the same pixel (up to ties among
            // values above saturation, which the copy clamps).
            bright - lo
        } else if let Some(c) = hidden {
            let (a, b) = (c.saturating_sub(near), (c + near).min(w - 1));
            argmax(&x[a..=b]) + a
        } else {
            let (a, b) = if screened { (a0.max(lo) - lo, b0.min(hi - 1) - lo) } else { (0, w - 1) };
            argmax(&x[a..=b]) + a
        };
        let view = RowView {
            x,
            g: if needs_g { &self.g[..w] } else { &[] },
            cfg: &self.cfg,
            plan: &self.plan,
            noise_q8,
            off: lo,
            row_len: n,
        };
        // `start` is the first brightest pixel within `near`: a
        // saturated run there includes it. At the window's end (not
        // the row's) it has no neighbour on one side, so the spike
        // screen could not test it (a stuck pixel cut from its
        // pair): the wide window is asked for, which holds it.
        let cut = screened
            && ((start == 0 && lo > 0)
                || (start + 1 == w && hi < n)
                || (spikes > 0 && hidden.is_none() && first_window));
        // A speckled line saturates in single speckles long before the
        // line itself does: the centroid takes the clipped pixels as they
        // are (and flags them) rather than centring on one speckle's run.
        let run = if x[start] >= sat && self.cfg.method != Method::Centroid {
            coarse::saturated_run(view.x, start, near, sat)
        } else {
            None
        };
        let got = match run {
            _ if cut => Err(cwt::Wider),
            Some((s, e)) => {
                let run = (s + lo, e + lo);
                if runs_used.contains(&run) {
                    Ok(None)
                } else {
                    let _ = runs_used.push(run);
                    Ok(saturated_stripe(&view, (s, e), sat))
                }
            }
            None => refine(&view, start, &mut self.s),
        };
        (got, spikes)
    }
}

/// After a repair, where in the repaired window `x` a stripe stands that
/// the repaired pixels may have hidden from the screen: the local maximum
/// nearest to `near_to` of the screen's box difference (`2B` pixels minus
/// the `B` on each side, the block response of [`screen`] taken at every
/// pixel instead of every block) above the screen's `threshold`; `None`
/// if there is none. The rare path (a window with a hot or stuck pixel,
/// which a sensor with a hot pixel near a line has on every row): the
/// three box sums slide a pixel at a time, six additions a pixel (out of
/// line).
#[inline(never)]
fn hidden_candidate(x: &[i32], block: usize, threshold: i32, near_to: usize) -> Option<usize> {
    let n = x.len();
    if n < 4 * block + 2 {
        return None;
    }
    let sum = |a: usize, b: usize| x[a..b].iter().sum::<i32>();
    let (first, last) = (2 * block, n - 2 * block);
    // At centre `c`: the centre's 2B pixels and the B either side.
    let (mut left, mut centre, mut right) = (
        sum(first - 2 * block, first - block),
        sum(first - block, first + block),
        sum(first + block, first + 2 * block),
    );
    let r_first = centre - left - right;
    let mut at = |c: usize| -> i32 {
        // Move the boxes from `c − 1` to `c` (`c + 2B − 1 < n`).
        left += x[c - 1 - block] - x[c - 1 - 2 * block];
        centre += x[c - 1 + block] - x[c - 1 - block];
        right += x[c - 1 + 2 * block] - x[c - 1 + block];
        centre - left - right
    };
    let mut best: Option<usize> = None;
    let (mut prev, mut cur) = (r_first, at(first + 1));
    for c in first + 1..last {
        let next = at(c + 1);
        if cur > threshold
            && cur > prev
            && cur >= next
            && best.is_none_or(|b| c.abs_diff(near_to) < b.abs_diff(near_to))
        {
            best = Some(c);
        }
        (prev, cur) = (cur, next);
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sliding box sums give the local maxima of the box difference
    /// taken by its definition at every pixel.
    #[test]
    fn hidden_candidate_is_the_nearest_local_maximum_of_the_box_difference() {
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for _ in 0..300 {
            let (n, block) = (20 + (next() % 100) as usize, 1usize << (1 + next() % 3));
            let mut buf = [0i32; 128];
            buf.iter_mut().for_each(|v| *v = (next() % 4096) as i32);
            let x = &buf[..n];
            let (threshold, near_to) = ((next() % 6000) as i32, (next() as usize) % n);
            let r = |c: usize| {
                let s = |a: usize, b: usize| x[a..b].iter().sum::<i32>();
                s(c - block, c + block) - s(c - 2 * block, c - block) - s(c + block, c + 2 * block)
            };
            let want =
                if n < 4 * block + 2 {
                    None
                } else {
                    (2 * block + 1..n - 2 * block)
                        .filter(|&c| r(c) > threshold && r(c) > r(c - 1) && r(c) >= r(c + 1))
                        .fold(None, |b: Option<usize>, c| {
                            if b.is_none_or(|b| c.abs_diff(near_to) < b.abs_diff(near_to)) { Some(c) } else { b }
                        })
                };
            assert_eq!(hidden_candidate(x, block, threshold, near_to), want, "n {n} block {block}");
        }
    }
}
