//! `cms-host measure`: its arguments, and each result as text or JSON.

use std::io::{self, BufWriter, Write};
use std::path::PathBuf;

use clap::Args;
use cms_host::Error;
use cms_host::calib::file::CalibrationFile;
use cms_host::measure::image::MethodChoice;
use cms_host::measure::verdict::Level;
use cms_host::measure::{self, Measurer};

/// Arguments of `cms-host measure`.
#[derive(Args, Debug, Clone)]
pub struct MeasureArgs {
    /// Calibration file (camera, datum, three lasers, and [head] for images).
    #[arg(long, value_name = "cal.toml")]
    pub calibration: PathBuf,

    /// One JSON object per image or frame per line on stdout, with the profiles.
    #[arg(long)]
    pub json: bool,

    /// Write NAME.svg and NAME.png per image or frame into DIR (created if needed).
    #[arg(long, value_name = "DIR")]
    pub plot: Option<PathBuf>,

    /// Exit with status 1 unless every result's verdict is good (after printing them all).
    #[arg(long)]
    pub strict: bool,

    /// The images' sub-pixel method: `auto` (by the light the image shows:
    /// `centroid` for a speckled laser line, `cwt` otherwise) or a method's
    /// name as `detect --method` takes it.
    #[arg(long, default_value = "auto", value_name = "METHOD", value_parser = choice_parser())]
    pub method: MethodChoice,

    /// Images (PNG, TIFF, JPEG, CSV rows) or recordings (.cmsrec).
    #[arg(required = true, value_name = "INPUT")]
    pub inputs: Vec<PathBuf>,
}

/// Runs `cms-host measure`.
pub fn run(args: &MeasureArgs) -> anyhow::Result<()> {
    let cal_name = args.calibration.display();
    // The file's own errors name it.
    let cal = CalibrationFile::load(&args.calibration).map_err(Error::from)?;
    let m = Measurer::new(&cal).map_err(|e| Error::Input(format!("{cal_name}: {e}")))?;
    if let Some(dir) = &args.plot {
        std::fs::create_dir_all(dir).map_err(|e| Error::Input(format!("--plot {}: {e}", dir.display())))?;
    }
    let mut out = BufWriter::new(io::stdout().lock());
    let (mut all, mut not_good) = (0usize, 0usize);
    for path in &args.inputs {
        let (results, warnings) =
            measure::measure_file(&m, path, &cal_name.to_string(), args.method, &super::progress::Bar::stderr())?;
        for w in warnings {
            // Not eprintln!: it panics if stderr is closed.
            let _ = writeln!(io::stderr(), "{w}");
        }
        for r in &results {
            all += 1;
            not_good += usize::from(r.level() != Level::Good);
            if args.json {
                serde_json::to_writer(&mut out, r).map_err(|e| Error::Output(e.into()))?;
                writeln!(out).map_err(Error::Output)?;
            } else {
                measure::write_text(&mut out, r).map_err(Error::Output)?;
            }
            if let Some(dir) = &args.plot {
                let stem = path.file_stem().map_or_else(|| "input".into(), |s| s.to_string_lossy().into_owned());
                let stem = match r.seq {
                    Some(seq) => format!("{stem}-frame{seq}"),
                    None => stem,
                };
                measure::plot(&dir.join(stem), r).map_err(|e| Error::Input(format!("--plot: {e}")))?;
            }
        }
    }
    out.flush().map_err(Error::Output)?;
    if args.strict && not_good > 0 {
        // Exit status 1: the inputs were sound, the results are not to be trusted.
        anyhow::bail!("--strict: {not_good} of {all} results are not good (see their verdicts)");
    }
    Ok(())
}

fn choice_parser() -> impl clap::builder::TypedValueParser<Value = MethodChoice> {
    use clap::builder::TypedValueParser as _;
    let names = std::iter::once("auto").chain(cms_core::peak::Method::ALL.map(cms_core::peak::Method::name));
    clap::builder::PossibleValuesParser::new(names).try_map(|s| match s.as_str() {
        "auto" => Ok(MethodChoice::Auto),
        name => cms_core::peak::Method::from_name(name)
            .map(MethodChoice::Fixed)
            .ok_or_else(|| format!("unknown method `{name}`")),
    })
}
