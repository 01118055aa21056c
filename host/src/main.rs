//! `cms-host`: the command-line front end. A thin dispatcher: each
//! subcommand's arguments and work live in its own module (`detect` in the
//! library, `bench` beside this file).

use std::io::Write as _;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use cms_host::analyze;
use cms_host::calib;
use cms_host::capture;
use cms_host::detect;
use cms_host::fit;
use cms_host::measure;
use cms_host::simulate;
use cms_host::{CliError, qemu};
use cms_host::{listen, record};

mod bench;

/// Host tools of the rail corrugation measurement system.
#[derive(Parser, Debug)]
#[command(name = "cms-host", version, about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Find the laser stripes of every image row and print them as CSV.
    Detect(detect::DetectArgs),
    /// Accuracy and speed of the detection methods.
    #[command(subcommand)]
    Bench(bench::BenchCmd),
    /// Stream profiles from a sensor head: live status, --json, --record.
    Listen {
        #[command(flatten)]
        args: listen::ListenArgs,
        #[command(flatten)]
        sim: simulate::SimPortArgs,
        #[command(flatten)]
        qemu: qemu::QemuPortArgs,
    },
    /// Export the profiles of a recording as CSV or JSON lines.
    Export(record::ExportArgs),
    /// Describe a recording: frames, time and distance spans, lasers, device, damage.
    Info(record::InfoArgs),
    /// Simulated sensor head on a pseudo-terminal (prints its path first).
    Simulate(simulate::SimulateArgs),
    /// Fit a sine (the paper's rotated sine by default) to a profile x_mm,z_mm.
    Fit(fit::FitArgs),
    /// Stitch a recording along the track; EN 13231-3 bands, EN 15610 roughness; --report DIR.
    Analyze(analyze::AnalyzeArgs),
    /// One full frame from a sensor head (or `sim`) as a PNG: what the sensor sees.
    Capture(capture::CaptureArgs),
    /// Corrugation per image or recorded frame: each laser's profile and rotated-sine fit, the joint fit of the
    /// three lines with the surface-normal correction, optional plots.
    Measure(measure::MeasureArgs),
    /// Camera and laser-plane calibration; upload to a head.
    #[command(subcommand)]
    Calibrate(calib::CalibrateCmd),
}

fn main() -> ExitCode {
    match Cli::parse().command {
        Command::Detect(args) => match detect::run(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => e.report(),
        },
        // PORT `sim` starts the simulated head on a pty of this process,
        // PORT `qemu` the emulated one in QEMU.
        Command::Listen { args, sim, qemu } => match qemu::with_port(&args.port, &qemu, |port| {
            simulate::with_port(port, &sim, |port| {
                listen::run(&listen::ListenArgs { port: port.to_string(), ..args.clone() })
            })
        }) {
            Ok(Ok(Ok(()))) => ExitCode::SUCCESS,
            Ok(Ok(Err(e))) => e.report(),
            Ok(Err(e)) => e.report(),
            Err(e) => CliError::from(e).report(),
        },
        Command::Export(args) => match record::export(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => e.report(),
        },
        Command::Info(args) => match record::info(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => e.report(),
        },
        Command::Bench(cmd) => match bench::run(cmd) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                let _ = writeln!(std::io::stderr(), "error: {e:#}");
                ExitCode::FAILURE
            }
        },
        Command::Simulate(args) => match simulate::run(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => e.report(),
        },
        Command::Fit(args) => match fit::run(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => e.report(),
        },
        Command::Analyze(args) => match analyze::run(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => e.report(),
        },
        Command::Capture(args) => match capture::run(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => e.report(),
        },
        Command::Measure(args) => match measure::run(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => e.report(),
        },
        Command::Calibrate(cmd) => match calib::run(&cmd) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => e.report(),
        },
    }
}
