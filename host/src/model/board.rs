//! The planar calibration target and its pose: the geometry that camera
//! calibration ([`crate::calib`]) fits and the simulator ([`crate::sim::scene`])
//! renders, so neither has to import the other. [`crate::calib::board`]
//! finds the corners of such a board in an image.
//!
//! Conventions (OpenCV's):
//! * board frame: inner corner `(i, j)` (column `i` in `0..cols`, row `j` in
//!   `0..rows`) at `(i·S, j·S, 0)` mm, `z` completing a right-handed frame;
//!   corners are listed row by row (`j` outer, `i` inner);
//! * a board pose maps board to camera: `X_cam = rot · X_board + t_mm`, the
//!   camera frame that of [`crate::model::camera`].

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corners_row_by_row_and_the_plane_of_a_pose() {
        let b = Board { cols: 3, rows: 2, square_mm: 10.0 };
        let p = b.object_points();
        assert_eq!(p.len(), 6);
        assert_eq!((p[1], p[3]), ([10.0, 0.0, 0.0], [0.0, 10.0, 0.0]));
        // Board turned half a turn about x, 200 mm in front of the camera.
        let pose = BoardPose { rot: [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]], t_mm: [5.0, 0.0, 200.0] };
        assert_eq!(pose.to_camera([10.0, 10.0, 0.0]), [15.0, -10.0, 200.0]);
        assert_eq!(pose.plane(), ([0.0, 0.0, -1.0], -200.0));
    }
}
