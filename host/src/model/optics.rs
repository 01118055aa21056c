//! What a recording was made with that sets its speckle: the lens's
//! F-number and the lasers' wavelength, validated once when built.
//!
//! A real head's iris is set and locked at calibration (the calibration
//! file's `[head]` table), the simulated head's is the `--sim-light` it was
//! given; a recording carries them in its survey block's `[optics]` table
//! ([`crate::recording::survey_info`]) and `analyze` predicts the noise
//! floor from them (`crate::analyze::optics_floor`).

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// The F-numbers a lens is taken to be set to.
pub const F_NUMBERS: std::ops::RangeInclusive<f64> = 0.7..=64.0;
/// The wavelengths a triangulation laser is taken to have, nm.
pub const WAVELENGTHS_NM: std::ops::RangeInclusive<f64> = 200.0..=2000.0;

/// A lens's F-number and the lasers' wavelength.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawOptics", deny_unknown_fields)]
pub struct Optics {
    f_number: f64,
    wavelength_nm: f64,
}

/// The table as written, before it is checked.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawOptics {
    f_number: f64,
    wavelength_nm: f64,
}

impl TryFrom<RawOptics> for Optics {
    type Error = OpticsError;

    fn try_from(r: RawOptics) -> Result<Optics, OpticsError> {
        Optics::new(r.f_number, r.wavelength_nm)
    }
}

/// What is wrong with an aperture or a wavelength.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum OpticsError {
    /// An F-number outside [`F_NUMBERS`].
    #[error("f_number {0}: a lens's F-number is 0.7 to 64")]
    FNumber(f64),
    /// A wavelength outside [`WAVELENGTHS_NM`].
    #[error("wavelength_nm {0}: a laser's wavelength is 200 to 2000 nm")]
    Wavelength(f64),
    /// Not `F_NUMBER@WAVELENGTH_NM`.
    #[error("`{0}` is not F_NUMBER@WAVELENGTH_NM (e.g. 2.8@685)")]
    Syntax(String),
    /// An F-number without a wavelength, or a wavelength without an F-number.
    #[error("f_number and wavelength_nm go together (the optics the head records with)")]
    Unpaired,
}

impl Optics {
    /// The optics of F-number `f_number` and wavelength `wavelength_nm`,
    /// checked.
    pub fn new(f_number: f64, wavelength_nm: f64) -> Result<Optics, OpticsError> {
        if !F_NUMBERS.contains(&f_number) {
            return Err(OpticsError::FNumber(f_number));
        }
        if !WAVELENGTHS_NM.contains(&wavelength_nm) {
            return Err(OpticsError::Wavelength(wavelength_nm));
        }
        Ok(Optics { f_number, wavelength_nm })
    }

    /// The lens's F-number.
    pub fn f_number(&self) -> f64 {
        self.f_number
    }

    /// The lasers' wavelength, nm.
    pub fn wavelength_nm(&self) -> f64 {
        self.wavelength_nm
    }
}

impl fmt::Display for Optics {
    /// `F/2.8, 685 nm`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "F/{}, {} nm", self.f_number, self.wavelength_nm)
    }
}

impl FromStr for Optics {
    type Err = OpticsError;

    /// `F_NUMBER@WAVELENGTH_NM`, e.g. `2.8@685` (an `F/` before the
    /// F-number is taken too).
    fn from_str(s: &str) -> Result<Optics, OpticsError> {
        let bad = || OpticsError::Syntax(s.to_string());
        let (f, nm) = s.trim().split_once('@').ok_or_else(bad)?;
        let f = f.trim();
        let f = f.strip_prefix("F/").or_else(|| f.strip_prefix("f/")).unwrap_or(f);
        let number = |t: &str| t.trim().parse::<f64>().ok().filter(|x| x.is_finite()).ok_or_else(bad);
        Optics::new(number(f)?, number(nm.trim().trim_end_matches("nm"))?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn optics_are_checked_when_built() {
        let o: Optics = "2.8@685".parse().unwrap();
        assert_eq!((o.f_number(), o.wavelength_nm()), (2.8, 685.0));
        assert_eq!("F/5.6@405nm".parse::<Optics>().unwrap(), Optics::new(5.6, 405.0).unwrap());
        assert_eq!(o.to_string(), "F/2.8, 685 nm");
        for (bad, want) in [
            ("2.8", "F_NUMBER@WAVELENGTH_NM"),
            ("0.5@685", "f_number 0.5"),
            ("2.8@20", "wavelength_nm 20"),
            ("NaN@685", "not F_NUMBER"),
            ("inf@685", "not F_NUMBER"),
            ("2.8@", "not F_NUMBER"),
        ] {
            let e = bad.parse::<Optics>().unwrap_err().to_string();
            assert!(e.contains(want), "{bad}: {e}");
        }
        // The table is checked as it is read.
        let t: Result<Optics, _> = toml::from_str("f_number = 100.0\nwavelength_nm = 685.0\n");
        assert!(t.unwrap_err().to_string().contains("f_number 100"));
        let t: Result<Optics, _> = toml::from_str("f_number = 4.0\nwavelength_nm = 685.0\nfocus = 1\n");
        assert!(t.is_err());
    }
}
