//! The hub: what the listener hands the view, turned into the page's
//! updates at the display rate (the module docs have the path).

use std::collections::VecDeque;
use std::sync::atomic::Ordering;
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use cms_core::peak::Flags;
use cms_core::protocol::{DeviceInfo, DeviceMsg, Profile, Status};
use serde::Serialize;

use super::http::Update;
use super::{DISPLAY_HZ, Input, ServeOptions, Shared};
use crate::analyze::live::bands::{BandsReport, LiveBands};
use crate::analyze::live::iso3095::{Iso3095Live, LiveIso3095};
use crate::analyze::live::{LaserEstimate, LiveEstimate};
use crate::device::listen::LinkState;
use crate::recording::FrameCounter;
use crate::recording::survey_info::Heading;

/// The overlap consecutive frames need for the stitcher to register them
/// (`analyze::stitch::Options::default().min_overlap_mm`, a test checks):
/// the speed limit leaves it.
pub const MIN_OVERLAP_MM: f64 = 3.0;
/// How often the running corrugation estimate is made.
const ESTIMATE_EVERY: Duration = Duration::from_millis(500);
/// The span of frames the rates are taken over.
const RATE_WINDOW: Duration = Duration::from_secs(2);
/// How often an update goes out while no frame arrives (handshake,
/// reconnecting): the link's state still changes.
const IDLE_EVERY: Duration = Duration::from_millis(250);

/// The fastest travel at which each laser's stretch of rail (`span_mm`
/// along the line) still overlaps the next frame it is lit in by
/// [`MIN_OVERLAP_MM`], lit `lit_per_s` frames a second: `(span −
/// overlap) × rate`. `None` for a span no longer than the overlap.
pub fn speed_limit_mm_s(span_mm: f64, lit_per_s: f64) -> Option<f64> {
    (span_mm > MIN_OVERLAP_MM && lit_per_s > 0.0).then_some((span_mm - MIN_OVERLAP_MM) * lit_per_s)
}

/// One laser's points of the newest frame as the page draws them:
/// metric (µm along, nm of height, the wire's own integers) once the head
/// is calibrated, else image row and stripe position (px).
#[derive(Debug, Default, Serialize)]
struct LaserPoints {
    laser: usize,
    /// Points kept: position along the line, height, strength (counts),
    /// saturated (0/1).
    x: Vec<f64>,
    y: Vec<f64>,
    strength: Vec<u16>,
    saturated: Vec<u8>,
    /// Candidates the head's line pass rejected: position, height, why
    /// ("glint", "ghost", "off-line").
    rejected_x: Vec<f64>,
    rejected_y: Vec<f64>,
    rejected_why: Vec<&'static str>,
    kept: usize,
    saturated_kept: usize,
    rejected: usize,
    /// Mean strength of the kept points, counts.
    mean_strength: Option<f64>,
    /// Extent of the kept metric points along the line, mm.
    span_mm: Option<f64>,
}

#[derive(Debug, Default, Serialize)]
struct FrameView {
    seq: u32,
    odometer_mm: f64,
    timestamp_us: u64,
    exposure_us: u32,
    laser_mask: u8,
    /// "metric" (x µm, y nm) or "pixel" (x row, y px).
    units: &'static str,
    lasers: Vec<LaserPoints>,
}

#[derive(Debug, Serialize)]
struct Corrugation {
    laser: usize,
    length_mm: f64,
    wavelength_mm: Option<f64>,
    amplitude_um: Option<f64>,
    /// The sine's fit to its one-wavelength model, a diagnostic (a rail
    /// of several wavelengths does not fit it): "good", "doubtful",
    /// "failed", or "none" without a sine.
    verdict: String,
    /// The verdict's reasons, or why there is no sine.
    reasons: Vec<String>,
}

#[derive(Debug, Serialize)]
struct Speed {
    mm_s: Option<f64>,
    limit_mm_s: Option<f64>,
    over: bool,
    /// Why there is no limit.
    note: Option<&'static str>,
}

/// One update, as the page reads it.
#[derive(Debug, Serialize)]
struct Snapshot<'a> {
    update: u64,
    port: &'a str,
    recording: bool,
    phase: &'static str,
    device: Option<Device>,
    head: Option<Head>,
    frames: u64,
    recorded: Option<u64>,
    lost_frames: u64,
    head_dropped_frames: u32,
    damaged_frames: u64,
    crc_errors: u64,
    resyncs: u64,
    reconnects: u32,
    stalls: u32,
    head_restarts: u32,
    frames_per_s: Option<f64>,
    odometer_m: Option<f64>,
    chainage: Option<String>,
    speed: Speed,
    view_dropped: u64,
    page_skipped: u64,
    pages: u64,
    frame: Option<&'a FrameView>,
    corrugation: &'a [Corrugation],
    /// The run's EN 13231-3 band figures so far (`None` before calibrated frames).
    bands: Option<&'a BandsReport>,
    /// The latest stretch's ISO 3095 verdicts, or what they need (`None`
    /// before calibrated frames).
    iso3095: Option<&'a Iso3095Live>,
}

#[derive(Debug, Serialize)]
struct Device {
    firmware: String,
    board: String,
    sensor_width: u16,
    sensor_height: u16,
    bits: u8,
    calibrated: bool,
    calibration_id: u32,
}

#[derive(Debug, Serialize)]
struct Head {
    state: &'static str,
    lasers_on: u8,
    laser_duty_percent: f64,
    fault: Option<String>,
}

/// A frame's timing for the rates: head clock, odometer and lasers lit.
#[derive(Clone, Copy, Debug)]
struct Tick {
    at: Instant,
    timestamp_us: u64,
    odometer_mm: f64,
    laser_mask: u8,
}

struct Hub<'a> {
    opts: &'a ServeOptions,
    device: Option<DeviceInfo>,
    head: Option<Status>,
    link: LinkState,
    counter: FrameCounter,
    building: Option<FrameView>,
    newest: Option<FrameView>,
    live: LiveEstimate,
    estimate: Vec<Corrugation>,
    estimated_at: Option<Instant>,
    bands: LiveBands,
    bands_report: Option<BandsReport>,
    /// Judged on a worker thread of its own (it would hold the hub for
    /// its cost: [`crate::analyze::live::iso3095`]).
    iso3095: LiveIso3095,
    iso3095_report: Option<Iso3095Live>,
    ticks: VecDeque<Tick>,
    frames_seen: u64,
}

/// Runs the hub until the view stops or the listener's feed goes away.
pub(super) fn run(rx: Receiver<Input>, out: tokio::sync::watch::Sender<Update>, shared: &Shared, opts: &ServeOptions) {
    let mut hub = Hub {
        opts,
        device: None,
        head: None,
        link: LinkState::default(),
        counter: FrameCounter::default(),
        building: None,
        newest: None,
        live: LiveEstimate::default(),
        estimate: Vec::new(),
        estimated_at: None,
        bands: LiveBands::new(opts.live_bands),
        bands_report: None,
        iso3095: LiveIso3095::threaded(crate::analyze::Options {
            stitch: opts.live_bands.stitch,
            ..crate::analyze::Options::default()
        }),
        iso3095_report: None,
        ticks: VecDeque::new(),
        frames_seen: 0,
    };
    let interval = Duration::from_secs_f64(1.0 / DISPLAY_HZ);
    let mut due = Instant::now();
    let mut last_sent = Instant::now();
    let mut fresh = false;
    while !shared.stop.load(Ordering::SeqCst) {
        match rx.recv_timeout(interval) {
            Ok(Input::Message(m)) => fresh |= hub.message(*m),
            Ok(Input::Link(l)) => hub.link = l,
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        let now = Instant::now();
        // A new frame at most DISPLAY_HZ times a second (the schedule keeps
        // its rate against frames that arrive at another), the link's
        // state alone four times a second.
        if (fresh && now >= due) || now.duration_since(last_sent) >= IDLE_EVERY {
            if hub.estimated_at.is_none_or(|t| now.duration_since(t) >= ESTIMATE_EVERY) {
                hub.estimate = hub.live.estimate().iter().map(corrugation).collect();
                hub.bands_report = hub.bands.report().cloned();
                hub.iso3095_report = hub.iso3095.report().cloned();
                hub.estimated_at = Some(now);
            }
            let n = shared.updates.fetch_add(1, Ordering::Relaxed) + 1;
            let json = hub.snapshot(n, now, shared);
            out.send_replace(Update { seq: n, json: json.into() });
            due = (due + interval).max(now - interval);
            last_sent = now;
            fresh = false;
        }
    }
}

fn corrugation(e: &LaserEstimate) -> Corrugation {
    match (&e.fit, &e.verdict) {
        (Ok(s), Some(v)) => Corrugation {
            laser: e.laser,
            length_mm: e.length_mm,
            wavelength_mm: Some(s.wavelength_mm),
            amplitude_um: Some(s.amplitude_um),
            verdict: v.level.to_string(),
            reasons: v.reasons.iter().map(ToString::to_string).collect(),
        },
        (Ok(_), None) => Corrugation {
            laser: e.laser,
            length_mm: e.length_mm,
            wavelength_mm: None,
            amplitude_um: None,
            verdict: "none".into(),
            reasons: vec!["no verdict".into()],
        },
        (Err(why), _) => Corrugation {
            laser: e.laser,
            length_mm: e.length_mm,
            wavelength_mm: None,
            amplitude_um: None,
            verdict: "none".into(),
            reasons: vec![format!("no sine over {:.0} mm: {why}", e.length_mm)],
        },
    }
}

fn why_rejected(f: Flags) -> &'static str {
    if f.0 & Flags::GLINT.0 != 0 {
        "glint"
    } else if f.0 & Flags::GHOST.0 != 0 {
        "ghost"
    } else {
        "off-line"
    }
}

impl Hub<'_> {
    /// Takes one message; true when it completed a frame.
    fn message(&mut self, m: DeviceMsg) -> bool {
        match m {
            DeviceMsg::Hello(info) => {
                self.device = Some(info);
                false
            }
            DeviceMsg::Status(s) => {
                self.head = Some(s);
                false
            }
            DeviceMsg::Profile(p) => self.profile(&p),
            _ => false,
        }
    }

    fn profile(&mut self, p: &Profile) -> bool {
        if let Some(f) = self.live.push(p) {
            self.bands.add(f);
            self.iso3095.add(f);
        }
        let complete = self.counter.profile(p);
        if p.part == 0 || self.building.as_ref().is_none_or(|b| b.seq != p.seq) {
            self.building = Some(FrameView {
                seq: p.seq,
                odometer_mm: p.odometer_um as f64 / 1000.0,
                timestamp_us: p.timestamp_us,
                exposure_us: p.exposure_us,
                laser_mask: p.laser_mask,
                units: "pixel",
                lasers: Vec::new(),
            });
        }
        let Some(b) = self.building.as_mut() else { return false };
        for l in &p.lasers {
            let k = usize::from(l.laser);
            let at = match b.lasers.iter().position(|v| v.laser == k) {
                Some(i) => i,
                None => {
                    b.lasers.push(LaserPoints { laser: k, ..LaserPoints::default() });
                    b.lasers.len() - 1
                }
            };
            let v = &mut b.lasers[at];
            for q in &l.points {
                let (x, y) = match q.metric {
                    Some(m) => {
                        b.units = "metric";
                        (f64::from(m.along_um), f64::from(m.height_nm))
                    }
                    None => (f64::from(q.row), q.position.to_f64()),
                };
                if q.flags.rejected() {
                    v.rejected_x.push(x);
                    v.rejected_y.push(y);
                    v.rejected_why.push(why_rejected(q.flags));
                } else {
                    let sat = q.flags.0 & Flags::SATURATED.0 != 0;
                    v.x.push(x);
                    v.y.push(y);
                    v.strength.push(q.strength);
                    v.saturated.push(u8::from(sat));
                }
            }
        }
        if !complete {
            return false;
        }
        let Some(mut f) = self.building.take() else { return false };
        f.lasers.sort_by_key(|l| l.laser);
        for l in &mut f.lasers {
            l.kept = l.x.len();
            l.rejected = l.rejected_x.len();
            l.saturated_kept = l.saturated.iter().filter(|&&s| s == 1).count();
            l.mean_strength =
                (l.kept > 0).then(|| l.strength.iter().map(|&s| f64::from(s)).sum::<f64>() / l.kept as f64);
            if f.units == "metric" && l.kept > 1 {
                let (lo, hi) = l.x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
                l.span_mm = Some((hi - lo) / 1000.0);
            }
        }
        self.frames_seen += 1;
        let now = Instant::now();
        self.ticks.push_back(Tick {
            at: now,
            timestamp_us: f.timestamp_us,
            odometer_mm: f.odometer_mm,
            laser_mask: f.laser_mask,
        });
        while self.ticks.front().is_some_and(|t| now.duration_since(t.at) > RATE_WINDOW) {
            self.ticks.pop_front();
        }
        self.newest = Some(f);
        true
    }

    /// Seconds between the first and last frame of the rate window, by
    /// the head's clock (by arrival if its clock does not advance).
    fn window_s(&self) -> Option<f64> {
        let (a, b) = (self.ticks.front()?, self.ticks.back()?);
        if self.ticks.len() < 2 {
            return None;
        }
        let head = b.timestamp_us.checked_sub(a.timestamp_us).map(|d| d as f64 * 1e-6).filter(|d| *d > 0.0);
        head.or_else(|| Some(b.at.duration_since(a.at).as_secs_f64()).filter(|d| *d > 0.0))
    }

    fn speed(&self, frames_per_s: Option<f64>) -> Speed {
        let none = |note| Speed { mm_s: None, limit_mm_s: None, over: false, note: Some(note) };
        let (Some(dt), Some(a), Some(b)) = (self.window_s(), self.ticks.front(), self.ticks.back()) else {
            return none("no frames yet");
        };
        let mm_s = (b.odometer_mm - a.odometer_mm) / dt;
        let Some(f) = self.newest.as_ref().filter(|f| f.units == "metric") else {
            return Speed {
                mm_s: Some(mm_s),
                limit_mm_s: None,
                over: false,
                note: Some("no limit without a calibration"),
            };
        };
        let n = self.ticks.len() as f64;
        // Per laser: its stretch and the frames a second it is lit in.
        let limit = f
            .lasers
            .iter()
            .filter_map(|l| {
                let lit = self.ticks.iter().filter(|t| t.laser_mask & (1 << l.laser) != 0).count() as f64;
                let per_s = frames_per_s? * lit / n;
                speed_limit_mm_s(l.span_mm?, per_s)
            })
            .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.min(v))));
        match limit {
            Some(l) => Speed { mm_s: Some(mm_s), limit_mm_s: Some(l), over: mm_s.abs() > l, note: None },
            None => {
                Speed { mm_s: Some(mm_s), limit_mm_s: None, over: false, note: Some("no laser's stretch to judge by") }
            }
        }
    }

    fn snapshot(&self, update: u64, _now: Instant, shared: &Shared) -> String {
        let frames_per_s = self.window_s().map(|dt| (self.ticks.len() - 1) as f64 / dt);
        let odometer_m = self.newest.as_ref().map(|f| f.odometer_mm / 1000.0);
        let chainage = match (self.opts.placement, odometer_m) {
            (Some(p), Some(o)) => p.start_m.map(|s| {
                let m = match p.heading {
                    Some(Heading::Down) => s - o,
                    _ => s + o,
                };
                crate::recording::survey_info::Chainage(m).to_string()
            }),
            _ => None,
        };
        let s = Snapshot {
            update,
            port: &self.opts.port,
            recording: self.opts.recording,
            phase: self.link.phase.name(),
            device: self.device.as_ref().map(|d| Device {
                firmware: d.firmware.as_str().to_string(),
                board: d.board.as_str().to_string(),
                sensor_width: d.sensor_width,
                sensor_height: d.sensor_height,
                bits: d.bits,
                calibrated: d.calibration_id != 0,
                calibration_id: d.calibration_id,
            }),
            head: self.head.as_ref().map(|h| Head {
                state: match h.state {
                    cms_core::protocol::HeadState::Idle => "idle",
                    cms_core::protocol::HeadState::Streaming => "streaming",
                    _ => "fault",
                },
                lasers_on: h.lasers_on,
                laser_duty_percent: f64::from(h.laser_duty_permille) / 10.0,
                fault: h.fault.map(|f| format!("{f:?}")),
            }),
            frames: self.link.frames.max(self.frames_seen),
            recorded: self.link.recorded,
            lost_frames: shared.lost_frames.load(Ordering::Relaxed),
            head_dropped_frames: self.head.map_or(0, |h| h.dropped_frames),
            damaged_frames: self.link.link.damaged(),
            crc_errors: self.link.link.crc_errors,
            resyncs: self.link.link.resyncs(),
            reconnects: self.link.reconnects,
            stalls: self.link.stalls,
            head_restarts: self.link.head_restarts,
            frames_per_s,
            odometer_m,
            chainage,
            speed: self.speed(frames_per_s),
            view_dropped: shared.view_dropped.load(Ordering::Relaxed),
            page_skipped: shared.page_skipped.load(Ordering::Relaxed),
            pages: shared.pages_open.load(Ordering::Relaxed),
            frame: self.newest.as_ref(),
            corrugation: &self.estimate,
            bands: self.bands_report.as_ref(),
            iso3095: self.iso3095_report.as_ref(),
        };
        serde_json::to_string(&s).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analyze::stitch;

    #[test]
    fn the_limit_leaves_the_stitchers_overlap() {
        assert_eq!(stitch::Options::default().min_overlap_mm, MIN_OVERLAP_MM);
        // The reference head's 69 mm at 30 frames/s: 1.98 m/s.
        assert_eq!(speed_limit_mm_s(69.0, 30.0), Some(1980.0));
        // Lit one frame in three (sequential): a third of it.
        assert_eq!(speed_limit_mm_s(69.0, 10.0), Some(660.0));
        assert_eq!(speed_limit_mm_s(3.0, 30.0), None);
        assert_eq!(speed_limit_mm_s(69.0, 0.0), None);
    }
}
