//! The simulated sensor head: a physical model that renders the camera rows
//! of the laser-triangulation corrugation measurement system (paper §2–4).
//! Pure and deterministic: no I/O, no clock, every random number seeded.
//!
//! # The model
//!
//! * A **camera** ([`Camera`]): pinhole with skew and Brown–Conrady distortion
//!   ([`crate::model::camera::Intrinsics`], OpenCV's convention), bit depth, exposure, full well.
//! * A **head** ([`HeadGeometry`]): the camera looks down at the rail head
//!   with image rows across the rail, so each row sees one position along
//!   the rail; the [`Laser`]s' planes contain the rail direction, make the
//!   angle α with the optical axis and put their lines a few mm apart across
//!   the running band. Their lines therefore appear as near-vertical
//!   stripes, one per laser, and a rail-top point that rises by Δz moves its
//!   stripe sideways by about `f_x·Δz·tan α / standoff` columns.
//! * A **rail** ([`RailModel`]): longitudinal profile (corrugation
//!   sinusoids + band-limited random roughness) and a transverse crown.
//! * **Motion**: the head runs along the rail at `speed_mm_s`; frame `n` is
//!   taken at odometer `odometer_start_mm + speed_mm_s·n/frame_rate_hz` (a
//!   global shutter: one odometer value per frame).
//! * **Rendering a row** ([`Scene::render_row`]): for each laser, the point of
//!   its plane on the rail surface that projects (with distortion) onto the
//!   row is solved for (Newton on the crown, secant along the rail, to 1e-9
//!   px): its column is the stripe's true centre. The stripe is a Gaussian
//!   across the row (paper §3, Fig. 4) of σ = `f_x·d·sin α / depth` px (paper
//!   Eq. 10–11 at the point's depth) and peak `signal_e_per_mw_us · power ·
//!   brightness · exposure · reflectance` electrons (scaled by σ₀/σ, the
//!   light of a narrower stripe being more concentrated), integrated over
//!   each pixel's width if `pixel_integration`. Then ambient light, hot
//!   pixels, banding, read and shot noise, saturation and quantisation (see
//!   [`noise`]).
//!
//! Every row also yields its ground truth ([`StripeTruth`]): the stripe's
//! sub-pixel column, its σ and peak, and the surface point (track position,
//! lateral position, height) it images.
//!
//! # Frames, shots and units
//!
//! [`Scene::render_frame`] / [`Scene::render_row`] take a frame index and
//! use the configured speed, frame rate and exposure. A server that paces
//! frames by its own clock and takes exposure commands renders a [`Shot`]
//! instead (odometer, exposure, laser mask, and the frame index that seeds
//! the noise): [`Scene::shot_at`], [`Scene::render_shot`],
//! [`Scene::render_shot_row`]. A row's pixels depend only on the scene, the
//! shot and the row index, so rows can be pulled one at a time, in any
//! order, with no allocation.
//!
//! Lengths are in mm (`_mm`), heights in µm (`_um`), image quantities in
//! pixels (`_px`), light and noise in electrons (`_e`, `_e_per_us`:
//! sensor-referred, so a scene looks the same at 8, 10 or 12 bits); one code
//! is [`Camera::gain_e_per_dn`] electrons (full well / (2^bits − 1)).
//!
//! # Presets
//!
//! | | `reference` (default) | `paper` (Table 4) |
//! |---|---|---|
//! | sensor | 752 × 480, 6 µm, global shutter, 8 bit | 4752 × 3168, 4.69 µm, 8 bit |
//! | focal length | 8.4 mm: fx = fy = 1400 px | 24 mm: fx = 5106, fy = 5107 px |
//! | distortion | k1 = −0.09, k2 = 0.12, p1 = 2e-4, p2 = −1.5e-4 | none |
//! | standoff, range | 200 mm, 170–230 mm | 450 mm, 350–550 mm |
//! | α, line thickness | 35°, 0.75 mm | 42°, 2 mm |
//! | stripe σ (Eq. 10–11) | 3.0 px (2.6–3.5 over the range) | 15.2 px (12.4–19.5) |
//! | rail per row | 0.143 mm (68.6 mm per frame) | 0.088 mm (279 mm per frame) |
//! | triangulation | 4.9 px per mm of height | 10.2 px per mm |
//! | lasers | 3 × 50 mW, lines 10 mm (70 px) apart, brightness 1 / 0.8 / 0.65 | 3 × 50 mW, 15 mm (170 px) apart, 1 / 0.85 / 0.7 |
//! | stripe peaks | 166 / 133 / 108 codes + 13 ambient | 151 / 128 / 106 codes + 9 ambient |
//! | exposure, motion | 100 µs, 2 m/s at 60 Hz | 250 µs, 0.5 m/s at 3.4 Hz |
//!
//! # Use
//!
//! ```
//! use cms_host::sim::scene::{Scene, SimConfig};
//! let mut scene = Scene::new(SimConfig::default()).unwrap();
//! let mut row = vec![0u16; scene.width()];
//! let truth = scene.render_row(0, 240, scene.all_lasers_mask(), &mut row);
//! let centre = truth.stripes[1].unwrap().column_px;
//! assert!(row[centre.round() as usize] > 100);
//! ```

pub mod camera;
pub mod geom;
pub mod light;
pub mod noise;
pub mod rail;
pub mod roughness_spectrum;

mod config;
#[cfg(test)]
mod repeat_tests;
mod stripe;
#[cfg(test)]
mod tests;

use std::fmt;

use crate::model::vec3::{self, Vec3};
pub use camera::Camera;
pub use geom::{HeadGeometry, Pose, ScenePlane};
pub use light::{Ghost, Glints, LightModel, Patches, RunningBand, Speckle};
pub use noise::NoiseModel;
pub use rail::{Corrugation, RailModel};
pub use roughness_spectrum::{RoughnessSpectrum, RoughnessSpectrumError};

use light::{LightCache, TileShot};
use noise::{Rng, SensorPattern};
use rail::RailSurface;

pub(crate) use config::check;
pub use config::{Laser, Preset, SimConfig, SimError};
use stripe::add_stripe;

/// Most lasers a head can have (one bit each of the laser mask).
pub const MAX_LASERS: usize = 8;

/// Stream of the per-frame noise in the seeded generator.
const NOISE_STREAM: u64 = 0x4e4f_4953;

/// The truth about one stripe in one row.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StripeTruth {
    /// Sub-pixel column of the stripe's centre (pixel centres at integers).
    pub column_px: f64,
    /// Gaussian σ of the stripe across the row, px (before pixel integration).
    pub sigma_px: f64,
    /// Noise-free peak above the background, codes (may exceed the largest code: saturated).
    pub peak_dn: f64,
    /// Track position of the imaged surface point (odometer coordinate), mm.
    pub x_mm: f64,
    /// Its lateral position from the rail centreline, mm.
    pub y_mm: f64,
    /// Its height above the nominal rail top (profile + crown), µm.
    pub height_um: f64,
    /// The longitudinal profile `h(x)` there (corrugation + roughness), µm.
    pub profile_um: f64,
    /// Its depth in the camera frame, mm.
    pub depth_mm: f64,
}

/// The truth of one row: per laser, the stripe (`None` if the laser is off
/// or its stripe is not in the row).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct RowTruth {
    /// Indexed by laser.
    pub stripes: [Option<StripeTruth>; MAX_LASERS],
}

/// One exposure: where the head is, how long the shutter is open, which
/// lasers are lit. The frame index seeds the exposure's random noise.
///
/// [`Scene::shot`] gives the nominal one of a frame (configured speed, frame
/// rate and exposure); a real-time server that paces frames by its own clock
/// and exposure commands builds it with [`Scene::shot_at`] or by hand.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shot {
    /// Frame index (seeds the frame's noise).
    pub frame_index: u64,
    /// Odometer at the exposure, mm.
    pub odometer_mm: f64,
    /// Exposure time, µs (scales the stripes, ambient light and dark signal).
    pub exposure_us: f64,
    /// Bit `k` lights laser `k`.
    pub laser_mask: u8,
}

/// The truth of one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameTruth {
    /// The frame's index.
    pub frame_index: u64,
    /// Odometer at the exposure, mm.
    pub odometer_mm: f64,
    /// Exposure time, µs.
    pub exposure_us: f64,
    /// The lasers that were on.
    pub laser_mask: u8,
    /// `stripes[laser][row]`: the stripe, `None` if the laser is off or its
    /// stripe is not in that row.
    pub stripes: Vec<Vec<Option<StripeTruth>>>,
}

impl FrameTruth {
    /// The true column of a laser's stripe in a row.
    pub fn column_px(&self, laser: usize, row: usize) -> Option<f64> {
        self.stripes.get(laser)?.get(row).copied().flatten().map(|s| s.column_px)
    }
}

/// A validated simulation: the rail, the head and the sensor's fixed pattern,
/// ready to render frames.
#[derive(Clone)]
pub struct Scene {
    cfg: SimConfig,
    surface: RailSurface,
    pose: Pose,
    planes_cam: Vec<ScenePlane>,
    planes_rail: Vec<ScenePlane>,
    /// Initial guess of the along-rail coordinate of a laser's point on a
    /// row: `s ≈ a + b·row`.
    guess: Vec<(f64, f64)>,
    sensor: SensorPattern,
    gain_e_per_dn: f64,
    sigma0_px: f64,
    sin_alpha: f64,
    row_buf: Vec<f64>,
    /// The light model's stripes of the last shot rendered.
    light_cache: LightCache,
}

impl fmt::Debug for Scene {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Scene")
            .field("cfg", &self.cfg)
            .field("pose", &self.pose)
            .field("planes_cam", &self.planes_cam)
            .finish_non_exhaustive()
    }
}

impl Scene {
    /// Validates `cfg` and builds the scene (roughness table, sensor pattern,
    /// laser planes). Fails if a field is out of range or a laser's line does
    /// not land on the rail inside the image.
    pub fn new(cfg: SimConfig) -> Result<Scene, SimError> {
        cfg.validate()?;
        let surface = RailSurface::new(&cfg.rail, cfg.seed)?;
        let pose = cfg.head.camera_pose();
        let planes_cam: Vec<ScenePlane> = cfg.lasers.iter().map(|l| cfg.head.laser_plane_cam(l.offset_mm)).collect();
        let planes_rail: Vec<ScenePlane> = planes_cam.iter().map(|p| pose.plane_to_rail(p)).collect();
        let cam = &cfg.camera;
        let sensor = SensorPattern::new(&cfg.noise, cam.width_px(), cam.height_px(), cfg.seed);
        let mut scene = Scene {
            gain_e_per_dn: cam.gain_e_per_dn(),
            sigma0_px: cfg.nominal_sigma_px(),
            sin_alpha: cfg.head.alpha_deg.to_radians().sin(),
            row_buf: vec![0.0; cam.width_px()],
            light_cache: LightCache::default(),
            cfg,
            surface,
            pose,
            planes_cam,
            planes_rail,
            guess: Vec::new(),
            sensor,
        };
        for k in 0..scene.planes_rail.len() {
            // The row as a function of the along-rail coordinate on the
            // nominal rail (profile 0), linearised over ±5 mm.
            let v = |s: f64| scene.eval(k, s, 0.0).map(|e| e.uv[1]);
            let (Some(v0), Some(v1)) = (v(-5.0), v(5.0)) else {
                return Err(SimError::LaserOutOfView { laser: k });
            };
            let dv = (v1 - v0).abs();
            if dv.is_nan() || dv <= 1e-9 {
                return Err(SimError::LaserOutOfView { laser: k });
            }
            let b = 10.0 / (v1 - v0);
            scene.guess.push((-5.0 - b * v0, b));
        }
        let mid = (scene.cfg.camera.height_px() as f64 - 1.0) / 2.0;
        for k in 0..scene.planes_rail.len() {
            if scene.solve(k, None, mid, 1.0).is_none() {
                return Err(SimError::LaserOutOfView { laser: k });
            }
        }
        Ok(scene)
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// The camera.
    pub fn camera(&self) -> &Camera {
        &self.cfg.camera
    }

    /// Image width, px.
    pub fn width(&self) -> usize {
        self.cfg.camera.width_px()
    }

    /// Image height, px.
    pub fn height(&self) -> usize {
        self.cfg.camera.height_px()
    }

    /// Bit depth.
    pub fn bits(&self) -> u8 {
        self.cfg.camera.bits
    }

    /// Number of lasers.
    pub fn laser_count(&self) -> usize {
        self.cfg.lasers.len()
    }

    /// The mask with every laser on.
    pub fn all_lasers_mask(&self) -> u8 {
        self.cfg.all_lasers_mask()
    }

    /// The laser planes in the camera frame (what a calibration would find).
    pub fn laser_planes(&self) -> &[ScenePlane] {
        &self.planes_cam
    }

    /// The camera's pose in the rail frame.
    pub fn camera_pose(&self) -> Pose {
        self.pose
    }

    /// Odometer of a frame, mm.
    pub fn odometer_mm(&self, frame_index: u64) -> f64 {
        self.cfg.odometer_mm(frame_index)
    }

    /// The rail's longitudinal profile `h(x)` at a track position, µm.
    pub fn profile_um(&self, x_mm: f64) -> f64 {
        self.surface.profile_mm(x_mm) * 1e3
    }

    /// Hot pixels of the sensor as (row, column), row-major order.
    pub fn hot_pixels(&self) -> Vec<(usize, usize)> {
        (0..self.height()).flat_map(|r| self.sensor.hot_in_row(r).iter().map(move |&(c, _)| (r, c as usize))).collect()
    }

    /// The nominal shot of a frame: odometer from the configured speed and
    /// frame rate, the camera's configured exposure.
    pub fn shot(&self, frame_index: u64, laser_mask: u8) -> Shot {
        Shot {
            frame_index,
            odometer_mm: self.odometer_mm(frame_index),
            exposure_us: self.cfg.camera.exposure_us,
            laser_mask,
        }
    }

    /// A shot taken `elapsed_us` after frame 0 (odometer
    /// `odometer_start_mm + speed_mm_s · elapsed`) with the given exposure.
    pub fn shot_at(&self, frame_index: u64, elapsed_us: f64, exposure_us: f64, laser_mask: u8) -> Shot {
        Shot {
            frame_index,
            odometer_mm: self.cfg.odometer_start_mm + self.cfg.speed_mm_s * elapsed_us * 1e-6,
            exposure_us,
            laser_mask,
        }
    }

    /// The stripe of laser `laser` in row `row` of frame `frame_index` (nominal
    /// shot), as if the laser were on (`None` if the line does not cross that
    /// row inside the image).
    pub fn stripe_truth(&self, frame_index: u64, row: usize, laser: usize) -> Option<StripeTruth> {
        if laser >= self.laser_count() || row >= self.height() {
            return None;
        }
        let shot = self.shot(frame_index, 1 << laser);
        self.solve(laser, Some(shot.odometer_mm), row as f64, shot.exposure_us)
    }

    /// The truth of a row of a shot.
    pub fn shot_row_truth(&self, shot: &Shot, row: usize) -> RowTruth {
        let mut t = RowTruth::default();
        if row >= self.height() {
            return t;
        }
        let exposure = sane_exposure(shot.exposure_us);
        for (k, s) in t.stripes.iter_mut().enumerate().take(self.laser_count()) {
            if shot.laser_mask & (1 << k) != 0 {
                *s = self.solve(k, Some(shot.odometer_mm), row as f64, exposure);
            }
        }
        t
    }

    /// The truth of a row of frame `frame_index` (nominal shot).
    pub fn row_truth(&self, frame_index: u64, row: usize, laser_mask: u8) -> RowTruth {
        self.shot_row_truth(&self.shot(frame_index, laser_mask), row)
    }

    /// The truth of a whole shot, without rendering it.
    pub fn shot_truth(&self, shot: &Shot) -> FrameTruth {
        let mut ft = self.empty_truth(shot);
        for r in 0..self.height() {
            let rt = self.shot_row_truth(shot, r);
            for (k, s) in ft.stripes.iter_mut().enumerate() {
                s[r] = rt.stripes[k];
            }
        }
        ft
    }

    /// The truth of a whole frame (nominal shot), without rendering it.
    pub fn frame_truth(&self, frame_index: u64, laser_mask: u8) -> FrameTruth {
        self.shot_truth(&self.shot(frame_index, laser_mask))
    }

    fn empty_truth(&self, shot: &Shot) -> FrameTruth {
        FrameTruth {
            frame_index: shot.frame_index,
            odometer_mm: shot.odometer_mm,
            exposure_us: sane_exposure(shot.exposure_us),
            laser_mask: shot.laser_mask,
            stripes: vec![vec![None; self.height()]; self.laser_count()],
        }
    }

    /// Renders frame `frame_index` (nominal shot) with the lasers of
    /// `laser_mask` on into `out` (height × width codes, row-major) and
    /// returns its truth.
    ///
    /// # Panics
    /// If `out.len()` is not width × height.
    pub fn render_frame(&mut self, frame_index: u64, laser_mask: u8, out: &mut [u16]) -> FrameTruth {
        let shot = self.shot(frame_index, laser_mask);
        self.render_shot(&shot, out)
    }

    /// Renders a shot into `out` (height × width codes, row-major) and
    /// returns its truth.
    ///
    /// # Panics
    /// If `out.len()` is not width × height.
    pub fn render_shot(&mut self, shot: &Shot, out: &mut [u16]) -> FrameTruth {
        let w = self.width();
        assert_eq!(out.len(), w * self.height(), "render_shot: output must hold width × height pixels");
        let mut ft = self.empty_truth(shot);
        for (r, row) in out.chunks_exact_mut(w).enumerate() {
            let rt = self.render_shot_row(shot, r, row);
            for (k, s) in ft.stripes.iter_mut().enumerate() {
                s[r] = rt.stripes[k];
            }
        }
        ft
    }

    /// Renders row `row` of frame `frame_index` (nominal shot) into `out`
    /// (width codes) and returns its truth. Equal to that row of
    /// [`Scene::render_frame`], whatever the order rows are rendered in;
    /// allocates nothing.
    ///
    /// # Panics
    /// If `row` ≥ height or `out.len()` is not the width.
    pub fn render_row(&mut self, frame_index: u64, row: usize, laser_mask: u8, out: &mut [u16]) -> RowTruth {
        let shot = self.shot(frame_index, laser_mask);
        self.render_shot_row(&shot, row, out)
    }

    /// Renders row `row` of a shot into `out` (width codes) and returns its
    /// truth; allocates nothing. The pixels depend only on the scene, the
    /// shot and the row.
    ///
    /// # Panics
    /// If `row` ≥ height or `out.len()` is not the width.
    pub fn render_shot_row(&mut self, shot: &Shot, row: usize, out: &mut [u16]) -> RowTruth {
        assert!(row < self.height(), "render_row: row {row} is outside the image");
        assert_eq!(out.len(), self.width(), "render_row: output must hold one row");
        let truth = self.shot_row_truth(shot, row);
        if !self.cfg.light.is_clean() {
            self.light_tiles(shot);
        }
        let mut buf = std::mem::take(&mut self.row_buf);
        self.photo_signal(shot, row, &truth, &mut buf);
        self.read_out(shot.frame_index, row, &buf, out);
        self.row_buf = buf;
        truth
    }

    /// CPU time the light model's threads have spent rendering (each
    /// laser's speckled stripe renders on a thread of its own): beside the
    /// calling thread's, which it does not include.
    pub fn light_threads_cpu(&self) -> std::time::Duration {
        self.light_cache.threads_cpu()
    }

    /// The light model's last grid per laser: samples across the line,
    /// along it, and sub-exposures (what a speckled stripe costs).
    pub fn light_grids(&self) -> Vec<(usize, usize, usize)> {
        self.light_cache.grids()
    }

    /// Triangulates pixel `(u, v)` of laser `laser`'s stripe: the
    /// camera-frame point where its ray meets the laser plane, mm (`None` if
    /// parallel or behind the camera). `Scene::camera_pose` maps it onto the rail.
    pub fn triangulate(&self, laser: usize, u: f64, v: f64) -> Option<Vec3> {
        let p = self.planes_cam.get(laser)?;
        let ray = self.cfg.camera.intrinsics.unproject(u, v);
        let den = vec3::dot(p.normal, ray);
        if den.abs() < 1e-12 {
            return None;
        }
        let t = p.d_mm / den;
        (t > 0.0).then(|| vec3::scale(ray, t))
    }

    /// The surface point of laser `k` at along-rail coordinate `s` (mm from
    /// the aim point) with longitudinal profile `h_mm` there, rail frame.
    fn point_on_laser(&self, k: usize, s: f64, h_mm: f64) -> Option<Vec3> {
        let ScenePlane { normal: n, d_mm } = self.planes_rail[k];
        if n[1].abs() < 1e-6 {
            return None;
        }
        // n0·s + n1·y + n2·(h + crown(y)) = d
        let q = d_mm - n[0] * s - n[2] * h_mm;
        let mut y = q / n[1];
        let mut crown = 0.0;
        if self.surface.crown_radius_mm().is_some() {
            let mut converged = false;
            for _ in 0..50 {
                let (c, dc) = self.surface.crown_mm(y)?;
                let f = n[1] * y + n[2] * c - q;
                let fp = n[1] + n[2] * dc;
                if fp.abs() < 1e-9 {
                    return None;
                }
                let dy = f / fp;
                y -= dy;
                if dy.abs() < 1e-12 {
                    converged = true;
                    break;
                }
            }
            if !converged {
                return None;
            }
            crown = self.surface.crown_mm(y)?.0;
        }
        Some([s, y, h_mm + crown])
    }

    /// Laser `k`'s point at along-rail coordinate `s`, projected. `odo` is
    /// the odometer (`None`: nominal rail, profile 0).
    fn eval_at(&self, k: usize, s: f64, odo: Option<f64>) -> Option<Eval> {
        let h = match odo {
            Some(o) => self.surface.profile_mm(o + s),
            None => 0.0,
        };
        self.eval(k, s, h)
    }

    fn eval(&self, k: usize, s: f64, h_mm: f64) -> Option<Eval> {
        let p = self.point_on_laser(k, s, h_mm)?;
        let pc = self.pose.rail_to_cam(p);
        let uv = self.cfg.camera.intrinsics.project(pc)?;
        Some(Eval { p, pc, uv, h_mm })
    }

    /// Solves for the point of laser `k` that images onto row `row`.
    fn solve(&self, k: usize, odo: Option<f64>, row: f64, exposure_us: f64) -> Option<StripeTruth> {
        let (a, b) = self.guess[k];
        let mut sa = a + b * row;
        let mut ea = self.eval_at(k, sa, odo)?;
        let mut sb = sa + 0.5 * b;
        let mut eb = self.eval_at(k, sb, odo)?;
        for _ in 0..60 {
            let (fa, fb) = (ea.uv[1] - row, eb.uv[1] - row);
            if fb.abs() < 1e-9 {
                break;
            }
            if fb == fa {
                return None;
            }
            let sn = sb - fb * (sb - sa) / (fb - fa);
            if !sn.is_finite() {
                return None;
            }
            (sa, ea) = (sb, eb);
            sb = sn;
            eb = self.eval_at(k, sb, odo)?;
        }
        if (eb.uv[1] - row).abs() > 1e-6 {
            return None;
        }
        let u = eb.uv[0];
        if !(u >= 0.0 && u <= (self.width() - 1) as f64) {
            return None;
        }
        let cam = &self.cfg.camera;
        let sigma_px = cam.intrinsics.fx_px * self.cfg.head.laser_diameter_mm * self.sin_alpha / eb.pc[2];
        let l = &self.cfg.lasers[k];
        let peak_e = self.cfg.signal_e_per_mw_us
            * l.power_mw
            * l.brightness
            * exposure_us
            * self.cfg.rail.reflectance
            * (self.sigma0_px / sigma_px);
        Some(StripeTruth {
            column_px: u,
            sigma_px,
            peak_dn: peak_e / self.gain_e_per_dn,
            x_mm: odo.unwrap_or(0.0) + eb.p[0],
            y_mm: eb.p[1],
            height_um: eb.p[2] * 1e3,
            profile_um: eb.h_mm * 1e3,
            depth_mm: eb.pc[2],
        })
    }

    /// Photo-signal of a row in electrons: ambient light, hot pixels' dark
    /// signal, stripes.
    fn photo_signal(&self, shot: &Shot, row: usize, truth: &RowTruth, buf: &mut [f64]) {
        let exposure_us = sane_exposure(shot.exposure_us);
        let cam = &self.cfg.camera;
        let nm = &self.cfg.noise;
        let a0 = nm.ambient_e_per_us * exposure_us;
        let base = a0 * (1.0 + nm.ambient_gradient_per_px[1] * (row as f64 - cam.intrinsics.cy_px));
        let slope = a0 * nm.ambient_gradient_per_px[0];
        for (i, b) in buf.iter_mut().enumerate() {
            *b = (base + slope * (i as f64 - cam.intrinsics.cx_px)).max(0.0);
        }
        for &(c, e) in self.sensor.hot_in_row(row) {
            buf[c as usize] += e * exposure_us;
        }
        let light = &self.cfg.light;
        if light.is_clean() {
            for s in truth.stripes.iter().flatten() {
                add_stripe(buf, s.column_px, s.sigma_px, s.peak_dn * self.gain_e_per_dn, self.cfg.pixel_integration);
            }
        } else if let Some(tiles) = self.light_cache.tiles_for(self.light_key(shot)) {
            for tile in tiles.iter().flatten() {
                tile.add_row(row, buf);
            }
        }
        if light.glints.per_m > 0.0 {
            for (k, s) in truth.stripes.iter().enumerate() {
                let Some(s) = s else { continue };
                let at = light::surface::GlintRow {
                    laser: k,
                    column_px: s.column_px,
                    sigma_px: s.sigma_px,
                    peak_e: s.peak_dn * self.gain_e_per_dn,
                    x0_mm: s.x_mm,
                    mm_per_row: self.guess[k].1,
                    travel_mm: self.cfg.speed_mm_s * exposure_us * 1e-6,
                };
                light::surface::add_glints(&light.glints, self.cfg.seed, &at, buf);
            }
        }
    }

    fn light_key(&self, shot: &Shot) -> (u64, u64, u64, u8) {
        LightCache::key(shot.frame_index, shot.odometer_mm, sane_exposure(shot.exposure_us), shot.laser_mask)
    }

    /// Makes the light model's stripes of a shot, once per shot: every
    /// row's line of every lit laser, imaged as a whole (speckle couples
    /// neighbouring rows).
    fn light_tiles(&mut self, shot: &Shot) {
        let key = self.light_key(shot);
        if self.light_cache.tiles_for(key).is_some() {
            return;
        }
        let exposure = sane_exposure(shot.exposure_us);
        let cam = &self.cfg.camera;
        let lines: Vec<Option<Vec<Option<StripeTruth>>>> = (0..self.laser_count())
            .map(|k| {
                (shot.laser_mask & (1 << k) != 0).then(|| {
                    (0..self.height()).map(|r| self.solve(k, Some(shot.odometer_mm), r as f64, exposure)).collect()
                })
            })
            .collect();
        let width_px = self.width();
        let focus: Vec<f64> =
            lines.iter().enumerate().map(|(k, l)| l.as_deref().map_or(0.0, |l| self.focus_mm(k, l))).collect();
        let shots: Vec<Option<TileShot>> = lines
            .iter()
            .enumerate()
            .map(|(k, lines)| {
                lines.as_ref().map(|lines| TileShot {
                    light: &self.cfg.light,
                    seed: self.cfg.seed,
                    laser: k,
                    wavelength_um: self.cfg.lasers[k].wavelength_nm * 1e-3,
                    pixel_pitch_um: cam.pixel_pitch_um,
                    fx_px: cam.intrinsics.fx_px,
                    focus_mm: focus[k],
                    lateral_px: self.cfg.head.lateral_offset_mm * cam.intrinsics.fx_px / self.cfg.head.standoff_mm,
                    lines,
                    gain_e_per_dn: self.gain_e_per_dn,
                    odometer_mm: shot.odometer_mm,
                    travel_mm: self.cfg.speed_mm_s * exposure * 1e-6,
                    row_mm: self.guess[k],
                    width_px,
                })
            })
            .collect();
        self.light_cache.render_shot(key, &shots);
    }

    /// Where the lens is focused for laser `laser`'s line, mm along the
    /// axis: the light's `focus_mm` (the standoff if not set), or under a
    /// Scheimpflug sensor the plane of focus — the plane of the laser
    /// nearest the aim point, or the line's own with a sensor per line —
    /// where the line's rays meet it (their mean over the lit rows).
    fn focus_mm(&self, laser: usize, lines: &[Option<StripeTruth>]) -> f64 {
        let across = self.cfg.light.focus_mm.unwrap_or(self.cfg.head.standoff_mm);
        let nearest = (0..self.cfg.lasers.len())
            .min_by(|&a, &b| self.cfg.lasers[a].offset_mm.abs().total_cmp(&self.cfg.lasers[b].offset_mm.abs()));
        let plane_of = if self.cfg.light.sensor_per_line { Some(laser) } else { nearest };
        let (true, Some(k)) = (self.cfg.light.scheimpflug, plane_of) else { return across };
        let plane = &self.planes_cam[k];
        let (mut sum, mut n) = (0.0, 0.0);
        for (r, l) in lines.iter().enumerate() {
            let Some(l) = l else { continue };
            let ray = self.cfg.camera.intrinsics.unproject(l.column_px, r as f64);
            let along = vec3::dot(plane.normal, ray);
            if along.abs() > 1e-9 {
                // The ray's point t·(x, y, 1) on the plane has depth t.
                sum += plane.d_mm / along;
                n += 1.0;
            }
        }
        if n > 0.0 { sum / n } else { across }
    }

    /// Noise, banding, saturation and quantisation of a row.
    fn read_out(&self, frame_index: u64, row: usize, buf: &[f64], out: &mut [u16]) {
        let nm = &self.cfg.noise;
        let inv_gain = 1.0 / self.gain_e_per_dn;
        let max = self.cfg.camera.max_dn() as f64;
        let col = &self.sensor.column_offset_e;
        let quantise = |e: f64| (e * inv_gain + 0.5).clamp(0.0, max) as u16;
        if !nm.is_random() {
            for ((o, &s), &c) in out.iter_mut().zip(buf).zip(col) {
                *o = quantise(s + c);
            }
            return;
        }
        // Run 0's stream is the seed's own; another run reads other noise.
        let stream = NOISE_STREAM ^ self.cfg.run.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let mut rng = Rng::for_stream(self.cfg.seed, stream, frame_index, row as u64);
        let row_offset = if nm.row_banding_e > 0.0 { nm.row_banding_e * rng.normal() } else { 0.0 };
        let read2 = nm.read_noise_e * nm.read_noise_e;
        let shot = if nm.shot_noise { 1.0 } else { 0.0 };
        let zig = noise::ziggurat();
        for ((o, &s), &c) in out.iter_mut().zip(buf).zip(col) {
            let sd = (read2 + shot * s).sqrt();
            *o = quantise(s + sd * rng.normal_with(zig) + row_offset + c);
        }
    }
}

/// A shot's exposure, finite and ≥ 0 (anything else renders dark).
fn sane_exposure(us: f64) -> f64 {
    if us.is_finite() { us.max(0.0) } else { 0.0 }
}

/// A laser point evaluated at one along-rail coordinate.
#[derive(Clone, Copy, Debug)]
struct Eval {
    /// Rail frame, mm.
    p: Vec3,
    /// Camera frame, mm.
    pc: Vec3,
    /// Pixel.
    uv: [f64; 2],
    /// Longitudinal profile there, mm.
    h_mm: f64,
}
