//! The verdict a level measured over a noise floor can earn against a
//! limit: the decision threshold and detection limit of ISO 11843 applied
//! to a one-third octave's ISO 3095 comparison.
//!
//! A band's measured power `P` (rail and noise together) is a Welch
//! average with `ν` equivalent degrees of freedom, `P̂ ~ P·χ²_ν/ν`; the
//! floor's `F` one with `ν_f`. The rail's own power is `R = P − F` (rail
//! and noise are independent: their powers add).
//!
//! * **within** when the upper confidence bound of `P` — noise included —
//!   is under the limit: the rail is at most the reading, so a good rail
//!   passes however high the floor.
//! * **EXCEEDS** when the lower bound of `R` is over the limit: the rail
//!   itself, the floor's power taken out, is over it with confidence.
//! * **not judged** between the two, with the floor, the limit and what
//!   would settle it (`settle`: a longer record where the
//!   interval's narrowing would decide, a lower floor where the floor
//!   itself stands at or over the limit).
//!
//! Each bound is one-sided at [`Z`] standard deviations (5 × 10⁻⁴): a
//! survey holds some sixty decisions (three lines and their average, about
//! twenty third octaves each, and the blocks'), so that noise alone reads
//! "EXCEEDS" once in tens of surveys rather than once in each. The rail's
//! interval `[P_lo − F_hi, P_hi − F_lo]` takes each of its two bounds at
//! [`Z_PAIR`] (half the risk each: together at least the same confidence).
//! A band a few FFT bins wide holds only part of a rail component at its
//! centre (the Hann window spreads it into the neighbours: 0.67 of it for
//! a band one bin wide), so the upper bounds are divided by that share
//! (`en15610::tone_capture`): the reading may be low, never the bound.
//! χ² quantiles are Wilson–Hilferty's (`χ²_p(ν)/ν ≈ (1 − 2/9ν + z√(2/9ν))³`,
//! within 1 % of the exact ones from ν = 3 at these tails): no statistics
//! crate is needed for one formula.

use std::fmt;

/// One-sided standard normal deviate of each bound: 5 × 10⁻⁴.
pub const Z: f64 = 3.29;
/// One-sided deviate of each of the two estimates a difference's bound
/// is made of: 2.5 × 10⁻⁴ each, 5 × 10⁻⁴ together.
pub const Z_PAIR: f64 = 3.48;
/// The confidence of the intervals reported, percent (two-sided, [`Z`] a side).
pub const CONFIDENCE_PERCENT: f64 = 99.9;

/// What a band earns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Its level, noise included, is under the limit with confidence.
    Within,
    /// The rail's own level, the floor's power taken out, is over the limit with confidence.
    Exceeds,
    /// Neither: the floor and the record's length cannot tell.
    NotJudged,
}

impl Verdict {
    /// The word the outputs carry: "within", "EXCEEDS", "not judged".
    pub fn name(self) -> &'static str {
        match self {
            Verdict::Within => "within",
            Verdict::Exceeds => "EXCEEDS",
            Verdict::NotJudged => "not judged",
        }
    }
}

impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A level's power estimate: level dB and its equivalent degrees of freedom.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    pub level_db: f64,
    pub dof: f64,
}

impl Estimate {
    fn power(&self) -> f64 {
        10f64.powf(self.level_db / 10.0)
    }

    /// Lower and upper bounds of the power at `z` deviations a side (upper `∞` when unbounded).
    fn bounds(&self, z: f64) -> (f64, f64) {
        let p = self.power();
        let (lo, hi) = (chi2_over_dof(self.dof, z), chi2_over_dof(self.dof, -z));
        (p / lo, if hi > 0.0 { p / hi } else { f64::INFINITY })
    }
}

/// `χ²_p(ν)/ν` at the normal deviate `z` of `p` (Wilson–Hilferty); 0 where
/// the approximation runs below zero (few degrees of freedom, far tail).
pub fn chi2_over_dof(dof: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * dof.max(0.5));
    (1.0 - a + z * a.sqrt()).max(0.0).powi(3)
}

/// The rail's own level with the floor taken out, dB re 1 µm, and its
/// interval at [`CONFIDENCE_PERCENT`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RailLevel {
    /// The estimate (`None`: the reading is at or under the floor).
    pub db: Option<f64>,
    /// The lower bound (`None`: the rail may be nothing at all).
    pub lo_db: Option<f64>,
    /// The upper bound (`None`: unbounded, too few degrees of freedom).
    pub hi_db: Option<f64>,
}

impl fmt::Display for RailLevel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let v = |d: Option<f64>| d.map_or("-".to_string(), |d| format!("{d:.1}"));
        match (self.lo_db, self.hi_db) {
            (Some(lo), Some(hi)) => write!(f, "{} [{lo:.1}, {hi:.1}]", v(self.db)),
            (None, Some(hi)) => write!(f, "{} [under {hi:.1}]", v(self.db)),
            (Some(lo), None) => write!(f, "{} [over {lo:.1}]", v(self.db)),
            (None, None) => write!(f, "{} [unbounded]", v(self.db)),
        }
    }
}

/// A band's ISO 3095 decision: its verdict and the figures it rests on.
#[derive(Debug, Clone, PartialEq)]
pub struct Decision {
    pub verdict: Verdict,
    /// The measured level (rail and noise), dB re 1 µm.
    pub level_db: f64,
    /// Its upper confidence bound, dB (`None`: unbounded).
    pub level_hi_db: Option<f64>,
    /// The rail's own level and interval.
    pub rail: RailLevel,
    pub limit_db: f64,
    /// The floor the rail was taken out of (`None`: not known; the rail is the reading).
    pub floor_db: Option<f64>,
    /// For a band not judged: what would settle it.
    pub settle: Option<String>,
}

fn db(p: f64) -> Option<f64> {
    (p.is_finite() && p > 0.0).then(|| 10.0 * p.log10())
}

/// The verdict alone of `level` over `floor` against `limit_db`, the band
/// holding at least `capture` of a rail component in it.
fn verdict_of(level: Estimate, floor: Option<Estimate>, limit: f64, capture: f64) -> (Verdict, (f64, f64)) {
    let (_, p_hi) = level.bounds(Z);
    let p_hi = p_hi / capture;
    let (p_lo2, p_hi2) = level.bounds(Z_PAIR);
    let p_hi2 = p_hi2 / capture;
    let rail = match floor {
        Some(f) => {
            let (f_lo2, f_hi2) = f.bounds(Z_PAIR);
            ((p_lo2 - f_hi2).max(0.0), (p_hi2 - f_lo2).max(0.0))
        }
        None => (p_lo2, p_hi2),
    };
    let v = if p_hi < limit {
        Verdict::Within
    } else if rail.0 > limit {
        Verdict::Exceeds
    } else {
        Verdict::NotJudged
    };
    (v, rail)
}

impl Decision {
    /// The decision for `level` over `floor` (`None`: not known) against
    /// `limit_db`, the band holding at least `capture` (0–1) of a rail
    /// component in it: the rest leaks to its neighbours, so the reading's
    /// upper bound, and the rail's, are divided by it.
    pub fn of(level: Estimate, floor: Option<Estimate>, limit_db: f64, capture: f64) -> Decision {
        let capture = capture.clamp(0.05, 1.0);
        let limit = 10f64.powf(limit_db / 10.0);
        let (verdict, (r_lo, r_hi)) = verdict_of(level, floor, limit, capture);
        let rail_power = level.power() - floor.map_or(0.0, |f| f.power());
        let (_, p_hi) = level.bounds(Z);
        let p_hi = p_hi / capture;
        let mut d = Decision {
            verdict,
            level_db: level.level_db,
            level_hi_db: db(p_hi),
            rail: RailLevel { db: db(rail_power), lo_db: db(r_lo), hi_db: db(r_hi) },
            limit_db,
            floor_db: floor.map(|f| f.level_db),
            settle: None,
        };
        if verdict == Verdict::NotJudged {
            d.settle = Some(settle(level, floor, limit_db, capture));
        }
        d
    }

    /// The verdict in words, with the floor and the limit and what would
    /// settle it where not judged.
    pub fn words(&self) -> String {
        match (self.verdict, &self.settle) {
            (Verdict::NotJudged, Some(s)) => format!(
                "not judged (floor {}, limit {:.1} dB: {s})",
                self.floor_db.map_or("not known".into(), |f| format!("{f:.1} dB")),
                self.limit_db
            ),
            (v, _) => v.name().to_string(),
        }
    }
}

/// What would settle a band not judged. As the record grows (more
/// segments: a longer survey, or more runs joined) both bounds close on
/// the readings, at the rate the χ² quantiles narrow with the degrees of
/// freedom: a longer record can show the band within only if its reading
/// is under the limit, EXCEEDS only if the rail's own reading is over it.
/// It narrows the interval; it does not lower the floor. So where the
/// floor itself stands at or over the limit, within is out of reach at
/// any length, and only a lower floor could show the rail within.
fn settle(level: Estimate, floor: Option<Estimate>, limit_db: f64, capture: f64) -> String {
    let limit = 10f64.powf(limit_db / 10.0);
    let times = longer_record(level, floor, limit, capture);
    let as_long = |m: f64| format!("a record about {}× as long (or as many runs joined)", fmt_times(m));
    match floor {
        Some(f) if f.level_db >= limit_db => {
            let mut s = format!(
                "within is out of reach at any record length: the floor stands {:.1} dB over the limit, and only a \
                 lower floor (other light, speckle diversity, averaged repeat runs) could show the rail within; a \
                 longer record could still show EXCEEDS if the rail is over the limit",
                f.level_db - limit_db
            );
            let (_, (rail_lo, _)) = verdict_of(level, floor, limit, capture);
            let rail_db = db(level.power() - f.power());
            match (times, rail_db) {
                // The rail stands out of the floor, and its reading is over the limit.
                (Some(m), Some(r)) if rail_lo > 0.0 => {
                    s += &format!(" (it reads {r:.1} dB: {} would show it)", as_long(m));
                }
                _ if rail_lo > 0.0 => s += " (it stands out of the floor, its reading under the limit)",
                _ => s += " (it does not stand out of the floor yet)",
            }
            s
        }
        _ => match times {
            Some(m) => format!("{} would settle it", as_long(m)),
            None => {
                let p = level.power();
                let rail = p - floor.map_or(0.0, |f| f.power());
                if p / capture >= limit && rail <= limit {
                    "the rail reads at the limit: no length of record settles it at this floor, only a lower floor \
                     (other light, speckle diversity, averaged repeat runs)"
                        .into()
                } else {
                    format!("only a record over {LONGEST:.0}× as long, or a lower floor, would settle it")
                }
            }
        },
    }
}

/// The longest record offered, as a multiple of this one.
const LONGEST: f64 = 100.0;

/// The shortest multiple of the record (1 to [`LONGEST`]) whose degrees
/// of freedom, the readings the same, would decide the band: the bounds
/// narrow monotonically with the degrees of freedom, so a bisection on
/// the multiple finds it (`None`: not within [`LONGEST`]).
fn longer_record(level: Estimate, floor: Option<Estimate>, limit: f64, capture: f64) -> Option<f64> {
    let decided = |m: f64| {
        let more = |e: Estimate| Estimate { dof: e.dof * m, ..e };
        verdict_of(more(level), floor.map(more), limit, capture).0 != Verdict::NotJudged
    };
    if !decided(LONGEST) {
        return None;
    }
    let (mut lo, mut hi) = (1.0, LONGEST);
    while hi / lo > 1.01 {
        let mid = (lo * hi).sqrt();
        if decided(mid) { hi = mid } else { lo = mid }
    }
    Some(hi)
}

/// A record multiple rounded up: a tenth under 10, a whole number over.
fn fmt_times(m: f64) -> String {
    if m < 10.0 { format!("{:.1}", (m * 10.0).ceil() / 10.0) } else { format!("{:.0}", m.ceil()) }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Wilson–Hilferty against tabulated quantiles: χ²₀.₀₅(10) = 3.940,
    /// χ²₀.₉₅(10) = 18.307, χ²₀.₀₀₀₅(89) ≈ 50.9 (z = 1.645, 3.29).
    #[test]
    fn chi_square_quantiles_are_close_to_the_tables() {
        assert!((chi2_over_dof(10.0, -1.645) * 10.0 - 3.940).abs() < 0.05);
        assert!((chi2_over_dof(10.0, 1.645) * 10.0 - 18.307).abs() < 0.1);
        assert!((chi2_over_dof(89.0, -3.29) * 89.0 - 50.9).abs() < 1.0);
    }

    fn est(level_db: f64, dof: f64) -> Estimate {
        Estimate { level_db, dof }
    }

    /// A reading far under the limit is within however high its floor;
    /// a rail far over the limit and its floor exceeds; a rail at the
    /// limit under a floor above it is not judged, with what would settle it.
    #[test]
    fn the_three_verdicts() {
        let within = Decision::of(est(-40.0, 90.0), Some(est(-40.2, 180.0)), -5.6, 1.0);
        assert_eq!(within.verdict, Verdict::Within);
        let over = Decision::of(est(10.0, 90.0), Some(est(-10.0, 180.0)), 0.0, 1.0);
        assert_eq!(over.verdict, Verdict::Exceeds);
        let r = over.rail;
        assert!(r.lo_db.unwrap() < 10.0 && r.hi_db.unwrap() > 10.0 && r.lo_db.unwrap() > 0.0, "{r}");
        let noise = Decision::of(est(10.0, 90.0), Some(est(10.0, 180.0)), 0.0, 1.0);
        assert_eq!(noise.verdict, Verdict::NotJudged);
        assert!(noise.words().contains("floor 10.0 dB") && noise.words().contains("lower floor"), "{}", noise.words());
        let close = Decision::of(est(-1.0, 20.0), Some(est(-20.0, 40.0)), 0.0, 1.0);
        assert_eq!(close.verdict, Verdict::NotJudged);
        assert!(close.words().contains("as long"), "{}", close.words());
    }

    /// A floor over the limit: within is out of reach whatever the
    /// record's length, and the words say so, with by how much the floor
    /// stands over it; no longer record is offered for noise that does
    /// not stand out of the floor, one is where the rail does and reads
    /// over the limit.
    #[test]
    fn a_floor_over_the_limit_cannot_be_outwaited() {
        // A smooth rail: the reading is the floor's, 15 dB over the limit.
        let smooth = Decision::of(est(15.5, 90.0), Some(est(15.0, 180.0)), 0.0, 1.0);
        assert_eq!(smooth.verdict, Verdict::NotJudged);
        let w = smooth.words();
        assert!(w.contains("out of reach") && w.contains("15.0 dB over the limit"), "{w}");
        assert!(w.contains("lower floor") && w.contains("EXCEEDS") && !w.contains("× as long"), "{w}");
        assert!(w.contains("does not stand out of the floor"), "{w}");
        // A rail standing out of a floor 1 dB over the limit, its reading 1 dB over it.
        let rail = Decision::of(est(18.0, 400.0), Some(est(15.0, 800.0)), 14.0, 1.0);
        assert_eq!(rail.verdict, Verdict::NotJudged);
        let w = rail.words();
        assert!(w.contains("out of reach") && w.contains("1.0 dB over the limit") && w.contains("× as long"), "{w}");
        // Whatever the length, never within.
        let limit = 10f64.powf(14.0 / 10.0);
        let huge = |e: Estimate| Estimate { dof: e.dof * 1e6, ..e };
        let (v, _) = verdict_of(huge(est(15.0, 90.0)), Some(huge(est(15.0, 180.0))), limit, 1.0);
        assert_ne!(v, Verdict::Within);
    }

    /// Under the floor's limit the record multiple offered is the least
    /// that decides: the interval at that many more degrees of freedom
    /// decides, at 5 % fewer it does not; a reading at the limit is
    /// offered no length at all.
    #[test]
    fn the_longer_record_offered_is_the_one_that_settles() {
        for (level, floor, limit) in [(-1.0, -20.0, 0.0), (3.0, -6.0, 0.0), (-3.0, -3.5, -1.0)] {
            let (l, f) = (est(level, 20.0), Some(est(floor, 40.0)));
            let d = Decision::of(l, f, limit, 1.0);
            assert_eq!(d.verdict, Verdict::NotJudged, "{level} {floor}");
            let lim = 10f64.powf(limit / 10.0);
            let m = longer_record(l, f, lim, 1.0).expect("a length that settles it");
            let more = |e: Estimate, m: f64| Estimate { dof: e.dof * m, ..e };
            assert_ne!(verdict_of(more(l, m), f.map(|f| more(f, m)), lim, 1.0).0, Verdict::NotJudged);
            assert_eq!(verdict_of(more(l, m / 1.05), f.map(|f| more(f, m / 1.05)), lim, 1.0).0, Verdict::NotJudged);
            assert!(d.words().contains(&format!("about {}× as long", fmt_times(m))), "{}", d.words());
        }
        // The reading over the limit, the rail's own under it: no length settles it.
        let at = Decision::of(est(0.2, 20.0), Some(est(-3.0, 40.0)), 0.0, 1.0);
        assert_eq!(at.verdict, Verdict::NotJudged);
        assert!(at.words().contains("at the limit") && !at.words().contains("× as long"), "{}", at.words());
    }
}
