//! Fixed-point types.
//!
//! Sub-pixel quantities travel as [`Px`]: pixels in Q16.16 (`i32`, one unit is
//! 1/65536 px). The resolution is far below any estimator's noise (the
//! Cramér–Rao bound of a σ = 1.5 px stripe at 40 dB is about 10⁻³ px; the
//! rounding adds 4.4·10⁻⁶ px RMS) and the range (±32767 px) covers any sensor row.
//!
//! Every other scaled integer that crosses a function boundary or sits in a
//! public field is one of the Q-format types below, named `Q<int>_<frac>`
//! (`UQ` unsigned) after its integer and fractional bits: [`Q24_8`],
//! [`Q56_8`], [`UQ8_8`], [`Q16_16`] and [`Q48_16`]. Each is a
//! `#[repr(transparent)]` newtype over its raw integer (`.0`, or
//! [`Q24_8::from_bits`] / [`Q24_8::to_bits`], both `#[inline(always)]`), so
//! it costs nothing in the hot loops, which work on the raw bits; it encodes
//! on the wire exactly as that integer (`serde(transparent)`). The unit is in
//! the name of the field or function that carries it (counts, σ, rows).

use core::fmt;
use core::ops::{Add, Sub};

/// Pixels in Q16.16: the value is `self.0 / 65536` px.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[serde(transparent)]
pub struct Px(pub i32);

impl Px {
    /// Number of fractional bits.
    pub const FRAC_BITS: u32 = 16;
    /// One pixel.
    pub const ONE: Px = Px(1 << 16);
    /// Zero.
    pub const ZERO: Px = Px(0);

    /// A whole number of pixels.
    pub const fn from_int(px: i32) -> Self {
        Px(px << Self::FRAC_BITS)
    }

    /// Rounds an `f64` to the nearest representable value (saturating).
    /// For configuration and host I/O, never on the per-pixel path.
    pub fn from_f64(px: f64) -> Self {
        let v = px * 65536.0;
        let r = if v >= 0.0 { v + 0.5 } else { v - 0.5 };
        Px(r as i32)
    }

    /// The value in pixels as `f64` (host side, reports).
    pub fn to_f64(self) -> f64 {
        self.0 as f64 / 65536.0
    }

    /// Largest whole pixel not above `self`.
    pub const fn floor(self) -> i32 {
        self.0 >> Self::FRAC_BITS
    }

    /// Nearest whole pixel (ties up).
    pub const fn round(self) -> i32 {
        (self.0 + (1 << (Self::FRAC_BITS - 1))) >> Self::FRAC_BITS
    }

    /// Absolute difference.
    pub const fn abs_diff(self, other: Px) -> Px {
        Px(self.0.abs_diff(other.0) as i32)
    }
}

impl Add for Px {
    type Output = Px;
    fn add(self, rhs: Px) -> Px {
        Px(self.0.saturating_add(rhs.0))
    }
}

impl Sub for Px {
    type Output = Px;
    fn sub(self, rhs: Px) -> Px {
        Px(self.0.saturating_sub(rhs.0))
    }
}

impl fmt::Display for Px {
    /// Decimal pixels with 5 fractional digits (1/65536 px ≈ 1.5·10⁻⁵ px).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let neg = self.0 < 0;
        let a = self.0.unsigned_abs() as u64;
        let int = a >> 16;
        let frac = ((a & 0xffff) * 100_000 + (1 << 15)) >> 16;
        let (int, frac) = if frac >= 100_000 { (int + 1, frac - 100_000) } else { (int, frac) };
        write!(f, "{}{}.{:05}", if neg && a != 0 { "-" } else { "" }, int, frac)
    }
}

/// Defines a Q-format newtype: `$raw` with `$frac` fractional bits.
macro_rules! q_format {
    ($(#[$doc:meta])* $name:ident, $raw:ty, $frac:expr) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        #[serde(transparent)]
        #[repr(transparent)]
        pub struct $name(pub $raw);

        impl $name {
            /// Number of fractional bits.
            pub const FRAC_BITS: u32 = $frac;
            /// One (1.0).
            pub const ONE: $name = $name(1 << $frac);
            /// Zero.
            pub const ZERO: $name = $name(0);

            /// The value whose raw bits are `bits` (`bits / 2^FRAC_BITS`).
            #[inline(always)]
            pub const fn from_bits(bits: $raw) -> Self {
                $name(bits)
            }

            /// The raw bits: the value × 2^FRAC_BITS.
            #[inline(always)]
            pub const fn to_bits(self) -> $raw {
                self.0
            }

            /// Rounds an `f64` to the nearest representable value, ties away
            /// from zero, saturating at the type's range (NaN gives zero).
            /// For configuration, tests and host I/O, never on the per-pixel
            /// path.
            pub fn from_f64(v: f64) -> Self {
                let v = v * (1u64 << $frac) as f64;
                let r = if v >= 0.0 { v + 0.5 } else { v - 0.5 };
                $name(r as $raw)
            }

            /// The value as `f64`: exact for raw integers of up to 53 bits,
            /// the nearest `f64` beyond.
            pub fn to_f64(self) -> f64 {
                self.0 as f64 / (1u64 << $frac) as f64
            }
        }
    };
}

q_format!(
    /// Q24.8 in an `i32`: the value is `self.0 / 256`. Noise σ and other
    /// count-scale levels (counts × 256), dimensionless factors near 1.
    Q24_8, i32, 8
);
q_format!(
    /// Q56.8 in an `i64`: the value is `self.0 / 256`. Filter responses and
    /// their gains (counts × 256), where products of pixel sums need 64 bits.
    Q56_8, i64, 8
);
q_format!(
    /// UQ8.8 in a `u16`: the value is `self.0 / 256`, 0 to 255.996.
    /// Thresholds in multiples of σ, stored noise levels.
    UQ8_8, u16, 8
);
q_format!(
    /// Q16.16 in an `i32`: the value is `self.0 / 65536`. Quantities other
    /// than pixel positions (those are [`Px`]): logarithms, row offsets.
    Q16_16, i32, 16
);
q_format!(
    /// Q48.16 in an `i64`: the value is `self.0 / 65536`. Factors and row
    /// positions whose integer part needs more than 15 bits.
    Q48_16, i64, 16
);

/// Raw bits of a [`UQ8_8`] for a public field that users outside this crate
/// still assign as a plain `u16`
/// ([`Config::threshold_sigma_q8`](crate::peak::Config::threshold_sigma_q8)):
/// read it with [`UQ8_8::from_bits`].
pub type UQ8_8Bits = u16;

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;
    use std::format;

    #[test]
    fn round_trip_and_display() {
        assert_eq!(Px::from_f64(1.5).0, 98304);
        assert_eq!(Px::from_f64(-0.25).0, -16384);
        assert_eq!(format!("{}", Px::from_f64(107.5)), "107.50000");
        assert_eq!(format!("{}", Px::from_f64(-2.000001)), "-2.00000");
        assert_eq!(format!("{}", Px(65535)), "0.99998");
        assert_eq!(Px::from_f64(3.7).floor(), 3);
        assert_eq!(Px::from_f64(-0.2).floor(), -1);
        assert_eq!(Px::from_f64(2.5).round(), 3);
    }

    #[test]
    fn q_formats_round_trip() {
        assert_eq!(Q24_8::from_f64(2.5).to_bits(), 640);
        assert_eq!(Q24_8::from_f64(-1.0 / 512.0).to_bits(), -1); // tie: away from zero
        assert_eq!(UQ8_8::from_f64(-3.0).to_bits(), 0); // saturates
        assert_eq!(UQ8_8::from_f64(1e9).to_bits(), u16::MAX);
        assert_eq!(Q48_16::from_bits(3 << 15).to_f64(), 1.5);
        assert_eq!(Q16_16::ONE.to_bits(), 65536);
        assert_eq!(Q56_8::from_f64(f64::NAN), Q56_8::ZERO);
    }
}
