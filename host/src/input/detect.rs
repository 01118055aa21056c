//! Laser-stripe detection of image rows, as CSV: the work of `cms-host
//! detect` (the command line parses the options and owns stdout).
//!
//! ```text
//! source,row,stripe,position_px,strength,width_px,flags
//! examples/stripes.png,0,0,181.23456,1497,2.01234,
//! ```
//!
//! One line per stripe; `row` is the 0-based row (the column with
//! [`Axis::Columns`]), `stripe` the 0-based index in ascending position,
//! positions and widths in pixels with 5 decimals, `strength` in counts above
//! the background, `flags` a `|`-joined subset of `saturated`, `clipped`,
//! `low-confidence`. A row without stripe prints nothing.
//!
//! Inputs are processed in order; the first bad one stops the run with an
//! error naming it (lines already written for earlier inputs stay). Each
//! input is read and checked whole before any of its lines is written.

use std::io::Write;
use std::path::PathBuf;

use cms_core::optics::ScaleRange;
use cms_core::peak::{Config, Detector, Error as DetectError, Flags, Method, Select, Stripes};

use crate::Error;
use crate::input::{self, Row};

/// Longest row the detector takes, pixels.
pub const MAX_ROW: usize = 8192;
/// Most stripes reported per row (the output buffer's capacity).
pub const MAX_STRIPES: usize = 16;
/// The CSV header.
pub const HEADER: &str = "source,row,stripe,position_px,strength,width_px,flags";

/// What to detect, and in which inputs.
#[derive(Clone, Debug)]
pub struct Options {
    /// Sub-pixel estimator.
    pub method: Method,
    /// Stripe widths to look for (Gaussian σ, px).
    pub scales: ScaleRange,
    /// Most stripes reported per row (1..=[`MAX_STRIPES`]).
    pub stripes: u8,
    /// Which stripes a row reports when it has more.
    pub select: Select,
    /// Along image rows or columns.
    pub axis: Axis,
    /// Bit depth of the pixels (`None`: the input's own).
    pub bits: Option<u8>,
    /// Detection threshold in multiples of the robust noise σ, Q8 (1/256 σ).
    pub threshold_sigma_q8: u16,
    /// Grayscale PNG or TIFF images, or CSV files of rows.
    pub inputs: Vec<PathBuf>,
}

/// Which way of an image is a detector row.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    /// Each image row is a detector row.
    Rows,
    /// Each image column is a detector row (the image is transposed).
    Columns,
}

impl Options {
    /// The detector configuration for pixels `bits` deep.
    pub fn config(&self, bits: u8) -> Config {
        let mut cfg = Config::new(bits, self.scales);
        cfg.method = self.method;
        cfg.select = self.select;
        cfg.max_stripes = self.stripes;
        cfg.threshold_sigma_q8 = self.threshold_sigma_q8;
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

fn detector(args: &Options, bits: u8) -> Result<Box<Detector<MAX_ROW>>, Error> {
    // Detector<8192> holds 128 KiB of buffers: build it on the heap.
    Detector::<MAX_ROW>::new(args.config(bits))
        .map(Box::new)
        .map_err(|e| Error::Input(format!("invalid {}: {e}", option_of(&e))))
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

/// Detects the stripes of every input, writing the CSV to `out` and
/// warnings to `warn`.
pub fn write_csv(args: &Options, out: &mut impl Write, warn: &mut impl Write) -> Result<(), Error> {
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
            return Err(Error::Input(format!(
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
            writeln!(out, "{HEADER}").map_err(Error::Output)?;
            header = true;
        }
        let source = csv_field(&name.to_string());
        for (i, row) in rows.rows().enumerate() {
            let r = match row {
                Row::U8(r) => det.detect(r, &mut stripes),
                Row::U16(r) => det.detect(r, &mut stripes),
            };
            r.map_err(|e| Error::Input(format!("{name}: row {i}: {e}")))?;
            for (k, s) in stripes.iter().enumerate() {
                writeln!(out, "{source},{i},{k},{},{},{},{}", s.position, s.strength, s.width, flag_names(s.flags))
                    .map_err(Error::Output)?;
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
        assert_eq!(flag_names(Flags(2 | 128)), "clipped|flag7");
    }

    #[test]
    fn csv_quoting() {
        assert_eq!(csv_field("a/b.png"), "a/b.png");
        assert_eq!(csv_field("a,b.png"), "\"a,b.png\"");
        assert_eq!(csv_field("a\"b.png"), "\"a\"\"b.png\"");
    }
}
