//! Calibration of the sensor head: camera intrinsics from checkerboard
//! photographs, laser planes from laser lines on the board, the calibration
//! file, and its upload to a head.
//!
//! * [`board`] — checkerboard inner-corner detection with sub-pixel refinement.
//! * [`camera`] — Zhang's closed-form initialisation and Levenberg–Marquardt
//!   refinement of intrinsics, distortion and board poses; board pose from
//!   corners with known intrinsics; `cms-host calibrate camera`.
//! * [`lasers`] — laser planes from laser-on/laser-off pairs; `cms-host calibrate lasers`.
//! * [`file`] — the TOML calibration file: versioned, units in the keys,
//!   validated on load.
//! * [`upload`] — `cms-host calibrate upload`.
//! * [`truth`] — the true calibration of a simulated head.
//! * [`render`] — `cms-host calibrate render`: calibration images from the
//!   simulated head, with the truth beside them.
//!
//! Conventions shared by all of them (OpenCV's):
//! * camera frame: `x` right, `y` down, `z` forward, millimetres; pixel
//!   centres at integer coordinates, `(0, 0)` the centre of the first pixel;
//! * board frame: inner corner `(i, j)` (column `i` in `0..cols`, row `j` in
//!   `0..rows`) at `(i·S, j·S, 0)` mm, `z` completing a right-handed frame;
//!   corners are listed row by row (`j` outer, `i` inner);
//! * a board pose maps board to camera: `X_cam = rot · X_board + t_mm`.

pub mod board;
pub mod camera;
pub mod file;
pub mod lasers;
pub mod render;
pub mod truth;
pub mod upload;

/// A planar checkerboard: `cols × rows` inner corners, `square_mm` apart.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Board {
    /// Inner corners per row.
    pub cols: usize,
    /// Inner corners per column.
    pub rows: usize,
    /// Side of a square, mm.
    pub square_mm: f64,
}

impl Board {
    /// The board-frame position of every inner corner, row by row, mm.
    pub fn object_points(&self) -> Vec<[f64; 3]> {
        let mut v = Vec::with_capacity(self.cols * self.rows);
        for j in 0..self.rows {
            for i in 0..self.cols {
                v.push([i as f64 * self.square_mm, j as f64 * self.square_mm, 0.0]);
            }
        }
        v
    }
}

/// A pinhole camera with skew and Brown–Conrady distortion (OpenCV's model;
/// the skew in pixels, OpenCV's `alpha = skew / fx`):
///
/// ```text
/// (x, y) = (X/Z, Y/Z),  r² = x² + y²,  k = 1 + k1·r² + k2·r⁴ + k3·r⁶
/// x_d = x·k + 2·p1·x·y + p2·(r² + 2x²),  y_d = y·k + p1·(r² + 2y²) + 2·p2·x·y
/// u = fx·x_d + skew·y_d + cx,  v = fy·y_d + cy
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point column, pixels.
    pub cx: f64,
    /// Principal point row, pixels.
    pub cy: f64,
    /// Skew, pixels.
    pub skew: f64,
    /// Radial r².
    pub k1: f64,
    /// Radial r⁴.
    pub k2: f64,
    /// Tangential p1.
    pub p1: f64,
    /// Tangential p2.
    pub p2: f64,
    /// Radial r⁶.
    pub k3: f64,
}

impl Intrinsics {
    /// Distorts normalised coordinates.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let k = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        (
            x * k + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * k + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// Undistorts normalised coordinates: Newton's method on the distortion
    /// (converges to 1e-15 in a few steps inside the image).
    pub fn undistort(&self, xd: f64, yd: f64) -> (f64, f64) {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..20 {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex.abs() < 1e-15 && ey.abs() < 1e-15 {
                break;
            }
            // Jacobian by central differences: cheap and exact enough for Newton.
            let h = 1e-7;
            let (ax, ay) = self.distort(x + h, y);
            let (bx, by) = self.distort(x - h, y);
            let (cx, cy) = self.distort(x, y + h);
            let (dx, dy) = self.distort(x, y - h);
            let (j11, j21) = ((ax - bx) / (2.0 * h), (ay - by) / (2.0 * h));
            let (j12, j22) = ((cx - dx) / (2.0 * h), (cy - dy) / (2.0 * h));
            let det = j11 * j22 - j12 * j21;
            if det.abs() < 1e-12 {
                break;
            }
            x -= (j22 * ex - j12 * ey) / det;
            y -= (j11 * ey - j21 * ex) / det;
        }
        (x, y)
    }

    /// The pixel of a camera-frame point (`None` behind the camera).
    pub fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        if p[2] <= 0.0 {
            return None;
        }
        let (xd, yd) = self.distort(p[0] / p[2], p[1] / p[2]);
        Some([self.fx * xd + self.skew * yd + self.cx, self.fy * yd + self.cy])
    }

    /// The ray `(x, y, 1)` (undistorted, normalised) through pixel `(u, v)`.
    pub fn unproject(&self, u: f64, v: f64) -> [f64; 3] {
        let yd = (v - self.cy) / self.fy;
        let xd = (u - self.cx - self.skew * yd) / self.fx;
        let (x, y) = self.undistort(xd, yd);
        [x, y, 1.0]
    }
}

/// A rigid board pose: `X_cam = rot · X_board + t_mm` (`rot` row-major).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoardPose {
    /// Rotation board → camera.
    pub rot: [[f64; 3]; 3],
    /// Board origin in the camera frame, mm.
    pub t_mm: [f64; 3],
}

impl BoardPose {
    /// A board-frame point in the camera frame.
    pub fn to_camera(&self, p: [f64; 3]) -> [f64; 3] {
        let r = &self.rot;
        [
            r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + self.t_mm[0],
            r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + self.t_mm[1],
            r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + self.t_mm[2],
        ]
    }

    /// The board plane in the camera frame: unit normal `n` (the board's
    /// `z` axis) and `d` with `n · X = d`.
    pub fn plane(&self) -> ([f64; 3], f64) {
        let n = [self.rot[0][2], self.rot[1][2], self.rot[2][2]];
        (n, n[0] * self.t_mm[0] + n[1] * self.t_mm[1] + n[2] * self.t_mm[2])
    }
}
