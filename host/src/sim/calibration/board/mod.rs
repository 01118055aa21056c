//! Calibration images from the simulated head: a planar checkerboard seen by
//! the head's camera, lit by a lamp and, optionally, by the head's lasers —
//! rendered from the same model as the rail ([`Camera`], the laser planes of
//! [`Scene::laser_planes`](crate::sim::scene::Scene::laser_planes), the sensor's [`noise`](crate::sim::scene::noise)), so that
//! the calibration chain (`cms-host calibrate camera|lasers`) can be checked
//! against the truth.
//!
//! # The board
//!
//! [`Board`] counts inner corners; corner `(i, j)` is at `(i·S, j·S, 0)` in
//! the board frame (see [`crate::model::board`]). The printed board has
//! `(cols + 1) × (rows + 1)` squares — square `(a, b)` covers
//! `[a·S, (a+1)·S] × [b·S, (b+1)·S]`, `a` in `-1..cols`, `b` in `-1..rows`,
//! black when `a + b` is even (so square `(-1, -1)` at the first corner is
//! black) — inside a white margin of [`RenderOptions::margin_squares`]
//! squares; beyond the paper is a dull backdrop lit by the lamp only.
//! The printed face is the board's `−z` side, the one a camera in front of it
//! sees when the board's `z` points away from it.
//!
//! # Rendering
//!
//! Each pixel is the square `[u ± ½] × [v ± ½]`. Its four corners are cast
//! through the camera model (undistortion, ray, board plane) into the board
//! frame, where the pixel's footprint is a quadrilateral (exact to ~1e-5 px:
//! the projection and distortion are affine at the scale of a pixel). Then:
//!
//! * **board reflectance**: the footprint's area in each square is computed
//!   exactly (polygon clipping), so checker edges are antialiased by true
//!   area coverage, not by a supersampling grid (no 1/N steps, no bias);
//! * **lasers**: a laser sheet is Gaussian across its plane — irradiance
//!   `exp(−δ²/2σ_s²)` at distance δ from the plane — with σ_s chosen so that
//!   on the head's nominal rail top the stripe has the sim's σ
//!   (`f_x·d·sin α / depth`, [`SimConfig::nominal_sigma_px`]); so on a board
//!   the stripe width is what the geometry makes of the same sheet. Its peak
//!   is the sim's (`signal_e_per_mw_us · power · brightness · exposure`, the
//!   sim's `depth / standoff` factor) times [`RenderOptions::laser_gain`],
//!   the board's reflectance and the ratio of the sheet's incidence cosine on
//!   the board to that on the rail. It is integrated over the pixel by 3 × 3
//!   Gauss–Legendre, times the pixel's mean reflectance plus the first-order
//!   covariance term (reflectance moment × sheet gradient) where a checker
//!   edge crosses the pixel;
//! * **lamp**: a uniform illumination of the board, [`RenderOptions::lamp_fraction`]
//!   of the full well on reflectance 1;
//! * **lens blur**: the pixel-integrated image is convolved with a sampled
//!   Gaussian of σ = [`RenderOptions::psf_sigma_px`] (separable, edges
//!   replicated): a symmetric point-spread function, so it blurs edges and
//!   stripes without moving them;
//! * **sensor**: the sim's ambient light (behind the band-pass filter, with
//!   its gradient), hot pixels, column and row banding, shot and read noise,
//!   saturation and quantisation, exactly as [`Scene`](crate::sim::scene::Scene) reads out a row (the
//!   same sensor pattern: same seed). The random noise of an image depends on
//!   `(config seed, shot)` only.
//!
//! # Cost
//!
//! Release build, one core (measured on a shared, loaded machine): about
//! 100 ms per 752 × 480 reference image (casting the pixel corners through
//! the distortion is a third of it) and about 2 s per 4752 × 3168 paper
//! image (15 M corner rays, the blur, 15 M noise draws).

mod poses;
mod render;
#[cfg(test)]
mod tests;

use crate::model::board::{Board, BoardPose};
use crate::model::vec3::{Vec3, dot, sub};
use crate::sim::scene::geom::mat_t_vec;
use crate::sim::scene::noise::SensorPattern;
use crate::sim::scene::{Camera, ScenePlane, SimConfig};
pub use poses::calibration_poses;
pub use render::render_board;

/// Stream of the board images' noise.
const BOARD_NOISE_STREAM: u64 = 0x424f_4152;
/// Stream of the poses' jitter.
const POSE_STREAM: u64 = 0x504f_5345;

/// How a board image is lit and blurred.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    /// σ of the Gaussian lens blur, px (0: none).
    pub psf_sigma_px: f64,
    /// Reflectance of the white squares and the margin (relative: the sim's
    /// rail at `rail.reflectance = 1` is 1).
    pub white: f64,
    /// Reflectance of the black squares.
    pub black: f64,
    /// Reflectance of the backdrop beyond the paper (lamp only: the lasers
    /// do not reach it).
    pub background: f64,
    /// White margin around the outer squares, in squares (≥ 1).
    pub margin_squares: u32,
    /// Lamp light on a surface of reflectance 1, as a fraction of the full
    /// well (at the camera's exposure).
    pub lamp_fraction: f64,
    /// Laser power during calibration relative to the nominal (keeps white
    /// + laser below saturation).
    pub laser_gain: f64,
}

impl Default for RenderOptions {
    /// σ_PSF 0.6 px; white 0.85, black 0.05, backdrop 0.2; one square of
    /// margin; lamp 0.3 of the full well (white ≈ 65 codes at 8 bits);
    /// lasers at 0.6 of their power (stripe peaks ≈ 50–110 codes on white).
    fn default() -> Self {
        RenderOptions {
            psf_sigma_px: 0.6,
            white: 0.85,
            black: 0.05,
            background: 0.2,
            margin_squares: 1,
            lamp_fraction: 0.3,
            laser_gain: 0.6,
        }
    }
}

/// A rendered image: `height` rows of `width` codes, `bits` deep.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BoardImage {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Bit depth of the codes.
    pub bits: u8,
    /// Row-major codes.
    pub pixels: Vec<u16>,
}

/// The calibration board for a head: 9 × 6 inner corners (10 × 7 squares;
/// odd × even, so its orientation is unambiguous) with squares such that
/// the 10 squares span about 2/3 of the image width at the near end of the
/// working range, rounded to 0.5 mm — room to tilt it and still keep the
/// outer squares inside the image:
///
/// * reference (752 px, f = 1400 px, 170–230 mm): 6 mm squares (60 × 42 mm
///   printed squares; 36–49 px a square);
/// * paper (4752 px, f = 5106 px, 350–550 mm): 21.5 mm squares (215 × 150.5
///   mm; 200–314 px a square).
pub fn board_for(cfg: &SimConfig) -> Board {
    let cam = &cfg.camera;
    let near_width_mm = cam.width_px() as f64 / cam.intrinsics.fx_px * cfg.head.working_range_mm[0];
    let square_mm = ((near_width_mm * 2.0 / 3.0 / 10.0) * 2.0).round().max(1.0) / 2.0;
    Board { cols: 9, rows: 6, square_mm }
}

/// The camera-frame point of the board plane that pixel `(u, v)` sees,
/// `None` if its ray misses the plane (parallel or behind the camera).
fn ray_on_board(cam: &Camera, pose: &BoardPose, u: f64, v: f64) -> Option<Vec3> {
    let ray = cam.intrinsics.unproject(u, v);
    let (n, d) = pose.plane();
    let den = dot(n, ray);
    if den.abs() < 1e-12 {
        return None;
    }
    let s = d / den;
    (s > 0.0 && s.is_finite()).then(|| [ray[0] * s, ray[1] * s, ray[2] * s])
}

/// The board-frame point `(x, y)` (mm) that pixel `(u, v)` sees, `None` if
/// its ray misses the board plane (parallel or behind the camera).
pub fn board_point(cam: &Camera, pose: &BoardPose, u: f64, v: f64) -> Option<[f64; 2]> {
    let x = ray_on_board(cam, pose, u, v)?;
    let b = mat_t_vec(&pose.rot, sub(x, pose.t_mm));
    Some([b[0], b[1]])
}

/// The signed distance (mm) from `plane` of the board point that pixel
/// `(u, v)` sees.
fn plane_distance_at(cam: &Camera, pose: &BoardPose, plane: &ScenePlane, u: f64, v: f64) -> Option<f64> {
    ray_on_board(cam, pose, u, v).map(|x| plane.distance_mm(x))
}

/// The true column (sub-pixel, pixel centres at integers) at which a laser
/// plane's line on the board plane crosses image row `row`: the `u` whose
/// ray meets the board plane on the laser plane (through the camera's
/// distortion), solved to 1e-9 px. `None` if it does not cross the row inside
/// the image. Whether that point is on the printed board is the caller's
/// question ([`board_point`]).
pub fn laser_column(cam: &Camera, plane: &ScenePlane, pose: &BoardPose, row: f64) -> Option<f64> {
    let f = |u: f64| plane_distance_at(cam, pose, plane, u, row);
    let (lo, hi) = (-0.5, cam.width_px() as f64 - 0.5);
    let step = 8.0;
    let mut a = lo;
    let mut fa = f(a);
    while a < hi {
        let b = (a + step).min(hi);
        let fb = f(b);
        if let (Some(x), Some(y)) = (fa, fb)
            && (x == 0.0 || x.signum() != y.signum())
        {
            // Bisection to a small bracket, then secant (δ is smooth in u).
            let (mut l, mut r, mut fl, mut fr) = (a, b, x, y);
            for _ in 0..60 {
                if r - l < 1e-10 {
                    break;
                }
                let m = if fr != fl { (l - fl * (r - l) / (fr - fl)).clamp(l, r) } else { 0.5 * (l + r) };
                // Guard against slow secant convergence: alternate with halving.
                let m = if (m - l).min(r - m) < 1e-3 * (r - l) { 0.5 * (l + r) } else { m };
                let fm = f(m)?;
                if fm == 0.0 {
                    return Some(m);
                }
                if fm.signum() == fl.signum() {
                    (l, fl) = (m, fm);
                } else {
                    (r, fr) = (m, fm);
                }
            }
            let u = if fr != fl { l - fl * (r - l) / (fr - fl) } else { 0.5 * (l + r) };
            return Some(u);
        }
        a = b;
        fa = fb;
    }
    None
}

/// One lit laser, for one pose.
#[derive(Clone, Copy, Debug)]
struct LaserOnBoard {
    /// Its plane, camera frame.
    plane: ScenePlane,
    /// δ = g0 + gx·x + gy·y on the board (x, y in mm, board frame).
    g: [f64; 3],
    /// Sheet σ, mm.
    sigma_mm: f64,
    /// Peak electrons on reflectance 1 at the standoff (before the depth factor).
    peak_e: f64,
}

/// A renderer of board images for one head: the scene's camera, lasers and
/// sensor, with [`RenderOptions`].
#[derive(Clone, Debug)]
pub struct BoardRenderer {
    cfg: SimConfig,
    planes: Vec<ScenePlane>,
    /// Per laser: the sheet's direction of propagation (unit, camera frame, z > 0).
    beams: Vec<Vec3>,
    /// Per laser: the sheet σ, mm.
    sheet_sigma_mm: Vec<f64>,
    /// Per laser: the incidence cosine on the nominal rail top.
    rail_incidence: Vec<f64>,
    sensor: SensorPattern,
    opts: RenderOptions,
}
