//! The sensor head's logic (`cms_core::pipeline::Head`): profiles from rows,
//! commands, and the laser-safety rules.

use cms_core::duty::{DUTY_BURST_US, DutyLimit, MAX_DUTY_PERMILLE};
use cms_core::peak::ColumnWindow;
use cms_core::persist::Stored;
use cms_core::pipeline::{Camera, HEARTBEAT_TIMEOUT_US, Head, Identity, LaserDriver, default_detector};
use cms_core::protocol::*;
use cms_core::readout::{Readout, RowSampling, RowSkip};
use cms_tests::{Gauss, Rng, clean_row, quantise};
use proptest::prelude::*;
use std::cell::{Cell, RefCell};
use std::rc::Rc;

/// The laser enables, with their whole history.
#[derive(Clone, Default)]
struct Lasers(Rc<RefCell<Vec<u8>>>);
impl LaserDriver for Lasers {
    fn set(&mut self, mask: u8) {
        self.0.borrow_mut().push(mask);
    }
}
impl Lasers {
    fn now(&self) -> u8 {
        *self.0.borrow().last().unwrap()
    }
}

/// A camera that renders three stripes drifting with the row (a corrugated
/// rail seen by the reference head), only for the lasers lit.
struct Cam {
    rng: Rng,
    row: u16,
    mask: u8,
    fail: bool,
    exposures: u32,
    /// The laser driver, to see what is lit at each exposure.
    lasers: Option<Lasers>,
    /// The driver's mask during each exposure.
    lit: Vec<u8>,
    /// The odometer, µm, when the head has an encoder.
    odo: Cell<Option<i64>>,
    /// Rows the camera lost (DMA overrun).
    lost_rows: u32,
    /// How it honours a readout (`None`: the default, whole frames), the
    /// readouts the head set, and rows read since the last exposure.
    sampling: Option<RowSampling>,
    readouts: Vec<Readout>,
    rows_read: u32,
}
impl Cam {
    fn new() -> Cam {
        Cam {
            rng: Rng::new(9),
            row: 0,
            mask: 0,
            fail: false,
            exposures: 0,
            lasers: None,
            lit: Vec::new(),
            odo: Cell::new(None),
            lost_rows: 0,
            sampling: None,
            readouts: Vec::new(),
            rows_read: 0,
        }
    }
    /// Sensor rows of output row `i` (the readout's group for a binning
    /// camera, the row itself otherwise).
    fn sensor_rows(&self, i: u16) -> std::ops::Range<u16> {
        match (self.sampling, self.readouts.last()) {
            (Some(RowSampling::Skip), Some(r)) => r.sensor_row(i)..r.sensor_row(i) + 1,
            (Some(RowSampling::Bin), Some(r)) => r.sensor_row(i)..r.sensor_row(i) + u16::from(r.skip().factor()),
            _ => i..i + 1,
        }
    }
    fn watching(l: &Lasers) -> Cam {
        Cam { lasers: Some(l.clone()), ..Cam::new() }
    }
    fn truth(row: u16, k: usize) -> f64 {
        200.0 + 180.0 * k as f64 + 2.0 * (row as f64 / 30.0).sin()
    }
}
impl Camera for Cam {
    type Error = ();
    fn width(&self) -> u16 {
        752
    }
    fn height(&self) -> u16 {
        480
    }
    fn bits(&self) -> u8 {
        12
    }
    fn expose(&mut self, _exposure_us: u32, laser_mask: u8) -> Result<i64, ()> {
        if self.fail {
            return Err(());
        }
        self.row = 0;
        self.rows_read = 0;
        self.mask = laser_mask;
        if let Some(l) = &self.lasers {
            self.lit.push(l.now());
        }
        self.exposures += 1;
        Ok(self.odo.get().unwrap_or(self.exposures as i64 * 1000))
    }
    fn odometer_um(&self) -> Option<i64> {
        self.odo.get()
    }
    fn dropped_rows(&self) -> u32 {
        self.lost_rows
    }
    fn read_row(&mut self, out: &mut [u16]) -> Result<(), ()> {
        // The mean of the output row's sensor rows (one but for binning).
        let rows = self.sensor_rows(self.row);
        let n = rows.len() as f64;
        let mut mean = vec![0.0; 752];
        for r in rows {
            let stripes: Vec<Gauss> = (0..3)
                .filter(|k| self.mask & (1 << k) != 0)
                .map(|k| Gauss { x0: Cam::truth(r, k), sigma: 2.5, amplitude: [2500.0, 1500.0, 900.0][k] })
                .collect();
            for (m, v) in mean.iter_mut().zip(clean_row(752, 150.0, &stripes)) {
                *m += v / n;
            }
        }
        let row = quantise(&mean, 4.0, 12, &mut self.rng);
        out.copy_from_slice(&row);
        self.row += 1;
        self.rows_read += 1;
        Ok(())
    }
    fn set_readout(&mut self, readout: &Readout) -> Result<RowSampling, ()> {
        self.readouts.push(*readout);
        Ok(self.sampling.unwrap_or(RowSampling::WholeFrame))
    }
}

fn head() -> (Head<752, Lasers>, Lasers) {
    let l = Lasers::default();
    let h = Head::new(l.clone(), default_detector(), Identity { firmware: "test", board: "test" }).unwrap();
    (h, l)
}

fn cmd(seq: u16, msg: HostMsg) -> Command {
    Command { seq, msg }
}

fn start(mask: u8, pattern: LaserPattern) -> HostMsg {
    HostMsg::Start(Start { rate_hz: 10, laser_mask: mask, pattern })
}

#[test]
fn lasers_are_off_until_streaming_and_profiles_match_the_truth() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    assert_eq!(l.now(), 0, "off at construction");
    let mut out = Vec::new();
    let mut clock = 0u64;
    let mut ns = || {
        clock += 1000;
        clock
    };
    h.poll(0, &mut cam, &mut ns, &mut |m| out.push(m.clone()));
    assert_eq!(l.now(), 0);
    assert_eq!(cam.exposures, 0, "idle: no exposure");
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 10, &cam, &mut |m| out.push(m.clone()));
    assert!(out.contains(&DeviceMsg::Ack(1)));
    h.poll(20, &mut cam, &mut ns, &mut |m| out.push(m.clone()));
    assert_eq!(cam.lit, vec![0b111], "lit during the exposure");
    assert_eq!(l.now(), 0, "strobed: off again before the rows are read");
    let profiles: Vec<&Profile> =
        out.iter().filter_map(|m| if let DeviceMsg::Profile(p) = m { Some(p) } else { None }).collect();
    assert_eq!(profiles.len(), 1);
    let p = profiles[0];
    assert_eq!(p.laser_mask, 0b111);
    assert_eq!(p.lasers.len(), 3);
    let mut se = 0.0;
    let mut n = 0;
    for lp in &p.lasers {
        assert_eq!(lp.points.len(), 480, "laser {}: one point per row", lp.laser);
        for pt in &lp.points {
            let e = pt.position.to_f64() - Cam::truth(pt.row, lp.laser as usize);
            se += e * e;
            n += 1;
        }
    }
    let rms = (se / n as f64).sqrt();
    assert!(rms < 0.02, "RMS {rms}");
    out.clear();
    h.handle(cmd(2, HostMsg::Stop), 30, &cam, &mut |m| out.push(m.clone()));
    assert_eq!(l.now(), 0);
    assert_eq!(h.state(), HeadState::Idle);
    assert!(out.contains(&DeviceMsg::Ack(2)));
}

#[test]
fn heartbeat_loss_turns_the_lasers_off() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    let mut out = Vec::new();
    let mut ns = || 0u64;
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |m| out.push(m.clone()));
    let mut t = 0;
    // Heartbeats every 250 ms keep it streaming for 3 s.
    while t < 3_000_000 {
        h.poll(t, &mut cam, &mut ns, &mut |m| out.push(m.clone()));
        if t % 250_000 == 0 {
            h.handle(cmd(2, HostMsg::Heartbeat), t, &cam, &mut |m| out.push(m.clone()));
        }
        t += 50_000;
    }
    assert_eq!(h.state(), HeadState::Streaming);
    assert!(cam.lit.len() >= 29 && cam.lit.iter().all(|&m| m == 0b111), "{:?}", cam.lit);
    // Silence: at most 1 s + one poll later the lasers are off.
    let last_heard = t - 50_000;
    out.clear();
    while h.state() == HeadState::Streaming {
        h.poll(t, &mut cam, &mut ns, &mut |m| out.push(m.clone()));
        t += 10_000;
    }
    assert!(t - last_heard <= HEARTBEAT_TIMEOUT_US + 70_000, "{}", t - last_heard);
    assert_eq!(l.now(), 0);
    assert_eq!(h.state(), HeadState::Fault);
    assert!(out.contains(&DeviceMsg::Error { seq: None, code: ErrorCode::HeartbeatLost }));
    // Nothing relights them but a new Start.
    let before = cam.exposures;
    for _ in 0..30 {
        h.poll(t, &mut cam, &mut ns, &mut |_| {});
        t += 100_000;
    }
    assert_eq!(l.now(), 0);
    assert_eq!(cam.exposures, before);
}

#[test]
fn any_error_while_streaming_stops_with_lasers_off() {
    for bad in
        [HostMsg::SetDetector(default_detector()), HostMsg::SetExposure { exposure_us: 0 }, HostMsg::CaptureImage(1)]
    {
        let (mut h, l) = head();
        let mut cam = Cam::watching(&l);
        let mut ns = || 0u64;
        h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
        h.poll(0, &mut cam, &mut ns, &mut |_| {});
        assert_eq!(cam.lit, vec![0b111]);
        let mut out = Vec::new();
        h.handle(cmd(2, bad.clone()), 1, &cam, &mut |m| out.push(m.clone()));
        assert_eq!(l.now(), 0, "{bad:?}");
        assert_eq!(h.state(), HeadState::Fault);
        assert!(out.iter().any(|m| matches!(m, DeviceMsg::Error { seq: Some(2), .. })));
        // No further strobe after the fault.
        h.poll(200_000, &mut cam, &mut ns, &mut |_| {});
        assert_eq!(cam.lit, vec![0b111], "{bad:?}");
    }
    // A link error (bad CRC from the host) too.
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    h.handle(cmd(1, start(0b001, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    h.poll(0, &mut cam, &mut || 0, &mut |_| {});
    assert_eq!(cam.lit, vec![0b001]);
    h.link_error(ErrorCode::Crc, &mut |_| {});
    assert_eq!(l.now(), 0);
    assert_eq!(h.state(), HeadState::Fault);
}

#[test]
fn camera_fault_turns_the_lasers_off() {
    let (mut h, l) = head();
    let mut cam = Cam::new();
    let mut out = Vec::new();
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    cam.fail = true;
    h.poll(0, &mut cam, &mut || 0, &mut |m| out.push(m.clone()));
    assert_eq!(l.now(), 0);
    assert!(out.contains(&DeviceMsg::Error { seq: None, code: ErrorCode::SensorFault }));
}

#[test]
fn sequential_pattern_lights_one_laser_per_frame() {
    let (mut h, l) = head();
    let mut cam = Cam::new();
    let mut masks = Vec::new();
    h.handle(cmd(1, start(0b101, LaserPattern::Sequential)), 0, &cam, &mut |_| {});
    for i in 0..4u64 {
        h.handle(cmd(2, HostMsg::Heartbeat), i * 100_000, &cam, &mut |_| {});
        h.poll(i * 100_000, &mut cam, &mut || 0, &mut |m| {
            if let DeviceMsg::Profile(p) = m {
                masks.push(p.laser_mask);
                assert_eq!(p.lasers.len(), 1);
                assert_eq!(p.lasers[0].points.len(), 480);
            }
        });
    }
    assert_eq!(masks, vec![0b001, 0b100, 0b001, 0b100]);
    // Between frames of the sequential pattern, all off.
    assert_eq!(l.now(), 0);
    assert!(l.0.borrow().iter().all(|&m| m.count_ones() <= 1));
}

#[test]
fn invalid_commands_are_refused_and_lasers_stay_off() {
    let (mut h, l) = head();
    let cam = Cam::new();
    let mut out = Vec::new();
    let mut bad_cfg = default_detector();
    bad_cfg.bits = 3;
    h.handle(cmd(1, HostMsg::SetDetector(bad_cfg)), 0, &cam, &mut |m| out.push(m.clone()));
    h.handle(cmd(2, start(0, LaserPattern::Simultaneous)), 0, &cam, &mut |m| out.push(m.clone()));
    h.handle(
        cmd(3, HostMsg::Start(Start { rate_hz: 0, laser_mask: 1, pattern: LaserPattern::Simultaneous })),
        0,
        &cam,
        &mut |m| out.push(m.clone()),
    );
    assert_eq!(
        out,
        vec![
            DeviceMsg::Error { seq: Some(1), code: ErrorCode::InvalidConfig },
            DeviceMsg::Error { seq: Some(2), code: ErrorCode::OutOfRange },
            DeviceMsg::Error { seq: Some(3), code: ErrorCode::OutOfRange },
        ]
    );
    assert_eq!(l.now(), 0);
    assert_eq!(h.state(), HeadState::Idle);
}

#[test]
fn dropping_the_head_turns_the_lasers_off() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    h.poll(0, &mut cam, &mut || 0, &mut |_| {});
    assert_eq!(cam.lit, vec![0b111]);
    let switches = l.0.borrow().len();
    drop(h);
    assert_eq!(l.now(), 0);
    assert_eq!(l.0.borrow().len(), switches + 1, "the drop drives the enables low");
}

#[test]
fn capture_sends_the_whole_image_with_lasers_lit_only_for_it() {
    let (mut h, l) = head();
    let mut cam = Cam::new();
    let mut out = Vec::new();
    h.handle(cmd(4, HostMsg::CaptureImage(0b010)), 0, &cam, &mut |m| out.push(m.clone()));
    h.poll(0, &mut cam, &mut || 0, &mut |m| out.push(m.clone()));
    let bytes: usize =
        out.iter().filter_map(|m| if let DeviceMsg::RawRows(r) = m { Some(r.data.len()) } else { None }).sum();
    assert_eq!(bytes, 752 * 480 * 2);
    assert_eq!(l.now(), 0);
    assert!(l.0.borrow().contains(&0b010));
}

#[test]
fn a_detector_of_another_bit_depth_is_refused_at_start() {
    let l = Lasers::default();
    let mut cfg = default_detector();
    cfg.bits = 8;
    cfg.saturation = 255;
    let mut h: Head<752, Lasers> = Head::new(l.clone(), cfg, Identity { firmware: "t", board: "t" }).unwrap();
    let cam = Cam::new(); // 12-bit
    let mut out = Vec::new();
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |m| out.push(m.clone()));
    assert_eq!(out, vec![DeviceMsg::Error { seq: Some(1), code: ErrorCode::InvalidConfig }]);
    assert_eq!(l.now(), 0);
    assert_eq!(ErrorCode::from(WireError::Crc), ErrorCode::Crc);
    assert_eq!(ErrorCode::from(WireError::Version(3)), ErrorCode::Version(3));
    assert_eq!(ErrorCode::from(WireError::Overflow), ErrorCode::Decode);
}

/// A calibration of the reference head (planes leaning 42° from the optical
/// axis, lines 10 mm apart, rail top 200 mm below the camera).
fn calibration(id: u32) -> Calibration {
    let (c, s) = (0.743_144_8f32, 0.669_130_6f32);
    Calibration {
        id,
        intrinsics: [1400.0, 1400.0, 376.0, 240.0, 0.0],
        distortion: [-0.09, 0.12, 2e-4, -1.5e-4, 0.0],
        planes: [-10.0f32, 0.0, 10.0].map(|o| [c, 0.0, -s, c * o - s * 200.0]),
        datum: [0.0, 0.0, -1.0, -200.0],
    }
}

#[test]
fn a_calibrated_head_triangulates_every_point_and_refuses_bad_calibrations() {
    let (mut h, l) = head();
    let mut cam = Cam::new();
    let mut out = Vec::new();
    // Refused: the id 0, a plane through the camera, a datum above it.
    let mut through = calibration(5);
    through.planes[1][3] = 0.0;
    let mut above = calibration(6);
    above.datum = [0.0, 0.0, 1.0, 200.0];
    // Refused too: three identical planes, and two swapped
    // (stripes are numbered left to right), which the host refuses as well.
    let mut same = calibration(10);
    same.planes = [same.planes[0]; 3];
    let mut swapped = calibration(11);
    swapped.planes.swap(0, 2);
    for (seq, bad) in [(1, calibration(0)), (2, through), (3, above), (8, same), (9, swapped)] {
        h.handle(cmd(seq, HostMsg::SetCalibration(bad)), 0, &cam, &mut |m| out.push(m.clone()));
        assert!(out.contains(&DeviceMsg::Error { seq: Some(seq), code: ErrorCode::InvalidConfig }), "{out:?}");
        assert!(h.calibration().is_none());
    }
    h.handle(cmd(4, HostMsg::SetCalibration(calibration(7))), 0, &cam, &mut |m| out.push(m.clone()));
    assert!(out.contains(&DeviceMsg::Ack(4)));
    out.clear();
    h.handle(cmd(5, HostMsg::GetInfo), 0, &cam, &mut |m| out.push(m.clone()));
    assert!(matches!(&out[0], DeviceMsg::Hello(i) if i.calibration_id == 7), "{out:?}");

    out.clear();
    let mut clock = 0u64;
    let mut ns = || {
        clock += 1000;
        clock
    };
    h.handle(cmd(6, start(0b111, LaserPattern::Simultaneous)), 10, &cam, &mut |m| out.push(m.clone()));
    h.poll(20, &mut cam, &mut ns, &mut |m| out.push(m.clone()));
    // Not while streaming: the lasers go off, the calibration stays.
    h.handle(cmd(7, HostMsg::SetCalibration(calibration(8))), 30, &cam, &mut |m| out.push(m.clone()));
    assert!(out.contains(&DeviceMsg::Error { seq: Some(7), code: ErrorCode::Busy }));
    assert_eq!(l.now(), 0);
    assert_eq!(h.calibration().map(|c| c.id), Some(7));

    let tri = h.triangulator().unwrap();
    let p = out.iter().find_map(|m| if let DeviceMsg::Profile(p) = m { Some(p) } else { None }).unwrap();
    let mut n = 0;
    for lp in &p.lasers {
        for pt in &lp.points {
            let m = pt.metric.expect("every point triangulated");
            let want = tri.profile(lp.laser as usize, pt.position, pt.row).unwrap();
            assert!((f64::from(m.along_um) - f64::from(want.along_mm) * 1e3).abs() <= 0.51, "{m:?} {want:?}");
            assert!((f64::from(m.height_nm) - f64::from(want.height_mm) * 1e6).abs() <= 4.0, "{m:?} {want:?}");
            n += 1;
        }
    }
    assert_eq!(n, 3 * 480);
}

/// Messages of one call, collected.
fn collect(f: impl FnOnce(&mut dyn FnMut(&DeviceMsg))) -> Vec<DeviceMsg> {
    let mut out = Vec::new();
    f(&mut |m: &DeviceMsg| out.push(m.clone()));
    out
}

#[test]
fn exposure_times_rate_over_the_duty_limit_is_refused() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    // 30 ms at 10 Hz is 30 %: over the 25 % limit.
    h.handle(cmd(1, HostMsg::SetExposure { exposure_us: 30_000 }), 0, &cam, &mut |_| {});
    let out = collect(|r| h.handle(cmd(2, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |m| r(m)));
    assert_eq!(out, vec![DeviceMsg::Error { seq: Some(2), code: ErrorCode::OutOfRange }]);
    assert_eq!(h.state(), HeadState::Idle);
    // 25 ms at 10 Hz is exactly the limit: accepted, and strobed 25 % of the time.
    h.handle(cmd(3, HostMsg::SetExposure { exposure_us: 25_000 }), 0, &cam, &mut |_| {});
    h.handle(cmd(4, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    assert_eq!(h.state(), HeadState::Streaming);
    let mut status = None;
    for t in (0..=2_000_000u64).step_by(10_000) {
        if t % 500_000 == 0 {
            h.handle(cmd(5, HostMsg::Heartbeat), t, &cam, &mut |_| {});
        }
        h.poll(t, &mut cam, &mut || 0, &mut |m| {
            if let DeviceMsg::Status(s) = m {
                status = Some(*s);
            }
        });
    }
    assert_eq!(cam.lit.len(), 21);
    assert_eq!(status.unwrap().laser_duty_permille, 250);
    assert_eq!(status.unwrap().dropped_frames, 0);
    // Raising the exposure while streaming past the limit is a fault: lasers off.
    let out =
        collect(|r| h.handle(cmd(6, HostMsg::SetExposure { exposure_us: 26_000 }), 2_000_000, &cam, &mut |m| r(m)));
    assert!(out.contains(&DeviceMsg::Error { seq: Some(6), code: ErrorCode::OutOfRange }));
    assert_eq!(h.state(), HeadState::Fault);
    assert_eq!(l.now(), 0);
}

proptest! {
    /// Whatever is asked, the strobes the limiter allows add up to at most
    /// duty · T + burst over every interval T (checked on all intervals
    /// between strobe starts, where the bound is tightest).
    #[test]
    fn the_duty_limit_holds_over_every_interval(
        requests in proptest::collection::vec((0u64..200_000, 1u32..60_000), 1..200),
    ) {
        let mut d = DutyLimit::default();
        let mut t = 0u64;
        let mut allowed: Vec<(u64, u64)> = Vec::new();
        for (gap, on) in requests {
            // A strobe cannot start before the previous one ended.
            t += gap + allowed.last().map_or(0, |&(s, o)| (s + o).saturating_sub(t));
            if d.request(t, on) {
                allowed.push((t, on as u64));
            }
        }
        for i in 0..allowed.len() {
            let mut on = 0;
            for j in i..allowed.len() {
                on += allowed[j].1;
                // Interval from the start of strobe i to the end of strobe j.
                let span = allowed[j].0 + allowed[j].1 - allowed[i].0;
                prop_assert!(
                    on * 1000 <= span * MAX_DUTY_PERMILLE as u64 + DUTY_BURST_US as u64 * 1000,
                    "{} us on in {} us", on, span
                );
            }
        }
    }
}

#[test]
fn heartbeat_loss_stops_the_strobes_within_one_second_in_every_mode() {
    for (pattern, mask) in [(LaserPattern::Simultaneous, 0b111), (LaserPattern::Sequential, 0b011)] {
        let (mut h, l) = head();
        let mut cam = Cam::watching(&l);
        cam.odo.set(Some(0));
        h.handle(cmd(1, HostMsg::SetTrigger(Trigger::Distance { every_um: 1000 })), 0, &cam, &mut |_| {});
        h.handle(cmd(2, start(mask, pattern)), 0, &cam, &mut |_| {});
        // The trolley moves 1 mm per 10 ms poll; the host falls silent at 0.
        let mut last_strobe = 0;
        let mut t = 0;
        while t < 3_000_000 {
            let before = cam.lit.len();
            h.poll(t, &mut cam, &mut || 0, &mut |_| {});
            if cam.lit.len() > before {
                last_strobe = t;
            }
            cam.odo.set(Some(t as i64 / 10));
            t += 10_000;
        }
        assert!(last_strobe > 0 && last_strobe <= HEARTBEAT_TIMEOUT_US, "{pattern:?}: strobe at {last_strobe} us");
        assert_eq!(l.now(), 0);
        assert_eq!(h.state(), HeadState::Fault);
    }
}

#[test]
fn the_distance_trigger_takes_a_frame_every_interval_and_counts_the_ones_it_cannot() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    // Without an encoder a distance trigger cannot start.
    h.handle(cmd(1, HostMsg::SetTrigger(Trigger::Distance { every_um: 5_000 })), 0, &cam, &mut |_| {});
    let out = collect(|r| h.handle(cmd(2, start(0b001, LaserPattern::Simultaneous)), 0, &cam, &mut |m| r(m)));
    assert_eq!(out, vec![DeviceMsg::Error { seq: Some(2), code: ErrorCode::OutOfRange }]);
    let out =
        collect(|r| h.handle(cmd(3, HostMsg::SetTrigger(Trigger::Distance { every_um: 0 })), 0, &cam, &mut |m| r(m)));
    assert_eq!(out, vec![DeviceMsg::Error { seq: Some(3), code: ErrorCode::OutOfRange }]);
    // With one: a frame at each 5 mm, carrying the odometer.
    cam.odo.set(Some(-2_000));
    h.handle(
        cmd(4, HostMsg::Start(Start { rate_hz: 50, laser_mask: 1, pattern: LaserPattern::Simultaneous })),
        0,
        &cam,
        &mut |_| {},
    );
    let mut odo = Vec::new();
    // 0.2 m/s for 0.3 s (polled every ms; 40 frames/s), then 10 m/s for
    // 0.2 s: 50 frames/s cannot keep up with one per 5 mm (2000/s), so
    // those are dropped.
    let mut p = -2_000i64;
    for ms in 0..500u64 {
        p += if ms < 300 { 200 } else { 10_000 };
        cam.odo.set(Some(p));
        if ms % 200 == 0 {
            h.handle(cmd(5, HostMsg::Heartbeat), ms * 1000, &cam, &mut |_| {});
        }
        h.poll(ms * 1000, &mut cam, &mut || 0, &mut |m| {
            if let DeviceMsg::Profile(pr) = m {
                odo.push(pr.odometer_um);
            }
        });
    }
    // The slow part: every 5 mm exactly, 12 frames in 60 mm.
    let slow: Vec<i64> = odo.iter().copied().filter(|&o| o <= 58_000).collect();
    assert_eq!(slow.len(), 12, "{slow:?}");
    assert_eq!(slow[0], 3_000);
    assert!(slow.windows(2).all(|w| w[1] - w[0] == 5_000), "{slow:?}");
    // The fast part: at most 50 frames/s, the rest counted as dropped.
    let fast = odo.len() - slow.len();
    assert!(fast <= 11, "{fast}");
    let status = h.status(500_000);
    let boundaries = (p + 2_000) / 5_000;
    assert_eq!(odo.len() as i64 + status.dropped_frames as i64, boundaries, "every boundary is a frame or a drop");
}

#[test]
fn settings_changes_ask_to_be_stored_and_restore_reports_what_it_refused() {
    let (mut h, _l) = head();
    let cam = Cam::new();
    assert_eq!(h.take_store_request(), None, "nothing changed");
    assert_eq!(h.info(&cam).store, StoreHealth::Volatile);
    h.handle(cmd(1, HostMsg::SetCalibration(calibration(7))), 0, &cam, &mut |_| {});
    h.handle(cmd(2, HostMsg::SetExposure { exposure_us: 300 }), 0, &cam, &mut |_| {});
    let s = h.take_store_request().expect("changed");
    assert_eq!(s.calibration, Some(calibration(7)));
    assert_eq!(s.exposure_us, 300);
    assert_eq!(h.take_store_request(), None, "asked once");
    // Not while streaming (a flash erase stalls the bus for a second).
    h.handle(cmd(3, start(0b001, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    h.handle(cmd(4, HostMsg::SetExposure { exposure_us: 200 }), 0, &cam, &mut |_| {});
    assert_eq!(h.take_store_request(), None);
    h.handle(cmd(5, HostMsg::Stop), 0, &cam, &mut |_| {});
    assert_eq!(h.take_store_request().map(|s| s.exposure_us), Some(200));

    // A fresh head restores it.
    let (mut h2, _) = head();
    h2.restore(&s, StoreHealth::Ok);
    assert_eq!(h2.stored(), s);
    assert_eq!(h2.info(&cam).calibration_id, 7);
    assert_eq!(h2.info(&cam).store, StoreHealth::Ok);
    assert_eq!(h2.take_store_request(), None, "restoring is not a change");
    // A stored calibration the head refuses is reported and not used.
    let (mut h3, _) = head();
    let bad = Stored { calibration: Some(calibration(0)), ..s };
    h3.restore(&bad, StoreHealth::Ok);
    assert_eq!(h3.calibration(), None);
    assert_eq!(h3.info(&cam).store, StoreHealth::Refused);
    assert_eq!(h3.stored().exposure_us, 300, "the rest is used");
}

#[test]
fn status_carries_cycles_dropped_rows_backlog_and_duty() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    h.set_cpu_hz(480_000_000);
    h.set_link_backlog(12_345);
    cam.lost_rows = 17;
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    let mut clock = 0u64;
    // 50 µs of processing per row, 480 rows per frame.
    let mut ns = || {
        clock += 480 * 50_000;
        clock
    };
    let mut statuses = Vec::new();
    for t in (0..=1_000_000u64).step_by(100_000) {
        h.poll(t, &mut cam, &mut ns, &mut |m| {
            if let DeviceMsg::Status(s) = m {
                statuses.push(*s);
            }
        });
    }
    let s = statuses.last().expect("a status after 1 s");
    assert_eq!(s.ns_per_row, 50_000);
    assert_eq!(s.cycles_per_row, 24_000, "50 us at 480 MHz");
    assert_eq!(s.dropped_rows, 17);
    assert_eq!(s.link_backlog_bytes, 12_345);
    assert_eq!(s.lasers_on, 0b111);
    // 10 exposures of 200 µs in 1 s: 2 per mille.
    assert_eq!(s.laser_duty_permille, 2);
}

/// The link budget's input: the encoded size of one full 752 × 480 frame of
/// three stripes, uncalibrated and calibrated (`--nocapture` prints it; the
/// link budget in docs/firmware.md quotes it).
#[test]
fn encoded_frame_sizes_for_the_link_budget() {
    let mut sizes = Vec::new();
    for calibrated in [false, true] {
        let (mut h, _l) = head();
        let mut cam = Cam::new();
        if calibrated {
            h.handle(cmd(1, HostMsg::SetCalibration(calibration(9))), 0, &cam, &mut |_| {});
        }
        h.handle(cmd(2, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
        let (mut bytes, mut points) = (0usize, 0usize);
        let mut out = vec![0u8; MAX_FRAME];
        h.poll(0, &mut cam, &mut || 0, &mut |m| {
            if let DeviceMsg::Profile(p) = m {
                bytes += encode(m, &mut out).unwrap().len();
                points += p.lasers.iter().map(|l| l.points.len()).sum::<usize>();
            }
        });
        assert_eq!(points, 3 * 480);
        println!("calibrated {calibrated}: {bytes} bytes per frame, {:.1} per point", bytes as f64 / points as f64);
        sizes.push(bytes);
    }
    // Protocol 4: at least position, strength and width (3 bytes) a point,
    // at most 6 with the metric point (the link's budget: 60 frames/s of
    // 1 440 points within 60 % of USB full speed's 1 MB/s); calibration
    // adds the two metric varints, a byte each at least.
    assert!(sizes[0] >= 1440 * 3 && sizes[1] <= 1440 * 6, "{sizes:?}");
    assert!(sizes[1] >= sizes[0] + 1440 * 2, "{sizes:?}");
}

/// A camera like the board's (firmware/src/camera.rs): after an exposure
/// the rows arrive one every `ROW_US` into a ring of `RING` rows whether
/// anyone reads them or not, and a row read after the ring has come round
/// over it is lost (zeros, counted). `start_band` copies a band of up to
/// `band_rows` rows out of the ring as they arrive, and `read_row` then
/// serves them at the reader's pace. Time is the shared `clock` (µs), which
/// the link advances by 1 µs per byte (USB full speed, ~1 MB/s).
struct RingCam {
    clock: Rc<Cell<u64>>,
    exposed_at: u64,
    next: u16,
    band_rows: u16,
    band: Vec<Vec<u16>>,
    band_next: Option<usize>,
    lost: u32,
    exposures: u32,
    lasers: Lasers,
    lit: Vec<u8>,
}

impl RingCam {
    const RING: u64 = 8;
    const ROW_US: u64 = 31;

    fn new(band_rows: u16, clock: &Rc<Cell<u64>>, lasers: &Lasers) -> RingCam {
        RingCam {
            clock: clock.clone(),
            exposed_at: 0,
            next: 0,
            band_rows,
            band: Vec::new(),
            band_next: None,
            lost: 0,
            exposures: 0,
            lasers: lasers.clone(),
            lit: Vec::new(),
        }
    }

    /// The scene: a static pattern (the head is not moving while it captures).
    fn pixel(r: u16, c: usize) -> u16 {
        ((u32::from(r) * 37 + c as u32 * 11 + (u32::from(r) * c as u32) % 97) % 4096) as u16
    }

    fn ring_row(&mut self, out: &mut [u16]) {
        let r = self.next;
        let arrival = self.exposed_at + (u64::from(r) + 1) * Self::ROW_US;
        let now = self.clock.get().max(arrival); // wait for it if it is not there yet
        self.clock.set(now);
        if now > arrival + Self::RING * Self::ROW_US {
            self.lost += 1;
            out.fill(0);
        } else {
            for (c, p) in out.iter_mut().enumerate() {
                *p = Self::pixel(r, c);
            }
        }
        self.next += 1;
    }
}

impl Camera for RingCam {
    type Error = ();
    fn width(&self) -> u16 {
        752
    }
    fn height(&self) -> u16 {
        480
    }
    fn bits(&self) -> u8 {
        12
    }
    fn expose(&mut self, exposure_us: u32, _laser_mask: u8) -> Result<i64, ()> {
        self.lit.push(self.lasers.now());
        self.exposures += 1;
        self.clock.set(self.clock.get() + u64::from(exposure_us));
        self.exposed_at = self.clock.get();
        self.next = 0;
        self.band_next = None;
        Ok(0)
    }
    fn read_row(&mut self, out: &mut [u16]) -> Result<(), ()> {
        match self.band_next {
            Some(i) => {
                out.copy_from_slice(self.band.get(i).ok_or(())?);
                self.band_next = Some(i + 1);
            }
            None => self.ring_row(out),
        }
        Ok(())
    }
    fn dropped_rows(&self) -> u32 {
        self.lost
    }
    fn capture_band_rows(&self) -> u16 {
        self.band_rows
    }
    fn start_band(&mut self, first: u16, rows: u16, scratch: &mut [u16]) -> Result<(), ()> {
        if self.band_rows >= self.height() {
            // No band buffer: the rows are read straight from the ring.
            for _ in 0..first {
                self.ring_row(scratch);
            }
            return Ok(());
        }
        for _ in 0..first {
            self.ring_row(scratch);
        }
        self.band.clear();
        for _ in 0..rows {
            self.ring_row(scratch);
            self.band.push(scratch.to_vec());
        }
        self.band_next = Some(0);
        Ok(())
    }
}

/// Captures with a `RingCam` of `band_rows` over the slow link, the link
/// buffer draining every other poll: the assembled image, the camera, and
/// the messages.
fn ring_capture(band_rows: u16) -> (Vec<Option<u16>>, RingCam, Vec<DeviceMsg>) {
    let (mut h, l) = head();
    let clock = Rc::new(Cell::new(0u64));
    let mut cam = RingCam::new(band_rows, &clock, &l);
    let mut out = Vec::new();
    h.handle(cmd(7, HostMsg::CaptureImage(0b101)), 0, &cam, &mut |m| out.push(m.clone()));
    let mut image = vec![None; 752 * 480];
    for poll in 0..200 {
        let mut sent = 0u64;
        h.poll(clock.get(), &mut cam, &mut || 0, &mut |m| {
            if let DeviceMsg::RawRows(r) = m {
                // 1 µs per byte on the wire (data and framing).
                sent += r.data.len() as u64 + 16;
                clock.set(clock.get() + r.data.len() as u64 + 16);
                for (k, px) in r.data.chunks_exact(2).enumerate() {
                    let i = usize::from(r.first_row) * 752 + r.offset_bytes as usize / 2 + k;
                    image[i] = Some(u16::from_le_bytes([px[0], px[1]]));
                }
            }
            out.push(m.clone());
        });
        // Every other poll the link buffer still holds what went out.
        h.set_link_backlog(if poll % 2 == 0 { sent as u32 } else { 0 });
        if image.iter().all(Option::is_some) {
            break;
        }
    }
    (image, cam, out)
}

/// A full-frame capture on a head whose camera holds 8 rows: band by
/// band, one exposure each, every band sent before the next exposure, the
/// lasers lit for the exposures only — and the image is exactly the scene.
/// The same camera read straight from its ring while the slow link sends
/// (the way a capture worked before bands) loses most rows.
#[test]
fn capture_in_bands_survives_a_small_ring_and_a_slow_link() {
    let (image, cam, out) = ring_capture(32);
    assert!(!out.iter().any(|m| matches!(m, DeviceMsg::Error { .. })), "{:?}", &out[..3]);
    assert_eq!(cam.lost, 0);
    assert_eq!(cam.exposures, 480 / 32);
    assert_eq!(cam.lit, vec![0b101; 15], "each band's exposure with the capture's lasers");
    assert_eq!(cam.lasers.now(), 0);
    let lit_switches = cam.lasers.0.borrow().iter().filter(|&&m| m != 0).count();
    assert_eq!(lit_switches, 15, "lit once per band, off in between");
    for r in 0..480u16 {
        for c in 0..752 {
            assert_eq!(image[usize::from(r) * 752 + c], Some(RingCam::pixel(r, c)), "row {r} col {c}");
        }
    }
    // Straight from the ring: rows lost (zeros in the image), counted.
    let (image, cam, ..) = ring_capture(480);
    assert_eq!(cam.exposures, 1);
    assert!(cam.lost > 400, "{} rows lost", cam.lost);
    assert!(image.iter().flatten().filter(|&&p| p == 0).count() > 400 * 700);
}

/// While a band (the first one too) waits for the link, nothing is
/// exposed; `Stop` cancels the capture; a second capture while one is under
/// way is refused (Busy).
#[test]
fn a_banded_capture_waits_for_the_link_and_stop_cancels_it() {
    let (mut h, l) = head();
    let clock = Rc::new(Cell::new(0u64));
    let mut cam = RingCam::new(32, &clock, &l);
    let mut out = Vec::new();
    // What streaming left in the link buffer goes out before the first band.
    h.set_link_backlog(90_000);
    h.handle(cmd(1, HostMsg::CaptureImage(0b010)), 0, &cam, &mut |m| out.push(m.clone()));
    h.poll(0, &mut cam, &mut || 0, &mut |_| {});
    assert_eq!(cam.exposures, 0, "no first band into a part-full link buffer");
    assert_eq!(l.now(), 0);
    h.set_link_backlog(0);
    h.poll(500, &mut cam, &mut || 0, &mut |_| {});
    assert_eq!(cam.exposures, 1);
    h.set_link_backlog(20_000);
    for t in 1..50 {
        h.poll(t * 1000, &mut cam, &mut || 0, &mut |_| {});
    }
    assert_eq!(cam.exposures, 1, "no exposure while the link holds the last band");
    out.clear();
    h.handle(cmd(2, HostMsg::CaptureImage(0b010)), 0, &cam, &mut |m| out.push(m.clone()));
    assert_eq!(out, vec![DeviceMsg::Error { seq: Some(2), code: ErrorCode::Busy }]);
    h.set_link_backlog(0);
    h.poll(60_000, &mut cam, &mut || 0, &mut |_| {});
    assert_eq!(cam.exposures, 2);
    h.handle(cmd(3, HostMsg::Stop), 61_000, &cam, &mut |_| {});
    for t in 0..20 {
        h.poll(70_000 + t * 1000, &mut cam, &mut || 0, &mut |_| {});
    }
    assert_eq!(cam.exposures, 2, "Stop cancelled the capture");
    assert_eq!(l.now(), 0);
}

/// A camera wider than the head's row buffer: a capture is refused as a
/// sensor fault (as `Start` is), not a panic, and the lasers stay off.
#[test]
fn a_capture_from_a_camera_wider_than_the_head_is_refused() {
    let l = Lasers::default();
    let mut h: Head<640, Lasers> =
        Head::new(l.clone(), default_detector(), Identity { firmware: "t", board: "t" }).unwrap();
    let mut cam = Cam::new(); // 752 px
    let mut out = Vec::new();
    h.handle(cmd(5, HostMsg::CaptureImage(0b001)), 0, &cam, &mut |m| out.push(m.clone()));
    h.poll(0, &mut cam, &mut || 0, &mut |m| out.push(m.clone()));
    assert_eq!(out, vec![DeviceMsg::Error { seq: Some(5), code: ErrorCode::SensorFault }]);
    assert_eq!(cam.exposures, 0);
    assert_eq!(l.now(), 0);
}

/// A dark camera that records when it exposed, for how long and with which
/// lasers lit (fast: the model test polls thousands of frames).
struct Strobes {
    now_us: Rc<Cell<u64>>,
    lasers: Lasers,
    exposures: Rc<RefCell<Vec<(u64, u32, u8)>>>,
}
impl Camera for Strobes {
    type Error = ();
    fn width(&self) -> u16 {
        752
    }
    fn height(&self) -> u16 {
        8
    }
    fn bits(&self) -> u8 {
        12
    }
    fn expose(&mut self, exposure_us: u32, _laser_mask: u8) -> Result<i64, ()> {
        self.exposures.borrow_mut().push((self.now_us.get(), exposure_us, self.lasers.now()));
        Ok(0)
    }
    fn read_row(&mut self, out: &mut [u16]) -> Result<(), ()> {
        out.fill(100);
        Ok(())
    }
}

/// What the host may do next in the model test.
#[derive(Clone, Debug)]
enum Step {
    Poll,
    Heartbeat,
    Start { mask: u8, sequential: bool, rate_hz: u16 },
    Stop,
    SetExposure(u32),
    GetInfo,
    Capture(u8),
}

fn step() -> impl Strategy<Value = Step> {
    prop_oneof![
        6 => Just(Step::Poll),
        3 => Just(Step::Heartbeat),
        2 => (0u8..8, any::<bool>(), 0u16..1200)
            .prop_map(|(mask, sequential, rate_hz)| Step::Start { mask, sequential, rate_hz }),
        1 => Just(Step::Stop),
        1 => (0u32..2_000_000).prop_map(Step::SetExposure),
        1 => Just(Step::GetInfo),
        1 => (0u8..8).prop_map(Step::Capture),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]
    /// `Head::handle` and `Head::poll` over arbitrary sequences of commands
    /// and times, against the laser rules as a model states them:
    /// * after every call the lasers are off (they are lit only around an
    ///   exposure, inside the call);
    /// * an exposure with lasers lit happens only while streaming — after a
    ///   `Start` the head acknowledged and before any `Stop` or error since —
    ///   or for a capture the head took, with that capture's lasers, and
    ///   never more than 1 s (the heartbeat timeout) after the last command
    ///   the head heard;
    /// * lit exposures add up to at most duty · T + burst over every interval.
    #[test]
    fn the_laser_rules_hold_whatever_the_host_does(
        steps in proptest::collection::vec((0u64..400_000, step()), 1..120),
    ) {
        let (mut h, l) = head();
        let now = Rc::new(Cell::new(0u64));
        let exposures = Rc::new(RefCell::new(Vec::new()));
        let mut cam = Strobes { now_us: now.clone(), lasers: l.clone(), exposures: exposures.clone() };
        let mut t = 0u64;
        let mut seq = 0u16;
        let mut last_heard = 0u64;
        // Streaming as the model sees it: since when, if at all.
        let mut streaming_since: Option<u64> = None;
        // The lasers of the last capture the head took (it lights them for
        // that capture's exposures only, streaming or not).
        let mut capture_mask = 0u8;
        for (gap, s) in steps {
            t += gap;
            now.set(t);
            let before = exposures.borrow().len();
            let mut out = Vec::new();
            let msg = match s {
                Step::Poll => None,
                Step::Heartbeat => Some(HostMsg::Heartbeat),
                Step::Start { mask, sequential, rate_hz } => Some(HostMsg::Start(Start {
                    rate_hz,
                    laser_mask: mask,
                    pattern: if sequential { LaserPattern::Sequential } else { LaserPattern::Simultaneous },
                })),
                Step::Stop => Some(HostMsg::Stop),
                Step::SetExposure(us) => Some(HostMsg::SetExposure { exposure_us: us }),
                Step::GetInfo => Some(HostMsg::GetInfo),
                Step::Capture(mask) => Some(HostMsg::CaptureImage(mask)),
            };
            match msg {
                Some(m) => {
                    seq = seq.wrapping_add(1).max(1);
                    let is_start = matches!(m, HostMsg::Start(_));
                    let is_stop = matches!(m, HostMsg::Stop);
                    let capture = if let HostMsg::CaptureImage(mask) = m { Some(mask) } else { None };
                    h.handle(cmd(seq, m), t, &cam, &mut |r| out.push(r.clone()));
                    last_heard = t;
                    if is_stop {
                        streaming_since = None;
                    }
                    if is_start && out.contains(&DeviceMsg::Ack(seq)) {
                        streaming_since = Some(t);
                    }
                    if let Some(mask) = capture
                        && !out.iter().any(|r| matches!(r, DeviceMsg::Error { seq: Some(q), .. } if *q == seq))
                    {
                        capture_mask = mask;
                    }
                }
                None => h.poll(t, &mut cam, &mut || 0, &mut |r| out.push(r.clone())),
            }
            if out.iter().any(|r| matches!(r, DeviceMsg::Error { .. })) {
                // Any error while streaming stops it (a refused command
                // while idle changes nothing either way).
                if h.state() != HeadState::Streaming {
                    streaming_since = None;
                }
            }
            prop_assert_eq!(l.now(), 0, "lasers left on after {:?} at {} us", out, t);
            for &(at, _, mask) in &exposures.borrow()[before..] {
                if mask != 0 {
                    prop_assert!(
                        streaming_since.is_some() || mask & !capture_mask == 0,
                        "lit exposure ({:#05b}) at {} us while neither streaming nor capturing", mask, at
                    );
                    prop_assert!(
                        at - last_heard <= HEARTBEAT_TIMEOUT_US,
                        "lit exposure at {} us, {} us after the last command", at, at - last_heard
                    );
                }
            }
        }
        let lit: Vec<(u64, u64)> =
            exposures.borrow().iter().filter(|e| e.2 != 0).map(|&(at, us, _)| (at, us as u64)).collect();
        for i in 0..lit.len() {
            let mut on = 0;
            for j in i..lit.len() {
                on += lit[j].1;
                let span = (lit[j].0 + lit[j].1).saturating_sub(lit[i].0);
                prop_assert!(
                    on * 1000 <= span * MAX_DUTY_PERMILLE as u64 + DUTY_BURST_US as u64 * 1000,
                    "{} us lit in {} us", on, span
                );
            }
        }
    }
}

/// `SetWindows`: with windows for lasers 0 and 1 only around their lines and
/// laser 2's window put where its line is not, a streaming head reports
/// lasers 0 and 1 as without windows and nothing for laser 2; a window past
/// the row or too narrow is refused (lasers off), as is the command while
/// streaming; a lit laser without a window makes the frame a full-row search.
#[test]
fn search_windows_set_by_the_host_restrict_what_the_head_reports() {
    let w = |first_px, width_px| Some(ColumnWindow { first_px, width_px });
    let run = |windows: Option<[Option<ColumnWindow>; 3]>| {
        let (mut h, l) = head();
        let mut cam = Cam::watching(&l);
        let mut out = Vec::new();
        if let Some(ws) = windows {
            h.handle(cmd(1, HostMsg::SetWindows(ws)), 0, &cam, &mut |m| out.push(m.clone()));
            assert!(out.contains(&DeviceMsg::Ack(1)), "{out:?}");
        }
        h.handle(cmd(2, start(0b111, LaserPattern::Simultaneous)), 10, &cam, &mut |m| out.push(m.clone()));
        let mut refused = Vec::new();
        h.handle(cmd(3, HostMsg::SetWindows([None; 3])), 15, &cam, &mut |m| refused.push(m.clone()));
        assert!(refused.contains(&DeviceMsg::Error { seq: Some(3), code: ErrorCode::Busy }), "{refused:?}");
        out.clear();
        h.handle(cmd(4, start(0b111, LaserPattern::Simultaneous)), 16, &cam, &mut |m| out.push(m.clone()));
        h.poll(20, &mut cam, &mut || 0, &mut |m| out.push(m.clone()));
        let p = out.iter().find_map(|m| if let DeviceMsg::Profile(p) = m { Some(p.clone()) } else { None }).unwrap();
        p.lasers.iter().map(|lp| lp.points.len()).collect::<Vec<_>>()
    };
    // Lines at 200, 380, 560 (±2 px).
    assert_eq!(run(None), vec![480, 480, 480]);
    assert_eq!(run(Some([w(152, 96), w(332, 96), w(640, 96)])), vec![480, 480, 0]);
    assert_eq!(run(Some([w(152, 96), w(332, 96), None])), vec![480, 480, 480], "laser 2 without a window: full rows");
    let (mut h, l) = head();
    let cam = Cam::watching(&l);
    for (seq, bad) in [(5, [w(700, 96), None, None]), (6, [w(100, 4), None, None])] {
        let mut out = Vec::new();
        h.handle(cmd(seq, HostMsg::SetWindows(bad)), 0, &cam, &mut |m| out.push(m.clone()));
        assert!(out.contains(&DeviceMsg::Error { seq: Some(seq), code: ErrorCode::OutOfRange }), "{out:?}");
        assert_eq!(l.now(), 0);
    }
}

/// `SetTracking`: a head whose windows follow their lines reports, frame
/// after frame, exactly what it reports without (the lines stand still
/// within a frame, so each row's candidate is the pixel the screen would
/// have led to); 0 turns it off; a half width the detector does not take
/// is refused (lasers off), as is the command while streaming.
#[test]
fn tracked_windows_set_by_the_host_report_what_the_windows_report() {
    let w = |first_px, width_px| Some(ColumnWindow { first_px, width_px });
    let frames = |track: Option<u16>| {
        let (mut h, l) = head();
        let mut cam = Cam::watching(&l);
        let mut out = Vec::new();
        h.handle(cmd(1, HostMsg::SetWindows([w(152, 96), w(332, 96), w(512, 96)])), 0, &cam, &mut |m| {
            out.push(m.clone())
        });
        if let Some(px) = track {
            h.handle(cmd(2, HostMsg::SetTracking { half_width_px: px }), 0, &cam, &mut |m| out.push(m.clone()));
            assert!(out.contains(&DeviceMsg::Ack(2)), "{out:?}");
        }
        h.handle(cmd(3, start(0b111, LaserPattern::Simultaneous)), 10, &cam, &mut |m| out.push(m.clone()));
        let mut refused = Vec::new();
        h.handle(cmd(4, HostMsg::SetTracking { half_width_px: 8 }), 15, &cam, &mut |m| refused.push(m.clone()));
        assert!(refused.contains(&DeviceMsg::Error { seq: Some(4), code: ErrorCode::Busy }), "{refused:?}");
        out.clear();
        h.handle(cmd(5, start(0b111, LaserPattern::Simultaneous)), 16, &cam, &mut |m| out.push(m.clone()));
        // Three frames at 10 Hz.
        for t in [20, 100_020, 200_020] {
            h.poll(t, &mut cam, &mut || 0, &mut |m| out.push(m.clone()));
        }
        let profiles: Vec<Profile> =
            out.iter().filter_map(|m| if let DeviceMsg::Profile(p) = m { Some(p.clone()) } else { None }).collect();
        assert!(profiles.len() >= 2, "{} profiles", profiles.len());
        profiles.iter().map(|p| p.lasers.clone()).collect::<Vec<_>>()
    };
    let plain = frames(None);
    assert!(plain[0].iter().all(|lp| lp.points.len() == 480), "every row of every line");
    assert_eq!(frames(Some(8)), plain, "tracked ±8 px");
    assert_eq!(frames(Some(64)), plain, "tracked ±64 px");
    assert_eq!(frames(Some(0)), plain, "off");
    let (mut h, l) = head();
    let cam = Cam::watching(&l);
    for (seq, bad) in [(5, 1), (6, 65), (7, u16::MAX)] {
        let mut out = Vec::new();
        h.handle(cmd(seq, HostMsg::SetTracking { half_width_px: bad }), 0, &cam, &mut |m| out.push(m.clone()));
        assert!(out.contains(&DeviceMsg::Error { seq: Some(seq), code: ErrorCode::OutOfRange }), "{bad}: {out:?}");
        assert_eq!(l.now(), 0);
    }
}

/// One frame's profile from a calibrated head after `SetReadout` (`None`:
/// none sent) on a camera honouring it as `sampling`, and the rows the
/// camera read for it.
fn readout_frame(readout: Option<(u16, u16, u8)>, sampling: Option<RowSampling>) -> (Profile, u32, Vec<Readout>) {
    let (mut h, l) = head();
    let mut cam = Cam { sampling, ..Cam::watching(&l) };
    let mut out = Vec::new();
    h.handle(cmd(1, HostMsg::SetCalibration(calibration(3))), 0, &cam, &mut |m| out.push(m.clone()));
    if let Some((first_row, rows, skip)) = readout {
        h.handle(cmd(2, HostMsg::SetReadout { first_row, rows, skip }), 0, &cam, &mut |m| out.push(m.clone()));
        assert!(out.contains(&DeviceMsg::Ack(2)), "{out:?}");
    }
    h.handle(cmd(3, start(0b111, LaserPattern::Simultaneous)), 10, &cam, &mut |m| out.push(m.clone()));
    h.poll(20, &mut cam, &mut || 0, &mut |m| out.push(m.clone()));
    let p = out.iter().find_map(|m| if let DeviceMsg::Profile(p) = m { Some(p.clone()) } else { None }).unwrap();
    (p, cam.rows_read, cam.readouts)
}

/// Each laser's metric point by sensor row.
fn metric_by_row(p: &Profile) -> Vec<std::collections::BTreeMap<u16, Metric>> {
    p.lasers.iter().map(|lp| lp.points.iter().map(|q| (q.row, q.metric.expect("calibrated"))).collect()).collect()
}

/// `SetReadout`: a window read one row in two gives half the window's
/// rows, numbered by their sensor rows, whether the camera reads whole
/// frames (the head passes over the others) or only those rows; their
/// metric points are the full readout's at the same rows within the
/// noise; a binning camera's are the mean of its two rows'.
#[test]
fn a_row_readout_numbers_points_by_sensor_row_and_keeps_their_metric_positions() {
    let (full, full_rows, _) = readout_frame(None, None);
    assert_eq!(full_rows, 480);
    let full = metric_by_row(&full);
    assert!(full.iter().all(|l| l.len() == 480));
    let want_rows: Vec<u16> = (40..440).step_by(2).collect();
    let close = |a: &Metric, b: &Metric, what: &str| {
        // Along the rail: the row decides (0.14 mm a row), the stripe's
        // noise moves it by well under a µm; height: σ of a few hundredths
        // of a pixel is a few µm.
        assert!((a.along_um - b.along_um).abs() <= 2, "{what}: {a:?} vs {b:?}");
        assert!((a.height_nm - b.height_nm).abs() <= 25_000, "{what}: {a:?} vs {b:?}");
    };
    for sampling in [None, Some(RowSampling::Skip)] {
        let (p, rows_read, set) = readout_frame(Some((40, 400, 2)), sampling);
        let want = Readout::new(40, 400, RowSkip::X2, 480).unwrap();
        assert_eq!(set, vec![want], "set once, before the exposure");
        assert_eq!(rows_read, if sampling.is_none() { 439 } else { 200 }, "{sampling:?}");
        for (k, l) in metric_by_row(&p).iter().enumerate() {
            assert_eq!(l.keys().copied().collect::<Vec<_>>(), want_rows, "laser {k}, {sampling:?}");
            for (r, m) in l {
                close(m, &full[k][r], &format!("laser {k} row {r} {sampling:?}"));
            }
        }
    }
    // Binned: rows 40 + 2i again, each point where the mean of rows r and
    // r + 1 is.
    let (p, rows_read, _) = readout_frame(Some((40, 400, 2)), Some(RowSampling::Bin));
    assert_eq!(rows_read, 200);
    for (k, l) in metric_by_row(&p).iter().enumerate() {
        assert_eq!(l.keys().copied().collect::<Vec<_>>(), want_rows, "laser {k} binned");
        for (r, m) in l {
            let (a, b) = (&full[k][r], &full[k][&(r + 1)]);
            let mid = Metric { along_um: (a.along_um + b.along_um) / 2, height_nm: (a.height_nm + b.height_nm) / 2 };
            close(m, &mid, &format!("laser {k} row {r} binned"));
            assert!(m.along_um != a.along_um, "triangulated at the centre, not at row {r}");
        }
    }
    // One row in four over the whole sensor.
    let (p, rows_read, _) = readout_frame(Some((0, 480, 4)), Some(RowSampling::Skip));
    assert_eq!(rows_read, 120);
    assert!(p.lasers.iter().all(|l| l.points.iter().map(|q| q.row).eq((0..480).step_by(4))));
}

/// `SetReadout` refuses, lasers off, what does not fit the sensor or is
/// not a skip of 1, 2 or 4, and anything while streaming; a capture reads
/// every row whatever the readout, and the next frame has the readout back.
#[test]
fn a_bad_readout_is_refused_and_captures_read_every_row() {
    let (mut h, l) = head();
    let mut cam = Cam { sampling: Some(RowSampling::Skip), ..Cam::watching(&l) };
    for (seq, (first_row, rows, skip)) in
        [(1, (0, 480, 3)), (2, (0, 0, 1)), (3, (0, 6, 4)), (4, (400, 96, 1)), (5, (u16::MAX, 2, 2)), (6, (0, 480, 0))]
    {
        let out =
            collect(|r| h.handle(cmd(seq, HostMsg::SetReadout { first_row, rows, skip }), 0, &cam, &mut |m| r(m)));
        assert_eq!(out, vec![DeviceMsg::Error { seq: Some(seq), code: ErrorCode::OutOfRange }]);
        assert_eq!(l.now(), 0);
    }
    let out = collect(|r| {
        h.handle(cmd(7, HostMsg::SetReadout { first_row: 100, rows: 200, skip: 4 }), 0, &cam, &mut |m| r(m))
    });
    assert_eq!(out, vec![DeviceMsg::Ack(7)]);
    assert_eq!(h.streaming_readout(), None, "from the next Start on");
    h.handle(cmd(8, start(0b001, LaserPattern::Simultaneous)), 10, &cam, &mut |_| {});
    let want = Readout::new(100, 200, RowSkip::X4, 480).unwrap();
    assert_eq!(h.streaming_readout(), Some(want));
    let busy = collect(|r| {
        h.handle(cmd(9, HostMsg::SetReadout { first_row: 0, rows: 480, skip: 1 }), 20, &cam, &mut |m| r(m))
    });
    assert!(busy.contains(&DeviceMsg::Error { seq: Some(9), code: ErrorCode::Busy }), "{busy:?}");
    assert_eq!(l.now(), 0);
    // A fault stopped it; a capture now reads all 480 rows.
    let out = collect(|r| {
        h.handle(cmd(10, HostMsg::CaptureImage(0b001)), 30, &cam, &mut |m| r(m));
        h.poll(30, &mut cam, &mut || 0, &mut |m| r(m));
    });
    let rows: std::collections::BTreeSet<u16> =
        out.iter().filter_map(|m| if let DeviceMsg::RawRows(r) = m { Some(r.first_row) } else { None }).collect();
    assert_eq!(rows.len(), 480);
    assert_eq!(cam.readouts, vec![Readout::full(480)], "no frame yet: the capture's readout only");
    h.handle(cmd(11, start(0b001, LaserPattern::Simultaneous)), 40, &cam, &mut |_| {});
    let out = collect(|r| h.poll(40, &mut cam, &mut || 0, &mut |m| r(m)));
    let p = out.iter().find_map(|m| if let DeviceMsg::Profile(p) = m { Some(p.clone()) } else { None }).unwrap();
    assert_eq!(cam.readouts, vec![Readout::full(480), want]);
    assert!(p.lasers[0].points.iter().map(|q| q.row).eq((100..300).step_by(4)), "{p:?}");
}
