//! The simulated head's camera: the lens and sensor geometry of
//! [`crate::model::camera::Intrinsics`] (pinhole with skew and Brown–Conrady
//! distortion, OpenCV's convention and frame; the model, its projection and
//! undistortion live there), and the sensor's photometric limits: pixel
//! pitch, bit depth, exposure and full well.

use super::SimError;
use super::check;
use crate::model::camera::Intrinsics;
use crate::model::head::{REFERENCE_FOCAL_PX, REFERENCE_PIXEL_UM};

/// A camera: intrinsics, distortion and image size, bit depth, exposure and
/// full-well capacity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Image size (columns across the stripes, rows one position along the
    /// rail each), pinhole and distortion.
    pub intrinsics: Intrinsics,
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
            intrinsics: Intrinsics {
                width_px: 752,
                height_px: 480,
                fx_px: REFERENCE_FOCAL_PX,
                fy_px: REFERENCE_FOCAL_PX,
                cx_px: 379.2,
                cy_px: 236.8,
                skew_px: 0.0,
                k1: -0.09,
                k2: 0.12,
                p1: 2.0e-4,
                p2: -1.5e-4,
                k3: 0.0,
            },
            pixel_pitch_um: REFERENCE_PIXEL_UM,
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
            intrinsics: Intrinsics {
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
            },
            pixel_pitch_um: 22.3e3 / 4752.0,
            bits: 8,
            exposure_us: 250.0,
            full_well_e: 27_000.0,
        }
    }

    /// Image width, px (columns: across the stripes).
    pub fn width_px(&self) -> usize {
        self.intrinsics.width_px as usize
    }

    /// Image height, px (rows: one position along the rail each).
    pub fn height_px(&self) -> usize {
        self.intrinsics.height_px as usize
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
        self.intrinsics.fx_px * self.pixel_pitch_um * 1e-3
    }

    pub(crate) fn validate(&self) -> Result<(), SimError> {
        let (width, height) = (self.width_px(), self.height_px());
        if !(5..=65_535).contains(&width) || !(1..=65_535).contains(&height) {
            return Err(SimError::ImageSize { width, height });
        }
        let i = &self.intrinsics;
        if !(8..=16).contains(&self.bits) {
            return Err(SimError::Bits(self.bits));
        }
        check("camera.fx_px", i.fx_px, i.fx_px > 0.0, "finite and > 0")?;
        check("camera.fy_px", i.fy_px, i.fy_px > 0.0, "finite and > 0")?;
        for (f, v) in [
            ("camera.cx_px", i.cx_px),
            ("camera.cy_px", i.cy_px),
            ("camera.skew_px", i.skew_px),
            ("camera.k1", i.k1),
            ("camera.k2", i.k2),
            ("camera.p1", i.p1),
            ("camera.p2", i.p2),
            ("camera.k3", i.k3),
        ] {
            check(f, v, v.is_finite(), "finite")?;
        }
        check("camera.pixel_pitch_um", self.pixel_pitch_um, self.pixel_pitch_um > 0.0, "finite and > 0")?;
        check("camera.exposure_us", self.exposure_us, self.exposure_us > 0.0, "finite and > 0")?;
        check("camera.full_well_e", self.full_well_e, self.full_well_e >= 1.0, "finite and ≥ 1")?;
        // The distortion must stay one-to-one over the image: check that the
        // undistortion of the corners and edge midpoints reproduces them.
        let (w, h) = ((width - 1) as f64, (height - 1) as f64);
        for (u, v) in
            [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h), (w / 2.0, 0.0), (0.0, h / 2.0), (w, h / 2.0), (w / 2.0, h)]
        {
            let r = i.unproject(u, v);
            let back = i.project(r);
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
    fn focal_lengths_and_codes() {
        let c = Camera::reference();
        assert!((c.focal_length_mm() - 8.4).abs() < 1e-12);
        assert!((Camera::paper().focal_length_mm() - 23.96).abs() < 0.01);
        assert_eq!((c.width_px(), c.height_px(), c.max_dn()), (752, 480, 255));
        assert!(c.validate().is_ok() && Camera::paper().validate().is_ok());
    }
}
