//! Runs placed by their GNSS fixes on a track register, the start chainage
//! typed for them (`--chainage`, the survey's `start_chainage`) kept as a
//! check.
//!
//! A run with fixes is placed where the fit [`crate::gnss::register::check`]
//! (`cms-host locate`'s) puts its odometer 0: `c₀` and the direction of
//! `c₀ + k·odometer`. Its **tolerance** is the largest of its fixes'
//! tolerances (three times the combined standard uncertainty of the fix,
//! the register and the receiver's latency). The typed start is checked
//! against it: the two **disagree** when they are farther apart than
//! their combined tolerance, `√(gnss² + typed²)`, where a typed start's
//! tolerance is what the user allows registration to move it
//! (`--search-m`); a typed heading disagrees when GNSS says the other
//! way. Either is reported as disputed, naming both, and GNSS places the
//! run. GNSS does not place a run whose fit fails (fewer than 3 fixes on
//! the track, under 1 m of travel) or disagrees with its own odometer
//! (some fix beyond its tolerance: a slipping wheel, the wrong register),
//! nor a recording of more than one head session (the odometer restarts):
//! then the typed placement stands, and the report says why.

use std::fmt;
use std::path::Path;

use crate::Error;
use crate::gnss::register::{self, Register};
use crate::recording::survey_info::{Chainage, Heading, Placement};

/// What GNSS says of a run.
#[derive(Debug, Clone, PartialEq)]
pub struct GnssFit {
    /// Chainage of the run's track position 0 (odometer 0), m.
    pub start_m: f64,
    /// The direction of chainage with the odometer.
    pub heading: Heading,
    /// The largest of its fixes' tolerances, m.
    pub tolerance_m: f64,
    /// Fixes used by the fit.
    pub fixes: usize,
    /// Of those, beyond their tolerance of the fit.
    pub disagreeing: usize,
}

/// What placed a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum PlacedBy {
    /// Its GNSS fixes on the register.
    Gnss,
    /// The start typed for it (or registration, without one).
    Typed,
}

impl PlacedBy {
    /// Its name in the outputs.
    pub fn name(self) -> &'static str {
        match self {
            PlacedBy::Gnss => "gnss",
            PlacedBy::Typed => "typed",
        }
    }
}

/// How one run was placed with a track register.
#[derive(Debug, Clone, PartialEq)]
pub struct GnssPlacing {
    /// The run, from 1.
    pub run: usize,
    /// GNSS's placement, or why there is none.
    pub fit: Result<GnssFit, String>,
    /// The placement typed for the run.
    pub typed: Placement,
    /// The typed start's tolerance, m.
    pub typed_tolerance_m: f64,
    /// What placed it.
    pub used: PlacedBy,
}

impl GnssPlacing {
    /// Typed start less GNSS's, m, and their combined tolerance, m.
    pub fn start_difference_m(&self) -> Option<(f64, f64)> {
        let (fit, typed) = (self.fit.as_ref().ok()?, self.typed.start_m?);
        Some((typed - fit.start_m, fit.tolerance_m.hypot(self.typed_tolerance_m)))
    }

    /// Whether the typed start disagrees with GNSS's.
    pub fn start_disputed(&self) -> bool {
        self.start_difference_m().is_some_and(|(d, tol)| d.abs() > tol)
    }

    /// Whether the typed heading disagrees with GNSS's.
    pub fn heading_disputed(&self) -> bool {
        matches!((&self.fit, self.typed.heading), (Ok(f), Some(h)) if f.heading != h)
    }

    /// The placement used.
    pub fn placement(&self) -> Placement {
        match (&self.fit, self.used) {
            (Ok(f), PlacedBy::Gnss) => Placement { start_m: Some(f.start_m), heading: Some(f.heading) },
            _ => self.typed,
        }
    }
}

impl fmt::Display for GnssPlacing {
    /// One line: what placed the run and why, the check of the typed start.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "run {}: placed by {}",
            self.run,
            if self.used == PlacedBy::Gnss { "GNSS" } else { "its typed start" }
        )?;
        match &self.fit {
            Ok(g) => {
                write!(
                    f,
                    " — GNSS puts position 0 at {} (±{:.3} m, chainage {} with the odometer, {} fixes",
                    Chainage(g.start_m),
                    g.tolerance_m,
                    g.heading.name(),
                    g.fixes
                )?;
                if g.disagreeing > 0 {
                    write!(f, ", {} beyond their tolerance of the odometer: not used to place it", g.disagreeing)?;
                }
                f.write_str(")")?;
            }
            Err(why) => write!(f, " — GNSS cannot place it: {why}")?,
        }
        match (self.start_difference_m(), self.typed.start_m) {
            (Some((d, tol)), Some(t)) => {
                let verdict = if d.abs() > tol { "START DISPUTED" } else { "agrees" };
                write!(
                    f,
                    "; typed start {} is {d:+.3} m from it: {verdict} (combined tolerance {tol:.3} m)",
                    Chainage(t)
                )?;
            }
            (None, Some(t)) => write!(f, "; typed start {}", Chainage(t))?,
            _ => f.write_str("; no start typed")?,
        }
        if self.heading_disputed() {
            write!(f, "; HEADING DISPUTED: typed chainage {}", self.typed.heading.map_or("?", Heading::name))?;
        }
        Ok(())
    }
}

/// How each run is placed with `register`: `typed` is each run's typed
/// placement, `paths` its recording; `typed_tolerance_m` a typed start's.
pub fn place(
    register: &Register,
    paths: &[&Path],
    typed: &[Placement],
    typed_tolerance_m: f64,
) -> Result<Vec<GnssPlacing>, Error> {
    let mut out = Vec::new();
    for (i, (path, typed)) in paths.iter().zip(typed).enumerate() {
        let fit = fit(register, path)?;
        let used = match &fit {
            Ok(g) if g.disagreeing == 0 || typed.start_m.is_none() => PlacedBy::Gnss,
            _ => PlacedBy::Typed,
        };
        out.push(GnssPlacing { run: i + 1, fit, typed: *typed, typed_tolerance_m, used });
    }
    Ok(out)
}

/// GNSS's placement of one recording, or why there is none.
fn fit(register: &Register, path: &Path) -> Result<Result<GnssFit, String>, Error> {
    let (sessions, _) = crate::recording::fixes_of(path).map_err(Error::from)?;
    Ok(match sessions.as_slice() {
        [] => Err("no fixes".into()),
        [s] => match register::check(register, &s.fixes, &s.profiles) {
            Ok(c) => Ok(GnssFit {
                start_m: c.chainage_at_zero_m,
                heading: if c.scale >= 0.0 { Heading::Up } else { Heading::Down },
                tolerance_m: c.located.iter().map(|l| l.tolerance_m).fold(0.0, f64::max),
                fixes: c.located.len(),
                disagreeing: c.disagreeing(),
            }),
            Err(e) => Err(e.to_string()),
        },
        many => Err(format!("fixes in {} head sessions (the odometer restarts in each)", many.len())),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn placing(typed: Placement, fit: Result<GnssFit, String>) -> GnssPlacing {
        let used = if fit.is_ok() { PlacedBy::Gnss } else { PlacedBy::Typed };
        GnssPlacing { run: 1, fit, typed, typed_tolerance_m: 25.0, used }
    }

    fn fit(start_m: f64) -> Result<GnssFit, String> {
        Ok(GnssFit { start_m, heading: Heading::Up, tolerance_m: 0.18, fixes: 99, disagreeing: 0 })
    }

    #[test]
    fn a_typed_start_beyond_the_combined_tolerance_is_disputed() {
        let typed = |m: f64, h| Placement { start_m: Some(m), heading: Some(h) };
        let p = placing(typed(41_110.0, Heading::Up), fit(41_100.0));
        assert!(!p.start_disputed() && !p.heading_disputed());
        assert_eq!(p.placement().start_m, Some(41_100.0));
        let p = placing(typed(41_200.0, Heading::Down), fit(41_100.0));
        assert!(p.start_disputed() && p.heading_disputed());
        let line = p.to_string();
        assert!(line.contains("placed by GNSS") && line.contains("+100.000 m from it: START DISPUTED"), "{line}");
        assert!(line.contains("combined tolerance 25.001 m") && line.contains("HEADING DISPUTED"), "{line}");
        // Without a fit the typed start stands.
        let p = placing(typed(41_200.0, Heading::Up), Err("no fixes".into()));
        assert_eq!((p.placement().start_m, p.start_disputed()), (Some(41_200.0), false));
        assert!(p.to_string().contains("GNSS cannot place it: no fixes"));
    }
}
