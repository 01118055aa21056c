//! Shared helpers for the behaviour tests of `cms-core`: synthetic rows with
//! known truth, the Cramér–Rao bound, and a small deterministic RNG.
//!
//! The noise model is the one of docs/reference.md §1: `y_i = A·exp(−(i − x0)²/(2σ²)) + b
//! + n_i` with white Gaussian `n_i`, quantised to the sensor's bit depth.

/// xoshiro256** seeded by splitmix64: deterministic, dependency-free.
#[derive(Clone, Debug)]
pub struct Rng([u64; 4]);

impl Rng {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Rng {
        let mut z = seed;
        let mut next = || {
            z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut x = z;
            x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            x ^ (x >> 31)
        };
        Rng([next(), next(), next(), next()])
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.0;
        let result = s[1].wrapping_mul(5).rotate_left(7).wrapping_mul(9);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
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
pub mod reference;
