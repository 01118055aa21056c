//! `cms-host fit`: its arguments, and the fit as text or JSON on stdout.

use std::io::{self, BufWriter, Write};
use std::path::PathBuf;

use clap::{Args, ValueEnum};
use cms_host::Error;

use super::exit::Usage;
use cms_host::measure::fit::{Fit, FitMethod, Model, Options, Start, fit, fit_jacquelin, parse_profile};

/// `--model`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModelArg {
    /// The paper's sine in a frame rotated by the unknown sensor rotation.
    Rotated,
    /// IEEE Std 1057 four-parameter sine (no rotation).
    Sine,
}

impl From<ModelArg> for Model {
    fn from(m: ModelArg) -> Model {
        match m {
            ModelArg::Rotated => Model::Rotated,
            ModelArg::Sine => Model::Sine,
        }
    }
}

/// `--method`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// Least squares: the best of several starts refined by Levenberg–Marquardt (the default).
    Lsq,
    /// Jacquelin's non-iterative integral-equation regression, not refined
    /// (model `sine`, one component only).
    Jacquelin,
}

/// Arguments of `cms-host fit`.
#[derive(Args, Debug, Clone)]
pub struct FitArgs {
    /// `rotated`: the paper's sine with the sensor rotation as an unknown; `sine`: IEEE 1057 four-parameter sine.
    #[arg(long, value_enum, default_value_t = ModelArg::Rotated)]
    pub model: ModelArg,

    /// Number of sine components (1..=8), dominant first.
    #[arg(long, default_value = "1", value_name = "N", value_parser = clap::value_parser!(u8).range(1..=8))]
    pub components: u8,

    /// `lsq` (default): least squares, the best of the DFT, ellipse, Jacquelin and scan starts refined by
    /// Levenberg–Marquardt; `jacquelin`: Jacquelin's non-iterative integral-equation estimate as is, not the
    /// least-squares optimum (needs `--model sine` and one component).
    #[arg(long, value_enum, default_value_t = MethodArg::Lsq)]
    pub method: MethodArg,

    /// One JSON object on stdout instead of text.
    #[arg(long)]
    pub json: bool,

    /// CSV with columns x_mm,z_mm (header optional).
    #[arg(value_name = "PROFILE.csv")]
    pub profile: PathBuf,
}

/// Runs `cms-host fit`.
pub fn run(args: &FitArgs) -> anyhow::Result<()> {
    let path = args.profile.display();
    let bytes = cms_host::input::read_capped(&args.profile, cms_host::input::MAX_INPUT_BYTES)?;
    let profile = parse_profile(&String::from_utf8_lossy(&bytes)).map_err(|e| Error::Input(format!("{path}: {e}")))?;
    let model = args.model.into();
    let opts = Options { model, components: usize::from(args.components) };
    let fit = match args.method {
        MethodArg::Lsq => fit(&profile.x_mm, &profile.z_mm, &opts),
        MethodArg::Jacquelin if model != Model::Sine || args.components != 1 => {
            anyhow::bail!(Usage("--method jacquelin needs --model sine and --components 1".into()));
        }
        MethodArg::Jacquelin => fit_jacquelin(&profile.x_mm, &profile.z_mm),
    }
    .map_err(|e| Error::Input(format!("{path}: {e}")))?;
    let mut out = BufWriter::new(io::stdout().lock());
    if args.json {
        serde_json::to_writer(&mut out, &fit).map_err(io::Error::from)?;
        writeln!(out)?;
    } else {
        write_text(&mut out, &fit)?;
    }
    out.flush()?;
    Ok(())
}

/// The human-readable report.
pub fn write_text(out: &mut impl Write, f: &Fit) -> io::Result<()> {
    let pm = |s: Option<f64>| s.map_or_else(String::new, |s| format!(" ± {s:.3e}"));
    let model = match f.model {
        Model::Rotated => "rotated sine",
        Model::Sine => "sine (IEEE 1057)",
    };
    let method = match f.method {
        FitMethod::Lsq => "least squares",
        FitMethod::Jacquelin => "Jacquelin (non-iterative)",
    };
    writeln!(out, "model        {model}, {method}, {} points, {} component(s)", f.points, f.components.len())?;
    let d = &f.components[0];
    writeln!(out, "omega        {:.6} rad/mm", d.omega_rad_per_mm)?;
    writeln!(out, "wavelength   {:.6} mm{}", f.wavelength_mm, pm(f.wavelength_sigma_mm))?;
    writeln!(out, "amplitude    {:.6} mm{}", f.amplitude_mm, pm(f.amplitude_sigma_mm))?;
    writeln!(out, "phase        {:.6} rad{}", f.phase_rad, pm(f.phase_sigma_rad))?;
    writeln!(out, "sin, cos     {:.6} mm, {:.6} mm", d.sin_mm, d.cos_mm)?;
    writeln!(out, "offset       {:.6} mm{}", f.offset_mm, pm(f.offset_sigma_mm))?;
    writeln!(out, "rotation     {:.6} rad{}", f.rotation_rad, pm(f.rotation_sigma_rad))?;
    writeln!(out, "rms residual {:.6} mm", f.rms_residual_mm)?;
    for (i, c) in f.components.iter().enumerate().skip(1) {
        writeln!(
            out,
            "component {}  wavelength {:.6} mm{}, amplitude {:.6} mm{}, phase {:.6} rad",
            i + 1,
            c.wavelength_mm,
            pm(c.wavelength_sigma_mm),
            c.amplitude_mm,
            pm(c.amplitude_sigma_mm),
            c.phase_rad
        )?;
    }
    let start = match f.start {
        Start::Dft => "DFT peak",
        Start::Ellipse => "ellipse method",
        Start::Scan => "residual scan",
        Start::Jacquelin => "Jacquelin's estimate",
    };
    writeln!(
        out,
        "iterations   {} ({}), start: {start}",
        f.iterations,
        if f.converged { "converged" } else { "not converged" }
    )
}
