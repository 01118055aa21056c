//! The shared front end: robust noise, hot pixels, the coarse Ricker pass and
//! its candidates.
//!
//! The coarse pass approximates the Ricker response at one scale `s` (the
//! geometric mean of the scale range) without a multiply: three box filters of
//! width `w = 2h + 1` (integer running sums, each followed by `>> floor(log2 w)`
//! to keep 16-bit data inside `i32`) approximate a Gaussian of σ = s (variance
//! 3(w² − 1)/12), and `2G[i] − G[i−q] − G[i+q]` with `q ≈ s` is minus a
//! second difference of it. Cost: about 8 additions per pixel, whatever `s`.
//! Edges replicate the first and last pixel, so a constant row gives exactly
//! zero response.

use super::kernels::Rung;
use super::median::Histogram;
use super::{Candidate, MAX_CANDIDATES, Pixel};
use core::cell::Cell;
use heapless::Vec;

/// Most hot-pixel candidates examined per row (the first ones in the row).
pub const MAX_SPIKES: usize = 64;

/// Robust white-noise σ of the pixels (counts × 256) from the median
/// absolute second difference: for white noise `x[i−1] − 2x[i] + x[i+1]` has
/// σ√6, and median |·| = 0.6745 σ√6, so σ = 1.4826 / √6 · median = 0.6053 ·
/// median (155/256). Stripes, hot pixels and edges are a minority of the row
/// and do not move the median.
///
/// Every `NOISE_STRIDE`-th value is used: the median of 250 samples of a 752-px
/// row has a relative standard error of about 8 %, ample for a threshold, at a
/// third of the selection cost.
#[inline(never)]
pub fn pixel_noise_q8(x: &[i32], scratch: &mut [i32]) -> i32 {
    let mut h = Histogram::new();
    let mut m = 0;
    // The windows at 0, 3, 6, … are the row's exact chunks of three.
    for (s, &[a, b, c]) in scratch.iter_mut().zip(x.as_chunks::<NOISE_STRIDE>().0) {
        let v = (a - 2 * b + c).abs();
        *s = v;
        h.add(v);
        m += 1;
    }
    h.set_total(m);
    h.kth(&mut scratch[..m], m / 2).saturating_mul(155)
}

/// Copies `row` into `x` (which must be as long), values above `sat`
/// clamped to it, and returns [`pixel_noise_q8`] of the copy: one pass
/// instead of two. `scratch` needs a third of the row.
#[inline(never)]
pub fn load_row<P: Pixel>(row: &[P], sat: i32, x: &mut [i32], scratch: &mut [i32]) -> i32 {
    let mut h = Histogram::new();
    let mut m = 0;
    let (xs, x_rest) = x.as_chunks_mut::<NOISE_STRIDE>();
    let (ps, p_rest) = row.as_chunks::<NOISE_STRIDE>();
    for ((d, &[a, b, c]), s) in xs.iter_mut().zip(ps).zip(scratch.iter_mut()) {
        let (a, b, c) = (a.value(), b.value(), c.value());
        // Pixels are non-negative, so `a | b | c` bounds all three: one test
        // instead of three clamps on rows within the bit depth.
        let (a, b, c) = if (a | b | c) > sat { (a.min(sat), b.min(sat), c.min(sat)) } else { (a, b, c) };
        *d = [a, b, c];
        let v = (a - 2 * b + c).abs();
        *s = v;
        h.add(v);
        m += 1;
    }
    for (d, p) in x_rest.iter_mut().zip(p_rest) {
        *d = p.value().min(sat);
    }
    h.set_total(m);
    h.kth(&mut scratch[..m], m / 2).saturating_mul(155)
}

/// Decimation of the robust noise estimates (see [`pixel_noise_q8`]).
pub const NOISE_STRIDE: usize = 3;

/// Robust σ (Q8) of a zero-mean response: 1.4826 · median |r| (380/256).
/// Every `NOISE_STRIDE`-th value is used, as in [`pixel_noise_q8`].
#[inline(never)]
pub fn abs_median_sigma_q8(r: &[i32], scratch: &mut [i32]) -> i32 {
    let mut h = Histogram::new();
    let mut m = 0;
    for (s, c) in scratch.iter_mut().zip(r.chunks(NOISE_STRIDE)) {
        let v = c[0].saturating_abs();
        *s = v;
        h.add(v);
        m += 1;
    }
    h.set_total(m);
    h.kth(&mut scratch[..m], m / 2).saturating_mul(380)
}

/// Replaces isolated hot pixels in place; returns how many.
///
/// A pixel is hot when it is a strict local maximum below saturation, its
/// excess over the mean of its neighbours exceeds 8.6 σ (`2x₀ − x₋ − x₊ >
/// 7 σ√6`), and, after subtracting the local background (the minimum over
/// ±3 px), `(u₀ − 3σ)² > K · (u₋ + 3σ)(u₊ + 3σ)` with `K = e^(1/σ_min²)`: no
/// Gaussian of width ≥ σ_min is that peaked anywhere on its profile, because
/// a sampled Gaussian has `u₀² = e^(1/σ²) u₋ u₊` exactly. The 3 σ allowances
/// keep noise from tipping the test.
#[inline(never)]
pub fn remove_spikes(x: &mut [i32], noise_q8: i32, k_q16: i64, sat: i32) -> u16 {
    let n = x.len();
    if n < 3 {
        return 0;
    }
    let sigma = (noise_q8 as i64 + 128) >> 8;
    let lin = ((noise_q8 as i64 * 7 * 627) >> 16).max(1); // 7 σ √6 (627/256 = √6)
    let margin = 3 * sigma;
    // Read-only screen first: strict local maxima standing out by more than
    // the noise allows. Almost every pixel stops here.
    let lin32 = lin.min(i32::MAX as i64) as i32;
    let mut hits: Vec<usize, MAX_SPIKES> = Vec::new();
    scan3(x, |a, b, c| 2 * b - a - c > lin32, |i, a, b, c| !(b > a && b > c && b < sat && hits.push(i).is_err()));
    let mut count = 0u16;
    for &i in &hits {
        let (a, b, c) = (x[i - 1] as i64, x[i] as i64, x[i + 1] as i64);
        if b <= a || b <= c {
            continue; // a neighbour was repaired meanwhile
        }
        let lo = i.saturating_sub(3);
        let hi = (i + 3).min(n - 1);
        let bg = x[lo..=hi].iter().copied().min().unwrap_or(0) as i64;
        let (ua, ub, uc) = (a - bg, b - bg, c - bg);
        let top = (ub - margin).max(0);
        let lhs = top * top;
        let rhs = (k_q16 * ((ua + margin) * (uc + margin))) >> 16;
        if lhs > rhs {
            x[i] = (bg + ((ua.max(0) * uc.max(0)) as u64).isqrt() as i64) as i32;
            count += 1;
        }
    }
    count
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

/// Local maxima of `r` above `threshold`, the strongest `MAX_CANDIDATES`.
#[inline(never)]
pub fn candidates(r: &[i32], threshold: i32) -> Vec<Candidate, MAX_CANDIDATES> {
    let mut out: Vec<Candidate, MAX_CANDIDATES> = Vec::new();
    let n = r.len();
    let mut push = |pos: usize, resp: i32| {
        let c = Candidate { pos, resp };
        if out.push(c).is_err() {
            // Full: replace the weakest if this one is stronger.
            if let Some((j, w)) = out.iter().enumerate().min_by_key(|(_, c)| c.resp)
                && w.resp < resp
            {
                out[j] = c;
            }
        }
    };
    if n == 0 {
        return Vec::new();
    }
    if (n == 1 || r[0] >= r[1]) && r[0] > threshold {
        push(0, r[0]);
    }
    scan3(
        r,
        |_, b, _| b > threshold,
        |i, a, b, c| {
            if b > a && b >= c {
                push(i, b);
            }
            true
        },
    );
    if n > 1 && r[n - 1] > r[n - 2] && r[n - 1] > threshold {
        push(n - 1, r[n - 1]);
    }
    out
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
        let k = (core::f64::consts::E * 65536.0) as i64; // σ_min = 1
        assert_eq!(remove_spikes(&mut x, 256, k, 4095), 1);
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
                assert_eq!(remove_spikes(&mut g, 256, k, 4095), 0, "σ {sigma}");
            }
        }
    }

    #[test]
    fn noise_of_alternating_pattern() {
        // ±2 alternation: second difference is ±8 everywhere, median 8 → σ_q8 = 8·155.
        let x: [i32; 10] = core::array::from_fn(|i| if i % 2 == 0 { 102 } else { 98 });
        let mut s = [0i32; 10];
        assert_eq!(pixel_noise_q8(&x, &mut s), 8 * 155);
    }
}
