//! Start-up self-test of the stripe detector on a synthetic sensor row.
//!
//! The row imitates one MT9V034 row (752 px, 12 bits) crossing the three laser
//! lines: three Gaussian stripes at sub-pixel positions that are neither whole
//! nor half pixels (docs/reference.md §1: never test only at .0 or .5), on a sloping
//! background with a little deterministic noise. Everything is integer math:
//! `exp(−t)` comes from a 16-entry table of `e^(−n)` and a degree-6 Taylor
//! polynomial for the fractional part, all in Q16.

use cms_core::fixed::Px;
use cms_core::peak::{Detector, Stripe, Stripes};

/// Row length of the head's sensor.
pub const WIDTH: usize = 752;

/// A synthetic stripe: position and σ in Q16.16 pixels, amplitude in counts.
#[derive(Clone, Copy)]
pub struct Truth {
    pub position: Px,
    pub sigma: Px,
    pub amplitude: i32,
}

/// The three stripes of the synthetic row (positions at .3125, .7 and .15 px).
pub const TRUTH: [Truth; 3] = [
    Truth { position: Px(201 * 65536 + 20480), sigma: Px(2 * 65536), amplitude: 1800 },
    Truth { position: Px(376 * 65536 + 45875), sigma: Px(5 * 32768), amplitude: 2600 },
    Truth { position: Px(552 * 65536 + 9830), sigma: Px(3 * 65536), amplitude: 1200 },
];

/// Largest position error accepted by the self-test: 1/20 px.
pub const TOLERANCE: Px = Px(65536 / 20);

/// `e^(−t)` for `t ≥ 0`, both Q16.
fn exp_neg_q16(t: i64) -> i64 {
    // e^(−n), n = 0..15, Q16 (rounded).
    const E_NEG_INT: [i64; 16] = [65536, 24109, 8869, 3263, 1200, 442, 162, 60, 22, 8, 3, 1, 0, 0, 0, 0];
    let n = (t >> 16) as usize;
    if n >= E_NEG_INT.len() {
        return 0;
    }
    let f = t & 0xffff;
    // e^(−f) = 1 − f(1 − f/2(1 − f/3(1 − f/4(1 − f/5(1 − f/6))))), Horner, Q16.
    let mut acc: i64 = 65536;
    for k in (1..=6i64).rev() {
        acc = 65536 - f * acc / (k << 16);
    }
    (E_NEG_INT[n] * acc) >> 16
}

/// Fills `row` with the synthetic 12-bit row.
pub fn synthetic_row(row: &mut [u16; WIDTH]) {
    let mut rng: u32 = 0x2545_f491; // xorshift32 state
    for (i, px) in row.iter_mut().enumerate() {
        let x = (i as i64) << 16;
        // Background: 60 counts rising to ~120 across the row.
        let mut v: i64 = 60 + (i as i64) * 60 / WIDTH as i64;
        for s in &TRUTH {
            let d = x - s.position.0 as i64;
            let sigma = s.sigma.0 as i64;
            if d.abs() < 8 * sigma {
                // t = d² / (2σ²) in Q16; |d| < 8σ with σ ≤ 16 px keeps d²·2^16 in i64.
                let t = ((d * d) << 16) / (2 * sigma * sigma);
                v += (s.amplitude as i64 * exp_neg_q16(t) + (1 << 15)) >> 16;
            }
        }
        // Deterministic noise, uniform in −2..=2 counts.
        rng ^= rng << 13;
        rng ^= rng >> 17;
        rng ^= rng << 5;
        v += (rng % 5) as i64 - 2;
        *px = v.clamp(0, 4095) as u16;
    }
}

/// Outcome of the self-test.
pub struct Report {
    /// Stripes that matched a true stripe within [`TOLERANCE`].
    pub matched: usize,
    /// Worst absolute position error over the matched stripes.
    pub worst: Px,
}

/// The true stripe nearest to `s`, and the signed error `s − truth`.
pub fn nearest_truth(s: &Stripe) -> (usize, Px) {
    let mut best = (0, Px(i32::MAX));
    for (k, t) in TRUTH.iter().enumerate() {
        let err = Px(s.position.0 - t.position.0);
        if err.0.unsigned_abs() < best.1.0.unsigned_abs() {
            best = (k, err);
        }
    }
    best
}

/// Compares the detector's output with [`TRUTH`].
pub fn check<const N: usize>(found: &Stripes<N>) -> Report {
    let mut report = Report { matched: 0, worst: Px::ZERO };
    let mut seen = [false; TRUTH.len()];
    for s in found {
        let (k, err) = nearest_truth(s);
        let abs = Px(err.0.saturating_abs());
        if abs <= TOLERANCE && !seen[k] {
            seen[k] = true;
            report.matched += 1;
            report.worst = report.worst.max(abs);
        }
    }
    report
}

/// Runs the detector once on the synthetic row; returns the stripes and the
/// CPU cycles `detect` took (DWT cycle counter; 0 if it is not running).
pub fn run<const N: usize>(detector: &mut Detector<WIDTH>, out: &mut Stripes<N>) -> Result<u32, cms_core::peak::Error> {
    let mut row = [0u16; WIDTH];
    synthetic_row(&mut row);
    let t0 = cortex_m::peripheral::DWT::cycle_count();
    detector.detect(&row, out)?;
    Ok(cortex_m::peripheral::DWT::cycle_count().wrapping_sub(t0))
}
