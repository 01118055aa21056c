//! NMEA 0183 sentences: checked and read into what an epoch needs.
//!
//! A sentence is `$`, an address (a two-letter talker and a three-letter
//! type, or `P` and a maker's code for a proprietary one), fields
//! separated by commas, `*` and the checksum in two hex digits. Its
//! checksum is checked first: a sentence that fails it, or whose fields
//! of a kind read here do not read, is damaged ([`SentenceError`]).
//! Every talker (`GP`, `GN`, `GL`, `GA`, `GB`, `BD`, `GQ`, `GI`) is taken.
//! Read: `GGA` and `GNS` (position), `RMC` (date, speed, course), `VTG`
//! (speed, course), `GST` (the receiver's own σ), `ZDA` (date) and `GLL`
//! (its time only, for the epoch). Anything else that checks — `GSA`,
//! `GSV`, `TXT`, proprietary `$P…` — is [`Sentence::Other`].

use super::Quality;

/// Knots to mm/s (1 kn = 1852 m/h).
const MM_S_PER_KNOT: f64 = 1852.0 * 1000.0 / 3600.0;
/// The longest line a receiver sends (NMEA 0183 allows 82 characters;
/// proprietary sentences of some receivers run longer).
pub const MAX_LINE_BYTES: usize = 256;

/// Why a line was not used: it is damaged.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SentenceError {
    /// Not an NMEA sentence, one whose checksum does not match, or one
    /// whose fields do not read.
    #[error("not a valid NMEA sentence ({0})")]
    Invalid(String),
    /// A line longer than any receiver sends.
    #[error("a line of {0} bytes (at most {MAX_LINE_BYTES})")]
    TooLong(usize),
}

fn bad(why: impl Into<String>) -> SentenceError {
    SentenceError::Invalid(why.into())
}

/// A position as `GGA` or `GNS` give it.
#[derive(Clone, Debug, PartialEq)]
pub struct Position {
    /// Latitude and longitude, degrees (absent without a fix).
    pub lat_lon_deg: Option<(f64, f64)>,
    /// The solution's kind.
    pub quality: Quality,
    /// Satellites used.
    pub satellites: Option<u8>,
    /// Horizontal dilution of precision.
    pub hdop: Option<f64>,
    /// Height above mean sea level, m.
    pub altitude_m: Option<f64>,
}

/// What one sentence says.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum Sentence {
    /// `GGA`: the position of reference.
    Gga(Option<u32>, Position),
    /// `GNS`: the position, when there is no `GGA`.
    Gns(Option<u32>, Position),
    /// `RMC`: date, and speed and course when its status is valid.
    Rmc {
        /// UTC, ms of day.
        utc: Option<u32>,
        /// Date (year, month, day).
        date: Option<(u16, u8, u8)>,
        /// Speed over ground, mm/s (status valid only).
        speed_mm_s: Option<f64>,
        /// Course over ground, degrees (status valid only).
        course_deg: Option<f64>,
    },
    /// `VTG`: speed and course over ground (none when its mode says no fix).
    Vtg(Option<f64>, Option<f64>),
    /// `GST`: the error ellipse's semi-major σ, m (or the larger of the
    /// latitude and longitude σ).
    Gst(Option<u32>, Option<f64>),
    /// `ZDA`: the date.
    Zda(Option<u32>, Option<(u16, u8, u8)>),
    /// `GLL`: its time.
    Gll(Option<u32>),
    /// A valid sentence of a kind not read (or proprietary).
    Other,
}

impl Sentence {
    /// The UTC of the epoch it belongs to, if it says.
    pub fn utc(&self) -> Option<u32> {
        match self {
            Sentence::Gga(t, _)
            | Sentence::Gns(t, _)
            | Sentence::Gst(t, _)
            | Sentence::Zda(t, _)
            | Sentence::Gll(t) => *t,
            Sentence::Rmc { utc, .. } => *utc,
            Sentence::Vtg(..) | Sentence::Other => None,
        }
    }

    /// Whether it is tied to an epoch by a time field.
    pub fn is_timed(&self) -> bool {
        !matches!(self, Sentence::Vtg(..) | Sentence::Other)
    }
}

fn number(s: &str) -> Result<Option<f64>, SentenceError> {
    if s.is_empty() {
        return Ok(None);
    }
    if !s.bytes().all(|b| b.is_ascii_digit() || b == b'.' || b == b'-' || b == b'+') {
        return Err(bad(format!("number {s:?}")));
    }
    s.parse::<f64>().map(Some).map_err(|_| bad(format!("number {s:?}")))
}

fn integer(s: &str) -> Result<Option<u32>, SentenceError> {
    if s.is_empty() {
        return Ok(None);
    }
    if !s.bytes().all(|b| b.is_ascii_digit()) || s.len() > 9 {
        return Err(bad(format!("integer {s:?}")));
    }
    Ok(s.parse().ok())
}

/// `hhmmss[.sss]` to ms of day.
fn time(s: &str) -> Result<Option<u32>, SentenceError> {
    if s.is_empty() {
        return Ok(None);
    }
    let (whole, frac) = s.split_once('.').unwrap_or((s, ""));
    let digits = |x: &str| x.bytes().all(|b| b.is_ascii_digit());
    if whole.len() != 6 || !digits(whole) || !digits(frac) {
        return Err(bad(format!("time {s:?}")));
    }
    let n = |i: usize| u32::from(whole.as_bytes()[i] - b'0') * 10 + u32::from(whole.as_bytes()[i + 1] - b'0');
    let (h, m, sec) = (n(0), n(2), n(4));
    if h > 23 || m > 59 || sec > 60 {
        return Err(bad(format!("time {s:?}")));
    }
    let ms = frac.bytes().chain(std::iter::repeat(b'0')).take(3).fold(0, |a, b| a * 10 + u32::from(b - b'0'));
    Ok(Some(((h * 60 + m) * 60 + sec) * 1000 + ms))
}

/// `(d)ddmm.mmmm` and its hemisphere to signed degrees.
fn angle(s: &str, hemi: &str, plus: &str, minus: &str, deg_digits: usize) -> Result<Option<f64>, SentenceError> {
    if s.is_empty() && hemi.is_empty() {
        return Ok(None);
    }
    let whole = s.split_once('.').map_or(s, |(w, _)| w);
    if whole.len() != deg_digits + 2 || !s.is_ascii() {
        return Err(bad(format!("angle {s:?}")));
    }
    let deg = integer(&s[..deg_digits])?.ok_or_else(|| bad("angle"))?;
    let min = number(&s[deg_digits..])?.ok_or_else(|| bad("angle"))?;
    let v = f64::from(deg) + min / 60.0;
    if min >= 60.0 || v > if deg_digits == 2 { 90.0 } else { 180.0 } {
        return Err(bad(format!("angle {s:?}")));
    }
    match hemi {
        h if h == plus => Ok(Some(v)),
        h if h == minus => Ok(Some(-v)),
        _ => Err(bad(format!("hemisphere {hemi:?}"))),
    }
}

fn lat_lon(f: &[&str]) -> Result<Option<(f64, f64)>, SentenceError> {
    match (angle(f[0], f[1], "N", "S", 2)?, angle(f[2], f[3], "E", "W", 3)?) {
        (Some(a), Some(b)) => Ok(Some((a, b))),
        (None, None) => Ok(None),
        _ => Err(bad("a latitude without longitude")),
    }
}

fn date(d: Option<u32>, m: Option<u32>, y: Option<u32>) -> Result<Option<(u16, u8, u8)>, SentenceError> {
    match (d, m, y) {
        (Some(d), Some(m), Some(y)) if (1..=31).contains(&d) && (1..=12).contains(&m) && y <= 9999 => {
            Ok(Some((y as u16, m as u8, d as u8)))
        }
        (None, None, None) => Ok(None),
        _ => Err(bad("date")),
    }
}

fn ddmmyy(s: &str) -> Result<Option<(u16, u8, u8)>, SentenceError> {
    if s.is_empty() {
        return Ok(None);
    }
    if s.len() != 6 {
        return Err(bad(format!("date {s:?}")));
    }
    let (d, m, y) = (integer(&s[0..2])?, integer(&s[2..4])?, integer(&s[4..6])?);
    // Two-digit years: GNSS receivers' dates are from 1980 on.
    date(d, m, y.map(|y| if y < 80 { 2000 + y } else { 1900 + y }))
}

fn speed_course(knots: &str, course: &str) -> Result<(Option<f64>, Option<f64>), SentenceError> {
    let course = number(course)?;
    if course.is_some_and(|c| !(0.0..=360.0).contains(&c)) {
        return Err(bad("course"));
    }
    Ok((number(knots)?.map(|kn| kn * MM_S_PER_KNOT), course))
}

/// The best solution among a `GNS`'s mode letters (one per constellation).
fn gns_quality(modes: &str) -> Result<Quality, SentenceError> {
    let rank = |q: Quality| {
        [Quality::RtkFixed, Quality::RtkFloat, Quality::Differential, Quality::Pps, Quality::Autonomous]
            .iter()
            .position(|&x| x == q)
            .unwrap_or(9)
    };
    let mut best = Quality::Invalid;
    for c in modes.chars() {
        let q = match c {
            'N' => Quality::Invalid,
            'A' => Quality::Autonomous,
            'D' => Quality::Differential,
            'P' => Quality::Pps,
            'R' => Quality::RtkFixed,
            'F' => Quality::RtkFloat,
            'E' => Quality::Estimated,
            'M' => Quality::Manual,
            'S' => Quality::Simulation,
            _ => return Err(bad(format!("GNS mode {modes:?}"))),
        };
        if best == Quality::Invalid || rank(q) < rank(best) {
            best = q;
        }
    }
    Ok(best)
}

fn position(f: &[&str], quality: Quality) -> Result<Position, SentenceError> {
    Ok(Position {
        lat_lon_deg: lat_lon(&f[2..6])?,
        quality,
        satellites: integer(f[7])?.map(|n| n.min(255) as u8),
        hdop: number(f[8])?,
        altitude_m: number(f[9])?,
    })
}

/// Checks one line's checksum and reads it.
pub fn parse(line: &str) -> Result<Sentence, SentenceError> {
    let line = line.trim_end_matches(['\r', '\n']);
    if line.len() > MAX_LINE_BYTES {
        return Err(SentenceError::TooLong(line.len()));
    }
    let Some(rest) = line.strip_prefix('$') else { return Err(bad("no `$`")) };
    let Some((body, sum)) = rest.rsplit_once('*') else { return Err(bad("no checksum")) };
    if !body.bytes().all(|b| (0x20..0x7F).contains(&b) && b != b'$' && b != b'*') {
        return Err(bad("a character no sentence holds"));
    }
    if sum.len() != 2 || u8::from_str_radix(sum, 16).ok() != Some(checksum(body)) {
        return Err(bad(format!("checksum {sum:?}, the sentence's is {:02X}", checksum(body))));
    }
    let f: Vec<&str> = body.split(',').collect();
    let address = f[0];
    if address.starts_with('P') && address.len() >= 2 {
        return Ok(Sentence::Other);
    }
    if address.len() != 5 || !address.bytes().all(|b| b.is_ascii_uppercase() || b.is_ascii_digit()) {
        return Err(bad(format!("address {address:?}")));
    }
    let need = |n: usize| if f.len() >= n { Ok(()) } else { Err(bad(format!("{address} of {} fields", f.len() - 1))) };
    Ok(match &address[2..] {
        "GGA" => {
            need(10)?;
            let q = match integer(f[6])? {
                None => Quality::Invalid,
                Some(d) => u8::try_from(d).ok().and_then(Quality::from_digit).ok_or_else(|| bad("GGA quality"))?,
            };
            Sentence::Gga(time(f[1])?, position(&f, q)?)
        }
        "GNS" => {
            need(10)?;
            Sentence::Gns(time(f[1])?, position(&f, gns_quality(f[6])?)?)
        }
        "RMC" => {
            need(10)?;
            let (speed, course) = speed_course(f[7], f[8])?;
            let valid = match f[2] {
                "A" => true,
                "V" | "" => false,
                s => return Err(bad(format!("RMC status {s:?}"))),
            };
            lat_lon(&f[3..7])?;
            let mode_no_fix = f.get(12).is_some_and(|m| *m == "N");
            let ok = valid && !mode_no_fix;
            Sentence::Rmc {
                utc: time(f[1])?,
                date: ddmmyy(f[9])?,
                speed_mm_s: speed.filter(|_| ok),
                course_deg: course.filter(|_| ok),
            }
        }
        "VTG" => {
            need(9)?;
            let (speed, course) = speed_course(f[5], f[1])?;
            if f.get(9).is_some_and(|m| *m == "N") { Sentence::Vtg(None, None) } else { Sentence::Vtg(speed, course) }
        }
        "GST" => {
            need(9)?;
            let (major, lat, lon) = (number(f[3])?, number(f[6])?, number(f[7])?);
            let sigma = major.or(match (lat, lon) {
                (Some(a), Some(b)) => Some(a.max(b)),
                _ => None,
            });
            Sentence::Gst(time(f[1])?, sigma.filter(|s| *s > 0.0))
        }
        "ZDA" => {
            need(5)?;
            Sentence::Zda(time(f[1])?, date(integer(f[2])?, integer(f[3])?, integer(f[4])?)?)
        }
        "GLL" => {
            need(7)?;
            lat_lon(&f[1..5])?;
            Sentence::Gll(time(f[5])?)
        }
        _ => Sentence::Other,
    })
}

/// The NMEA checksum: XOR of the bytes between `$` and `*`.
pub fn checksum(body: &str) -> u8 {
    body.bytes().fold(0, |a, b| a ^ b)
}

/// `$body*hh\r\n`.
pub fn sentence(body: &str) -> String {
    format!("${body}*{:02X}\r\n", checksum(body))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_checksum_is_nmea_s() {
        // The example of the NMEA 0183 standard's GGA.
        assert_eq!(
            sentence("GPGGA,092750.000,5321.6802,N,00630.3372,W,1,8,1.03,61.7,M,55.2,M,,"),
            "$GPGGA,092750.000,5321.6802,N,00630.3372,W,1,8,1.03,61.7,M,55.2,M,,*76\r\n"
        );
    }

    #[test]
    fn each_kind_reads() {
        let p = |b: &str| parse(&sentence(b)).unwrap();
        let Sentence::Gga(t, g) = p("GPGGA,092750.000,5321.6802,N,00630.3372,W,1,8,1.03,61.7,M,55.2,M,,") else {
            panic!()
        };
        assert_eq!(t, Some(((9 * 60 + 27) * 60 + 50) * 1000));
        let (lat, lon) = g.lat_lon_deg.unwrap();
        assert!((lat - (53.0 + 21.6802 / 60.0)).abs() < 1e-12 && (lon + 6.0 + 30.3372 / 60.0).abs() < 1e-12);
        assert_eq!(
            (g.quality, g.satellites, g.hdop, g.altitude_m),
            (Quality::Autonomous, Some(8), Some(1.03), Some(61.7))
        );
        // u-blox GNS: GPS RTK fixed, GLONASS float, Galileo and BeiDou none.
        let Sentence::Gns(_, g) = p("GNGNS,101530.20,4807.038,N,01131.000,E,RFNN,14,0.8,101.3,47.0,1.0,0000,V") else {
            panic!()
        };
        assert_eq!(g.quality, Quality::RtkFixed);
        assert_eq!(
            p("GNRMC,101530.20,A,4807.038,N,01131.000,E,1.944,87.5,041226,,,R,V"),
            Sentence::Rmc {
                utc: Some(36_930_200),
                date: Some((2026, 12, 4)),
                speed_mm_s: Some(1.944 * MM_S_PER_KNOT),
                course_deg: Some(87.5)
            }
        );
        // A receiver without a fix: its date stands, no speed or course.
        let Sentence::Rmc { date, speed_mm_s, .. } = p("GPRMC,101530.20,V,,,,,,,041226,,,N") else { panic!() };
        assert_eq!((date, speed_mm_s), (Some((2026, 12, 4)), None));
        assert_eq!(p("GPVTG,87.5,T,,M,1.944,N,3.600,K,R"), Sentence::Vtg(Some(1.944 * MM_S_PER_KNOT), Some(87.5)));
        assert_eq!(p("GPVTG,,T,,M,,N,,K,N"), Sentence::Vtg(None, None));
        assert_eq!(
            p("GNGST,101530.20,0.9,0.012,0.008,45.0,0.010,0.011,0.020"),
            Sentence::Gst(Some(36_930_200), Some(0.012))
        );
        assert_eq!(p("GNGST,101530.20,,,,,0.010,0.011,0.020"), Sentence::Gst(Some(36_930_200), Some(0.011)));
        assert_eq!(p("GNZDA,101530.20,04,12,2026,00,00"), Sentence::Zda(Some(36_930_200), Some((2026, 12, 4))));
        assert_eq!(p("GNGLL,4807.038,N,01131.000,E,101530.20,A,R"), Sentence::Gll(Some(36_930_200)));
        for other in [
            "PUBX,00,101530.20,4807.038,N",
            "GPGSV,3,1,11,05,45,120,40",
            "GNGSA,A,3,05,07,,,,,,,,,,,1.2,0.8,0.9,1",
            "GNTXT,01,01,02,u-blox AG",
            "PTNL,PJK,101530.20",
            "PSRF156,1",
        ] {
            assert_eq!(p(other), Sentence::Other, "{other}");
        }
    }

    #[test]
    fn damaged_sentences_are_refused() {
        let good = sentence("GPGGA,101530.20,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,");
        let mut bad = good.clone().into_bytes();
        bad[20] = b'9';
        for line in [
            String::from_utf8(bad).unwrap(),
            "garbage".into(),
            "$GPGGA,101530.20,4807.038,N".into(),
            "$GPGGA,".repeat(100),
            sentence("GPGGA,1015,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"),
            sentence("GPGGA,101530.20,4807.038,X,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"),
            sentence("GPGGA,101530.20,4807.038,N,01131.000,E,9,08,0.9,545.4,M,46.9,M,,"),
            sentence("GPGGA,101530.20,4807.038,N,01131.000,E,1,08,inf,545.4,M,46.9,M,,"),
            sentence("GPGGA,101530.20,4807.038,N"),
            sentence("GPRMC,101530.20,A,4807.038,N,01131.000,E,1.9,87.5,321226,,,A"),
            sentence("GPRMC,101530.20,A,4807.038,N,01131.000,E,1.9,387.5,041226,,,A"),
            sentence("GNGNS,101530.20,4807.038,N,01131.000,E,RX,14,0.8,101.3,47.0,,,V"),
            sentence("gpgga,1"),
        ] {
            assert!(parse(&line).is_err(), "{line:?}");
        }
        assert_eq!(parse(&"$GPGGA,".repeat(100)), Err(SentenceError::TooLong(700)));
    }
}
