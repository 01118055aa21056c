//! Whether the head keeps a calibration: its triangulator can be built and
//! its laser lines stay apart over the working depth. Checked once, when a
//! calibration is loaded (`SetCalibration`, or restored from flash).

use crate::protocol::{Calibration, LASERS};
use crate::triangulation::{CameraModel, Plane, Triangulator};

/// The triangulator of a calibration: what the head checks before it keeps
/// one (a zero id is refused too: 0 means "none" in `DeviceInfo`), and the
/// laser lines apart in the working depth ([`check_laser_lines`] over
/// [`working_depth_mm`]).
pub fn triangulator(c: &Calibration) -> Result<Triangulator, CalibrationError> {
    if c.id == 0 {
        return Err(CalibrationError::ZeroId);
    }
    let camera = CameraModel::from_arrays(c.intrinsics, c.distortion);
    let planes = c.planes.map(Plane::from);
    let t = Triangulator::new(&camera, &planes, &Plane::from(c.datum)).map_err(CalibrationError::Geometry)?;
    check_laser_lines(c, working_depth_mm(c))?;
    Ok(t)
}

/// Laser lines closer than this in an image row, px, are refused: the
/// detector would merge their stripes (σ up to ~2 px on the reference head,
/// a stripe ±3σ wide) and nothing could tell which laser a stripe is.
pub const MIN_LINE_SEPARATION_PX: f64 = 8.0;

/// The working depth [`triangulator`] checks the laser lines over: the
/// datum's depth on the optical axis ± this fraction (the rail moves mm,
/// the head is mounted at a fixed height: ±25 % is generous).
pub const WORKING_DEPTH_FRACTION: f64 = 0.25;

/// The depth range (along the optical axis, mm) the head checks the laser
/// lines over: the datum's depth on the axis ± [`WORKING_DEPTH_FRACTION`]
/// (`(NaN, NaN)` for a datum the axis misses, which [`Triangulator::new`]
/// refuses first).
pub fn working_depth_mm(c: &Calibration) -> (f64, f64) {
    let z = f64::from(c.datum[3]) / f64::from(c.datum[2]);
    (z * (1.0 - WORKING_DEPTH_FRACTION), z * (1.0 + WORKING_DEPTH_FRACTION))
}

/// Checks that the three laser lines are where the head's pipeline needs
/// them for every surface depth `z` in `depth_mm` and every image row: in
/// laser order left to right (the pipeline and `measure` number the
/// stripes of a row that way), at least [`MIN_LINE_SEPARATION_PX`] apart,
/// and each laser's line inside the image in the middle row at the middle
/// of `depth_mm`.
///
/// In the undistorted normalised image, laser `k` (`n·X = d`) on a surface
/// at depth `z` in the row of normalised `y` lies at
/// `x = (d/z − n_y·y − n_z)/n_x`: affine in `(y, 1/z)`, so the gap between
/// two lines is least at a corner of the rectangle rows × depths, and the
/// four corners decide (no sampling, a few dozen flops). The rows are
/// `y ∈ ±c_y/f_y` and the columns `±c_x/f_x` (the principal point taken as
/// the image centre: the message carries no image size; distortion
/// ignored, which moves the edges by a few px).
pub fn check_laser_lines(c: &Calibration, depth_mm: (f64, f64)) -> Result<(), CalibrationError> {
    let [fx, fy, cx, cy, _] = c.intrinsics.map(f64::from);
    let x_at = |k: usize, y: f64, z: f64| {
        let [nx, ny, nz, d] = c.planes[k].map(f64::from);
        (d / z - ny * y - nz) / nx
    };
    let z_datum = 0.5 * (depth_mm.0 + depth_mm.1);
    for k in 0..LASERS {
        let u = fx * x_at(k, 0.0, z_datum);
        if !(u.is_finite() && u.abs() <= cx) {
            return Err(CalibrationError::LineOutOfView { laser: k as u8, depth_mm: z_datum as f32 });
        }
    }
    let y_edge = cy / fy;
    for k in 0..LASERS - 1 {
        for z in [depth_mm.0, depth_mm.1] {
            for y in [-y_edge, y_edge] {
                let gap_px = fx * (x_at(k + 1, y, z) - x_at(k, y, z));
                // NaN (a degenerate plane) fails too.
                if gap_px.is_nan() || gap_px < MIN_LINE_SEPARATION_PX {
                    return Err(CalibrationError::LinesTooClose {
                        left: k as u8,
                        gap_px: gap_px as f32,
                        depth_mm: z as f32,
                        row_px: (fy * y + cy) as f32,
                    });
                }
            }
        }
    }
    Ok(())
}

/// A calibration is usable when [`triangulator`] accepts it.
pub fn calibration_is_valid(c: &Calibration) -> bool {
    triangulator(c).is_ok()
}

/// Why a head refuses a calibration (`PartialEq` only: it carries the
/// figures of a refusal as `f32`).
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CalibrationError {
    /// The identifier is 0.
    ZeroId,
    /// The camera or the planes are unusable.
    Geometry(crate::triangulation::Error),
    /// Laser `left`'s line and the next laser's are less than
    /// [`MIN_LINE_SEPARATION_PX`] apart (negative: crossed, or out of laser
    /// order) in image row `row_px` on a surface at `depth_mm`.
    LinesTooClose {
        /// The left laser of the pair (the other is `left + 1`).
        left: u8,
        /// Column of laser `left + 1` minus that of laser `left`, px.
        gap_px: f32,
        /// Depth along the optical axis, mm.
        depth_mm: f32,
        /// Image row, px.
        row_px: f32,
    },
    /// The laser's line is outside the image in its middle row at the
    /// middle of the working depth.
    LineOutOfView {
        /// The laser.
        laser: u8,
        /// Depth along the optical axis, mm.
        depth_mm: f32,
    },
}

impl core::fmt::Display for CalibrationError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            CalibrationError::ZeroId => f.write_str("calibration id is 0"),
            CalibrationError::Geometry(e) => write!(f, "calibration: {e}"),
            CalibrationError::LinesTooClose { left, gap_px, depth_mm, row_px } if *gap_px <= 0.0 => write!(
                f,
                "laser planes {left} and {} cross, coincide or are out of laser order in the working depth: at {depth_mm:.0} mm, \
                 row {row_px:.0}, laser {} is {:.1} px left of laser {left} (the lines must run left to right in laser order, \
                 at least {MIN_LINE_SEPARATION_PX} px apart)",
                left + 1,
                left + 1,
                -gap_px
            ),
            CalibrationError::LinesTooClose { left, gap_px, depth_mm, row_px } => write!(
                f,
                "laser planes {left} and {} are {gap_px:.1} px apart at {depth_mm:.0} mm, row {row_px:.0} \
                 (at least {MIN_LINE_SEPARATION_PX} px needed to tell their stripes apart)",
                left + 1
            ),
            CalibrationError::LineOutOfView { laser, depth_mm } => {
                write!(f, "laser plane {laser} puts its line outside the image at {depth_mm:.0} mm depth")
            }
        }
    }
}

impl core::error::Error for CalibrationError {}
