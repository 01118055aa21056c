//! The detector's front end (`cms_core::peak::coarse`, `peak::median`)
//! against straightforward references, bit for bit.
//!
//! The product's stages are fused, unrolled and histogram-based for speed
//! on the Cortex-M4 (see `coarse.rs`); these references are the plain
//! definitions — a sort for every median, a direct sum for every box
//! output, clamped indices everywhere — so any input on which the fast code
//! differs from the definition fails here.

use cms_core::peak::coarse;
use cms_core::peak::kernels::{LADDER_LEN, RUNGS};
use cms_core::peak::median::Histogram;
use proptest::prelude::*;

/// The `k`-th smallest by sorting.
fn kth_sorted(v: &[i32], k: usize) -> i32 {
    let mut s = v.to_vec();
    s.sort_unstable();
    s[k]
}

/// Robust pixel noise: median |second difference| of every third window, × 155.
fn pixel_noise_ref(x: &[i32]) -> i32 {
    let v: Vec<i32> = x.windows(3).step_by(3).map(|w| (w[0] - 2 * w[1] + w[2]).abs()).collect();
    if v.is_empty() { 0 } else { kth_sorted(&v, v.len() / 2).saturating_mul(155) }
}

/// Robust response σ: median |r| of every third value, × 380.
fn abs_median_ref(r: &[i32]) -> i32 {
    let v: Vec<i32> = r.iter().step_by(3).map(|v| v.saturating_abs()).collect();
    if v.is_empty() { 0 } else { kth_sorted(&v, v.len() / 2).saturating_mul(380) }
}

fn clamped(v: &[i32], i: isize) -> i32 {
    v[i.clamp(0, v.len() as isize - 1) as usize]
}

/// One box pass by direct sums.
fn box_ref(src: &[i32], h: usize, shift: u32) -> Vec<i32> {
    let h = h as isize;
    (0..src.len() as isize).map(|i| (-h..=h).map(|k| clamped(src, i + k)).sum::<i32>() >> shift).collect()
}

/// The coarse pass by definition: three box passes, then the lagged second difference.
fn response_ref(x: &[i32], k: usize) -> (Vec<i32>, Vec<i32>) {
    let rung = &RUNGS[k];
    let mut g = x.to_vec();
    for _ in 0..3 {
        g = box_ref(&g, rung.box_half, rung.box_shift);
    }
    let q = rung.lag as isize;
    let r = (0..g.len() as isize).map(|i| 2 * g[i as usize] - clamped(&g, i - q) - clamped(&g, i + q)).collect();
    (g, r)
}

/// Candidates by definition: local maxima above the threshold, in order,
/// the weakest replaced when the list is full.
fn candidates_ref(r: &[i32], threshold: i32) -> Vec<(usize, i32)> {
    let n = r.len();
    let mut out: Vec<(usize, i32)> = Vec::new();
    for i in 0..n {
        let left = if i == 0 { i32::MIN } else { r[i - 1] };
        let right = if i + 1 == n { i32::MIN } else { r[i + 1] };
        // First pixel: ≥ its right neighbour; last: > its left one; inside: > left, ≥ right.
        let is_max = if i == 0 { n == 1 || r[0] >= r[1] } else { r[i] > left && r[i] >= right };
        if r[i] > threshold && is_max {
            if out.len() < cms_core::peak::MAX_CANDIDATES {
                out.push((i, r[i]));
            } else if let Some((j, w)) = out.iter().enumerate().min_by_key(|(_, c)| c.1)
                && w.1 < r[i]
            {
                out[j] = (i, r[i]);
            }
        }
    }
    out
}

/// The hot-pixel screen and repair by definition.
fn remove_spikes_ref(x: &mut [i32], noise_q8: i32, k_q16: i64, sat: i32) -> u16 {
    let n = x.len();
    if n < 3 {
        return 0;
    }
    let sigma = (noise_q8 as i64 + 128) >> 8;
    let lin = ((noise_q8 as i64 * 7 * 627) >> 16).max(1).min(i32::MAX as i64) as i32;
    let margin = 3 * sigma;
    let hits: Vec<usize> = (1..n - 1)
        .filter(|&i| {
            let (a, b, c) = (x[i - 1], x[i], x[i + 1]);
            b > a && b > c && 2 * b - a - c > lin && b < sat
        })
        .take(coarse::MAX_SPIKES)
        .collect();
    let mut count = 0;
    for i in hits {
        let (a, b, c) = (x[i - 1] as i64, x[i] as i64, x[i + 1] as i64);
        if b <= a || b <= c {
            continue;
        }
        let bg = x[i.saturating_sub(3)..=(i + 3).min(n - 1)].iter().copied().min().unwrap() as i64;
        let (ua, ub, uc) = (a - bg, b - bg, c - bg);
        let top = (ub - margin).max(0);
        if top * top > (k_q16 * ((ua + margin) * (uc + margin))) >> 16 {
            x[i] = (bg + ((ua.max(0) * uc.max(0)) as u64).isqrt() as i64) as i32;
            count += 1;
        }
    }
    count
}

/// Rows with structure: noise on a background, stripes, plateaus, spikes,
/// and runs of equal values (ties in every median and maximum).
fn row(max: i32) -> impl Strategy<Value = Vec<i32>> {
    (0usize..400, any::<u64>(), 0u8..5).prop_map(move |(len, seed, kind)| {
        let mut s = seed | 1;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let noise = [0, 1, 4, 40, max / 8][kind as usize].max(0) as u64;
        let base = (next() % (max as u64 / 2 + 1)) as i32;
        let mut v: Vec<i32> =
            (0..len).map(|_| (base + (next() % (2 * noise + 1)) as i32 - noise as i32).clamp(0, max)).collect();
        for _ in 0..next() % 4 {
            if len == 0 {
                break;
            }
            let c = (next() % len as u64) as usize;
            let w = 1 + (next() % 12) as usize;
            let a = (next() % (max as u64 + 1)) as i32;
            for (i, p) in v.iter_mut().enumerate().skip(c.saturating_sub(3 * w)).take(6 * w) {
                let t = (i as f64 - c as f64) / w as f64;
                *p = (*p + (a as f64 * (-t * t / 2.0).exp()) as i32).min(max);
            }
        }
        for _ in 0..next() % 6 {
            if len > 0 {
                let i = (next() % len as u64) as usize;
                v[i] = (next() % (max as u64 + 1)) as i32;
            }
        }
        v
    })
}

fn depth() -> impl Strategy<Value = i32> {
    prop_oneof![Just(255), Just(4095), Just(65535)]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    /// The histogram median is the sorted median, whatever the values (the
    /// full `i32` range, ties, one bin for all).
    #[test]
    fn histogram_kth_is_the_sorted_kth(
        v in prop_oneof![
            proptest::collection::vec(0i32..16, 1..300),
            proptest::collection::vec(0i32..5000, 1..300),
            proptest::collection::vec(1000i32..1040, 1..300),
            proptest::collection::vec(0i32..=i32::MAX, 1..300),
        ],
        pick in any::<prop::sample::Index>(),
    ) {
        let k = pick.index(v.len());
        let mut h = Histogram::new();
        v.iter().for_each(|&s| h.add(s));
        h.set_total(v.len());
        let mut scratch = v.clone();
        prop_assert_eq!(h.kth(&mut scratch, k), kth_sorted(&v, k));
    }

    /// Copy, clamp and noise in one pass equal the plain copy and the sorted median.
    #[test]
    fn load_row_and_noise_match(x in depth().prop_flat_map(row), sat in 1i32..=65535) {
        let row: Vec<u16> = x.iter().map(|&v| v as u16).collect();
        let copy: Vec<i32> = x.iter().map(|&v| v.min(sat)).collect();
        let (mut out, mut scratch) = (vec![0; x.len()], vec![0; x.len()]);
        let noise = coarse::load_row(&row, sat, &mut out, &mut scratch);
        prop_assert_eq!(&out, &copy);
        prop_assert_eq!(noise, pixel_noise_ref(&copy));
        prop_assert_eq!(coarse::pixel_noise_q8(&copy, &mut scratch), pixel_noise_ref(&copy));
        let bytes: Vec<u8> = x.iter().map(|&v| v.min(255) as u8).collect();
        let copy8: Vec<i32> = bytes.iter().map(|&v| (v as i32).min(sat)).collect();
        prop_assert_eq!(coarse::load_row(&bytes, sat, &mut out, &mut scratch), pixel_noise_ref(&copy8));
        prop_assert_eq!(&out, &copy8);
    }

    /// The fused coarse pass equals three box passes and a second
    /// difference, on every rung, for every row length (the short-row path,
    /// the ends, and the loops).
    #[test]
    fn response_matches_the_passes(x in depth().prop_flat_map(row), k in 0..LADDER_LEN) {
        let n = x.len();
        let (g_ref, r_ref) = response_ref(&x, k);
        let (mut r, mut b, mut g) = (vec![7; n], vec![7; n], vec![7; n]);
        let mut xm = x.clone();
        coarse::response(&mut xm, &mut r, &mut b, &mut g, &RUNGS[k]);
        prop_assert_eq!(&xm, &x);
        prop_assert_eq!(&g, &g_ref);
        prop_assert_eq!(&r, &r_ref);
        let mut scratch = vec![0; n];
        prop_assert_eq!(coarse::abs_median_sigma_q8(&r, &mut scratch), abs_median_ref(&r));
    }

    /// Candidates equal the plain local-maximum scan, including a full list.
    #[test]
    fn candidates_match(x in depth().prop_flat_map(row), k in 0..LADDER_LEN, frac in 0.0f64..1.2) {
        let (_, r) = response_ref(&x, k);
        let top = r.iter().copied().max().unwrap_or(0);
        let threshold = ((top as f64 * frac) as i32).max(1);
        for thr in [threshold, 1] {
            let got: Vec<(usize, i32)> = coarse::candidates(&r, thr).iter().map(|c| (c.pos, c.resp)).collect();
            prop_assert_eq!(got, candidates_ref(&r, thr));
        }
    }

    /// The hot-pixel screen and repair equal the plain definition.
    #[test]
    fn remove_spikes_matches(
        x in depth().prop_flat_map(row), noise_q8 in 0i32..20_000, k_q16 in 65_536i64..4_000_000, sat in 1i32..=65535,
    ) {
        let (mut a, mut b) = (x.clone(), x.clone());
        let got = coarse::remove_spikes(&mut a, noise_q8, k_q16, sat);
        prop_assert_eq!(got, remove_spikes_ref(&mut b, noise_q8, k_q16, sat));
        prop_assert_eq!(a, b);
    }
}
