//! Shared plotting plumbing: the font plotters draws text with, and one
//! drawing rendered both as SVG and as PNG.
//!
//! plotters is built with `ab_glyph` (pure Rust text layout) instead of its
//! system-font backend, so text needs a registered font: DejaVu Sans is
//! embedded (the `dejavu` crate) and registered as `sans-serif` by
//! [`fonts`], which every plotting function calls first. PNGs are drawn
//! into an RGB buffer (`BitMapBackend::with_buffer`) and encoded by the
//! `image` crate the host already uses for PNG.

use std::path::Path;
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;

/// Registers the embedded font as `sans-serif` (once; later calls are free).
pub fn fonts() {
    static DONE: OnceLock<()> = OnceLock::new();
    DONE.get_or_init(|| {
        // The embedded file is a valid font: this cannot fail but is not unwrapped.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular());
        let _ = plotters::style::register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold());
    });
}

/// A figure that can draw itself on any plotters backend.
pub trait Figure {
    /// Draws onto `root` (plotters' errors as text).
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String>;
}

/// Why a plot could not be made.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlotError {
    /// plotters could not draw it (its error, as text: plotters' errors
    /// borrow the backend and cannot be kept).
    #[error("{0}")]
    Draw(String),
    /// The PNG could not be encoded.
    #[error("{}: {source}", path.display())]
    Encode {
        /// The PNG's file.
        path: std::path::PathBuf,
        /// The encoder's error.
        source: image::ImageError,
    },
    /// A file could not be written.
    #[error(transparent)]
    Output(#[from] crate::output::OutputError),
}

impl crate::error::Classify for PlotError {
    fn class(&self) -> crate::Class {
        match self {
            PlotError::Output(e) => e.class(),
            PlotError::Draw(_) | PlotError::Encode { .. } => crate::Class::Other,
        }
    }
}

/// plotters' drawing error as text.
pub fn err<E: std::fmt::Debug>(e: E) -> String {
    format!("plotting: {e:?}")
}

/// Renders `fig` at `size` px as `BASE.svg` and `BASE.png`. Returns the SVG
/// text too (for embedding in HTML).
pub fn svg_and_png(base: &Path, size: (u32, u32), fig: &impl Figure) -> Result<String, PlotError> {
    fonts();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        fig.draw(&root).map_err(PlotError::Draw)?;
        root.present().map_err(|e| PlotError::Draw(err(e)))?;
    }
    let svg_path = base.with_extension("svg");
    crate::output::write_atomically(&svg_path, |w| w.write_all(svg.as_bytes()))?;
    let mut rgb = vec![0u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, size).into_drawing_area();
        fig.draw(&root).map_err(PlotError::Draw)?;
        root.present().map_err(|e| PlotError::Draw(err(e)))?;
    }
    let png_path = base.with_extension("png");
    let mut png = std::io::Cursor::new(Vec::new());
    image::write_buffer_with_format(
        &mut png,
        &rgb,
        size.0,
        size.1,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(|source| PlotError::Encode { path: png_path.clone(), source })?;
    crate::output::write_atomically(&png_path, |w| w.write_all(png.get_ref()))?;
    Ok(svg)
}
