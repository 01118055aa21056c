//! `cms-host detect`: its arguments, and the CSV on stdout.

use std::io::{self, BufWriter, Write};
use std::path::PathBuf;

use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::{Args, ValueEnum};
use cms_core::fixed::Px;
use cms_core::optics::ScaleRange;
use cms_core::peak::{Config, Detector, Method, Select};
use cms_host::input::detect::{self, Axis, MAX_STRIPES, Options};

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
    #[arg(long, value_enum, default_value_t = AxisArg::Rows)]
    pub axis: AxisArg,

    /// Bit depth of the pixels, 8..=16 (sets the saturation level 2^B − 1).
    /// Default: 8 or 16 for an image (its container), for CSV the smallest of
    /// 8, 10, 12, 14, 16 that holds the file's largest value.
    #[arg(long, value_name = "B", value_parser = clap::value_parser!(u8).range(8..=16))]
    pub bits: Option<u8>,

    /// Detection threshold in multiples of the robust noise σ, in steps of 1/256 (1/256 ≤ SIGMA ≤ 255.996).
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
pub enum AxisArg {
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
fn parse_scales(s: &str) -> Result<ScaleRange, String> {
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
    if !(v.is_finite() && v > 0.0) {
        return Err(format!("threshold must be a positive number of noise σ, got {s}"));
    }
    // The detector counts the threshold in steps of 1/256 σ (Q8).
    let q8 = (v * 256.0).round();
    if q8 < 1.0 {
        return Err(format!(
            "threshold {s} σ is below the detector's step of 1/256 σ ({:.4} σ), its smallest threshold",
            1.0 / 256.0
        ));
    }
    if q8 > u16::MAX as f64 {
        return Err(format!("threshold {s} σ is above the largest, 65535/256 σ ({:.3} σ)", u16::MAX as f64 / 256.0));
    }
    Ok(Threshold(q8 as u16))
}

impl DetectArgs {
    /// The library's options.
    pub fn options(&self) -> Options {
        Options {
            method: self.method,
            scales: self.scales,
            stripes: self.stripes,
            select: self.select.into(),
            axis: match self.axis {
                AxisArg::Rows => Axis::Rows,
                AxisArg::Columns => Axis::Columns,
            },
            bits: self.bits,
            threshold_sigma_q8: self.threshold.0,
            inputs: self.inputs.clone(),
        }
    }
}

/// Runs `cms-host detect` with stdout as the output.
pub fn run(args: &DetectArgs) -> anyhow::Result<()> {
    let stdout = io::stdout();
    let mut out = BufWriter::new(stdout.lock());
    let r = detect::write_csv(&args.options(), &mut out, &mut io::stderr());
    // Flush what the good inputs produced even if a later one failed.
    let flushed = out.flush();
    r?;
    flushed.map_err(cms_host::Error::Output)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

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
