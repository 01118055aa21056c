//! `cms-host export` and `cms-host info`: their arguments and output.

use super::progress::Bar;
use std::io::{self, BufWriter, Write as _};
use std::path::PathBuf;

use clap::{Args, ValueEnum};
use cms_host::Error;
use cms_host::output;
use cms_host::recording::{self, ExportFormat};

use super::exit::Usage;

/// `--format` of `cms-host export`.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FormatArg {
    /// One line per point: `seq,part,timestamp_us,odometer_mm,laser,row,position_px,strength,width_px,flags,along_mm,height_um`.
    Csv,
    /// One JSON object per profile message, as `listen --json`.
    Jsonl,
    /// The run's GNSS track and fixes as GeoJSON (a recording made with `listen --gnss`).
    Geojson,
    /// The event marks, CSV: `kind,text,odometer_mm,seq,head_us,host_us,after_us`.
    Marks,
}

impl From<FormatArg> for ExportFormat {
    fn from(f: FormatArg) -> ExportFormat {
        match f {
            FormatArg::Csv => ExportFormat::Csv,
            FormatArg::Jsonl => ExportFormat::Jsonl,
            FormatArg::Geojson => ExportFormat::Geojson,
            FormatArg::Marks => ExportFormat::Marks,
        }
    }
}

/// Arguments of `cms-host export`.
#[derive(Args, Debug, Clone)]
pub struct ExportArgs {
    /// A recording made by `cms-host listen --record`.
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
    /// Output format.
    #[arg(long, value_enum)]
    pub format: FormatArg,
    /// Write here instead of stdout (`-`: stdout); a regular file, replaced whole.
    #[arg(long, value_name = "OUT")]
    pub out: Option<PathBuf>,
}

/// `cms-host export`.
pub fn export(args: &ExportArgs) -> anyhow::Result<()> {
    // Validate the recording before creating the output file.
    recording::check_header(&args.file)?;
    let stats = match &args.out {
        Some(o) if recording::same_file(o, &args.file) => {
            anyhow::bail!(Usage(format!("--out {} is the recording itself; refusing to overwrite it", o.display())));
        }
        Some(o) if !output::is_stdout(o) => {
            // Written atomically: a failed export leaves no half file.
            output::check_target(o)?;
            let mut stats = None;
            let mut failed = None;
            output::write_atomically(o, |w| {
                match recording::export_to(&args.file, args.format.into(), w, &Bar::stderr()) {
                    Ok(s) => {
                        stats = Some(s);
                        Ok(())
                    }
                    Err(e) => {
                        failed = Some(e);
                        Err(io::Error::other("export failed"))
                    }
                }
            })
            .map_err(|e| match failed.take() {
                Some(r) => anyhow::Error::from(r),
                None => e.into(),
            })?;
            stats.expect("the export ran")
        }
        _ => {
            let stdout = io::stdout();
            recording::export_to(&args.file, args.format.into(), &mut BufWriter::new(stdout.lock()), &Bar::stderr())?
        }
    };
    for w in recording::warnings(&args.file, &stats) {
        let _ = writeln!(io::stderr(), "{w}");
    }
    Ok(())
}

/// Arguments of `cms-host info`.
#[derive(Args, Debug, Clone)]
pub struct InfoArgs {
    /// A recording made by `cms-host listen --record`.
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
}

/// `cms-host info`.
pub fn info(args: &InfoArgs) -> anyhow::Result<()> {
    let info = recording::Info::of_file(&args.file, &Bar::stderr())?;
    let mut out = io::stdout().lock();
    out.write_all(info.report(&args.file).as_bytes()).map_err(Error::Output)?;
    out.flush().map_err(Error::Output)?;
    Ok(())
}
