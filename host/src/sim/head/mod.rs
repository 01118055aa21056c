//! `cms-host simulate`: the simulated sensor head on a pseudo-terminal.
//!
//! The head is `cms_core::pipeline::Head` — the firmware's own command
//! handling, detector, framing and laser-safety rules — fed with camera rows
//! rendered by the scene model ([`crate::sim::scene`]) instead of a sensor, and
//! talking the wire protocol over a pty instead of USB. A listener cannot
//! tell the difference except by the `board` name in `Hello` (`cms-sim`).
//!
//! * [`serve_on_new_pty`] — `cms-host simulate`: the server on a new pty,
//!   until stopped (the command line prints the pty's path and the summary).
//! * [`spawn_on_pty`] — the same server on a thread of this process (for
//!   `cms-host listen sim` and tests); [`resolve_port`] turns a `listen`
//!   PORT argument into a device path, starting the simulator for `sim`.

pub mod server;
pub mod stored;
pub mod worker;

use std::io::{self, Write as _};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::thread::JoinHandle;

pub use scene::SceneCamera;
pub use server::{MAX_WIDTH, RowRenderer, ServeOptions, ServeSummary, serve};

use crate::sim::pty::Pty;
use crate::sim::scene::{Corrugation, RoughnessSpectrum, SimConfig};

pub use crate::sim::SimulateError;
pub use crate::sim::scene::Preset;

/// The simulated head's travel when none is asked for, mm/s: a quarter of
/// the fastest at which the reference head's 69 mm frames still overlap by
/// the stitcher's 3 mm at `listen`'s 30 frames/s (`serve::speed_limit_mm_s`,
/// 1.98 m/s), so that every join of a default run registers with ~52 mm of
/// overlap. Rendering laser light slower than the head's rate holds the
/// trolley back ([`server::SimCamera::streaming_at`]) instead of opening gaps.
pub const DEFAULT_SPEED_MM_S: f64 = 500.0;

/// Farthest the head may stand across the rail from where the preset aims
/// it, mm: its outer lines stay on a rail head's top (about 70 mm wide).
pub const MAX_LATERAL_MM: f64 = 15.0;

/// One corrugation component, `WAVELENGTH_MM:AMPLITUDE_UM[:PHASE_DEG]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CorrugationSpec {
    /// Wavelength along the rail, mm.
    pub wavelength_mm: f64,
    /// Amplitude (half peak-to-peak), µm.
    pub amplitude_um: f64,
    /// Phase, degrees.
    pub phase_deg: f64,
}

/// The simulated head: its scene, camera and state directory (`cms-host
/// simulate`, and the scene part of `listen sim`). `Default` is the command
/// line without options; `None` keeps the preset's value.
#[derive(Clone, Debug)]
pub struct HeadOptions {
    /// Camera and head geometry.
    pub preset: Preset,
    /// Seed of every random part of the scene (roughness, noise, hot pixels).
    pub seed: u64,
    /// Which run over the rail: each run reads its own frame noise on the
    /// same rail (`SimConfig::run`).
    pub run: u64,
    /// The head's place across the rail for the run, mm from where the
    /// preset aims it (a trolley's play on the rail head; `None`: there).
    pub lateral_mm: Option<f64>,
    /// The camera's highest frame rate, Hz: the host's `Start` picks the
    /// rate, and one above this is refused (out of range).
    pub rate: u16,
    /// Travel speed along the rail, mm/s ([`DEFAULT_SPEED_MM_S`] if none).
    pub speed_mm_s: Option<f64>,
    /// A corrugation component (repeat for several).
    pub corrugation: Vec<CorrugationSpec>,
    /// RMS random roughness of the running surface, µm.
    pub roughness_um: Option<f64>,
    /// A measured roughness spectrum laid on the rail: the rail is then
    /// the spectrum plus the corrugation and roughness given above (the
    /// preset's own corrugation and roughness are left out).
    pub roughness_spectrum: Option<RoughnessSpectrum>,
    /// Random (read) noise, RMS counts.
    pub noise: Option<f64>,
    /// Fraction of hot pixels (fixed pattern), 0..=0.1.
    pub hot_pixels: Option<f64>,
    /// Row banding, RMS counts.
    pub banding: Option<f64>,
    /// Ambient light, counts.
    pub ambient: Option<f64>,
    /// Output bit depth (8, 10 or 12).
    pub bits: Option<u8>,
    /// Relative power of the three lasers (multiplies the preset's).
    pub laser_gain: Option<[f64; 3]>,
    /// Directory where the head keeps its calibration across restarts
    /// [default: $CMS_SIM_STATE, else $XDG_STATE_HOME/cms-host/sim-head, else
    /// ~/.local/state/cms-host/sim-head].
    pub state: Option<PathBuf>,
    /// Whether the head leaves the factory calibrated (its true
    /// calibration, as a real profiler's factory calibration): used
    /// whenever no calibration is kept in its state directory.
    pub factory_calibration: bool,
    /// What the rail does to the lasers' light (speckle, finish, glints,
    /// ghosts); `None` keeps the preset's scene light (incoherent: the
    /// commands give [`default_light`] instead).
    pub light: Option<crate::sim::scene::LightModel>,
    /// Where each frame's odometer is published (µm) for a simulated GNSS
    /// receiver riding with the head ([`crate::sim::gnss`]).
    pub odometer_tap: Option<Arc<AtomicI64>>,
}

impl Default for HeadOptions {
    fn default() -> Self {
        HeadOptions {
            preset: Preset::Reference,
            seed: 1,
            run: 0,
            lateral_mm: None,
            rate: 30,
            speed_mm_s: None,
            corrugation: Vec::new(),
            roughness_um: None,
            roughness_spectrum: None,
            noise: None,
            hot_pixels: None,
            banding: None,
            ambient: None,
            bits: None,
            laser_gain: None,
            state: None,
            factory_calibration: true,
            light: None,
            odometer_tap: None,
        }
    }
}

/// `cms-host simulate`: serves the head described by `args` on a new pty
/// until `stop` is set. `on_open` gets the pty's slave path first (the
/// command prints it as the first line of stdout).
pub fn serve_on_new_pty(
    args: &HeadOptions,
    stop: &AtomicBool,
    on_open: impl FnOnce(&std::path::Path) -> io::Result<()>,
) -> Result<ServeSummary, SimulateError> {
    let built = scene::build(args)?;
    let pty = Pty::open()?;
    on_open(pty.path()).map_err(|e| SimulateError::Io("printing the pty path", e))?;
    let opts = ServeOptions {
        max_rate_hz: built.max_rate_hz,
        exposure_us: Some(built.exposure_us),
        calibration_file: calibration_file(args),
        factory_calibration: built.factory,
        ..ServeOptions::default()
    };
    serve(pty, built.renderer, built.detector, stop, &opts)
}

/// Where the head described by `args` keeps its calibration.
fn calibration_file(args: &HeadOptions) -> Option<PathBuf> {
    args.state.clone().or_else(stored::default_dir).map(|d| d.join(stored::FILE_NAME))
}

/// A simulated head serving on a thread of this process. Dropping it stops
/// the server (lasers off) and waits for the thread.
pub struct SimHandle {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<ServeSummary, SimulateError>>>,
    /// A simulated GNSS receiver riding with the head.
    gnss: Option<crate::sim::gnss::GnssSim>,
}

impl SimHandle {
    /// The port of the simulated GNSS receiver riding with the head, if any.
    pub fn gnss_path(&self) -> Option<&std::path::Path> {
        self.gnss.as_ref().map(|g| g.path())
    }

    /// Whether the server is still running.
    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }

    /// Stops the server and returns what it did.
    pub fn stop(mut self) -> Result<ServeSummary, SimulateError> {
        self.join()
    }

    fn join(&mut self) -> Result<ServeSummary, SimulateError> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take() {
            Some(t) => {
                t.join().unwrap_or_else(|_| Err(SimulateError::Io("simulated head", io::Error::other("panicked"))))
            }
            None => Ok(ServeSummary::default()),
        }
    }
}

impl Drop for SimHandle {
    fn drop(&mut self) {
        let _ = self.join();
    }
}

/// Starts the simulated head described by `args` on a new pty, served by a
/// thread of this process (laser changes are not logged). Returns the pty's
/// slave path — open it like a serial port — and the handle that stops it.
pub fn spawn_on_pty(args: &HeadOptions) -> Result<(PathBuf, SimHandle), SimulateError> {
    let built = scene::build(args)?;
    let pty = Pty::open()?;
    let path = pty.path().to_path_buf();
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let opts = ServeOptions {
        log_lasers: false,
        max_rate_hz: built.max_rate_hz,
        exposure_us: Some(built.exposure_us),
        calibration_file: calibration_file(args),
        factory_calibration: built.factory,
        ..ServeOptions::default()
    };
    let thread = std::thread::Builder::new()
        .name("cms-sim".into())
        .stack_size(8 << 20)
        .spawn(move || serve(pty, built.renderer, built.detector, &flag, &opts))
        .map_err(|e| SimulateError::Io("starting the simulated head's thread", e))?;
    Ok((path, SimHandle { stop, thread: Some(thread), gnss: None }))
}

/// The simulated head's options where a command takes a PORT (`listen`,
/// `capture`, `calibrate upload`): they apply only to PORT `sim`.
#[derive(Clone, Debug, Default)]
pub struct SimPort {
    /// With PORT `sim`: seed of the simulated scene.
    pub sim_seed: Option<u64>,
    /// With PORT `sim`: which run over the rail (its own frame noise, the same rail).
    pub sim_run: Option<u64>,
    /// With PORT `sim`: the head's place across the rail for the run, mm.
    pub sim_lateral_mm: Option<f64>,
    /// With PORT `sim`: camera and head geometry of the simulated head.
    pub sim_preset: Option<Preset>,
    /// With PORT `sim`: the simulated head's state directory (its kept calibration).
    pub sim_state: Option<PathBuf>,
    /// With PORT `sim`: travel speed of the simulated head along the rail, mm/s.
    pub sim_speed_mm_s: Option<f64>,
    /// With PORT `sim`: a corrugation component of the simulated rail (repeat for several).
    pub sim_corrugation: Vec<CorrugationSpec>,
    /// With PORT `sim`: RMS random roughness of the simulated rail, µm.
    pub sim_roughness_um: Option<f64>,
    /// With PORT `sim`: a measured roughness spectrum laid on the
    /// simulated rail ([`HeadOptions::roughness_spectrum`]).
    pub sim_roughness_spectrum: Option<RoughnessSpectrum>,
    /// With PORT `sim`: the simulated head starts without its factory calibration.
    pub sim_uncalibrated: bool,
    /// With PORT `sim`: the light on the simulated rail (speckle, finish,
    /// glints, ghosts); `None`: [`default_light`] (the recommended head's
    /// light on the reference head).
    pub sim_light: Option<crate::sim::scene::LightModel>,
    /// With PORT `sim`: a simulated GNSS receiver rides with the head
    /// ([`crate::sim::gnss`]).
    pub sim_gnss: Option<crate::sim::gnss::GnssSimOptions>,
}

impl SimPort {
    /// Whether any option was given (they all need PORT `sim`).
    pub fn any(&self) -> bool {
        self.sim_seed.is_some()
            || self.sim_run.is_some()
            || self.sim_lateral_mm.is_some()
            || self.sim_preset.is_some()
            || self.sim_state.is_some()
            || self.sim_speed_mm_s.is_some()
            || !self.sim_corrugation.is_empty()
            || self.sim_roughness_um.is_some()
            || self.sim_roughness_spectrum.is_some()
            || self.sim_uncalibrated
            || self.sim_light.is_some()
            || self.sim_gnss.is_some()
    }
}

/// A `listen` PORT: `sim` starts the simulated head on a new pty and returns
/// its slave path with the handle that keeps it running; anything else is
/// a device path, returned as it is.
pub fn resolve_port(port: &str, sim: &SimPort) -> Result<(PathBuf, Option<SimHandle>), SimulateError> {
    if port != "sim" {
        if sim.any() {
            return Err(SimulateError::Usage("--sim-seed, --sim-run, --sim-lateral-mm, --sim-preset, --sim-state, --sim-speed-mm-s, --sim-corrugation, --sim-roughness-um, --sim-roughness-spectrum, --sim-uncalibrated, --sim-light and --gnss sim need PORT `sim`".into()));
        }
        return Ok((PathBuf::from(port), None));
    }
    let args = port_options(sim);
    let (path, mut handle) = spawn_on_pty(&args)?;
    if let (Some(g), Some(tap)) = (&sim.sim_gnss, &args.odometer_tap) {
        handle.gnss = Some(crate::sim::gnss::GnssSim::spawn(g.clone(), tap.clone())?);
    }
    Ok((path, Some(handle)))
}

/// The simulated head PORT `sim` starts.
fn port_options(sim: &SimPort) -> HeadOptions {
    // The listener's `--rate` decides: the camera allows up to 1000 Hz.
    let preset = sim.sim_preset.unwrap_or(Preset::Reference);
    HeadOptions {
        seed: sim.sim_seed.unwrap_or(1),
        run: sim.sim_run.unwrap_or(0),
        lateral_mm: sim.sim_lateral_mm,
        preset,
        rate: 1000,
        state: sim.sim_state.clone(),
        speed_mm_s: sim.sim_speed_mm_s,
        corrugation: sim.sim_corrugation.clone(),
        roughness_um: sim.sim_roughness_um,
        roughness_spectrum: sim.sim_roughness_spectrum.clone(),
        factory_calibration: !sim.sim_uncalibrated,
        light: Some(sim.sim_light.clone().unwrap_or_else(|| default_light(preset))),
        odometer_tap: sim.sim_gnss.as_ref().map(|_| Arc::new(AtomicI64::new(crate::sim::gnss::NO_FRAME))),
        ..HeadOptions::default()
    }
}

/// The simulated head's light when none is asked for (`simulate` without
/// `--light`, PORT `sim` without `--sim-light`): the reference head's
/// lasers as the recommended head of docs/light.md shines them (a line
/// source of 100 speckle patterns through the lens at F/1.4 on a
/// Scheimpflug sensor; the camera's 100 µs exposure), the paper's geometry
/// in incoherent light (its synthetic protocol's).
pub fn default_light(preset: Preset) -> crate::sim::scene::LightModel {
    match preset {
        Preset::Reference => crate::sim::scene::LightModel::recommended(),
        Preset::Paper => crate::sim::scene::LightModel::incoherent(),
    }
}

/// The optics PORT `sim` records with (`listen sim`'s survey block): the
/// F-number of the lens its speckle is rendered through and its lasers'
/// wavelength. Optics `given` by the user (`--optics`) must be those: the
/// head renders its own light, so other optics would be recorded for images
/// they did not make, and `analyze` would check the floor against them —
/// refused, as two sources that disagree are. `None` in incoherent light
/// (no speckle to predict a floor from: optics given are refused) and for
/// the paper's geometry (not the head the prediction knows: optics given
/// are kept if they are its light's).
pub fn port_optics(
    sim: &SimPort,
    given: Option<crate::model::optics::Optics>,
) -> Result<Option<crate::model::optics::Optics>, SimulateError> {
    use crate::model::optics::Optics;
    let preset = sim.sim_preset.unwrap_or(Preset::Reference);
    let told = sim.sim_light.is_some();
    let light = sim.sim_light.clone().unwrap_or_else(|| default_light(preset));
    let config = match preset {
        Preset::Reference => SimConfig::reference(),
        Preset::Paper => SimConfig::paper(),
    };
    let wavelength_nm = config.lasers.first().map(|l| l.wavelength_nm);
    let own = light.speckle.zip(wavelength_nm).and_then(|(s, w)| Optics::new(s.f_number, w).ok());
    let whose = if told { "its --sim-light" } else { "its default light" };
    match (given, own) {
        (Some(g), Some(o)) if g != o => Err(SimulateError::Usage(format!(
            "--optics says the optics are {g}, the simulated head renders {o} ({whose}): give one (--sim-light speckle={} renders F/{})",
            g.f_number(),
            g.f_number()
        ))),
        (Some(g), None) => Err(SimulateError::Usage(format!(
            "--optics says the optics are {g}, the simulated head renders incoherent light ({whose}): no optics to record (--sim-light speckle={} renders F/{})",
            g.f_number(),
            g.f_number()
        ))),
        _ if !matches!(preset, Preset::Reference) => Ok(given),
        _ => Ok(own),
    }
}

/// Runs `f` on the device path of a `listen` PORT (see [`resolve_port`]);
/// a simulated head is stopped afterwards (lasers off) and its summary
/// printed as one `sim:` line on stderr.
pub fn with_port<T>(port: &str, sim: &SimPort, f: impl FnOnce(&str) -> T) -> Result<T, SimulateError> {
    with_ports(port, sim, |head, _| f(head))
}

/// [`with_port`], giving `f` the simulated GNSS receiver's port too when
/// one rides with the head ([`SimPort::sim_gnss`]).
pub fn with_ports<T>(port: &str, sim: &SimPort, f: impl FnOnce(&str, Option<&str>) -> T) -> Result<T, SimulateError> {
    let (path, head) = resolve_port(port, sim)?;
    let Some(path) = path.to_str() else {
        return Err(SimulateError::Usage(format!("port path {path:?} is not UTF-8")));
    };
    let gnss = head.as_ref().and_then(|h| h.gnss_path()).and_then(|p| p.to_str());
    let r = f(path, gnss);
    if let Some(head) = head {
        match head.stop() {
            Ok(s) => {
                let _ = writeln!(io::stderr(), "sim: {s}");
            }
            Err(e) => {
                let _ = writeln!(io::stderr(), "sim: error: {e}");
            }
        }
    }
    Ok(r)
}

/// The scene's configuration these options describe: the preset, then
/// every option given on top of it. Values are checked here and by
/// [`Scene::new`](crate::sim::scene::Scene::new).
pub fn sim_config(args: &HeadOptions) -> Result<SimConfig, SimulateError> {
    let mut cfg = match args.preset {
        Preset::Reference => SimConfig::reference(),
        Preset::Paper => SimConfig::paper(),
    };
    if let Some(light) = &args.light {
        cfg.light = light.clone();
    }
    cfg.seed = args.seed;
    cfg.run = args.run;
    if let Some(y) = args.lateral_mm {
        if !y.is_finite() || y.abs() > MAX_LATERAL_MM {
            return Err(SimulateError::Usage(format!(
                "the head's place across the rail must be within ±{MAX_LATERAL_MM} mm, got {y}"
            )));
        }
        cfg.head.lateral_offset_mm += y;
    }
    cfg.frame_rate_hz = args.rate as f64;
    if let Some(b) = args.bits {
        cfg.camera.bits = b;
    }
    // Counts are codes at the chosen bit depth; the model works in electrons.
    let e_per_count = cfg.camera.gain_e_per_dn();
    cfg.speed_mm_s = args.speed_mm_s.unwrap_or(DEFAULT_SPEED_MM_S);
    if !args.corrugation.is_empty() {
        cfg.rail.corrugation = args
            .corrugation
            .iter()
            .map(|c| Corrugation {
                wavelength_mm: c.wavelength_mm,
                amplitude_um: c.amplitude_um,
                phase_rad: c.phase_deg.to_radians(),
            })
            .collect();
    }
    if let Some(r) = args.roughness_um {
        cfg.rail.roughness_rms_um = r;
    }
    if let Some(spectrum) = &args.roughness_spectrum {
        // The measured spectrum is the rail's roughness: the preset's own
        // corrugation and roughness would be a second rail laid over it.
        if args.corrugation.is_empty() {
            cfg.rail.corrugation.clear();
        }
        if args.roughness_um.is_none() {
            cfg.rail.roughness_rms_um = 0.0;
        }
        cfg.rail.roughness_spectrum = Some(spectrum.clone());
    }
    if let Some(n) = args.noise {
        cfg.noise.read_noise_e = n * e_per_count;
    }
    if let Some(h) = args.hot_pixels {
        cfg.noise.hot_pixel_fraction = h;
    }
    if let Some(b) = args.banding {
        cfg.noise.row_banding_e = b * e_per_count;
    }
    if let Some(a) = args.ambient {
        cfg.noise.ambient_e_per_us = a * e_per_count / cfg.camera.exposure_us;
    }
    if let Some(g) = args.laser_gain {
        if cfg.lasers.len() != g.len() {
            return Err(SimulateError::Usage(format!(
                "--laser-gain: the preset has {} lasers, not {}",
                cfg.lasers.len(),
                g.len()
            )));
        }
        for (l, g) in cfg.lasers.iter_mut().zip(g) {
            l.brightness *= g;
        }
    }
    Ok(cfg)
}

/// The scene behind the simulated camera.
mod scene {
    use super::worker::Threaded;
    use super::{HeadOptions, RowRenderer, SimulateError, sim_config};
    use crate::sim::scene::{Scene, Shot};
    use cms_core::peak::{Config, Select};
    use cms_core::protocol::LASERS;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicI64, Ordering};

    /// The renderer, the detector configuration for its camera, its frame
    /// rate limit and its exposure.
    pub(super) struct Built {
        pub renderer: Threaded,
        pub detector: Config,
        pub max_rate_hz: u16,
        pub exposure_us: u32,
        /// The factory calibration, unless the head is to start without one.
        pub factory: Option<cms_core::protocol::Calibration>,
    }

    pub(super) fn build(args: &HeadOptions) -> Result<Built, SimulateError> {
        let cfg = sim_config(args)?;
        let scene = Scene::new(cfg).map_err(|e| SimulateError::Usage(format!("scene: {e}")))?;
        if scene.laser_count() != LASERS {
            return Err(SimulateError::Usage(format!("scene: {} lasers; the head has {LASERS}", scene.laser_count())));
        }
        let scales =
            scene.config().optics().scale_range().map_err(|e| SimulateError::Usage(format!("scene optics: {e}")))?;
        let mut detector = Config::new(scene.bits(), scales);
        // The estimator the scene's light calls for (laser light is
        // speckled: the centroid).
        detector.method = scene.config().light.method();
        detector.max_stripes = LASERS as u8;
        detector.select = Select::Strongest;
        cms_core::peak::Detector::<1>::new(detector)
            .map_err(|e| SimulateError::Usage(format!("detector for this scene: {e}")))?;
        let exposure_us = scene.camera().exposure_us.round().clamp(1.0, 1e6) as u32;
        let factory = if args.factory_calibration {
            // The head's own calibration, wherever it stands on the rail
            // (runs of one head across the rail are of one head).
            let at_aim = HeadOptions { lateral_mm: None, ..args.clone() };
            let aimed = Scene::new(sim_config(&at_aim)?).map_err(|e| SimulateError::Usage(format!("scene: {e}")))?;
            let file = crate::sim::calibration::truth::truth(&aimed);
            Some(file.to_head().map_err(|e| SimulateError::Usage(format!("factory calibration: {e}")))?)
        } else {
            None
        };
        let renderer = Threaded::new(SceneCamera::with_tap(scene, args.odometer_tap.clone()))
            .map_err(|e| SimulateError::Io("starting the render thread", e))?;
        Ok(Built { renderer, detector, max_rate_hz: args.rate, exposure_us, factory })
    }

    /// The scene model as the head's row source: frames are exposed at the
    /// odometer the head has travelled to (real time × speed), rounded to
    /// the micrometre the `Profile` reports, so the truth of a received
    /// profile is `Scene::shot_row_truth` of that odometer.
    pub struct SceneCamera {
        scene: Scene,
        shot: Shot,
        tap: Option<Arc<AtomicI64>>,
    }

    impl SceneCamera {
        /// Renders `scene`.
        pub fn new(scene: Scene) -> SceneCamera {
            SceneCamera { shot: scene.shot(0, 0), scene, tap: None }
        }

        /// [`SceneCamera::new`], publishing each frame's odometer (µm) in
        /// `tap` as the frame begins (the simulated GNSS receiver follows it).
        pub fn with_tap(scene: Scene, tap: Option<Arc<AtomicI64>>) -> SceneCamera {
            SceneCamera { tap, ..SceneCamera::new(scene) }
        }

        /// The scene.
        pub fn scene(&self) -> &Scene {
            &self.scene
        }
    }

    impl RowRenderer for SceneCamera {
        fn size(&self) -> (u16, u16) {
            (self.scene.width() as u16, self.scene.height() as u16)
        }
        fn bits(&self) -> u8 {
            self.scene.bits()
        }
        fn begin_frame(&mut self, frame: u64, t_us: u64, exposure_us: u32, mask: u8) -> i64 {
            let at = self.scene.shot_at(frame, t_us as f64, exposure_us as f64, mask);
            let odometer_um = (at.odometer_mm * 1000.0).round() as i64;
            self.shot = Shot { odometer_mm: odometer_um as f64 / 1000.0, ..at };
            if let Some(t) = &self.tap {
                t.store(odometer_um, Ordering::Relaxed);
            }
            odometer_um
        }
        fn row(&mut self, r: u16, out: &mut [u16]) {
            self.scene.render_shot_row(&self.shot, r as usize, out);
        }
        fn cpu(&self) -> std::time::Duration {
            self.scene.light_threads_cpu()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::scene::Scene;

    #[test]
    fn port_sim_shines_laser_light_unless_told() {
        use crate::sim::scene::LightModel;
        let light = |sim: &SimPort| sim_config(&port_options(sim)).unwrap().light;
        assert_eq!(light(&SimPort::default()), LightModel::recommended());
        assert_eq!(light(&SimPort::default()).method(), cms_core::peak::Method::Centroid);
        let told = SimPort { sim_light: Some(LightModel::incoherent()), ..SimPort::default() };
        assert_eq!(light(&told), LightModel::incoherent());
        let paper = SimPort { sim_preset: Some(Preset::Paper), ..SimPort::default() };
        assert_eq!(light(&paper), LightModel::incoherent());
        // A scene built without a light keeps the preset's.
        assert_eq!(sim_config(&HeadOptions::default()).unwrap().light, LightModel::incoherent());
    }

    /// The optics PORT `sim` records are its light's; others given are refused.
    #[test]
    fn port_sim_records_its_own_optics_and_refuses_others() {
        use crate::model::optics::Optics;
        use crate::sim::scene::LightModel;
        let o = |f: f64, nm: f64| Optics::new(f, nm).unwrap();
        // The default light: the recommended head's, at F/1.4.
        let plain = SimPort::default();
        assert_eq!(port_optics(&plain, None).unwrap(), Some(o(1.4, 685.0)));
        assert_eq!(port_optics(&plain, Some(o(1.4, 685.0))).unwrap(), Some(o(1.4, 685.0)));
        assert!(port_optics(&plain, Some(o(2.8, 685.0))).is_err());
        let f4 = SimPort { sim_light: Some(LightModel::speckle(4.0)), ..SimPort::default() };
        assert_eq!(port_optics(&f4, Some(o(4.0, 685.0))).unwrap(), Some(o(4.0, 685.0)));
        let clean = SimPort { sim_light: Some(LightModel::incoherent()), ..SimPort::default() };
        assert_eq!(port_optics(&clean, None).unwrap(), None);
        assert!(port_optics(&clean, Some(o(2.8, 685.0))).is_err());
        let paper = SimPort { sim_preset: Some(Preset::Paper), ..SimPort::default() };
        assert_eq!(port_optics(&paper, None).unwrap(), None);
        let paper_f4 = SimPort { sim_light: Some(LightModel::speckle(4.0)), ..paper };
        assert_eq!(port_optics(&paper_f4, None).unwrap(), None);
        assert_eq!(port_optics(&paper_f4, Some(o(4.0, 685.0))).unwrap(), Some(o(4.0, 685.0)));
    }

    #[test]
    fn counts_are_codes_at_the_chosen_depth() {
        let args = HeadOptions {
            bits: Some(12),
            noise: Some(2.0),
            banding: Some(1.0),
            ambient: Some(40.0),
            laser_gain: Some([1.0, 1.0, 0.5]),
            corrugation: vec![CorrugationSpec { wavelength_mm: 60.0, amplitude_um: 25.0, phase_deg: 180.0 }],
            ..HeadOptions::default()
        };
        let cfg = sim_config(&args).unwrap();
        let g = cfg.camera.gain_e_per_dn();
        assert_eq!(cfg.camera.bits, 12);
        assert!((cfg.noise.read_noise_e - 2.0 * g).abs() < 1e-9);
        assert!((cfg.noise.row_banding_e - g).abs() < 1e-9);
        assert!((cfg.noise.ambient_e_per_us * cfg.camera.exposure_us - 40.0 * g).abs() < 1e-6);
        let preset = SimConfig::reference();
        assert_eq!(cfg.lasers[2].brightness, preset.lasers[2].brightness * 0.5);
        assert_eq!(cfg.rail.corrugation.len(), 1);
        assert!((cfg.rail.corrugation[0].phase_rad - std::f64::consts::PI).abs() < 1e-12);
        // Unset options keep the preset's values.
        let plain = sim_config(&HeadOptions::default()).unwrap();
        assert_eq!(plain.noise, preset.noise);
        assert_eq!(plain.rail, preset.rail);
    }

    #[test]
    fn threaded_rendering_equals_inline() {
        let scene = Scene::new(sim_config(&HeadOptions::default()).unwrap()).unwrap();
        let mut inline = SceneCamera::new(scene.clone());
        let mut threaded = worker::Threaded::new(SceneCamera::new(scene)).unwrap();
        assert_eq!(threaded.size(), (752, 480));
        let (mut a, mut b) = (vec![0u16; 752], vec![0u16; 752]);
        // A frame abandoned half-way must not leak rows into the next.
        threaded.begin_frame(0, 0, 100, 0b111);
        threaded.row(0, &mut b);
        for (frame, t_us) in [(1u64, 12_345u64), (2, 50_000)] {
            let oa = inline.begin_frame(frame, t_us, 100, 0b101);
            let ob = threaded.begin_frame(frame, t_us, 100, 0b101);
            assert_eq!(oa, ob);
            // DEFAULT_SPEED_MM_S mm/s is DEFAULT_SPEED_MM_S / 1000 µm/µs, from 0.
            let want = t_us as f64 * DEFAULT_SPEED_MM_S / 1000.0;
            assert!((oa as f64 - want).abs() <= 1.0, "{oa} µm at {t_us} µs: {want}");
            for r in 0..480 {
                inline.row(r, &mut a);
                threaded.row(r, &mut b);
                assert_eq!(a, b, "frame {frame} row {r}");
            }
        }
        drop(threaded); // joins the worker
    }

    #[test]
    fn lasers_report_what_was_lit() {
        use cms_core::pipeline::LaserDriver as _;
        let mut l = server::SimLasers::default();
        l.set(0b001);
        l.set(0);
        l.set(0b100);
        assert_eq!((l.mask(), l.switches()), (0b100, 3));
    }
}
