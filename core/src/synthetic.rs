//! A synthetic sensor scene: the image rows an emulated sensor head sees,
//! computed with integers only, so that a Cortex-M under QEMU and a PC produce
//! the same pixels bit for bit.
//!
//! The scene is the reference head's (752 × 480, 12 bits, three lasers) over
//! a corrugated rail, simplified to what the detector and the pipeline care
//! about. In row `r` of a frame exposed at odometer `s`, laser `k` draws one
//! Gaussian stripe
//!
//! ```text
//! x_k(r, s) = centre_k + slope_k·r + crown_k·(r − H/2)²/(H/2)² + gain_k·z(s + along_k)
//! z(s)      = Σ_j  A_j·sin(2π·s/λ_j)                       (corrugation, nm)
//! ```
//!
//! of σ `sigma_k` and height `amplitude_k × exposure / nominal exposure`
//! (clamped to 4×), on a background rising linearly across the row, plus
//! noise: an Irwin–Hall sum of four uniform bytes (nearly Gaussian, RMS
//! `noise_q8 / 256` counts) from an xorshift32 seeded by the seed, the
//! odometer, the row and the laser mask. The pixel is clamped to the bit
//! depth (bright stripes saturate, as on a sensor).
//!
//! # Design
//! * Integer only: `e^(−t)` from a table of `e^(−n)` (Q30) and a degree-7
//!   Horner polynomial of the fractional part; `sin` from a quarter-wave table
//!   of 65 Q15 values with linear interpolation. Integer division truncates
//!   towards zero on every target, so there is nothing left to differ.
//! * A row depends only on `(config, odometer, mask, exposure, row)` — the
//!   values a `Profile` carries — so a host can regenerate the rows of every
//!   frame it receives from the frame alone ([`SceneCamera::travel_to`]).
//!
//! # Cost
//! Per pixel one xorshift step and a few multiplies; per pixel within 6 σ of
//! a stripe one `exp` (about 40 integer operations). About 25 000 Thumb-2
//! instructions for a 752-px row with three stripes (a third of the
//! detector's cost).

use crate::fixed::{Px, UQ8_8};
use crate::pipeline::Camera;
use crate::protocol::LASERS;
use crate::readout::{Readout, RowSampling};

/// One laser's stripe in the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LaserStripe {
    /// Stripe centre in row 0 on a flat rail, px.
    pub centre: Px,
    /// Change of the centre per row (the line's tilt in the image), px per row.
    pub slope: Px,
    /// Extra offset at the first and last row relative to the middle row
    /// (the rail head's crown bends the line), px.
    pub crown: Px,
    /// Stripe σ, px.
    pub sigma: Px,
    /// Stripe height above background at the nominal exposure, counts.
    pub amplitude: u16,
    /// Where along the rail this laser meets it, relative to the odometer, µm.
    pub along_um: i32,
    /// Image shift per millimetre of rail height (triangulation gain), px/mm.
    pub gain_px_per_mm: Px,
}

/// One corrugation component.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Wave {
    /// Wavelength along the rail, µm.
    pub wavelength_um: u32,
    /// Amplitude (half peak-to-peak), nm.
    pub amplitude_nm: i32,
}

/// Everything that decides the pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SceneConfig {
    /// Row length, px.
    pub width: u16,
    /// Rows per frame.
    pub height: u16,
    /// Bits per pixel, 8..=16.
    pub bits: u8,
    /// Seed of the noise.
    pub seed: u32,
    /// The three lasers, left to right.
    pub lasers: [LaserStripe; LASERS],
    /// Corrugation components.
    pub waves: [Wave; 2],
    /// Background at the row's start, counts.
    pub background: u16,
    /// Background rise across the row, counts.
    pub background_rise: u16,
    /// Noise RMS, counts.
    pub noise_q8: UQ8_8,
    /// Exposure at which the stripes have their `amplitude`, µs.
    pub nominal_exposure_us: u32,
    /// Travel speed of the head along the rail, µm per ms (= mm/s).
    pub speed_um_per_ms: u32,
}

impl SceneConfig {
    /// The reference head's scene: 752 × 480, 12 bits, stripes of σ 1.8,
    /// 2.4 and 3.0 px (inside the default detector's 1.5–4 px), 2–3 counts of
    /// noise, corrugation of 50 mm × 30 µm and 120 mm × 15 µm seen at
    /// 20 px/mm, the head travelling at 1 m/s.
    pub const fn reference(seed: u32) -> SceneConfig {
        const fn px_q(whole: i32, frac_q16: i32) -> Px {
            Px(whole * 65536 + frac_q16)
        }
        SceneConfig {
            width: 752,
            height: 480,
            bits: 12,
            seed,
            lasers: [
                LaserStripe {
                    centre: px_q(178, 20480),
                    slope: Px(2621), // 0.04 px/row
                    crown: px_q(-5, 0),
                    sigma: px_q(1, 52429), // 1.8
                    amplitude: 1700,
                    along_um: 0,
                    gain_px_per_mm: px_q(20, 0),
                },
                LaserStripe {
                    centre: px_q(371, 45875),
                    slope: Px(655), // 0.01 px/row
                    crown: px_q(-6, 0),
                    sigma: px_q(2, 26214), // 2.4
                    amplitude: 2400,
                    along_um: 12_000,
                    gain_px_per_mm: px_q(20, 0),
                },
                LaserStripe {
                    centre: px_q(574, 9830),
                    slope: Px(-1966), // −0.03 px/row
                    crown: px_q(-5, 0),
                    sigma: px_q(3, 0),
                    amplitude: 1300,
                    along_um: 24_000,
                    gain_px_per_mm: px_q(20, 0),
                },
            ],
            waves: [
                Wave { wavelength_um: 50_000, amplitude_nm: 30_000 },
                Wave { wavelength_um: 120_000, amplitude_nm: 15_000 },
            ],
            background: 60,
            background_rise: 60,
            noise_q8: UQ8_8(640), // 2.5 counts
            nominal_exposure_us: 200,
            speed_um_per_ms: 1000,
        }
    }
}

/// Why a scene configuration was refused.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SceneError {
    /// Width or height is zero.
    Size,
    /// Bits outside 8..=16.
    BitDepth(u8),
    /// A stripe σ outside 0.5..=16 px.
    Sigma(u8),
    /// A corrugation wavelength is zero.
    Wavelength,
    /// The nominal exposure is zero.
    Exposure,
}

impl core::fmt::Display for SceneError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SceneError::Size => f.write_str("scene width and height must be positive"),
            SceneError::BitDepth(b) => write!(f, "scene bit depth {b} is outside 8..=16"),
            SceneError::Sigma(k) => write!(f, "stripe σ of laser {k} is outside 0.5..=16 px"),
            SceneError::Wavelength => f.write_str("corrugation wavelength must be positive"),
            SceneError::Exposure => f.write_str("nominal exposure must be positive"),
        }
    }
}

impl core::error::Error for SceneError {}

/// A validated scene.
#[derive(Clone, Copy, Debug)]
pub struct Scene {
    cfg: SceneConfig,
}

/// Pixels farther than this many σ from a stripe get none of it (e^(−18)
/// of a 16-bit amplitude is below half a count).
const REACH_SIGMAS: i64 = 6;

impl Scene {
    /// Validates `cfg`.
    pub fn new(cfg: SceneConfig) -> Result<Scene, SceneError> {
        if cfg.width == 0 || cfg.height == 0 {
            return Err(SceneError::Size);
        }
        if !(8..=16).contains(&cfg.bits) {
            return Err(SceneError::BitDepth(cfg.bits));
        }
        for (k, l) in cfg.lasers.iter().enumerate() {
            if !(32768..=16 * 65536).contains(&l.sigma.0) {
                return Err(SceneError::Sigma(k as u8));
            }
        }
        if cfg.waves.iter().any(|w| w.wavelength_um == 0) {
            return Err(SceneError::Wavelength);
        }
        if cfg.nominal_exposure_us == 0 {
            return Err(SceneError::Exposure);
        }
        Ok(Scene { cfg })
    }

    /// The configuration.
    pub fn config(&self) -> &SceneConfig {
        &self.cfg
    }

    /// Rail height under laser `k` at odometer `odometer_um`, nm.
    pub fn height_nm(&self, k: usize, odometer_um: i64) -> i64 {
        let s = odometer_um + self.cfg.lasers[k].along_um as i64;
        self.cfg
            .waves
            .iter()
            .map(|w| {
                let lambda = w.wavelength_um as i64;
                let phase = (s.rem_euclid(lambda) << 32) / lambda; // [0, 2^32): a turn
                (w.amplitude_nm as i64 * sin_q15(phase as u32) as i64) >> 15
            })
            .sum()
    }

    /// The true centre of laser `k`'s stripe in row `r`, Q16.16 px (before
    /// the pixel noise and quantisation).
    pub fn centre(&self, k: usize, odometer_um: i64, r: u16) -> Px {
        let l = &self.cfg.lasers[k];
        let mid = (self.cfg.height as i64 / 2).max(1);
        let d = r as i64 - mid;
        let crown = l.crown.0 as i64 * d * d / (mid * mid);
        let shift = l.gain_px_per_mm.0 as i64 * self.height_nm(k, odometer_um) / 1_000_000;
        Px((l.centre.0 as i64 + l.slope.0 as i64 * r as i64 + crown + shift) as i32)
    }

    /// Row `r` of a frame exposed at `odometer_um` for `exposure_us` with the
    /// lasers of `mask` lit, into `out` (`width` pixels; a longer `out` is
    /// filled up to `width`, a shorter one up to its length).
    pub fn row(&self, odometer_um: i64, mask: u8, exposure_us: u32, r: u16, out: &mut [u16]) {
        let c = &self.cfg;
        let n = out.len().min(c.width as usize);
        let full = (1i64 << c.bits) - 1;
        let mut rng = row_seed(c.seed, odometer_um, mask, r);
        for (i, px) in out[..n].iter_mut().enumerate() {
            let bg = c.background as i64 + c.background_rise as i64 * i as i64 / c.width as i64;
            rng = xorshift32(rng);
            let b = rng.to_le_bytes();
            let sum = b.iter().map(|&v| v as i64).sum::<i64>() - 510;
            // Irwin–Hall of four bytes: RMS 255·√(4/12) = 147.2 (147 here).
            let noise = sum * c.noise_q8.0 as i64 / (147 * 256);
            *px = (bg + noise).clamp(0, full) as u16;
        }
        let gain_q16 = ((exposure_us as i64) << 16) / c.nominal_exposure_us as i64;
        let gain_q16 = gain_q16.min(4 << 16);
        for (k, l) in c.lasers.iter().enumerate() {
            if mask & (1 << k) == 0 {
                continue;
            }
            let x0 = self.centre(k, odometer_um, r).0 as i64;
            let sigma = l.sigma.0 as i64;
            let amp = l.amplitude as i64 * gain_q16; // counts, Q16
            let lo = ((x0 - REACH_SIGMAS * sigma) >> 16).max(0);
            let hi = ((x0 + REACH_SIGMAS * sigma) >> 16).min(n as i64 - 1);
            let two_s2 = (2 * sigma * sigma) >> 16; // 2σ², Q16
            for i in lo..=hi {
                let d = (i << 16) - x0;
                // t = d²/(2σ²), Q16; |d| ≤ 6σ ≤ 96 px keeps d² within i64.
                let t = (d * d) / two_s2.max(1);
                let v = (((amp * exp_neg_q30(t)) >> 30) + (1 << 15)) >> 16;
                let p = &mut out[i as usize];
                *p = (*p as i64 + v).min(full) as u16;
            }
        }
    }
}

/// The noise generator's start for one row: a splitmix of everything that
/// names the row (never zero, as xorshift32 needs).
fn row_seed(seed: u32, odometer_um: i64, mask: u8, r: u16) -> u32 {
    let mut z = ((seed as u64) << 32) ^ (odometer_um as u64) ^ ((r as u64) << 48) ^ ((mask as u64) << 40);
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z as u32 ^ (z >> 32) as u32) | 1
}

fn xorshift32(mut x: u32) -> u32 {
    x ^= x << 13;
    x ^= x >> 17;
    x ^= x << 5;
    x
}

/// `e^(−t)`, `t ≥ 0` in Q16, result in Q30.
fn exp_neg_q30(t: i64) -> i64 {
    /// e^(−n), n = 0..=16, Q30.
    const WHOLE: [i64; 17] = [
        1_073_741_824,
        395_007_542,
        145_315_154,
        53_458_458,
        19_666_268,
        7_234_816,
        2_661_540,
        979_126,
        360_200,
        132_510,
        48_748,
        17_933,
        6_597,
        2_427,
        893,
        328,
        121,
    ];
    let n = (t >> 16) as usize;
    if n >= WHOLE.len() {
        return 0;
    }
    // e^(−f), f ∈ [0, 1): 1 − f(1 − f/2(1 − f/3(… (1 − f/7)))), Q30; the
    // truncation error is below f^8/8! < 2.5·10^−5.
    let f = (t & 0xffff) << 14; // Q30
    let mut acc: i64 = 1 << 30;
    for k in (1..=7i64).rev() {
        acc = (1 << 30) - ((f * acc) >> 30) / k;
    }
    (WHOLE[n] * acc) >> 30
}

/// `sin(2π·phase/2^32)`, Q15.
fn sin_q15(phase: u32) -> i32 {
    /// sin(π/2 · i/64), i = 0..=64, Q15 (×32767).
    const QUARTER: [i32; 65] = [
        0, 804, 1608, 2410, 3212, 4011, 4808, 5602, 6393, 7179, 7962, 8739, 9512, 10278, 11039, 11793, 12539, 13279,
        14010, 14732, 15446, 16151, 16846, 17530, 18204, 18868, 19519, 20159, 20787, 21403, 22005, 22594, 23170, 23731,
        24279, 24811, 25329, 25832, 26319, 26790, 27245, 27683, 28105, 28510, 28898, 29268, 29621, 29956, 30273, 30571,
        30852, 31113, 31356, 31580, 31785, 31971, 32137, 32285, 32412, 32521, 32609, 32678, 32728, 32757, 32767,
    ];
    let quadrant = phase >> 30;
    let within = phase & 0x3fff_ffff; // [0, 2^30): a quarter turn
    let pos = if quadrant & 1 == 0 { within } else { (1 << 30) - within };
    let i = (pos >> 24) as usize; // 64 steps per quarter
    let frac = ((pos >> 8) & 0xffff) as i32;
    let v = if i >= 64 { QUARTER[64] } else { QUARTER[i] + (((QUARTER[i + 1] - QUARTER[i]) * frac) >> 16) };
    if quadrant >= 2 { -v } else { v }
}

/// The scene as a [`Camera`]: what an emulated head's sensor is, and how a
/// host replays a received frame. The odometer an exposure reports is the one
/// set last by [`SceneCamera::travel_to`] (from the head's clock on the
/// emulated head, from the received `Profile` on a host).
#[derive(Clone, Debug)]
pub struct SceneCamera {
    scene: Scene,
    odometer_um: i64,
    exposure: Option<(i64, u8, u32)>,
    /// The rows it reads (as the sensor would: only these), and the next
    /// of them (an index into the readout).
    readout: Readout,
    next_row: u16,
}

/// A row was asked for with no frame exposed, or past the last row.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NoFrame;

impl SceneCamera {
    /// A camera at odometer 0.
    pub fn new(scene: Scene) -> SceneCamera {
        let readout = Readout::full(scene.cfg.height);
        SceneCamera { scene, odometer_um: 0, exposure: None, readout, next_row: 0 }
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Moves the head to `odometer_um` (the next exposure's).
    pub fn travel_to(&mut self, odometer_um: i64) {
        self.odometer_um = odometer_um;
    }

    /// The odometer of a head travelling at the scene's speed for `t_us`.
    pub fn odometer_at(&self, t_us: u64) -> i64 {
        (t_us as i64).saturating_mul(self.scene.cfg.speed_um_per_ms as i64) / 1000
    }
}

impl Camera for SceneCamera {
    type Error = NoFrame;
    fn width(&self) -> u16 {
        self.scene.cfg.width
    }
    fn height(&self) -> u16 {
        self.scene.cfg.height
    }
    fn bits(&self) -> u8 {
        self.scene.cfg.bits
    }
    fn expose(&mut self, exposure_us: u32, laser_mask: u8) -> Result<i64, NoFrame> {
        self.exposure = Some((self.odometer_um, laser_mask, exposure_us));
        self.next_row = 0;
        Ok(self.odometer_um)
    }
    fn read_row(&mut self, row: &mut [u16]) -> Result<(), NoFrame> {
        let (odometer, mask, exposure) = self.exposure.ok_or(NoFrame)?;
        if self.next_row >= self.readout.rows_read() {
            self.exposure = None;
            return Err(NoFrame);
        }
        self.scene.row(odometer, mask, exposure, self.readout.sensor_row(self.next_row), row);
        self.next_row += 1;
        Ok(())
    }
    fn set_readout(&mut self, readout: &Readout) -> Result<RowSampling, NoFrame> {
        if readout.end_row() > self.scene.cfg.height {
            return Err(NoFrame);
        }
        self.readout = *readout;
        Ok(RowSampling::Skip)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::peak::{Detector, Stripes};
    use crate::pipeline::default_detector;

    #[test]
    fn exp_and_sin_follow_f64() {
        extern crate std;
        use std::primitive::f64;
        for t in (0..17 * 65536).step_by(997) {
            let want = f64::exp(-(t as f64) / 65536.0);
            let got = exp_neg_q30(t) as f64 / (1u64 << 30) as f64;
            assert!((got - want).abs() < 3e-5, "t {t}: {got} vs {want}");
        }
        assert_eq!(exp_neg_q30(17 << 16), 0);
        for p in (0..u32::MAX).step_by(9_999_991) {
            let want = f64::sin(p as f64 / 4294967296.0 * core::f64::consts::TAU);
            let got = sin_q15(p) as f64 / 32767.0;
            assert!((got - want).abs() < 2e-4, "phase {p}: {got} vs {want}");
        }
    }

    #[test]
    fn the_detector_finds_every_stripe_near_its_centre() {
        let scene = Scene::new(SceneConfig::reference(7)).unwrap();
        let mut d = Detector::<752>::new(default_detector()).unwrap();
        let mut row = [0u16; 752];
        let mut worst = 0;
        for (odo, r) in [(0i64, 0u16), (33_333, 17), (1_000_000, 240), (-5_000, 479)] {
            scene.row(odo, 0b111, 200, r, &mut row);
            let mut s: Stripes<3> = Stripes::new();
            d.detect(&row[..], &mut s).unwrap();
            assert_eq!(s.len(), 3, "odometer {odo} row {r}");
            for (k, st) in s.iter().enumerate() {
                let err = st.position.abs_diff(scene.centre(k, odo, r)).0;
                worst = worst.max(err);
            }
        }
        // 1/10 px: stripes of 1300–2400 counts over 2.5 counts of noise.
        assert!(worst < 6554, "worst error {worst} (Q16)");
    }

    #[test]
    fn rows_depend_on_what_names_them_and_nothing_else() {
        let scene = Scene::new(SceneConfig::reference(1)).unwrap();
        let (mut a, mut b) = ([0u16; 752], [0u16; 752]);
        scene.row(1234, 0b101, 200, 9, &mut a);
        scene.row(1234, 0b101, 200, 9, &mut b);
        assert_eq!(a, b);
        scene.row(1235, 0b101, 200, 9, &mut b);
        assert_ne!(a, b, "odometer");
        scene.row(1234, 0b111, 200, 9, &mut b);
        assert_ne!(a, b, "mask");
        // Lasers off: background and noise only.
        scene.row(1234, 0, 200, 9, &mut b);
        assert!(b.iter().all(|&p| p < 140), "{:?}", b.iter().max());
        // A long exposure saturates the stripes.
        scene.row(0, 0b010, 2000, 0, &mut b);
        assert_eq!(b.iter().max(), Some(&4095));
    }

    #[test]
    fn corrugation_moves_the_stripes() {
        let scene = Scene::new(SceneConfig::reference(1)).unwrap();
        // 30 µm at 50 mm plus 15 µm at 120 mm (at most 45 µm together), 20 px/mm.
        let peak = (0..120_000).step_by(500).map(|s| scene.height_nm(0, s)).max().unwrap();
        assert!((35_000..=45_000).contains(&peak), "{peak}");
        let shift = scene.centre(0, 12_500, 240).0 - scene.centre(0, 0, 240).0;
        assert!(shift.abs() > 65536 / 4, "{shift}");
    }

    #[test]
    fn bad_scenes_are_refused() {
        let mut c = SceneConfig::reference(1);
        c.bits = 7;
        assert_eq!(Scene::new(c).unwrap_err(), SceneError::BitDepth(7));
        let mut c = SceneConfig::reference(1);
        c.lasers[2].sigma = Px(1000);
        assert_eq!(Scene::new(c).unwrap_err(), SceneError::Sigma(2));
        let mut c = SceneConfig::reference(1);
        c.waves[1].wavelength_um = 0;
        assert_eq!(Scene::new(c).unwrap_err(), SceneError::Wavelength);
    }

    #[test]
    fn the_camera_serves_one_frame_of_rows() {
        let mut cam = SceneCamera::new(Scene::new(SceneConfig::reference(3)).unwrap());
        let mut row = [0u16; 752];
        assert_eq!(cam.read_row(&mut row), Err(NoFrame));
        cam.travel_to(cam.odometer_at(40_000));
        assert_eq!(cam.expose(200, 0b111), Ok(40_000));
        let mut want = [0u16; 752];
        for r in 0..480 {
            cam.read_row(&mut row).unwrap();
            cam.scene().row(40_000, 0b111, 200, r, &mut want);
            assert_eq!(row, want);
        }
        assert_eq!(cam.read_row(&mut row), Err(NoFrame));
    }
}
