//! The scene's configuration: camera, head, lasers, rail and motion, its
//! presets, and the checks that refuse what cannot be rendered.

use super::{Camera, HeadGeometry, LightModel, MAX_LASERS, NoiseModel, RailModel};

/// Why a configuration was refused.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SimError {
    /// A numeric field is out of range.
    #[error("{field} = {value} must be {expected}")]
    Field {
        /// The field, as `camera.fx_px`.
        field: &'static str,
        /// Its value.
        value: f64,
        /// What it must be.
        expected: &'static str,
    },
    /// Image width outside 5..=65535 or height outside 1..=65535.
    #[error("image size {width} × {height} px: width must be in 5..=65535, height in 1..=65535")]
    ImageSize {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
    },
    /// Bit depth outside 8..=16.
    #[error("camera.bits = {0} must be in 8..=16")]
    Bits(u8),
    /// The distortion folds over inside the image (not one-to-one).
    #[error("camera distortion is not one-to-one over the image")]
    Distortion,
    /// Number of lasers outside 1..=8.
    #[error("{0} lasers: a head has 1..={MAX_LASERS}")]
    LaserCount(usize),
    /// A laser's line misses the rail head (beyond the crown) or the image.
    #[error("laser {laser}: its line misses the rail head or falls outside the image")]
    LaserOutOfView {
        /// Laser index.
        laser: usize,
    },
    /// The roughness band gives no component or too long a table.
    #[error(
        "roughness band {min_mm}–{max_mm} mm: needs at least one component and at most 2^22 samples (max/min wavelength ≤ about 6500)"
    )]
    RoughnessBand {
        /// Shortest wavelength, mm.
        min_mm: f64,
        /// Longest wavelength, mm.
        max_mm: f64,
    },
}

/// `Ok` if `ok` and `value` is finite, else a [`SimError::Field`].
pub(crate) fn check(field: &'static str, value: f64, ok: bool, expected: &'static str) -> Result<(), SimError> {
    if ok && value.is_finite() { Ok(()) } else { Err(SimError::Field { field, value, expected }) }
}

/// One line laser of the head.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Laser {
    /// Where its line falls across the rail, from the aim point, on the
    /// nominal rail top, mm (+ = towards higher columns).
    pub offset_mm: f64,
    /// Optical power, mW.
    pub power_mw: f64,
    /// Relative brightness of this emitter and its optics (1 = nominal).
    pub brightness: f64,
    /// Wavelength, nm (informational: the band-pass filter passes it; no
    /// chromatic effect is modelled).
    pub wavelength_nm: f64,
}

/// Camera and head geometry presets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Preset {
    /// The reference head: 752 × 480 global-shutter sensor, 8 bits.
    #[default]
    Reference,
    /// The geometry of the paper's Table 4 (4752 × 3168).
    Paper,
}

/// Everything the simulated head and rail are made of.
///
/// `Default` is [`SimConfig::reference`]; [`SimConfig::paper`] is the
/// paper's prototype. Every field is public; [`Scene::new`](super::Scene::new) validates them.
#[derive(Clone, Debug, PartialEq)]
pub struct SimConfig {
    /// The camera (the bit depth is `camera.bits`, the exposure `camera.exposure_us`).
    pub camera: Camera,
    /// Camera and laser mounting.
    pub head: HeadGeometry,
    /// The lasers, 1..=8; bit `k` of a laser mask switches laser `k`.
    pub lasers: Vec<Laser>,
    /// The rail head's surface.
    pub rail: RailModel,
    /// Noise and ambient light.
    pub noise: NoiseModel,
    /// What the rail does to the lasers' light: speckle, focus, finish,
    /// glints, secondary reflections (default: none, incoherent light).
    pub light: LightModel,
    /// Stripe peak per mW of laser power per µs of exposure at the standoff
    /// on a rail of reflectance 1, electrons (lumps reflection, optics, QE).
    pub signal_e_per_mw_us: f64,
    /// Integrate the stripe over each pixel's width (else sample at the centre).
    pub pixel_integration: bool,
    /// Speed of the head along the rail, mm/s (negative: backwards).
    pub speed_mm_s: f64,
    /// Frame rate, Hz.
    pub frame_rate_hz: f64,
    /// Odometer at frame 0, mm.
    pub odometer_start_mm: f64,
    /// Seed of every random quantity (roughness, sensor pattern, frame noise).
    pub seed: u64,
    /// Which run of the head over the rail: each run reads its own frame
    /// noise, on the same rail and surface (the seed's). The head's place
    /// across the rail for the run is [`HeadGeometry::lateral_offset_mm`].
    pub run: u64,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig::reference()
    }
}

impl SimConfig {
    /// The reference head (see the module's table): 752 × 480 camera at
    /// 200 mm, three 50 mW lines 10 mm apart at α = 35°, σ ≈ 3 px, moderate
    /// corrugation, 2 m/s at 60 Hz.
    pub fn reference() -> SimConfig {
        SimConfig {
            camera: Camera::reference(),
            head: HeadGeometry::reference(),
            lasers: three_lasers(10.0, [1.0, 0.8, 0.65]),
            rail: RailModel::default(),
            noise: NoiseModel::default(),
            light: LightModel::incoherent(),
            signal_e_per_mw_us: 2.6,
            pixel_integration: true,
            speed_mm_s: 2000.0,
            frame_rate_hz: 60.0,
            odometer_start_mm: 0.0,
            seed: 1,
            run: 0,
        }
    }

    /// The paper's prototype (Table 4): Canon 500D at 450 mm (middle of the
    /// 350–550 mm range), α = 42°, 2 mm lines (σ ≈ 15 px), 50 mW lasers,
    /// 1/4000 s, 0.5 m/s at 3.4 frames/s (the camera's burst rate).
    ///
    /// The lines are 15 mm apart (170 px = 11 σ, covering a 30 mm running
    /// band): at 10 mm (113 px = 7.5 σ) each stripe's tails reach into its
    /// neighbours' CWT windows and bias the detector by 0.07–0.1 px.
    pub fn paper() -> SimConfig {
        SimConfig {
            camera: Camera::paper(),
            head: HeadGeometry::paper(),
            lasers: three_lasers(15.0, [1.0, 0.85, 0.7]),
            rail: RailModel::default(),
            noise: NoiseModel { read_noise_e: 24.0, ambient_e_per_us: 4.0, ..NoiseModel::default() },
            light: LightModel::incoherent(),
            signal_e_per_mw_us: 1.28,
            pixel_integration: true,
            speed_mm_s: 500.0,
            frame_rate_hz: 3.4,
            odometer_start_mm: 0.0,
            seed: 1,
            run: 0,
        }
    }

    /// The simulated head as the optics prediction of the noise floor
    /// reads it (`crate::analyze::optics_floor`): its geometry, focal
    /// length, pixel pitch and speckle patterns.
    pub fn head_lens(&self) -> crate::model::head::HeadLens {
        crate::model::head::HeadLens {
            geometry: self.head,
            focal_px: self.camera.intrinsics.fx_px,
            pixel_um: self.camera.pixel_pitch_um,
            speckle_patterns: self.light.speckle.map_or(1, |s| s.patterns),
            source: crate::model::head::HeadSource::Simulated,
        }
    }

    /// The head's optics for `cms_core` (paper Eq. 10–11 with the 25 %
    /// margin): `optics().scale_range()` is the detector's scale range.
    pub fn optics(&self) -> cms_core::optics::Optics {
        cms_core::optics::Optics {
            fx_px: self.camera.intrinsics.fx_px,
            laser_diameter_mm: self.head.laser_diameter_mm,
            alpha_deg: self.head.alpha_deg,
            r_min_mm: self.head.working_range_mm[0],
            r_max_mm: self.head.working_range_mm[1],
            margin: 0.25,
        }
    }

    /// Stripe σ at the standoff, px (Eq. 10–11).
    pub fn nominal_sigma_px(&self) -> f64 {
        self.camera.intrinsics.fx_px * self.head.laser_diameter_mm * self.head.alpha_deg.to_radians().sin()
            / self.head.standoff_mm
    }

    /// Odometer of a frame, mm.
    pub fn odometer_mm(&self, frame_index: u64) -> f64 {
        self.odometer_start_mm + self.speed_mm_s * frame_index as f64 / self.frame_rate_hz
    }

    /// The mask with every laser on.
    pub fn all_lasers_mask(&self) -> u8 {
        ((1u16 << self.lasers.len().min(MAX_LASERS)) - 1) as u8
    }

    pub(super) fn validate(&self) -> Result<(), SimError> {
        self.camera.validate()?;
        self.head.validate()?;
        if self.lasers.is_empty() || self.lasers.len() > MAX_LASERS {
            return Err(SimError::LaserCount(self.lasers.len()));
        }
        for l in &self.lasers {
            check("lasers.offset_mm", l.offset_mm, l.offset_mm.is_finite(), "finite")?;
            check("lasers.power_mw", l.power_mw, l.power_mw >= 0.0, "finite and ≥ 0")?;
            check("lasers.brightness", l.brightness, l.brightness >= 0.0, "finite and ≥ 0")?;
            check("lasers.wavelength_nm", l.wavelength_nm, l.wavelength_nm > 0.0, "finite and > 0")?;
        }
        self.rail.validate()?;
        self.noise.validate()?;
        self.light.validate(self.lasers.len())?;
        let g = self.signal_e_per_mw_us;
        check("signal_e_per_mw_us", g, g >= 0.0, "finite and ≥ 0")?;
        check("speed_mm_s", self.speed_mm_s, self.speed_mm_s.is_finite(), "finite")?;
        check("frame_rate_hz", self.frame_rate_hz, self.frame_rate_hz > 0.0, "finite and > 0")?;
        check("odometer_start_mm", self.odometer_start_mm, self.odometer_start_mm.is_finite(), "finite")?;
        Ok(())
    }
}

pub(super) fn three_lasers(spacing_mm: f64, brightness: [f64; 3]) -> Vec<Laser> {
    [-spacing_mm, 0.0, spacing_mm]
        .into_iter()
        .zip(brightness)
        .map(|(offset_mm, brightness)| Laser { offset_mm, power_mw: 50.0, brightness, wavelength_nm: 685.0 })
        .collect()
}
