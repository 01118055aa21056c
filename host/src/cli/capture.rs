//! `cms-host capture PORT --out frame.png`: its arguments and the line it prints.

use std::path::PathBuf;

use cms_core::protocol::LASERS;
use cms_host::device::capture::{self, Options};
use cms_host::sim::head;

use super::simulate::SimPortArgs;

use super::exit::Usage;

/// Arguments of `capture`.
#[derive(clap::Args, Debug, Clone)]
pub struct CaptureArgs {
    /// Serial port of the head (`/dev/ttyACM0`), or `sim` for the simulated head.
    #[arg(value_name = "PORT")]
    pub port: String,
    /// Where to write the image (PNG).
    #[arg(long, value_name = "FILE.png")]
    pub out: PathBuf,
    /// Lasers lit during the exposure, as a bit mask (0 = none, 7 = all three).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u8).range(0..(1 << LASERS)))]
    pub lasers: u8,
    /// Exposure, µs (default: the head's own).
    #[arg(long = "exposure", value_name = "US")]
    pub exposure_us: Option<u32>,
    /// Baud rate (ignored by USB CDC heads).
    #[arg(long, default_value_t = 115_200)]
    pub baud: u32,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub sim: SimPortArgs,
}

/// Runs `capture`.
pub fn run(args: &CaptureArgs) -> anyhow::Result<()> {
    if args.out.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() != Some("png") {
        anyhow::bail!(Usage(format!("--out {}: the image is written as PNG; name it *.png", args.out.display())));
    }
    // Before the head lights its lasers for nothing.
    cms_host::output::check_target(&args.out)?;
    let opts = Options { lasers: args.lasers, exposure_us: args.exposure_us, baud: args.baud };
    let frame = head::with_port(&args.port, &args.sim.options()?, |port| capture::capture(port, &opts))??;
    capture::save_png(&frame, &args.out)?;
    println!(
        "{}: {}×{} px, {} bit, lasers {:#05b}",
        args.out.display(),
        frame.width,
        frame.height,
        frame.bits,
        args.lasers
    );
    Ok(())
}
