//! The detector's scale range from the sensor head's optics (paper §5.2).
//!
//! A laser line of diameter `d` seen at range `r` by a camera of focal length
//! `f_x` (pixels) at an angle α between the camera and the laser plane images to
//! a stripe whose width scales as
//!
//! ```text
//! s_min = f_x / r_max · d · sin α      (Eq. 10)
//! s_max = f_x / r_min · d · sin α      (Eq. 11)
//! ```
//!
//! and the paper widens the range by a safety margin of 25 % *of the range* at
//! each end (§5.2). With Table 4 (f_x = 5106 px, d = 2 mm, α = 42°, r = 35–55 cm)
//! this gives 12.42–19.52 px before and 10.65–21.30 px after the margin; the
//! paper prints 10.5 and 21.5 (rounded outward).
//!
//! This is configuration, computed once, so it uses `f64` (soft-float on the
//! microcontroller, which never calls it per row). The sine is a short
//! Taylor series: `core` has no `sin`, and |α| ≤ π/2 keeps it exact to 1e-12.

use crate::fixed::Px;

/// Why a scale range could not be built.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum OpticsError {
    /// A length, focal length or range is not finite and positive.
    NotPositive,
    /// `r_min` is not below `r_max`.
    RangeOrder,
    /// α is outside (0°, 90°].
    Angle,
    /// The margin is negative or above 100 %.
    Margin,
    /// `s_min` is not below `s_max`.
    ScaleOrder,
    /// A scale is not positive.
    ScaleNotPositive,
}

impl core::fmt::Display for OpticsError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            OpticsError::NotPositive => "focal length, laser diameter and working range must be finite and > 0",
            OpticsError::RangeOrder => "working range: r_min must be below r_max",
            OpticsError::Angle => "laser angle must be in (0°, 90°]",
            OpticsError::Margin => "scale margin must be in [0, 1]",
            OpticsError::ScaleOrder => "scale range: s_min must be below s_max",
            OpticsError::ScaleNotPositive => "scale range: scales must be > 0 px",
        })
    }
}

impl core::error::Error for OpticsError {}

/// The head geometry that fixes the stripe width (paper Table 4).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Optics {
    /// Focal length along the detection axis, pixels.
    pub fx_px: f64,
    /// Laser line diameter on the object, millimetres.
    pub laser_diameter_mm: f64,
    /// Angle between camera axis and laser plane, degrees.
    pub alpha_deg: f64,
    /// Nearest working distance, millimetres.
    pub r_min_mm: f64,
    /// Farthest working distance, millimetres.
    pub r_max_mm: f64,
    /// Safety margin as a fraction of the range, added at both ends (paper: 0.25).
    pub margin: f64,
}

impl Optics {
    /// The prototype of the paper, Table 4.
    pub const PAPER: Optics = Optics {
        fx_px: 5106.0,
        laser_diameter_mm: 2.0,
        alpha_deg: 42.0,
        r_min_mm: 350.0,
        r_max_mm: 550.0,
        margin: 0.25,
    };

    /// The detector's scale range (Eq. 10–11 with the margin).
    pub fn scale_range(&self) -> Result<ScaleRange, OpticsError> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        if !(pos(self.fx_px) && pos(self.laser_diameter_mm) && pos(self.r_min_mm) && pos(self.r_max_mm)) {
            return Err(OpticsError::NotPositive);
        }
        if self.r_min_mm >= self.r_max_mm {
            return Err(OpticsError::RangeOrder);
        }
        if !(self.alpha_deg > 0.0 && self.alpha_deg <= 90.0) {
            return Err(OpticsError::Angle);
        }
        if !(self.margin >= 0.0 && self.margin <= 1.0) {
            return Err(OpticsError::Margin);
        }
        let k = self.laser_diameter_mm * sin(self.alpha_deg.to_radians_core());
        let lo = self.fx_px / self.r_max_mm * k;
        let hi = self.fx_px / self.r_min_mm * k;
        let m = self.margin * (hi - lo);
        ScaleRange::new(Px::from_f64((lo - m).max(0.5)), Px::from_f64(hi + m))
    }
}

/// A validated scale range `[min, max]` in pixels (stripe σ, see `peak`).
/// On the wire it is the pair `(min, max)`, validated again when decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[serde(try_from = "(Px, Px)", into = "(Px, Px)")]
pub struct ScaleRange {
    min: Px,
    max: Px,
}

impl ScaleRange {
    /// Explicit values; `min` must be positive and below `max`.
    pub fn new(min: Px, max: Px) -> Result<Self, OpticsError> {
        if min.0 <= 0 {
            return Err(OpticsError::ScaleNotPositive);
        }
        if min >= max {
            return Err(OpticsError::ScaleOrder);
        }
        Ok(ScaleRange { min, max })
    }
    /// Smallest scale.
    pub fn min(&self) -> Px {
        self.min
    }
    /// Largest scale.
    pub fn max(&self) -> Px {
        self.max
    }
}

impl TryFrom<(Px, Px)> for ScaleRange {
    type Error = OpticsError;
    fn try_from((min, max): (Px, Px)) -> Result<Self, OpticsError> {
        ScaleRange::new(min, max)
    }
}

impl From<ScaleRange> for (Px, Px) {
    fn from(r: ScaleRange) -> (Px, Px) {
        (r.min, r.max)
    }
}

trait ToRadians {
    fn to_radians_core(self) -> f64;
}
impl ToRadians for f64 {
    fn to_radians_core(self) -> f64 {
        self * (core::f64::consts::PI / 180.0)
    }
}

/// sin(x) for |x| ≤ π/2 by its Taylor series (13 terms: error < 1e-15);
/// `core` has no `f64::sin`. Also used by `triangulation`'s setup.
pub(crate) fn sin(x: f64) -> f64 {
    let x2 = x * x;
    let mut term = x;
    let mut sum = x;
    for n in 1..13 {
        term *= -x2 / ((2 * n) as f64 * (2 * n + 1) as f64);
        sum += term;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_table4() {
        let r = Optics::PAPER.scale_range().unwrap();
        // Computed by hand: 5106·2·sin 42°/550 = 12.4237, /350 = 19.5230,
        // margin 0.25·7.0993 = 1.7748 → 10.649, 21.298. Paper prints 10.5, 21.5.
        assert!((r.min().to_f64() - 10.649).abs() < 0.002, "{:?}", r);
        assert!((r.max().to_f64() - 21.298).abs() < 0.002, "{:?}", r);
        assert!((r.min().to_f64() - 10.5).abs() < 0.2);
        assert!((r.max().to_f64() - 21.5).abs() < 0.25);
    }

    #[test]
    fn sine() {
        assert!((sin(0.5) - 0.479_425_538_604_203).abs() < 1e-14);
        assert!((sin(core::f64::consts::FRAC_PI_2) - 1.0).abs() < 1e-14);
    }

    #[test]
    fn rejects_bad_geometry() {
        let mut o = Optics::PAPER;
        o.r_min_mm = 600.0;
        assert_eq!(o.scale_range(), Err(OpticsError::RangeOrder));
        o = Optics::PAPER;
        o.alpha_deg = 0.0;
        assert_eq!(o.scale_range(), Err(OpticsError::Angle));
        o = Optics::PAPER;
        o.fx_px = f64::NAN;
        assert_eq!(o.scale_range(), Err(OpticsError::NotPositive));
        assert_eq!(ScaleRange::new(Px::from_int(3), Px::from_int(2)), Err(OpticsError::ScaleOrder));
    }
}
