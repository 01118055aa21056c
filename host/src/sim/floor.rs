//! The instrument's noise floor, closed loop: the simulated head driven
//! over a rail of known profile under a chosen light, every frame
//! rendered, detected and triangulated as the head does, stitched and
//! judged as `analyze` judges a recording — so that the floor the
//! analysis reports ([`crate::analyze::floor`]) can be held against what
//! a smooth rail really reads, and the head's optics and timing chosen
//! from it (`cms-host bench floor`).
//!
//! Frames are rendered off line, not at the head's frame rate: the step
//! between frames is a setting of its own, and the speed sets only the
//! travel during the exposure (the motion that averages speckle). The
//! speckle is tied to the rail, so frames that overlap see the same
//! pattern where they overlap: the step changes how often a point is
//! seen, not its speckle.
//!
//! Cost: a frame of 480 rows under speckle at F/4 renders in about
//! 150 ms; a 3 m rail at a frame every 30 mm is 100 frames.

use crate::analyze::stitch::{self, FramePoints, Stitcher};
use crate::analyze::{self, Analysis};
use crate::measure::Measurer;
use crate::sim::calibration::truth::truth;
use crate::sim::closed_loop::{ClosedLoopError, detector, frame_profiles};
use crate::sim::scene::{Corrugation, LightModel, NoiseModel, RailModel, Scene, SimConfig, Speckle};

/// One setting of the head and one rail.
#[derive(Debug, Clone, PartialEq)]
pub struct Setting {
    /// The lens's F-number (`None`: incoherent light, no speckle).
    pub f_number: Option<f64>,
    /// The line source's independent speckle patterns ([`Speckle::patterns`]).
    pub patterns: u32,
    /// A Scheimpflug sensor ([`LightModel::scheimpflug`]).
    pub scheimpflug: bool,
    /// A Scheimpflug sensor per line ([`LightModel::sensor_per_line`]).
    pub sensor_per_line: bool,
    /// Many patterns rendered as speckle fields, not fast
    /// ([`LightModel::exact_speckle`]).
    pub exact_speckle: bool,
    /// Exposure, µs.
    pub exposure_us: f64,
    /// Travel speed, mm/s (the motion during the exposure).
    pub speed_mm_s: f64,
    /// Travel between frames, mm (a frame sees about 69 mm).
    pub step_mm: f64,
    /// Every `row_step`-th image row (1, 2, 4: the head's row skip).
    pub row_step: usize,
    /// The lasers' wavelength, nm (the reference head's is 685).
    pub wavelength_nm: f64,
    /// Length of rail driven over, mm.
    pub length_mm: f64,
    /// The rail's corrugation (none: a smooth rail).
    pub corrugation: Vec<Corrugation>,
    /// Seed of the sensor noise and the surface.
    pub seed: u64,
    /// The sensor: what sets its own floor under the line.
    pub sensor: Sensor,
}

/// What sets the sensor's own floor: the light it gets, its noise, and
/// how many rows see a millimetre of rail.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sensor {
    /// Each laser's optical power, mW (the reference head's 50; the
    /// stripe's peak scales with it, up to the sensor's full well).
    pub power_mw: f64,
    /// Read noise σ, electrons (the reference sensor's 25).
    pub read_noise_e: f64,
    /// The lens's focal length, px (the reference 8.4 mm lens on 6 µm
    /// pixels: 1400): a longer lens or finer pixels put more rows on a
    /// millimetre of rail and a shorter stretch of rail in a frame.
    pub focal_px: f64,
    /// The sensor's random noise and the ambient light (`false`: none,
    /// quantisation alone: what speckle does by itself).
    pub noise: bool,
}

impl Sensor {
    /// The reference head's sensor and lasers.
    pub fn reference() -> Sensor {
        Sensor {
            power_mw: 50.0,
            read_noise_e: crate::sim::scene::NoiseModel::default().read_noise_e,
            focal_px: crate::model::head::REFERENCE_FOCAL_PX,
            noise: true,
        }
    }

    /// `Ok` if every figure is one the simulated head can take.
    pub fn check(&self) -> Result<(), ClosedLoopError> {
        let ok = self.power_mw > 0.0
            && self.power_mw <= 1000.0
            && (0.0..=200.0).contains(&self.read_noise_e)
            && (700.0..=5600.0).contains(&self.focal_px);
        if ok {
            return Ok(());
        }
        Err(ClosedLoopError::Options(format!(
            "{} mW a laser, {} e⁻ read noise, a {} px lens: the power in (0, 1000] mW, the read noise in [0, 200] e⁻, the focal length in [700, 5600] px",
            self.power_mw, self.read_noise_e, self.focal_px
        )))
    }
}

impl Setting {
    /// The push-trolley setting `docs/light.md` recommends (F/2.8, 100 µs,
    /// walking pace 1.5 m/s) over `length_mm` of smooth rail, a frame
    /// every 30 mm.
    pub fn push_trolley(length_mm: f64) -> Setting {
        Setting {
            f_number: Some(crate::sim::scene::light::PUSH_TROLLEY_F_NUMBER),
            patterns: 1,
            scheimpflug: false,
            sensor_per_line: false,
            exact_speckle: false,
            exposure_us: 100.0,
            speed_mm_s: 1500.0,
            step_mm: 30.0,
            row_step: 1,
            wavelength_nm: 685.0,
            length_mm,
            corrugation: Vec::new(),
            seed: 11,
            sensor: Sensor::reference(),
        }
    }

    /// The simulated head's configuration for this setting.
    pub fn config(&self) -> SimConfig {
        let mut cfg = SimConfig::reference();
        cfg.rail = RailModel { corrugation: self.corrugation.clone(), roughness_rms_um: 0.0, ..RailModel::default() };
        cfg.light = LightModel {
            speckle: self.f_number.map(|f_number| Speckle { f_number, patterns: self.patterns }),
            scheimpflug: self.scheimpflug,
            sensor_per_line: self.sensor_per_line,
            exact_speckle: self.exact_speckle,
            ..LightModel::incoherent()
        };
        cfg.camera.exposure_us = self.exposure_us;
        for l in &mut cfg.lasers {
            l.wavelength_nm = self.wavelength_nm;
            l.power_mw = self.sensor.power_mw;
        }
        let i = &mut cfg.camera.intrinsics;
        (i.fx_px, i.fy_px) = (self.sensor.focal_px, i.fy_px * self.sensor.focal_px / i.fx_px);
        cfg.noise = if self.sensor.noise {
            NoiseModel { read_noise_e: self.sensor.read_noise_e, ..cfg.noise }
        } else {
            NoiseModel::none()
        };
        cfg.speed_mm_s = self.speed_mm_s;
        cfg.frame_rate_hz = self.speed_mm_s / self.step_mm;
        cfg.seed = self.seed;
        cfg
    }
}

/// Shortest rail, mm: the 10–30 mm band's window and its edge zones
/// (720 mm) and an EN 15610 segment with margin.
pub const MIN_LENGTH_MM: f64 = 1200.0;

/// Drives the head over the rail and judges what it measured with
/// `analyze`'s defaults.
pub fn run(s: &Setting) -> Result<Analysis, ClosedLoopError> {
    if !(s.length_mm >= MIN_LENGTH_MM && s.length_mm <= 1e6 && s.step_mm > 0.0 && s.speed_mm_s > 0.0) {
        return Err(ClosedLoopError::Options(format!(
            "{} mm of rail at {} mm a frame and {} mm/s: at least {} mm, a positive step and speed",
            s.length_mm, s.step_mm, s.speed_mm_s, MIN_LENGTH_MM
        )));
    }
    s.sensor.check()?;
    let stitching = drive(s, s.config())?;
    analyze::judge(stitching, Vec::new(), &analyze::Options::default(), &crate::progress::Silent)
        .map_err(|e| ClosedLoopError::Analysis(e.to_string()))
}

/// The head as `cfg` sets it driven over the setting's rail, a frame every
/// `s.step_mm`: its lines stitched as `analyze` stitches a recording.
pub fn drive(s: &Setting, cfg: SimConfig) -> Result<stitch::Stitching, ClosedLoopError> {
    let mut scene = Scene::new(cfg.clone())?;
    let m = Measurer::new(&truth(&scene))?;
    let mut det = detector(&cfg)?;
    let opts = analyze::Options::default();
    let mut stitcher = Stitcher::new(&opts.stitch).map_err(|e| ClosedLoopError::Analysis(e.to_string()))?;
    let frames = (s.length_mm / s.step_mm).ceil() as u64 + 1;
    for n in 0..frames {
        let p = frame_profiles(&mut scene, n, &m, &mut det, s.row_step)?;
        let mut f = FramePoints { seq: n as u32, odometer_mm: scene.odometer_mm(n), ..FramePoints::default() };
        for (k, line) in p.iter().enumerate() {
            f.lasers[k] = line.iter().map(|&(a, h)| (a, h * 1000.0)).collect();
        }
        stitcher.push(&f);
    }
    stitcher.finish().map_err(|e| ClosedLoopError::Analysis(e.to_string()))
}
