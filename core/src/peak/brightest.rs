//! The brightest pixel of a span of the row: where the estimators start
//! from a screen candidate or a track.

use super::Pixel;

/// The brightest pixel of a track's columns ([`Detector::detect_tracked`]):
/// the first maximum of one pixel in four (and the last but one), then the
/// first maximum within ±3 of it. Every pixel is within 2 of a sample, so
/// where a stripe's brightest pixel is nearer its sample than any other
/// sample is to it (always for a noiseless stripe, which falls from its
/// top: by 2·e^(−1/(2σ²)) ≈ 15 % of its amplitude between 1 and 3 px for
/// σ 2.5), the search finds it, at about a third of the cost of every
/// pixel's. What it can miss is a lone pixel brighter than the stripe,
/// which the window's spike screen is there for, or, on the flat top of a
/// wide stripe, a pixel that noise makes brightest further away (the
/// estimators climb to the response's maximum from there).
#[inline(always)]
pub(super) fn brightest_of_track<P: Pixel>(x: &[P]) -> usize {
    let (quads, _) = x.as_chunks::<4>();
    let n = x.len();
    // The key `v · 64 + (63 − j)` (as in `argmax_raw`): sample j is pixel
    // 4j + 1 of the quads, and j = quads.len() (below 63) is pixel n − 2.
    if quads.len() < 2 || quads.len() >= ARGMAX_KEYED_MAX {
        return argmax_raw(x);
    }
    let mut key = 0u32;
    for (j, q) in quads.iter().enumerate() {
        key = key.max(((q[1].value() as u32) << 6) | (63 - j) as u32);
    }
    let last = quads.len();
    key = key.max(((x[n - 2].value() as u32) << 6) | (63 - last) as u32);
    let j = 63 - (key & 63) as usize;
    let at = if j == last { n - 2 } else { 4 * j + 1 };
    // The first maximum of the (up to) seven pixels around it: inline where
    // there are seven (a call of `argmax_raw` costs about twice the search).
    let a = at.saturating_sub(3);
    let near = &x[a..(at + 4).min(n)];
    match near.first_chunk::<7>() {
        Some(w) => {
            // Unrolled (a loop of seven costs nine instructions a pixel).
            let k = |i: usize| ((w[i].value() as u32) << 6) | (63 - i) as u32;
            let key = k(0).max(k(1)).max(k(2)).max(k(3)).max(k(4)).max(k(5)).max(k(6));
            a + 63 - (key & 63) as usize
        }
        None => a + argmax_raw(near),
    }
}

/// The longest slice [`argmax_raw`] finds the maximum of by keys.
const ARGMAX_KEYED_MAX: usize = 64;

/// Index of the first maximum of a slice of pixels (0 if empty). Up to
/// [`ARGMAX_KEYED_MAX`] pixels by keys (below); longer ones two
/// pixels per iteration: the larger of the pair (the left one on a tie)
/// against the best so far, one compare and select each.
pub(super) fn argmax_raw<P: Pixel>(x: &[P]) -> usize {
    if !x.is_empty() && x.len() <= ARGMAX_KEYED_MAX {
        // Pixels are below 2^16: the value and the complement of the index
        // in one key, `v · 64 + (63 − i)`, whose maximum is the first
        // maximum's (a tie goes to the lower index): a load, a shifted add
        // and a compare-select a pixel, no index carried.
        // Two pixels an iteration, the index term counting down by two (one
        // counter for both).
        let (pairs, rest) = x.as_chunks::<2>();
        let (mut key, mut tag) = (0u32, 63u32);
        for q in pairs {
            let a = ((q[0].value() as u32) << 6) | tag;
            let b = ((q[1].value() as u32) << 6) | (tag - 1);
            key = key.max(a).max(b);
            // Wraps after the last pair of a 64-pixel run (then unused).
            tag = tag.wrapping_sub(2);
        }
        if let Some(p) = rest.first() {
            key = key.max(((p.value() as u32) << 6) | tag);
        }
        return 63 - (key & 63) as usize;
    }
    let (mut best, mut top) = (0, i32::MIN);
    let (pairs, rest) = x.as_chunks::<2>();
    for (j, q) in pairs.iter().enumerate() {
        let (a, b) = (q[0].value(), q[1].value());
        let (v, i) = if b > a { (b, 2 * j + 1) } else { (a, 2 * j) };
        if v > top {
            (best, top) = (i, v);
        }
    }
    if let Some(p) = rest.first()
        && p.value() > top
    {
        best = x.len() - 1;
    }
    best
}

/// Index of the first maximum of a slice (0 if empty).
pub(super) fn argmax(x: &[i32]) -> usize {
    let (mut best, mut top) = (0, i32::MIN);
    for (i, &v) in x.iter().enumerate() {
        if v > top {
            (best, top) = (i, v);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn argmax_raw_is_the_first_maximum() {
        let mut s = 12345u32;
        // Both paths (keys up to ARGMAX_KEYED_MAX pixels, pairs past it),
        // ties among few levels and full-scale 16-bit values.
        for len in 0..80usize {
            for t in 0..50 {
                let x: heapless::Vec<u16, 80> = (0..len)
                    .map(|_| {
                        s ^= s << 13;
                        s ^= s >> 17;
                        s ^= s << 5;
                        if t % 2 == 0 { (s % 5) as u16 } else { u16::MAX - (s % 3) as u16 }
                    })
                    .collect();
                let want = x
                    .iter()
                    .enumerate()
                    .fold((0, -1i32), |(b, t), (i, &v)| if v as i32 > t { (i, v as i32) } else { (b, t) })
                    .0;
                assert_eq!(argmax_raw(&x), want, "{x:?}");
            }
        }
    }
}
