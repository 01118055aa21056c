//! Reading detector input: grayscale PNG/TIFF images and CSV rows.
//!
//! [`read_rows`] turns a file into [`Rows`] (a row-major 8- or 16-bit pixel
//! grid and the bit depth it implies), or an [`InputError`] that names the file
//! and, for CSV, the 1-based line and the offending field. It never panics on
//! any content: the decoders run under allocation limits and every CSV value is
//! range-checked.
//!
//! The format is chosen by the extension alone (case-insensitive): `.png`,
//! `.tif`/`.tiff`, `.csv`. Content sniffing is deliberately not done, so a
//! mislabelled file is an error rather than a surprise.

pub mod detect;

use std::fmt;
use std::io::Cursor;
use std::path::{Path, PathBuf};

use image::{ColorType, DynamicImage, ImageDecoder, ImageFormat, ImageReader, Limits};

/// Largest decoded image accepted, bytes (the `image` crate's own default).
pub const MAX_IMAGE_BYTES: u64 = 512 << 20;
/// Largest image, CSV or profile file read, bytes: as large as the largest
/// decoded image (an uncompressed TIFF is its pixels).
pub const MAX_INPUT_BYTES: u64 = MAX_IMAGE_BYTES;

/// The pixels of an input, row-major.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Pixels {
    /// 8-bit samples.
    U8(Vec<u8>),
    /// 16-bit samples.
    U16(Vec<u16>),
}

/// One row of an input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Row<'a> {
    /// 8-bit samples.
    U8(&'a [u8]),
    /// 16-bit samples.
    U16(&'a [u16]),
}

impl Row<'_> {
    /// Number of samples.
    pub fn len(&self) -> usize {
        match self {
            Row::U8(r) => r.len(),
            Row::U16(r) => r.len(),
        }
    }

    /// Whether the row has no sample.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A grid of pixels read from one input: `height` rows of `width` samples.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Rows {
    width: usize,
    height: usize,
    pixels: Pixels,
    bits: u8,
}

impl Rows {
    /// 8-bit rows; `None` unless `data.len() == width × height` and both are positive.
    pub fn from_u8(width: usize, height: usize, data: Vec<u8>) -> Option<Rows> {
        Rows::check(width, height, data.len()).then_some(Rows { width, height, pixels: Pixels::U8(data), bits: 8 })
    }

    /// 16-bit rows with the container depth `bits` (8..=16); `None` unless
    /// `data.len() == width × height`, both are positive and `bits` is in range.
    pub fn from_u16(width: usize, height: usize, data: Vec<u16>, bits: u8) -> Option<Rows> {
        (Rows::check(width, height, data.len()) && (8..=16).contains(&bits)).then_some(Rows {
            width,
            height,
            pixels: Pixels::U16(data),
            bits,
        })
    }

    fn check(width: usize, height: usize, len: usize) -> bool {
        width > 0 && height > 0 && width.checked_mul(height) == Some(len)
    }

    /// Samples per row.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Number of rows.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The default bit depth: the container's (8 or 16) for an image; for CSV
    /// the smallest of 8, 10, 12, 14, 16 that holds the largest value.
    pub fn bits(&self) -> u8 {
        self.bits
    }

    /// The samples, row-major.
    pub fn pixels(&self) -> &Pixels {
        &self.pixels
    }

    /// Largest sample value.
    pub fn max_value(&self) -> u16 {
        match &self.pixels {
            Pixels::U8(d) => d.iter().copied().max().unwrap_or(0) as u16,
            Pixels::U16(d) => d.iter().copied().max().unwrap_or(0),
        }
    }

    /// Row `i` (`None` past the last row).
    pub fn row(&self, i: usize) -> Option<Row<'_>> {
        if i >= self.height {
            return None;
        }
        let span = i * self.width..(i + 1) * self.width;
        Some(match &self.pixels {
            Pixels::U8(d) => Row::U8(&d[span]),
            Pixels::U16(d) => Row::U16(&d[span]),
        })
    }

    /// The rows in order.
    pub fn rows(&self) -> impl Iterator<Item = Row<'_>> + '_ {
        (0..self.height).filter_map(|i| self.row(i))
    }

    /// The transposed grid: row `j` of the result is column `j` of `self`.
    pub fn transposed(&self) -> Rows {
        fn t<T: Copy>(d: &[T], w: usize, h: usize) -> Vec<T> {
            (0..w).flat_map(|x| (0..h).map(move |y| d[y * w + x])).collect()
        }
        let pixels = match &self.pixels {
            Pixels::U8(d) => Pixels::U8(t(d, self.width, self.height)),
            Pixels::U16(d) => Pixels::U16(t(d, self.width, self.height)),
        };
        Rows { width: self.height, height: self.width, pixels, bits: self.bits }
    }
}

/// The input formats, chosen by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// `.png`
    Png,
    /// `.tif`, `.tiff`
    Tiff,
    /// `.csv`
    Csv,
}

impl Format {
    /// The format of `path` by its extension (case-insensitive).
    pub fn from_path(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "png" => Some(Format::Png),
            "tif" | "tiff" => Some(Format::Tiff),
            "csv" => Some(Format::Csv),
            _ => None,
        }
    }
}

/// Why an input could not be read.
#[derive(Debug)]
pub struct InputError {
    /// The file, as given.
    pub path: PathBuf,
    /// What went wrong.
    pub kind: InputErrorKind,
}

impl crate::error::Classify for InputError {
    fn class(&self) -> crate::Class {
        crate::Class::Input
    }
}

impl fmt::Display for InputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.kind)
    }
}

impl std::error::Error for InputError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match &self.kind {
            InputErrorKind::Io(e) => Some(e),
            _ => None,
        }
    }
}

/// What went wrong reading an input.
#[derive(Debug)]
#[non_exhaustive]
pub enum InputErrorKind {
    /// The file could not be read.
    Io(std::io::Error),
    /// The file holds more than the cap of its kind ([`read_capped`]).
    TooBig {
        /// The cap, bytes.
        max_bytes: u64,
    },
    /// The extension is not one of the supported ones.
    UnknownExtension(Option<String>),
    /// The file has no byte (or, for CSV, only blank lines).
    Empty,
    /// A colour, grey+alpha or palette image.
    NotGrayscale(String),
    /// A pixel format the decoder has no type for (e.g. 32-bit float or
    /// 12-bit grayscale TIFF): its bits per pixel.
    PixelFormat(u16),
    /// The image decoder refused the file (corrupt, truncated, unsupported
    /// sample format such as 32-bit float, over the size limit…).
    Decode {
        /// PNG or TIFF.
        format: Format,
        /// The decoder's message, on one line.
        message: String,
    },
    /// A CSV line is malformed.
    Csv(CsvError),
}

impl fmt::Display for InputErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            InputErrorKind::Io(e) => write!(f, "cannot read file: {e}"),
            InputErrorKind::TooBig { max_bytes } => {
                write!(f, "more than {}; too big for this kind of input (a device or a wrong file?)", size(*max_bytes))
            }
            InputErrorKind::UnknownExtension(Some(ext)) => {
                write!(f, "unknown file type `.{}` (expected .png, .tif, .tiff or .csv)", one_line(ext, 16))
            }
            InputErrorKind::UnknownExtension(None) => {
                f.write_str("no file extension (expected .png, .tif, .tiff or .csv)")
            }
            InputErrorKind::Empty => f.write_str("empty file"),
            InputErrorKind::NotGrayscale(what) => {
                write!(f, "{what}: only single-channel grayscale images (8 or 16 bit) are supported")
            }
            InputErrorKind::PixelFormat(bits) => {
                // The decoder tells only the bits: say what they usually are.
                let what = match bits {
                    1..=15 => format!(
                        "{bits} bits per pixel, packed; save {bits}-bit pixels as a 16-bit image, as the sensor's \
                         10- and 12-bit data are"
                    ),
                    32 | 64 => format!("{bits} bits per pixel: float or {bits}-bit integer samples"),
                    _ => format!("{bits} bits per pixel"),
                };
                write!(
                    f,
                    "unsupported pixel format ({what}): only 8- or 16-bit unsigned grayscale images are supported"
                )
            }
            InputErrorKind::Decode { format, message } => {
                let name = match format {
                    Format::Png => "PNG",
                    Format::Tiff => "TIFF",
                    Format::Csv => "CSV",
                };
                write!(f, "cannot decode {name}: {message}")
            }
            InputErrorKind::Csv(e) => e.fmt(f),
        }
    }
}

/// A malformed CSV line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CsvError {
    /// A field is not an integer in 0..=65535.
    Field {
        /// 1-based line number.
        line: usize,
        /// 1-based field number.
        field: usize,
        /// The field's text (lossy UTF-8, truncated).
        text: String,
        /// Why it was refused.
        reason: FieldError,
    },
    /// A line has a different number of fields than the first.
    Ragged {
        /// 1-based line number.
        line: usize,
        /// Fields on that line.
        fields: usize,
        /// Fields on line 1.
        expected: usize,
    },
    /// A blank line followed by more data.
    BlankLine {
        /// 1-based line number of the blank line.
        line: usize,
    },
}

/// Why a CSV field was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldError {
    /// Nothing between the commas.
    Empty,
    /// Not made of decimal digits only.
    NotInteger,
    /// Above 65535.
    OutOfRange,
}

impl fmt::Display for CsvError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CsvError::Field { line, field, text, reason } => {
                let why = match reason {
                    FieldError::Empty => "empty field",
                    FieldError::NotInteger => "not a non-negative integer",
                    FieldError::OutOfRange => "out of range (0..=65535)",
                };
                write!(f, "line {line}, field {field} \"{text}\": {why}")
            }
            CsvError::Ragged { line, fields, expected } => {
                let s = if *fields == 1 { "" } else { "s" };
                write!(f, "line {line}: {fields} field{s}, expected {expected} (as on line 1)")
            }
            CsvError::BlankLine { line } => write!(f, "line {line}: blank line before more data"),
        }
    }
}

/// A size in words: `1 MiB`, `512 MiB`, `100 bytes`.
fn size(bytes: u64) -> String {
    match bytes {
        b if b >= 1 << 20 && b % (1 << 20) == 0 => format!("{} MiB", b >> 20),
        b if b >= 1 << 10 && b % (1 << 10) == 0 => format!("{} KiB", b >> 10),
        b => format!("{b} bytes"),
    }
}

/// Reads the whole of `path`, refusing more than `max_bytes`.
///
/// The cap is checked while reading (at most `max_bytes + 1` bytes are
/// ever read), not against the file's metadata: a device (`/dev/zero`), a
/// FIFO or a file that grows while being read is stopped at the cap
/// instead of filling memory. Every reader of a whole input file —
/// images, CSV rows, profiles, calibration files, the simulated head's
/// stored calibration — goes through here, each with the cap of its kind.
pub fn read_capped(path: &Path, max_bytes: u64) -> Result<Vec<u8>, InputError> {
    use std::io::Read as _;
    let err = |kind| InputError { path: path.to_path_buf(), kind };
    let file = std::fs::File::open(path).map_err(|e| err(InputErrorKind::Io(e)))?;
    // A regular file's length sizes the buffer (capped: metadata may lie).
    let hint = file.metadata().map_or(0, |m| m.len()).min(max_bytes);
    let mut bytes = Vec::with_capacity(usize::try_from(hint).unwrap_or(0));
    file.take(max_bytes.saturating_add(1)).read_to_end(&mut bytes).map_err(|e| err(InputErrorKind::Io(e)))?;
    if bytes.len() as u64 > max_bytes {
        return Err(err(InputErrorKind::TooBig { max_bytes }));
    }
    Ok(bytes)
}

/// Reads `path` (format by extension) into rows.
pub fn read_rows(path: &Path) -> Result<Rows, InputError> {
    let err = |kind| InputError { path: path.to_path_buf(), kind };
    let format = Format::from_path(path).ok_or_else(|| {
        err(InputErrorKind::UnknownExtension(path.extension().map(|e| e.to_string_lossy().into_owned())))
    })?;
    let bytes = read_capped(path, MAX_INPUT_BYTES)?;
    parse(&bytes, format).map_err(err)
}

/// Parses the content of a file of the given format.
pub fn parse(bytes: &[u8], format: Format) -> Result<Rows, InputErrorKind> {
    if bytes.is_empty() {
        return Err(InputErrorKind::Empty);
    }
    match format {
        Format::Csv => parse_csv(bytes),
        Format::Png => decode_image(bytes, format, ImageFormat::Png),
        Format::Tiff => decode_image(bytes, format, ImageFormat::Tiff),
    }
}

fn decode_image(bytes: &[u8], format: Format, image_format: ImageFormat) -> Result<Rows, InputErrorKind> {
    let decode_err = |e: image::ImageError| {
        if let image::ImageError::Unsupported(u) = &e
            && let image::error::UnsupportedErrorKind::Color(c) = u.kind()
        {
            return InputErrorKind::PixelFormat(c.bits_per_pixel());
        }
        InputErrorKind::Decode { format, message: one_line(&e.to_string(), 200) }
    };
    let mut reader = ImageReader::with_format(Cursor::new(bytes), image_format);
    let mut limits = Limits::default();
    limits.max_alloc = Some(MAX_IMAGE_BYTES);
    reader.limits(limits);
    let decoder = reader.into_decoder().map_err(decode_err)?;
    let color = decoder.color_type();
    if !matches!(color, ColorType::L8 | ColorType::L16) {
        // PNG colour type 3 (IHDR byte 25) is expanded to RGB by the decoder.
        let palette = format == Format::Png && bytes.get(25) == Some(&3);
        let what = if palette { "palette (indexed-colour) image".to_string() } else { describe(color) };
        return Err(InputErrorKind::NotGrayscale(what));
    }
    if decoder.total_bytes() > MAX_IMAGE_BYTES {
        return Err(InputErrorKind::Decode {
            format,
            message: format!("image of {} bytes exceeds the {MAX_IMAGE_BYTES}-byte limit", decoder.total_bytes()),
        });
    }
    let (w, h) = decoder.dimensions();
    let (w, h) = (w as usize, h as usize);
    let bad_size =
        || InputErrorKind::Decode { format, message: format!("image of {w}×{h} pixels has no usable pixel data") };
    match DynamicImage::from_decoder(decoder).map_err(decode_err)? {
        DynamicImage::ImageLuma8(b) => Rows::from_u8(w, h, b.into_raw()).ok_or_else(bad_size),
        DynamicImage::ImageLuma16(b) => Rows::from_u16(w, h, b.into_raw(), 16).ok_or_else(bad_size),
        other => Err(InputErrorKind::NotGrayscale(describe(other.color()))),
    }
}

fn describe(color: ColorType) -> String {
    let (what, bits) = match color {
        ColorType::La8 => ("grayscale+alpha", "8"),
        ColorType::La16 => ("grayscale+alpha", "16"),
        ColorType::Rgb8 => ("colour (RGB)", "8"),
        ColorType::Rgb16 => ("colour (RGB)", "16"),
        ColorType::Rgba8 => ("colour (RGBA)", "8"),
        ColorType::Rgba16 => ("colour (RGBA)", "16"),
        ColorType::Rgb32F => ("colour (RGB)", "32-bit float"),
        ColorType::Rgba32F => ("colour (RGBA)", "32-bit float"),
        other => return format!("{other:?} image"),
    };
    if bits.ends_with("float") { format!("{what} {bits} image") } else { format!("{what} {bits}-bit image") }
}

/// `s` on one printable line, at most `max` characters (then `…`).
pub fn one_line(s: &str, max: usize) -> String {
    let mut out = String::new();
    for (n, c) in s.chars().enumerate() {
        if n == max {
            out.push('…');
            break;
        }
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

/// Parses CSV rows: one row per line, comma-separated integers 0..=65535,
/// optional spaces around fields, `\n` or `\r\n` line ends, blank lines
/// allowed only at the end, all rows the same length.
pub fn parse_csv(bytes: &[u8]) -> Result<Rows, InputErrorKind> {
    let mut data: Vec<u16> = Vec::new();
    let mut width = 0usize;
    let mut height = 0usize;
    let mut blank: Option<usize> = None;
    for (i, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let line = i + 1;
        let text = raw.strip_suffix(b"\r").unwrap_or(raw);
        if text.iter().all(|b| matches!(b, b' ' | b'\t' | b'\r')) {
            blank.get_or_insert(line);
            continue;
        }
        if let Some(b) = blank {
            return Err(InputErrorKind::Csv(CsvError::BlankLine { line: b }));
        }
        let start = data.len();
        for (k, field) in text.split(|&b| b == b',').enumerate() {
            let v = parse_field(field).map_err(|reason| {
                InputErrorKind::Csv(CsvError::Field {
                    line,
                    field: k + 1,
                    text: one_line(&String::from_utf8_lossy(field.trim_ascii()), 40),
                    reason,
                })
            })?;
            data.push(v);
        }
        let fields = data.len() - start;
        if height == 0 {
            width = fields;
        } else if fields != width {
            return Err(InputErrorKind::Csv(CsvError::Ragged { line, fields, expected: width }));
        }
        height += 1;
    }
    if height == 0 {
        return Err(InputErrorKind::Empty);
    }
    let max = data.iter().copied().max().unwrap_or(0);
    let bits = [8u8, 10, 12, 14, 16].into_iter().find(|&b| (max as u32) < (1u32 << b)).unwrap_or(16);
    Rows::from_u16(width, height, data, bits).ok_or(InputErrorKind::Empty)
}

fn parse_field(field: &[u8]) -> Result<u16, FieldError> {
    let f = field.trim_ascii();
    if f.is_empty() {
        return Err(FieldError::Empty);
    }
    if !f.iter().all(u8::is_ascii_digit) {
        return Err(FieldError::NotInteger);
    }
    let mut v: u32 = 0;
    for &d in f {
        v = v * 10 + (d - b'0') as u32;
        if v > u16::MAX as u32 {
            return Err(FieldError::OutOfRange);
        }
    }
    Ok(v as u16)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn csv(s: &str) -> Result<Rows, InputErrorKind> {
        parse(s.as_bytes(), Format::Csv)
    }

    fn csv_err(s: &str) -> String {
        csv(s).err().map(|e| e.to_string()).unwrap_or_default()
    }

    #[test]
    fn csv_rows_and_bits() {
        let r = csv("1,2,3\n4, 5 ,6\r\n\n\n").unwrap();
        assert_eq!((r.width(), r.height(), r.bits()), (3, 2, 8));
        assert_eq!(r.pixels(), &Pixels::U16(vec![1, 2, 3, 4, 5, 6]));
        assert_eq!(csv("0,256").unwrap().bits(), 10);
        assert_eq!(csv("4095,0").unwrap().bits(), 12);
        assert_eq!(csv("4096").unwrap().bits(), 14);
        assert_eq!(csv("65535").unwrap().bits(), 16);
        assert_eq!(csv("255").unwrap().bits(), 8);
    }

    #[test]
    fn csv_errors_name_line_and_field() {
        assert_eq!(csv_err("1,2\n3,x\n"), "line 2, field 2 \"x\": not a non-negative integer");
        assert_eq!(csv_err("1,2\n3,65536\n"), "line 2, field 2 \"65536\": out of range (0..=65535)");
        assert_eq!(csv_err("1,2\n3,-1\n"), "line 2, field 2 \"-1\": not a non-negative integer");
        assert_eq!(csv_err("1,2\n3,1.5\n"), "line 2, field 2 \"1.5\": not a non-negative integer");
        assert_eq!(csv_err("1,,2\n"), "line 1, field 2 \"\": empty field");
        assert_eq!(csv_err("1,2\n3\n"), "line 2: 1 field, expected 2 (as on line 1)");
        assert_eq!(csv_err("1,2\n\n3,4\n"), "line 2: blank line before more data");
        assert_eq!(csv_err("\n\n"), "empty file");
        assert_eq!(csv_err(""), "empty file");
        assert!(csv_err("1,99999999999999999999999999").contains("out of range"));
        assert_eq!(csv_err("1,\u{7}\n"), "line 1, field 2 \"\\u{7}\": not a non-negative integer");
    }

    #[test]
    fn transpose() {
        let r = Rows::from_u8(3, 2, vec![1, 2, 3, 4, 5, 6]).unwrap();
        let t = r.transposed();
        assert_eq!((t.width(), t.height()), (2, 3));
        assert_eq!(t.pixels(), &Pixels::U8(vec![1, 4, 2, 5, 3, 6]));
        assert_eq!(t.row(2), Some(Row::U8(&[3, 6])));
        assert_eq!(t.row(3), None);
    }

    #[test]
    fn extensions() {
        assert_eq!(Format::from_path(Path::new("a/B.PNG")), Some(Format::Png));
        assert_eq!(Format::from_path(Path::new("x.tiff")), Some(Format::Tiff));
        assert_eq!(Format::from_path(Path::new("x.Tif")), Some(Format::Tiff));
        assert_eq!(Format::from_path(Path::new("x.csv")), Some(Format::Csv));
        assert_eq!(Format::from_path(Path::new("x.bmp")), None);
        assert_eq!(Format::from_path(Path::new("csv")), None);
    }
}
