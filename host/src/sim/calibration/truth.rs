//! The true calibration of a simulated head, as a calibration file: what
//! `calibrate camera` + `calibrate lasers` should find from its images, and
//! what the end-to-end tests triangulate with.

use crate::calib::file::{CalibrationFile, FILE_VERSION, LaserSection, PlaneSection};
use crate::sim::scene::Scene;
use crate::sim::scene::geom::ScenePlane;

/// A plane as `[[laser]]`/`[datum]` numbers, oriented so that `d < 0` (the
/// normal points from the plane towards the camera).
fn oriented(p: &ScenePlane) -> ([f64; 3], f64) {
    let s = if p.d_mm > 0.0 { -1.0 } else { 1.0 };
    ([s * p.normal[0], s * p.normal[1], s * p.normal[2]], s * p.d_mm)
}

/// The scene's camera, laser planes and rail-top datum (the nominal rail
/// top, `z = 0` of the rail frame: heights are then the sim's
/// `StripeTruth::height_um`), with the head's optics.
pub fn truth(scene: &Scene) -> CalibrationFile {
    let cfg = scene.config();
    let rail_top = ScenePlane { normal: [0.0, 0.0, 1.0], d_mm: 0.0 };
    let datum = scene.camera_pose().plane_to_cam(&rail_top);
    let (n, d_mm) = oriented(&datum);
    let mut f = CalibrationFile::camera_only(&scene.camera().intrinsics, 0.0, None);
    f.version = FILE_VERSION;
    f.datum = Some(PlaneSection { nx: n[0], ny: n[1], nz: n[2], d_mm });
    f.head = Some(crate::calib::file::HeadSection {
        laser_diameter_mm: cfg.head.laser_diameter_mm,
        range_min_mm: cfg.head.working_range_mm[0],
        range_max_mm: cfg.head.working_range_mm[1],
        f_number: None,
        wavelength_nm: None,
    });
    f.lasers = scene
        .laser_planes()
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let (n, d_mm) = oriented(p);
            LaserSection {
                id: k as u32,
                nx: n[0],
                ny: n[1],
                nz: n[2],
                d_mm,
                rms_mm: 0.0,
                points: None,
                spread_mm: None,
                depth_min_mm: None,
                depth_max_mm: None,
            }
        })
        .collect();
    f
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::scene::SimConfig;

    /// The head a calibration describes is the head it was made of: the
    /// optics prediction reads the same geometry the simulator renders.
    #[test]
    fn the_calibration_gives_back_the_head() {
        let mut cfg = SimConfig::reference();
        cfg.head.camera_tilt_deg = 10.0;
        cfg.head.alpha_deg = 30.0;
        let want = cfg.head_lens();
        let got = truth(&Scene::new(cfg).unwrap()).head_lens().unwrap();
        assert_eq!(got.source, crate::model::head::HeadSource::Calibration);
        assert!((got.standoff_mm() - 200.0).abs() < 1e-9, "{got:?}");
        assert!((got.triangulation_deg() - 30.0).abs() < 1e-9, "{got:?}");
        assert!((got.geometry.camera_tilt_deg - 10.0).abs() < 1e-9, "{got:?}");
        assert_eq!((got.focal_px, got.pixel_um), (want.focal_px, want.pixel_um));
        assert_eq!(got.geometry.working_range_mm, want.geometry.working_range_mm);
        // A camera calibration alone describes no head.
        assert_eq!(CalibrationFile::camera_only(&want_intrinsics(), 0.0, None).head_lens(), None);
    }

    fn want_intrinsics() -> crate::model::camera::Intrinsics {
        crate::sim::scene::Camera::reference().intrinsics
    }
}
