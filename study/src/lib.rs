//! `cms-study`: synthetic stripe rows with known truth, the Cramér–Rao bound,
//! and the Monte-Carlo accuracy study with its speed rows.
//!
//! One implementation shared by `cms-host bench` (accuracy, speed), the
//! behaviour tests of `cms-core` (`cms-tests`) and the emulated head's build
//! script (which bakes the speed rows into the firmware image), so that the
//! figures the benchmarks print and the limits the tests assert come from the
//! same rows. Not published; not a test crate (nothing here asserts).
//!
//! The noise model is the one of docs/reference.md §1: `y_i = A·exp(−(i − x0)²/(2σ²)) + b
//! + n_i` with white Gaussian `n_i`, quantised to the sensor's bit depth.

use rand_core::{Rng as _, SeedableRng};
use rand_xoshiro::Xoshiro256StarStar;

/// The seeded generator of every study and test: `rand_xoshiro`'s
/// xoshiro256** seeded through SplitMix64 (`seed_from_u64`), with the two
/// draws the studies need. Uniforms take the top 53 bits; normals are
/// Box–Muller (one per two uniforms, the second discarded) so that a given
/// seed keeps producing the same rows, and so the same published figures.
#[derive(Clone, Debug)]
pub struct Rng(Xoshiro256StarStar);

impl Rng {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Rng {
        Rng(Xoshiro256StarStar::seed_from_u64(seed))
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// Cramér–Rao bound of the position of a sampled Gaussian stripe in white
/// noise (docs/reference.md §1): `(σn/A)·sqrt(2σ/√π)` px.
pub fn crlb(sigma: f64, amplitude: f64, noise: f64) -> f64 {
    noise / amplitude * (2.0 * sigma / std::f64::consts::PI.sqrt()).sqrt()
}

/// One Gaussian stripe: centre, σ and amplitude.
#[derive(Clone, Copy, Debug)]
pub struct Gauss {
    /// Centre, px.
    pub x0: f64,
    /// Width σ, px.
    pub sigma: f64,
    /// Peak height, counts.
    pub amplitude: f64,
}

/// The noiseless row: background plus stripes, f64.
pub fn clean_row(len: usize, background: f64, stripes: &[Gauss]) -> Vec<f64> {
    (0..len)
        .map(|i| {
            let i = i as f64;
            background
                + stripes
                    .iter()
                    .map(|g| g.amplitude * (-(i - g.x0).powi(2) / (2.0 * g.sigma * g.sigma)).exp())
                    .sum::<f64>()
        })
        .collect()
}

/// Noise σ for a measured SNR over the whole row, as MATLAB's
/// `awgn(x, snr_db, 'measured')`: signal power is the mean square of the
/// row's stripe signal (without the background, which the paper's synthetic
/// row does not have).
pub fn awgn_sigma(signal: &[f64], snr_db: f64) -> f64 {
    let p = signal.iter().map(|v| v * v).sum::<f64>() / signal.len() as f64;
    (p / 10f64.powf(snr_db / 10.0)).sqrt()
}

/// Adds white noise and quantises to `bits` (round to nearest, clamp).
pub fn quantise(row: &[f64], noise: f64, bits: u8, rng: &mut Rng) -> Vec<u16> {
    let max = ((1u32 << bits) - 1) as f64;
    row.iter().map(|v| (v + noise * rng.normal()).round().clamp(0.0, max) as u16).collect()
}
pub mod montecarlo;

#[cfg(test)]
mod tests {
    use super::Rng;

    /// The first outputs of xoshiro256** seeded by SplitMix64, computed
    /// independently (a Python transcription of the reference C code): the
    /// studies' rows, and so every published figure, depend on this stream.
    #[test]
    fn stream_is_xoshiro256starstar_from_splitmix64() {
        let mut r = Rng::new(42);
        assert_eq!(
            [r.next_u64(), r.next_u64(), r.next_u64()],
            [0x1578_0b2e_0c2e_c716, 0x6104_d986_6d11_3a7e, 0xae17_5332_39e4_99a1]
        );
        let mut r = Rng::new(0);
        assert_eq!([r.next_u64(), r.next_u64()], [0x99ec_5f36_cb75_f2b4, 0xbf6e_1f78_4956_452a]);
    }

    #[test]
    fn uniform_in_unit_interval_and_normal_has_unit_variance() {
        let mut r = Rng::new(7);
        let n = 20_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            let u = r.uniform();
            assert!((0.0..1.0).contains(&u));
            let z = r.normal();
            s += z;
            s2 += z * z;
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(mean.abs() < 0.03, "mean {mean}");
        assert!((var - 1.0).abs() < 0.04, "variance {var}");
    }
}
