//! Receivers' streams as their makers document them, read as the receiver
//! thread reads a port: every epoch's fix whole, every sentence that is
//! not damaged either used or counted as other.
//!
//! Each family's epoch is written in its documented order and talkers,
//! with the empty fields it leaves, its proprietary sentences and its
//! binary frames between the sentences (payloads holding `$`, line ends
//! and other protocols' sync bytes), at its rates:
//!
//! - u-blox F9 (NMEA 4.11, interface description): `RMC, VTG, GNS, GGA,
//!   GSA…, GSV…, GLL, GST, ZDA`, `$PUBX,00` and `$PUBX,04`, UBX-NAV-PVT
//!   and UBX-NAV-HPPOSLLH frames, talker `GN` (`GSV` per constellation:
//!   `GP`, `GL`, `GA`, `GB`), 1–20 Hz;
//! - u-blox with `GGA` off: the position from `GNS`;
//! - Septentrio (mosaic, AsteRx): `GGA, GST, RMC, VTG, ZDA` in the order
//!   of its NMEA output stream, SBF blocks (PVTGeodetic) and RTCM 3
//!   between them, talker `GP`, 10 Hz;
//! - Trimble (BD9xx, R-series): `ZDA, GGA, GST, VTG, RMC` and `$PTNL,GGK`,
//!   RTCM 3 corrections echoed, talker `GN`, 5 Hz;
//! - NovAtel OEM7: one log after another, `BESTPOSB` (binary) then
//!   `GPGGA, GPGST, GPVTG, GPRMC, GPZDA`, 20 Hz;
//! - MediaTek / Quectel chipsets: `RMC, VTG, GGA, GSA, GSV…, GLL` and
//!   `$PMTK`, talker `GP`, 1–10 Hz;
//! - SiRF chipsets: `GGA, GLL, GSA, GSV…, RMC, VTG` and `$PSRF`, 1 Hz.

use std::time::{Duration, Instant};

use super::framing::frames;
use super::receiver::Lines;
use super::sentence::sentence;
use super::{Fix, Quality};

/// One epoch as the receiver knows it.
struct Truth {
    ms: u32,
    lat_deg: f64,
    lon_deg: f64,
    knots: f64,
    course_deg: f64,
}

const DATE: &str = "061226";

fn hms(ms: u32) -> String {
    let s = ms / 1000;
    format!("{:02}{:02}{:02}.{:02}", s / 3600, s / 60 % 60, s % 60, ms % 1000 / 10)
}

/// `ddmm.mmmmmmm,N` or `dddmm.mmmmmmm,E`.
fn angle(v: f64, deg_digits: usize, pos: char, neg: char) -> String {
    let a = v.abs();
    let d = a.trunc();
    format!("{:0w$}{:010.7},{}", d as u32, (a - d) * 60.0, if v < 0.0 { neg } else { pos }, w = deg_digits)
}

fn ll(t: &Truth) -> String {
    format!("{},{}", angle(t.lat_deg, 2, 'N', 'S'), angle(t.lon_deg, 3, 'E', 'W'))
}

/// What a stream's sentences say, read back from their text: the
/// position to the last digit written.
fn read_back(t: &Truth) -> (f64, f64) {
    let f = |s: &str, d: usize| {
        let (deg, min) = s.split_at(d);
        deg.parse::<f64>().unwrap() + min.parse::<f64>().unwrap() / 60.0
    };
    let l = ll(t);
    let p: Vec<&str> = l.split(',').collect();
    let sign = |h: &str| if h == "S" || h == "W" { -1.0 } else { 1.0 };
    (sign(p[1]) * f(p[0], 2), sign(p[3]) * f(p[2], 3))
}

fn s(body: String) -> Vec<u8> {
    sentence(&body).into_bytes()
}

/// A binary payload as hostile as a real one: `$`, line ends, a sentence,
/// the sync bytes of every protocol.
fn payload(n: usize) -> Vec<u8> {
    b"$GNGGA,000000.00*4A\r\n\n\r$\xB5\x62\xD3\x00\xAA\x44\x12$@*\x00".iter().copied().cycle().take(n).collect()
}

fn gsv(talker: &str) -> Vec<Vec<u8>> {
    vec![
        s(format!("{talker}GSV,2,1,07,05,45,120,40,07,30,200,38,08,12,300,,10,60,050,44,1")),
        s(format!("{talker}GSV,2,2,07,13,05,010,,15,70,250,47,18,33,090,41,1")),
    ]
}

/// An epoch's pieces (sentences and frames) and how many of them are
/// "other" (proprietary, not read, binary).
type Epoch = (Vec<Vec<u8>>, u64);

fn ublox(t: &Truth, gga: bool) -> Epoch {
    let (h, p) = (hms(t.ms), ll(t));
    let mut v = vec![
        s(format!("GNRMC,{h},A,{p},{:.3},{:.2},{DATE},,,R,V", t.knots, t.course_deg)),
        s(format!("GNVTG,{:.2},T,,M,{:.3},N,{:.3},K,R", t.course_deg, t.knots, t.knots * 1.852)),
        s(format!("GNGNS,{h},{p},RRRN,24,0.55,101.345,47.012,1.0,0000,V")),
    ];
    if gga {
        v.push(s(format!("GNGGA,{h},{p},4,12,0.55,101.345,M,47.012,M,1.0,0000")));
    }
    v.push(frames::ubx(0x01, 0x07, &payload(92)));
    v.push(s("GNGSA,A,3,05,07,10,13,15,18,,,,,,,0.98,0.55,0.81,1".into()));
    v.push(s("GNGSA,A,3,65,66,,,,,,,,,,,0.98,0.55,0.81,2".into()));
    for talker in ["GP", "GL", "GA", "GB"] {
        v.extend(gsv(talker));
    }
    v.push(s(format!("GNGLL,{p},{h},A,R")));
    v.push(s(format!("GNGST,{h},0.012,0.0123,0.0081,88.1,0.0082,0.0121,0.019")));
    v.push(s(format!("GNZDA,{h},06,12,2026,00,00")));
    v.push(frames::ubx(0x01, 0x14, &payload(36)));
    v.push(s(format!("PUBX,00,{h},{p},101.345,R2,0.012,0.019,3.6,87.5,0.000,,0.55,0.81,0.98,24,0,0")));
    v.push(s(format!("PUBX,04,{h},{DATE},36930.20,2344,18,120000,-12.5,21")));
    // The UBX frames, GSAs, GSVs and PUBXs.
    (v, 2 + 2 + 8 + 2)
}

fn septentrio(t: &Truth) -> Epoch {
    let (h, p) = (hms(t.ms), ll(t));
    let v = vec![
        frames::sbf(4007, &payload(88)),
        s(format!("GPGGA,{h},{p},4,18,0.6,101.345,M,47.012,M,1.2,0001")),
        s(format!("GPGST,{h},0.015,0.013,0.009,12.0,0.010,0.012,0.020")),
        s(format!("GPRMC,{h},A,{p},{:.3},{:.2},{DATE},1.2,E,R", t.knots, t.course_deg)),
        frames::rtcm3(&payload(180)),
        s(format!(
            "GPVTG,{:.2},T,{:.2},M,{:.3},N,{:.3},K,R",
            t.course_deg,
            t.course_deg - 1.2,
            t.knots,
            t.knots * 1.852
        )),
        s(format!("GPZDA,{h},06,12,2026,,")),
        frames::sbf(4027, &payload(300)),
    ];
    (v, 3)
}

fn trimble(t: &Truth) -> Epoch {
    let (h, p) = (hms(t.ms), ll(t));
    let v = vec![
        s(format!("GNZDA,{h},06,12,2026,00,00")),
        s(format!("GNGGA,{h},{p},4,21,0.7,101.345,M,47.012,M,2.0,0031")),
        frames::rtcm3(&payload(240)),
        s(format!("GNGST,{h},0.016,0.014,0.010,33.0,0.011,0.013,0.022")),
        s(format!("GNVTG,{:.2},T,,M,{:.3},N,{:.3},K,D", t.course_deg, t.knots, t.knots * 1.852)),
        s(format!("GNRMC,{h},A,{p},{:.3},{:.2},{DATE},,,D", t.knots, t.course_deg)),
        s(format!("PTNL,GGK,{h},120626,{p},3,21,0.7,EHT148.357,M")),
    ];
    (v, 2)
}

fn novatel(t: &Truth) -> Epoch {
    let (h, p) = (hms(t.ms), ll(t));
    let v = vec![
        frames::novatel(42, &payload(72)),
        s(format!("GPGGA,{h},{p},4,16,0.9,101.345,M,47.012,M,03,0022")),
        s(format!("GPGST,{h},0.020,0.015,0.011,75.0,0.012,0.014,0.021")),
        s(format!(
            "GPVTG,{:.3},T,{:.3},M,{:.4},N,{:.4},K,D",
            t.course_deg,
            t.course_deg + 2.0,
            t.knots,
            t.knots * 1.852
        )),
        s(format!("GPRMC,{h},A,{p},{:.4},{:.3},{DATE},2.0,W,D", t.knots, t.course_deg)),
        s(format!("GPZDA,{h},06,12,2026,,")),
        frames::novatel(43, &payload(44 + 44 * 12)),
    ];
    (v, 2)
}

fn mediatek(t: &Truth) -> Epoch {
    let (h, p) = (hms(t.ms), ll(t));
    let mut v = vec![
        s(format!("GPRMC,{h},A,{p},{:.2},{:.2},{DATE},,,D", t.knots, t.course_deg)),
        s(format!("GPVTG,{:.2},T,,M,{:.2},N,{:.2},K,D", t.course_deg, t.knots, t.knots * 1.852)),
        s(format!("GPGGA,{h},{p},2,09,0.92,101.3,M,47.0,M,,")),
        s("GPGSA,A,3,05,07,10,13,15,18,,,,,,,1.21,0.92,0.79".into()),
    ];
    v.extend(gsv("GP"));
    v.push(s(format!("GPGLL,{p},{h},A,D")));
    v.push(s("PMTK010,002".into()));
    (v, 4)
}

fn sirf(t: &Truth) -> Epoch {
    let (h, p) = (hms(t.ms), ll(t));
    let mut v = vec![
        s(format!("GPGGA,{h},{p},1,07,1.1,101.3,M,47.0,M,,0000")),
        s(format!("GPGLL,{p},{h},A,A")),
        s("GPGSA,A,3,05,07,10,13,15,18,,,,,,,1.8,1.1,1.4".into()),
    ];
    v.extend(gsv("GP"));
    v.push(s(format!("GPRMC,{h},A,{p},{:.1},{:.1},{DATE},,,A", t.knots, t.course_deg)));
    v.push(s(format!("GPVTG,{:.1},T,,M,{:.1},N,{:.1},K,A", t.course_deg, t.knots, t.knots * 1.852)));
    v.push(s("PSRF151,1".into()));
    (v, 4)
}

fn truths(rate_hz: u32, n: usize) -> Vec<Truth> {
    let step_ms = 1000 / rate_hz;
    (0..n)
        .map(|i| Truth {
            ms: 10 * 3_600_000 + 59 * 60_000 + 59_000 + i as u32 * step_ms,
            lat_deg: 52.0907 + i as f64 * 1.234_567e-6,
            lon_deg: -0.1214 - i as f64 * 2.345_678e-6,
            knots: 1.944 + i as f64 * 0.01,
            course_deg: 87.5 + i as f64 * 0.25,
        })
        .collect()
}

struct Read {
    fixes: Vec<(Instant, Fix)>,
    lines: Lines,
    other: u64,
}

/// Writes `n` epochs of a family at `rate_hz`, each epoch a burst of
/// bytes delivered in pieces of `chunk`, the port silent between bursts.
fn read(family: &dyn Fn(&Truth) -> Epoch, rate_hz: u32, n: usize, chunk: usize, damage: &[(usize, usize)]) -> Read {
    let t0 = Instant::now();
    let mut lines = Lines::default();
    let (mut fixes, mut other) = (Vec::new(), 0);
    for (i, t) in truths(rate_hz, n).iter().enumerate() {
        let (pieces, o) = family(t);
        other += o;
        let mut burst: Vec<u8> = Vec::new();
        for (j, mut p) in pieces.into_iter().enumerate() {
            if damage.contains(&(i, j)) {
                let k = p.len() / 2;
                p[k] = if p[k] == b'7' { b'8' } else { b'7' };
            }
            burst.extend(p);
        }
        let at = t0 + Duration::from_millis(u64::from(t.ms));
        for c in burst.chunks(chunk) {
            lines.feed(c, at, &mut |t, f| fixes.push((t, f)));
        }
        lines.idle(&mut |t, f| fixes.push((t, f)));
    }
    Read { fixes, lines, other }
}

fn check(name: &str, family: &dyn Fn(&Truth) -> Epoch, rates: &[u32], quality: Quality, sigma: Option<f64>) {
    for &rate in rates {
        for chunk in [1, 17, 4096] {
            let n = 12;
            let r = read(family, rate, n, chunk, &[]);
            let l = &r.lines;
            let at = format!("{name} at {rate} Hz in pieces of {chunk}");
            assert_eq!(r.fixes.len(), n, "{at}");
            assert_eq!((l.asm.invalid, l.broken, l.framer.stray_bytes), (0, 0, 0), "{at}: damaged");
            assert_eq!(l.asm.ignored + l.asm.late + l.frames, r.other, "{at}: other");
            assert_eq!(l.asm.no_position, 0, "{at}");
            let t0 = r.fixes[0].0;
            for ((stamp, f), t) in r.fixes.iter().zip(truths(rate, n)) {
                let (lat, lon) = read_back(&t);
                assert_eq!((f.lat_deg, f.lon_deg), (lat, lon), "{at}");
                assert_eq!((f.utc_ms_of_day, f.date, f.quality), (Some(t.ms), Some((2026, 12, 6)), quality), "{at}");
                let kn = f.speed_mm_s.unwrap() * 3600.0 / 1_852_000.0;
                assert!((kn - t.knots).abs() < 0.051, "{at}: {kn} kn, sent {}", t.knots);
                assert!((f.course_deg.unwrap() - t.course_deg).abs() < 0.051, "{at}");
                assert_eq!(f.receiver_sigma_m, sigma, "{at}");
                // Stamped when its epoch's burst arrived.
                let since = (*stamp - t0).as_millis() as u32;
                assert_eq!(since, t.ms - truths(rate, 1)[0].ms, "{at}");
            }
        }
    }
}

#[test]
fn u_blox_epochs_are_whole_whatever_their_order() {
    check("u-blox", &|t| ublox(t, true), &[1, 5, 10, 20], Quality::RtkFixed, Some(0.0123));
    check("u-blox without GGA", &|t| ublox(t, false), &[10], Quality::RtkFixed, Some(0.0123));
}

#[test]
fn septentrio_trimble_and_novatel_epochs_are_whole() {
    check("Septentrio", &septentrio, &[10], Quality::RtkFixed, Some(0.013));
    check("Trimble", &trimble, &[5], Quality::RtkFixed, Some(0.014));
    check("NovAtel", &novatel, &[20], Quality::RtkFixed, Some(0.015));
}

#[test]
fn chipsets_epochs_are_whole() {
    check("MediaTek", &mediatek, &[1, 10], Quality::Differential, None);
    check("SiRF", &sirf, &[1], Quality::Autonomous, None);
}

/// Damaged sentences are counted as damaged, exactly; the rest of their
/// epoch still gives its fix where it has a position.
#[test]
fn damaged_is_what_was_damaged() {
    // u-blox: the RMC of epoch 2, the GGA of 5 (its GNS stands in), a GSV of 7.
    let r = read(&|t| ublox(t, true), 10, 12, 64, &[(2, 0), (5, 3), (7, 8)]);
    assert_eq!((r.lines.asm.invalid, r.lines.broken, r.fixes.len()), (3, 0, 12));
    // Epoch 2 has its speed from its VTG, its date from its ZDA.
    let f = &r.fixes[2].1;
    assert!(f.date.is_some() && f.speed_mm_s.is_some());
    assert_eq!(r.lines.asm.ignored + r.lines.frames, r.other - 1);
    // SiRF: the GGA of epoch 3: no position, that epoch is missing.
    let r = read(&sirf, 1, 6, 64, &[(3, 0)]);
    assert_eq!((r.lines.asm.invalid, r.fixes.len(), r.lines.asm.no_position), (1, 5, 1));
}
