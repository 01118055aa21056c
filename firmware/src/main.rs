//! `cms-firmware`: the CMS sensor head (STM32H743VI, OpenMV-Cam-H7 class,
//! MT9V034 global-shutter sensor). Thin over `cms-core`: the head's logic
//! (commands, laser-safety rules, row pipeline, triangulation, protocol) is
//! `cms_core::pipeline::Head`, the same code the simulated head runs and the
//! host tests exercise; this crate supplies the hardware behind its traits.
//!
//! `main` is setup, spawn, loop: `board::setup()` brings the chip up and
//! hands it the devices (pins are named in `board.rs` only), `main` spawns
//! the LED and USB tasks and runs the head loop. Start-up order:
//! 1. laser enables driven low through the registers (`board::setup`'s
//!    first statement, before clocks or any other init);
//! 2. clocks (480 MHz on rev V silicon, 400 MHz on rev Y: `board.rs`), the
//!    `Lasers` driver owning the pins, I-cache, DWT cycle counter, then every
//!    other device created (nothing started);
//! 3. the independent watchdog (500 ms; a hung head resets, and after reset
//!    the pins are high impedance, held off by the laser board's pull-downs);
//! 4. the detector self-test on a synthetic row (logged);
//! 5. flash: calibration and settings restored, or reported missing/corrupt;
//! 6. the MT9V034 over I²C, the DCMI ring, the encoder timer;
//! 7. USB CDC-ACM tasks, then the head loop: commands in, `Head::poll`, a
//!    settings save when the head asks for one, the watchdog fed.
//!
//! Build and flash from this directory: `cargo build --release`,
//! `cargo run --release` (probe-rs, see `.cargo/config.toml`).

#![no_std]
#![no_main]

mod board;
mod camera;
mod fault;
mod lasers;
mod link;
mod selftest;
mod store;

use core::sync::atomic::{AtomicU32, Ordering};

use cms_core::fixed::Px;
use cms_core::optics::{OpticsError, ScaleRange};
use cms_core::peak::{self, Config, Detector, Stripes};
use cms_core::pipeline::{Head, Identity, default_detector};
use cms_core::protocol::{
    Command, DeviceMsg, FrameReader, HeadState, MAX_COMMAND_FRAME, MAX_FRAME, StoreHealth, WireError, encode,
};
use defmt::{error, info, unwrap, warn};
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_stm32::gpio::Output;
use embassy_time::{Duration, Instant, Timer};
use static_cell::StaticCell;

use crate::camera::Mt9v034;
use crate::lasers::Lasers;

/// Most stripes the self-test collects (the head has three lasers).
const MAX_STRIPES: usize = 4;

/// Why the detector could not start.
#[derive(defmt::Format)]
enum StartError {
    /// The scale range was refused.
    Scales(OpticsError),
    /// The detector configuration was refused.
    Config(peak::Error),
}

/// The self-test's detector: 12-bit pixels, stripe σ between 1 and 4 px.
fn build_selftest_detector() -> Result<Detector<{ board::WIDTH }>, StartError> {
    let scales = ScaleRange::new(Px::from_f64(1.0), Px::from_f64(4.0)).map_err(StartError::Scales)?;
    Detector::new(Config::new(12, scales)).map_err(StartError::Config)
}

/// The head's detector: the core's default at the sensor's 8 bits, with
/// the estimator for laser light (its lines are speckled: the centroid).
fn head_detector() -> Config {
    let mut c = default_detector();
    c.method = peak::Method::Centroid;
    c.bits = board::BITS;
    c.saturation = (1 << board::BITS) - 1;
    c
}

/// Q16.16 pixels as `f32`, for log messages only.
fn px_f32(p: Px) -> f32 {
    p.0 as f32 / 65536.0
}

/// Runs the detector on the synthetic row and logs what it found.
fn self_test(detector: &mut Detector<{ board::WIDTH }>, mhz: u32) -> bool {
    let mut stripes: Stripes<MAX_STRIPES> = Stripes::new();
    let cycles = match selftest::run(detector, &mut stripes) {
        Ok(cycles) => cycles,
        Err(e) => {
            error!("self-test: detect failed: {}", e);
            return false;
        }
    };
    info!("self-test: {} stripes in {} cycles ({} us at {} MHz)", stripes.len(), cycles, cycles / mhz, mhz);
    let report = selftest::check(&stripes);
    let ok = report.matched == selftest::TRUTH.len() && stripes.len() == selftest::TRUTH.len();
    if ok {
        info!("self-test passed: worst error {=f32} px", px_f32(report.worst));
    } else {
        error!("self-test FAILED: {} of {} stripes", report.matched, selftest::TRUTH.len());
    }
    ok
}

/// The DWT cycle counter extended to 64 bits (it wraps every 8.9 s at
/// 480 MHz; the head loop reads it far more often).
fn cycles64() -> u64 {
    static HIGH: AtomicU32 = AtomicU32::new(0);
    static LAST: AtomicU32 = AtomicU32::new(0);
    critical_section::with(|_| {
        let now = cortex_m::peripheral::DWT::cycle_count();
        if now < LAST.load(Ordering::Relaxed) {
            HIGH.fetch_add(1, Ordering::Relaxed);
        }
        LAST.store(now, Ordering::Relaxed);
        ((HIGH.load(Ordering::Relaxed) as u64) << 32) | now as u64
    })
}

/// Blinks the status LED (active low) once a second; the fault LED at 5 Hz
/// when the head could not start.
#[embassy_executor::task]
async fn blink(mut led: Output<'static>, fast: bool) {
    let (on, off) = if fast { (100, 100) } else { (50, 950) };
    loop {
        led.set_low();
        Timer::after(Duration::from_millis(on)).await;
        led.set_high();
        Timer::after(Duration::from_millis(off)).await;
    }
}

/// Opens the settings slots and restores what they hold into the head (or
/// tells it why there is nothing).
fn open_store(
    flash: embassy_stm32::flash::Flash<'static, embassy_stm32::flash::Blocking>,
    head: &mut Head<{ board::WIDTH }, Lasers>,
) -> Option<store::Store> {
    let mut store = match store::Store::new(flash) {
        Ok(s) => {
            if let Some(i) = s.faulted {
                warn!("flash: reading slot {} faulted before the last reset (ECC); not read until rewritten", i);
            }
            Some(s)
        }
        Err(e) => {
            error!("flash slots: {}", e);
            None
        }
    };
    match store.as_mut().map(|s| s.load()) {
        Some((Some(stored), health)) => {
            head.restore(&stored, health);
            let id = head.calibration().map_or(0, |c| c.id);
            info!("flash: {}, calibration {} (0: none or refused)", health, id);
        }
        Some((None, health)) => {
            head.set_store_health(health);
            warn!("flash: {}: defaults, no calibration", health);
        }
        None => head.set_store_health(StoreHealth::Corrupt),
    }
    store
}

/// The encoding buffer for one device message: postcard writes version,
/// payload, CRC and COBS into it in one pass.
struct Encoder {
    out: [u8; MAX_FRAME],
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    // 1–2. Lasers off, clocks, every device (board.rs: the only file that
    // names pins).
    let board::Devices {
        silicon_revision,
        sysclk_hz: sysclk,
        lasers,
        status_led,
        fault_led,
        mut watchdog,
        flash,
        sensor,
        usb,
    } = board::setup(store::WATCHDOG_MS as u32 * 1000);
    info!(
        "cms-firmware {}: silicon rev {=u16:#x}, {} MHz, lasers off",
        env!("CARGO_PKG_VERSION"),
        silicon_revision,
        sysclk / 1_000_000
    );

    // 3. Watchdog.
    watchdog.unleash();

    // 4. Self-test.
    let healthy = match build_selftest_detector() {
        Ok(mut d) => self_test(&mut d, sysclk / 1_000_000),
        Err(e) => {
            error!("self-test detector refused: {}", e);
            false
        }
    };
    watchdog.pet();

    // 5. The head, with what flash holds.
    static HEAD: StaticCell<Head<{ board::WIDTH }, Lasers>> = StaticCell::new();
    let identity = Identity { firmware: env!("CARGO_PKG_VERSION"), board: "OpenMV-H7 MT9V034" };
    let head = match Head::new(lasers, head_detector(), identity) {
        Ok(h) => HEAD.init(h),
        Err(e) => {
            error!("head detector refused: {}; lasers stay off", e);
            spawner.spawn(unwrap!(blink(fault_led, true)));
            loop {
                watchdog.pet();
                Timer::after(Duration::from_millis(100)).await;
            }
        }
    };
    head.set_cpu_hz(sysclk);
    let mut store = open_store(flash, head);
    watchdog.pet();

    // 6. Sensor, DCMI, encoder.
    let board::SensorParts { i2c, dcmi, exposure, encoder, reset: _sensor_reset, standby: _sensor_standby } = sensor;
    Timer::after(Duration::from_millis(2)).await; // sensor out of reset
    let mut camera = match Mt9v034::new(i2c, dcmi, exposure, encoder, sysclk) {
        Ok(c) => Some(c),
        Err(e) => {
            error!("camera: {}; streaming will be refused", e);
            None
        }
    };
    let ok = healthy && camera.is_some();
    spawner.spawn(unwrap!(blink(if ok { status_led } else { fault_led }, !ok)));

    // 7. USB and the head loop.
    let (device, tx, rx) = link::build(usb);
    spawner.spawn(unwrap!(link::usb_device(device)));
    spawner.spawn(unwrap!(link::usb_tx(tx)));
    spawner.spawn(unwrap!(link::usb_rx(rx)));

    static ENCODER: StaticCell<Encoder> = StaticCell::new();
    let enc = ENCODER.init(Encoder { out: [0; MAX_FRAME] });
    let mut reader: FrameReader<MAX_COMMAND_FRAME> = FrameReader::new();
    let mhz = (sysclk / 1_000_000) as u64;
    let mut clock_ns = move || cycles64() * 1000 / mhz;
    let mut reply = |m: &DeviceMsg| {
        if let DeviceMsg::Status(s) = m {
            info!(
                "status: {} frames, {} mHz, {} ns/row ({} cycles), dropped {} frames {} rows, backlog {} B, duty {} permille",
                s.frames,
                s.frame_rate_millihz,
                s.ns_per_row,
                s.cycles_per_row,
                s.dropped_frames,
                s.dropped_rows,
                s.link_backlog_bytes,
                s.laser_duty_permille
            );
        }
        match encode(m, &mut enc.out) {
            Ok(frame) => {
                link::send(frame);
            }
            Err(e) => error!("encode: {}", e),
        }
    };
    let mut rx_buf = [0u8; 64];
    loop {
        watchdog.pet();
        let now_us = Instant::now().as_micros();
        // Commands in.
        while let Ok(n) = link::RX.try_read(&mut rx_buf) {
            let mut cmds: heapless::Vec<Result<Command, WireError>, 16> = heapless::Vec::new();
            reader.feed::<Command, _>(&rx_buf[..n], |r| {
                let _ = cmds.push(r);
            });
            for r in cmds {
                match (r, camera.as_ref()) {
                    (Ok(cmd), Some(cam)) => head.handle(cmd, now_us, cam, &mut reply),
                    (Ok(cmd), None) => reply(&DeviceMsg::Error {
                        seq: Some(cmd.seq),
                        code: cms_core::protocol::ErrorCode::SensorFault,
                    }),
                    (Err(e), _) => head.link_error(e.into(), &mut reply),
                }
            }
        }
        // Rows in, profiles out.
        if let Some(cam) = camera.as_mut() {
            head.set_link_backlog(link::backlog());
            head.poll(now_us, cam, &mut clock_ns, &mut reply);
            let _ = cms_core::pipeline::Camera::odometer_um(cam); // keep the 16-bit count from wrapping unseen
        }
        // Settings to flash, when idle.
        if let Some(s) = head.take_store_request() {
            match store.as_mut().map(|st| st.save(&s)) {
                Some(Ok(seq)) => info!("flash: settings saved (record {})", seq),
                Some(Err(e)) => {
                    error!("flash: save failed: {}", e);
                    head.storage_error(&mut reply);
                }
                None => head.storage_error(&mut reply),
            }
        }
        if head.state() == HeadState::Streaming {
            embassy_futures::yield_now().await;
        } else {
            Timer::after(Duration::from_millis(1)).await;
        }
    }
}
