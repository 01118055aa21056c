//! What a calibration file gives the head: its calibration message and
//! the search windows of its lasers; and the head it describes
//! ([`HeadLens`]) for the optics prediction of the noise floor.

use cms_core::peak::ColumnWindow;
use cms_core::peak::window::MIN_WINDOW_PX;
use cms_core::protocol::{Calibration, LASERS};

use super::{CalibrationFile, FileError};
use crate::model::head::{HeadGeometry, HeadLens, HeadSource, REFERENCE_PIXEL_UM};

impl CalibrationFile {
    /// The calibration message for the head: needs the datum and all three lasers.
    ///
    /// Every value must be finite in the head's single precision too (a
    /// `k2 = 1e300` is a finite f64 but an infinite f32): the error names
    /// the key, which the head's own check cannot.
    pub fn to_head(&self) -> Result<Calibration, FileError> {
        let datum = self.datum.ok_or_else(|| FileError("no [datum]: run cms-host calibrate lasers".into()))?;
        if self.lasers.len() != LASERS {
            return Err(FileError(format!(
                "{} [[laser]] entries; the head needs {LASERS} (run cms-host calibrate lasers)",
                self.lasers.len()
            )));
        }
        self.fits_single_precision()?;
        let camera = self.camera.intrinsics.to_core();
        let mut planes = [[0.0f32; 4]; LASERS];
        for l in &self.lasers {
            planes[l.id as usize] = [l.nx as f32, l.ny as f32, l.nz as f32, l.d_mm as f32];
        }
        Ok(Calibration {
            id: self.head_id(),
            intrinsics: [camera.fx, camera.fy, camera.cx, camera.cy, camera.skew],
            distortion: [camera.k1, camera.k2, camera.p1, camera.p2, camera.k3],
            planes,
            datum: [datum.nx as f32, datum.ny as f32, datum.nz as f32, datum.d_mm as f32],
        })
    }
}

impl CalibrationFile {
    /// Search windows for the head (`SetWindows`), one a laser: the columns
    /// where laser k's line can fall between `[head]`'s `range_min_mm` and
    /// `range_max_mm`, through this camera (its distortion included), over
    /// every 8th row and the last, widened by `margin_px` either side and
    /// clamped to the image. `None` for a laser whose line is nowhere in
    /// view there, or that has no plane. An error without a `[head]`
    /// section.
    ///
    /// Why: profilers search only where the line can be (their "active
    /// area"); the head's detector is cheaper in windows
    /// (docs/detector.md, "Search windows"). Cost: 2 × 61 projections a
    /// laser.
    pub fn search_windows(&self, margin_px: f64) -> Result<[Option<ColumnWindow>; LASERS], FileError> {
        let h = self
            .head
            .as_ref()
            .ok_or_else(|| FileError("the calibration has no [head] section (range_min_mm, range_max_mm)".into()))?;
        let cam = self.intrinsics();
        let (width, height) = (f64::from(cam.width_px), cam.height_px);
        let mut out = [None; LASERS];
        for l in &self.lasers {
            let Some(slot) = out.get_mut(l.id as usize) else { continue };
            if l.nx.abs() < 1e-9 {
                continue; // a plane containing the columns' direction: no one column range
            }
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            let rows = (0..height).step_by(8).chain([height.saturating_sub(1)]);
            for v in rows {
                let y = (f64::from(v) - cam.cy_px) / cam.fy_px;
                for z in [h.range_min_mm, h.range_max_mm] {
                    // n·(x z, y z, z) = d on the plane, at depth z and row v.
                    let x = (l.d_mm / z - l.nz - l.ny * y) / l.nx;
                    if let Some([u, _]) = cam.project([x * z, y * z, z]).filter(|p| p[0].is_finite()) {
                        lo = lo.min(u);
                        hi = hi.max(u);
                    }
                }
            }
            let (first, end) = ((lo - margin_px).floor().max(0.0), (hi + margin_px).ceil().min(width));
            if end - first >= f64::from(MIN_WINDOW_PX) {
                *slot = Some(ColumnWindow { first_px: first as u16, width_px: (end - first) as u16 });
            }
        }
        Ok(out)
    }
}

impl CalibrationFile {
    /// The head this calibration describes, as the optics prediction of
    /// the noise floor reads it: the focal length, the stand-off along the
    /// optical axis to the datum, the camera's tilt from the datum's
    /// normal, the mean angle between the optical axis and the laser
    /// planes, `[head]`'s line and range (the reference head's where it
    /// has none), one speckle pattern a line, and the reference sensor's pixel pitch (the file gives
    /// the focal length in pixels, not the pitch). `None` without a datum
    /// and laser planes (a camera calibration alone).
    pub fn head_lens(&self) -> Option<HeadLens> {
        let datum = self.datum?;
        if self.lasers.is_empty() || datum.nz.abs() < 1e-9 {
            return None;
        }
        let alpha_deg = self.lasers.iter().map(|l| l.nz.abs().clamp(0.0, 1.0).asin().to_degrees()).sum::<f64>()
            / self.lasers.len() as f64;
        let mut geometry = HeadGeometry {
            standoff_mm: datum.d_mm / datum.nz,
            alpha_deg,
            camera_tilt_deg: datum.nx.atan2(-datum.nz).to_degrees(),
            ..HeadGeometry::reference()
        };
        if let Some(h) = self.head {
            geometry.laser_diameter_mm = h.laser_diameter_mm;
            geometry.working_range_mm = [h.range_min_mm, h.range_max_mm];
        }
        (geometry.standoff_mm > 0.0).then_some(HeadLens {
            geometry,
            focal_px: self.intrinsics().fx_px,
            pixel_um: REFERENCE_PIXEL_UM,
            speckle_patterns: 1,
            source: HeadSource::Calibration,
        })
    }
}
