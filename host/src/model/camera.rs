//! The host's camera model, in `f64`: a pinhole with skew and Brown–Conrady
//! distortion in OpenCV's form and order, with the image size. Calibration
//! estimates it ([`crate::calib::camera`]), the calibration file stores it
//! ([`crate::calib::file`]), the simulator renders through it
//! ([`crate::sim::scene::Camera`]); the head runs the `f32` copy that
//! [`Intrinsics::to_core`] makes — the only conversion between the two.
//!
//! ```text
//! (x, y) = (X/Z, Y/Z),  r² = x² + y²,  k = 1 + k1·r² + k2·r⁴ + k3·r⁶
//! x_d = x·k + 2·p1·x·y + p2·(r² + 2x²),  y_d = y·k + p1·(r² + 2y²) + 2·p2·x·y
//! u = fx·x_d + skew·y_d + cx,  v = fy·y_d + cy
//! ```
//!
//! Camera frame `x` right, `y` down, `z` forward (mm); pixel centres at
//! integer coordinates, `(0, 0)` the centre of the first pixel, as for
//! `cms_core::peak` positions. The skew is in pixels (the `(0, 1)` entry of
//! the camera matrix, `α_c` of the paper's Eq. 6; OpenCV's `alpha` is
//! `skew / fx`).
//!
//! **Undistortion** has no closed form. It is Newton's method on the
//! distortion with its analytic 2 × 2 Jacobian, started at the distorted
//! point, until the distortion of the estimate reproduces the input to
//! [`UNDISTORT_TOLERANCE`] (normalised units: 1e-12 px at a 1000 px focal
//! length): 3–4 steps inside an image with the usual few-percent
//! distortion. Newton with the analytic Jacobian rather than central
//! differences (four more distortions a step) or OpenCV's fixed-point
//! `undistortPoints` (linear convergence, up to 100 steps): the same
//! answer to within 1e-14, in fewer steps.
//!
//! The model is [`serde`]-serialisable with OpenCV's names (`width`,
//! `height`, `fx`, `fy`, `cx`, `cy`, `skew`, `k1`, `k2`, `p1`, `p2`, `k3`):
//! the keys of the calibration file's `[camera]` table and of `calibrate
//! render`'s `truth.json`.

use cms_core::triangulation::CameraModel;
use serde::{Deserialize, Serialize};

/// Largest residual `|distort(undistort(p)) − p|` (each coordinate,
/// normalised units) at which [`Intrinsics::undistort`] stops.
pub const UNDISTORT_TOLERANCE: f64 = 1e-15;

/// Most Newton steps of [`Intrinsics::undistort`]: far beyond what a
/// one-to-one distortion needs; reached only past the fold of an extreme
/// distortion, where the result is not meaningful (and the simulator's
/// configuration check rejects such a camera).
const MAX_UNDISTORT_STEPS: usize = 20;

/// A camera's image size, pinhole intrinsics and Brown–Conrady distortion
/// (see the [module](self) for the model).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Intrinsics {
    /// Image width, px.
    #[serde(rename = "width")]
    pub width_px: u32,
    /// Image height, px.
    #[serde(rename = "height")]
    pub height_px: u32,
    /// Focal length along x (columns), px.
    #[serde(rename = "fx")]
    pub fx_px: f64,
    /// Focal length along y (rows), px.
    #[serde(rename = "fy")]
    pub fy_px: f64,
    /// Principal point column, px.
    #[serde(rename = "cx")]
    pub cx_px: f64,
    /// Principal point row, px.
    #[serde(rename = "cy")]
    pub cy_px: f64,
    /// Skew, px.
    #[serde(rename = "skew")]
    pub skew_px: f64,
    /// Radial r² coefficient.
    pub k1: f64,
    /// Radial r⁴ coefficient.
    pub k2: f64,
    /// Tangential coefficient p1.
    pub p1: f64,
    /// Tangential coefficient p2.
    pub p2: f64,
    /// Radial r⁶ coefficient.
    pub k3: f64,
}

impl Intrinsics {
    /// Whether any distortion coefficient is non-zero.
    pub fn has_distortion(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2, self.k3].iter().any(|&k| k != 0.0)
    }

    /// Normalised → distorted normalised coordinates.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let k = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        (
            x * k + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * k + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// The Jacobian `[[∂x_d/∂x, ∂x_d/∂y], [∂y_d/∂x, ∂y_d/∂y]]` of
    /// [`Intrinsics::distort`] at `(x, y)`.
    fn distortion_jacobian(&self, x: f64, y: f64) -> [[f64; 2]; 2] {
        let r2 = x * x + y * y;
        let k = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        // dk/d(r²); ∂k/∂x = 2x·dk, ∂k/∂y = 2y·dk.
        let dk = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let xy = 2.0 * x * y * dk + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        [
            [k + 2.0 * x * x * dk + 2.0 * self.p1 * y + 6.0 * self.p2 * x, xy],
            [xy, k + 2.0 * y * y * dk + 6.0 * self.p1 * y + 2.0 * self.p2 * x],
        ]
    }

    /// Distorted → normalised coordinates: Newton's method with the analytic
    /// Jacobian, to [`UNDISTORT_TOLERANCE`] (see the [module](self)).
    pub fn undistort(&self, xd: f64, yd: f64) -> (f64, f64) {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..MAX_UNDISTORT_STEPS {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex.abs() <= UNDISTORT_TOLERANCE && ey.abs() <= UNDISTORT_TOLERANCE {
                break;
            }
            let [[a, b], [c, d]] = self.distortion_jacobian(x, y);
            let det = a * d - b * c;
            // A singular Jacobian is the fold of the distortion: no Newton step.
            if det.is_nan() || det.abs() <= 1e-12 {
                break;
            }
            x -= (d * ex - b * ey) / det;
            y -= (a * ey - c * ex) / det;
        }
        (x, y)
    }

    /// Pixel `(u, v)` of a camera-frame point (mm); `None` behind the camera
    /// or within 1e-9 mm of its plane, where `X/Z` means nothing.
    pub fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        if p[2].is_nan() || p[2] <= 1e-9 {
            return None;
        }
        let (xd, yd) = self.distort(p[0] / p[2], p[1] / p[2]);
        Some([self.fx_px * xd + self.skew_px * yd + self.cx_px, self.fy_px * yd + self.cy_px])
    }

    /// The ray through pixel `(u, v)`: the undistorted camera-frame
    /// direction `(x, y, 1)`.
    pub fn unproject(&self, u: f64, v: f64) -> [f64; 3] {
        let yd = (v - self.cy_px) / self.fy_px;
        let xd = (u - self.cx_px - self.skew_px * yd) / self.fx_px;
        let (x, y) = self.undistort(xd, yd);
        [x, y, 1.0]
    }

    /// The head's `f32` model of this camera (each number rounded to the
    /// nearest `f32`): the one conversion from the host's model to the core's.
    pub fn to_core(&self) -> CameraModel {
        CameraModel::from_arrays(
            [self.fx_px as f32, self.fy_px as f32, self.cx_px as f32, self.cy_px as f32, self.skew_px as f32],
            [self.k1 as f32, self.k2 as f32, self.p1 as f32, self.p2 as f32, self.k3 as f32],
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference head's camera (as `sim::Camera::reference`), with skew.
    fn camera() -> Intrinsics {
        Intrinsics {
            width_px: 752,
            height_px: 480,
            fx_px: 1400.0,
            fy_px: 1400.0,
            cx_px: 379.2,
            cy_px: 236.8,
            skew_px: 0.7,
            k1: -0.09,
            k2: 0.12,
            p1: 2.0e-4,
            p2: -1.5e-4,
            k3: 0.01,
        }
    }

    #[test]
    fn project_unproject_round_trip() {
        let c = camera();
        for &(u, v) in &[(0.0, 0.0), (751.0, 479.0), (379.2, 236.8), (100.3, 400.7), (751.0, 0.0)] {
            let r = c.unproject(u, v);
            assert_eq!(r[2], 1.0);
            let p = c.project([r[0] * 250.0, r[1] * 250.0, 250.0]).unwrap();
            assert!((p[0] - u).abs() < 1e-9 && (p[1] - v).abs() < 1e-9, "{u} {v} → {p:?}");
        }
        assert!(c.project([0.0, 0.0, -1.0]).is_none());
        assert!(c.project([0.0, 0.0, f64::NAN]).is_none());
        // Barrel distortion pulls the corner inwards by about 1 %.
        let corner = c.distort(0.27, 0.17);
        assert!(corner.0 < 0.27 && corner.0 > 0.265, "{corner:?}");
    }

    #[test]
    fn jacobian_matches_central_differences() {
        let c = camera();
        let h = 1e-6;
        for &(x, y) in &[(0.0, 0.0), (0.27, 0.17), (-0.3, 0.2), (0.1, -0.25)] {
            let j = c.distortion_jacobian(x, y);
            let (ax, ay) = c.distort(x + h, y);
            let (bx, by) = c.distort(x - h, y);
            let (cx, cy) = c.distort(x, y + h);
            let (dx, dy) = c.distort(x, y - h);
            let fd = [[(ax - bx) / (2.0 * h), (cx - dx) / (2.0 * h)], [(ay - by) / (2.0 * h), (cy - dy) / (2.0 * h)]];
            for (r, f) in j.iter().zip(&fd) {
                for (a, b) in r.iter().zip(f) {
                    assert!((a - b).abs() < 1e-8, "({x}, {y}): {j:?} vs {fd:?}");
                }
            }
        }
    }

    #[test]
    fn undistortion_meets_its_tolerance_under_strong_distortion() {
        // OpenCV's sample camera (k1 ≈ −0.29): a fixed-point iteration needs
        // dozens of steps at the corners, Newton a handful.
        let c = Intrinsics { k1: -0.29, k2: 0.11, p1: 1e-3, p2: -3e-4, k3: 0.0, ..camera() };
        for &(xd, yd) in &[(0.0, 0.0), (0.45, 0.3), (-0.4, -0.3), (0.2, -0.35)] {
            let (x, y) = c.undistort(xd, yd);
            let (bx, by) = c.distort(x, y);
            assert!((bx - xd).abs() <= UNDISTORT_TOLERANCE && (by - yd).abs() <= UNDISTORT_TOLERANCE, "{xd} {yd}");
        }
    }

    #[test]
    fn the_core_model_is_the_rounded_copy() {
        let c = camera();
        let m = c.to_core();
        assert_eq!((m.fx, m.cx, m.skew, m.k1, m.p2), (1400.0, 379.2, 0.7, -0.09, -1.5e-4));
        let p = [12.0, -7.0, 210.0];
        let [u, v] = m.project([p[0] as f32, p[1] as f32, p[2] as f32]);
        let want = c.project(p).unwrap();
        assert!((f64::from(u) - want[0]).abs() < 1e-3 && (f64::from(v) - want[1]).abs() < 1e-3);
    }

    #[test]
    fn serde_uses_opencv_names() {
        let c = camera();
        let v = serde_json::to_value(c).unwrap();
        assert_eq!(v["fx"], 1400.0);
        assert_eq!(v["width"], 752);
        assert_eq!(serde_json::from_value::<Intrinsics>(v).unwrap(), c);
    }
}
