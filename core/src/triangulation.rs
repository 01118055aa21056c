//! From a stripe centre in the image to millimetres: the camera-frame point
//! on laser plane k and its coordinates in the profile frame of that laser.
//!
//! # Model
//! OpenCV's conventions: camera frame x right, y down, z forward (mm); pixel
//! centres at integer coordinates. A normalised, undistorted point `(x, y)`
//! (the ray `(x, y, 1)`) is distorted (Brown–Conrady) and projected as
//!
//! ```text
//! r² = x² + y²,  k = 1 + k1 r² + k2 r⁴ + k3 r⁶
//! x_d = x k + 2 p1 x y + p2 (r² + 2x²)
//! y_d = y k + p1 (r² + 2y²) + 2 p2 x y
//! u = fx x_d + skew y_d + cx,   v = fy y_d + cy
//! ```
//!
//! Laser k lights the plane `n_k · X = d_k` (unit `n_k`, camera frame). The
//! datum plane `n_r · X = d_r` is the rail-top reference surface, its unit
//! normal pointing from the rail towards the camera, so `d_r < 0` (the camera
//! is `−d_r` mm above it).
//!
//! **Profile frame** of laser k: the line `L_k = laser plane ∩ datum`, with
//! axis `a_k = unit(n_k × n_r)` oriented so that `a_k · (0, 1, 0) > 0` (along
//! increasing image rows) and origin `O_k` = the point of `L_k` closest to the
//! point where the optical axis meets the datum. Then
//!
//! ```text
//! along_mm  = a_k · (X − O_k)
//! height_mm = n_r · X − d_r        (normal to the rail surface, + towards the camera)
//! ```
//!
//! # Precision
//! The per-point path is `f32` (the STM32H743 has a single-precision FPU) and
//! stays within 0.1 µm of an `f64` evaluation over the paper's working range
//! (350–550 mm; `tests/tests/it/triangulation.rs` measures max 0.06 µm along,
//! 0.05 µm height, 0.07 µm |ΔX|). One ulp of `f32` at 512 mm is 61 nm, so the
//! camera-frame point itself cannot be stored better than ~0.03 µm, and the
//! naive `t = d/(n·r), X = t r` — even on the same carefully undistorted ray —
//! reaches 0.09 µm in `X` and 0.12 µm in height (a difference of two ~450 mm
//! numbers). So:
//!
//! * The pixel offsets `u − cx`, `v − cy` are formed exactly in integers
//!   (`Px` is Q16.16; the principal point is kept in Q32.32, exact for any
//!   `f32` above 2⁻⁸ px) and rounded to `f32` once.
//! * Undistortion solves for the *correction* `e = x − x_d` (Newton, analytic
//!   2×2 Jacobian, [`UNDISTORT_STEPS`] fixed steps) so its residual is formed
//!   from small terms and `x` is good to about one ulp.
//! * The intersection is taken relative to a per-laser origin `O` on the
//!   laser plane (precomputed in `f64`): with `r0 = O / O_z`, `t0 = O_z`,
//!   `Δ = (x, y) − r0`,
//!
//!   ```text
//!   q = t0 (n · Δ) / d,    X − O = t0 / (1 + q) · (Δ − q r0)
//!   ```
//!
//!   (`n·r0 = d/t0` because `O` is on the plane), where every quantity is
//!   small, so rounding scales with `|X − O|`, not with the range; `1 + q` is
//!   compensated (Fast2Sum) and `O` is added back as an `f32` pair
//!   `hi + lo`. The profile coordinates come straight from `X − O`.
//!
//! Cost per point (thumbv7em release, static count): undistortion about 300
//! instructions (the five Newton steps, one `VDIV` each, plus two for the
//! focal lengths and two `i64 → f32` library conversions), `profile` about
//! 130 more with two `VDIV`: roughly 1 µs at 480 MHz. Without distortion
//! coefficients the Newton steps are skipped.
//!
//! Setup (once per calibration) is `f64`: soft-float on the microcontroller,
//! never per point. `core` has no `f64` square root, so it is Newton from
//! micromath's `f32` estimate.

// `!(x > limit)` rejects NaN along with the out-of-range values, on purpose.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::fixed::{Px, Q48_16};
use crate::optics::{Optics, OpticsError, ScaleRange, sin};
use crate::protocol::LASERS;
use micromath::F32;

/// Newton steps of the undistortion. Measured (unit test
/// `undistort_convergence`, starting from `x_d`, counting steps until the
/// iterate is within 2 `f32` ulp of the fixed point): over |k1| ≤ 0.5,
/// |k2|, |k3| ≤ 0.05, |p1|, |p2| ≤ 1e-3 and undistorted radius ≤ 0.7 it takes
/// at most 4 steps wherever the model is clear of its fold (radial slope
/// `d r_d / d r ≥ 1/3`), and 2 for the paper-like lens (k1 = −0.1, corner
/// radius 0.56). The fifth step is the margin and doubles as the convergence
/// check. (Next to the fold — k1 = −0.5 with negative k2, k3 at r = 0.7,
/// slope < 0.25 — up to 9 steps are needed; there the result is good to the
/// residual before the last step, < 1e-4, or `None`.)
pub const UNDISTORT_STEPS: usize = 5;

/// A residual above this (normalised units) before the last Newton step
/// means the point is outside the region where the distortion model can be
/// inverted (it folds over beyond its maximum radius): no point.
const UNDISTORT_TOL: f32 = 1e-4;

/// `1 + q = t0 / t` must exceed this: rays (nearly) parallel to the laser
/// plane, behind the camera or meeting it beyond 64 × the origin's range give
/// no point.
const MIN_SCALE: f32 = 1.0 / 64.0;

/// Tolerance on the length of a unit normal before it is renormalised.
pub const UNIT_TOLERANCE: f64 = 1e-3;

/// Smallest sine of the angle between a laser plane and the datum.
pub const MIN_PLANE_ANGLE_SIN: f64 = 0.1;

/// Smallest `|n_z|` of the datum normal (the optical axis must meet it).
pub const MIN_DATUM_NZ: f64 = 0.1;

/// Laser planes closer than this to the camera centre (mm) are rejected.
pub const MIN_PLANE_DISTANCE_MM: f64 = 1.0;

/// The scale margin of paper §5.2 (25 % of the range at each end).
pub const PAPER_MARGIN: f64 = 0.25;

/// Pinhole camera with Brown–Conrady distortion (OpenCV's model).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CameraModel {
    /// Focal length along x, px.
    pub fx: f32,
    /// Focal length along y, px.
    pub fy: f32,
    /// Principal point, column (px, pixel centres at integers).
    pub cx: f32,
    /// Principal point, row (px).
    pub cy: f32,
    /// Skew (px): `u = fx x_d + skew y_d + cx`.
    pub skew: f32,
    /// Radial r² coefficient.
    pub k1: f32,
    /// Radial r⁴ coefficient.
    pub k2: f32,
    /// Tangential coefficient p1.
    pub p1: f32,
    /// Tangential coefficient p2.
    pub p2: f32,
    /// Radial r⁶ coefficient.
    pub k3: f32,
}

impl CameraModel {
    /// From the wire layout: intrinsics `[fx, fy, cx, cy, skew]` and
    /// distortion `[k1, k2, p1, p2, k3]` (OpenCV's order).
    pub const fn from_arrays(intrinsics: [f32; 5], distortion: [f32; 5]) -> Self {
        let [fx, fy, cx, cy, skew] = intrinsics;
        let [k1, k2, p1, p2, k3] = distortion;
        CameraModel { fx, fy, cx, cy, skew, k1, k2, p1, p2, k3 }
    }

    /// The ideal pinhole: no skew, no distortion.
    pub const fn pinhole(fx: f32, fy: f32, cx: f32, cy: f32) -> Self {
        CameraModel { fx, fy, cx, cy, skew: 0.0, k1: 0.0, k2: 0.0, p1: 0.0, p2: 0.0, k3: 0.0 }
    }

    /// Distorts a normalised point (the forward model, `f32`).
    pub fn distort(&self, x: f32, y: f32) -> [f32; 2] {
        let r2 = x * x + y * y;
        let kr = r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xy = x * y;
        [
            x + x * kr + 2.0 * self.p1 * xy + self.p2 * (r2 + 2.0 * x * x),
            y + y * kr + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * xy,
        ]
    }

    /// Projects a camera-frame point (mm, `z > 0`) to pixels `[u, v]`.
    pub fn project(&self, p: [f32; 3]) -> [f32; 2] {
        let [xd, yd] = self.distort(p[0] / p[2], p[1] / p[2]);
        [self.fx * xd + self.skew * yd + self.cx, self.fy * yd + self.cy]
    }
}

/// A plane `normal · X = d_mm` in the camera frame (unit normal).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Plane {
    /// Unit normal (within [`UNIT_TOLERANCE`]; renormalised at setup).
    pub normal: [f32; 3],
    /// Offset, mm.
    pub d_mm: f32,
}

impl From<[f32; 4]> for Plane {
    /// From the wire layout `[nx, ny, nz, d]`.
    fn from([x, y, z, d]: [f32; 4]) -> Self {
        Plane { normal: [x, y, z], d_mm: d }
    }
}

/// Why a [`Triangulator`] could not be built.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// A camera or plane parameter is NaN or infinite.
    NotFinite,
    /// `fx` or `fy` is not positive.
    FocalLength,
    /// The principal point is outside ±32767 px.
    PrincipalPoint,
    /// A plane normal is not of unit length (±[`UNIT_TOLERANCE`]); `laser`
    /// is `None` for the datum.
    NotUnit {
        /// The laser, or `None` for the datum.
        laser: Option<u8>,
    },
    /// The datum is not below the camera (`d_r` must be < 0 with its normal
    /// pointing towards the camera).
    DatumNotBelow,
    /// The optical axis (nearly) misses the datum (`n_r,z` must be below
    /// −[`MIN_DATUM_NZ`]).
    DatumAxis,
    /// Laser plane (nearly) parallel to the datum: no well-defined line.
    ParallelToDatum {
        /// The laser.
        laser: u8,
    },
    /// Laser plane passes within [`MIN_PLANE_DISTANCE_MM`] of the camera centre.
    ThroughCamera {
        /// The laser.
        laser: u8,
    },
    /// The profile origin of this laser is not in front of the camera.
    OriginBehind {
        /// The laser.
        laser: u8,
    },
    /// Laser index out of range.
    Laser,
    /// The scale range (Eq. 10–11) could not be formed.
    Optics(OpticsError),
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Error::NotFinite => f.write_str("calibration: a parameter is not finite"),
            Error::FocalLength => f.write_str("calibration: fx and fy must be > 0"),
            Error::PrincipalPoint => f.write_str("calibration: principal point outside ±32767 px"),
            Error::NotUnit { laser: None } => f.write_str("calibration: datum normal is not a unit vector"),
            Error::NotUnit { laser: Some(k) } => write!(f, "calibration: laser {k} normal is not a unit vector"),
            Error::DatumNotBelow => f.write_str("calibration: datum plane is not below the camera (d_r must be < 0)"),
            Error::DatumAxis => f.write_str("calibration: the optical axis does not meet the datum plane"),
            Error::ParallelToDatum { laser } => write!(f, "calibration: laser {laser} plane is parallel to the datum"),
            Error::ThroughCamera { laser } => write!(f, "calibration: laser {laser} plane passes through the camera"),
            Error::OriginBehind { laser } => write!(f, "calibration: laser {laser} line is behind the camera"),
            Error::Laser => f.write_str("laser index out of range"),
            Error::Optics(e) => write!(f, "optics: {e}"),
        }
    }
}

impl core::error::Error for Error {}

impl From<OpticsError> for Error {
    fn from(e: OpticsError) -> Self {
        Error::Optics(e)
    }
}

/// A point in the profile frame of one laser.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ProfilePoint {
    /// Along the laser line on the datum, mm (`a_k · (X − O_k)`).
    pub along_mm: f32,
    /// Above the datum, mm (`n_r · X − d_r`).
    pub height_mm: f32,
}

/// The profile frame of one laser (camera frame, mm).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ProfileFrame {
    /// `O_k`: origin, on the laser plane and the datum.
    pub origin_mm: [f64; 3],
    /// `a_k`: unit direction of the laser line on the datum.
    pub along: [f64; 3],
    /// `n_r`: unit datum normal (height direction).
    pub up: [f64; 3],
    /// Unit laser plane normal.
    pub laser_normal: [f64; 3],
}

/// Per-laser constants of the per-point path.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Laser {
    /// `r0 = O'/O'_z` (the `f32` values define `O'`).
    r0: [f32; 2],
    /// `n_{x,y} / (n · r0)`: `q = c · Δ`.
    c: [f32; 2],
    /// `t0 = d / (n · r0)` = `O'_z`.
    t0: f32,
    /// `O'` as an unevaluated sum `hi + lo`.
    origin_hi: [f32; 3],
    origin_lo: [f32; 3],
    /// `a_k`.
    along: [f32; 3],
    /// `a_k · (O' − O_k)`, `n_r · O' − d_r`: `O'` is `O_k` up to `f32` rounding of `r0`.
    along_off: f32,
    height_off: f32,
    frame: ProfileFrame,
}

/// Triangulation for one calibration: validated once, then per point
/// without errors (`None` only for rays that miss).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Triangulator {
    camera: CameraModel,
    /// `cx`, `cy` in Q32.32.
    cx_q32: i64,
    cy_q32: i64,
    /// No distortion coefficients: undistortion is the identity.
    pinhole: bool,
    /// `n_r` (unit, `f32`).
    up: [f32; 3],
    lasers: [Laser; LASERS],
}

impl Triangulator {
    /// Validates the calibration and precomputes the per-laser constants.
    pub fn new(camera: &CameraModel, lasers: &[Plane; LASERS], datum: &Plane) -> Result<Self, Error> {
        let c = camera;
        let params = [c.fx, c.fy, c.cx, c.cy, c.skew, c.k1, c.k2, c.p1, c.p2, c.k3];
        let planes_finite = lasers
            .iter()
            .chain(core::iter::once(datum))
            .all(|p| p.normal.iter().all(|v| v.is_finite()) && p.d_mm.is_finite());
        if !params.iter().all(|v| v.is_finite()) || !planes_finite {
            return Err(Error::NotFinite);
        }
        if !(c.fx > 0.0 && c.fy > 0.0) {
            return Err(Error::FocalLength);
        }
        if !(c.cx > -32767.0 && c.cx < 32767.0 && c.cy > -32767.0 && c.cy < 32767.0) {
            return Err(Error::PrincipalPoint);
        }
        let (nr, dr) = unit_plane(datum).ok_or(Error::NotUnit { laser: None })?;
        if !(dr < 0.0) {
            return Err(Error::DatumNotBelow);
        }
        if !(nr[2] < -MIN_DATUM_NZ) {
            return Err(Error::DatumAxis);
        }
        // Where the optical axis meets the datum.
        let p = [0.0, 0.0, dr / nr[2]];

        let mut out = [None; LASERS];
        for (k, plane) in lasers.iter().enumerate() {
            let laser = k as u8;
            let (n, d) = unit_plane(plane).ok_or(Error::NotUnit { laser: Some(laser) })?;
            if !(abs64(d) > MIN_PLANE_DISTANCE_MM) {
                return Err(Error::ThroughCamera { laser });
            }
            let axis = cross(n, nr);
            let s2 = dot(axis, axis);
            if !(s2 > MIN_PLANE_ANGLE_SIN * MIN_PLANE_ANGLE_SIN) {
                return Err(Error::ParallelToDatum { laser });
            }
            let mut a = scale(axis, 1.0 / sqrt64(s2));
            // Along increasing rows; ties (a line horizontal in the image)
            // towards +x, then +z.
            let key = if a[1] != 0.0 {
                a[1]
            } else if a[0] != 0.0 {
                a[0]
            } else {
                a[2]
            };
            if key < 0.0 {
                a = scale(a, -1.0);
            }
            // O = P + λ n + μ n_r on both planes, P on the datum:
            // λ (1 − c²) = d − n·P, μ = −λ c, c = n·n_r.
            let cnr = dot(n, nr);
            let lambda = (d - dot(n, p)) / s2;
            let o = add(p, add(scale(n, lambda), scale(nr, -lambda * cnr)));
            if !(o[2] > MIN_PLANE_DISTANCE_MM) {
                return Err(Error::OriginBehind { laser });
            }
            // The f32 direction r0 defines O' = t0 r0 exactly on the plane.
            let r0 = [(o[0] / o[2]) as f32, (o[1] / o[2]) as f32];
            let r0d = [r0[0] as f64, r0[1] as f64, 1.0];
            let m = dot(n, r0d);
            let t0 = d / m;
            let o1 = scale(r0d, t0);
            let hi = [o1[0] as f32, o1[1] as f32, o1[2] as f32];
            let lo = [(o1[0] - hi[0] as f64) as f32, (o1[1] - hi[1] as f64) as f32, (o1[2] - hi[2] as f64) as f32];
            out[k] = Some(Laser {
                r0,
                c: [(n[0] / m) as f32, (n[1] / m) as f32],
                t0: t0 as f32,
                origin_hi: hi,
                origin_lo: lo,
                along: [a[0] as f32, a[1] as f32, a[2] as f32],
                along_off: dot(a, sub(o1, o)) as f32,
                height_off: (dot(nr, o1) - dr) as f32,
                frame: ProfileFrame { origin_mm: o, along: a, up: nr, laser_normal: n },
            });
        }
        let lasers = out.map(|l| l.expect("every laser set above"));
        Ok(Triangulator {
            camera: *camera,
            cx_q32: (c.cx as f64 * 4_294_967_296.0) as i64,
            cy_q32: (c.cy as f64 * 4_294_967_296.0) as i64,
            pinhole: [c.k1, c.k2, c.p1, c.p2, c.k3].iter().all(|&v| v == 0.0),
            up: [nr[0] as f32, nr[1] as f32, nr[2] as f32],
            lasers,
        })
    }

    /// The camera model.
    pub fn camera(&self) -> &CameraModel {
        &self.camera
    }

    /// The profile frame of laser `laser` (`None` if out of range).
    pub fn frame(&self, laser: usize) -> Option<ProfileFrame> {
        self.lasers.get(laser).map(|l| l.frame)
    }

    /// The normalised, undistorted image point `(x, y)` (the ray `(x, y, 1)`)
    /// of pixel `(column, row)`. `None` where the distortion model cannot be
    /// inverted (far outside the calibrated field).
    pub fn undistort(&self, column: Px, row: Px) -> Option<[f32; 2]> {
        self.undistort_q32((column.0 as i64) << 16, (row.0 as i64) << 16)
    }

    /// `u − cx`, `v − cy` exactly in Q32.32, then `f32`.
    fn undistort_q32(&self, u_q32: i64, v_q32: i64) -> Option<[f32; 2]> {
        let c = &self.camera;
        const INV_2_32: f32 = 1.0 / 4_294_967_296.0;
        let du = (u_q32 - self.cx_q32) as f32 * INV_2_32;
        let dv = (v_q32 - self.cy_q32) as f32 * INV_2_32;
        let yd = dv / c.fy;
        let xd = (du - c.skew * yd) / c.fx;
        if self.pinhole {
            return Some([xd, yd]);
        }
        let mut e = [0.0f32; 2];
        let mut converged = false;
        for step in 0..UNDISTORT_STEPS {
            let (next, residual2, det) = undistort_step(c, xd, yd, e);
            if step == UNDISTORT_STEPS - 1 {
                converged = residual2 < UNDISTORT_TOL * UNDISTORT_TOL && det > 0.0;
            }
            e = next;
        }
        let (ex, ey) = (e[0], e[1]);
        let (x, y) = (xd + ex, yd + ey);
        (converged && x.is_finite() && y.is_finite()).then_some([x, y])
    }

    /// `X − O'` for laser `l`, or `None`.
    #[inline]
    fn delta(&self, l: &Laser, position: Px, row_q32: i64) -> Option<[f32; 3]> {
        let [x, y] = self.undistort_q32((position.0 as i64) << 16, row_q32)?;
        let dx = x - l.r0[0];
        let dy = y - l.r0[1];
        let q = l.c[0] * dx + l.c[1] * dy;
        let w = 1.0 + q;
        if !(w > MIN_SCALE) {
            return None;
        }
        // Fast2Sum: w + e = 1 + q exactly; t0/(w + e) ≈ s (1 − e/w).
        let e = if q <= 1.0 { q - (w - 1.0) } else { 1.0 - (w - q) };
        let s0 = l.t0 / w;
        let s = s0 - s0 * (e / w);
        let v = [s * (dx - q * l.r0[0]), s * (dy - q * l.r0[1]), -(s * q)];
        (v[0].is_finite() && v[1].is_finite() && v[2].is_finite()).then_some(v)
    }

    /// The camera-frame point (mm) of the stripe centre at column `position`
    /// in image row `row` on laser plane `laser`. `None` if the ray is
    /// (nearly) parallel to the plane, meets it behind the camera, the pixel
    /// is outside the invertible field, or `laser` is out of range.
    pub fn point_mm(&self, laser: usize, position: Px, row: u16) -> Option<[f32; 3]> {
        let l = self.lasers.get(laser)?;
        let v = self.delta(l, position, (row as i64) << 32)?;
        let p = [
            l.origin_hi[0] + (v[0] + l.origin_lo[0]),
            l.origin_hi[1] + (v[1] + l.origin_lo[1]),
            l.origin_hi[2] + (v[2] + l.origin_lo[2]),
        ];
        (p[0].is_finite() && p[1].is_finite() && p[2].is_finite()).then_some(p)
    }

    /// The profile-frame coordinates of the same point (see [`Self::point_mm`]).
    pub fn profile(&self, laser: usize, position: Px, row: u16) -> Option<ProfilePoint> {
        self.profile_q32(laser, position, (row as i64) << 32)
    }

    /// [`Self::profile`] at a fractional `row` (wide enough for any `u16`
    /// row and its fraction): the centre of a binned row
    /// ([`RowSampling::Bin`](crate::readout::RowSampling::Bin)).
    pub fn profile_at(&self, laser: usize, position: Px, row: Q48_16) -> Option<ProfilePoint> {
        self.profile_q32(laser, position, row.0 << 16)
    }

    fn profile_q32(&self, laser: usize, position: Px, row_q32: i64) -> Option<ProfilePoint> {
        let l = self.lasers.get(laser)?;
        let v = self.delta(l, position, row_q32)?;
        let a = &l.along;
        let n = &self.up;
        let along_mm = (a[0] * v[0] + a[1] * v[1] + a[2] * v[2]) + l.along_off;
        let height_mm = (n[0] * v[0] + n[1] * v[1] + n[2] * v[2]) + l.height_off;
        (along_mm.is_finite() && height_mm.is_finite()).then_some(ProfilePoint { along_mm, height_mm })
    }

    /// α of laser `laser`: the angle between the optical axis and the laser
    /// plane, `asin(|n_z|)`, degrees.
    ///
    /// The paper writes α = arctan(n_y/n_z) in its own axes; what the sin α of
    /// Eq. 10–11 needs is the angle between the camera's line of sight and
    /// the laser sheet (the stripe's apparent width is `d · sin α` seen at
    /// range r), i.e. between the optical axis and the plane: 42° for Table 4.
    pub fn alpha_deg(&self, laser: usize) -> Result<f64, Error> {
        let l = self.lasers.get(laser).ok_or(Error::Laser)?;
        Ok(asin(abs64(l.frame.laser_normal[2])).to_degrees_core())
    }

    /// The detector's optics for laser `laser` (paper Eq. 10–11, 25 % margin):
    /// `fx`, α from the plane, the given laser line diameter and working range
    /// (distance along the optical axis, mm).
    pub fn optics(&self, laser: usize, laser_diameter_mm: f64, working_range_mm: (f64, f64)) -> Result<Optics, Error> {
        let o = Optics {
            fx_px: self.camera.fx as f64,
            laser_diameter_mm,
            alpha_deg: self.alpha_deg(laser)?,
            r_min_mm: working_range_mm.0,
            r_max_mm: working_range_mm.1,
            margin: PAPER_MARGIN,
        };
        o.scale_range()?;
        Ok(o)
    }

    /// A scale range covering all lasers (the union of their Eq. 10–11 ranges).
    pub fn scale_range(&self, laser_diameter_mm: f64, working_range_mm: (f64, f64)) -> Result<ScaleRange, Error> {
        let mut lo = Px(i32::MAX);
        let mut hi = Px(i32::MIN);
        for k in 0..LASERS {
            let r = self.optics(k, laser_diameter_mm, working_range_mm)?.scale_range()?;
            lo = lo.min(r.min());
            hi = hi.max(r.max());
        }
        Ok(ScaleRange::new(lo, hi)?)
    }
}

/// One Newton step of the undistortion on the correction `e = (x, y) −
/// (x_d, y_d)`: `F(e) = e + x kr + tangential(x, y)` (= distort(x, y) −
/// (x_d, y_d), formed from small terms), `J = ∂distort/∂(x, y)` (symmetric
/// in its off-diagonal). Returns the next `e`, `|F(e)|²` and `det J` at `e`.
#[inline(always)]
fn undistort_step(c: &CameraModel, xd: f32, yd: f32, e: [f32; 2]) -> ([f32; 2], f32, f32) {
    let (k1, k2, k3, p1, p2) = (c.k1, c.k2, c.k3, c.p1, c.p2);
    let x = xd + e[0];
    let y = yd + e[1];
    let (x2, y2, xy) = (x * x, y * y, x * y);
    let r2 = x2 + y2;
    let kr = r2 * (k1 + r2 * (k2 + r2 * k3));
    // d kr / d r²
    let g = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
    let fx = e[0] + (x * kr + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2));
    let fy = e[1] + (y * kr + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy);
    let j11 = 1.0 + kr + 2.0 * x2 * g + 2.0 * p1 * y + 6.0 * p2 * x;
    let j12 = 2.0 * xy * g + 2.0 * p1 * x + 2.0 * p2 * y;
    let j22 = 1.0 + kr + 2.0 * y2 * g + 6.0 * p1 * y + 2.0 * p2 * x;
    let det = j11 * j22 - j12 * j12;
    let inv = 1.0 / det;
    ([e[0] - (j22 * fx - j12 * fy) * inv, e[1] - (j11 * fy - j12 * fx) * inv], fx * fx + fy * fy, det)
}

/// The plane with its normal renormalised in `f64` (`d` scaled alike), or
/// `None` if `|n|` is not 1 ± [`UNIT_TOLERANCE`].
fn unit_plane(p: &Plane) -> Option<([f64; 3], f64)> {
    let n = [p.normal[0] as f64, p.normal[1] as f64, p.normal[2] as f64];
    let len = sqrt64(dot(n, n));
    if !(abs64(len - 1.0) <= UNIT_TOLERANCE) {
        return None;
    }
    Some((scale(n, 1.0 / len), p.d_mm as f64 / len))
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn abs64(x: f64) -> f64 {
    if x < 0.0 { -x } else { x }
}

/// √x in `f64` without `std`: Newton from micromath's `f32` estimate (~5 %
/// off; quadratic convergence reaches `f64` precision in 5 steps, 7 run).
/// For setup values of moderate size (finite, within `f32` range).
fn sqrt64(x: f64) -> f64 {
    if !(x > 0.0) {
        return if x == 0.0 { 0.0 } else { f64::NAN };
    }
    let mut y = F32(x as f32).sqrt().0 as f64;
    if !(y > 0.0 && y.is_finite()) {
        y = 1.0;
    }
    for _ in 0..7 {
        y = 0.5 * (y + x / y);
    }
    y
}

/// asin(s) for s ∈ [0, 1] by bisection on `optics::sin` (setup only; 64 halvings
/// of [0, π/2] reach `f64` resolution, robust at s = 1 where Newton is not).
fn asin(s: f64) -> f64 {
    let (mut lo, mut hi) = (0.0f64, core::f64::consts::FRAC_PI_2);
    if !(s < 1.0) {
        return hi;
    }
    for _ in 0..64 {
        let mid = 0.5 * (lo + hi);
        if sin(mid) < s {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

trait ToDegrees {
    fn to_degrees_core(self) -> f64;
}
impl ToDegrees for f64 {
    fn to_degrees_core(self) -> f64 {
        self * (180.0 / core::f64::consts::PI)
    }
}

#[cfg(test)]
mod tests;
