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
//! date = "2026-12-04"         # the day of the run, YYYY-MM-DD
//! operator = "A. Engineer"
//! instrument = "CMS head 0042"
//! notes = "after grinding, pass 2"
//! ```
//!
//! Every key is optional; unknown keys are refused (a typo must not pass
//! silently). The text is stored as given (at most [`MAX_BYTES`]), so a
//! later build reads keys this one does not know.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

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
    /// The day of the run, `YYYY-MM-DD` (a fleet's surveys partitioned by year).
    pub date: Option<String>,
    pub operator: Option<String>,
    pub instrument: Option<String>,
    pub notes: Option<String>,
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
    /// The survey's `date`, not a `YYYY-MM-DD` day.
    #[error("date: `{0}` is not a day (YYYY-MM-DD)")]
    Date(String),
    /// A placement's heading, neither up nor down.
    #[error("`{0}`: heading `{1}` is neither up nor down")]
    PlacementHeading(String, String),
}

impl Survey {
    /// Parses and checks a survey file's text; the error names the key.
    pub fn parse(text: &str) -> Result<Survey, SurveyError> {
        if text.len() > MAX_BYTES {
            return Err(SurveyError::TooLong(text.len()));
        }
        let s: Survey = toml::from_str(text).map_err(|e| SurveyError::Toml(e.message().to_string()))?;
        s.placement()?;
        s.day()?;
        Ok(s)
    }

    /// The `date` as (year, month, day), checked (the Gregorian calendar's
    /// month lengths, years 1000 to 9999).
    pub fn day(&self) -> Result<Option<(u16, u8, u8)>, SurveyError> {
        let Some(text) = &self.date else { return Ok(None) };
        let bad = || SurveyError::Date(text.clone());
        let parts: Vec<&str> = text.trim().split('-').collect();
        let [y, m, d] = parts.as_slice() else { return Err(bad()) };
        let digits = |t: &str, n: usize| t.len() == n && t.bytes().all(|b| b.is_ascii_digit());
        if !(digits(y, 4) && digits(m, 2) && digits(d, 2)) {
            return Err(bad());
        }
        let (y, m, d): (u16, u8, u8) =
            (y.parse().map_err(|_| bad())?, m.parse().map_err(|_| bad())?, d.parse().map_err(|_| bad())?);
        let leap = (y % 4 == 0 && y % 100 != 0) || y % 400 == 0;
        let days = match m {
            1 | 3 | 5 | 7 | 8 | 10 | 12 => 31,
            4 | 6 | 9 | 11 => 30,
            2 if leap => 29,
            2 => 28,
            _ => return Err(bad()),
        };
        if y < 1000 || d == 0 || d > days {
            return Err(bad());
        }
        Ok(Some((y, m, d)))
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
        if let Ok(Some((y, m, d))) = self.day() {
            parts.push(format!("on {y:04}-{m:02}-{d:02}"));
        }
        if let Some(o) = &self.operator {
            parts.push(format!("operator {}", printable(o)));
        }
        if let Some(i) = &self.instrument {
            parts.push(format!("instrument {}", printable(i)));
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
    fn a_date_is_a_day() {
        let s = Survey::parse("date = \"2024-02-29\"\n").unwrap();
        assert_eq!(s.day().unwrap(), Some((2024, 2, 29)));
        assert!(s.describe().contains("on 2024-02-29"), "{}", s.describe());
        assert!(Survey::parse("date = \"2023-02-29\"\n").is_err());
        assert_eq!(Survey::default().day().unwrap(), None);
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
