//! Coherent imaging of a laser-lit rough surface: speckle.
//!
//! Steel ground or worn rough at the scale of the wavelength returns a
//! laser's light with a random phase from every point (fully developed
//! speckle). The lens passes only the spatial frequencies inside its pupil:
//! the image's field is the surface's field low-passed by the coherent
//! transfer function, a disc of radius `f_c = 1 / (2 λ N_eff)` cycles per
//! µm with `N_eff = N (1 + M)`, times the defocus phase `exp(i 2π W₀₂₀ ρ²)`
//! over it. The camera records the intensity, integrated over each pixel
//! and over the exposure (Goodman, *Speckle Phenomena in Optics*, 2007,
//! ch. 4–5). So:
//!
//! * one sample's intensity is exponentially distributed (contrast 1);
//! * a speckle (the first zero of the intensity's correlation, an Airy
//!   disc) is `2.44 λ N_eff` across;
//! * a pixel averages `M` speckles' worth of independent patterns, and its
//!   contrast is `1/√M` ([`pixel_contrast`], Goodman eq. 4.5-9 with the
//!   circular pupil's `|μ|²`);
//! * motion during the exposure moves the surface, and with it the pattern,
//!   under the fixed illumination: a longer integration window, so `M`
//!   grows and the contrast falls as `1/√K`.
//!
//! The field lives on a grid of `q` samples per pixel in both directions,
//! with `q` above twice the intensity's bandwidth (`4 f_c`), so the pixel
//! sums are a midpoint rule on a band-limited function. The filtering is
//! an FFT over the whole grid (`rustfft`), which guard bands of several
//! speckles keep from wrapping round.

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftNum, FftPlanner};
use std::sync::Arc;

/// A lens's coherent transfer function in pixel units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Pupil {
    /// Cut-off of the field's spectrum, cycles per pixel.
    pub cutoff_per_px: f64,
    /// Defocus: the wavefront error at the pupil's edge, waves (`W₀₂₀ / λ`).
    pub defocus_waves: f64,
}

impl Pupil {
    /// The pupil of a lens at F-number `f_number` imaging at magnification
    /// `magnification` onto pixels of `pitch_um`, light of `wavelength_um`;
    /// `image_defocus_um` is the image-side focus error (the object's
    /// distance from the plane of best focus times `M²`).
    pub fn new(wavelength_um: f64, f_number: f64, magnification: f64, pitch_um: f64, image_defocus_um: f64) -> Pupil {
        let n_eff = f_number * (1.0 + magnification);
        Pupil {
            cutoff_per_px: pitch_um / (2.0 * wavelength_um * n_eff),
            // W₀₂₀ = Δz·NA²/2 = Δz / (8 N_eff²).
            defocus_waves: image_defocus_um / (8.0 * n_eff * n_eff) / wavelength_um,
        }
    }

    /// A speckle's diameter (the Airy disc's first dark ring), px:
    /// `2.44 λ N_eff / pitch`.
    pub fn speckle_px(&self) -> f64 {
        1.22 / self.cutoff_per_px
    }

    /// Samples per pixel that resolve the intensity (above `4 f_c`), at least 2.
    pub fn samples_per_px(&self) -> usize {
        ((4.0 * self.cutoff_per_px).floor() as usize + 1).max(2)
    }
}

/// A size at least `n` whose factors are 2, 3 and 5 only (fast FFTs).
pub(crate) fn fft_size(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut k = m;
        for p in [2, 3, 5] {
            while k.is_multiple_of(p) {
                k /= p;
            }
        }
        if k == 1 {
            return m;
        }
        m += 1;
    }
}

/// The pupil filter for one grid size: plans and the transfer function,
/// made once and applied to many fields, in `f64` or `f32`.
///
/// The pupil passes only `|f| ≤ f_c`, a band of the columns' spectrum
/// (`2 f_c / q` of it: 42 % at F/4): the transform along the long axis, the
/// product and its inverse run over those columns only, the others being
/// zero after the product. The result is the full product's.
pub(crate) struct Filter<T: FftNum = f64> {
    w: usize,
    h: usize,
    fwd_w: Arc<dyn Fft<T>>,
    inv_w: Arc<dyn Fft<T>>,
    fwd_h: Arc<dyn Fft<T>>,
    inv_h: Arc<dyn Fft<T>>,
    /// The columns of the spectrum inside the pupil, ascending.
    live: Vec<usize>,
    /// The others, as ranges (zero after the product).
    dead: Vec<std::ops::Range<usize>>,
    /// Transfer function over the live columns, transposed (`h`
    /// frequencies along each of them), divided by `w·h` (the unnormalised
    /// transforms) and scaled so that a field of unit-amplitude random
    /// phases keeps unit mean intensity: the light the pupil collects is in
    /// the stripe's peak already.
    transfer: Vec<Complex<T>>,
}

impl<T: FftNum> Filter<T> {
    /// A filter for fields of `w × h` samples (`q` per pixel), row-major.
    #[cfg(test)]
    pub fn new(pupil: &Pupil, q: usize, w: usize, h: usize) -> Filter<T> {
        Filter::planned(&mut FftPlanner::new(), pupil, q, w, h)
    }

    /// A filter for fields of `w × h` samples (`q` per pixel), row-major,
    /// its transforms from `planner` (which keeps the plans of the sizes it
    /// has made: the same transforms, made once).
    pub fn planned(planner: &mut FftPlanner<T>, pupil: &Pupil, q: usize, w: usize, h: usize) -> Filter<T> {
        let freq = |k: usize, n: usize| {
            let s = if k <= n / 2 { k as f64 } else { k as f64 - n as f64 };
            s * q as f64 / n as f64
        };
        let fc2 = pupil.cutoff_per_px * pupil.cutoff_per_px;
        let mut live = Vec::new();
        let mut transfer = Vec::new();
        let mut inside = 0usize;
        for ku in 0..w {
            let fu = freq(ku, w);
            if fu * fu > fc2 {
                continue;
            }
            live.push(ku);
            for kv in 0..h {
                let fv = freq(kv, h);
                let rho2 = (fu * fu + fv * fv) / fc2;
                transfer.push(if rho2 <= 1.0 {
                    inside += 1;
                    let phase = 2.0 * std::f64::consts::PI * pupil.defocus_waves * rho2;
                    Complex::from_polar(1.0, phase)
                } else {
                    Complex::new(0.0, 0.0)
                });
            }
        }
        // |E|² of white unit phasors after the filter: inside / (w h).
        let scale = 1.0 / ((w * h) as f64 * (inside.max(1) as f64 / (w * h) as f64).sqrt());
        let cast = |x: f64| T::from_f64(x).expect("a float type");
        let transfer = transfer.into_iter().map(|t| Complex::new(cast(t.re * scale), cast(t.im * scale))).collect();
        let mut dead = Vec::new();
        let mut next = 0;
        for &ku in live.iter().chain(std::iter::once(&w)) {
            if ku > next {
                dead.push(next..ku);
            }
            next = ku + 1;
        }
        Filter {
            dead,
            w,
            h,
            fwd_w: planner.plan_fft_forward(w),
            inv_w: planner.plan_fft_inverse(w),
            fwd_h: planner.plan_fft_forward(h),
            inv_h: planner.plan_fft_inverse(h),
            live,
            transfer,
        }
    }

    /// Images `field` (row-major, `h` rows of `w`) through the pupil, in place.
    #[cfg(test)]
    pub fn apply(&self, field: &mut [Complex<T>]) {
        self.apply_with(field, &mut Vec::new());
    }

    /// Images `field` (row-major, `h` rows of `w`) through the pupil, in
    /// place, the pupil's columns transposed into `scratch` (kept by the
    /// caller across filters: its size is the filter's).
    pub fn apply_with(&self, field: &mut [Complex<T>], scratch: &mut Vec<Complex<T>>) {
        let (w, h) = (self.w, self.h);
        assert_eq!(field.len(), w * h, "field size");
        let zero = Complex::new(T::zero(), T::zero());
        scratch.resize(self.live.len() * h, zero);
        self.fwd_w.process(field);
        // The live columns, transposed into `scratch` (blocks of rows, for
        // the cache).
        const B: usize = 32;
        for r0 in (0..h).step_by(B) {
            let r1 = (r0 + B).min(h);
            for (col, &ku) in scratch.chunks_exact_mut(h).zip(&self.live) {
                for (s, f) in col[r0..r1].iter_mut().zip(field[r0 * w + ku..].iter().step_by(w)) {
                    *s = *f;
                }
            }
        }
        self.fwd_h.process(scratch);
        for (s, t) in scratch.iter_mut().zip(&self.transfer) {
            *s = *s * *t;
        }
        self.inv_h.process(scratch);
        for r0 in (0..h).step_by(B) {
            let r1 = (r0 + B).min(h);
            for row in field[r0 * w..r1 * w].chunks_exact_mut(w) {
                for d in &self.dead {
                    row[d.clone()].fill(zero);
                }
            }
            for (col, &ku) in scratch.chunks_exact(h).zip(&self.live) {
                for (f, s) in field[r0 * w + ku..].iter_mut().step_by(w).zip(&col[r0..r1]) {
                    *f = *s;
                }
            }
        }
        self.inv_w.process(field);
    }
}

/// A uniform random phasor for surface cell `(a, b)` of stream `stream`
/// (SplitMix64's finaliser over the mixed indices: independent of the
/// order cells are drawn in, so a surface point keeps its phase from frame
/// to frame).
#[inline]
pub(crate) fn phasor(seed: u64, stream: u64, a: i64, b: i64) -> Complex<f64> {
    let z = cell_hash(seed, stream, a, b);
    let phase = (z >> 11) as f64 * (std::f64::consts::TAU / (1u64 << 53) as f64);
    Complex::from_polar(1.0, phase)
}

/// [`phasor`] in `f32`: the same cell's phase to 24 bits (within 4·10⁻⁷
/// rad of it), its cosine and sine by polynomials on the nearest quarter
/// turn (within 3·10⁻⁷), without the library's `sin_cos`.
#[cfg(test)]
pub(crate) fn phasor_f32(seed: u64, stream: u64, a: i64, b: i64) -> Complex<f32> {
    phasor_of_turns(phase_turns(column_hash(seed, stream, a), b))
}

/// The part of a cell's hash its column `a` decides, shared by the cells
/// of a column ([`phase_turns`]).
#[inline]
pub(crate) fn column_hash(seed: u64, stream: u64, a: i64) -> u64 {
    let z = seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    mix(z ^ (a as u64).wrapping_mul(0xD1B5_4A32_D192_ED03))
}

/// The phase of cell `b` of a column, in 2⁻²⁴ turns.
#[inline]
pub(crate) fn phase_turns(column: u64, b: i64) -> i32 {
    (mix(column ^ (b as u64).wrapping_mul(0x8CB9_2BA7_2F3D_8DD7)) >> 40) as i32
}

/// The unit phasor of a phase in 2⁻²⁴ turns: the nearest quarter turn `k`
/// (2²² of them) and the rest `r` in [−π/4, π/4], its cosine and sine by
/// polynomials, turned by `k` quarters without branches (so that a row of
/// them vectorises).
#[inline]
pub(crate) fn phasor_of_turns(u: i32) -> Complex<f32> {
    let k = (u + (1 << 21)) >> 22;
    let r = (u - (k << 22)) as f32 * (std::f32::consts::FRAC_PI_2 / (1u32 << 22) as f32);
    let r2 = r * r;
    let sin = r * (1.0 + r2 * (-1.0 / 6.0 + r2 * (1.0 / 120.0 + r2 * (-1.0 / 5040.0 + r2 * (1.0 / 362_880.0)))));
    let cos = 1.0 + r2 * (-0.5 + r2 * (1.0 / 24.0 + r2 * (-1.0 / 720.0 + r2 * (1.0 / 40_320.0))));
    let odd = k & 1 != 0;
    let (x, y) = (if odd { -sin } else { cos }, if odd { cos } else { sin });
    let sign = if k & 2 != 0 { -1.0 } else { 1.0 };
    Complex::new(sign * x, sign * y)
}

#[inline]
pub(crate) fn cell_hash(seed: u64, stream: u64, a: i64, b: i64) -> u64 {
    mix(column_hash(seed, stream, a) ^ (b as u64).wrapping_mul(0x8CB9_2BA7_2F3D_8DD7))
}

fn mix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// `J₁(x)` by its integral `(1/π) ∫₀^π cos(τ − x sin τ) dτ` (Simpson,
/// 400 intervals: 1e-10 for |x| ≤ 30).
pub(crate) fn bessel_j1(x: f64) -> f64 {
    let n = 400;
    let h = std::f64::consts::PI / n as f64;
    let f = |t: f64| (t - x * t.sin()).cos();
    let mut s = f(0.0) + f(std::f64::consts::PI);
    for i in 1..n {
        s += f(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    s * h / 3.0 / std::f64::consts::PI
}

/// `|μ(r)|²` of a circular pupil: the normalised intensity correlation of
/// the speckle at a distance `r_px` (`[2 J₁(π r/(λN))/(π r/(λN))]²`, with
/// `λN = 1/(2 f_c)`).
pub(crate) fn mu2(pupil: &Pupil, r_px: f64) -> f64 {
    let x = std::f64::consts::PI * r_px * 2.0 * pupil.cutoff_per_px;
    if x < 1e-9 {
        return 1.0;
    }
    let j = 2.0 * bessel_j1(x) / x;
    j * j
}

/// The speckle contrast of an integration window of `lx × ly` px (a pixel,
/// lengthened along the rail by the motion during the exposure): `1/√M`
/// with `1/M = (1/(lx ly)²) ∬ (lx − |Δx|)(ly − |Δy|) |μ(Δx, Δy)|²`
/// (Goodman 2007, eq. 4.5-9), by the midpoint rule.
pub(crate) fn pixel_contrast(pupil: &Pupil, lx: f64, ly: f64) -> f64 {
    let n = 160;
    let (hx, hy) = (2.0 * lx / n as f64, 2.0 * ly / n as f64);
    let mut s = 0.0;
    for i in 0..n {
        let dx = -lx + (i as f64 + 0.5) * hx;
        for j in 0..n {
            let dy = -ly + (j as f64 + 0.5) * hy;
            s += (lx - dx.abs()) * (ly - dy.abs()) * mu2(pupil, (dx * dx + dy * dy).sqrt());
        }
    }
    (s * hx * hy / (lx * ly * lx * ly)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// F/8 at 685 nm on 6 µm pixels, M = 0.044 (the reference head).
    fn f8() -> Pupil {
        Pupil::new(0.685, 8.0, 0.044, 6.0, 0.0)
    }

    /// A uniformly lit field of `w × h` samples imaged through `pupil`:
    /// the sample intensities.
    fn uniform_speckle(pupil: &Pupil, w: usize, h: usize, seed: u64) -> Vec<f64> {
        let q = pupil.samples_per_px();
        let f = Filter::new(pupil, q, w, h);
        let mut field: Vec<Complex<f64>> =
            (0..w * h).map(|k| phasor(seed, 1, (k % w) as i64, (k / w) as i64)).collect();
        f.apply(&mut field);
        field.iter().map(|e| e.norm_sqr()).collect()
    }

    #[test]
    fn the_reference_lens_speckle_is_2_33_px_at_f8() {
        let p = f8();
        assert!((p.speckle_px() - 2.44 * 0.685 * 8.0 * 1.044 / 6.0).abs() < 1e-12);
        assert!((p.speckle_px() - 2.33).abs() < 0.01, "{}", p.speckle_px());
        assert_eq!(p.samples_per_px(), 3);
        assert_eq!(Pupil::new(0.685, 4.0, 0.044, 6.0, 0.0).samples_per_px(), 5);
        assert!((bessel_j1(3.831_705_970_207_512)).abs() < 1e-9);
        assert!((bessel_j1(1.0) - 0.440_050_585_744_933_5).abs() < 1e-10);
    }

    #[test]
    fn fully_developed_speckle_has_unit_mean_and_contrast_per_sample() {
        let p = f8();
        let i = uniform_speckle(&p, 240, 240, 7);
        let n = i.len() as f64;
        let mean = i.iter().sum::<f64>() / n;
        let var = i.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
        // About 240²/(q·2.33)² ≈ 1200 independent speckles: ±3 % on each.
        assert!((mean - 1.0).abs() < 0.06, "mean {mean}");
        assert!((var.sqrt() / mean - 1.0).abs() < 0.06, "contrast {}", var.sqrt() / mean);
        // Exponential statistics: P(I > 2⟨I⟩) = e⁻² = 0.135.
        let tail = i.iter().filter(|&&v| v > 2.0 * mean).count() as f64 / n;
        assert!((tail - 0.135).abs() < 0.02, "{tail}");
    }

    #[test]
    fn speckle_size_is_the_airy_disc() {
        // The intensity's autocovariance along a row falls to its first
        // zero at the Airy radius 1.22 λ N_eff (half a speckle's diameter).
        let p = f8();
        let q = p.samples_per_px();
        let (w, h) = (360, 360);
        let mut cov = [0.0; 12];
        for seed in 0..4 {
            let i = uniform_speckle(&p, w, h, seed);
            let mean = i.iter().sum::<f64>() / i.len() as f64;
            for (lag, c) in cov.iter_mut().enumerate() {
                let mut s = 0.0;
                for r in 0..h {
                    for u in 0..w - lag {
                        s += (i[r * w + u] - mean) * (i[r * w + u + lag] - mean);
                    }
                }
                *c += s / (h * (w - lag)) as f64;
            }
        }
        let first_min = (1..cov.len()).find(|&k| cov[k] < cov[k + 1]).unwrap();
        let radius_px = first_min as f64 / q as f64;
        let want = p.speckle_px() / 2.0;
        assert!((radius_px - want).abs() <= 0.5 / q as f64 + 0.05, "{radius_px} vs {want}");
        // And the whole curve follows |μ|²: at one sample, and half the radius.
        for lag in [1, 2] {
            let want = mu2(&p, lag as f64 / q as f64);
            assert!((cov[lag] / cov[0] - want).abs() < 0.05, "lag {lag}: {} vs {want}", cov[lag] / cov[0]);
        }
    }

    /// Per-pixel contrast, at rest and with the window lengthened by motion.
    #[test]
    fn pixel_contrast_follows_goodman_and_motion_averages() {
        let p = f8();
        let q = p.samples_per_px();
        let (w, h) = (360, 720);
        for stretch_px in [0usize, 4, 12] {
            let (mut s, mut s2, mut n) = (0.0, 0.0, 0.0);
            for seed in 0..3 {
                let i = uniform_speckle(&p, w, h, 100 + seed);
                // Windows of 1 × (1 + stretch) px, every window-length apart.
                let rows_per = q * (1 + stretch_px);
                for r0 in (0..h - rows_per).step_by(rows_per) {
                    for c0 in (0..w - q).step_by(q) {
                        let mut v = 0.0;
                        for r in r0..r0 + rows_per {
                            for c in c0..c0 + q {
                                v += i[r * w + c];
                            }
                        }
                        v /= (rows_per * q) as f64;
                        s += v;
                        s2 += v * v;
                        n += 1.0;
                    }
                }
            }
            let mean = s / n;
            let contrast = (s2 / n - mean * mean).sqrt() / mean;
            let want = pixel_contrast(&p, 1.0, 1.0 + stretch_px as f64);
            assert!((contrast / want - 1.0).abs() < 0.05, "stretch {stretch_px}: {contrast} vs {want}");
            if stretch_px == 0 {
                // 0.70 for the reference lens at F/8 (2.33 px speckle on 1 px).
                assert!((want - 0.70).abs() < 0.02, "{want}");
            }
        }
        // Long windows: M grows with the length, contrast as 1/√K.
        let (c4, c16) = (pixel_contrast(&p, 1.0, 4.0), pixel_contrast(&p, 1.0, 16.0));
        assert!((c4 / c16 - 2.0).abs() < 0.2, "{c4} {c16}");
    }

    #[test]
    fn defocus_blurs_but_keeps_the_light() {
        let sharp = Pupil::new(0.685, 4.0, 0.044, 6.0, 0.0);
        let blurred = Pupil::new(0.685, 4.0, 0.044, 6.0, 60.0);
        assert!((blurred.defocus_waves - 60.0 / (8.0 * 4.176 * 4.176) / 0.685).abs() < 1e-3);
        for p in [sharp, blurred] {
            let i = uniform_speckle(&p, 200, 200, 3);
            let mean = i.iter().sum::<f64>() / i.len() as f64;
            assert!((mean - 1.0).abs() < 0.05, "{mean}");
        }
    }

    #[test]
    fn the_f32_phasor_is_the_f64_one() {
        let mut worst = 0.0f64;
        for a in -300..300 {
            for b in 0..100 {
                let (p, q) = (phasor(9, 5, a, b), phasor_f32(9, 5, a, b));
                worst = worst.max((p.re - f64::from(q.re)).abs()).max((p.im - f64::from(q.im)).abs());
            }
        }
        assert!(worst < 1e-6, "{worst}");
    }

    #[test]
    fn fft_sizes_are_smooth() {
        assert_eq!(fft_size(7), 8);
        assert_eq!(fft_size(241), 243);
        assert_eq!(fft_size(1), 1);
        assert_eq!(fft_size(1441), 1458);
    }
}
