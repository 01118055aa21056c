//! One epoch's NMEA sentences gathered into a [`Fix`].

use chrono::{Datelike, NaiveTime, Timelike};
use nmea::sentences::FixType;
use nmea::{ParseResult, parse_str};

use super::{Fix, Quality};

/// Knots to mm/s (1 kn = 1852 m/h).
const MM_S_PER_KNOT: f64 = 1852.0 * 1000.0 / 3600.0;
/// The longest line a receiver sends (NMEA 0183 allows 82 characters;
/// proprietary sentences of some receivers run longer).
pub const MAX_LINE_BYTES: usize = 256;

/// Why a line was not used.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SentenceError {
    /// Not an NMEA sentence, or one whose checksum does not match.
    #[error("not a valid NMEA sentence ({0})")]
    Invalid(String),
    /// A line longer than any receiver sends.
    #[error("a line of {0} bytes (at most {MAX_LINE_BYTES})")]
    TooLong(usize),
}

/// Gathers sentences into fixes: a `GGA` opens an epoch; `RMC` and `VTG`
/// of the same epoch add date, speed and course; the epoch is given out
/// when the next one opens (or by [`Assembler::flush`]).
#[derive(Clone, Debug, Default)]
pub struct Assembler {
    open: Option<Fix>,
    /// Sentences used.
    pub used: u64,
    /// Sentences that failed their checksum or did not parse.
    pub invalid: u64,
    /// Valid sentences of other kinds (`GSV`, `GSA`, proprietary...).
    pub ignored: u64,
    /// Epochs without a position (quality 0, or no latitude/longitude).
    pub no_position: u64,
}

fn ms_of_day(t: NaiveTime) -> u32 {
    t.num_seconds_from_midnight() * 1000 + t.nanosecond() / 1_000_000
}

fn quality(t: FixType) -> Quality {
    match t {
        FixType::Invalid => Quality::Invalid,
        FixType::Gps => Quality::Autonomous,
        FixType::DGps => Quality::Differential,
        FixType::Pps => Quality::Pps,
        FixType::Rtk => Quality::RtkFixed,
        FixType::FloatRtk => Quality::RtkFloat,
        FixType::Estimated => Quality::Estimated,
        FixType::Manual => Quality::Manual,
        FixType::Simulation => Quality::Simulation,
    }
}

impl Assembler {
    /// A new assembler.
    pub fn new() -> Assembler {
        Assembler::default()
    }

    /// Takes one line (with or without its `\r\n`); returns the epoch it
    /// closed, if any.
    pub fn line(&mut self, line: &str) -> Result<Option<Fix>, SentenceError> {
        let line = line.trim_end_matches(['\r', '\n']);
        if line.len() > MAX_LINE_BYTES {
            self.invalid += 1;
            return Err(SentenceError::TooLong(line.len()));
        }
        if line.is_empty() {
            return Ok(None);
        }
        let parsed = match parse_str(line) {
            Ok(p) => p,
            Err(nmea::Error::DisabledSentence | nmea::Error::Unsupported(_) | nmea::Error::Unknown(_)) => {
                self.ignored += 1;
                return Ok(None);
            }
            Err(e) => {
                self.invalid += 1;
                return Err(SentenceError::Invalid(format!("{e:?}")));
            }
        };
        self.used += 1;
        Ok(match parsed {
            ParseResult::GGA(g) => {
                let closed = self.flush();
                let q = g.fix_type.map_or(Quality::Invalid, quality);
                match (g.latitude, g.longitude) {
                    (Some(lat), Some(lon)) if q != Quality::Invalid && lat.is_finite() && lon.is_finite() => {
                        self.open = Some(Fix {
                            utc_ms_of_day: g.fix_time.map(ms_of_day),
                            date: None,
                            lat_deg: lat,
                            lon_deg: lon,
                            altitude_m: g.altitude.map(f64::from),
                            quality: q,
                            satellites: g.fix_satellites.map(|n| n.min(255) as u8),
                            hdop: g.hdop.map(f64::from),
                            speed_mm_s: None,
                            course_deg: None,
                        });
                    }
                    _ => self.no_position += 1,
                }
                closed
            }
            ParseResult::RMC(r) => {
                if let Some(f) = self.open.as_mut()
                    && (r.fix_time.map(ms_of_day) == f.utc_ms_of_day || r.fix_time.is_none())
                {
                    f.date = r.fix_date.map(|d| (d.year().clamp(0, 9999) as u16, d.month() as u8, d.day() as u8));
                    f.speed_mm_s = f.speed_mm_s.or(r.speed_over_ground.map(|kn| f64::from(kn) * MM_S_PER_KNOT));
                    f.course_deg = f.course_deg.or(r.true_course.map(f64::from));
                }
                None
            }
            ParseResult::VTG(v) => {
                if let Some(f) = self.open.as_mut() {
                    if let Some(kn) = v.speed_over_ground {
                        f.speed_mm_s = Some(f64::from(kn) * MM_S_PER_KNOT);
                    }
                    if let Some(c) = v.true_course {
                        f.course_deg = Some(f64::from(c));
                    }
                }
                None
            }
            _ => {
                self.used -= 1;
                self.ignored += 1;
                None
            }
        })
    }

    /// The epoch still open, if any (at the end of the stream).
    pub fn flush(&mut self) -> Option<Fix> {
        self.open.take()
    }
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

    // Sentences as a u-blox receiver sends them (checksums computed).
    fn epoch(t: &str, lat: &str, lon: &str, q: u8) -> Vec<String> {
        vec![
            sentence(&format!("GNGGA,{t},{lat},N,{lon},E,{q},14,0.8,101.3,M,47.0,M,,")),
            sentence(&format!("GNRMC,{t},A,{lat},N,{lon},E,1.944,87.5,041226,,,R,V")),
            sentence("GNVTG,87.5,T,,M,1.944,N,3.600,K,R"),
            sentence("GPGSV,3,1,11,05,45,120,40,07,30,200,38,08,12,300,30,10,60,050,44"),
        ]
    }

    #[test]
    fn an_epoch_is_gathered_from_its_sentences() {
        let mut a = Assembler::new();
        let mut got = Vec::new();
        for l in epoch("101530.20", "4807.038000", "01131.000000", 4).iter().chain(&epoch(
            "101530.30",
            "4807.038100",
            "01131.000000",
            4,
        )) {
            if let Some(f) = a.line(l).unwrap() {
                got.push(f);
            }
        }
        got.extend(a.flush());
        assert_eq!(got.len(), 2);
        let f = &got[0];
        assert_eq!(f.utc_ms_of_day, Some(((10 * 60 + 15) * 60 + 30) * 1000 + 200));
        assert_eq!(f.date, Some((2026, 12, 4)));
        assert!((f.lat_deg - (48.0 + 7.038 / 60.0)).abs() < 1e-9, "{}", f.lat_deg);
        assert!((f.lon_deg - (11.0 + 31.0 / 60.0)).abs() < 1e-9);
        assert_eq!(
            (f.quality, f.satellites, f.hdop.map(|h| (h * 10.0).round())),
            (Quality::RtkFixed, Some(14), Some(8.0))
        );
        // 1.944 kn = 1.000 m/s.
        assert!((f.speed_mm_s.unwrap() - 1000.1).abs() < 0.5, "{:?}", f.speed_mm_s);
        assert_eq!(f.course_deg, Some(87.5));
        assert_eq!((a.used, a.ignored, a.invalid), (6, 2, 0));
    }

    #[test]
    fn damaged_and_foreign_lines_are_counted_never_used() {
        let mut a = Assembler::new();
        let good = sentence("GPGGA,101530.20,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,");
        let mut bad = good.clone().into_bytes();
        bad[20] = b'9';
        assert!(a.line(std::str::from_utf8(&bad).unwrap()).is_err());
        assert!(a.line("garbage").is_err());
        assert!(a.line(&"$GPGGA,".repeat(100)).is_err());
        assert!(a.line("$GPGGA,1*00\u{e9}").is_err());
        assert_eq!(a.line("").unwrap(), None);
        assert_eq!(a.invalid, 4);
        assert!(a.flush().is_none());
        // No fix: an epoch without a position is counted, not given out.
        a.line(&sentence("GPGGA,101530.20,,,,,0,00,99.9,,M,,M,,")).unwrap();
        assert_eq!((a.flush(), a.no_position), (None, 1));
    }

    proptest::proptest! {
        /// Whatever a port delivers, the assembler never panics, and one
        /// changed byte of a sentence never yields another fix: the
        /// checksum refuses it, or it reads as the same.
        #[test]
        fn damaged_lines_never_give_a_wrong_fix(
            noise in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..300),
            at in 0usize..80,
            byte in proptest::prelude::any::<u8>(),
        ) {
            let mut a = Assembler::new();
            let _ = a.line(&String::from_utf8_lossy(&noise));
            let _ = a.flush();
            let good = sentence("GNGGA,101530.20,4807.0380000,N,01131.0000000,E,4,14,0.8,101.3,M,47.0,M,1.0,0000");
            let mut want = Assembler::new();
            want.line(&good).unwrap();
            let want = want.flush();
            let mut bad = good.clone().into_bytes();
            let i = at % (bad.len() - 2);
            bad[i] = byte;
            let mut a = Assembler::new();
            if a.line(&String::from_utf8_lossy(&bad)).is_ok() {
                let got = a.flush();
                proptest::prop_assert!(got.is_none() || got == want, "{:?}", String::from_utf8_lossy(&bad));
            }
        }
    }

    #[test]
    fn the_checksum_is_nmea_s() {
        // The example of the NMEA 0183 standard's GGA.
        assert_eq!(
            sentence("GPGGA,092750.000,5321.6802,N,00630.3372,W,1,8,1.03,61.7,M,55.2,M,,"),
            "$GPGGA,092750.000,5321.6802,N,00630.3372,W,1,8,1.03,61.7,M,55.2,M,,*76\r\n"
        );
    }
}
