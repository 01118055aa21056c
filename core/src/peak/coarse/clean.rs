//! Whether a candidate's window can be read in place: the spike screen
//! without the copy ([`window_is_clean`]), two pixels a word where the
//! pixels are narrow enough.

use super::super::Pixel;

/// Whether the window `row` would come out of [`load_window`](super::load_window) and
/// [`repair_spikes`](super::repair_spikes) unchanged, so that the estimators can read it in place
/// (no copy): no pixel above `sat`, and no pixel that passes the spike
/// screen's first test (threshold `level`, [`spike_screen_level`](super::spike_screen_level)) is worth
/// the repair's tests (`SpikeTest::worth_testing`: the top of a bright
/// stripe passes the first test and fails that one). Where this holds the
/// repair changes nothing, since it touches only pixels worth testing; where
/// it does not, the detector copies the window and repairs it. One pass, four
/// pixels per iteration, no store.
///
/// Where the pixels are narrow enough (a saturation level `2^b − 1` below
/// 2^13, the default for sensors of up to 13 bits) and `level` small enough,
/// two pixels are tested per 32-bit word (`window_is_clean_pairs`): the
/// same answer at about 5 instead of 8.5 instructions a pixel.
#[inline(never)]
pub fn window_is_clean<P: Pixel>(row: &[P], sat: i32, level: i32) -> bool {
    if pairs_apply(row.len(), sat, level) {
        return window_is_clean_pairs(row, sat, level);
    }
    window_is_clean_scalar(row, sat, level)
}

/// `sat` must be below this for `window_is_clean_pairs` (2^13: the
/// pixels then fit the lanes with the second difference's range).
pub const PAIR_SAT_LIMIT: i32 = 1 << 13;
/// The largest `level` `window_is_clean_pairs` takes.
pub const PAIR_LEVEL_MAX: i32 = 0x4001;

/// [`window_is_clean`] for a window whose candidate starts at pixel `top`
/// (its brightest pixel, the stripe's top): the same answer for any `top`.
///
/// A stripe's top passes the first test in most windows, and the word loop
/// would leave for the rare path there and test those centres again. Here
/// the three centres `top − 1 ..= top + 1` take the whole test at once (the
/// first test, and the flanks' where it passes: seven pixels), and the
/// words run over the centres either side of them, `1 ..= top − 2` and
/// `top + 2 ..= n − 2`: with the window centred on `top` (37 px: 16
/// centres a side), four chunks each and no tail. Elsewhere (`top` within
/// 6 px of an end, pixels or `level` too wide for words) it is
/// [`window_is_clean`].
#[inline(never)]
pub fn window_is_clean_at<P: Pixel>(row: &[P], sat: i32, level: i32, top: usize) -> bool {
    let n = row.len();
    if !pairs_apply(n, sat, level) || top < 6 || top + 7 > n {
        return window_is_clean(row, sat, level);
    }
    // x[top − 3 ..= top + 3]: D(j) = 2x[j] − x[j−1] − x[j+1] for j = top − 2 ..= top + 2.
    let Ok(w) = <&[P; 7]>::try_from(&row[top - 3..top + 4]) else {
        return window_is_clean(row, sat, level);
    };
    let (x0, x1, x2, x3) = (w[0].value(), w[1].value(), w[2].value(), w[3].value());
    let (x4, x5, x6) = (w[4].value(), w[5].value(), w[6].value());
    let (d1, d2, d3) = (2 * x1 - x0 - x2, 2 * x2 - x1 - x3, 2 * x3 - x2 - x4);
    let (d4, d5) = (2 * x4 - x3 - x5, 2 * x5 - x4 - x6);
    // Pixel j (D = d): no hit, or its flanks' sum above `level` (as `hits_are_stripe_tops`).
    let top_ok = |d: i32, l: i32, r: i32| d <= level || l + r > level;
    if !(top_ok(d2, d1, d3) && top_ok(d3, d2, d4) && top_ok(d4, d3, d5)) {
        return false;
    }
    let k = lanes_k(level);
    let Some(left) = clean_centres(row, 1, top - 2, k, level) else {
        return false;
    };
    let Some(right) = clean_centres(row, top + 2, n - 2, k, level) else {
        return false;
    };
    (left | right | x3 as u32) & !(sat as u32 * LANES) == 0
}

/// [`window_is_clean_at`] for a window of `2·H + 1` pixels centred on its
/// candidate (`top = H`), `H ≡ 2 (mod 4)`: each side `H` pixels long
/// (`H − 2` centres, whole chunks), so the loops have known lengths and no
/// bounds to test. Other windows take [`window_is_clean_at`].
#[inline(never)]
pub fn window_is_clean_centred<P: Pixel, const H: usize>(row: &[P], sat: i32, level: i32) -> bool {
    let n = row.len();
    let (Some((left, rest)), true) = (row.split_first_chunk::<H>(), H % 4 == 2 && H >= 6 && n == 2 * H + 1) else {
        return window_is_clean_at(row, sat, level, H);
    };
    let Some(right) = rest.last_chunk::<H>() else {
        return window_is_clean_at(row, sat, level, H);
    };
    if !pairs_apply(n, sat, level) {
        return window_is_clean(row, sat, level);
    }
    // x[H − 3 ..= H + 3]: the last three of the left side, the top, the
    // first three of the right.
    let (x0, x1, x2) = (left[H - 3].value(), left[H - 2].value(), left[H - 1].value());
    let (x3, x4, x5, x6) = (rest[0].value(), right[0].value(), right[1].value(), right[2].value());
    let (d1, d2, d3) = (2 * x1 - x0 - x2, 2 * x2 - x1 - x3, 2 * x3 - x2 - x4);
    let (d4, d5) = (2 * x4 - x3 - x5, 2 * x5 - x4 - x6);
    let top_ok = |d: i32, l: i32, r: i32| d <= level || l + r > level;
    if !(top_ok(d2, d1, d3) && top_ok(d3, d2, d4) && top_ok(d4, d3, d5)) {
        return false;
    }
    let k = lanes_k(level);
    let pair = |a: P, b: P| a.value() as u32 | (b.value() as u32) << 16;
    // The test words of a chunk of four pixels `p` after the word `e`.
    let chunk = |e: u32, p: &[P]| {
        let (lo, hi) = (pair(p[0], p[1]), pair(p[2], p[3]));
        let b0 = (e >> 16) | (lo << 16);
        let b1 = (lo >> 16) | (hi << 16);
        let t = k.wrapping_add(b0 << 1).wrapping_sub(e.wrapping_add(lo))
            | k.wrapping_add(b1 << 1).wrapping_sub(lo.wrapping_add(hi));
        (t, lo | hi, hi)
    };
    // Eight pixels an iteration (the loop's count and branch shared), then
    // the last four where `H − 2` is not a multiple of eight.
    let sweep = |side: &[P; H]| {
        let mut e = pair(side[0], side[1]);
        let (mut hits, mut all) = (0u32, e);
        let (eights, rest) = side[2..].as_chunks::<8>();
        for p in eights {
            let (t0, a0, e0) = chunk(e, &p[..4]);
            let (t1, a1, e1) = chunk(e0, &p[4..]);
            (hits, all, e) = (hits | t0 | t1, all | a0 | a1, e1);
        }
        if rest.len() == 4 {
            let (t, a, _) = chunk(e, rest);
            (hits, all) = (hits | t, all | a);
        }
        (hits, all)
    };
    let ((h0, a0), (h1, a1)) = (sweep(left), sweep(right));
    if (h0 | h1) & SIGNS != 0 && !clean_sides(row, [h0, h1], k, level, H) {
        return false;
    }
    (a0 | a1 | x3 as u32) & !(sat as u32 * LANES) == 0
}

/// The sign bits of both halves of a word.
const SIGNS: u32 = 0x8000_8000;

/// `window_is_clean_centred`'s rare path: where some centre of a side
/// (`1 ..= top − 2`, `top + 2 ..= n − 2`) passed the first test (`hits`:
/// the side's test words OR-ed), that side's chunks again with the
/// stripe-top test (`clean_centres`); whether every centre passes.
#[cold]
#[inline(never)]
fn clean_sides<P: Pixel>(row: &[P], hits: [u32; 2], k: u32, level: i32, top: usize) -> bool {
    (hits[0] & SIGNS == 0 || clean_centres(row, 1, top - 2, k, level).is_some())
        && (hits[1] & SIGNS == 0 || clean_centres(row, top + 2, row.len() - 2, k, level).is_some())
}

/// Whether [`window_is_clean`]'s words apply: at least 6 pixels, `sat =
/// 2^b − 1 < 2^13` and `0 ≤ level ≤ 0x4001`.
#[inline(always)]
fn pairs_apply(n: usize, sat: i32, level: i32) -> bool {
    n >= 6 && sat < PAIR_SAT_LIMIT && sat & (sat + 1) == 0 && (0..=PAIR_LEVEL_MAX).contains(&level)
}

/// Both halves of a word.
const LANES: u32 = 0x0001_0001;

/// The word test's constant `K = 0x7FFF − level` in both halves.
#[inline(always)]
fn lanes_k(level: i32) -> u32 {
    (0x7FFF - level) as u32 * LANES
}

/// [`window_is_clean`] two pixels per 32-bit word, for `sat = 2^b − 1 <
/// 2^13` and `0 ≤ level ≤ 0x4001` (and at least 6 pixels); the same answer as
/// [`window_is_clean_scalar`], chunk for chunk.
///
/// A word holds pixels `j` (low half) and `j + 1` (high half). For the
/// centres `i, i + 1` with words `A = (x[i−1], x[i])`, `B = (x[i], x[i+1])`,
/// `C = (x[i+1], x[i+2])`, each half of `K + 2B − A − C`, `K = 0x7FFF −
/// level` in both halves, is `2b − a − c + 0x7FFF − level`. With every
/// pixel below 2^13, `2b − a − c` lies in `[−16 382, 16 382]`, so each half
/// lies in `[16 385 − level, 49 149 − level] ⊂ [0, 2^16)` for `level ≤
/// 16 385`: the halves never carry into each other (the word is their
/// exact sum, whatever order the operations run in, being linear), and bit 15
/// of a half is set exactly where `2b − a − c − level ≥ 1`, the first test.
/// Pixels at or above 2^13 are above `sat` and make the window unclean:
/// every pixel is OR-ed into one word tested once at the end, so the halves'
/// arithmetic is only trusted when it held. A chunk of four centres with a
/// bit set goes to the scalar test's rare path (the stripe's top).
fn window_is_clean_pairs<P: Pixel>(row: &[P], sat: i32, level: i32) -> bool {
    match clean_centres(row, 1, row.len() - 2, lanes_k(level), level) {
        Some(all) => all & !(sat as u32 * LANES) == 0,
        None => false,
    }
}

/// `window_is_clean_pairs` over the centres `a ..= b` of `row` (`1 ≤ a`,
/// `b − a ≥ 3`, `b + 2 ≤ row.len()`): `None` where one of them passes the
/// first test and is worth the repair's (tested on the whole row, so the
/// flanks of the span's end centres are the row's), else every pixel
/// `a − 1 ..= b + 1` OR-ed, for the saturation test. Chunks of four
/// centres, and where their number is not a multiple of four, the chunk of
/// the span's last four pixels (some centres tested twice: the same answer).
#[inline(always)]
fn clean_centres<P: Pixel>(row: &[P], a: usize, b: usize, k: u32, level: i32) -> Option<u32> {
    let pair = |a: P, b: P| a.value() as u32 | (b.value() as u32) << 16;
    // `e` holds (x[i − 1], x[i]) for the chunk of centres i..i + 4.
    let mut e = pair(row[a - 1], row[a]);
    let mut all = e;
    let (ps, _) = row[a + 1..b + 2].as_chunks::<4>();
    let mut from = 0;
    loop {
        let scan = scan_pairs(&ps[from..], e, k);
        all |= scan.all;
        e = scan.e;
        match scan.hit {
            None => break,
            Some(c) => {
                let c = from + c;
                if !hits_are_stripe_tops(row, a + 4 * c, level) {
                    return None;
                }
                from = c + 1;
            }
        }
    }
    if ps.len() * 4 < b + 1 - a {
        // Pixels b − 2 ..= b + 1: centres b − 3 ..= b.
        let tail = <&[P; 4]>::try_from(&row[b - 2..b + 2]).ok()?;
        let scan = scan_pairs(core::slice::from_ref(tail), pair(row[b - 4], row[b - 3]), k);
        all |= scan.all;
        if scan.hit.is_some() && !hits_are_stripe_tops(row, b - 3, level) {
            return None;
        }
    }
    Some(all)
}

/// Where [`scan_pairs`] stopped: the first chunk whose centres pass the
/// first test (`None`: none did), the last word read, and every word read
/// OR-ed.
struct PairScan {
    hit: Option<usize>,
    e: u32,
    all: u32,
}

/// `window_is_clean_pairs`'s loop over chunks of four pixels (`e`: the
/// pair before the first chunk, `k`: the test's constant in both halves),
/// up to the first chunk with a bit set. A loop of its own with the rare
/// path's call outside it keeps its five values in registers (with the call
/// inside, they are spilled to the stack every chunk); inlined, as a call
/// per scan costs more than the spills.
#[inline(always)]
fn scan_pairs<P: Pixel>(ps: &[[P; 4]], mut e: u32, k: u32) -> PairScan {
    let pair = |a: P, b: P| a.value() as u32 | (b.value() as u32) << 16;
    let mut all = 0;
    for (c, p) in ps.iter().enumerate() {
        let (lo, hi) = (pair(p[0], p[1]), pair(p[2], p[3]));
        let b0 = (e >> 16) | (lo << 16);
        let b1 = (lo >> 16) | (hi << 16);
        let t0 = k.wrapping_add(b0 << 1).wrapping_sub(e.wrapping_add(lo));
        let t1 = k.wrapping_add(b1 << 1).wrapping_sub(lo.wrapping_add(hi));
        all |= lo | hi;
        e = hi;
        if (t0 | t1) & SIGNS != 0 {
            return PairScan { hit: Some(c), e, all };
        }
    }
    PairScan { hit: None, e, all }
}

/// [`window_is_clean`] a pixel at a time (any `sat` and `level`).
#[inline(never)]
pub fn window_is_clean_scalar<P: Pixel>(row: &[P], sat: i32, level: i32) -> bool {
    let n = row.len();
    if n < 6 {
        return false;
    }
    // `level − (2b − a − c)` is negative where the first test passes, and
    // `sat − v` where a pixel is above saturation: the signs of four
    // pixels' are OR-ed and tested once (wrapping: a large `level` can only
    // make a clean window look unclean, never the reverse).
    let miss = |a: i32, b: i32, c: i32| level.wrapping_sub(2 * b - a - c);
    let (mut a, mut b) = (row[0].value(), row[1].value());
    if (a | b) > sat {
        return false;
    }
    let mut i = 1;
    let (ps, p_rest) = row[2..].as_chunks::<4>();
    for p in ps {
        let (v0, v1, v2, v3) = (p[0].value(), p[1].value(), p[2].value(), p[3].value());
        if (v0 | v1 | v2 | v3) > sat {
            return false;
        }
        if (miss(a, b, v0) | miss(b, v0, v1) | miss(v0, v1, v2) | miss(v1, v2, v3)) < 0
            && !hits_are_stripe_tops(row, i, level)
        {
            return false;
        }
        (a, b) = (v2, v3);
        i += 4;
    }
    for p in p_rest {
        let c = p.value();
        if c > sat || (miss(a, b, c) < 0 && !hits_are_stripe_tops(row, i, level)) {
            return false;
        }
        (a, b) = (b, c);
        i += 1;
    }
    true
}

/// [`window_is_clean`]'s rare path: whether every pixel of `i..i + 4` that
/// passes the first test fails `worth_testing` (out of the window's ends:
/// worth testing, as in [`repair_spikes`]).
#[inline(never)]
fn hits_are_stripe_tops<P: Pixel>(row: &[P], i: usize, level: i32) -> bool {
    let n = row.len();
    if i < 2 || i + 6 > n {
        // At the window's ends (pixels 1 and n − 2 lack a second neighbour):
        // the general test, pixel by pixel.
        let level = level as i64;
        return (i..(i + 4).min(n - 1)).all(|j| {
            let first = (2 * row[j].value() - row[j - 1].value() - row[j + 1].value()) as i64;
            first <= level
                || match row.get(j.wrapping_sub(2)..j + 3) {
                    Some(&[l2, l1, m, r1, r2]) => {
                        ((2 * (l1.value() + r1.value() - m.value()) - l2.value() - r2.value()) as i64) > level
                    }
                    _ => false,
                }
        });
    }
    // x[i − 2 ..= i + 5]; D(j) = 2x[j] − x[j−1] − x[j+1] for j = i − 1 ..= i + 4.
    let Ok(w) = <&[P; 8]>::try_from(&row[i - 2..i + 6]) else {
        return false;
    };
    let (x0, x1, x2, x3) = (w[0].value(), w[1].value(), w[2].value(), w[3].value());
    let (x4, x5, x6, x7) = (w[4].value(), w[5].value(), w[6].value(), w[7].value());
    let (d0, d1, d2) = (2 * x1 - x0 - x2, 2 * x2 - x1 - x3, 2 * x3 - x2 - x4);
    let (d3, d4, d5) = (2 * x4 - x3 - x5, 2 * x5 - x4 - x6, 2 * x6 - x5 - x7);
    // Pixel i + j (D = d_{j+1}): no hit, or its flanks' sum above `level`.
    let top = |d: i32, l: i32, r: i32| d <= level || l + r > level;
    top(d1, d0, d2) && top(d2, d1, d3) && top(d3, d2, d4) && top(d4, d3, d5)
}
