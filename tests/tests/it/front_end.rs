//! The detector's front end (`cms_core::peak::screen`, `peak::coarse`,
//! `peak::median`) against straightforward references, bit for bit.
//!
//! The product's stages are fused, unrolled and histogram-based for speed
//! on the Cortex-M4 (see `screen.rs`, `coarse.rs`); these references are
//! the plain definitions — a sort for every median, a direct sum for every
//! block and box output, clamped indices everywhere — so any input on which
//! the fast code differs from the definition fails here.

use cms_core::fixed::{Q24_8, Q48_16};
use cms_core::peak::kernels::{LADDER_LEN, RUNGS};
use cms_core::peak::median::Histogram;
use cms_core::peak::{MAX_CANDIDATES, coarse, screen};
use proptest::prelude::*;

/// The `k`-th smallest by sorting.
fn kth_sorted(v: &[i32], k: usize) -> i32 {
    let mut s = v.to_vec();
    s.sort_unstable();
    s[k]
}

/// Robust pixel noise: median |second difference| of every third window, × 155.
fn pixel_noise_ref(x: &[i32]) -> Q24_8 {
    let step = if x.len() < screen::NOISE_EVERY_TRIPLE_BELOW { 1 } else { 3 };
    let v: Vec<i32> = x.windows(3).step_by(step).map(|w| (w[0] - 2 * w[1] + w[2]).abs()).collect();
    Q24_8(if v.is_empty() { 0 } else { kth_sorted(&v, v.len() / 2).saturating_mul(155) })
}

/// Robust σ of the screen's responses: median |R| of all of them, × 380.
fn screen_sigma_ref(r: &[i32]) -> Q24_8 {
    let v: Vec<i32> = r.iter().map(|v| v.saturating_abs()).collect();
    Q24_8(if v.is_empty() { 0 } else { kth_sorted(&v, v.len() / 2).saturating_mul(380) })
}

/// The screen's block responses by definition: block sums of `B` pixels
/// (the last block aligned to the row's end), `B` × the edge pixel past
/// either end, `R[j] = S[j] + S[j+1] − S[j−1] − S[j+2]` for `j` in `0..=m−2`.
fn screen_ref(row: &[i32], log2_b: u32) -> Vec<i32> {
    let (n, b) = (row.len(), 1usize << log2_b);
    let m = n.div_ceil(b);
    let mut s = vec![b as i32 * row[0]];
    s.extend((0..m).map(|j| row[(j * b).min(n - b)..][..b].iter().sum::<i32>()));
    s.push(b as i32 * row[n - 1]);
    // s[k] is S[k − 1].
    (0..m - 1).map(|j| s[j + 1] + s[j + 2] - s[j] - s[j + 3]).collect()
}

/// The screen's candidates by definition: local maxima of the responses
/// (`R[j] > R[j−1]`, `R[j] ≥ R[j+1]`, nothing past the ends) above the
/// threshold, at `(j + 1)·B` (clamped to the row), in order, the weakest
/// replaced when the list is full.
fn screen_candidates_ref(row: &[i32], log2_b: u32, threshold: i32) -> Vec<(usize, i32)> {
    let r = screen_ref(row, log2_b);
    let mut out: Vec<(usize, i32)> = Vec::new();
    for j in 0..r.len() {
        let left = if j == 0 { i32::MIN } else { r[j - 1] };
        let right = if j + 1 == r.len() { i32::MIN } else { r[j + 1] };
        if r[j] > threshold && r[j] > left && r[j] >= right {
            let c = (((j + 1) << log2_b).min(row.len() - 1), r[j]);
            if out.len() < MAX_CANDIDATES {
                out.push(c);
            } else if let Some((k, w)) = out.iter().enumerate().min_by_key(|(_, c)| c.1)
                && w.1 < c.1
            {
                out[k] = c;
            }
        }
    }
    out
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

/// The first test of the spike screen: `2x[i] − x[i−1] − x[i+1] > level`.
fn spike_hits_ref(x: &[i32], level: i32) -> Vec<usize> {
    (1..x.len().saturating_sub(1))
        .filter(|&i| 2 * x[i] - x[i - 1] - x[i + 1] > level)
        .take(coarse::MAX_SPIKES)
        .collect()
}

/// The hot- and stuck-pixel repair by definition (`coarse::repair_spikes`'s
/// documentation), with plain indices.
fn repair_ref(x: &mut [i32], hits: &[usize], noise: Q24_8, k: Q48_16) -> u16 {
    let n = x.len();
    if n < 3 {
        return 0;
    }
    let sigma = (noise.0 as i64 + 128) >> 8;
    let level = coarse::spike_screen_level(noise) as i64;
    let margin = 3 * sigma;
    let (k_q16, k2) = (k.0, (k.0 * k.0) >> 16);
    let v = |x: &[i32], i: usize| x[i] as i64;
    let d = |x: &[i32], i: usize| 2 * v(x, i) - v(x, i - 1) - v(x, i + 1);
    let bg =
        |x: &[i32], lo: usize, hi: usize| *x[lo.saturating_sub(3)..=(hi + 3).min(n - 1)].iter().min().unwrap() as i64;
    // One pixel's tests: the pixels repaired, if any.
    let test = |x: &mut [i32], i: usize| -> Option<(usize, usize)> {
        if i == 0 || i + 1 >= n || d(x, i) <= level {
            return None;
        }
        let side = if i >= 2 && i + 2 < n { d(x, i - 1) + d(x, i + 1) } else { i64::MIN };
        if side > level {
            return None;
        }
        let (a, b, c) = (v(x, i - 1), v(x, i), v(x, i + 1));
        // The pair with the brighter neighbour first, then the pixel alone.
        let j = if c >= a { i } else { i - 1 };
        if j >= 1 && j + 2 < n {
            let (pa, p, q, pc) = (v(x, j - 1), v(x, j), v(x, j + 1), v(x, j + 2));
            let outer_ok = if j >= 2 && j + 3 < n {
                d(x, j - 1) + d(x, j + 2) < level - (d(x, j) + d(x, j + 1)) / 4
            } else {
                true
            };
            if p.min(q) > pa.max(pc) && outer_ok {
                let g = bg(x, j, j + 1);
                let top = (p - g - margin).max(0) * (q - g - margin).max(0);
                if top > (k2 * ((pa - g + margin) * (pc - g + margin))) >> 16 {
                    let (ua, uc) = ((pa - g).max(0) as u64, (pc - g).max(0) as u64);
                    let mid = (ua * uc).isqrt();
                    x[j] = (g + (ua * mid).isqrt() as i64) as i32;
                    x[j + 1] = (g + (uc * mid).isqrt() as i64) as i32;
                    return Some((j, j + 1));
                }
            }
        }
        if side < level - d(x, i) / 4 && b > a && b > c {
            let g = bg(x, i, i);
            let top = (b - g - margin).max(0);
            if top * top > (k_q16 * ((a - g + margin) * (c - g + margin))) >> 16 {
                x[i] = (g + (((a - g).max(0) * (c - g).max(0)) as u64).isqrt() as i64) as i32;
                return Some((i, i));
            }
        }
        None
    };
    // Each hit, then the pixels beside each repair that now pass the first
    // test (last in, first out).
    let mut count = 0;
    for &h in hits {
        let mut todo = vec![h];
        while let Some(i) = todo.pop() {
            if let Some((lo, hi)) = test(x, i) {
                count += (hi - lo + 1) as u16;
                for q in [lo.wrapping_sub(1), hi + 1] {
                    if (1..n - 1).contains(&q) && d(x, q) > level && todo.len() < 8 {
                        todo.push(q);
                    }
                }
            }
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

    /// The noise straight from the row equals the plain copy's sorted median.
    #[test]
    fn pixel_noise_matches(x in depth().prop_flat_map(row), sat in 1i32..=65535) {
        let row: Vec<u16> = x.iter().map(|&v| v as u16).collect();
        let copy: Vec<i32> = x.iter().map(|&v| v.min(sat)).collect();
        let mut scratch = vec![0; x.len()];
        prop_assert_eq!(screen::pixel_noise_q8(&row, sat, &mut scratch), pixel_noise_ref(&copy));
        let bytes: Vec<u8> = x.iter().map(|&v| v.min(255) as u8).collect();
        let copy8: Vec<i32> = bytes.iter().map(|&v| (v as i32).min(sat)).collect();
        prop_assert_eq!(screen::pixel_noise_q8(&bytes, sat, &mut scratch), pixel_noise_ref(&copy8));
    }

    /// The screen's responses, their σ and its candidates equal the
    /// definitions, for every block width and row length it accepts, both
    /// pixel types, with two pixels per word (pixels below 2^15) and without.
    #[test]
    fn screen_matches(x in depth().prop_flat_map(row), log2_b in 1u32..=5, frac in 0.0f64..1.2) {
        prop_assume!(screen::screens(x.len(), log2_b));
        let narrow_x: Vec<i32> = x.iter().map(|&v| v & 0x7fff).collect();
        for (narrow, x) in [(false, &x), (true, &narrow_x)] {
            let row: Vec<u16> = x.iter().map(|&v| v as u16).collect();
            let want = screen_ref(x, log2_b);
            let mut got = vec![0; x.len()];
            let m = screen::responses(&row, log2_b, &mut got);
            prop_assert_eq!(&got[..m], &want[..]);
            prop_assert_eq!(screen::sigma_q8(&mut got[..m]), screen_sigma_ref(&want));
            let top = want.iter().copied().max().unwrap_or(0);
            let mut cands = heapless::Vec::new();
            for thr in [((top as f64 * frac) as i32).max(1), 1, i32::MIN + 1] {
                screen::candidates(&row, log2_b, narrow, thr, &mut cands);
                let got: Vec<(usize, i32)> = cands.iter().map(|c| (c.pos, c.resp)).collect();
                prop_assert_eq!(got, screen_candidates_ref(x, log2_b, thr));
            }
            let bytes: Vec<u8> = x.iter().map(|&v| v.min(255) as u8).collect();
            let x8: Vec<i32> = bytes.iter().map(|&v| v as i32).collect();
            screen::candidates(&bytes, log2_b, narrow, 1, &mut cands);
            let got: Vec<(usize, i32)> = cands.iter().map(|c| (c.pos, c.resp)).collect();
            prop_assert_eq!(got, screen_candidates_ref(&x8, log2_b, 1));
        }
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
    }

    /// The spike screen two pixels a word (`sat = 2^b − 1 < 2^13`) gives the
    /// scalar screen's answer, on rows with stripes, spikes and pairs, with
    /// pixels above the saturation level (up to the container's) or not, at
    /// any level the word path takes; and so does the screen told where the
    /// candidate starts (`window_is_clean_at`), at the stripe's top, beside
    /// it or anywhere.
    #[test]
    fn window_is_clean_in_pairs_is_the_scalar_test(
        bits in 8u32..=13, over in any::<bool>(), seed in any::<u64>(), len in 0usize..120, level in 0i32..=0x4001,
        hot in 0usize..4, top_from in 0usize..3, top_any in 0usize..130, top_step in -3isize..=3,
    ) {
        let sat = (1i32 << bits) - 1;
        let max = if over { 65_535 } else { sat };
        let mut s = seed | 1;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let base = (next() % (sat as u64 / 2 + 1)) as i32;
        let noise = 1 + (next() % 40) as i32;
        let mut row: Vec<u16> = (0..len).map(|_| (base + (next() % noise as u64) as i32).min(sat) as u16).collect();
        // A stripe (its top passes the first test), and hot pixels.
        let mut top = top_any;
        if len > 10 {
            let c = (next() % len as u64) as usize;
            for (i, p) in row.iter_mut().enumerate() {
                let t = (i as f64 - c as f64) / 2.5;
                *p = (*p as f64 + sat as f64 / 2.0 * (-t * t / 2.0).exp()).min(sat as f64) as u16;
            }
            // The detector's case: the window centred on its brightest pixel.
            if top_from == 0 {
                let half = [18, 10, 6][(next() % 3) as usize];
                let bright = (0..len).fold(0, |b, i| if row[i] > row[b] { i } else { b });
                let lo = bright.saturating_sub(half);
                row = row[lo..(bright + half + 1).min(len)].to_vec();
                top = bright - lo;
            } else if top_from == 1 {
                top = c.saturating_add_signed(top_step);
            }
        }
        for _ in 0..hot {
            if !row.is_empty() {
                let i = (next() % row.len() as u64) as usize;
                row[i] = (next() % (max as u64 + 1)) as u16;
            }
        }
        let want = coarse::window_is_clean_scalar(&row, sat, level);
        prop_assert_eq!(coarse::window_is_clean(&row, sat, level), want);
        prop_assert_eq!(coarse::window_is_clean_at(&row, sat, level, top), want, "top {}", top);
        // Sized for windows of 2H + 1 centred on their candidate (and any other row).
        prop_assert_eq!(coarse::window_is_clean_centred::<u16, 18>(&row, sat, level), want);
        prop_assert_eq!(coarse::window_is_clean_centred::<u16, 10>(&row, sat, level), want);
        prop_assert_eq!(coarse::window_is_clean_centred::<u16, 6>(&row, sat, level), want);
    }

    /// The window's copy and spike screen, and the repair, equal the plain
    /// definitions (on rows with spikes and pairs at any level).
    #[test]
    fn window_and_repair_match(
        x in depth().prop_flat_map(row), noise_q8 in 0i32..20_000, k_q16 in 65_536i64..4_000_000, sat in 1i32..=65535,
    ) {
        let row: Vec<u16> = x.iter().map(|&v| v as u16).collect();
        let copy: Vec<i32> = x.iter().map(|&v| v.min(sat)).collect();
        let (noise, k) = (Q24_8(noise_q8), Q48_16(k_q16));
        let level = coarse::spike_screen_level(noise);
        let (mut w, mut hits) = (vec![0; x.len()], heapless::Vec::new());
        coarse::load_window(&row, sat, level, &mut w, &mut hits);
        prop_assert_eq!(&w, &copy);
        let want_hits = spike_hits_ref(&copy, level);
        prop_assert_eq!(&hits[..], &want_hits[..]);
        let mut want = copy.clone();
        let n_want = repair_ref(&mut want, &want_hits, noise, k);
        prop_assert_eq!(coarse::repair_spikes(&mut w, &hits, noise, k), n_want);
        prop_assert_eq!(&w, &want);
        let mut again = copy.clone();
        prop_assert_eq!(coarse::remove_spikes(&mut again, noise, k), n_want);
        prop_assert_eq!(&again, &want);
        // A window the detector reads in place is one the copy and the
        // repair leave as it is.
        if coarse::window_is_clean(&row, sat, level) {
            prop_assert_eq!(n_want, 0);
            prop_assert_eq!(&want, &x);
        }
    }
}
