//! Wheel-encoder arithmetic (`cms_core::odometer`): counter wrap-around,
//! counts → µm, direction, and the frame-every-N-µm trigger, against an
//! exact model (the true count as an unbounded integer).

use cms_core::odometer::{DistanceTrigger, Odometer};
use proptest::prelude::*;

/// What a hardware counter of `bits` shows after `count` counts from `start`.
fn raw(bits: u8, start: u32, count: i64) -> u32 {
    let m = if bits == 32 { 1u64 << 32 } else { 1u64 << bits };
    ((start as i64 as i128 + count as i128).rem_euclid(m as i128)) as u32
}

proptest! {
    /// Any walk whose steps stay under half the counter range between reads
    /// gives exactly the true count and distance, however often it wraps.
    #[test]
    fn wrapping_counters_track_the_true_count(
        bits in prop_oneof![Just(16u8), Just(32u8)],
        start in any::<u32>(),
        nm in 1u32..2_000_000,
        reverse in any::<bool>(),
        steps in proptest::collection::vec(-32_767i64..=32_767, 1..400),
    ) {
        let start = raw(bits, start, 0);
        let mut o = Odometer::new(bits, start, nm, reverse).unwrap();
        let mut truth = 0i64;
        for s in steps {
            // 32-bit counters get large steps too (scaled into their range).
            let s = if bits == 32 { s * 65_536 } else { s };
            truth += s;
            let d = o.update(raw(bits, start, truth));
            let counted = if reverse { -truth } else { truth };
            prop_assert_eq!(o.count(), counted);
            // µm from the exact count: floor(count · nm / 1000), no drift.
            prop_assert_eq!(d as i128, (counted as i128 * nm as i128).div_euclid(1000));
        }
    }

    /// Monotonic travel fires once per interval: after travelling D µm from
    /// the arming point, fired + skipped = floor(D / N), and a frame never
    /// fires between boundaries.
    #[test]
    fn distance_trigger_counts_every_boundary(
        every in 1u32..100_000,
        origin in -1_000_000_000i64..1_000_000_000,
        forward in any::<bool>(),
        steps in proptest::collection::vec(0i64..300_000, 1..300),
    ) {
        let mut t = DistanceTrigger::new(every, origin).unwrap();
        let (mut fired, mut skipped, mut d) = (0u64, 0u64, 0i64);
        for s in steps {
            d += s;
            let p = if forward { origin + d } else { origin - d };
            if let Some(k) = t.poll(p) {
                fired += 1;
                skipped += k as u64;
            }
            prop_assert_eq!(fired + skipped, (d / every as i64) as u64, "at {} um", d);
        }
    }

    /// Jitter back and forth around a position never fires more than the
    /// boundaries actually crossed in the net direction plus the returns.
    #[test]
    fn dithering_within_one_interval_fires_at_most_once(every in 10u32..10_000, jitter in proptest::collection::vec(0u32..10, 1..100)) {
        // Arm at 0 and sit just across the first boundary, dithering by less
        // than one interval: one frame at the boundary, then none.
        let mut t = DistanceTrigger::new(every, 0).unwrap();
        let mut fired = 0;
        for j in jitter {
            let p = every as i64 + (j as i64 * every as i64 / 20) - (every as i64 / 4);
            if p >= every as i64 && t.poll(p).is_some() {
                fired += 1;
            }
        }
        prop_assert!(fired <= 1);
    }
}

#[test]
fn a_wheel_of_known_size_measures_a_kilometre() {
    // A 200 mm wheel with a 2500-line encoder, ×4 quadrature: 10 000 counts
    // per 628.318 5 mm turn = 62 831.85 nm per count, rounded to 62 832.
    let nm = 62_832;
    let mut o = Odometer::new(16, 0, nm, false).unwrap();
    let turns = 1_000_000_000 / 628_318 + 1; // just over a kilometre
    let mut c = 0i64;
    for _ in 0..turns {
        c += 10_000;
        o.update(raw(16, 0, c));
    }
    assert_eq!(o.count(), turns * 10_000);
    assert_eq!(o.distance_um(), turns * 10_000 * nm as i64 / 1000);
    assert!(o.distance_um() > 1_000_000_000);
}
