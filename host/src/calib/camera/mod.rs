//! Camera calibration from checkerboard views: Zhang's closed-form
//! initialisation, Levenberg–Marquardt refinement of the intrinsics, the
//! distortion and every board pose; the pose of a board seen by a calibrated
//! camera; and `cms-host calibrate camera`.
//!
//! **Initialisation** (Zhang 2000). A homography per view from the board
//! plane to the image by the normalised DLT (Hartley's conditioning; the
//! null vector of the 9 × 9 normal matrix, so four points suffice); the
//! image of the absolute conic `B = K⁻ᵀK⁻¹` from the two constraints
//! `h₁ᵀBh₂ = 0`, `h₁ᵀBh₁ = h₂ᵀBh₂` of each view (plus `B₁₂ = 0` when the skew
//! is fixed), solved after mapping the image to `[-½, ½]` so the six unknowns
//! have comparable magnitudes; the intrinsics in closed form; each pose from
//! `K⁻¹H` with its rotation made orthonormal by SVD. When the closed form is
//! degenerate (too few or too similar views, or a principal point outside the
//! image) it falls back to OpenCV's initialisation: principal point at the
//! image centre, focal lengths by linear least squares on the same
//! constraints. Distortion starts at zero.
//!
//! **Refinement.** One dense Levenberg–Marquardt ([`crate::model::lm`]) over the
//! free intrinsics (`fx, fy, cx, cy`, optionally the skew — fixed at 0 by
//! default, as in OpenCV — `k1, k2, p1, p2, k3`) and six parameters per view
//! (Rodrigues vector, translation), minimising the squared pixel
//! reprojection error. With a fixed aspect ratio (OpenCV's
//! `CALIB_FIX_ASPECT_RATIO`) `fx = a·fy` and only `fy` is free. The Jacobian
//! is by central differences ([`lm::CentralDifferences`]: the model is
//! smooth and cheap, 13 views × 54 corners is 88 unknowns and 1404
//! residuals, a few ms per Jacobian); Marquardt's `μ·diag(JᵀJ)` damping
//! makes the step invariant to each parameter's units. Block-sparse normal
//! equations (Schur complement on the poses) would matter only beyond ~100
//! views.
//!
//! **Errors** are reported as OpenCV does: the RMS over corners of the
//! Euclidean reprojection distance, overall and per view.
//!
//! **Checks a metrologist makes**, in this order:
//! 1. *Distinct views.* Two views whose corners lie within
//!    [`DUPLICATE_RMS_PX`] RMS of each other are one pose photographed twice
//!    (the same file given twice, a head held still): they add no
//!    information but make the fit look certain, so the later one is named
//!    and left out ([`CameraCalibration::duplicates`]). `O(V²·N)` for `V`
//!    views of `N` corners: nothing beside the fit.
//! 2. *What the views can determine.* `k3` multiplies r⁶: corners that do not
//!    reach [`MIN_RADIUS_K3`] of the focal length off the axis cannot tell it
//!    from `k1` and `k2`, so it is fixed at 0 (OpenCV's `CALIB_FIX_K3`). After
//!    the fit, when the uncertainty of the radial (or tangential) distortion
//!    at the farthest corner seen exceeds [`FIX_DISTORTION_SIGMA_PX`], `k3`
//!    (then `p1, p2`) is fixed and the fit made again. Each fixing is said
//!    ([`CameraCalibration::fixed`]).
//! 3. *Uncertainty.* The covariance of all the parameters is
//!    `σ²·(JᵀJ)⁻¹` at the solution (`J` the Jacobian of the residuals, `σ²`
//!    their sum of squares over `m − n`, OpenCV's
//!    `stdDeviationsIntrinsics`); the standard deviation of each intrinsic
//!    is its diagonal ([`CameraCalibration::sigma`]). One more Jacobian and a
//!    Cholesky of the `n × n` normal matrix: ~10 ms for 24 views. The
//!    calibration is refused ([`CalibError::Uncertain`]) when σ(fx) or σ(fy)
//!    exceeds [`MAX_SIGMA_FOCAL`] of the focal length, σ(cx) or σ(cy)
//!    [`MAX_SIGMA_CENTRE`] of the image side, or the distortion at the
//!    farthest corner seen is uncertain by more than [`MAX_DISTORTION_SIGMA_PX`]:
//!    the views do not determine the camera (too few, too alike, too little
//!    tilt), and the message says which figure failed.

mod geometry;
mod refine;

use std::fmt;
use std::path::{Path, PathBuf};

use crate::calib::board::{CornerError, find_corners};

use nalgebra::Matrix3;

use crate::model::board::{Board, BoardPose};
use crate::model::camera::Intrinsics;
use crate::model::lm;
use geometry::{homography, pose_from, pose_from_homography};
use refine::{calibrate_subset, rms_of, view_residuals};

/// Two views closer than this (RMS over corners, px) are one pose.
pub const DUPLICATE_RMS_PX: f64 = 1.0;
/// Farthest corner from the principal point, as a fraction of the focal
/// length, below which `k3` is fixed at 0.
pub const MIN_RADIUS_K3: f64 = 0.5;
/// Uncertainty of the distortion at the farthest corner seen above which
/// `k3`, then `p1, p2`, are fixed and the fit made again, px.
pub const FIX_DISTORTION_SIGMA_PX: f64 = 0.5;
/// Largest accepted σ(fx), σ(fy), as a fraction of the focal length.
pub const MAX_SIGMA_FOCAL: f64 = 0.01;
/// Largest accepted σ(cx), σ(cy), as a fraction of the image width, height.
pub const MAX_SIGMA_CENTRE: f64 = 0.02;
/// Largest accepted uncertainty of the radial or tangential distortion at
/// the farthest corner seen, px.
pub const MAX_DISTORTION_SIGMA_PX: f64 = 1.0;

/// The intrinsics in [`Sigma`]'s order (the calibration file's keys).
pub const INTRINSIC_NAMES: [&str; 10] = ["fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3"];

/// One standard deviation of each intrinsic, in [`INTRINSIC_NAMES`] order
/// (px for `fx … skew`); `None` for a parameter held fixed.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sigma(pub [Option<f64>; 10]);

/// The covariance of the intrinsics, in [`INTRINSIC_NAMES`] order (0 for a
/// parameter held fixed).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Covariance(pub [[f64; 10]; 10]);

impl Covariance {
    /// Entry `(i, j)`.
    pub fn get(&self, i: usize, j: usize) -> f64 {
        self.0[i][j]
    }
}

impl Sigma {
    /// σ of the intrinsic named `name` (see [`INTRINSIC_NAMES`]).
    pub fn get(&self, name: &str) -> Option<f64> {
        INTRINSIC_NAMES.iter().position(|n| *n == name).and_then(|i| self.0[i])
    }
}

/// What [`calibrate`] estimates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibOptions {
    /// Keep the skew at 0 (OpenCV always does).
    pub fix_skew: bool,
    /// Keep `fx / fy` at this ratio (OpenCV's `CALIB_FIX_ASPECT_RATIO`).
    pub fix_aspect: Option<f64>,
    /// After a first fit, drop views whose RMS error exceeds this (px) and
    /// fit again.
    pub max_view_rms_px: Option<f64>,
    /// Levenberg–Marquardt limit on trial steps (accepted or not).
    pub max_iterations: usize,
    /// Keep `k3` at 0 (it is also fixed when the views cannot determine it).
    pub fix_k3: bool,
    /// Keep `p1, p2` at 0 (they are also fixed when the views cannot determine them).
    pub fix_tangential: bool,
}

impl Default for CalibOptions {
    fn default() -> Self {
        CalibOptions {
            fix_skew: true,
            fix_aspect: None,
            max_view_rms_px: None,
            max_iterations: 200,
            fix_k3: false,
            fix_tangential: false,
        }
    }
}

/// The result of [`calibrate`].
#[derive(Clone, Debug, PartialEq)]
pub struct CameraCalibration {
    /// Intrinsics and distortion.
    pub intrinsics: Intrinsics,
    /// RMS reprojection error over all corners of the views used, px.
    pub rms_px: f64,
    /// Indices (into the `views` given) of the views used.
    pub views_used: Vec<usize>,
    /// Views dropped for their RMS error (`CalibOptions::max_view_rms_px`),
    /// with that error from the first fit, px.
    pub views_rejected: Vec<(usize, f64)>,
    /// RMS reprojection error of each view used, px.
    pub per_view_rms_px: Vec<f64>,
    /// Board pose of each view used.
    pub poses: Vec<BoardPose>,
    /// Levenberg–Marquardt trial steps (accepted or not) of the last fit.
    pub iterations: usize,
    /// Views left out as near-duplicates: `(view, the earlier view it
    /// repeats, RMS corner distance px)`.
    pub duplicates: Vec<(usize, usize, f64)>,
    /// Parameters fixed because the views could not determine them, each
    /// with why.
    pub fixed: Vec<String>,
    /// One standard deviation of each intrinsic, from the Jacobian at the
    /// solution.
    pub sigma: Sigma,
    /// The covariance of the intrinsics.
    pub covariance: Covariance,
    /// Farthest corner seen from the principal point, px.
    pub max_radius_px: f64,
}

/// Why a calibration failed.
#[derive(Clone, Debug, PartialEq)]
pub enum CalibError {
    /// Fewer than three views (after rejection).
    TooFewViews {
        /// Views available.
        got: usize,
    },
    /// A view does not hold one point per board corner.
    CornerCount {
        /// Index of the view.
        view: usize,
        /// Points given.
        got: usize,
        /// `cols × rows`.
        expected: usize,
    },
    /// The views do not determine the camera (collinear corners, parallel
    /// views, non-finite numbers).
    Degenerate(&'static str),
    /// An intrinsic's uncertainty exceeds its limit: what, in words.
    Uncertain(String),
}

impl fmt::Display for CalibError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CalibError::TooFewViews { got } => write!(f, "{got} distinct usable views; calibration needs at least 3"),
            CalibError::CornerCount { view, got, expected } => {
                write!(f, "view {view} has {got} corners, the board {expected}")
            }
            CalibError::Degenerate(why) => write!(f, "degenerate views: {why}"),
            CalibError::Uncertain(why) => write!(f, "the views do not determine the camera: {why}"),
        }
    }
}

impl std::error::Error for CalibError {}

/// Calibrates a camera from views of `board`: each view the detected
/// corners, in [`Board::object_points`] order, px. Near-duplicate views are
/// left out, parameters the views cannot determine fixed, and the result
/// refused when an intrinsic is too uncertain (see the [module](self)).
pub fn calibrate(
    board: &Board,
    views: &[Vec<[f64; 2]>],
    width: u32,
    height: u32,
    opts: &CalibOptions,
) -> Result<CameraCalibration, CalibError> {
    let expected = board.cols * board.rows;
    for (view, v) in views.iter().enumerate() {
        if v.len() != expected {
            return Err(CalibError::CornerCount { view, got: v.len(), expected });
        }
        if !v.iter().all(|p| p[0].is_finite() && p[1].is_finite()) {
            return Err(CalibError::Degenerate("non-finite corner"));
        }
    }
    let duplicates = duplicates_of(views);
    let distinct: Vec<usize> = (0..views.len()).filter(|v| !duplicates.iter().any(|d| d.0 == *v)).collect();
    let mut opts = *opts;
    let mut fixed = Vec::new();
    let mut cal = fit_rejecting(board, views, &distinct, width, height, &opts)?;
    loop {
        let f = cal.intrinsics.fx_px.min(cal.intrinsics.fy_px);
        let reach = cal.max_radius_px / f;
        let (radial, tangential) = distortion_sigma_px(&cal);
        let why = if !opts.fix_k3 && reach < MIN_RADIUS_K3 {
            opts.fix_k3 = true;
            format!(
                "k3 fixed at 0: the corners reach {reach:.2} of the focal length from the principal point, k3 needs {MIN_RADIUS_K3}"
            )
        } else if !opts.fix_k3 && radial > FIX_DISTORTION_SIGMA_PX {
            opts.fix_k3 = true;
            format!(
                "k3 fixed at 0: with it the radial distortion at the farthest corner is uncertain by {radial:.2} px (> {FIX_DISTORTION_SIGMA_PX} px)"
            )
        } else if !opts.fix_tangential && tangential > FIX_DISTORTION_SIGMA_PX {
            opts.fix_tangential = true;
            format!(
                "p1, p2 fixed at 0: with them the tangential distortion at the farthest corner is uncertain by {tangential:.2} px (> {FIX_DISTORTION_SIGMA_PX} px)"
            )
        } else {
            break;
        };
        fixed.push(why);
        cal = fit_rejecting(board, views, &distinct, width, height, &opts)?;
    }
    check_uncertainty(&cal)?;
    cal.duplicates = duplicates;
    cal.fixed = fixed;
    Ok(cal)
}

/// One fit of the views `used`, and with `max_view_rms_px` a second without
/// the views above it.
fn fit_rejecting(
    board: &Board,
    views: &[Vec<[f64; 2]>],
    used: &[usize],
    width: u32,
    height: u32,
    opts: &CalibOptions,
) -> Result<CameraCalibration, CalibError> {
    let mut cal = calibrate_subset(board, views, used, width, height, opts)?;
    if let Some(limit) = opts.max_view_rms_px {
        let rejected: Vec<(usize, f64)> = cal
            .views_used
            .iter()
            .zip(&cal.per_view_rms_px)
            .filter(|&(_, &e)| e > limit)
            .map(|(&v, &e)| (v, e))
            .collect();
        if !rejected.is_empty() {
            let keep: Vec<usize> = used.iter().copied().filter(|v| !rejected.iter().any(|r| r.0 == *v)).collect();
            cal = calibrate_subset(board, views, &keep, width, height, opts)?;
            cal.views_rejected = rejected;
        }
    }
    Ok(cal)
}

/// RMS distance of two views' corners, px: in the same order, or reversed
/// (a board symmetric under a half turn may be labelled either way).
fn corner_rms_px(a: &[[f64; 2]], b: &[[f64; 2]]) -> f64 {
    let rms = |it: &mut dyn Iterator<Item = (&[f64; 2], &[f64; 2])>| {
        let (s, n) =
            it.fold((0.0, 0usize), |(s, n), (p, q)| (s + (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2), n + 1));
        (s / n.max(1) as f64).sqrt()
    };
    rms(&mut a.iter().zip(b)).min(rms(&mut a.iter().zip(b.iter().rev())))
}

/// Views within [`DUPLICATE_RMS_PX`] of an earlier view kept: `(view,
/// earlier view, RMS px)`.
pub fn duplicates_of(views: &[Vec<[f64; 2]>]) -> Vec<(usize, usize, f64)> {
    let mut out: Vec<(usize, usize, f64)> = Vec::new();
    for j in 0..views.len() {
        let nearest = (0..j)
            .filter(|i| !out.iter().any(|d| d.0 == *i))
            .map(|i| (i, corner_rms_px(&views[i], &views[j])))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((i, d)) = nearest
            && d < DUPLICATE_RMS_PX
        {
            out.push((j, i, d));
        }
    }
    out
}

/// Uncertainty (one σ, px) of the radial and of the tangential distortion
/// at the farthest corner seen: the radial displacement `f·(k1 r³ + k2 r⁵ +
/// k3 r⁷)` with the covariance of `k1, k2, k3` (they are strongly
/// correlated: their σ alone would overstate it), and the tangential
/// `3 f r² · max(σ(p1), σ(p2))` (its largest term).
fn distortion_sigma_px(cal: &CameraCalibration) -> (f64, f64) {
    let f = cal.intrinsics.fx_px.min(cal.intrinsics.fy_px);
    let r = cal.max_radius_px / f;
    let g = [f * r.powi(3), f * r.powi(5), f * r.powi(7)];
    let mut var = 0.0;
    for (a, ga) in [5, 6, 9].iter().zip(g) {
        for (b, gb) in [5, 6, 9].iter().zip(g) {
            var += ga * gb * cal.covariance.get(*a, *b);
        }
    }
    let p = cal.sigma.0[7].unwrap_or(0.0).max(cal.sigma.0[8].unwrap_or(0.0));
    (var.max(0.0).sqrt(), 3.0 * f * r * r * p)
}

/// Refuses a calibration an intrinsic of which is too uncertain.
fn check_uncertainty(cal: &CameraCalibration) -> Result<(), CalibError> {
    let k = &cal.intrinsics;
    let spread = orientation_spread_deg(&cal.poses);
    let fail = |what: String| {
        Err(CalibError::Uncertain(format!(
            "{what} ({} views, board orientations within {spread:.1}°: add views with the board tilted differently)",
            cal.views_used.len()
        )))
    };
    for (i, v, name) in [(0, k.fx_px, "fx"), (1, k.fy_px, "fy")] {
        if let Some(s) = cal.sigma.0[i]
            && (s.is_nan() || s > MAX_SIGMA_FOCAL * v)
        {
            return fail(format!(
                "σ({name}) = {s:.2} px is {:.2} % of {name} (limit {} %)",
                100.0 * s / v,
                100.0 * MAX_SIGMA_FOCAL
            ));
        }
    }
    for (i, side, name) in [(2, k.width_px, "cx"), (3, k.height_px, "cy")] {
        if let Some(s) = cal.sigma.0[i]
            && (s.is_nan() || s > MAX_SIGMA_CENTRE * f64::from(side))
        {
            return fail(format!(
                "σ({name}) = {s:.2} px is {:.2} % of the image side (limit {} %)",
                100.0 * s / f64::from(side),
                100.0 * MAX_SIGMA_CENTRE
            ));
        }
    }
    let (radial, tangential) = distortion_sigma_px(cal);
    for (s, what) in [(radial, "radial"), (tangential, "tangential")] {
        if s.is_nan() || s > MAX_DISTORTION_SIGMA_PX {
            return fail(format!(
                "the {what} distortion at the farthest corner is uncertain by {s:.2} px (limit {MAX_DISTORTION_SIGMA_PX} px)"
            ));
        }
    }
    Ok(())
}

/// Largest angle between two views' board normals, degrees.
fn orientation_spread_deg(poses: &[BoardPose]) -> f64 {
    let mut worst: f64 = 0.0;
    for (i, a) in poses.iter().enumerate() {
        for b in &poses[i + 1..] {
            let c: f64 = (0..3).map(|r| a.rot[r][2] * b.rot[r][2]).sum();
            worst = worst.max(c.clamp(-1.0, 1.0).acos().to_degrees());
        }
    }
    worst
}

/// The pose of `board` seen by a calibrated camera, from its detected
/// `corners` (in [`Board::object_points`] order, px), and the RMS
/// reprojection error of the fit, px: the homography of the undistorted,
/// normalised corners gives the pose, Levenberg–Marquardt on the pixel
/// reprojection error refines it.
pub fn board_pose(intr: &Intrinsics, board: &Board, corners: &[[f64; 2]]) -> Result<(BoardPose, f64), CalibError> {
    let obj = board.object_points();
    if corners.len() != obj.len() {
        return Err(CalibError::CornerCount { view: 0, got: corners.len(), expected: obj.len() });
    }
    if !(intr.fx_px > 0.0 && intr.fy_px > 0.0 && corners.iter().all(|p| p[0].is_finite() && p[1].is_finite())) {
        return Err(CalibError::Degenerate("bad intrinsics or corners"));
    }
    let plane: Vec<[f64; 2]> = obj.iter().map(|p| [p[0], p[1]]).collect();
    let norm: Vec<[f64; 2]> = corners
        .iter()
        .map(|p| {
            let r = intr.unproject(p[0], p[1]);
            [r[0], r[1]]
        })
        .collect();
    let hm = homography(&plane, &norm)?;
    let (r, t) = pose_from_homography(&Matrix3::identity(), &hm)?;
    let x0: Vec<f64> = r.into_iter().chain(t).collect();
    let n_res = 2 * obj.len();
    let residuals = |x: &[f64], out: &mut [f64]| view_residuals(intr, x, &obj, corners, out);
    let x = lm::levenberg_marquardt(x0, &[0, 1, 2, 3, 4, 5], 100, &mut lm::CentralDifferences::new(n_res, residuals))
        .ok_or(CalibError::Degenerate("the pose fit diverged"))?
        .p;
    let mut res = vec![0.0; n_res];
    residuals(&x, &mut res);
    let rms = rms_of(&res);
    if !rms.is_finite() || !x.iter().all(|v| v.is_finite()) {
        return Err(CalibError::Degenerate("the pose fit diverged"));
    }
    Ok((pose_from([x[0], x[1], x[2]], [x[3], x[4], x[5]]), rms))
}

/// The board's corners in a set of photographs, as camera calibration
/// takes them: every image of one size, the views where the whole board
/// was found, and their files' names.
#[derive(Debug, Clone)]
pub struct BoardViews {
    /// Each view's corners, px, in [`Board::object_points`] order.
    pub views: Vec<Vec<[f64; 2]>>,
    /// Each view's file, as given.
    pub names: Vec<String>,
    /// The images' size, px.
    pub size: (u32, u32),
}

/// Why a set of photographs gives no views to calibrate with.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ViewsError {
    /// An image could not be read.
    #[error("{0}")]
    Read(String),
    /// Images of different sizes: not one camera mode.
    #[error("{}: {} x {}, but {} is {} x {}; all images must come from one camera mode", path.display(), size.0, size.1, first.display(), first_size.0, first_size.1)]
    Size {
        /// The image of another size.
        path: PathBuf,
        /// Its size.
        size: (u32, u32),
        /// The first image.
        first: PathBuf,
        /// The first image's size.
        first_size: (u32, u32),
    },
    /// The corner search failed on an image (not merely a board not found).
    #[error("{}: {source}", path.display())]
    Corners {
        /// The image.
        path: PathBuf,
        /// Why.
        source: CornerError,
    },
    /// No images.
    #[error("no images")]
    NoImages,
    /// Fewer than three views.
    #[error("the board ({}x{}) was found in {found} of {images} images; calibration needs at least 3", board.0, board.1)]
    TooFew {
        /// The board's inner corners.
        board: (usize, usize),
        /// Views found.
        found: usize,
        /// Images given.
        images: usize,
    },
}

/// Finds `board` in each image of `paths` (read one at a time by `load` as
/// grayscale `0..1`); an image where the board is incomplete or
/// inconsistent is passed to `rejected` and left out.
pub fn board_views<E: std::fmt::Display>(
    paths: &[PathBuf],
    board: &Board,
    mut load: impl FnMut(&Path) -> Result<(Vec<f32>, u32, u32), E>,
    mut rejected: impl FnMut(&Path, &CornerError),
) -> Result<BoardViews, ViewsError> {
    let (mut views, mut names) = (Vec::new(), Vec::new());
    let mut size: Option<(u32, u32, &Path)> = None;
    for path in paths {
        let (px, w, h) = load(path).map_err(|e| ViewsError::Read(e.to_string()))?;
        match size {
            None => size = Some((w, h, path)),
            Some((w0, h0, first)) if (w0, h0) != (w, h) => {
                return Err(ViewsError::Size {
                    path: path.clone(),
                    size: (w, h),
                    first: first.to_path_buf(),
                    first_size: (w0, h0),
                });
            }
            Some(_) => {}
        }
        match find_corners(&px, w as usize, h as usize, board) {
            Ok(c) => {
                views.push(c);
                names.push(path.display().to_string());
            }
            Err(e @ (CornerError::Incomplete { .. } | CornerError::Inconsistent)) => rejected(path, &e),
            Err(source) => return Err(ViewsError::Corners { path: path.clone(), source }),
        }
    }
    let Some((w, h, _)) = size else { return Err(ViewsError::NoImages) };
    if views.len() < 3 {
        return Err(ViewsError::TooFew { board: (board.cols, board.rows), found: views.len(), images: paths.len() });
    }
    Ok(BoardViews { views, names, size: (w, h) })
}
