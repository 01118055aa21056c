//! A synthetic calibrated recording of any length: the frames a head would
//! send while travelling over a known rail, written straight to a
//! `.cmsrec` without rendering a pixel. It exists to measure what reads
//! recordings at the scale of a survey (`analyze`, `export`: 10⁴–10⁵
//! frames, kilometres of rail) in seconds rather than the hours the
//! real-time simulated head would take; the detector and the optics are
//! not exercised here (the simulated head and `bench corrugation` do that).
//!
//! The rail is 30 µm of corrugation at 50 mm, 20 µm at 200 mm and 3 µm at
//! 17 mm; the head takes a frame every `step_mm` of travel, each seeing
//! [`Options::points_per_line`] points over 68.6 mm per laser (the sim
//! head's field of view), bounced by up to ±20 µm, with Gaussian noise per
//! point. Points carry their metric (along, height) as a calibrated head
//! sends them, plus a plausible pixel position. The recording starts with
//! a `Hello` naming [`CALIBRATION_ID`] (or [`Options::calibration_id`])
//! and a 752 × 480 sensor.
//!
//! With [`Options::gnss`], a simulated GNSS receiver rides along
//! ([`crate::sim::gnss`]'s model and noise, seeded): its fixes are written
//! among the frames as host records, as `listen --gnss sim` records them
//! (see [`Gnss`] for the clocks).
//!
//! Cost: about a microsecond per point; memory one frame. Deterministic:
//! the same options give the same bytes.

use std::io::{self, Write};
use std::path::Path;

use cms_core::fixed::Px;
use cms_core::peak::Flags;
use cms_core::pipeline::default_detector;
use cms_core::protocol::{
    self, DeviceInfo, DeviceMsg, LASERS, LaserPoints, MAX_FRAME, Metric, PROTOCOL_VERSION, Point, Profile, StoreHealth,
};
use rand_xoshiro::Xoshiro256PlusPlus;
use rand_xoshiro::rand_core::{Rng as _, SeedableRng};

use crate::gnss::Placed;
use crate::output::{self, OutputError};
use crate::progress::Progress;
use crate::recording::{self, HostRecord};
use crate::sim::gnss::{Antenna, GnssSimOptions};

/// The calibration id the synthetic head reports.
pub const CALIBRATION_ID: u32 = 0x5157_4e54;

/// The head's time between frames, µs (30 Hz).
pub const FRAME_US: u64 = 33_333;

/// A simulated GNSS receiver riding with the synthetic head.
///
/// Its epochs are `1 / rate_hz` apart on the head's clock from the first
/// frame's time (0). The host's clock is the head's (each frame arrives as
/// it is taken), so a fix is recorded after the last frame taken at or
/// before its epoch, with that frame's time plus the time since
/// (`head_us`, equal to `host_us`) and its odometer, as the listener
/// places a fix ([`crate::gnss`], "Time alignment"). Its antenna is at
/// the chainage of that frame's odometer, `start + direction × odometer`,
/// as the simulated receiver reads the odometer of the frame being taken:
/// behind the head by up to one frame's travel. No output latency.
#[derive(Debug, Clone)]
pub struct Gnss {
    /// The receiver: its register, start chainage, direction, rate, quality, noise and seed.
    pub receiver: GnssSimOptions,
    /// UTC date of the first frame.
    pub date: chrono::NaiveDate,
    /// UTC of the first frame, milliseconds of its day.
    pub utc_ms_of_day: u32,
}

/// What to synthesise.
#[derive(Debug, Clone)]
pub struct Options {
    /// Frames to write.
    pub frames: u32,
    /// Travel between frames, mm (17 mm: 0.5 m/s at 30 Hz).
    pub step_mm: f64,
    /// Points per laser line and frame (the sensor's rows).
    pub points_per_line: u16,
    /// Noise per point, µm RMS.
    pub noise_um: f64,
    /// Seed of the noise and the bounce.
    pub seed: u64,
    /// The rail under the run.
    pub rail: Rail,
    /// Track position of the odometer's zero, mm.
    pub start_mm: f64,
    /// Driven the other way: track position = start − (odometer + along)
    /// (the head turned round with the trolley).
    pub reverse: bool,
    /// The calibration id its `Hello` names (another id: another head).
    pub calibration_id: u32,
    /// The survey block's text (`listen --survey`'s, [`crate::recording::survey_info`]).
    pub survey: Option<String>,
    /// A GNSS receiver riding along: its fixes among the frames.
    pub gnss: Option<Gnss>,
}

impl Options {
    /// The odometer of the first and the last frame, mm.
    pub fn odometer_span_mm(&self) -> (f64, f64) {
        (odometer_mm(0, self.step_mm), odometer_mm(self.frames.saturating_sub(1), self.step_mm))
    }
}

/// The odometer of frame `seq`, mm.
fn odometer_mm(seq: u32, step_mm: f64) -> f64 {
    100.0 + step_mm * f64::from(seq)
}

impl Default for Options {
    fn default() -> Self {
        Options {
            frames: 10_000,
            step_mm: 17.0,
            points_per_line: 480,
            noise_um: 1.0,
            seed: 1,
            rail: Rail::Corrugated,
            start_mm: 0.0,
            reverse: false,
            calibration_id: CALIBRATION_ID,
            survey: None,
            gnss: None,
        }
    }
}

/// What the rail looks like.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rail {
    /// [`rail_um`]: corrugated everywhere.
    Corrugated,
    /// A survey's rail ([`survey_rail_um`]): broadband roughness, and
    /// corrugation of `amplitude_um` at `wavelength_mm` between `zone_mm`.
    Survey { zone_mm: (f64, f64), wavelength_mm: f64, amplitude_um: f64 },
}

impl Rail {
    /// The height at track position `x_mm`, µm.
    pub fn height_um(&self, x_mm: f64) -> f64 {
        match *self {
            Rail::Corrugated => rail_um(x_mm),
            Rail::Survey { zone_mm, wavelength_mm, amplitude_um } => {
                survey_rail_um(x_mm, zone_mm, wavelength_mm, amplitude_um)
            }
        }
    }
}

/// Broadband roughness every rail has: 48 sines with wavelengths spread
/// evenly in log from 8 to 2 000 mm, amplitudes 0.01 µm per mm of
/// wavelength (0.08 µm at 8 mm, 0.4 µm at 40 mm, 20 µm at 2 m), fixed
/// phases: under every EN 13231-3 limit, but no two placements of a
/// record alike. Plus the corrugated zone, with its whole amplitude
/// between its ends (the ends of the zone are where the rail changes).
pub fn survey_rail_um(x_mm: f64, zone_mm: (f64, f64), wavelength_mm: f64, amplitude_um: f64) -> f64 {
    use std::f64::consts::TAU;
    // Wavelength and phase per component, computed once: a survey asks
    // for millions of heights.
    static COMPONENTS: std::sync::LazyLock<[(f64, f64); 48]> = std::sync::LazyLock::new(|| {
        std::array::from_fn(|k| {
            let w = 8.0 * (2000.0f64 / 8.0).powf(k as f64 / 47.0);
            // A fixed pseudo-random phase per component (golden-ratio sequence).
            (w, TAU * ((k as f64 * 0.618_033_988_75) % 1.0))
        })
    });
    let mut z = 0.0;
    for &(w, phase) in COMPONENTS.iter() {
        z += 0.01 * w * (TAU * x_mm / w + phase).sin();
    }
    if x_mm >= zone_mm.0 && x_mm < zone_mm.1 {
        z += amplitude_um * (TAU * x_mm / wavelength_mm).sin();
    }
    z
}

/// The rail's height at track position `x_mm`, µm.
pub fn rail_um(x_mm: f64) -> f64 {
    use std::f64::consts::TAU;
    30.0 * (TAU * x_mm / 50.0).sin() + 20.0 * (TAU * x_mm / 200.0 + 1.0).sin() + 3.0 * (TAU * x_mm / 17.0).cos()
}

/// Frame length along each line, mm (the simulated head's field of view).
pub const FRAME_MM: f64 = 68.6;

/// Writes the recording to `path` (atomically, a regular file only).
pub fn write(path: &Path, opts: &Options, progress: &dyn Progress) -> Result<(), OutputError> {
    progress.begin(&format!("writing {}", path.display()), opts.frames.into(), "frames");
    let r = output::write_atomically(path, |w| write_to(w, opts, progress));
    progress.end();
    r
}

/// Writes the recording's bytes to `w`, telling `progress` the frames written.
pub fn write_to(w: &mut dyn Write, opts: &Options, progress: &dyn Progress) -> io::Result<()> {
    let mut w = io::BufWriter::with_capacity(1 << 16, w);
    let mut out = vec![0u8; MAX_FRAME];
    let mut put = |w: &mut dyn Write, msg: &DeviceMsg| -> io::Result<()> {
        let bytes = protocol::encode(msg, &mut out).map_err(|e| io::Error::other(format!("{e:?}")))?;
        w.write_all(bytes)
    };
    w.write_all(&recording::header_and_survey(opts.survey.as_deref()))?;
    let mut board = heapless::String::new();
    let _ = board.push_str("synthetic");
    let hello = DeviceInfo {
        firmware: heapless::String::new(),
        protocol: PROTOCOL_VERSION,
        board,
        sensor_width: 752,
        sensor_height: 480,
        bits: 10,
        detector: default_detector(),
        calibration_id: opts.calibration_id,
        store: StoreHealth::Volatile,
    };
    put(&mut w, &DeviceMsg::Hello(hello))?;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(opts.seed);
    let mut uniform = move || -> f64 { (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64 };
    let n = opts.points_per_line.clamp(2, protocol::MAX_ROWS_PER_PROFILE as u16) as usize;
    let pitch_mm = FRAME_MM / (n - 1) as f64;
    let mut receiver = opts.gnss.as_ref().map(Receiver::new);
    for seq in 0..opts.frames {
        let odometer_mm = odometer_mm(seq, opts.step_mm);
        let bounce_um = 40.0 * (uniform() - 0.5);
        let mut p = Profile {
            seq,
            parts: 1,
            timestamp_us: u64::from(seq) * FRAME_US,
            odometer_um: (odometer_mm * 1000.0).round() as i64,
            exposure_us: 500,
            laser_mask: (1 << LASERS) - 1,
            ..Profile::EMPTY
        };
        for k in 0..LASERS {
            let mut lp = LaserPoints { laser: k as u8, points: heapless::Vec::new() };
            for r in 0..n {
                let along_mm = -FRAME_MM / 2.0 + pitch_mm * r as f64;
                // Box–Muller: one normal deviate per point.
                let (u1, u2) = (uniform().max(1e-300), uniform());
                let noise = (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
                let track_mm = if opts.reverse {
                    opts.start_mm - (odometer_mm + along_mm)
                } else {
                    opts.start_mm + odometer_mm + along_mm
                };
                let height_um = opts.rail.height_um(track_mm) + 100.0 * k as f64 + bounce_um + opts.noise_um * noise;
                let pt = Point {
                    row: r as u16,
                    position: Px::from_f64(200.0 + 170.0 * k as f64 + 0.05 * height_um),
                    strength: 900,
                    width: Px::from_f64(2.5),
                    flags: Flags::NONE,
                    metric: Some(Metric {
                        along_um: (along_mm * 1000.0).round() as i32,
                        height_nm: (height_um * 1000.0).round() as i32,
                    }),
                };
                // `n` is at most the capacity.
                let _ = lp.points.push(pt);
            }
            let _ = p.lasers.push(lp);
        }
        let (timestamp_us, odometer_um) = (p.timestamp_us, p.odometer_um);
        put(&mut w, &DeviceMsg::Profile(p))?;
        if let Some(r) = &mut receiver {
            // The epochs until the next frame is taken (the last frame's own only).
            let next_us = if seq + 1 < opts.frames { timestamp_us + FRAME_US } else { timestamp_us + 1 };
            r.epochs(&mut w, next_us, odometer_um)?;
        }
        if seq % 256 == 255 {
            progress.set(u64::from(seq) + 1);
        }
    }
    w.flush()
}

/// The riding receiver's state: its antenna and its next epoch.
struct Receiver<'a> {
    gnss: &'a Gnss,
    antenna: Antenna,
    period_us: u64,
    next_us: u64,
}

impl<'a> Receiver<'a> {
    fn new(gnss: &'a Gnss) -> Receiver<'a> {
        Receiver {
            gnss,
            antenna: Antenna::new(gnss.receiver.clone()),
            period_us: 1_000_000 / u64::from(gnss.receiver.rate_hz.max(1)),
            next_us: 0,
        }
    }

    /// Writes the fixes of the epochs before `until_us`, after the frame of
    /// odometer `odometer_um` (taken at or before every one of them).
    fn epochs(&mut self, w: &mut dyn Write, until_us: u64, odometer_um: i64) -> io::Result<()> {
        while self.next_us < until_us {
            let t_us = self.next_us;
            self.next_us += self.period_us;
            let ms = u64::from(self.gnss.utc_ms_of_day) + t_us / 1000;
            let day = self.gnss.date.checked_add_days(chrono::Days::new(ms / 86_400_000)).unwrap_or(self.gnss.date);
            let date = {
                use chrono::Datelike as _;
                (day.year().clamp(0, 9999) as u16, day.month() as u8, day.day() as u8)
            };
            let fix = self.antenna.fix(t_us, odometer_um as f64 * 1e-6, (ms % 86_400_000) as u32, date);
            let placed = Placed { host_us: t_us, head_us: Some(t_us), odometer_um: Some(odometer_um), fix };
            w.write_all(&HostRecord::Fix(placed).frame())?;
        }
        Ok(())
    }
}
