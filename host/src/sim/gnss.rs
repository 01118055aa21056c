//! A simulated GNSS receiver riding with the simulated head: NMEA 0183
//! (`GGA`, `RMC`, `VTG`) on a pseudo-terminal of its own, as a receiver
//! on its own USB serial port sends them.
//!
//! Its antenna follows a track register's centreline
//! ([`crate::gnss::register`]) at the chainage the head's odometer says:
//! `start + direction × odometer`, the odometer read from the simulated
//! camera as each frame begins ([`HeadOptions::odometer_tap`](crate::sim::head::HeadOptions)).
//! Every epoch adds the solution's noise: independent normal errors east
//! and north with the quality's standard uncertainty per axis (RTK fixed
//! by default: 10 mm a side, 14 mm horizontal RMS), as a receiver whose
//! errors are white at the epoch rate. Speed and course over ground come
//! from the odometer's change between epochs and the centreline's
//! direction, as a receiver's Doppler speed would. The UTC of each epoch
//! is the host's clock.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crate::gnss::register::{Register, offset};
use crate::gnss::sentence::sentence;
use crate::gnss::{Fix, Quality};
use crate::sim::head::{Pty, SimulateError};
use crate::sim::scene::noise::Rng;

/// The built-in register: 3 km from chainage 41+000 (examples/track-register.csv).
pub const BUILT_IN_REGISTER: &str = include_str!("../../../examples/track-register.csv");
/// The odometer tap's value before the first frame.
pub const NO_FRAME: i64 = i64::MIN;

/// What the simulated receiver does.
#[derive(Clone, Debug)]
pub struct GnssSimOptions {
    /// The centreline it follows.
    pub register: Register,
    /// Chainage at odometer 0, m.
    pub start_chainage_m: f64,
    /// +1: chainage grows with the odometer; −1: it falls.
    pub direction: f64,
    /// Epochs per second.
    pub rate_hz: u32,
    /// The solution it reports.
    pub quality: Quality,
    /// Standard uncertainty east and north, m (each).
    pub sigma_m: f64,
    /// Seed of its noise.
    pub seed: u64,
}

impl GnssSimOptions {
    /// An RTK-fixed receiver at 10 Hz on the built-in register, 100 m
    /// after its start, chainage rising.
    pub fn built_in(seed: u64) -> GnssSimOptions {
        let register = Register::parse(BUILT_IN_REGISTER).expect("the built-in register parses");
        GnssSimOptions {
            start_chainage_m: register.span_m().0 + 100.0,
            register,
            direction: 1.0,
            rate_hz: 10,
            quality: Quality::RtkFixed,
            sigma_m: 0.01,
            seed,
        }
    }
}

/// The receiver's state from one epoch to the next: its antenna on the
/// centreline, its noise, its Doppler speed. Shared by the receiver on a
/// pty and the synthetic recordings ([`crate::sim::synthetic`]).
#[derive(Debug)]
pub struct Antenna {
    opts: GnssSimOptions,
    rng: Rng,
    last: Option<(u64, f64)>,
}

impl Antenna {
    /// The antenna of a receiver with `opts`, its noise seeded by `opts.seed`.
    pub fn new(opts: GnssSimOptions) -> Antenna {
        Antenna { rng: Rng::for_stream(opts.seed, 0x6e55, 0, 0), opts, last: None }
    }

    /// The fix at `t_us` (the receiver's clock, µs) with the odometer at `odometer_m`.
    pub fn fix(&mut self, t_us: u64, odometer_m: f64, utc_ms_of_day: u32, date: (u16, u8, u8)) -> Fix {
        let o = &self.opts;
        let (p, heading) = o.register.at(o.start_chainage_m + o.direction * odometer_m);
        let (e, n) = (self.rng.normal() * o.sigma_m, self.rng.normal() * o.sigma_m);
        let q = offset(p, e, n);
        let speed_mm_s = match self.last {
            Some((t, odo)) if t_us > t => (odometer_m - odo).abs() * 1e9 / (t_us - t) as f64,
            _ => 0.0,
        };
        self.last = Some((t_us, odometer_m));
        Fix {
            utc_ms_of_day: Some(utc_ms_of_day),
            date: Some(date),
            lat_deg: q.lat_deg,
            lon_deg: q.lon_deg,
            altitude_m: Some(2.0),
            quality: o.quality,
            satellites: Some(14),
            hdop: Some(0.8),
            speed_mm_s: Some(speed_mm_s),
            course_deg: Some(if o.direction < 0.0 { (heading + 180.0) % 360.0 } else { heading }),
            receiver_sigma_m: None,
        }
    }
}

/// Degrees as NMEA's `ddmm.mmmmmmm` (`deg_digits` digits of degrees) and hemisphere.
fn angle(v: f64, deg_digits: usize, pos: char, neg: char) -> (String, char) {
    let a = v.abs();
    let mut d = a.trunc();
    let mut m = (a - d) * 60.0;
    // Rounded to the 7 decimals written: 59.99999996 would print as 60.
    if (m * 1e7).round() >= 60.0 * 1e7 {
        d += 1.0;
        m = 0.0;
    }
    (format!("{:0w$}{:010.7}", d as u32, m, w = deg_digits), if v < 0.0 { neg } else { pos })
}

/// The epoch's sentences, as a receiver sends them.
pub fn sentences(f: &Fix) -> String {
    let t = f.utc_ms_of_day.unwrap_or(0);
    let hms = format!("{:02}{:02}{:02}.{:02}", t / 3_600_000, t / 60_000 % 60, t / 1000 % 60, t % 1000 / 10);
    let (lat, ns) = angle(f.lat_deg, 2, 'N', 'S');
    let (lon, ew) = angle(f.lon_deg, 3, 'E', 'W');
    let knots = f.speed_mm_s.unwrap_or(0.0) / (1852.0 * 1000.0 / 3600.0);
    let course = f.course_deg.unwrap_or(0.0);
    let (y, mo, d) = f.date.unwrap_or((2000, 1, 1));
    let mut out = sentence(&format!(
        "GNGGA,{hms},{lat},{ns},{lon},{ew},{},{:02},{:.1},{:.3},M,47.000,M,1.0,0000",
        f.quality.digit(),
        f.satellites.unwrap_or(0),
        f.hdop.unwrap_or(99.9),
        f.altitude_m.unwrap_or(0.0)
    ));
    out += &sentence(&format!(
        "GNRMC,{hms},A,{lat},{ns},{lon},{ew},{knots:.3},{course:.2},{d:02}{mo:02}{:02},,,R,V",
        y % 100
    ));
    out += &sentence(&format!("GNVTG,{course:.2},T,,M,{knots:.3},N,{:.3},K,R", knots * 1.852));
    out
}

/// UTC now: milliseconds of the day and the date.
fn utc_now() -> (u32, (u16, u8, u8)) {
    let since = SystemTime::now().duration_since(UNIX_EPOCH).unwrap_or_default();
    let (days, ms) = (since.as_secs() / 86_400, (since.as_millis() % 86_400_000) as u32);
    let date = chrono::NaiveDate::from_ymd_opt(1970, 1, 1)
        .and_then(|e| e.checked_add_days(chrono::Days::new(days)))
        .map_or((1970, 1, 1), |d| {
            use chrono::Datelike as _;
            (d.year().clamp(0, 9999) as u16, d.month() as u8, d.day() as u8)
        });
    (ms, date)
}

/// A simulated receiver sending on its pty; dropping it stops it.
pub struct GnssSim {
    path: PathBuf,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for GnssSim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GnssSim").field("path", &self.path).finish_non_exhaustive()
    }
}

impl GnssSim {
    /// Starts the receiver on a new pty, its antenna at the odometer `tap`
    /// publishes (µm; [`NO_FRAME`] until the first frame: odometer 0).
    pub fn spawn(opts: GnssSimOptions, tap: Arc<AtomicI64>) -> Result<GnssSim, SimulateError> {
        let mut pty = Pty::open()?;
        let path = pty.path().to_path_buf();
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let period = Duration::from_secs_f64(1.0 / f64::from(opts.rate_hz.max(1)));
        let mut antenna = Antenna::new(opts);
        let thread = std::thread::Builder::new()
            .name("cms-sim-gnss".into())
            .spawn(move || {
                let t0 = Instant::now();
                let mut k = 0u32;
                while !flag.load(Ordering::Relaxed) {
                    // Epochs on the receiver's own clock, a fixed period apart.
                    let due = t0 + period * k;
                    let now = Instant::now();
                    if due > now {
                        std::thread::sleep((due - now).min(Duration::from_millis(50)));
                        continue;
                    }
                    k += 1;
                    let odo_um = tap.load(Ordering::Relaxed);
                    let odometer_m = if odo_um == NO_FRAME { 0.0 } else { odo_um as f64 * 1e-6 };
                    let (ms, date) = utc_now();
                    let fix = antenna.fix((now - t0).as_micros() as u64, odometer_m, ms, date);
                    // A receiver sends whether anyone listens: what the
                    // pty cannot take is lost.
                    let _ = pty.send(sentences(&fix).as_bytes());
                }
            })
            .map_err(|e| SimulateError::Io("starting the simulated GNSS receiver", e))?;
        Ok(GnssSim { path, stop, thread: Some(thread) })
    }

    /// The pty's slave path: the receiver's port.
    pub fn path(&self) -> &std::path::Path {
        &self.path
    }
}

impl Drop for GnssSim {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gnss::Assembler;

    /// What the receiver sends is what the parser reads back, to the
    /// 7th decimal of a minute (0.2 mm).
    #[test]
    fn its_sentences_read_back_as_its_fixes() {
        let mut a = Antenna { opts: GnssSimOptions::built_in(3), rng: Rng::for_stream(3, 0, 0, 0), last: None };
        let f0 = a.fix(7_000, 0.0, 36_930_200, (2026, 12, 4));
        let f1 = a.fix(107_000, 0.05, 36_930_300, (2026, 12, 4));
        assert!((f1.speed_mm_s.unwrap() - 500.0).abs() < 1e-6);
        let mut asm = Assembler::new();
        let mut got = Vec::new();
        for f in [&f0, &f1] {
            for line in sentences(f).split_inclusive('\n') {
                got.extend(asm.line(line).unwrap());
            }
        }
        got.extend(asm.flush());
        assert_eq!(got.len(), 2);
        for (sent, read) in [&f0, &f1].into_iter().zip(&got) {
            assert!((sent.lat_deg - read.lat_deg).abs() < 1e-7 / 60.0 * 1.01, "{} {}", sent.lat_deg, read.lat_deg);
            assert!((sent.lon_deg - read.lon_deg).abs() < 1e-7 / 60.0 * 1.01);
            assert_eq!((read.quality, read.utc_ms_of_day, read.date), (sent.quality, sent.utc_ms_of_day, sent.date));
            assert!((read.speed_mm_s.unwrap() - sent.speed_mm_s.unwrap()).abs() < 1.0);
        }
        assert_eq!(angle(-0.999_999_999_9, 3, 'E', 'W'), ("00100.0000000".to_string(), 'W'));
    }

    /// The noise is what it says: 10 mm a side, on the built-in track's curve.
    #[test]
    fn the_noise_has_its_stated_deviation() {
        let opts = GnssSimOptions { start_chainage_m: 42_300.0, ..GnssSimOptions::built_in(5) };
        let mut a = Antenna { rng: Rng::for_stream(5, 0, 0, 0), opts, last: None };
        let reg = a.opts.register.clone();
        let n = 4000;
        let (mut s_along, mut s_cross) = (0.0, 0.0);
        for _ in 0..n {
            let f = a.fix(0, 0.0, 0, (2026, 1, 1));
            let on = reg.project(crate::gnss::register::Geodetic { lat_deg: f.lat_deg, lon_deg: f.lon_deg });
            s_along += (on.chainage_m - 42_300.0).powi(2);
            s_cross += on.offset_m.powi(2);
        }
        let (along, cross) = ((s_along / n as f64).sqrt(), (s_cross / n as f64).sqrt());
        // 4 000 draws: the RMS within ±4 % (3σ of its sampling error 1/√(2n) = 1.1 %).
        for v in [along, cross] {
            assert!((v - 0.01).abs() < 0.0004, "along {along} cross {cross}");
        }
    }
}
