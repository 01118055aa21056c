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

mod line;
mod model;
mod readout;
mod safety;
mod windows;

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

/// Messages of one call, collected.
fn collect(f: impl FnOnce(&mut dyn FnMut(&DeviceMsg))) -> Vec<DeviceMsg> {
    let mut out = Vec::new();
    f(&mut |m: &DeviceMsg| out.push(m.clone()));
    out
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
    // Protocol 5: at most 4 bytes a point with the metric point (the link's
    // budget: 60 frames/s of 1 440 points within 35 % of USB full speed's
    // 1 MB/s); no code is shorter than a bit, so a point costs at least a
    // bit a field (position, strength, width) and the metric point two more
    // (along, height).
    assert!(sizes[1] <= 1440 * 4, "{sizes:?}");
    assert!(sizes[0] * 8 >= 1440 * 3 && sizes[1] > sizes[0] + 1440 / 4, "{sizes:?}");
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
