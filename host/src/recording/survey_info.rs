//! What a recording is of: the survey metadata a user gives `listen
//! --survey FILE.toml` — line, track, rail, where the run starts and which
//! way chainage runs, who measured with what — carried in the recording's
//! header (format version 2, [`crate::recording`]) so that the file says
//! where on the network it was taken, and `analyze` places the run by it.
//!
//! ```toml
//! line = "LN 1234 Northtown–Southville"
//! track = "up main"
//! rail = "left"                 # left | right, facing the direction chainage runs
//! start_chainage = "12+345.600" # of the odometer's zero (km+m, or metres)
//! chainage = "up"               # up | down: chainage with the odometer
//! date = "2026-05-14"           # of the survey, ISO 8601 (YYYY-MM-DD)
//! operator = "A. Engineer"
//! instrument = "CMS head 0042"
//! notes = "after grinding, pass 2"
//!
//! [optics]                      # what set the speckle: the lens's iris, the lasers
//! f_number = 2.8
//! wavelength_nm = 685.0
//! ```
//!
//! `[optics]` is written by `listen` from the head's calibration
//! (`[head]`'s `f_number`, `wavelength_nm`), its `--optics`, or the
//! simulated head's own light; `analyze` predicts the noise floor from it
//! (docs/noise-floor.md#the-floor-the-optics-predict). Every key is optional (a block written before `date` existed reads as
//! it did, without a date); unknown keys are refused (a typo must not pass
//! silently). The date is a quoted string, checked to be a real day. The text is stored as given (at most [`MAX_BYTES`]), so a
//! later build reads keys this one does not know.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::model::optics::Optics;

/// The largest survey block a recording holds, bytes.
pub const MAX_BYTES: usize = 16 * 1024;

/// Which rail of the track.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RailSide {
    Left,
    Right,
}

/// The survey a recording belongs to.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Survey {
    pub line: Option<String>,
    pub track: Option<String>,
    pub rail: Option<RailSide>,
    /// Chainage of the odometer's zero, `km+m` or metres.
    pub start_chainage: Option<String>,
    /// `up` or `down`: chainage with the odometer.
    pub chainage: Option<String>,
    /// The day of the survey, `YYYY-MM-DD` ([`SurveyDate`]).
    pub date: Option<String>,
    pub operator: Option<String>,
    pub instrument: Option<String>,
    pub notes: Option<String>,
    /// The lens's F-number and the lasers' wavelength (`[optics]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub optics: Option<Optics>,
}

/// What is wrong with a survey file, a chainage or a placement; the text
/// names the key or quotes the value.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SurveyError {
    /// A survey file longer than a recording's survey block holds.
    #[error("{0} bytes: a survey file holds at most {MAX_BYTES}")]
    TooLong(usize),
    /// Not TOML, or a key this format does not have.
    #[error("{0}")]
    Toml(String),
    /// Neither `km+m` nor metres.
    #[error("`{0}` is not a chainage (km+m, e.g. 12+345.678, or metres)")]
    NotAChainage(String),
    /// `km+m` with the metres outside 0 to 1000.
    #[error("`{0}`: the metres after + must be 0 to under 1000")]
    Metres(String),
    /// The survey's `start_chainage`.
    #[error("start_chainage: {0}")]
    StartChainage(Box<SurveyError>),
    /// The survey's `chainage`, neither up nor down.
    #[error("chainage: `{0}` is neither up nor down")]
    Heading(String),
    /// A placement's heading, neither up nor down.
    #[error("`{0}`: heading `{1}` is neither up nor down")]
    PlacementHeading(String, String),
    /// Not a day written `YYYY-MM-DD`.
    #[error("`{0}` is not a date (YYYY-MM-DD, a real day)")]
    NotADate(String),
    /// The survey's `date`.
    #[error("date: {0}")]
    Date(Box<SurveyError>),
}

/// A survey's day (ISO 8601 calendar date), ordered; days between two by
/// subtraction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct SurveyDate(chrono::NaiveDate);

impl SurveyDate {
    /// The year (a fleet's surveys partitioned by it).
    pub fn year(self) -> i32 {
        use chrono::Datelike as _;
        self.0.year()
    }

    /// Days since 0001-01-01 (proleptic Gregorian).
    pub fn day_number(self) -> i64 {
        use chrono::Datelike as _;
        i64::from(self.0.num_days_from_ce())
    }

    /// The date `days` after this one (`None` past year 262 143).
    pub fn plus_days(self, days: i64) -> Option<SurveyDate> {
        self.0.checked_add_signed(chrono::TimeDelta::try_days(days)?).map(SurveyDate)
    }

    /// Years (of 365.2425 days) from `earlier` to this date.
    pub fn years_since(self, earlier: SurveyDate) -> f64 {
        (self.day_number() - earlier.day_number()) as f64 / DAYS_PER_YEAR
    }
}

/// The mean Gregorian year, days.
pub const DAYS_PER_YEAR: f64 = 365.2425;

impl fmt::Display for SurveyDate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use chrono::Datelike as _;
        write!(f, "{:04}-{:02}-{:02}", self.0.year(), self.0.month(), self.0.day())
    }
}

impl FromStr for SurveyDate {
    type Err = SurveyError;

    /// Exactly `YYYY-MM-DD`, a day that exists (no times, no week dates).
    fn from_str(s: &str) -> Result<Self, SurveyError> {
        let bad = || SurveyError::NotADate(s.to_string());
        let b = s.as_bytes();
        let shape = b.len() == 10
            && b[4] == b'-'
            && b[7] == b'-'
            && b.iter().enumerate().all(|(i, c)| i == 4 || i == 7 || c.is_ascii_digit());
        if !shape {
            return Err(bad());
        }
        let num = |r: std::ops::Range<usize>| s[r].parse::<u32>().map_err(|_| bad());
        let year = i32::try_from(num(0..4)?).map_err(|_| bad())?;
        chrono::NaiveDate::from_ymd_opt(year, num(5..7)?, num(8..10)?).map(SurveyDate).ok_or_else(bad)
    }
}

impl Survey {
    /// Parses and checks a survey file's text; the error names the key.
    pub fn parse(text: &str) -> Result<Survey, SurveyError> {
        if text.len() > MAX_BYTES {
            return Err(SurveyError::TooLong(text.len()));
        }
        let s: Survey = toml::from_str(text).map_err(|e| SurveyError::Toml(e.message().to_string()))?;
        s.placement()?;
        s.date()?;
        Ok(s)
    }

    /// The survey's day, if it has one.
    pub fn date(&self) -> Result<Option<SurveyDate>, SurveyError> {
        self.date.as_deref().map(|d| d.parse().map_err(|e| SurveyError::Date(Box::new(e)))).transpose()
    }

    /// The placement of the run it describes.
    pub fn placement(&self) -> Result<Placement, SurveyError> {
        let start_m = match &self.start_chainage {
            Some(c) => Some(c.parse::<Chainage>().map_err(|e| SurveyError::StartChainage(Box::new(e)))?.0),
            None => None,
        };
        let heading = match self.chainage.as_deref().map(str::to_ascii_lowercase).as_deref() {
            None => None,
            Some("up") => Some(Heading::Up),
            Some("down") => Some(Heading::Down),
            Some(o) => return Err(SurveyError::Heading(o.to_string())),
        };
        Ok(Placement { start_m, heading })
    }

    /// Reads and checks a survey file (at most one byte past
    /// [`MAX_BYTES`] is read: a device or a huge file is refused by its
    /// size, not read without end); the error names the file.
    pub fn load(path: &std::path::Path) -> Result<Survey, crate::Error> {
        use std::io::Read as _;
        let name = path.display();
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .and_then(|f| f.take(MAX_BYTES as u64 + 1).read_to_end(&mut bytes))
            .map_err(|e| crate::Error::Input(format!("cannot read {name}: {e}")))?;
        let text = String::from_utf8(bytes).map_err(|_| crate::Error::Input(format!("{name}: not UTF-8 text")))?;
        Survey::parse(&text).map_err(|e| crate::Error::Input(format!("{name}: {e}")))
    }

    /// The text stored in a recording.
    pub fn to_text(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }

    /// One line for people: "line …, track …, left rail, from 12+345.600 up,
    /// operator …"; what the user wrote shown, never acted on
    /// ([`crate::output::printable`]: no terminal escapes, no line breaks).
    pub fn describe(&self) -> String {
        use crate::output::printable;
        let mut parts = Vec::new();
        if let Some(l) = &self.line {
            parts.push(format!("line {}", printable(l)));
        }
        if let Some(t) = &self.track {
            parts.push(format!("track {}", printable(t)));
        }
        if let Some(r) = self.rail {
            parts.push(format!("{} rail", if r == RailSide::Left { "left" } else { "right" }));
        }
        if let Ok(p) = self.placement() {
            match (p.start_m, p.heading) {
                (Some(m), h) => parts.push(format!(
                    "odometer 0 at {}{}",
                    Chainage(m),
                    h.map_or(String::new(), |h| format!(", chainage {}", h.name()))
                )),
                (None, Some(h)) => parts.push(format!("chainage {}", h.name())),
                (None, None) => {}
            }
        }
        match self.date() {
            Ok(Some(d)) => parts.push(format!("surveyed {d}")),
            Ok(None) => {}
            Err(_) => parts.push(format!("date {}", printable(self.date.as_deref().unwrap_or_default()))),
        }
        if let Some(o) = &self.operator {
            parts.push(format!("operator {}", printable(o)));
        }
        if let Some(i) = &self.instrument {
            parts.push(format!("instrument {}", printable(i)));
        }
        if let Some(o) = &self.optics {
            parts.push(format!("optics {o}"));
        }
        if let Some(n) = &self.notes {
            parts.push(format!("notes: {}", printable(n)));
        }
        if parts.is_empty() { "no survey details".into() } else { parts.join(", ") }
    }
}

/// Which way chainage runs along a run's track position.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Heading {
    /// Chainage increases with track position.
    Up,
    /// Chainage decreases with track position (the run was driven the other way).
    Down,
}

impl Heading {
    /// "up" or "down".
    pub fn name(self) -> &'static str {
        match self {
            Heading::Up => "up",
            Heading::Down => "down",
        }
    }
}

/// A position along the line, metres; printed and read as `km+m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Chainage(pub f64);

impl fmt::Display for Chainage {
    /// `12+345.678` (`-0+012.500` before the origin).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let m = (self.0 * 1000.0).round() / 1000.0;
        let sign = if m < 0.0 { "-" } else { "" };
        let a = m.abs();
        let km = (a / 1000.0).floor();
        write!(f, "{sign}{km:.0}+{:07.3}", a - km * 1000.0)
    }
}

impl FromStr for Chainage {
    type Err = SurveyError;

    /// `12+345.678` (km + m) or `12345.678` (m).
    fn from_str(s: &str) -> Result<Self, SurveyError> {
        let t = s.trim();
        let bad = || SurveyError::NotAChainage(s.to_string());
        let (neg, body) = match t.strip_prefix('-') {
            Some(b) => (true, b),
            None => (false, t),
        };
        // Plain decimals only: Rust's float syntax would also take a sign,
        // an exponent, `inf` and `NaN` (`--5`, `12+1e2`), none of which a
        // chainage is written with.
        let m = match body.split_once('+') {
            Some((km, m)) => {
                let km = decimal(km).filter(|_| !km.contains('.')).ok_or_else(bad)?;
                let m = decimal(m).ok_or_else(bad)?;
                if !(0.0..1000.0).contains(&m) {
                    return Err(SurveyError::Metres(s.to_string()));
                }
                km * 1000.0 + m
            }
            None => decimal(body).ok_or_else(bad)?,
        };
        if !m.is_finite() || m.abs() > 1e8 {
            return Err(bad());
        }
        Ok(Chainage(if neg { -m } else { m }))
    }
}

/// A plain decimal: digits, then optionally a point and digits.
fn decimal(s: &str) -> Option<f64> {
    let (int, frac) = s.split_once('.').unwrap_or((s, "0"));
    let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
    (digits(int) && digits(frac)).then(|| s.parse().ok()).flatten()
}

/// Where a run lies on the line, as far as its user said.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Placement {
    /// Chainage of the run's track position 0, m (`None`: unknown, found by registration).
    pub start_m: Option<f64>,
    /// `None`: unknown, found by registration (the first run: up).
    pub heading: Option<Heading>,
}

impl FromStr for Placement {
    type Err = SurveyError;

    /// `KM+M`, `KM+M:up`, `KM+M:down`, `:down` or `auto`.
    fn from_str(s: &str) -> Result<Self, SurveyError> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("auto") {
            return Ok(Placement::default());
        }
        let (c, h) = match t.rsplit_once(':') {
            Some((c, h)) => (c, Some(h)),
            None => (t, None),
        };
        let heading = match h.map(str::to_ascii_lowercase).as_deref() {
            None => None,
            Some("up") => Some(Heading::Up),
            Some("down") => Some(Heading::Down),
            Some(o) => return Err(SurveyError::PlacementHeading(s.to_string(), o.to_string())),
        };
        let start_m = if c.is_empty() { None } else { Some(c.parse::<Chainage>()?.0) };
        Ok(Placement { start_m, heading })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_survey_file_parses_and_places_its_run() {
        let s = Survey::parse(
            "line = \"LN 1\"\ntrack = \"up main\"\nrail = \"left\"\nstart_chainage = \"12+345.6\"\nchainage = \"down\"\n",
        )
        .unwrap();
        assert_eq!(s.placement().unwrap(), Placement { start_m: Some(12_345.6), heading: Some(Heading::Down) });
        assert_eq!(Survey::parse(&s.to_text()).unwrap(), s);
        assert!(s.describe().contains("line LN 1, track up main, left rail, odometer 0 at 12+345.600, chainage down"));
    }

    #[test]
    fn what_the_user_wrote_is_shown_not_acted_on() {
        let s = Survey::parse(
            r#"line = "LN\u001b[31m 1"
notes = "pass 2\u001b]0;owned\u0007\nsecond line"
"#,
        )
        .unwrap();
        let d = s.describe();
        assert!(!d.chars().any(char::is_control), "{d:?}");
        assert!(
            d.contains("line LN\\u{1b}[31m 1") && d.contains("pass 2\\u{1b}]0;owned\\u{7}\\u{a}second line"),
            "{d}"
        );
    }

    #[test]
    fn a_survey_has_a_date_or_none() {
        let s = Survey::parse("line = \"LN 1\"\ndate = \"2026-05-14\"\n").unwrap();
        let d = s.date().unwrap().unwrap();
        assert_eq!(d.to_string(), "2026-05-14");
        assert_eq!(Survey::parse(&s.to_text()).unwrap(), s);
        assert!(s.describe().contains("surveyed 2026-05-14"), "{}", s.describe());
        // A block written before the key existed.
        assert_eq!(Survey::parse("line = \"LN 1\"\n").unwrap().date().unwrap(), None);
        let e: SurveyDate = "2027-05-14".parse().unwrap();
        assert!((e.years_since(d) - 365.0 / DAYS_PER_YEAR).abs() < 1e-12);
        assert_eq!(d.plus_days(365), Some(e));
        assert_eq!("2024-02-29".parse::<SurveyDate>().unwrap().to_string(), "2024-02-29");
        for bad in ["2023-02-29", "2026-13-01", "2026-5-14", "2026-05-14T00:00", "+2026-05-14", "2026-05-1x", ""] {
            assert!(bad.parse::<SurveyDate>().is_err(), "{bad} was taken");
        }
    }

    #[test]
    fn a_survey_says_what_optics_it_was_made_with() {
        let text = "line = \"LN 1\"\n\n[optics]\nf_number = 2.8\nwavelength_nm = 685.0\n";
        let s = Survey::parse(text).unwrap();
        assert_eq!(s.optics, Some(Optics::new(2.8, 685.0).unwrap()));
        // Written byte for byte as read: the block a recording stores.
        assert_eq!(s.to_text(), text);
        assert!(s.describe().contains("optics F/2.8, 685 nm"), "{}", s.describe());
        // A block without the table (every recording before it) reads as it did.
        assert_eq!(Survey::parse("line = \"LN 1\"\n").unwrap().optics, None);
        for (bad, want) in [
            ("[optics]\nf_number = 0.1\nwavelength_nm = 685.0\n", "f_number 0.1"),
            ("[optics]\nf_number = 2.8\nwavelength_nm = 5.0\n", "wavelength_nm 5"),
            ("[optics]\nf_number = 2.8\n", "wavelength_nm"),
            ("[optics]\nf_number = 2.8\nwavelength_nm = 685.0\niris = 1\n", "iris"),
        ] {
            let e = Survey::parse(bad).unwrap_err().to_string();
            assert!(e.contains(want), "{bad}: {e}");
        }
    }

    #[test]
    fn chainages_are_plain_decimals() {
        for (text, m) in
            [("12+345.678", 12_345.678), ("0+000", 0.0), ("12345.5", 12_345.5), ("-0+250", -250.0), ("7", 7.0)]
        {
            assert_eq!(text.parse::<Chainage>().unwrap().0, m, "{text}");
        }
        for text in [
            "--5", "12+1e2", "1e3", "+5", "12+-3", "1.5+200", "inf", "NaN", "12+", "+", "", "-", "12+3.", ".5", "0x10",
            "1_000",
        ] {
            assert!(text.parse::<Chainage>().is_err(), "{text} was taken");
        }
    }

    #[test]
    fn bad_survey_files_name_the_key() {
        for (text, want) in [
            ("lnie = \"x\"\n", "lnie"),
            ("rail = \"middle\"\n", "middle"),
            ("start_chainage = \"12+3456\"\n", "start_chainage"),
            ("chainage = \"sideways\"\n", "sideways"),
            ("date = \"2026-02-30\"\n", "date: `2026-02-30`"),
            ("date = \"14/05/2026\"\n", "date"),
            ("date = 2026-05-14\n", "string"),
            ("line = 3\n", "string"),
            ("date = \"2026-02-30\"\n", "date"),
            ("date = \"26-12-04\"\n", "date"),
            ("date = \"2026-13-01\"\n", "date"),
        ] {
            let e = Survey::parse(text).unwrap_err();
            assert!(e.to_string().contains(want), "{text}: {e}");
        }
    }
}
