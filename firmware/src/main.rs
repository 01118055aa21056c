//! `cms-firmware`: the CMS sensor head (STM32H743VI, OpenMV-Cam-H7 class).
//!
//! A minimal embassy skeleton around `cms-core`:
//!
//! 1. clocks: HSI → PLL1 → 400 MHz core (valid for every H743 silicon
//!    revision at VOS1), 200 MHz AHB, 100 MHz APB; instruction cache on;
//! 2. the three laser-enable outputs, driven low (lasers off) right after
//!    the clocks (see `lasers.rs` for the pins and the safety chain);
//! 3. the stripe detector, built once and validated; a self-test on a
//!    synthetic 752-px row whose stripes are logged over defmt-rtt;
//! 4. a heartbeat: a short blink of PC1 once a second when healthy, or a fast
//!    blink of the red LED (PC0) when the detector or its self-test failed —
//!    the lasers then stay off.
//!
//! Build and flash from this directory: `cargo build --release`,
//! `cargo run --release` (probe-rs, see `.cargo/config.toml`).

#![no_std]
#![no_main]

mod fault;
mod lasers;
mod selftest;

use cms_core::fixed::Px;
use cms_core::optics::{OpticsError, ScaleRange};
use cms_core::peak::{self, Config, Detector, Stripes};
use defmt::{error, info, warn};
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_time::{Duration, Timer};

use crate::lasers::Lasers;
use crate::selftest::WIDTH;

/// Core clock after [`clock_config`], for turning cycle counts into time.
const SYSCLK_HZ: u32 = 400_000_000;
/// Most stripes the self-test collects (the head has three lasers).
const MAX_STRIPES: usize = 4;

/// HSI (64 MHz) / 4 × 50 = 800 MHz VCO; P / 2 = 400 MHz system clock.
///
/// HSI rather than HSE because the crystal frequency is board specific; USB
/// will use the HSI48 (on by default) trimmed by the CRS.
fn clock_config() -> embassy_stm32::Config {
    use embassy_stm32::rcc::{
        AHBPrescaler, APBPrescaler, HSIPrescaler, Pll, PllDiv, PllMul, PllPreDiv, PllSource, Sysclk, VoltageScale,
    };
    let mut config = embassy_stm32::Config::default();
    config.rcc.hsi = Some(HSIPrescaler::DIV1);
    config.rcc.pll1 = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL50,
        fracn: None,
        divp: Some(PllDiv::DIV2), // 400 MHz: system clock
        divq: Some(PllDiv::DIV8), // 100 MHz: SPI/SDMMC kernel clocks
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.ahb_pre = AHBPrescaler::DIV2; // 200 MHz (AXI, AHB: DCMI, DMA)
    config.rcc.apb1_pre = APBPrescaler::DIV2; // 100 MHz
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.apb3_pre = APBPrescaler::DIV2;
    config.rcc.apb4_pre = APBPrescaler::DIV2;
    config.rcc.voltage_scale = VoltageScale::Scale1;
    config
}

/// Instruction cache and the DWT cycle counter. The data cache stays off
/// until the DMA buffers get an uncached MPU region (camera DMA into a cached
/// AXI SRAM would otherwise need explicit cache maintenance).
fn enable_core_features() {
    match cortex_m::Peripherals::take() {
        Some(mut cp) => {
            cp.SCB.enable_icache();
            cp.DCB.enable_trace();
            cortex_m::peripheral::DWT::unlock();
            cp.DWT.enable_cycle_counter();
        }
        None => warn!("core peripherals already taken: no I-cache, no cycle counts"),
    }
}

/// Why the detector could not start.
#[derive(defmt::Format)]
enum StartError {
    /// The scale range was refused.
    Scales(OpticsError),
    /// The detector configuration was refused.
    Config(peak::Error),
}

/// The head's detector: 12-bit pixels, stripe σ between 1 and 4 px.
fn build_detector() -> Result<Detector<WIDTH>, StartError> {
    let scales = ScaleRange::new(Px::from_f64(1.0), Px::from_f64(4.0)).map_err(StartError::Scales)?;
    Detector::new(Config::new(12, scales)).map_err(StartError::Config)
}

/// Q16.16 pixels as `f32`, for log messages only.
fn px_f32(p: Px) -> f32 {
    p.0 as f32 / 65536.0
}

/// Runs the detector on the synthetic row and logs what it found. Returns
/// whether every synthetic stripe was found within the tolerance.
fn self_test(detector: &mut Detector<WIDTH>) -> bool {
    let mut stripes: Stripes<MAX_STRIPES> = Stripes::new();
    let cycles = match selftest::run(detector, &mut stripes) {
        Ok(cycles) => cycles,
        Err(e) => {
            error!("self-test: detect failed: {}", e);
            return false;
        }
    };
    info!(
        "self-test: {} stripes in {} cycles ({} us at {} MHz); {}",
        stripes.len(),
        cycles,
        cycles / (SYSCLK_HZ / 1_000_000),
        SYSCLK_HZ / 1_000_000,
        detector.stats()
    );
    for s in &stripes {
        let (laser, err) = selftest::nearest_truth(s);
        info!(
            "  stripe x = {=f32} px (laser {}, error {=f32} px), strength {}, sigma {=f32} px, {}",
            px_f32(s.position),
            laser,
            px_f32(err),
            s.strength,
            px_f32(s.width),
            s.flags
        );
    }
    let report = selftest::check(&stripes);
    let ok = report.matched == selftest::TRUTH.len() && stripes.len() == selftest::TRUTH.len();
    if ok {
        info!("self-test passed: worst error {=f32} px", px_f32(report.worst));
    } else {
        error!(
            "self-test FAILED: {} of {} stripes within {=f32} px ({} found)",
            report.matched,
            selftest::TRUTH.len(),
            px_f32(selftest::TOLERANCE),
            stripes.len()
        );
    }
    ok
}

/// Blinks the status LEDs (active low): a 50 ms flash of `status` every
/// second when healthy, otherwise `fault` at 5 Hz.
#[embassy_executor::task]
async fn heartbeat(mut status: Output<'static>, mut fault: Output<'static>, healthy: bool) {
    let (led, on, off) = if healthy {
        (&mut status, Duration::from_millis(50), Duration::from_millis(950))
    } else {
        (&mut fault, Duration::from_millis(100), Duration::from_millis(100))
    };
    loop {
        led.set_low();
        Timer::after(on).await;
        led.set_high();
        Timer::after(off).await;
    }
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clock_config());
    // First thing once the GPIO clocks run: own the laser enables, all low.
    let lasers = Lasers::new(p.PD12, p.PD13, p.PD14);
    info!("cms-firmware {}: {} lasers off", env!("CARGO_PKG_VERSION"), lasers::COUNT);
    enable_core_features();

    // OpenMV-Cam-H7 RGB LED, active low: start dark.
    let status_led = Output::new(p.PC1, Level::High, Speed::Low);
    let fault_led = Output::new(p.PC0, Level::High, Speed::Low);

    let mut detector = match build_detector() {
        Ok(d) => Some(d),
        Err(e) => {
            error!("detector refused its configuration: {}; lasers stay off", e);
            None
        }
    };
    let healthy = match detector.as_mut() {
        Some(d) => self_test(d),
        None => false,
    };
    if !healthy {
        warn!("not healthy: lasers stay off");
    }
    debug_assert!(lasers.all_are_off());

    match heartbeat(status_led, fault_led, healthy) {
        Ok(token) => spawner.spawn(token),
        Err(e) => error!("heartbeat task not spawned: {}", e),
    }

    // The row pipeline (DCMI capture → detector → host link) will take the
    // detector and the lasers from here. Until then this task keeps both, so
    // the enables stay actively driven low.
    core::future::pending::<()>().await;
    drop((lasers, detector));
}
