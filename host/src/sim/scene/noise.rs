//! Image noise of a digital camera (paper §4, Table 1) and the seeded
//! random numbers behind it (`rand_xoshiro`'s xoshiro256++, with a
//! hand-written ziggurat for the normal deviates).
//!
//! All quantities are in electrons (sensor-referred), so one scene looks the
//! same at 8, 10 or 12 bits apart from the quantisation; the camera's
//! [`gain`](super::Camera::gain_e_per_dn) converts to codes. Per pixel:
//!
//! ```text
//! S = ambient(u, v) + dark(hot pixel) + Σ stripes          photo-signal, e⁻
//! e = S + N(0, sqrt(S·[shot] + read²)) + row(v, frame) + column(u)
//! code = clamp(round(e / gain), 0, 2^bits − 1)             saturation + quantisation
//! ```
//!
//! * **random** noise: Gaussian read noise and photon shot noise (Gaussian
//!   with variance = signal, the Poisson limit), new every frame;
//! * **fixed-pattern** noise: hot pixels (a fixed random set of pixels of the
//!   sensor, each with its own dark current, so brighter with longer
//!   exposures) and fixed column offsets;
//! * **banding**: a random offset per row, new every frame;
//! * **ambient** light behind the band-pass filter: an offset with a linear
//!   gradient across the image, scaling with the exposure.
//!
//! The random numbers of a row depend only on (seed, frame, row), so a row
//! rendered alone equals the same row of the whole frame, in any order.

use rand_xoshiro::Xoshiro256PlusPlus;
use rand_xoshiro::rand_core::{Rng as _, SeedableRng};

use super::{SimError, check};

/// The noise and ambient light of the sensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseModel {
    /// Read noise σ, electrons.
    pub read_noise_e: f64,
    /// Photon shot noise on the photo-signal (ambient, stripes, dark current).
    pub shot_noise: bool,
    /// Ambient light at the principal point, electrons per µs of exposure.
    pub ambient_e_per_us: f64,
    /// Ambient gradient: relative change per column and per row, [1/px, 1/px]
    /// (e.g. `[5e-4, 0]`: +5 % 100 columns right of the principal point).
    pub ambient_gradient_per_px: [f64; 2],
    /// Banding: σ of a random offset of each row, new every frame, electrons.
    pub row_banding_e: f64,
    /// Banding: σ of a fixed offset of each column (fixed per sensor), electrons.
    pub column_banding_e: f64,
    /// Fraction of hot pixels (fixed positions per sensor), in [0, 0.1].
    pub hot_pixel_fraction: f64,
    /// Mean dark signal of a hot pixel, electrons per µs of exposure (each
    /// hot pixel draws a fixed factor in [0.5, 1.5] of it).
    pub hot_pixel_e_per_us: f64,
}

impl Default for NoiseModel {
    /// The reference sensor: 25 e⁻ read noise, shot noise, 10 e⁻/µs ambient
    /// (1000 e⁻ ≈ 13 codes at 100 µs, 8 bits) with a +5 %/100 px gradient
    /// across and +3 %/100 px along, 15 e⁻ row banding, 10 e⁻ column
    /// banding, 1 hot pixel in 10 000 at 40 e⁻/µs (4000 e⁻ ≈ 51 codes at
    /// 100 µs).
    fn default() -> Self {
        NoiseModel {
            read_noise_e: 25.0,
            shot_noise: true,
            ambient_e_per_us: 10.0,
            ambient_gradient_per_px: [5e-4, 3e-4],
            row_banding_e: 15.0,
            column_banding_e: 10.0,
            hot_pixel_fraction: 1e-4,
            hot_pixel_e_per_us: 40.0,
        }
    }
}

impl NoiseModel {
    /// No noise and no ambient light: the ideal, deterministic image (still
    /// saturated and quantised).
    pub fn none() -> NoiseModel {
        NoiseModel {
            read_noise_e: 0.0,
            shot_noise: false,
            ambient_e_per_us: 0.0,
            ambient_gradient_per_px: [0.0, 0.0],
            row_banding_e: 0.0,
            column_banding_e: 0.0,
            hot_pixel_fraction: 0.0,
            hot_pixel_e_per_us: 0.0,
        }
    }

    /// Whether rendering draws random numbers at all.
    pub(crate) fn is_random(&self) -> bool {
        self.read_noise_e > 0.0 || self.shot_noise || self.row_banding_e > 0.0
    }

    pub(crate) fn validate(&self) -> Result<(), SimError> {
        for (f, v) in [
            ("noise.read_noise_e", self.read_noise_e),
            ("noise.ambient_e_per_us", self.ambient_e_per_us),
            ("noise.row_banding_e", self.row_banding_e),
            ("noise.column_banding_e", self.column_banding_e),
            ("noise.hot_pixel_e_per_us", self.hot_pixel_e_per_us),
        ] {
            check(f, v, v >= 0.0, "finite and ≥ 0")?;
        }
        for (f, v) in [
            ("noise.ambient_gradient_per_px[0]", self.ambient_gradient_per_px[0]),
            ("noise.ambient_gradient_per_px[1]", self.ambient_gradient_per_px[1]),
        ] {
            check(f, v, v.is_finite(), "finite")?;
        }
        let h = self.hot_pixel_fraction;
        check("noise.hot_pixel_fraction", h, (0.0..=0.1).contains(&h), "in [0, 0.1]")?;
        Ok(())
    }
}

/// The fixed pattern of one sensor: column offsets and hot pixels.
#[derive(Clone, Debug)]
pub(crate) struct SensorPattern {
    /// Offset of each column, electrons.
    pub column_offset_e: Vec<f64>,
    /// Hot pixels of row `r` are `hot[hot_start[r]..hot_start[r + 1]]`.
    pub hot_start: Vec<u32>,
    /// (column, dark signal in electrons per µs of exposure).
    pub hot: Vec<(u32, f64)>,
}

impl SensorPattern {
    pub(crate) fn new(noise: &NoiseModel, width: usize, height: usize, seed: u64) -> SensorPattern {
        let mut rng = Rng::for_stream(seed, 0x5345_4e53, 0, 0);
        let column_offset_e = (0..width)
            .map(|_| if noise.column_banding_e > 0.0 { noise.column_banding_e * rng.normal() } else { 0.0 })
            .collect();
        let total = width * height;
        let count = (noise.hot_pixel_fraction * total as f64).round() as usize;
        let mut pos: Vec<usize> = Vec::with_capacity(count);
        // Distinct positions: draw, sort, dedup, top up (count ≤ 10 % of the sensor).
        while pos.len() < count {
            while pos.len() < count {
                pos.push((rng.next_u64() % total as u64) as usize);
            }
            pos.sort_unstable();
            pos.dedup();
        }
        let mut hot_start = vec![0u32; height + 1];
        let mut hot = Vec::with_capacity(count);
        for &p in &pos {
            hot_start[p / width + 1] += 1;
            let factor = 0.5 + rng.uniform();
            hot.push(((p % width) as u32, noise.hot_pixel_e_per_us * factor));
        }
        for r in 0..height {
            hot_start[r + 1] += hot_start[r];
        }
        SensorPattern { column_offset_e, hot_start, hot }
    }

    /// Hot pixels of a row: (column, dark electrons per µs).
    pub(crate) fn hot_in_row(&self, row: usize) -> &[(u32, f64)] {
        &self.hot[self.hot_start[row] as usize..self.hot_start[row + 1] as usize]
    }
}

/// The simulator's seeded generator: xoshiro256++ from `rand_xoshiro`,
/// one per (stream, item). The state of item `(a, b)` of a stream is
/// SplitMix64 seeded with a value chained from `(seed, stream, a, b)`
/// through SplitMix64 outputs — exactly what the hand-written generator this
/// replaced did, so every simulated image, roughness table and sensor
/// pattern is bit-identical to before (pinned by a test below).
#[derive(Clone, Debug)]
pub(crate) struct Rng(Xoshiro256PlusPlus);

/// One SplitMix64 step (Vigna's `splitmix64.c`): mixes the stream and item
/// indices into the seed; `rand_xoshiro`'s `SplitMix64` has no way to take
/// the mixed value out between steps, so this one line stays.
fn splitmix(z: &mut u64) -> u64 {
    *z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut x = *z;
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

impl Rng {
    /// The generator of one stream (sensor pattern, roughness, frame noise)
    /// and, within it, of item `(a, b)` (frame, row): independent of the
    /// order in which items are drawn.
    pub(crate) fn for_stream(seed: u64, stream: u64, a: u64, b: u64) -> Rng {
        let mut z = seed;
        for k in [stream, a, b] {
            z = splitmix(&mut z) ^ k.wrapping_mul(0xD1B5_4A32_D192_ED03);
        }
        // `seed_from_u64` fills the state with four SplitMix64 outputs from `z`.
        Rng(Xoshiro256PlusPlus::seed_from_u64(z))
    }

    #[inline(always)]
    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// Uniform in [0, 1).
    pub(crate) fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// One standard normal (256-layer ziggurat, Marsaglia & Tsang 2000, with
    /// the layer and the abscissa from disjoint bits of one draw: about 99 %
    /// of draws cost one multiplication and a comparison).
    pub(crate) fn normal(&mut self) -> f64 {
        self.normal_with(ziggurat())
    }

    /// [`Rng::normal`] with the tables at hand (hot loops).
    #[inline(always)]
    pub(crate) fn normal_with(&mut self, z: &Ziggurat) -> f64 {
        loop {
            let bits = self.next_u64();
            let i = (bits & 0xff) as usize;
            // Uniform in (−1, 1) from the top 53 bits.
            let u = ((bits >> 11) as f64 + 0.5) * (2.0 / (1u64 << 53) as f64) - 1.0;
            let x = u * z.x[i];
            if x.abs() < z.x[i + 1] {
                return x;
            }
            if i == 0 {
                // The tail beyond r (Marsaglia 1964).
                let r = z.x[1];
                loop {
                    let a = -(1.0 - self.uniform()).ln() / r;
                    let b = -(1.0 - self.uniform()).ln();
                    if 2.0 * b >= a * a {
                        return if u < 0.0 { -(r + a) } else { r + a };
                    }
                }
            }
            if z.f[i + 1] + (z.f[i] - z.f[i + 1]) * self.uniform() < (-0.5 * x * x).exp() {
                return x;
            }
        }
    }
}

/// Ziggurat tables: layer edges `x[0] = v/f(r) > x[1] = r > … > x[256] = 0`
/// and `f[i] = exp(−x[i]²/2)`.
pub(crate) struct Ziggurat {
    x: [f64; 257],
    f: [f64; 257],
}

pub(crate) fn ziggurat() -> &'static Ziggurat {
    static Z: std::sync::OnceLock<Ziggurat> = std::sync::OnceLock::new();
    Z.get_or_init(|| {
        const R: f64 = 3.654_152_885_361_009;
        const V: f64 = 0.004_928_673_233_99;
        let f = |x: f64| (-0.5 * x * x).exp();
        let mut x = [0.0; 257];
        x[0] = V / f(R);
        x[1] = R;
        for i in 1..255 {
            x[i + 1] = (-2.0 * (V / x[i] + f(x[i])).ln()).sqrt();
        }
        x[256] = 0.0;
        let fx = x.map(f);
        Ziggurat { x, f: fx }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normals_have_unit_variance() {
        let mut r = Rng::for_stream(1, 2, 3, 4);
        let n = 1_000_000;
        let (mut s, mut s2, mut s4) = (0.0, 0.0, 0.0);
        let mut beyond = [0usize; 4];
        for _ in 0..n {
            let a = r.normal();
            s += a;
            s2 += a * a;
            s4 += a * a * a * a;
            for (k, b) in beyond.iter_mut().enumerate() {
                *b += usize::from(a.abs() > (k + 1) as f64);
            }
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        let kurt = s4 / n as f64;
        assert!(mean.abs() < 0.004 && (var - 1.0).abs() < 0.005 && (kurt - 3.0).abs() < 0.05, "{mean} {var} {kurt}");
        // P(|x| > k) for k = 1..4: 0.3173, 0.0455, 0.0027, 6.3e-5.
        let want = [0.317_31, 0.045_50, 0.002_70, 0.000_063];
        for k in 0..4 {
            let p = beyond[k] as f64 / n as f64;
            let sd = (want[k] * (1.0 - want[k]) / n as f64).sqrt();
            assert!((p - want[k]).abs() < 5.0 * sd, "|x| > {}: {p} vs {}", k + 1, want[k]);
        }
    }

    /// The stream is the one of the hand-written xoshiro256++ this module
    /// had before `rand_xoshiro` (values printed by that implementation):
    /// every seeded figure of the simulator stays as it was.
    #[test]
    fn stream_is_bit_identical_to_the_former_generator() {
        let mut r = Rng::for_stream(1, 0x4e4f_4953, 7, 240);
        let got = [r.next_u64(), r.next_u64(), r.next_u64()];
        assert_eq!(got, [0x586b_ed59_3cad_f511, 0x3f63_5386_ca28_aebc, 0x24dc_7b88_ee03_cd71]);
        let mut r = Rng::for_stream(0, 0, 0, 0);
        let last = (0..1000).map(|_| r.next_u64()).last();
        assert_eq!(last, Some(0x5ec4_eba9_8bed_fabd));
    }

    #[test]
    fn streams_are_independent_of_order() {
        let a = Rng::for_stream(9, 1, 5, 6).next_u64();
        let _ = Rng::for_stream(9, 1, 5, 7).next_u64();
        assert_eq!(a, Rng::for_stream(9, 1, 5, 6).next_u64());
        assert_ne!(a, Rng::for_stream(9, 1, 6, 5).next_u64());
        assert_ne!(a, Rng::for_stream(10, 1, 5, 6).next_u64());
    }

    #[test]
    fn hot_pixels_distinct_and_counted() {
        let n = NoiseModel { hot_pixel_fraction: 0.01, ..NoiseModel::default() };
        let p = SensorPattern::new(&n, 100, 50, 3);
        assert_eq!(p.hot.len(), 50);
        let mut all: Vec<(usize, u32)> =
            (0..50).flat_map(|r| p.hot_in_row(r).iter().map(move |&(c, _)| (r, c))).collect();
        let len = all.len();
        all.dedup();
        assert_eq!(all.len(), len);
        assert!(p.hot.iter().all(|&(_, e)| (20.0..=60.0).contains(&e)));
    }
}
