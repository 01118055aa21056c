//! A candidate's window: its copy with hot and stuck pixels repaired, the
//! saturated run in it, and the box-cascade low-pass the FIR baselines use.
//!
//! The detector copies only the pixels around a candidate of the screen
//! ([`super::screen`]), and only there looks for defects: the copy and the
//! spike screen's first test are one pass ([`load_window`]); the few pixels
//! that pass go to [`repair_spikes`].
//!
//! The coarse pass approximates the Ricker response at one scale `s` (the
//! geometric mean of the scale range) without a multiply: three box filters of
//! width `w = 2h + 1` (integer running sums, each followed by `>> floor(log2 w)`
//! to keep 16-bit data inside `i32`) approximate a Gaussian of σ = s (variance
//! 3(w² − 1)/12), and `2G[i] − G[i−q] − G[i+q]` with `q ≈ s` is minus a
//! second difference of it. Cost: about 8 additions per pixel, whatever `s`.
//! Edges replicate the first and last pixel, so a constant row gives exactly
//! zero response.

use super::Pixel;
use super::kernels::Rung;
use crate::fixed::{Q24_8, Q48_16};
use core::cell::Cell;
use heapless::Vec;

mod clean;
pub use clean::{
    PAIR_LEVEL_MAX, PAIR_SAT_LIMIT, window_is_clean, window_is_clean_at, window_is_clean_centred,
    window_is_clean_scalar,
};

/// Most hot-pixel candidates examined per window (the first ones in it).
pub const MAX_SPIKES: usize = 64;

/// The spike screen's first test, `2x₀ − x₋ − x₊ > 7 σ√6` (8.6 σ above the
/// neighbours' mean): its threshold, counts, for a pixel noise σ of
/// `noise` counts.
pub fn spike_screen_level(noise: Q24_8) -> i32 {
    ((noise.to_bits() as i64 * 7 * 627) >> 16).clamp(1, i32::MAX as i64) as i32 // 627/256 = √6
}

/// Copies `row` into `x` (as long), values above `sat` clamped, and lists
/// in `hits` (the first [`MAX_SPIKES`]) the pixels `i` in `1..n − 1` with
/// `2x[i] − x[i−1] − x[i+1] > level` ([`spike_screen_level`]): the copy
/// and the spike screen in one pass, the window in registers, four pixels
/// per iteration (a pixel costs a load, a store, the test and its share of
/// one branch).
#[inline(never)]
pub fn load_window<P: Pixel>(row: &[P], sat: i32, level: i32, x: &mut [i32], hits: &mut Vec<usize, MAX_SPIKES>) {
    let n = row.len().min(x.len());
    let (row, x) = (&row[..n], &mut x[..n]);
    hits.clear();
    let pre = |a: i32, b: i32, c: i32| 2 * b - a - c > level;
    if n < 6 {
        for (d, p) in x.iter_mut().zip(row) {
            *d = p.value().min(sat);
        }
        for i in 1..n.saturating_sub(1) {
            if pre(x[i - 1], x[i], x[i + 1]) && hits.push(i).is_err() {
                break;
            }
        }
        return;
    }
    let (x0, x1) = (row[0].value().min(sat), row[1].value().min(sat));
    x[0] = x0;
    x[1] = x1;
    let (mut a, mut b) = (x0, x1);
    // `b` is pixel `i`.
    let mut i = 1;
    let (xs, x_rest) = x[2..].as_chunks_mut::<4>();
    let (ps, p_rest) = row[2..].as_chunks::<4>();
    for (d, p) in xs.iter_mut().zip(ps) {
        // Scalars, not an array: an array here is kept on the stack.
        let (v0, v1, v2, v3) = (p[0].value(), p[1].value(), p[2].value(), p[3].value());
        // Pixels are non-negative: `|` bounds all four, one test for four clamps.
        let (v0, v1, v2, v3) = if (v0 | v1 | v2 | v3) > sat {
            (v0.min(sat), v1.min(sat), v2.min(sat), v3.min(sat))
        } else {
            (v0, v1, v2, v3)
        };
        d[0] = v0;
        d[1] = v1;
        d[2] = v2;
        d[3] = v3;
        if pre(a, b, v0) | pre(b, v0, v1) | pre(v0, v1, v2) | pre(v1, v2, v3) {
            push_hits(&[a, b, v0, v1, v2, v3], i, level, hits);
        }
        (a, b) = (v2, v3);
        i += 4;
    }
    for (d, p) in x_rest.iter_mut().zip(p_rest) {
        let c = p.value().min(sat);
        *d = c;
        if pre(a, b, c) {
            let _ = hits.push(i);
        }
        (a, b) = (b, c);
        i += 1;
    }
}

/// [`load_window`]'s rare path, out of line: the windows of `w` from pixel `i`.
#[inline(never)]
fn push_hits(w: &[i32; 6], i: usize, level: i32, hits: &mut Vec<usize, MAX_SPIKES>) {
    for (j, t) in w.windows(3).enumerate() {
        if 2 * t[1] - t[0] - t[2] > level {
            let _ = hits.push(i + j);
        }
    }
}

/// Replaces hot and stuck pixels — single pixels and adjacent pairs, at any
/// level up to full scale — in place; returns how many pixels. Screens the
/// whole of `x` first ([`load_window`] does that while copying; see
/// [`repair_spikes`] for the tests).
pub fn remove_spikes(x: &mut [i32], noise: Q24_8, k: Q48_16) -> u16 {
    let level = spike_screen_level(noise);
    let mut hits: Vec<usize, MAX_SPIKES> = Vec::new();
    scan3(x, |a, b, c| 2 * b - a - c > level, |i, _, _, _| hits.push(i).is_ok());
    repair_spikes(x, &hits, noise, k)
}

/// Repairs the hot and stuck pixels among `hits` (pixels that passed the
/// screen's first test, ascending) for a pixel noise σ of `noise` counts and
/// the factor `k` (`K` below); returns how many pixels.
///
/// After subtracting the local background (the minimum over ±3 px of the
/// pixel or pair):
///
/// * **single** (a strict local maximum): hot when `(u₀ − 3σ)² > K · (u₋ +
///   3σ)(u₊ + 3σ)` with `K = e^(1/σ_min²)`: no Gaussian of width ≥ σ_min
///   is that peaked anywhere on its profile, because a sampled Gaussian has
///   `u₀² = e^(1/σ²) u₋ u₊` exactly. Replaced by the geometric mean of its
///   neighbours (exact on a Gaussian's flank).
/// * **pair** `p, q` (the hit and its brighter neighbour, both above both
///   outer neighbours `a`, `c`): stuck when `(u_p − 3σ)(u_q − 3σ) > K² ·
///   (u_a + 3σ)(u_c + 3σ)`: a sampled Gaussian has `u_p u_q = e^(2/σ²) u_a
///   u_c` exactly, at any offset (the log of a Gaussian is a parabola).
///   Replaced by the log-linear interpolation between `a` and `c` (at ¼ and
///   ¾ of the way).
///
/// A saturated pixel is tested like any other: clipping only lowers `u₀`,
/// so a pixel found too peaked at its clipped value is too peaked at its
/// true one. This is what keeps a stuck pixel at full scale from passing
/// for a saturated stripe: a stripe is known by its width. The 3 σ
/// allowances keep noise from tipping the tests.
///
/// # Cost
/// The top of every bright stripe passes the first test, so each test is
/// preceded by a cheap necessary condition on the second differences
/// `D(i) = 2x[i] − x[i−1] − x[i+1]` beside it: a spike of height `h` has
/// `D = 2h` and `−h` on either side (a pair: `h, h` and `−h` outside), a
/// Gaussian top of σ ≳ 1 px has positive ones there. A candidate goes on
/// to the background and products only when the flanks' sum is below
/// `level − D/4` (`level` the first test's threshold).
pub fn repair_spikes(x: &mut [i32], hits: &[usize], noise: Q24_8, k: Q48_16) -> u16 {
    let (noise_q8, k_q16) = (noise.to_bits(), k.to_bits());
    let n = x.len();
    if n < 3 {
        return 0;
    }
    let t = SpikeTest {
        margin: 3 * ((noise_q8 as i64 + 128) >> 8),
        level: spike_screen_level(noise) as i64,
        k_q16,
        k2_q16: (k_q16 * k_q16) >> 16,
    };
    let mut count = 0u16;
    for &h in hits {
        // Most hits are a stripe's top, rejected at once.
        if !t.worth_testing(x, h) {
            continue;
        }
        let Some(first) = t.repair(x, h) else {
            continue;
        };
        // A repair can unmask a neighbour (a hot pixel beside a stuck one
        // was no local maximum before): the pixels beside a repair are
        // tested again, a few at most.
        let mut todo: Vec<usize, 8> = Vec::new();
        let mut done = Some(first);
        loop {
            if let Some((lo, hi)) = done {
                count += (hi - lo + 1) as u16;
                for q in [lo.wrapping_sub(1), hi + 1] {
                    if (1..n - 1).contains(&q) && peak_at(x, q) > t.level {
                        let _ = todo.push(q);
                    }
                }
            }
            let Some(i) = todo.pop() else {
                break;
            };
            done = t.repair(x, i);
        }
    }
    count
}

/// `2x[i] − x[i−1] − x[i+1]` (minus the second difference), `0 < i < n − 1`.
fn peak_at(x: &[i32], i: usize) -> i64 {
    2 * x[i] as i64 - x[i - 1] as i64 - x[i + 1] as i64
}

/// The constants of [`repair_spikes`]'s tests.
struct SpikeTest {
    /// 3 σ, counts.
    margin: i64,
    /// The first test's threshold (7 σ√6), counts.
    level: i64,
    /// `K = e^(1/σ_min²)` and `K²`, Q16.
    k_q16: i64,
    k2_q16: i64,
}

impl SpikeTest {
    /// The cheap part of [`SpikeTest::repair`]: whether pixel `i` still
    /// passes the first test and is not a stripe's top (see below).
    #[inline(always)]
    fn worth_testing(&self, x: &[i32], i: usize) -> bool {
        match x.get(i.wrapping_sub(2)..i + 3) {
            Some(&[l2, l1, m, r1, r2]) => {
                (2 * m - l1 - r1) as i64 > self.level && ((2 * (l1 + r1 - m) - l2 - r2) as i64) <= self.level
            }
            _ => true,
        }
    }

    /// Tests the pair of pixel `i` and its brighter neighbour, then pixel `i`
    /// alone; repairs and returns the pixels `lo..=hi` it found hot or stuck.
    #[inline(never)]
    fn repair(&self, x: &mut [i32], i: usize) -> Option<(usize, usize)> {
        let n = x.len();
        if i == 0 || i + 1 >= n {
            return None;
        }
        let (level, margin) = (self.level, self.margin);
        let bg_near = |x: &[i32], lo: usize, hi: usize| {
            x[lo.saturating_sub(3)..=(hi + 3).min(n - 1)].iter().copied().min().unwrap_or(0) as i64
        };
        let (a, b, c) = (x[i - 1] as i64, x[i] as i64, x[i + 1] as i64);
        let d0 = 2 * b - a - c;
        if d0 <= level {
            return None; // a neighbour was repaired meanwhile
        }
        // D(i−1) + D(i+1) = 2(a + c − b) − x[i−2] − x[i+2] (pixels are ≤ 16
        // bits: i32 holds it). Clearly positive — curved down on both sides,
        // a Gaussian's top — rules out a single spike (−2h) and a pair (≈ 0)
        // at once.
        let side = match x.get(i.wrapping_sub(2)..i + 3) {
            Some(&[l2, l1, m, r1, r2]) => (2 * (l1 + r1 - m) - l2 - r2) as i64,
            _ => i64::MIN,
        };
        if side > level {
            return None;
        }
        // The pair with the brighter neighbour first, (j, j + 1): a hot
        // pixel beside a stuck one is a pair, and repairing the stuck one
        // alone would take the hot one for its flank.
        let j = if c >= a { i } else { i - 1 };
        if j >= 1 && j + 2 < n {
            let (pa, p, q, pc) = (x[j - 1] as i64, x[j] as i64, x[j + 1] as i64, x[j + 2] as i64);
            let pair_like = p.min(q) > pa.max(pc)
                && match x.get(j.wrapping_sub(2)..j + 4) {
                    // inner = D(j) + D(j+1) = p + q − a − c; outer = D(j−1) +
                    // D(j+2) = 2(a + c) − x[j−2] − x[j+3] − p − q.
                    Some(&[l2, a, p, q, c, r2]) => {
                        let inner = (p + q - a - c) as i64;
                        ((2 * (a + c) - l2 - r2 - p - q) as i64) < level - inner / 4
                    }
                    _ => true,
                };
            if pair_like {
                let bg = bg_near(x, j, j + 1);
                let (ua, up, uq, uc) = (pa - bg, p - bg, q - bg, pc - bg);
                let top = (up - margin).max(0) * (uq - margin).max(0);
                if top > (self.k2_q16 * ((ua + margin) * (uc + margin))) >> 16 {
                    let (ua, uc) = (ua.max(0) as u64, uc.max(0) as u64);
                    let mid = (ua * uc).isqrt();
                    x[j] = (bg + (ua * mid).isqrt() as i64) as i32;
                    x[j + 1] = (bg + (uc * mid).isqrt() as i64) as i32;
                    return Some((j, j + 1));
                }
            }
        }
        let single_like = side < level - d0 / 4;
        if single_like && b > a && b > c {
            let bg = bg_near(x, i, i);
            let (ua, ub, uc) = (a - bg, b - bg, c - bg);
            let top = (ub - margin).max(0);
            if top * top > (self.k_q16 * ((ua + margin) * (uc + margin))) >> 16 {
                x[i] = (bg + ((ua.max(0) * uc.max(0)) as u64).isqrt() as i64) as i32;
                return Some((i, i));
            }
        }
        None
    }
}

/// `dst[lo..hi]` of one box pass of half-width `h` over `src`, edges
/// replicated, `>> shift` after: `dst[i] = Σ src[clamp(i−h..=i+h)] >> shift`.
/// Returns the running sum at `hi − 1` (unshifted). Used for rows too short
/// for [`response`]'s fused loops and for those loops' ends (out of line:
/// it is called eleven times and is not hot).
#[inline(never)]
fn box_span(src: &[Cell<i32>], dst: &[Cell<i32>], h: usize, shift: u32, lo: usize, hi: usize) -> i32 {
    let last = src.len() as isize - 1;
    let at = |i: isize| src[i.clamp(0, last) as usize].get();
    let (h, lo_) = (h as isize, lo as isize);
    let mut acc: i32 = (lo_ - h..=lo_ + h).map(at).sum();
    let Some((first, rest)) = dst[lo..hi].split_first() else {
        return acc;
    };
    first.set(acc >> shift);
    for (i, d) in (lo_ + 1..).zip(rest) {
        acc += at(i + h) - at(i - h - 1);
        d.set(acc >> shift);
    }
    acc
}

/// `r[lo..hi]` of `r[i] = 2 g[i] − g[i−q] − g[i+q]`, edges replicated.
#[inline(never)]
fn second_difference_span(g: &[Cell<i32>], r: &[Cell<i32>], q: usize, lo: usize, hi: usize) {
    let last = g.len() - 1;
    for (i, (d, c)) in (lo..hi).zip(r[lo..hi].iter().zip(&g[lo..hi])) {
        d.set(2 * c.get() - g[i.saturating_sub(q)].get() - g[(i + q).min(last)].get());
    }
}

/// The coarse pass: `g`, the row `x` smoothed by three box passes of
/// half-width `h = rung.box_half` (each `>> rung.box_shift`, edges
/// replicated: each pass repeats its own input's end values), and `r[i] =
/// 2 g[i] − g[i−q] − g[i+q]` (`q = rung.lag`, edges replicated). `b` is
/// scratch; `r` doubles as the first pass's output. All as long as `x`,
/// which is only read (`&mut` lets it be read as cells, like the others).
///
/// # Cost
/// Two streaming loops instead of four passes: the first runs box passes 1
/// and 2 (at step `t` it produces `a[t]`, then `b[t−h]` from it), the second
/// box pass 3 and the second difference (`g[u]`, then `r[u−q]`). The newest
/// input of the second stage of each loop is in a register, so each loop
/// reads 3 values and writes 2 per pixel, and each keeps its pointers in
/// registers on the Cortex-M4 (a single loop over all four stages would
/// not). The few pixels at each end, where indices would be clamped, are
/// done stage by stage.
#[inline(never)]
pub fn response(x: &mut [i32], r: &mut [i32], b: &mut [i32], g: &mut [i32], rung: &Rung) {
    let n = x.len();
    // `x` is only read; as cells it shares the ends' code with the other passes.
    let x = Cell::from_mut(x).as_slice_of_cells();
    let (h, sh, q) = (rung.box_half, rung.box_shift, rung.lag);
    let (r, b, g) = (&mut r[..n], &mut b[..n], &mut g[..n]);
    let (r, b, g) = (
        Cell::from_mut(r).as_slice_of_cells(),
        Cell::from_mut(b).as_slice_of_cells(),
        Cell::from_mut(g).as_slice_of_cells(),
    );
    // The first pass's output lives in `r`'s buffer until `g` is complete.
    let a = r;
    let (ta, tb) = (2 * h + 1, (h + 1).max(2 * q));
    if n == 0 {
        return;
    }
    if n < ta.max(tb) + h + 1 {
        // Too short for the fused loops: pass by pass.
        box_span(x, a, h, sh, 0, n);
        box_span(a, b, h, sh, 0, n);
        box_span(b, g, h, sh, 0, n);
        second_difference_span(g, r, q, 0, n);
        return;
    }
    let end = n - 1 - h; // last step of both loops
    // Box passes 1 and 2: heads, loop over t in ta..=end, tails.
    let mut acc1 = box_span(x, a, h, sh, 0, ta);
    let mut acc2 = box_span(a, b, h, sh, 0, ta - h);
    let steps = x[ta + h..]
        .iter()
        .zip(&x[ta - h - 1..=end - h - 1])
        .zip(&a[ta..=end])
        .zip(&a[..=end - ta])
        .zip(&b[ta - h..=end - h]);
    for ((((x_add, x_sub), a_new), a_old), b_new) in steps {
        acc1 += x_add.get() - x_sub.get();
        let va = acc1 >> sh;
        a_new.set(va);
        acc2 += va - a_old.get();
        b_new.set(acc2 >> sh);
    }
    box_span(x, a, h, sh, n - h, n);
    box_span(a, b, h, sh, n - 2 * h, n);
    // Box pass 3 and the second difference: the same over u in tb..=end.
    let mut acc3 = box_span(b, g, h, sh, 0, tb);
    second_difference_span(g, r, q, 0, tb - q);
    let steps = b[tb + h..]
        .iter()
        .zip(&b[tb - h - 1..=end - h - 1])
        .zip(&g[tb..=end])
        .zip(&g[tb - q..=end - q])
        .zip(&g[tb - 2 * q..=end - 2 * q])
        .zip(&r[tb - q..=end - q]);
    for (((((b_add, b_sub), g_new), g_mid), g_far), r_out) in steps {
        acc3 += b_add.get() - b_sub.get();
        let vg = acc3 >> sh;
        g_new.set(vg);
        r_out.set(2 * g_mid.get() - g_far.get() - vg);
    }
    box_span(b, g, h, sh, n - h, n);
    second_difference_span(g, r, q, n - h - q, n);
}

/// Calls `f(i, v[i−1], v[i], v[i+1])` for every `i` in `1..len − 1`, in
/// order, where the cheap test `pre` on the same three values holds; stops
/// when `f` returns false. The window slides in registers, four pixels per
/// iteration: a pixel costs a load, `pre` and a branch.
#[inline(always)]
fn scan3(v: &[i32], pre: impl Fn(i32, i32, i32) -> bool, mut f: impl FnMut(usize, i32, i32, i32) -> bool) {
    if v.len() < 3 {
        return;
    }
    let (mut a, mut b) = (v[0], v[1]);
    let mut i = 1;
    let mut chunks = v[2..].chunks_exact(4);
    for ch in &mut chunks {
        let (c0, c1, c2, c3) = (ch[0], ch[1], ch[2], ch[3]);
        if (pre(a, b, c0) || pre(b, c0, c1) || pre(c0, c1, c2) || pre(c1, c2, c3))
            && !scan3_hits(&[a, b, c0, c1, c2, c3], i, &pre, &mut f)
        {
            return;
        }
        (a, b) = (c2, c3);
        i += 4;
    }
    for &c in chunks.remainder() {
        if pre(a, b, c) && !f(i, a, b, c) {
            return;
        }
        (a, b) = (b, c);
        i += 1;
    }
}

/// [`scan3`]'s rare path, out of line so that the fast loop keeps its
/// window in registers: the four windows of `w` from index `i`; false when
/// `f` says stop.
#[inline(never)]
fn scan3_hits(
    w: &[i32; 6],
    i: usize,
    pre: &impl Fn(i32, i32, i32) -> bool,
    f: &mut impl FnMut(usize, i32, i32, i32) -> bool,
) -> bool {
    for (j, t) in w.windows(3).enumerate() {
        if pre(t[0], t[1], t[2]) && !f(i + j, t[0], t[1], t[2]) {
            return false;
        }
    }
    true
}

/// The saturated run within `reach` of `pos`, if any: `(first, last)` index.
pub fn saturated_run(x: &[i32], pos: usize, reach: usize, sat: i32) -> Option<(usize, usize)> {
    let n = x.len();
    let lo = pos.saturating_sub(reach);
    let hi = (pos + reach).min(n - 1);
    // The saturated pixel nearest to pos.
    let hit = (0..=reach)
        .flat_map(|d| [pos.checked_sub(d), Some(pos + d)])
        .flatten()
        .filter(|&i| i >= lo && i <= hi)
        .find(|&i| x[i] >= sat)?;
    let mut s = hit;
    while s > 0 && x[s - 1] >= sat {
        s -= 1;
    }
    let mut e = hit;
    while e + 1 < n && x[e + 1] >= sat {
        e += 1;
    }
    Some((s, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_span_of_constant_is_constant() {
        let x = [7i32; 20];
        let mut y = [0i32; 20];
        let mut x = x;
        let xc = Cell::from_mut(&mut x[..]).as_slice_of_cells();
        let yc = Cell::from_mut(&mut y[..]).as_slice_of_cells();
        box_span(xc, yc, 2, 0, 0, 20);
        assert!(y.iter().all(|&v| v == 35));
    }

    #[test]
    fn box_span_matches_direct_sum() {
        let x: [i32; 12] = [1, 5, 2, 8, 3, 9, 4, 7, 6, 0, 2, 1];
        let mut y = [0i32; 12];
        let mut x = x;
        let xc = Cell::from_mut(&mut x[..]).as_slice_of_cells();
        let yc = Cell::from_mut(&mut y[..]).as_slice_of_cells();
        // In two spans: the running sum restarts exactly.
        box_span(xc, yc, 1, 0, 0, 5);
        box_span(xc, yc, 1, 0, 5, 12);
        // interior: y[i] = x[i-1] + x[i] + x[i+1]
        assert_eq!(y[1], 8);
        assert_eq!(y[5], 16);
        // edges replicate: y[0] = x[0] + x[0] + x[1]
        assert_eq!(y[0], 7);
        assert_eq!(y[11], 4);
    }

    #[test]
    fn spike_is_removed_and_gaussian_kept() {
        // A hot pixel on a flat background of 100 with noise 0.
        let mut x = [100i32; 16];
        x[8] = 900;
        let k = Q48_16((core::f64::consts::E * 65536.0) as i64); // σ_min = 1
        assert_eq!(remove_spikes(&mut x, Q24_8::ONE, k), 1);
        assert!(x[8] < 110);
        // Gaussians of σ = 1.05 … 4 at any sub-pixel offset are untouched,
        // even 20 times above the noise.
        extern crate std;
        for tenth in 0..10 {
            for sigma in [1.05f64, 1.5, 2.5, 4.0] {
                let mut g: [i32; 41] = core::array::from_fn(|i| {
                    let t = i as f64 - 20.0 - tenth as f64 / 10.0;
                    (100.0 + 3000.0 * std::primitive::f64::exp(-t * t / (2.0 * sigma * sigma))) as i32
                });
                assert_eq!(remove_spikes(&mut g, Q24_8::ONE, k), 0, "σ {sigma}");
            }
        }
    }

    #[test]
    fn stuck_pixels_and_pairs_at_full_scale_are_repaired() {
        let k = Q48_16((core::f64::consts::E * 65536.0) as i64); // σ_min = 1
        // A single pixel and a pair at full scale on a flat background.
        let mut x = [100i32; 24];
        x[6] = 4095;
        x[15] = 4095;
        x[16] = 4095;
        assert_eq!(remove_spikes(&mut x, Q24_8::ONE, k), 3);
        assert!(x.iter().all(|&v| v < 110), "{x:?}");
        // The same copied by load_window, clamped to a lower saturation.
        let row: [u16; 24] = core::array::from_fn(|i| if i == 9 { 4095 } else { 100 });
        let (mut y, mut hits) = ([0i32; 24], Vec::new());
        load_window(&row, 1000, spike_screen_level(Q24_8::ONE), &mut y, &mut hits);
        assert_eq!(y[9], 1000);
        assert_eq!(&hits[..], &[9]);
        assert_eq!(repair_spikes(&mut y, &hits, Q24_8::ONE, k), 1);
        assert!(y[9] < 110);
    }
}
