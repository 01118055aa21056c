//! Invariants of the detector, property-tested.

use cms_core::fixed::Px;
use cms_core::optics::ScaleRange;
use cms_core::peak::{Config, Detector, Method, Select, Stripes};
use cms_tests::{Gauss, Rng, clean_row, quantise};
use proptest::prelude::*;

const W: usize = 2048;

fn detector(method: Method, bits: u8) -> Box<Detector<W>> {
    let mut cfg = Config::new(bits, ScaleRange::new(Px::from_f64(1.5), Px::from_f64(4.0)).unwrap());
    cfg.method = method;
    cfg.select = Select::All;
    Box::new(Detector::new(cfg).unwrap())
}

fn detect<P: cms_core::peak::Pixel>(det: &mut Detector<W>, row: &[P]) -> Stripes<16> {
    let mut out = Stripes::new();
    det.detect(row, &mut out).unwrap();
    out
}

fn noisy_row(len: usize, x0: f64, sigma: f64, seed: u64) -> Vec<u16> {
    let mut rng = Rng::new(seed);
    quantise(&clean_row(len, 300.0, &[Gauss { x0, sigma, amplitude: 2500.0 }]), 5.0, 12, &mut rng)
}

fn method() -> impl Strategy<Value = Method> {
    proptest::sample::select(Method::ALL.to_vec())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    /// Shifting a row by k pixels shifts every stripe by exactly k.
    #[test]
    fn shift_moves_the_peak_by_the_same_amount(
        m in method(), frac in 0.0f64..1.0, sigma in 1.6f64..3.8, k in 1usize..40, seed in any::<u64>()
    ) {
        let row = noisy_row(400, 180.0 + frac, sigma, seed);
        // The shifted row: k samples of the same background noise in front.
        let mut shifted = noisy_row(k, -1000.0, sigma, seed ^ 1);
        shifted.extend_from_slice(&row);
        let mut det = detector(m, 12);
        let a = detect(&mut det, &row);
        let b = detect(&mut det, &shifted);
        prop_assert_eq!(a.len(), 1);
        prop_assert_eq!(b.len(), 1);
        let d = b[0].position.to_f64() - a[0].position.to_f64() - k as f64;
        prop_assert!(d.abs() < 1e-4, "{}: shift error {d}", m.name());
    }

    /// Mirroring a row mirrors every stripe: x ↦ (n − 1) − x.
    #[test]
    fn mirror_mirrors_the_peak(m in method(), frac in 0.0f64..1.0, sigma in 1.6f64..3.8, seed in any::<u64>()) {
        let row = noisy_row(401, 200.0 + frac, sigma, seed);
        let mut rev = row.clone();
        rev.reverse();
        let mut det = detector(m, 12);
        let a = detect(&mut det, &row);
        let b = detect(&mut det, &rev);
        prop_assert_eq!(a.len(), 1);
        prop_assert_eq!(b.len(), 1);
        let d = a[0].position.to_f64() + b[0].position.to_f64() - 400.0;
        // Max picks the first of equal pixels, so mirroring may move it by one.
        let tol = if m == Method::Max { 1.0 + 1e-9 } else { 1e-4 };
        prop_assert!(d.abs() <= tol, "{}: mirror error {d}", m.name());
    }

    /// Random bytes: no stripe (white noise has no stripe in it) in rows
    /// long enough to measure their noise on; shorter ones are
    /// `white_noise_in_short_rows_is_rarely_a_stripe`'s.
    #[test]
    fn random_bytes_give_no_stripe(m in method(), bytes in proptest::collection::vec(any::<u8>(), 32..1500)) {
        let mut det = detector(m, 8);
        let out = detect(&mut det, &bytes);
        prop_assert!(out.is_empty(), "{}: {out:?}", m.name());
    }

    /// Random bytes of any length: never a panic.
    #[test]
    fn random_bytes_never_panic(m in method(), bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
        let mut det = detector(m, 8);
        let out = detect(&mut det, &bytes);
        prop_assert!(out.len() <= 16);
    }

    /// Speckled stripes — a Gaussian envelope times exponential speckle,
    /// anywhere in the row (its ends included), dim to far past
    /// saturation, several close together: never a panic, and every
    /// stripe inside the row or flagged as cut by its end.
    #[test]
    fn speckled_rows_never_panic(
        m in method(),
        bits in prop::sample::select(vec![8u8, 12]),
        len in 8usize..200,
        lines in prop::collection::vec((-0.1f64..1.1, 1.0f64..8.0, 0.0f64..4.0), 1..5),
        seed in any::<u64>(),
    ) {
        let max = f64::from((1u32 << bits) - 1);
        let mut rng = Rng::new(seed);
        let row: Vec<u16> = (0..len)
            .map(|i| {
                let envelope: f64 = lines
                    .iter()
                    .map(|&(at, sigma, peak)| peak * max * (-0.5 * ((i as f64 - at * len as f64) / sigma).powi(2)).exp())
                    .sum();
                // Exponential speckle: −ln(U), U uniform in (0, 1].
                let speckle = -(1.0 - rng.uniform()).max(1e-12).ln();
                (envelope * speckle + 2.0 * rng.uniform()).round().clamp(0.0, max) as u16
            })
            .collect();
        let mut det = detector(m, bits);
        let out = detect(&mut det, &row);
        // A stripe cut by the row's end may be placed a little past it, and
        // says so (clipped); any other lies inside the row.
        let inside = |s: &cms_core::peak::Stripe| (0.0..=(len - 1) as f64).contains(&s.position.to_f64());
        prop_assert!(out.iter().all(|s| inside(s) || s.flags.contains(cms_core::peak::Flags::CLIPPED)), "{out:?}");
        if bits == 8 {
            let bytes: Vec<u8> = row.iter().map(|&v| v as u8).collect();
            let out = detect(&mut det, &bytes);
            prop_assert!(out.len() <= 16);
        }
    }

    /// Random 16-bit words as 16-bit pixels: never a panic.
    #[test]
    fn random_words_never_panic(m in method(), words in proptest::collection::vec(any::<u16>(), 0..1500)) {
        let mut det = detector(m, 16);
        let out = detect(&mut det, &words);
        prop_assert!(out.len() <= 16);
    }
}

#[test]
fn degenerate_rows_give_no_stripe() {
    for m in Method::ALL {
        for bits in [8u8, 12, 16] {
            let max = ((1u32 << bits) - 1) as u16;
            let mut det = detector(m, bits);
            for len in 0..=3 {
                for v in [0, 1, max / 2, max] {
                    assert!(detect(&mut det, &vec![v; len]).is_empty());
                }
            }
            for len in [4, 5, 7, 100, 752, W] {
                for v in [0u16, 1, 1000.min(max), max] {
                    let out = detect(&mut det, &vec![v; len]);
                    assert!(out.is_empty(), "{} bits {bits} len {len} value {v}: {out:?}", m.name());
                }
            }
        }
    }
}

#[test]
fn row_longer_than_buffers_is_an_error() {
    let mut det = detector(Method::Cwt, 12);
    let mut out: Stripes<4> = Stripes::new();
    let row = vec![0u16; W + 1];
    assert_eq!(det.detect(&row, &mut out), Err(cms_core::peak::Error::RowTooLong { len: W + 1, max: W }));
}

#[test]
fn configuration_is_validated_once() {
    use cms_core::peak::Error;
    let scales = ScaleRange::new(Px::from_f64(1.5), Px::from_f64(4.0)).unwrap();
    let ok = Config::new(12, scales);
    let check = |f: &dyn Fn(&mut Config), e: Error| {
        let mut c = ok;
        f(&mut c);
        assert_eq!(Detector::<64>::new(c).err(), Some(e));
    };
    check(&|c| c.bits = 7, Error::BitDepth(7));
    check(&|c| c.bits = 17, Error::BitDepth(17));
    check(&|c| c.max_stripes = 0, Error::MaxStripes);
    check(&|c| c.threshold_sigma_q8 = 0, Error::Threshold);
    check(&|c| c.saturation = 5000, Error::Saturation);
    check(&|c| c.min_width = c.max_width, Error::WidthRange);
    check(&|c| c.scales = ScaleRange::new(Px::from_f64(0.5), Px::from_f64(4.0)).unwrap(), Error::ScaleTooSmall);
    check(&|c| c.scales = ScaleRange::new(Px::from_f64(2.0), Px::from_f64(30.0)).unwrap(), Error::ScaleTooLarge);
    assert!(Detector::<64>::new(ok).is_ok());
}

/// Two rows of a kind the properties above draw (one in about 2 000):
/// white noise of σ 5 whose last or first pixels stand a little high. The
/// Ricker kernel near the row's end reads the edge pixel repeated past
/// it and can take them for a wide, weak, clipped stripe; so near an end
/// a stripe must pass twice the threshold, and each row has its one
/// stripe only.
#[test]
fn a_noisy_edge_pixel_is_no_stripe() {
    let mut det = detector(Method::Cwt, 12);
    let row = noisy_row(401, 200.0, 1.6, 10_106_275_183_394_868_772);
    let mut rev = row.clone();
    rev.reverse();
    let mut shifted = noisy_row(5, -1000.0, 1.6, 16_305_263_258_708_476_157 ^ 1);
    shifted.extend_from_slice(&noisy_row(400, 180.0, 1.6, 16_305_263_258_708_476_157));
    for (row, x0) in [(&row, 200.0), (&rev, 200.0), (&shifted, 185.0)] {
        det.refresh_noise();
        let out = detect(&mut det, row);
        assert_eq!(out.len(), 1, "{out:?}");
        assert!((out[0].position.to_f64() - x0).abs() < 0.05, "{out:?}");
    }
}
