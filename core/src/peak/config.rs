//! What the detector is told and what it reports: its configuration
//! ([`Config`], [`Method`], [`Select`]), why one is refused ([`Error`]),
//! and the stripes found ([`Stripe`], [`Flags`]) with the row's
//! statistics ([`RowStats`]). Plain data, kept apart from the detector
//! itself (`peak/mod.rs`), which is the per-row work.

use crate::fixed::{Px, Q24_8, UQ8_8Bits};
use crate::optics::ScaleRange;
use heapless::Vec;

/// Per-stripe quality flags (a bit set).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Flags(pub u8);

impl Flags {
    /// The stripe reaches the saturation level; centred on the saturated run.
    pub const SATURATED: Flags = Flags(1);
    /// The estimator's window runs past the row's edge.
    pub const CLIPPED: Flags = Flags(2);
    /// Weak (under twice the threshold), width at the edge of the scale
    /// range, or no sub-pixel solution (integer position reported).
    pub const LOW_CONFIDENCE: Flags = Flags(4);

    /// Rejected by the line pass ([`crate::pipeline::line`]): saturated and
    /// narrower than the optics allow a line (a specular glint).
    pub const GLINT: Flags = Flags(8);
    /// Rejected by the line pass: outside the band of columns the laser's
    /// calibration allows over the working depth (a secondary reflection,
    /// or another laser's stripe).
    pub const GHOST: Flags = Flags(16);
    /// Rejected by the line pass: off the line its neighbouring rows draw
    /// by more than the frame's scatter allows (an outlier).
    pub const OFF_LINE: Flags = Flags(32);
    /// Kept by the line pass, which dropped a second candidate for this
    /// laser in this row that broke the line (a ghost beside it): the
    /// point itself is good, the flag counts the one not carried.
    pub const SECOND_DROPPED: Flags = Flags(64);
    /// The flags that reject a point: a profile, a fit or an export built
    /// from points leaves out every point with one of them.
    pub const REJECTED: Flags = Flags(8 | 16 | 32);

    /// No flag.
    pub const NONE: Flags = Flags(0);
    /// Whether any bit of `other` is set.
    pub const fn intersects(self, other: Flags) -> bool {
        self.0 & other.0 != 0
    }
    /// Whether the line pass rejected the point ([`Flags::REJECTED`]).
    pub const fn rejected(self) -> bool {
        self.intersects(Flags::REJECTED)
    }
    /// Whether every bit of `other` is set.
    pub const fn contains(self, other: Flags) -> bool {
        self.0 & other.0 == other.0
    }
    /// Sets the bits of `other`.
    pub fn insert(&mut self, other: Flags) {
        self.0 |= other.0;
    }
    /// Every flag with its name, as printed by the host tools.
    pub const NAMES: [(Flags, &'static str); 7] = [
        (Flags::SATURATED, "saturated"),
        (Flags::CLIPPED, "clipped"),
        (Flags::LOW_CONFIDENCE, "low-confidence"),
        (Flags::GLINT, "glint"),
        (Flags::GHOST, "ghost"),
        (Flags::OFF_LINE, "off-line"),
        (Flags::SECOND_DROPPED, "second-dropped"),
    ];
    /// The names of the flags set, in bit order.
    pub fn names(self) -> impl Iterator<Item = &'static str> {
        Flags::NAMES.into_iter().filter(move |(f, _)| self.contains(*f)).map(|(_, n)| n)
    }
}

/// One laser stripe found in a row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Stripe {
    /// Centre, pixels from the first sample (Q16.16).
    pub position: Px,
    /// Peak height above the local background, counts.
    pub strength: u32,
    /// Estimated Gaussian σ of the stripe, pixels.
    pub width: Px,
    /// Quality flags.
    pub flags: Flags,
}

/// The stripes of one row, in ascending position.
pub type Stripes<const N: usize> = Vec<Stripe, N>;

/// The sub-pixel estimator.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Method {
    /// Multi-scale Ricker CWT, maximum of the response over continuous
    /// position at the best-matching scale (the default; see [`cwt`](super::cwt)).
    Cwt,
    /// The paper's Eq. (12)–(13) as written (see [`paper`](super::paper)).
    CwtPaper,
    /// Brightest pixel.
    Max,
    /// Centre of gravity over the run above half maximum.
    Cog,
    /// Centre of gravity of the low-pass (box-cascade FIR) filtered row.
    CogFiltered,
    /// Gaussian 3-point fit (Table 2).
    Gaussian,
    /// Parabolic 3-point fit (Table 2).
    Parabolic,
    /// Blais–Rioux 4th-order detector (Table 2).
    BlaisRioux,
    /// Linear interpolation (Table 2).
    Linear,
    /// Zero crossing of the FIR first derivative (Table 2, Forest et al.).
    FirZero,
    /// Centroid over ±3σ of the optics' scale, re-centred: the estimator
    /// for laser light, which speckle does not pull onto single speckles
    /// (`core/src/peak/centroid.rs`).
    Centroid,
}

impl Method {
    /// Every method, default first.
    pub const ALL: [Method; 11] = [
        Method::Cwt,
        Method::CwtPaper,
        Method::Max,
        Method::Cog,
        Method::CogFiltered,
        Method::Gaussian,
        Method::Parabolic,
        Method::BlaisRioux,
        Method::Linear,
        Method::FirZero,
        Method::Centroid,
    ];

    /// The name used on the command line and in reports.
    pub const fn name(self) -> &'static str {
        match self {
            Method::Cwt => "cwt",
            Method::CwtPaper => "cwt-paper",
            Method::Max => "max",
            Method::Cog => "cog",
            Method::CogFiltered => "cog-filtered",
            Method::Gaussian => "gaussian",
            Method::Parabolic => "parabolic",
            Method::BlaisRioux => "blais-rioux",
            Method::Linear => "linear",
            Method::FirZero => "fir-zero",
            Method::Centroid => "centroid",
        }
    }

    /// Parses [`Method::name`].
    pub fn from_name(s: &str) -> Option<Method> {
        Method::ALL.into_iter().find(|m| m.name() == s)
    }
}

/// Which stripes a row reports.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Select {
    /// The `max_stripes` strongest.
    Strongest,
    /// The `max_stripes` nearest the row's start.
    First,
    /// The `max_stripes` nearest the row's end.
    Last,
    /// Every stripe (up to the output's capacity; the strongest if more).
    All,
}

/// Detector configuration, validated by [`Detector::new`](super::Detector::new).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// Sub-pixel estimator.
    pub method: Method,
    /// Bit depth of the pixels, 8..=16.
    pub bits: u8,
    /// Stripe widths (Gaussian σ, px) to look for: the CWT's scale range.
    pub scales: ScaleRange,
    /// Most stripes per row (also capped by the output's capacity).
    pub max_stripes: u8,
    /// Which stripes to keep when there are more.
    pub select: Select,
    /// Detection threshold in multiples of the robust noise σ: [`UQ8_8`](crate::fixed::UQ8_8) bits.
    pub threshold_sigma_q8: UQ8_8Bits,
    /// Absolute floor: smallest stripe height above background, counts.
    pub min_amplitude: u16,
    /// Stripes closer than this are one (the stronger is kept).
    pub min_separation: Px,
    /// Narrowest stripe σ accepted (also the hot-pixel test's reference).
    pub min_width: Px,
    /// Widest stripe σ accepted.
    pub max_width: Px,
    /// Pixels at or above this value are saturated.
    pub saturation: u16,
}

impl Config {
    /// Defaults for `bits`-deep pixels and the given scale range: CWT, 3
    /// strongest stripes, threshold 6 σ, floor 4 counts, separation 2·s_max,
    /// widths [max(0.6·s_min, 0.7), 1.6·s_max], saturation 2^bits − 1.
    pub fn new(bits: u8, scales: ScaleRange) -> Config {
        let smin = scales.min().0 as i64;
        let smax = scales.max().0 as i64;
        Config {
            method: Method::Cwt,
            bits,
            scales,
            max_stripes: 3,
            select: Select::Strongest,
            threshold_sigma_q8: 6 * 256,
            min_amplitude: 4,
            min_separation: Px((2 * smax) as i32),
            min_width: Px((smin * 6 / 10).max(45875) as i32),
            max_width: Px((smax * 16 / 10) as i32),
            saturation: if (8..=16).contains(&bits) { ((1u32 << bits) - 1) as u16 } else { u16::MAX },
        }
    }
}

/// Why a configuration or a row was refused.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// Bit depth outside 8..=16.
    BitDepth(u8),
    /// Smallest scale below 1 px (the ladder's first rung).
    ScaleTooSmall,
    /// Largest scale above 24 px (the fit needs 1.5 × s_max on the ladder).
    ScaleTooLarge,
    /// `max_stripes` is zero.
    MaxStripes,
    /// `min_width` ≥ `max_width`, or not positive.
    WidthRange,
    /// Threshold is zero.
    Threshold,
    /// The saturation level is zero or above the bit depth's maximum.
    Saturation,
    /// The row is longer than the detector's buffers.
    RowTooLong {
        /// Row length.
        len: usize,
        /// Capacity.
        max: usize,
    },
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Error::BitDepth(b) => write!(f, "bit depth {b} is outside 8..=16"),
            Error::ScaleTooSmall => f.write_str("smallest scale must be at least 1 px"),
            Error::ScaleTooLarge => f.write_str("largest scale must be at most 24 px"),
            Error::MaxStripes => f.write_str("max stripes must be at least 1"),
            Error::WidthRange => f.write_str("min width must be positive and below max width"),
            Error::Threshold => f.write_str("threshold must be positive"),
            Error::Saturation => f.write_str("saturation level must be in 1..=2^bits-1"),
            Error::RowTooLong { len, max } => write!(f, "row of {len} px exceeds the detector's {max} px"),
        }
    }
}

impl core::error::Error for Error {}

/// What the front end saw in the last row.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RowStats {
    /// Robust pixel-noise σ, counts.
    pub noise_q8: Q24_8,
    /// Candidates above threshold after the coarse pass.
    pub candidates: u16,
    /// Hot pixels replaced.
    pub spikes: u16,
}
