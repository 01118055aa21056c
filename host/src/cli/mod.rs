//! The command line: clap arguments, printing, progress bars and exit
//! statuses over the `cms_host` library, which knows none of them (as
//! stabilizer keeps `bin/` over `hardware/`). One module per subcommand;
//! [`exit`] maps failures to statuses in one place.

pub mod analyze;
pub mod bench;
pub mod calibrate;
pub mod capture;
pub mod detect;
pub mod exit;
pub mod fit;
pub mod listen;
pub mod locate;
pub mod measure;
pub mod progress;
pub mod qemu;
pub mod record;
pub mod simulate;
pub mod trend;
pub mod view;

use std::process::ExitCode;

use anyhow::Result;
use clap::{Parser, Subcommand};

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
    /// A recording in the browser: the stitched profile along the track with zoom, zones, blocks, marks,
    /// the frames to scrub through; the figures of `analyze`.
    View(view::ViewArgs),
    /// One full frame from a sensor head (or `sim`) as a PNG: what the sensor sees.
    Capture(capture::CaptureArgs),
    /// Corrugation per image or recorded frame: each laser's profile and rotated-sine fit, the joint fit of the
    /// three lines with the surface-normal correction, optional plots.
    Measure(measure::MeasureArgs),
    /// A recording's GNSS fixes on a track register: chainage from GNSS, checked against the odometer and
    /// the survey.
    Locate(locate::LocateArgs),
    /// Surveys of one site at different dates: each block's growth per year per EN 13231-3 band, and when
    /// it will cross the limit.
    Trend(trend::TrendArgs),
    /// Camera and laser-plane calibration; upload to a head.
    #[command(subcommand)]
    Calibrate(calibrate::CalibrateCmd),
}

/// Parses the command line, runs the subcommand and reports its failure.
pub fn main() -> ExitCode {
    match dispatch(Cli::parse().command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => exit::report(&e),
    }
}

fn dispatch(command: Command) -> Result<()> {
    match command {
        Command::Detect(args) => detect::run(&args),
        // PORT `sim` starts the simulated head on a pty of this process,
        // PORT `qemu` the emulated one in QEMU.
        Command::Listen { args, sim, qemu } => {
            // Ctrl-C from here on stops the listener (and then QEMU) instead of
            // ending this process with QEMU left running in its own process group.
            let stop = listen::interrupt_flag();
            let mut sim_port = sim.options()?;
            if args.gnss.as_deref() == Some("sim") {
                sim_port.sim_gnss = Some(cms_host::sim::gnss::GnssSimOptions::built_in(sim_port.sim_seed.unwrap_or(1)));
            }
            // The simulated head records the optics it renders with (other
            // optics given are refused before it starts).
            let optics = match args.port.as_str() {
                "sim" => cms_host::sim::head::port_optics(&sim_port, args.optics)?,
                _ => args.optics,
            };
            // The certificate is read before a head starts, so that a bad
            // one is the only thing said.
            let tls = view::serve_tls(args.serve_tls.as_deref())?;
            Ok(cms_host::device::qemu::with_port(&args.port, &qemu.options(), stop, |port| {
                cms_host::sim::head::with_ports(port, &sim_port, |port, gnss| {
                    let gnss = gnss.map(str::to_string).or(args.gnss.clone());
                    listen::run(&listen::ListenArgs { port: port.to_string(), gnss, optics, ..args.clone() }, tls)
                })
            })???)
        }
        Command::Export(args) => record::export(&args),
        Command::Info(args) => record::info(&args),
        Command::Bench(cmd) => bench::run(cmd),
        Command::Simulate(args) => simulate::run(&args),
        Command::Fit(args) => fit::run(&args),
        Command::Analyze(args) => analyze::run(&args),
        Command::View(args) => view::run(&args),
        Command::Capture(args) => capture::run(&args),
        Command::Measure(args) => measure::run(&args),
        Command::Locate(args) => locate::run(&args),
        Command::Trend(args) => trend::run(&args),
        Command::Calibrate(cmd) => calibrate::run(&cmd),
    }
}
