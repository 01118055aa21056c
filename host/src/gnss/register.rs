//! Chainage from GNSS: fixes projected onto a track register's
//! centreline, and checked against the head's odometer.
//!
//! # The register
//! A CSV file of the track's centreline, one vertex a line, in chainage
//! order: `lat_deg,lon_deg,chainage_m` (WGS 84 degrees; the chainage the
//! railway gives that point, metres — at kilometre posts and between).
//! Chainage along a segment is interpolated linearly between its ends'
//! chainages, so a register whose chainage is not the geometric length
//! (a chainage jump, a surveyed length) is followed as the railway
//! counts it. At least two vertices; chainages strictly increasing.
//!
//! # The geometry
//! Each segment is projected in the local east-north plane of its first
//! vertex (WGS 84 to earth-centred to east-north-up): for segments of up to
//! a few kilometres the plane's error is below a millimetre. A fix's
//! chainage is that of the nearest point of the nearest segment; its
//! cross-track distance says whether it is on this track at all (a fix
//! farther than [`OFF_TRACK_M`] is not used, and counted).
//!
//! # The check against the odometer
//! Along one run the chainage is `c₀ ± k·odometer`: one offset, one
//! direction, one scale (the odometer's calibration, 1 within a few per
//! mille). The check fits `c₀` and `k` to the fixes by weighted least
//! squares and compares every fix with the fit. A fix disagrees when its
//! residual exceeds the **tolerance**: three times the combined standard
//! uncertainty of the fix (its solution's typical σ times HDOP), the
//! register ([`Register::sigma_m`], 0.05 m unless given) and the
//! receiver's unknown output latency (up to [`LATENCY_S`] at the fix's
//! speed, a uniform distribution: σ = v·L/√12 around its middle, with the
//! middle taken off). A disagreement is reported, with the worst fix,
//! never hidden: a slipping wheel, a wrong register, or a run placed on
//! the wrong track.

use std::path::Path;

use super::Placed;

/// Farther from the centreline than this, a fix is not on the track.
pub const OFF_TRACK_M: f64 = 10.0;
/// The receiver's output latency assumed at most, s.
pub const LATENCY_S: f64 = 0.1;
/// Semi-major axis of WGS 84, m.
const WGS84_A_M: f64 = 6_378_137.0;
/// Flattening of WGS 84.
const WGS84_F: f64 = 1.0 / 298.257_223_563;
/// The most vertices a register may have.
pub const MAX_VERTICES: usize = 1_000_000;

/// Why a register file cannot be used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RegisterError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A line is not what the format says.
    #[error("{path}:{line}: {why}")]
    Line {
        /// The file.
        path: String,
        /// Its line, from 1.
        line: usize,
        /// What is wrong.
        why: String,
    },
    /// The file as a whole is not a register.
    #[error("{path}: {why}")]
    File {
        /// The file.
        path: String,
        /// What is wrong.
        why: String,
    },
}

impl crate::error::Classify for RegisterError {
    fn class(&self) -> crate::Class {
        crate::Class::Input
    }
}

/// A point on the earth, WGS 84.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Geodetic {
    /// Latitude, degrees.
    pub lat_deg: f64,
    /// Longitude, degrees.
    pub lon_deg: f64,
}

/// Earth-centred, earth-fixed coordinates of a point on the ellipsoid, m.
fn ecef(p: Geodetic) -> [f64; 3] {
    let (lat, lon) = (p.lat_deg.to_radians(), p.lon_deg.to_radians());
    let e2 = WGS84_F * (2.0 - WGS84_F);
    let n = WGS84_A_M / (1.0 - e2 * lat.sin().powi(2)).sqrt();
    [n * lat.cos() * lon.cos(), n * lat.cos() * lon.sin(), n * (1.0 - e2) * lat.sin()]
}

/// A local east-north plane at a point.
#[derive(Clone, Copy, Debug)]
struct Plane {
    origin: [f64; 3],
    east: [f64; 3],
    north: [f64; 3],
}

impl Plane {
    fn at(p: Geodetic) -> Plane {
        let (lat, lon) = (p.lat_deg.to_radians(), p.lon_deg.to_radians());
        Plane {
            origin: ecef(p),
            east: [-lon.sin(), lon.cos(), 0.0],
            north: [-lat.sin() * lon.cos(), -lat.sin() * lon.sin(), lat.cos()],
        }
    }

    /// East and north of `p` in this plane, m.
    fn en(&self, p: Geodetic) -> (f64, f64) {
        let x = ecef(p);
        let d = [x[0] - self.origin[0], x[1] - self.origin[1], x[2] - self.origin[2]];
        let dot = |u: [f64; 3]| d[0] * u[0] + d[1] * u[1] + d[2] * u[2];
        (dot(self.east), dot(self.north))
    }

    /// The point `east`, `north` metres from the origin (on the ellipsoid,
    /// by fixed-point steps from the plane; exact to well under a
    /// millimetre within a few kilometres: each step's error is the
    /// ellipsoid's radii against the semi-major axis, under 1 %).
    pub fn geodetic(&self, origin: Geodetic, east_m: f64, north_m: f64) -> Geodetic {
        let mut g = origin;
        for _ in 0..6 {
            let (e, n) = self.en(g);
            let (de, dn) = (east_m - e, north_m - n);
            let r_n = WGS84_A_M; // metres per radian, near enough for a step
            g.lat_deg += (dn / r_n).to_degrees();
            g.lon_deg += (de / (r_n * g.lat_deg.to_radians().cos())).to_degrees();
        }
        g
    }
}

/// The point `east_m`, `north_m` metres from `origin` in its local plane.
pub fn offset(origin: Geodetic, east_m: f64, north_m: f64) -> Geodetic {
    Plane::at(origin).geodetic(origin, east_m, north_m)
}

/// East and north of `p` in the local plane at `origin`, m (the inverse
/// of [`offset`]).
pub fn east_north(origin: Geodetic, p: Geodetic) -> (f64, f64) {
    Plane::at(origin).en(p)
}

/// One segment of the centreline.
#[derive(Clone, Copy, Debug)]
struct Segment {
    from: Geodetic,
    plane: Plane,
    /// The far vertex in the plane, m.
    to_en: (f64, f64),
    chainage_m: (f64, f64),
}

/// A track register: the centreline with its chainages.
#[derive(Clone, Debug)]
pub struct Register {
    segments: Vec<Segment>,
    /// The standard uncertainty of the centreline's position, m.
    pub sigma_m: f64,
}

/// Where a fix falls on the register.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OnTrack {
    /// Chainage, m.
    pub chainage_m: f64,
    /// Distance from the centreline, m (positive to the left of the
    /// direction of increasing chainage).
    pub offset_m: f64,
}

impl Register {
    /// A register from its vertices (in chainage order).
    pub fn new(vertices: &[(Geodetic, f64)]) -> Result<Register, String> {
        if vertices.len() < 2 {
            return Err(format!("{} vertices; a centreline needs at least 2", vertices.len()));
        }
        let mut segments = Vec::with_capacity(vertices.len() - 1);
        for w in vertices.windows(2) {
            let ((a, ca), (b, cb)) = (w[0], w[1]);
            if cb <= ca {
                return Err(format!("chainage {cb} m after {ca} m: chainages must increase along the centreline"));
            }
            let plane = Plane::at(a);
            segments.push(Segment { from: a, plane, to_en: plane.en(b), chainage_m: (ca, cb) });
        }
        Ok(Register { segments, sigma_m: 0.05 })
    }

    /// Reads a register file (see the module docs).
    pub fn load(path: &Path) -> Result<Register, RegisterError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| RegisterError::Io { path: name.clone(), source })?;
        Register::parse(&text).map_err(|(line, why)| match line {
            0 => RegisterError::File { path: name.clone(), why },
            line => RegisterError::Line { path: name.clone(), line, why },
        })
    }

    /// Parses a register's text; the error gives its line (0: the file).
    pub fn parse(text: &str) -> Result<Register, (usize, String)> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut v = Vec::new();
        let mut header = false;
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let f: Vec<&str> = line.split(',').map(str::trim).collect();
            if !header {
                if f != ["lat_deg", "lon_deg", "chainage_m"] {
                    return Err((i + 1, format!("header {line:?}; a register starts with lat_deg,lon_deg,chainage_m")));
                }
                header = true;
                continue;
            }
            if f.len() != 3 {
                return Err((i + 1, format!("{} fields; expected lat_deg,lon_deg,chainage_m", f.len())));
            }
            let num = |s: &str, what: &str, lim: f64| -> Result<f64, (usize, String)> {
                match s.parse::<f64>() {
                    Ok(x) if x.is_finite() && x.abs() <= lim => Ok(x),
                    _ => Err((i + 1, format!("{what} {s:?} is not a number within ±{lim}"))),
                }
            };
            let g = Geodetic { lat_deg: num(f[0], "lat_deg", 89.0)?, lon_deg: num(f[1], "lon_deg", 180.0)? };
            v.push((g, num(f[2], "chainage_m", 1e8)?));
            if v.len() > MAX_VERTICES {
                return Err((i + 1, format!("more than {MAX_VERTICES} vertices")));
            }
        }
        if !header {
            return Err((0, "empty: no lat_deg,lon_deg,chainage_m header".into()));
        }
        Register::new(&v).map_err(|why| (0, why))
    }

    /// The register's chainages, first and last, m.
    pub fn span_m(&self) -> (f64, f64) {
        (self.segments[0].chainage_m.0, self.segments[self.segments.len() - 1].chainage_m.1)
    }

    /// The point of the centreline at `chainage_m` (clamped to the span),
    /// with the direction of increasing chainage (degrees from north).
    pub fn at(&self, chainage_m: f64) -> (Geodetic, f64) {
        let s = self
            .segments
            .iter()
            .find(|s| chainage_m <= s.chainage_m.1)
            .unwrap_or(&self.segments[self.segments.len() - 1]);
        let t = ((chainage_m - s.chainage_m.0) / (s.chainage_m.1 - s.chainage_m.0)).clamp(0.0, 1.0);
        let (e, n) = (s.to_en.0 * t, s.to_en.1 * t);
        (s.plane.geodetic(s.from, e, n), s.to_en.0.atan2(s.to_en.1).to_degrees().rem_euclid(360.0))
    }

    /// Where `p` falls: the nearest point of the centreline.
    pub fn project(&self, p: Geodetic) -> OnTrack {
        let mut best: Option<(f64, OnTrack)> = None;
        for s in &self.segments {
            let (pe, pn) = s.plane.en(p);
            let (de, dn) = s.to_en;
            let len2 = de * de + dn * dn;
            let t = ((pe * de + pn * dn) / len2).clamp(0.0, 1.0);
            let (ce, cn) = (pe - t * de, pn - t * dn);
            let d = (ce * ce + cn * cn).sqrt();
            if best.is_none_or(|(b, _)| d < b) {
                let side = if de * cn - dn * ce >= 0.0 { 1.0 } else { -1.0 };
                let chainage_m = s.chainage_m.0 + t * (s.chainage_m.1 - s.chainage_m.0);
                best = Some((d, OnTrack { chainage_m, offset_m: side * d }));
            }
        }
        best.expect("a register has segments").1
    }
}

/// The odometer at head time `t_us`, interpolated between the profiles'
/// `(timestamp_us, odometer_mm)` (sorted by time); `None` outside them.
pub fn odometer_at(profiles: &[(u64, f64)], t_us: u64) -> Option<f64> {
    let (first, last) = (profiles.first()?, profiles.last()?);
    if t_us < first.0 || t_us > last.0 {
        return None;
    }
    // The last profile at or before `t_us` (one exists), and the next.
    let i = profiles.partition_point(|&(t, _)| t <= t_us);
    let (t0, o0) = profiles[i - 1];
    Some(match profiles.get(i) {
        Some(&(t1, o1)) => o0 + (o1 - o0) * (t_us - t0) as f64 / (t1 - t0) as f64,
        None => o0,
    })
}

/// One fix as the check used it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Located {
    /// The odometer at the fix, m.
    pub odometer_m: f64,
    /// The fix on the register.
    pub on_track: OnTrack,
    /// The fit's chainage at that odometer, m.
    pub fitted_m: f64,
    /// The tolerance of this fix, m (see the module docs).
    pub tolerance_m: f64,
}

impl Located {
    /// The fix's chainage less the fit's, m.
    pub fn residual_m(&self) -> f64 {
        self.on_track.chainage_m - self.fitted_m
    }

    /// Whether the fix disagrees with the odometer.
    pub fn disagrees(&self) -> bool {
        self.residual_m().abs() > self.tolerance_m
    }
}

/// What the check found.
#[derive(Clone, Debug, PartialEq)]
pub struct Check {
    /// The fixes used, in time order.
    pub located: Vec<Located>,
    /// Fixes not used: no profile around them, a solution not from
    /// satellites, or off the track.
    pub unused: u64,
    /// Of those, farther than [`OFF_TRACK_M`] from the centreline.
    pub off_track: u64,
    /// Chainage at odometer 0, m.
    pub chainage_at_zero_m: f64,
    /// Metres of chainage per metre of odometer: ±1 (the direction) times
    /// the odometer's scale.
    pub scale: f64,
}

impl Check {
    /// The fixes beyond their tolerance.
    pub fn disagreeing(&self) -> usize {
        self.located.iter().filter(|l| l.disagrees()).count()
    }

    /// The fix with the largest residual against its tolerance.
    pub fn worst(&self) -> Option<&Located> {
        self.located
            .iter()
            .max_by(|a, b| (a.residual_m().abs() / a.tolerance_m).total_cmp(&(b.residual_m().abs() / b.tolerance_m)))
    }

    /// RMS of the residuals, m.
    pub fn rms_m(&self) -> f64 {
        let n = self.located.len().max(1) as f64;
        (self.located.iter().map(|l| l.residual_m().powi(2)).sum::<f64>() / n).sqrt()
    }
}

/// Why the check could not be made.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CheckError {
    /// Too few fixes on the track to fit an offset and a scale.
    #[error(
        "{used} fixes on the track with profiles around them ({unused} not used, {off_track} of them more than {OFF_TRACK_M} m off the centreline); the check needs at least 3"
    )]
    TooFew {
        /// Fixes usable.
        used: usize,
        /// Fixes not used.
        unused: u64,
        /// Of those, off the track.
        off_track: u64,
    },
    /// The fixes span too little odometer to tell a direction.
    #[error("the fixes span {0:.2} m of odometer; the check needs at least 1 m of travel")]
    NoTravel(f64),
}

/// Checks the recorded fixes against the odometer on `register`.
/// `profiles` are the run's `(timestamp_us, odometer_mm)`, sorted by time.
pub fn check(register: &Register, fixes: &[Placed], profiles: &[(u64, f64)]) -> Result<Check, CheckError> {
    let (mut rows, mut unused, mut off_track) = (Vec::new(), 0u64, 0u64);
    for p in fixes {
        let odo = p.head_us.and_then(|t| odometer_at(profiles, t));
        let (Some(odo_mm), true) = (odo, p.fix.quality.is_measured()) else {
            unused += 1;
            continue;
        };
        let on = register.project(super::register::Geodetic { lat_deg: p.fix.lat_deg, lon_deg: p.fix.lon_deg });
        if on.offset_m.abs() > OFF_TRACK_M {
            unused += 1;
            off_track += 1;
            continue;
        }
        let v_m_s = p.fix.speed_mm_s.unwrap_or(0.0) / 1000.0;
        let latency = v_m_s * LATENCY_S / 12f64.sqrt();
        let sigma = (p.fix.sigma_m().powi(2) + register.sigma_m.powi(2) + latency.powi(2)).sqrt();
        rows.push((odo_mm / 1000.0, on, sigma));
    }
    if rows.len() < 3 {
        return Err(CheckError::TooFew { used: rows.len(), unused, off_track });
    }
    let (lo, hi) = rows.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), r| (l.min(r.0), h.max(r.0)));
    if hi - lo < 1.0 {
        return Err(CheckError::NoTravel(hi - lo));
    }
    // Weighted least squares of chainage = c0 + k·odometer.
    let (mut sw, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(x, on, s) in &rows {
        let w = 1.0 / (s * s);
        sw += w;
        sx += w * x;
        sy += w * on.chainage_m;
        sxx += w * x * x;
        sxy += w * x * on.chainage_m;
    }
    let k = (sw * sxy - sx * sy) / (sw * sxx - sx * sx);
    let c0 = (sy - k * sx) / sw;
    let located = rows
        .into_iter()
        .map(|(x, on, s)| Located { odometer_m: x, on_track: on, fitted_m: c0 + k * x, tolerance_m: 3.0 * s })
        .collect();
    Ok(Check { located, unused, off_track, chainage_at_zero_m: c0, scale: k })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gnss::{Fix, Quality};

    fn fix(p: Geodetic, q: Quality) -> Fix {
        Fix {
            utc_ms_of_day: None,
            date: None,
            lat_deg: p.lat_deg,
            lon_deg: p.lon_deg,
            altitude_m: None,
            quality: q,
            satellites: Some(12),
            hdop: Some(0.8),
            speed_mm_s: Some(1000.0),
            course_deg: None,
            receiver_sigma_m: None,
        }
    }

    fn curved() -> Register {
        // 2 km: 1 km due east, then a 1 km chord north-east; chainage from 12 000 m.
        let o = Geodetic { lat_deg: 52.0, lon_deg: 5.0 };
        let a = offset(o, 1000.0, 0.0);
        let b = offset(o, 1000.0 + 1000.0 / 2f64.sqrt(), 1000.0 / 2f64.sqrt());
        Register::new(&[(o, 12_000.0), (a, 13_000.0), (b, 14_000.0)]).unwrap()
    }

    #[test]
    fn the_plane_is_true_to_a_millimetre_over_kilometres() {
        let o = Geodetic { lat_deg: 52.0, lon_deg: 5.0 };
        for (e, n) in [(1000.0, 0.0), (0.0, 2000.0), (-1500.0, 700.0)] {
            let p = offset(o, e, n);
            let (e2, n2) = east_north(o, p);
            assert!((e2 - e).abs() < 1e-3 && (n2 - n).abs() < 1e-3, "{e},{n} -> {e2},{n2}");
        }
        // One arc-minute of latitude is about 1 855 m at 52° N (WGS 84's meridian radius).
        let (_, n) = Plane::at(o).en(Geodetic { lat_deg: 52.0 + 1.0 / 60.0, lon_deg: 5.0 });
        assert!((n - 1855.0).abs() < 3.0, "{n}");
    }

    #[test]
    fn fixes_project_to_their_chainage_and_side() {
        let r = curved();
        let (p, heading) = r.at(12_500.0);
        assert!((heading - 90.0).abs() < 0.01, "{heading}");
        let on = r.project(p);
        assert!((on.chainage_m - 12_500.0).abs() < 1e-3 && on.offset_m.abs() < 1e-3, "{on:?}");
        // 2 m north of the first segment: left of the direction of travel (east).
        let left = offset(p, 0.0, 2.0);
        let on = r.project(left);
        assert!((on.chainage_m - 12_500.0).abs() < 1e-3 && (on.offset_m - 2.0).abs() < 1e-3, "{on:?}");
        let (p, _) = r.at(13_700.0);
        assert!((r.project(p).chainage_m - 13_700.0).abs() < 1e-3);
    }

    #[test]
    fn registers_with_bad_lines_are_refused_with_the_line() {
        assert!(Register::parse("lat_deg,lon_deg,chainage_m\n52,5,100\n52.001,5,200\n").is_ok());
        let bad = [
            ("x,y\n", 1),
            ("lat_deg,lon_deg,chainage_m\n52,5,100\n52,5\n", 3),
            ("lat_deg,lon_deg,chainage_m\n52,5,100\n95,5,200\n", 3),
            ("lat_deg,lon_deg,chainage_m\n52,5,100\n52.1,5,NaN\n", 3),
            ("lat_deg,lon_deg,chainage_m\n52,5,100\n52.1,5,100\n", 0),
            ("lat_deg,lon_deg,chainage_m\n52,5,100\n", 0),
            ("", 0),
        ];
        for (text, line) in bad {
            let e = Register::parse(text).unwrap_err();
            assert_eq!(e.0, line, "{text:?}: {e:?}");
        }
    }

    fn run(r: &Register, start_m: f64, dir: f64, n: usize, shift_m: f64) -> (Vec<Placed>, Vec<(u64, f64)>) {
        // 1 m/s for n seconds; a profile every 33 ms, a fix every 100 ms.
        let profiles: Vec<(u64, f64)> = (0..n * 30).map(|i| (i as u64 * 33_333, i as f64 * 33.333)).collect();
        let fixes = (0..n * 10)
            .map(|i| {
                let t_us = i as u64 * 100_000;
                let odo_m = t_us as f64 * 1e-6;
                let extra = if i >= n * 5 { shift_m } else { 0.0 };
                let (p, _) = r.at(start_m + dir * odo_m + extra);
                Placed { host_us: t_us, head_us: Some(t_us), odometer_um: None, fix: fix(p, Quality::RtkFixed) }
            })
            .collect();
        (fixes, profiles)
    }

    #[test]
    fn a_run_agrees_with_its_odometer_and_a_slip_is_reported() {
        let r = curved();
        let (fixes, profiles) = run(&r, 13_100.0, -1.0, 20, 0.0);
        let c = check(&r, &fixes, &profiles).unwrap();
        assert!((c.chainage_at_zero_m - 13_100.0).abs() < 0.01, "{}", c.chainage_at_zero_m);
        assert!((c.scale + 1.0).abs() < 1e-3, "{}", c.scale);
        assert_eq!(c.disagreeing(), 0);
        // Half-way, the wheel slips 0.5 m: the fixes disagree with the odometer.
        let (fixes, profiles) = run(&r, 13_100.0, 1.0, 20, 0.5);
        let c = check(&r, &fixes, &profiles).unwrap();
        assert!(c.disagreeing() > 0, "rms {}", c.rms_m());
        // Fixes of another track.
        let far: Vec<Placed> = fixes
            .iter()
            .map(|p| {
                let q = offset(Geodetic { lat_deg: p.fix.lat_deg, lon_deg: p.fix.lon_deg }, 0.0, 50.0);
                Placed { fix: fix(q, Quality::RtkFixed), ..p.clone() }
            })
            .collect();
        assert!(matches!(check(&r, &far, &profiles), Err(CheckError::TooFew { off_track: 200, .. })));
    }

    #[test]
    fn the_odometer_is_interpolated_between_profiles() {
        let p = [(0, 0.0), (100, 10.0), (200, 30.0)];
        assert_eq!(odometer_at(&p, 50), Some(5.0));
        assert_eq!(odometer_at(&p, 150), Some(20.0));
        assert_eq!(odometer_at(&p, 200), Some(30.0));
        assert_eq!(odometer_at(&p, 0), Some(0.0));
        assert_eq!(odometer_at(&p, 201), None);
        assert_eq!(odometer_at(&[], 0), None);
    }
}
