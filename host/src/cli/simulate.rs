//! `cms-host simulate`: its arguments, the pty path on stdout and the
//! summary on stderr; and the `--sim-…` options of the commands that take a
//! PORT.

use std::io::{self, Write as _};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::{Args, ValueEnum};
use cms_host::sim::head::{self, CorrugationSpec, HeadOptions, Preset, SimPort, SimulateError};
use cms_host::sim::scene::light::MAX_PATTERNS;
use cms_host::sim::scene::{LightModel, RoughnessSpectrum, RoughnessSpectrumError, Speckle};

/// `--preset`: camera and head geometry.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ValueEnum)]
pub enum PresetArg {
    /// The reference head: 752 × 480 global-shutter sensor, 8 bits.
    #[default]
    Reference,
    /// The geometry of the paper's Table 4 (4752 × 3168).
    Paper,
}

impl From<PresetArg> for Preset {
    fn from(p: PresetArg) -> Preset {
        match p {
            PresetArg::Reference => Preset::Reference,
            PresetArg::Paper => Preset::Paper,
        }
    }
}

fn finite(s: &str, what: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(format!("{what} {s:?} is not a finite number")),
    }
}

fn non_negative(s: &str) -> Result<f64, String> {
    let v = finite(s, "value")?;
    if v < 0.0 {
        return Err(format!("must be ≥ 0, got {v}"));
    }
    Ok(v)
}

fn fraction(s: &str) -> Result<f64, String> {
    let v = finite(s, "fraction")?;
    if !(0.0..=0.1).contains(&v) {
        return Err(format!("must be in 0..=0.1, got {v}"));
    }
    Ok(v)
}

fn finite_mm(s: &str) -> Result<f64, String> {
    finite(s, "length")
}

pub(crate) fn speed(s: &str) -> Result<f64, String> {
    let v = finite(s, "speed")?;
    if v.abs() > 100_000.0 {
        return Err(format!("speed must be within ±100000 mm/s, got {v}"));
    }
    Ok(v)
}

fn bits(s: &str) -> Result<u8, String> {
    match s.trim() {
        "8" => Ok(8),
        "10" => Ok(10),
        "12" => Ok(12),
        _ => Err(format!("bit depth must be 8, 10 or 12, got {s:?}")),
    }
}

/// Arguments of `cms-host simulate`.
#[derive(Args, Clone, Debug)]
pub struct SimulateArgs {
    /// Camera and head geometry.
    #[arg(long, value_enum, default_value_t = PresetArg::Reference)]
    pub preset: PresetArg,
    /// Seed of every random part of the scene (roughness, noise, hot pixels).
    #[arg(long, value_name = "S", default_value_t = 1)]
    pub seed: u64,
    /// The camera's highest frame rate, Hz: the host's `Start` picks the
    /// rate, and one above this is refused (out of range).
    #[arg(long, value_name = "HZ", default_value_t = 30, value_parser = clap::value_parser!(u16).range(1..=1000))]
    pub rate: u16,
    /// Travel speed along the rail, mm/s.
    #[arg(long = "speed-mm-s", value_name = "V", value_parser = speed)]
    pub speed_mm_s: Option<f64>,
    /// A corrugation component (repeat for several).
    #[arg(long, value_name = "WAVELENGTH_MM:AMPLITUDE_UM[:PHASE_DEG]", value_parser = parse_corrugation)]
    pub corrugation: Vec<CorrugationSpec>,
    /// RMS random roughness of the running surface, µm.
    #[arg(long = "roughness-um", value_name = "R", value_parser = non_negative)]
    pub roughness_um: Option<f64>,
    /// A measured roughness spectrum laid on the rail: CSV `wavelength_mm,level_db` (third octaves as EN 15610 and
    /// ISO 3095 report them, dB re 1 µm; a header line, `#` comments), random phases from --seed. The rail is then
    /// the spectrum plus any --corrugation and --roughness-um given (the default rail's are left out).
    #[arg(long = "roughness-spectrum", value_name = "FILE")]
    pub roughness_spectrum: Option<PathBuf>,
    /// Random (read) noise, RMS counts.
    #[arg(long, value_name = "COUNTS", value_parser = non_negative)]
    pub noise: Option<f64>,
    /// Fraction of hot pixels (fixed pattern), 0..=0.1.
    #[arg(long = "hot-pixels", value_name = "FRACTION", value_parser = fraction)]
    pub hot_pixels: Option<f64>,
    /// Row banding, RMS counts.
    #[arg(long, value_name = "COUNTS", value_parser = non_negative)]
    pub banding: Option<f64>,
    /// Ambient light, counts.
    #[arg(long, value_name = "COUNTS", value_parser = non_negative)]
    pub ambient: Option<f64>,
    /// Output bit depth (8, 10 or 12).
    #[arg(long, value_name = "8|10|12", value_parser = bits)]
    pub bits: Option<u8>,
    /// Relative power of the three lasers (multiplies the preset's).
    #[arg(long = "laser-gain", value_name = "A,B,C", value_parser = parse_gains)]
    pub laser_gain: Option<[f64; 3]>,
    /// Directory where the head keeps its calibration across restarts
    /// [default: $CMS_SIM_STATE, else $XDG_STATE_HOME/cms-host/sim-head, else
    /// ~/.local/state/cms-host/sim-head].
    #[arg(long, value_name = "DIR")]
    pub state: Option<PathBuf>,
    /// Start without the factory calibration (pixels only until one is uploaded).
    #[arg(long)]
    pub uncalibrated: bool,
    /// The light on the rail, comma-separated: incoherent (clean stripes), speckle[=F-NUMBER] (laser
    /// speckle through the lens, F/8 if no number), patterns=K (independent speckle patterns, up to 10000: a
    /// broad-area or multimode line source; more than 4 are rendered fast where the speckle is under a pixel, as the
    /// line's expected image with the stripe-centre error their speckle causes, else as 4 with the statistics of K),
    /// exact (many patterns rendered as 4 speckle fields with the statistics of K even so: the reference, slow), focus=MM (where
    /// the lens is focused), scheimpflug (a tilted sensor: the middle laser's plane in focus; scheimpflug=each: a sensor per line, each line in focus), oxidation, grease, band (the running band), glints, ghost (a secondary reflection of the
    /// middle line). Speckle's rendering can cap the frame rate: `cms-host bench render` measures it. [default:
    /// `listen sim`'s: speckle=1.4,patterns=100,scheimpflug on the reference head, the recommended head's light
    /// (speckle=2.8 is the push-trolley setting: one pattern at F/2.8); incoherent on the paper's]
    #[arg(long, value_name = "SPEC", value_parser = parse_light)]
    pub light: Option<LightModel>,
}

impl SimulateArgs {
    /// The simulated head these arguments describe (the roughness
    /// spectrum read and checked).
    pub fn options(&self) -> Result<HeadOptions, RoughnessSpectrumError> {
        Ok(HeadOptions {
            preset: self.preset.into(),
            seed: self.seed,
            rate: self.rate,
            speed_mm_s: self.speed_mm_s,
            corrugation: self.corrugation.clone(),
            roughness_um: self.roughness_um,
            roughness_spectrum: spectrum(self.roughness_spectrum.as_deref())?,
            noise: self.noise,
            hot_pixels: self.hot_pixels,
            banding: self.banding,
            ambient: self.ambient,
            bits: self.bits,
            laser_gain: self.laser_gain,
            state: self.state.clone(),
            factory_calibration: !self.uncalibrated,
            light: Some(self.light.clone().unwrap_or_else(|| head::default_light(self.preset.into()))),
            ..HeadOptions::default()
        })
    }
}

/// Reads a `--roughness-spectrum` file, if one is given.
fn spectrum(path: Option<&std::path::Path>) -> Result<Option<RoughnessSpectrum>, RoughnessSpectrumError> {
    path.map(RoughnessSpectrum::load).transpose()
}

/// Runs `cms-host simulate`: the pty's path as the first line of stdout,
/// served until SIGINT/SIGTERM, a summary on stderr.
pub fn run(args: &SimulateArgs) -> anyhow::Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed))
        .map_err(|e| SimulateError::Io("installing the SIGINT/SIGTERM handler", io::Error::other(e)))?;
    let summary = head::serve_on_new_pty(&args.options()?, &stop, |path| {
        let mut out = io::stdout().lock();
        writeln!(out, "{}", path.display())?;
        out.flush()
    })?;
    let _ = writeln!(io::stderr(), "simulate: {summary}");
    Ok(())
}

/// The simulated head's options inside `cms-host listen` (flatten into the
/// listener's arguments).
#[derive(Args, Clone, Debug, Default)]
pub struct SimPortArgs {
    /// With PORT `sim`: seed of the simulated scene.
    #[arg(long = "sim-seed", value_name = "S")]
    pub sim_seed: Option<u64>,
    /// With PORT `sim`: which run over the same rail (0 first): each run's
    /// camera reads its own noise, the rail (the seed's) is the same.
    #[arg(long = "sim-run", value_name = "N")]
    pub sim_run: Option<u64>,
    /// With PORT `sim`: the head's place across the rail for the run, mm
    /// (within ±15; a trolley's play on the rail head): its lines light
    /// other surface, whose speckle is its own (a repeat run over the same
    /// rail 2.5 mm or more across sees speckle independent of the first's).
    #[arg(long = "sim-lateral-mm", value_name = "Y", allow_hyphen_values = true, value_parser = finite_mm)]
    pub sim_lateral_mm: Option<f64>,
    /// With PORT `sim`: camera and head geometry of the simulated head.
    #[arg(long = "sim-preset", value_enum)]
    pub sim_preset: Option<PresetArg>,
    /// With PORT `sim`: the simulated head's state directory (its kept calibration).
    #[arg(long = "sim-state", value_name = "DIR")]
    pub sim_state: Option<PathBuf>,
    /// With PORT `sim`: travel speed of the simulated head along the rail,
    /// mm/s (1500: frames overlap by ~19 mm at 30 frames/s).
    #[arg(long = "sim-speed-mm-s", value_name = "V", value_parser = speed)]
    pub sim_speed_mm_s: Option<f64>,
    /// With PORT `sim`: a corrugation component of the simulated rail (repeat for several).
    #[arg(long = "sim-corrugation", value_name = "WAVELENGTH_MM:AMPLITUDE_UM[:PHASE_DEG]", value_parser = parse_corrugation)]
    pub sim_corrugation: Vec<CorrugationSpec>,
    /// With PORT `sim`: RMS random roughness of the simulated rail, µm.
    #[arg(long = "sim-roughness-um", value_name = "R", value_parser = non_negative)]
    pub sim_roughness_um: Option<f64>,
    /// With PORT `sim`: a measured roughness spectrum laid on the simulated rail (as `simulate --roughness-spectrum`:
    /// CSV `wavelength_mm,level_db`, third octaves in dB re 1 µm); the rail is then the spectrum plus any
    /// --sim-corrugation and --sim-roughness-um given.
    #[arg(long = "sim-roughness-spectrum", value_name = "FILE")]
    pub sim_roughness_spectrum: Option<PathBuf>,
    /// With PORT `sim`: the simulated head starts without its factory calibration.
    #[arg(long = "sim-uncalibrated")]
    pub sim_uncalibrated: bool,
    /// With PORT `sim`: the light on the simulated rail (as `simulate --light`) [default:
    /// speckle=1.4,patterns=100,scheimpflug, the recommended head's light; speckle=2.8: the push-trolley setting;
    /// `incoherent`: the clean stripes].
    #[arg(long = "sim-light", value_name = "SPEC", value_parser = parse_light_boxed)]
    pub sim_light: Option<Box<LightModel>>,
}

impl SimPortArgs {
    /// The library's options (the roughness spectrum read and checked).
    pub fn options(&self) -> Result<SimPort, RoughnessSpectrumError> {
        Ok(SimPort {
            sim_seed: self.sim_seed,
            sim_run: self.sim_run,
            sim_lateral_mm: self.sim_lateral_mm,
            sim_preset: self.sim_preset.map(Into::into),
            sim_state: self.sim_state.clone(),
            sim_speed_mm_s: self.sim_speed_mm_s,
            sim_corrugation: self.sim_corrugation.clone(),
            sim_roughness_um: self.sim_roughness_um,
            sim_roughness_spectrum: spectrum(self.sim_roughness_spectrum.as_deref())?,
            sim_uncalibrated: self.sim_uncalibrated,
            sim_light: self.sim_light.as_deref().cloned(),
            sim_gnss: None,
        })
    }
}

/// Parses `--light`: comma-separated items (see [`SimulateArgs::light`]);
/// the ranges are checked when the scene is built.
pub(crate) fn parse_light(s: &str) -> Result<LightModel, String> {
    const ITEMS: &str = "incoherent, speckle[=F-NUMBER], patterns=K, exact, focus=MM, scheimpflug[=each], oxidation, grease, band, glints, ghost";
    let mut light = LightModel::incoherent();
    for item in s.split(',').map(str::trim) {
        let (key, value) = item.split_once('=').map_or((item, None), |(k, v)| (k.trim(), Some(v.trim())));
        let number = |what: &str| -> Result<f64, String> {
            let v = value.ok_or_else(|| format!("light {key:?} needs ={what}"))?;
            v.parse::<f64>().ok().filter(|x| x.is_finite()).ok_or_else(|| format!("light {key}={v:?}: not a number"))
        };
        let flag = |l: &mut LightModel, f: fn(&mut LightModel)| {
            if value.is_some() {
                return Err(format!("light {key:?} takes no value"));
            }
            f(l);
            Ok(())
        };
        match key {
            "speckle" => {
                let f_number = if value.is_some() { number("F-NUMBER")? } else { 8.0 };
                let patterns = light.speckle.map_or(1, |s| s.patterns);
                light.speckle = Some(Speckle { f_number, patterns });
            }
            "patterns" => {
                let k = number("K")?;
                if k.fract() != 0.0 || !(1.0..=f64::from(MAX_PATTERNS)).contains(&k) {
                    return Err(format!("light patterns={k}: a whole number in 1..={MAX_PATTERNS}"));
                }
                let f_number = light.speckle.map_or(8.0, |s| s.f_number);
                light.speckle = Some(Speckle { f_number, patterns: k as u32 });
            }
            "incoherent" => flag(&mut light, |l| l.speckle = None)?,
            "focus" => light.focus_mm = Some(number("MM")?),
            "scheimpflug" => match value {
                None => light.scheimpflug = true,
                Some("each") => (light.scheimpflug, light.sensor_per_line) = (true, true),
                Some(v) => {
                    return Err(format!(
                        "light scheimpflug={v:?}: `scheimpflug` (one sensor) or `scheimpflug=each` (a sensor per line)"
                    ));
                }
            },
            "exact" => flag(&mut light, |l| l.exact_speckle = true)?,
            "oxidation" => flag(&mut light, |l| l.oxidation = LightModel::oxidation())?,
            "grease" => flag(&mut light, |l| l.grease = LightModel::grease())?,
            "band" => flag(&mut light, |l| l.band = Some(LightModel::running_band()))?,
            "glints" => flag(&mut light, |l| l.glints = LightModel::glints())?,
            "ghost" => flag(&mut light, |l| l.ghosts.push(LightModel::ghost()))?,
            _ => return Err(format!("unknown light {item:?}; the items are {ITEMS}")),
        }
    }
    Ok(light)
}

/// [`parse_light`], boxed (the option sits in every PORT command's arguments).
fn parse_light_boxed(s: &str) -> Result<Box<LightModel>, String> {
    parse_light(s).map(Box::new)
}

/// Parses `--corrugation`.
fn parse_corrugation(s: &str) -> Result<CorrugationSpec, String> {
    let parts: Vec<&str> = s.split(':').collect();
    if !(2..=3).contains(&parts.len()) {
        return Err("expected WAVELENGTH_MM:AMPLITUDE_UM[:PHASE_DEG], e.g. 50:30 or 50:30:90".into());
    }
    let wavelength_mm = finite(parts[0], "wavelength")?;
    let amplitude_um = finite(parts[1], "amplitude")?;
    let phase_deg = parts.get(2).map_or(Ok(0.0), |p| finite(p, "phase"))?;
    if wavelength_mm <= 0.0 {
        return Err(format!("wavelength must be > 0 mm, got {wavelength_mm}"));
    }
    if !(0.0..=10_000.0).contains(&amplitude_um) {
        return Err(format!("amplitude must be in 0..=10000 µm, got {amplitude_um}"));
    }
    Ok(CorrugationSpec { wavelength_mm, amplitude_um, phase_deg })
}

/// Parses `--laser-gain a,b,c`.
fn parse_gains(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<&str> = s.split(',').collect();
    if v.len() != 3 {
        return Err(format!("expected three comma-separated gains (one per laser), got {}", v.len()));
    }
    let mut g = [0.0; 3];
    for (o, p) in g.iter_mut().zip(v) {
        *o = finite(p, "gain")?;
        if !(0.0..=100.0).contains(o) {
            return Err(format!("gain must be in 0..=100, got {o}"));
        }
    }
    Ok(g)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corrugation_and_gains_parse_or_explain() {
        let c = parse_corrugation("50:30:90").unwrap();
        assert_eq!((c.wavelength_mm, c.amplitude_um, c.phase_deg), (50.0, 30.0, 90.0));
        assert_eq!(parse_corrugation(" 80 : 5 ").unwrap().phase_deg, 0.0);
        for bad in ["", "50", "50:30:1:2", "0:30", "-5:30", "50:-1", "50:nan", "inf:3", "50:30:x"] {
            assert!(parse_corrugation(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_gains("1,0.5,2").unwrap(), [1.0, 0.5, 2.0]);
        for bad in ["1,2", "1,2,3,4", "1,x,1", "1,-1,1", "1,nan,1"] {
            assert!(parse_gains(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn option_values_parse_or_explain() {
        assert!(bits("10").is_ok() && bits("9").is_err() && bits("16").is_err());
        assert!(fraction("0.01").is_ok() && fraction("0.2").is_err());
        assert!(non_negative("0").is_ok() && non_negative("-1").is_err());
        assert!(speed("-500").is_ok() && speed("1e9").is_err());
    }

    /// `simulate` without `--light` renders `listen sim`'s default light.
    #[test]
    fn simulate_shines_the_default_light() {
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            args: SimulateArgs,
        }
        let light = |args: &[&str]| {
            let cli = <Cli as clap::Parser>::try_parse_from(std::iter::once("simulate").chain(args.iter().copied()));
            cli.unwrap().args.options().unwrap().light.unwrap()
        };
        assert_eq!(light(&[]), head::default_light(Preset::Reference));
        assert_eq!(light(&[]), LightModel::recommended());
        assert_eq!(light(&["--preset", "paper"]), head::default_light(Preset::Paper));
        assert_eq!(light(&["--light", "incoherent"]), LightModel::incoherent());
    }

    #[test]
    fn light_parses_or_explains() {
        let l = parse_light("speckle=4, patterns=3,oxidation,ghost,focus=230").unwrap();
        assert_eq!(l.speckle, Some(Speckle { f_number: 4.0, patterns: 3 }));
        assert_eq!((l.oxidation, l.ghosts.len(), l.focus_mm), (LightModel::oxidation(), 1, Some(230.0)));
        assert_eq!(parse_light("speckle").unwrap().speckle, Some(Speckle { f_number: 8.0, patterns: 1 }));
        assert!(parse_light("glints,band,grease").unwrap().speckle.is_none());
        assert_eq!(parse_light("speckle=4,incoherent").unwrap(), LightModel::incoherent());
        for bad in
            ["", "laser", "speckle=x", "focus", "patterns=1.5", "patterns=0", "glints=2", "speckle=nan", "incoherent=1"]
        {
            assert!(parse_light(bad).is_err(), "{bad}");
        }
    }
}
