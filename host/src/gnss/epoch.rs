//! One epoch's sentences gathered into a [`Fix`] by their UTC time,
//! whatever order the receiver sends them in.
//!
//! Receivers differ in the order of an epoch's sentences: u-blox sends
//! `RMC, VTG, GNS, GGA, GSA…, GSV…, GLL, GST, ZDA` (and `$PUBX`),
//! Septentrio and Trimble send what is enabled in their own orders
//! (`GGA` first, `ZDA` or `GST` among them), NovAtel one log after
//! another, MediaTek and SiRF chipsets `GGA, GSA, GSV, RMC, VTG` or `RMC,
//! VTG, GGA, …`. So an epoch is not opened by a kind of sentence but by a
//! time: every sentence with a time field (`GGA`, `GNS`, `RMC`, `GST`,
//! `ZDA`, `GLL`) joins the epoch of its time, and one of another time
//! closes the epoch open and opens its own. `VTG` has no time: it joins the
//! epoch open unless that one already has a `VTG`, and then waits for the
//! next epoch (a receiver sending `VTG` first). A sentence of an epoch
//! already given out (the port fell silent inside an epoch) is counted as
//! late and not used.
//!
//! What an epoch's fix takes: the position, quality, satellites, HDOP and
//! altitude of its `GGA`, or of its `GNS` when it has no `GGA`; the date
//! of its `RMC` or `ZDA`; speed and course of its `RMC` (status valid) or
//! `VTG`; the receiver's own σ from its `GST`.

use super::sentence::{Position, Sentence, SentenceError, parse};
use super::{Fix, Quality};

#[derive(Clone, Debug, Default)]
struct Epoch {
    utc: Option<u32>,
    gga: Option<Position>,
    gns: Option<Position>,
    date: Option<(u16, u8, u8)>,
    speed_mm_s: Option<f64>,
    course_deg: Option<f64>,
    sigma_m: Option<f64>,
    has_vtg: bool,
}

impl Epoch {
    fn fix(self) -> Option<Fix> {
        let p = self.gga.or(self.gns)?;
        let (lat, lon) = p.lat_lon_deg?;
        if p.quality == Quality::Invalid || !lat.is_finite() || !lon.is_finite() {
            return None;
        }
        Some(Fix {
            utc_ms_of_day: self.utc,
            date: self.date,
            lat_deg: lat,
            lon_deg: lon,
            altitude_m: p.altitude_m,
            quality: p.quality,
            satellites: p.satellites,
            hdop: p.hdop,
            speed_mm_s: self.speed_mm_s,
            course_deg: self.course_deg,
            receiver_sigma_m: self.sigma_m,
        })
    }

    fn vtg(&mut self, speed: Option<f64>, course: Option<f64>) {
        self.has_vtg = true;
        self.speed_mm_s = self.speed_mm_s.or(speed);
        self.course_deg = self.course_deg.or(course);
    }
}

/// Gathers sentences into fixes by their UTC time (see the module docs);
/// an epoch is given out when one of another time opens (or by
/// [`Assembler::flush`]).
#[derive(Clone, Debug, Default)]
pub struct Assembler {
    open: Option<Epoch>,
    /// A `VTG` that came after the open epoch had one: the next epoch's.
    pending_vtg: Option<(Option<f64>, Option<f64>)>,
    /// The time of the epoch given out last.
    last_utc: Option<u32>,
    opened: u64,
    /// Sentences used.
    pub used: u64,
    /// Sentences damaged: checksum or syntax.
    pub invalid: u64,
    /// Valid sentences of other kinds (`GSV`, `GSA`, proprietary...).
    pub ignored: u64,
    /// Valid sentences of an epoch already given out.
    pub late: u64,
    /// Epochs without a position (quality 0, or no latitude/longitude).
    pub no_position: u64,
}

impl Assembler {
    /// A new assembler.
    pub fn new() -> Assembler {
        Assembler::default()
    }

    /// Epochs opened so far: it changes when a sentence opens one.
    pub fn epochs_opened(&self) -> u64 {
        self.opened
    }

    /// Takes one line (with or without its `\r\n`); returns the epoch it
    /// closed, if any.
    pub fn line(&mut self, line: &str) -> Result<Option<Fix>, SentenceError> {
        if line.trim_end_matches(['\r', '\n']).is_empty() {
            return Ok(None);
        }
        let s = match parse(line) {
            Ok(s) => s,
            Err(e) => {
                self.invalid += 1;
                return Err(e);
            }
        };
        if s == Sentence::Other {
            self.ignored += 1;
            return Ok(None);
        }
        if let Sentence::Vtg(speed, course) = s {
            self.used += 1;
            match self.open.as_mut() {
                Some(e) if !e.has_vtg => e.vtg(speed, course),
                _ => self.pending_vtg = Some((speed, course)),
            }
            return Ok(None);
        }
        let utc = s.utc();
        let joins = self.open.as_ref().is_some_and(|e| e.utc == utc || utc.is_none());
        if !joins && utc.is_some() && utc == self.last_utc {
            self.late += 1;
            return Ok(None);
        }
        self.used += 1;
        let closed = if joins { None } else { self.close() };
        let e = self.open.get_or_insert_with(|| {
            self.opened += 1;
            let mut e = Epoch { utc, ..Epoch::default() };
            if let Some((speed, course)) = self.pending_vtg.take() {
                e.vtg(speed, course);
            }
            e
        });
        match s {
            Sentence::Gga(_, p) => e.gga = Some(p),
            Sentence::Gns(_, p) => e.gns = Some(p),
            Sentence::Rmc { date, speed_mm_s, course_deg, .. } => {
                e.date = e.date.or(date);
                e.speed_mm_s = e.speed_mm_s.or(speed_mm_s);
                e.course_deg = e.course_deg.or(course_deg);
            }
            Sentence::Zda(_, date) => e.date = e.date.or(date),
            Sentence::Gst(_, sigma) => e.sigma_m = sigma,
            _ => {}
        }
        Ok(closed)
    }

    fn close(&mut self) -> Option<Fix> {
        let e = self.open.take()?;
        self.last_utc = e.utc.or(self.last_utc);
        let fix = e.fix();
        if fix.is_none() {
            self.no_position += 1;
        }
        fix
    }

    /// The epoch still open, if any (at the end of the stream, or when
    /// the port falls silent).
    pub fn flush(&mut self) -> Option<Fix> {
        self.close()
    }
}

#[cfg(test)]
mod tests {
    use super::super::sentence::sentence;
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
        // A sentence of that epoch after it was given out is late.
        a.line(&sentence("GPZDA,101530.20,04,12,2026,,")).unwrap();
        assert_eq!((a.flush(), a.late, a.no_position), (None, 1, 1));
    }

    /// `VTG` first or last in an epoch, it joins its own.
    #[test]
    fn a_vtg_joins_its_own_epoch_before_or_after_the_timed_sentences() {
        let gga = |t: &str| sentence(&format!("GPGGA,{t},4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"));
        let vtg = |kn: u32| sentence(&format!("GPVTG,10.0,T,,M,{kn}.0,N,,K,A"));
        for first in [true, false] {
            let mut a = Assembler::new();
            let mut got = Vec::new();
            for (t, kn) in [("000000.00", 1), ("000001.00", 2), ("000002.00", 3)] {
                let lines = if first { [vtg(kn), gga(t)] } else { [gga(t), vtg(kn)] };
                for l in lines {
                    got.extend(a.line(&l).unwrap());
                }
            }
            got.extend(a.flush());
            let knots: Vec<f64> = got.iter().map(|f| (f.speed_mm_s.unwrap() / MM_S_PER_KNOT).round()).collect();
            assert_eq!(knots, [1.0, 2.0, 3.0], "VTG first: {first}");
        }
    }

    const MM_S_PER_KNOT: f64 = 1852.0 * 1000.0 / 3600.0;

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
}
