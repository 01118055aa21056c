//! Small 3-D geometry: vectors, planes, rigid poses, and the sensor head's
//! construction (camera pose on the rail, laser planes in the camera frame)
//! from its geometry ([`crate::model::head::HeadGeometry`], which the
//! optics prediction reads too).
//!
//! On the plain `[f64; 3]` of [`crate::model::vec3`] (a few dozen operations
//! per image row).

use super::SimError;
use super::check;
pub use crate::model::head::HeadGeometry;
use crate::model::vec3::{Vec3, add, dot, scale, sub};

/// A 3 × 3 matrix, row-major.
pub type Mat3 = [[f64; 3]; 3];

pub(crate) fn mat_vec(m: &Mat3, v: Vec3) -> Vec3 {
    [dot(m[0], v), dot(m[1], v), dot(m[2], v)]
}

pub(crate) fn mat_t_vec(m: &Mat3, v: Vec3) -> Vec3 {
    [
        m[0][0] * v[0] + m[1][0] * v[1] + m[2][0] * v[2],
        m[0][1] * v[0] + m[1][1] * v[1] + m[2][1] * v[2],
        m[0][2] * v[0] + m[1][2] * v[1] + m[2][2] * v[2],
    ]
}

pub(crate) fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    m
}

fn rot_x(a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]
}

fn rot_y(a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
}

fn rot_z(a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

/// A plane `normal · X = d_mm` (unit normal).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScenePlane {
    /// Unit normal.
    pub normal: Vec3,
    /// Offset along the normal, mm.
    pub d_mm: f64,
}

impl ScenePlane {
    /// Signed distance of `p` from the plane, mm.
    pub fn distance_mm(&self, p: Vec3) -> f64 {
        dot(self.normal, p) - self.d_mm
    }
}

/// A rigid pose of the camera in the rail frame: `X_rail = rot · X_cam + origin_mm`.
/// The columns of `rot` are the camera's axes in rail coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Rotation camera → rail (row-major).
    pub rot: Mat3,
    /// Camera centre in the rail frame, mm.
    pub origin_mm: Vec3,
}

impl Pose {
    /// A camera-frame point in the rail frame.
    pub fn cam_to_rail(&self, p: Vec3) -> Vec3 {
        add(mat_vec(&self.rot, p), self.origin_mm)
    }
    /// A rail-frame point in the camera frame.
    pub fn rail_to_cam(&self, p: Vec3) -> Vec3 {
        mat_t_vec(&self.rot, sub(p, self.origin_mm))
    }
    /// A camera-frame plane in the rail frame.
    pub fn plane_to_rail(&self, p: &ScenePlane) -> ScenePlane {
        let n = mat_vec(&self.rot, p.normal);
        ScenePlane { normal: n, d_mm: p.d_mm + dot(n, self.origin_mm) }
    }
    /// A rail-frame plane in the camera frame.
    pub fn plane_to_cam(&self, p: &ScenePlane) -> ScenePlane {
        let n = mat_t_vec(&self.rot, p.normal);
        ScenePlane { normal: n, d_mm: p.d_mm - dot(p.normal, self.origin_mm) }
    }
}

impl HeadGeometry {
    pub(crate) fn validate(&self) -> Result<(), SimError> {
        check("head.standoff_mm", self.standoff_mm, self.standoff_mm > 0.0, "finite and > 0")?;
        check("head.alpha_deg", self.alpha_deg, self.alpha_deg > 0.0 && self.alpha_deg < 80.0, "in (0, 80)")?;
        check("head.camera_tilt_deg", self.camera_tilt_deg, self.camera_tilt_deg.abs() < 80.0, "in (-80, 80)")?;
        let lean = self.camera_tilt_deg + self.alpha_deg;
        check("head.camera_tilt_deg + head.alpha_deg", lean, lean.abs() < 80.0, "in (-80, 80)")?;
        check("head.lateral_offset_mm", self.lateral_offset_mm, self.lateral_offset_mm.is_finite(), "finite")?;
        for (f, v) in
            [("head.yaw_deg", self.yaw_deg), ("head.pitch_deg", self.pitch_deg), ("head.roll_deg", self.roll_deg)]
        {
            check(f, v, v.abs() < 45.0, "in (-45, 45)")?;
        }
        check("head.laser_diameter_mm", self.laser_diameter_mm, self.laser_diameter_mm > 0.0, "finite and > 0")?;
        let [lo, hi] = self.working_range_mm;
        check("head.working_range_mm[0]", lo, lo > 0.0, "finite and > 0")?;
        check("head.working_range_mm[1]", hi, hi > lo, "finite and above working_range_mm[0]")?;
        Ok(())
    }

    /// The aim point on the nominal rail top, rail frame.
    pub fn aim_point_mm(&self) -> Vec3 {
        [0.0, self.lateral_offset_mm, 0.0]
    }

    /// Rotation of the whole head about the aim point (yaw · pitch · roll).
    fn misalignment(&self) -> Mat3 {
        let r = mat_mul(&rot_z(self.yaw_deg.to_radians()), &rot_y(self.pitch_deg.to_radians()));
        mat_mul(&r, &rot_x(self.roll_deg.to_radians()))
    }

    /// The camera's nominal pose (before the misalignment).
    fn nominal_pose(&self) -> Pose {
        let (s, c) = self.camera_tilt_deg.to_radians().sin_cos();
        // Columns: x_cam = (0, c, s), y_cam = (1, 0, 0), z_cam = (0, s, -c).
        let rot = [[0.0, 1.0, 0.0], [c, 0.0, s], [s, 0.0, -c]];
        let axis = [0.0, s, -c];
        Pose { rot, origin_mm: sub(self.aim_point_mm(), scale(axis, self.standoff_mm)) }
    }

    /// The camera's pose in the rail frame.
    pub fn camera_pose(&self) -> Pose {
        let nominal = self.nominal_pose();
        let m = self.misalignment();
        let a = self.aim_point_mm();
        Pose { rot: mat_mul(&m, &nominal.rot), origin_mm: add(a, mat_vec(&m, sub(nominal.origin_mm, a))) }
    }

    /// The plane of a laser whose line falls `offset_mm` across the rail
    /// from the aim point on the nominal rail top, in the camera frame (a
    /// property of the head: independent of its misalignment).
    pub fn laser_plane_cam(&self, offset_mm: f64) -> ScenePlane {
        let lean = (self.camera_tilt_deg + self.alpha_deg).to_radians();
        let (s, c) = lean.sin_cos();
        // Contains the rail axis and the direction (0, sin, -cos): normal (0, cos, sin).
        let normal = [0.0, c, s];
        let through = [0.0, self.lateral_offset_mm + offset_mm, 0.0];
        let rail = ScenePlane { normal, d_mm: dot(normal, through) };
        self.nominal_pose().plane_to_cam(&rail)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_round_trip_and_axes() {
        let mut h = HeadGeometry::reference();
        h.camera_tilt_deg = 10.0;
        h.yaw_deg = 3.0;
        h.roll_deg = -2.0;
        h.pitch_deg = 1.0;
        let p = h.camera_pose();
        let x = [12.0, -7.0, 3.0];
        let back = p.cam_to_rail(p.rail_to_cam(x));
        for i in 0..3 {
            assert!((back[i] - x[i]).abs() < 1e-12);
        }
        // The aim point is on the optical axis at the standoff.
        let a = p.rail_to_cam(h.aim_point_mm());
        assert!(a[0].abs() < 1e-9 && a[1].abs() < 1e-9 && (a[2] - h.standoff_mm).abs() < 1e-9, "{a:?}");
        // Angle between the optical axis and the laser plane is α.
        let n = h.laser_plane_cam(5.0).normal;
        assert!((n[2].abs().asin().to_degrees() - h.alpha_deg).abs() < 1e-9);
        // The plane maps back and forth.
        let pl = h.laser_plane_cam(-4.0);
        let r = p.plane_to_rail(&pl);
        let q = p.plane_to_cam(&r);
        assert!((q.d_mm - pl.d_mm).abs() < 1e-9);
    }
}
