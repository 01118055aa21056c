//! The camera: pinhole with skew and Brown–Conrady distortion (OpenCV
//! convention), and the sensor's photometric limits.
//!
//! Axes: `x` right, `y` down, `z` forward, millimetres. A point `(X, Y, Z)`
//! goes to normalised coordinates `(x, y) = (X/Z, Y/Z)`, is distorted
//!
//! ```text
//! r² = x² + y²,  k = 1 + k1·r² + k2·r⁴ + k3·r⁶
//! x_d = x·k + 2·p1·x·y + p2·(r² + 2x²)
//! y_d = y·k + p1·(r² + 2y²) + 2·p2·x·y
//! ```
//!
//! and lands on pixel `u = fx·x_d + skew·y_d + cx`, `v = fy·y_d + cy`
//! (the skew in pixels, as `α_c` of the paper's Eq. 6; OpenCV's `alpha` is
//! `skew / fx`). Pixel centres are at integer coordinates: `(0, 0)` is the
//! centre of the first pixel, as for `cms_core::peak` positions.

use super::SimError;
use super::check;

/// A camera: intrinsics, distortion, image size, bit depth, exposure and
/// full-well capacity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Image width, pixels (columns: across the stripes).
    pub width_px: usize,
    /// Image height, pixels (rows: one position along the rail each).
    pub height_px: usize,
    /// Focal length along x (columns), pixels.
    pub fx_px: f64,
    /// Focal length along y (rows), pixels.
    pub fy_px: f64,
    /// Principal point, column, pixels.
    pub cx_px: f64,
    /// Principal point, row, pixels.
    pub cy_px: f64,
    /// Skew, pixels (the (0, 1) entry of the camera matrix).
    pub skew_px: f64,
    /// Radial distortion r² coefficient.
    pub k1: f64,
    /// Radial distortion r⁴ coefficient.
    pub k2: f64,
    /// Tangential distortion coefficient p1.
    pub p1: f64,
    /// Tangential distortion coefficient p2.
    pub p2: f64,
    /// Radial distortion r⁶ coefficient.
    pub k3: f64,
    /// Pixel pitch, µm (informational: focal length in mm = fx · pitch).
    pub pixel_pitch_um: f64,
    /// ADC bit depth, 8..=16 (8, 10, 12 are the usual).
    pub bits: u8,
    /// Exposure time, µs (scales the laser, ambient light and dark signal).
    pub exposure_us: f64,
    /// Full-well capacity, electrons: it maps to the largest code.
    pub full_well_e: f64,
}

impl Camera {
    /// The reference head's camera: an MT9V034-class 752 × 480 global-shutter
    /// sensor (6 µm pixels, 8-bit over the DCMI port) behind an 8.4 mm M12
    /// lens, so `fx = fy = 8.4 mm / 6 µm = 1400 px`; the principal point a few
    /// pixels off centre and a mild barrel distortion (−1 % at the corners),
    /// as a calibration of such a lens gives. Full well 20 000 e⁻, exposure
    /// 100 µs (0.2 mm of travel at 2 m/s: no motion blur worth modelling).
    pub fn reference() -> Camera {
        Camera {
            width_px: 752,
            height_px: 480,
            fx_px: 1400.0,
            fy_px: 1400.0,
            cx_px: 379.2,
            cy_px: 236.8,
            skew_px: 0.0,
            k1: -0.09,
            k2: 0.12,
            p1: 2.0e-4,
            p2: -1.5e-4,
            k3: 0.0,
            pixel_pitch_um: 6.0,
            bits: 8,
            exposure_us: 100.0,
            full_well_e: 20_000.0,
        }
    }

    /// The paper's camera (Table 4): Canon EOS 500D, 4752 × 3168 (22.3 mm
    /// wide: 4.69 µm pixels), 24 mm focal length = 5106 / 5107 px, principal
    /// point at the centre, no distortion (§5.2 neglects it), 8-bit
    /// grayscale, 1/4000 s exposure (§2.1, §3: short exposures), full well
    /// about 27 000 e⁻ (typical of that sensor generation at ISO 100).
    pub fn paper() -> Camera {
        Camera {
            width_px: 4752,
            height_px: 3168,
            fx_px: 5106.0,
            fy_px: 5107.0,
            cx_px: 2375.5,
            cy_px: 1583.5,
            skew_px: 0.0,
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
            pixel_pitch_um: 22.3e3 / 4752.0,
            bits: 8,
            exposure_us: 250.0,
            full_well_e: 27_000.0,
        }
    }

    /// Largest code of the ADC, `2^bits − 1`.
    pub fn max_dn(&self) -> u16 {
        ((1u32 << self.bits.clamp(1, 16)) - 1) as u16
    }

    /// Electrons per code: the full well maps to [`Camera::max_dn`].
    pub fn gain_e_per_dn(&self) -> f64 {
        self.full_well_e / self.max_dn() as f64
    }

    /// Focal length along x, mm.
    pub fn focal_length_mm(&self) -> f64 {
        self.fx_px * self.pixel_pitch_um * 1e-3
    }

    /// Whether any distortion coefficient is non-zero.
    pub fn has_distortion(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2, self.k3].iter().any(|&k| k != 0.0)
    }

    /// Normalised → distorted normalised coordinates.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let k = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xd = x * k + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * k + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    /// Distorted → normalised coordinates (fixed-point iteration, as
    /// OpenCV's `undistortPoints`, refined until it reproduces the input to
    /// 1e-14).
    pub fn undistort(&self, xd: f64, yd: f64) -> (f64, f64) {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..100 {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex.abs() < 1e-14 && ey.abs() < 1e-14 {
                break;
            }
            x -= ex;
            y -= ey;
        }
        (x, y)
    }

    /// Pixel `(u, v)` of a camera-frame point (mm); `None` behind the camera.
    pub fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        if p[2].is_nan() || p[2] <= 1e-9 {
            return None;
        }
        let (xd, yd) = self.distort(p[0] / p[2], p[1] / p[2]);
        Some([self.fx_px * xd + self.skew_px * yd + self.cx_px, self.fy_px * yd + self.cy_px])
    }

    /// The ray through pixel `(u, v)`: a camera-frame direction with `z = 1`.
    pub fn unproject(&self, u: f64, v: f64) -> [f64; 3] {
        let yd = (v - self.cy_px) / self.fy_px;
        let xd = (u - self.cx_px - self.skew_px * yd) / self.fx_px;
        let (x, y) = self.undistort(xd, yd);
        [x, y, 1.0]
    }

    pub(crate) fn validate(&self) -> Result<(), SimError> {
        if !(5..=65_535).contains(&self.width_px) || !(1..=65_535).contains(&self.height_px) {
            return Err(SimError::ImageSize { width: self.width_px, height: self.height_px });
        }
        if !(8..=16).contains(&self.bits) {
            return Err(SimError::Bits(self.bits));
        }
        check("camera.fx_px", self.fx_px, self.fx_px > 0.0, "finite and > 0")?;
        check("camera.fy_px", self.fy_px, self.fy_px > 0.0, "finite and > 0")?;
        for (f, v) in [
            ("camera.cx_px", self.cx_px),
            ("camera.cy_px", self.cy_px),
            ("camera.skew_px", self.skew_px),
            ("camera.k1", self.k1),
            ("camera.k2", self.k2),
            ("camera.p1", self.p1),
            ("camera.p2", self.p2),
            ("camera.k3", self.k3),
        ] {
            check(f, v, v.is_finite(), "finite")?;
        }
        check("camera.pixel_pitch_um", self.pixel_pitch_um, self.pixel_pitch_um > 0.0, "finite and > 0")?;
        check("camera.exposure_us", self.exposure_us, self.exposure_us > 0.0, "finite and > 0")?;
        check("camera.full_well_e", self.full_well_e, self.full_well_e >= 1.0, "finite and ≥ 1")?;
        // The distortion must stay one-to-one over the image: check that the
        // undistortion of the corners and edge midpoints reproduces them.
        let (w, h) = ((self.width_px - 1) as f64, (self.height_px - 1) as f64);
        for (u, v) in
            [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h), (w / 2.0, 0.0), (0.0, h / 2.0), (w, h / 2.0), (w / 2.0, h)]
        {
            let r = self.unproject(u, v);
            let back = self.project(r);
            let ok = back.is_some_and(|b| (b[0] - u).abs() < 1e-6 && (b[1] - v).abs() < 1e-6);
            if !ok {
                return Err(SimError::Distortion);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_unproject_round_trip() {
        let c = Camera::reference();
        for &(u, v) in &[(0.0, 0.0), (751.0, 479.0), (379.2, 236.8), (100.3, 400.7)] {
            let r = c.unproject(u, v);
            let p = c.project([r[0] * 250.0, r[1] * 250.0, 250.0]).unwrap();
            assert!((p[0] - u).abs() < 1e-9 && (p[1] - v).abs() < 1e-9, "{u} {v} → {p:?}");
        }
        assert!(c.project([0.0, 0.0, -1.0]).is_none());
        assert!((c.focal_length_mm() - 8.4).abs() < 1e-12);
        assert!((Camera::paper().focal_length_mm() - 23.96).abs() < 0.01);
        // Barrel distortion pulls the corner inwards by about 1 %.
        let corner = c.distort(0.27, 0.17);
        assert!(corner.0 < 0.27 && corner.0 > 0.265, "{corner:?}");
    }
}
