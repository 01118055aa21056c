//! `cms-host detect`: the laser stripes of every row of one or more images,
//! as CSV on stdout.
//!
//! ```text
//! source,row,stripe,position_px,strength,width_px,flags
//! examples/stripes.png,0,0,181.23456,1497,2.01234,
//! ```
//!
//! One line per stripe; `row` is the 0-based row (the column with
//! `--axis columns`), `stripe` the 0-based index in ascending position,
//! positions and widths in pixels with 5 decimals, `strength` in counts above
//! the background, `flags` a `|`-joined subset of `saturated`, `clipped`,
//! `low-confidence`. A row without stripe prints nothing.
//!
//! Inputs are processed in order; the first bad one stops the run with a
//! one-line `error: ` message naming it and exit status 2 (lines already
//! printed for earlier inputs stay). Each input is read and checked whole
//! before any of its lines is printed.

use std::io::{self, BufWriter, Write};
use std::path::PathBuf;

use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::{Args, ValueEnum};
use cms_core::fixed::Px;
use cms_core::optics::ScaleRange;
use cms_core::peak::{Config, Detector, Error as DetectError, Flags, Method, Select, Stripes};

use crate::CliError;
use crate::input::{self, Row};

/// Longest row the detector takes, pixels.
pub const MAX_ROW: usize = 8192;
/// Most stripes reported per row (the output buffer's capacity).
pub const MAX_STRIPES: usize = 16;
/// The CSV header.
pub const HEADER: &str = "source,row,stripe,position_px,strength,width_px,flags";

/// Arguments of `cms-host detect`.
#[derive(Args, Debug, Clone)]
pub struct DetectArgs {
    /// Sub-pixel estimator.
    #[arg(long, default_value = "cwt", value_parser = method_parser())]
    pub method: Method,

    /// Stripe widths to look for (Gaussian σ, px), as MIN:MAX with 1 ≤ MIN < MAX ≤ 24.
    #[arg(long, default_value = "1.5:4", value_name = "MIN:MAX", value_parser = parse_scales)]
    pub scales: ScaleRange,

    /// Most stripes reported per row (1..=16).
    #[arg(long, default_value = "3", value_name = "N", value_parser = parse_stripes)]
    pub stripes: u8,

    /// Which stripes a row reports when it has more than N (`all`: up to 16).
    #[arg(long, value_enum, default_value_t = SelectArg::Strongest)]
    pub select: SelectArg,

    /// Detect along image rows, or along columns (each column is a row).
    #[arg(long, value_enum, default_value_t = Axis::Rows)]
    pub axis: Axis,

    /// Bit depth of the pixels, 8..=16 (sets the saturation level 2^B − 1).
    /// Default: 8 or 16 for an image (its container), for CSV the smallest of
    /// 8, 10, 12, 14, 16 that holds the file's largest value.
    #[arg(long, value_name = "B", value_parser = clap::value_parser!(u8).range(8..=16))]
    pub bits: Option<u8>,

    /// Detection threshold in multiples of the robust noise σ (0 < SIGMA < 256).
    #[arg(long, default_value = "6", value_name = "SIGMA", value_parser = parse_threshold)]
    pub threshold: Threshold,

    /// Grayscale PNG or TIFF (8 or 16 bit), or CSV of rows (.csv).
    #[arg(required = true, value_name = "INPUT")]
    pub inputs: Vec<PathBuf>,
}

/// `--select`.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SelectArg {
    /// The N strongest.
    Strongest,
    /// The N nearest the row's start.
    First,
    /// The N nearest the row's end.
    Last,
    /// Every stripe (up to 16; the strongest if more).
    All,
}

impl From<SelectArg> for Select {
    fn from(s: SelectArg) -> Select {
        match s {
            SelectArg::Strongest => Select::Strongest,
            SelectArg::First => Select::First,
            SelectArg::Last => Select::Last,
            SelectArg::All => Select::All,
        }
    }
}

/// `--axis`.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    /// Each image row is a detector row.
    Rows,
    /// Each image column is a detector row (the image is transposed).
    Columns,
}

/// `--threshold`, in multiples of the noise σ, Q8.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Threshold(pub u16);

fn method_parser() -> impl TypedValueParser<Value = Method> {
    PossibleValuesParser::new(Method::ALL.map(Method::name))
        .try_map(|s| Method::from_name(&s).ok_or_else(|| format!("unknown method `{s}`")))
}

/// Parses `MIN:MAX` (stripe σ, px) into a scale range the detector accepts.
pub fn parse_scales(s: &str) -> Result<ScaleRange, String> {
    let usage = || format!("expected MIN:MAX, two positive numbers of pixels such as 1.5:4, got `{s}`");
    let (a, b) = s.split_once(':').ok_or_else(usage)?;
    let min: f64 = a.trim().parse().map_err(|_| usage())?;
    let max: f64 = b.trim().parse().map_err(|_| usage())?;
    if !(min.is_finite() && max.is_finite() && min > 0.0 && max > 0.0) {
        return Err(usage());
    }
    if Px::from_f64(min).0 <= 0 {
        return Err(format!("MIN {min} px is below the detector's resolution (1/65536 px)"));
    }
    let range = ScaleRange::new(Px::from_f64(min), Px::from_f64(max)).map_err(|e| e.to_string())?;
    // The scale limits (1..=24 px) are the detector's: ask it.
    Detector::<{ cms_core::peak::MIN_ROW }>::new(Config::new(16, range)).map_err(|e| e.to_string())?;
    Ok(range)
}

fn parse_stripes(s: &str) -> Result<u8, String> {
    let n: u64 = s.trim().parse().map_err(|_| format!("expected a whole number of stripes, got `{s}`"))?;
    match n {
        0 => Err("at least 1 stripe per row".into()),
        n if n > MAX_STRIPES as u64 => {
            Err(format!("at most {MAX_STRIPES} stripes per row (the output's capacity), got {n}"))
        }
        n => Ok(n as u8),
    }
}

fn parse_threshold(s: &str) -> Result<Threshold, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("expected a number of noise σ, got `{s}`"))?;
    let q8 = (v * 256.0).round();
    if !(v.is_finite() && v > 0.0 && (1.0..=u16::MAX as f64).contains(&q8)) {
        return Err(format!("threshold must be above 0 and below 256 σ, got {s}"));
    }
    Ok(Threshold(q8 as u16))
}

impl DetectArgs {
    /// The detector configuration for pixels `bits` deep.
    pub fn config(&self, bits: u8) -> Config {
        let mut cfg = Config::new(bits, self.scales);
        cfg.method = self.method;
        cfg.select = self.select.into();
        cfg.max_stripes = self.stripes;
        cfg.threshold_sigma_q8 = self.threshold.0;
        cfg
    }
}

/// The option a configuration error is about, for the message.
fn option_of(e: &DetectError) -> &'static str {
    match e {
        DetectError::BitDepth(_) | DetectError::Saturation => "--bits",
        DetectError::ScaleTooSmall | DetectError::ScaleTooLarge | DetectError::WidthRange => "--scales",
        DetectError::MaxStripes => "--stripes",
        DetectError::Threshold => "--threshold",
        _ => "options",
    }
}

fn detector(args: &DetectArgs, bits: u8) -> Result<Box<Detector<MAX_ROW>>, CliError> {
    // Detector<8192> holds 128 KiB of buffers: build it on the heap.
    Detector::<MAX_ROW>::new(args.config(bits))
        .map(Box::new)
        .map_err(|e| CliError::Usage(format!("invalid {}: {e}", option_of(&e))))
}

/// The flag names, `|`-joined (empty for none).
pub fn flag_names(flags: Flags) -> String {
    let mut names: Vec<String> = flags.names().map(String::from).collect();
    let known = Flags::NAMES.iter().fold(0, |m, (f, _)| m | f.0);
    for b in 0..8 {
        if flags.0 & !known & (1 << b) != 0 {
            names.push(format!("flag{b}"));
        }
    }
    names.join("|")
}

/// A CSV field: quoted (RFC 4180) if it holds a comma, quote or line break.
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

/// Runs `cms-host detect` with stdout as the output.
pub fn run(args: &DetectArgs) -> Result<(), CliError> {
    let stdout = io::stdout();
    let mut out = BufWriter::new(stdout.lock());
    let r = run_to(args, &mut out, &mut io::stderr());
    // Flush what the good inputs produced even if a later one failed.
    let flushed = out.flush();
    r?;
    flushed.map_err(CliError::Output)
}

/// Runs `cms-host detect`, writing the CSV to `out` and warnings to `warn`.
pub fn run_to(args: &DetectArgs, out: &mut impl Write, warn: &mut impl Write) -> Result<(), CliError> {
    // Refuse a bad configuration before reading any input.
    detector(args, args.bits.unwrap_or(16))?;
    let mut stripes: Stripes<MAX_STRIPES> = Stripes::new();
    let mut header = false;
    for path in &args.inputs {
        let rows = input::read_rows(path)?;
        let rows = match args.axis {
            Axis::Rows => rows,
            Axis::Columns => rows.transposed(),
        };
        let name = path.display();
        if rows.width() > MAX_ROW {
            let what = match args.axis {
                Axis::Rows => "rows",
                Axis::Columns => "columns",
            };
            return Err(CliError::Usage(format!(
                "{name}: {what} of {} px exceed the detector's {MAX_ROW} px",
                rows.width()
            )));
        }
        let bits = args.bits.unwrap_or(rows.bits());
        let mut det = detector(args, bits)?;
        let sat = det.config().saturation;
        let max = rows.max_value();
        if max > sat {
            // Only possible with an explicit --bits below the data's depth.
            let _ = writeln!(
                warn,
                "warning: {name}: values up to {max} exceed --bits {bits}; clamped to the saturation level {sat}"
            );
        }
        if !header {
            writeln!(out, "{HEADER}")?;
            header = true;
        }
        let source = csv_field(&name.to_string());
        for (i, row) in rows.rows().enumerate() {
            let r = match row {
                Row::U8(r) => det.detect(r, &mut stripes),
                Row::U16(r) => det.detect(r, &mut stripes),
            };
            r.map_err(|e| CliError::Usage(format!("{name}: row {i}: {e}")))?;
            for (k, s) in stripes.iter().enumerate() {
                writeln!(out, "{source},{i},{k},{},{},{},{}", s.position, s.strength, s.width, flag_names(s.flags))?;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags() {
        assert_eq!(flag_names(Flags::NONE), "");
        assert_eq!(flag_names(Flags(1 | 4)), "saturated|low-confidence");
        assert_eq!(flag_names(Flags(7)), "saturated|clipped|low-confidence");
        assert_eq!(flag_names(Flags(2 | 8)), "clipped|flag3");
    }

    #[test]
    fn csv_quoting() {
        assert_eq!(csv_field("a/b.png"), "a/b.png");
        assert_eq!(csv_field("a,b.png"), "\"a,b.png\"");
        assert_eq!(csv_field("a\"b.png"), "\"a\"\"b.png\"");
    }

    #[test]
    fn scales() {
        let r = parse_scales("1.5:4").unwrap();
        assert_eq!((r.min(), r.max()), (Px::from_f64(1.5), Px::from_f64(4.0)));
        assert!(parse_scales("4:1.5").unwrap_err().contains("s_min must be below s_max"));
        assert!(parse_scales("2:2").is_err());
        assert!(parse_scales("0.5:4").unwrap_err().contains("at least 1 px"));
        assert!(parse_scales("2:30").unwrap_err().contains("at most 24 px"));
        assert!(parse_scales("1e-9:4").is_err());
        for bad in ["", "1.5", "a:b", "1:", ":4", "-1:4", "nan:4", "1:inf", "1:4:5"] {
            assert!(parse_scales(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn stripes_and_threshold() {
        assert_eq!(parse_stripes("16"), Ok(16));
        assert!(parse_stripes("17").unwrap_err().contains("at most 16"));
        assert!(parse_stripes("0").is_err());
        assert!(parse_stripes("-1").is_err());
        assert_eq!(parse_threshold("6"), Ok(Threshold(1536)));
        assert_eq!(parse_threshold("2.5"), Ok(Threshold(640)));
        for bad in ["0", "-1", "256", "nan", "inf", "x", "0.001"] {
            assert!(parse_threshold(bad).is_err(), "{bad}");
        }
    }
}
