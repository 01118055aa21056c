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
use super::{Candidate, MAX_CANDIDATES};
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
pub fn pixel_noise_q8(x: &[i32], scratch: &mut [i32]) -> i32 {
    let mut m = 0;
    for (s, w) in scratch.iter_mut().zip(x.windows(3).step_by(NOISE_STRIDE)) {
        *s = (w[0] - 2 * w[1] + w[2]).abs();
        m += 1;
    }
    if m == 0 {
        return 0;
    }
    let med = *scratch[..m].select_nth_unstable(m / 2).1;
    med.saturating_mul(155)
}

/// Decimation of the robust noise estimates (see [`pixel_noise_q8`]).
pub const NOISE_STRIDE: usize = 3;

/// Robust σ (Q8) of a zero-mean response: 1.4826 · median |r| (380/256).
/// Every `NOISE_STRIDE`-th value is used, as in [`pixel_noise_q8`].
pub fn abs_median_sigma_q8(r: &[i32], scratch: &mut [i32]) -> i32 {
    let mut m = 0;
    for (s, v) in scratch.iter_mut().zip(r.iter().step_by(NOISE_STRIDE)) {
        *s = v.saturating_abs();
        m += 1;
    }
    if m == 0 {
        return 0;
    }
    let med = *scratch[..m].select_nth_unstable(m / 2).1;
    med.saturating_mul(380)
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
    for (i, w) in x.windows(3).enumerate() {
        let (a, b, c) = (w[0], w[1], w[2]);
        if b > a && b > c && 2 * b - a - c > lin32 && b < sat && hits.push(i + 1).is_err() {
            break;
        }
    }
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

/// One box pass of half-width `h` with edge replication, `>> shift` after.
///
/// A running sum: `dst[i] = Σ src[i−h..=i+h] >> shift`, updated by one add
/// and one subtract per pixel. The interior is a `zip` over two offset
/// slices (no index clamping); only the `h` pixels at each end read the
/// replicated edge.
fn box_pass(src: &[i32], dst: &mut [i32], h: usize, shift: u32) {
    let n = src.len();
    let (first, last) = (src[0], src[n - 1]);
    let at = |i: isize| src[i.clamp(0, n as isize - 1) as usize];
    let hi = h as isize;
    let mut acc: i32 = (-hi..=hi).map(at).sum();
    if n <= 2 * h + 1 {
        for (i, d) in dst.iter_mut().enumerate() {
            *d = acc >> shift;
            let i = i as isize;
            acc += at(i + hi + 1) - at(i - hi);
        }
        return;
    }
    // i in 0..h: the subtracted pixel is left of the row.
    for (d, &add) in dst[..h].iter_mut().zip(&src[h + 1..]) {
        *d = acc >> shift;
        acc += add - first;
    }
    // i in h..n−h−1: both inside.
    for ((d, &add), &sub) in dst[h..n - h - 1].iter_mut().zip(&src[2 * h + 1..]).zip(&src[..n - 2 * h - 1]) {
        *d = acc >> shift;
        acc += add - sub;
    }
    // i in n−h−1..n: the added pixel is right of the row.
    for (d, &sub) in dst[n - h - 1..].iter_mut().zip(&src[n - 2 * h - 1..]) {
        *d = acc >> shift;
        acc += last - sub;
    }
}

/// Three box passes `x → a → b → g`.
pub fn smooth(x: &[i32], a: &mut [i32], b: &mut [i32], g: &mut [i32], rung: &Rung) {
    box_pass(x, a, rung.box_half, rung.box_shift);
    box_pass(a, b, rung.box_half, rung.box_shift);
    box_pass(b, g, rung.box_half, rung.box_shift);
}

/// `r[i] = 2 g[i] − g[i−q] − g[i+q]`, edges replicated.
pub fn second_difference(g: &[i32], r: &mut [i32], q: usize) {
    let n = g.len();
    if n <= 2 * q {
        for (i, d) in r.iter_mut().enumerate() {
            *d = 2 * g[i] - g[i.saturating_sub(q)] - g[(i + q).min(n - 1)];
        }
        return;
    }
    let (first, last) = (g[0], g[n - 1]);
    for ((d, &c), &h) in r[..q].iter_mut().zip(g).zip(&g[q..]) {
        *d = 2 * c - first - h;
    }
    for (((d, &c), &l), &h) in r[q..n - q].iter_mut().zip(&g[q..]).zip(g).zip(&g[2 * q..]) {
        *d = 2 * c - l - h;
    }
    for ((d, &c), &l) in r[n - q..].iter_mut().zip(&g[n - q..]).zip(&g[n - 2 * q..]) {
        *d = 2 * c - l - last;
    }
}

/// Local maxima of `r` above `threshold`, the strongest `MAX_CANDIDATES`.
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
    for (i, w) in r.windows(3).enumerate() {
        if w[1] > threshold && w[1] > w[0] && w[1] >= w[2] {
            push(i + 1, w[1]);
        }
    }
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
    fn box_pass_of_constant_is_constant() {
        let x = [7i32; 20];
        let mut y = [0i32; 20];
        box_pass(&x, &mut y, 2, 0);
        assert!(y.iter().all(|&v| v == 35));
    }

    #[test]
    fn box_pass_matches_direct_sum() {
        let x: [i32; 12] = [1, 5, 2, 8, 3, 9, 4, 7, 6, 0, 2, 1];
        let mut y = [0i32; 12];
        box_pass(&x, &mut y, 1, 0);
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
