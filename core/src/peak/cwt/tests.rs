use super::kernels::PHASES;
use super::*;

/// A row with structure and noise (xorshift), values up to 16 bits.
fn row(n: usize, seed: u64) -> [i32; 160] {
    let mut s = seed | 1;
    core::array::from_fn(|i| {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        let bump = if (i as isize - n as isize / 2).abs() < 6 { 40_000 } else { 0 };
        ((s % 25_000) as i32 + bump).min(65_535)
    })
}

/// The 32-bit pair equals the 64-bit one wherever the plan allows it:
/// 12-bit rows (the widest rung whose bound holds at 4095), every
/// phase it takes, every position whose taps fit the row.
#[test]
fn slope_pair32_matches_slope_pair() {
    let sat = 4095i64;
    let top = (0..=kernels::PAIR_RUNGS).take_while(|&k| sat * RUNGS[k].deriv_abs < 1 << 31).last().unwrap();
    assert!(top >= 9, "12-bit rows take the 32-bit slope up to rung {top}");
    for seed in 1..4u64 {
        let full = row(160, seed).map(|v| v & 4095);
        // Full scale where the taps are largest, too.
        let mut hot = full;
        hot[70..90].fill(4095);
        for x in [&full[..], &hot[..]] {
            for k in 0..=top {
                let (d, dp) = (kernels::deriv(k), kernels::DerivPairs::of(k).unwrap());
                let w = 2 * dp.per_phase();
                assert!(w == d.half_len() || w == d.half_len() + 1);
                for c in 0..x.len() {
                    for p in 0..PHASES {
                        let got = slope_pair32(x, c, p, dp);
                        if (1..PHASES - 1).contains(&p) && c + 1 >= w && c + w < x.len() {
                            let (a, b) = got.unwrap();
                            assert_eq!((a as i64, b as i64), slope_pair(x, c as isize, p, d), "k {k} c {c} p {p}");
                        } else {
                            assert_eq!(got, None, "k {k} c {c} p {p}");
                        }
                    }
                }
            }
        }
    }
}

/// From a guess in the zero's bracket, the bracketed zero
/// ([`slope_zero`]'s) itself; from a guess a phase beside it, the line
/// through the first pair, extrapolated, within 2·10⁻⁴ px of it for
/// σ ≥ 1.5 px; from further (up to 4 phases), a later pass that lands
/// within a phase of it, as close. Noiseless Gaussian stripes on
/// 12-bit rows, every 1/64 px, the fit rung nearest 1.5 σ, both slope
/// paths.
#[test]
fn a_phase_beside_the_pair() {
    extern crate std;
    let mut worst = [0.0f64; 3];
    for sigma in [1.5f64, 2.5, 4.0, 10.0] {
        let j = kernels::nearest_rung(Px::from_f64(1.5 * sigma));
        let d = kernels::deriv(j);
        for o in 0..64 {
            let x0 = 80.0 + o as f64 / 64.0;
            let x: [i32; 160] = core::array::from_fn(|i| {
                let t = (i as f64 - x0) / sigma;
                (200.0 + 3000.0 * std::primitive::f64::exp(-0.5 * t * t)).round() as i32
            });
            let c = 80 + o / 32;
            let z = slope_zero(&x, c, d).unwrap().0;
            // The bracket's first phase, from c.
            let b = ((z as i64 - ((c as i64) << 16)) >> 12) as i32;
            for pairs in [None, kernels::DerivPairs::of(j)] {
                for g in b - 4..=b + 4 {
                    let got = slope_zero_near(&x, c, g, d, pairs).unwrap().0;
                    let e = (got - z).abs() as f64 / 65536.0;
                    let at = match (g - b).abs() {
                        0 => 0,
                        1 => 1,
                        _ => 2,
                    };
                    worst[at] = worst[at].max(e);
                }
            }
        }
    }
    assert!(worst[0] < 2e-5, "{worst:?}");
    assert!(worst[1] < 2e-4 && worst[2] < 2e-4, "{worst:?}");
}

/// Every response of 16-bit pixels fits i32 with room for the sums of
/// three that `confirm` forms (below 2^28): `sat × Σ|ψ| × norm / 2^24`.
#[test]
fn responses_fit_32_bits() {
    for (k, r) in RUNGS.iter().enumerate() {
        let bound = (65_535 * r.ricker_abs * r.norm) >> NORM_SHIFT;
        assert!(bound < 1 << 26, "rung {k}: {bound}");
        assert!(r.norm < 1 << 31);
    }
}

/// The rung constants `confirm` multiplies as 32-bit values fit them.
#[test]
fn rung_constants_fit_32_bits() {
    for (k, r) in RUNGS.iter().enumerate() {
        assert!(i32::try_from(r.noise_q8.0).is_ok(), "rung {k}: noise {}", r.noise_q8.0);
        assert!(i32::try_from(r.amp_inv).is_ok(), "rung {k}: amp_inv {}", r.amp_inv);
    }
}

/// The 32-bit sum straight from the row equals the 64-bit one on the
/// rungs the plan allows for 12-bit rows, wherever its taps fit.
#[test]
fn ricker_sum32_matches_response() {
    let sat = 4095i64;
    let top =
        (0..kernels::LADDER_LEN).take_while(|&k| sat * (RUNGS[k].ricker_abs + (1 << 15)) < 1 << 31).last().unwrap();
    assert!(top >= 9, "12-bit rows take the 32-bit responses up to rung {top}");
    for seed in 1..4u64 {
        let full = row(160, seed).map(|v| v & 4095);
        let mut hot = full;
        hot[60..100].fill(4095);
        for x in [&full[..], &hot[..]] {
            for (k, rung) in RUNGS.iter().enumerate().take(top + 1) {
                let reach = 2 * kernels::ricker_pairs(k).len() - 1;
                for c in 0..x.len() {
                    match ricker_sum32(x, c, k) {
                        Some(acc) => {
                            assert_eq!((acc as i64 * rung.norm) >> NORM_SHIFT, response_q8(x, c, k).0, "{k} {c}")
                        }
                        None => assert!(c < reach || c + reach >= x.len(), "k {k} c {c}"),
                    }
                }
            }
        }
    }
}

/// Both by definition: every tap, indices clamped to the row.
#[test]
fn response_and_slope_match_direct_sums() {
    for seed in 1..4u64 {
        for n in [20usize, 97, 160] {
            let full = row(n, seed);
            let x = &full[..n];
            let at = |i: isize| x[i.clamp(0, n as isize - 1) as usize] as i64;
            for k in [0, 3, 6, 9] {
                let h = kernels::ricker(k);
                let d = kernels::deriv(k);
                for c in 0..n {
                    let sum: i64 = (-(h.len() as isize - 1)..h.len() as isize)
                        .map(|m| h[m.unsigned_abs()] as i64 * at(c as isize + m))
                        .sum();
                    assert_eq!(response_q8(x, c, k).0, (sum * RUNGS[k].norm) >> NORM_SHIFT, "k {k} c {c} n {n}");
                    let mut buf = [0i32; 160];
                    let mut f = Folded::new(x, c, &mut buf[..n]);
                    for k2 in [k, k + 2, k + 1] {
                        assert_eq!(f.response_q8(k2), response_q8(x, c, k2), "k {k2} c {c} n {n}");
                    }
                    for p in 0..PHASES {
                        let next = slope_at(x, c as isize, p + 1, d);
                        assert_eq!(slope_pair(x, c as isize, p, d), (slope_at(x, c as isize, p, d), next));
                    }
                    if c + 1 < n {
                        assert_eq!(slope_at(x, c as isize, PHASES, d), slope_at(x, c as isize + 1, 0, d));
                    }
                    for p in [0, 1, 7, PHASES - 1] {
                        // Σ x[i] D(i − (c + p/P)), D odd: table index |i − c|·P ∓ p.
                        let mut s = 0i64;
                        for m in 1.. {
                            let j = m * PHASES - p;
                            if j >= d.len() {
                                break;
                            }
                            s += at(c as isize + m as isize) * d.at(j) as i64;
                        }
                        for m in 0.. {
                            let j = m * PHASES + p;
                            if j >= d.len() {
                                break;
                            }
                            s -= at(c as isize - m as isize) * d.at(j) as i64;
                        }
                        assert_eq!(slope_at(x, c as isize, p, d), s, "k {k} c {c} p {p} n {n}");
                    }
                }
            }
        }
    }
}
