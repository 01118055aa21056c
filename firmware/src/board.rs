//! Everything specific to the board: pins, clocks, sensor constants, and
//! [`setup`], which brings the chip up and hands `main` its devices with
//! their pins assigned. Another board is a change to this file only (and
//! `lasers.rs`' port constant): `main` names no pin.
//!
//! # Reference board
//! An OpenMV-Cam-H7-class board (STM32H743VI) with an MT9V034 global-shutter
//! monochrome sensor on the 8-bit DCMI, a carrier with three 685 nm laser
//! diode drivers, an optional quadrature wheel encoder and USB full speed.
//!
//! | function            | pin(s)                                   | peripheral          |
//! |---------------------|------------------------------------------|---------------------|
//! | laser 0, 1, 2 enable| PD12, PD13, PD14 (active high, pulled down on the driver) | GPIO (TIM4_CH1–3) |
//! | DCMI D0–D7          | PC6 PC7 PE0 PE1 PE4 PB6 PE5 PE6          | DCMI (AF13)         |
//! | DCMI VSYNC/HSYNC/PIXCLK | PB7 / PA4 / PA6                      | DCMI                |
//! | sensor I²C SCL/SDA  | PB8 / PB9                                | I2C1, 100 kHz       |
//! | sensor RESET_BAR    | PA10 (active low)                        | GPIO                |
//! | sensor STANDBY      | PD7 (active high)                        | GPIO                |
//! | sensor EXPOSURE     | PD6 (snapshot trigger, rising edge)      | GPIO                |
//! | encoder A / B       | PA0 / PA1                                | TIM5 encoder mode   |
//! | USB D− / D+         | PA11 / PA12                              | OTG_FS, HSI48 + CRS |
//! | LEDs red/green      | PC0 / PC1 (active low)                   | GPIO                |
//! | SWD                 | PA13 / PA14                              | probe-rs, defmt-rtt |
//!
//! # Why the MT9V034
//! 752 × 480 global shutter (every row exposed in the same window, so a
//! moving trolley does not shear the stripes, and a strobed laser lights the
//! whole frame), monochrome with a good 685 nm response, 60 frames/s at full
//! resolution on an 8/10-bit parallel bus that the DCMI takes directly, a
//! snapshot mode with an EXPOSURE trigger input and an LED_OUT output high
//! during exposure (to gate the laser drivers in hardware too), and a public
//! register reference (ON Semiconductor MT9V034 data sheet). The OpenMV
//! global-shutter module uses it, so the board exists.
//!
//! # Clocks
//! 480 MHz needs voltage scale 0 (VOS0, overdrive), which only revision V
//! silicon supports. The revision is read from DBGMCU_IDC before the clocks
//! are set: rev V → 480 MHz at VOS0, anything older (rev Y) → 400 MHz at
//! VOS1. AHB/AXI at half the core (240/200 MHz), APBs at a quarter.

use embassy_stm32::flash::{Blocking as FlashBlocking, Flash};
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::i2c::{I2c, Master};
use embassy_stm32::mode::Blocking;
use embassy_stm32::peripherals::{self, DCMI, IWDG1, TIM5};
use embassy_stm32::timer::qei::Qei;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, dcmi, dma, i2c, pac, timer, usb};
use static_cell::StaticCell;

use crate::lasers::Lasers;
use crate::link::UsbDriver;

bind_interrupts!(pub struct Irqs {
    OTG_FS => usb::InterruptHandler<peripherals::USB_OTG_FS>;
    DCMI => dcmi::InterruptHandler<peripherals::DCMI>;
    DMA1_STREAM0 => dma::InterruptHandler<peripherals::DMA1_CH0>;
    I2C1_EV => i2c::EventInterruptHandler<peripherals::I2C1>;
    I2C1_ER => i2c::ErrorInterruptHandler<peripherals::I2C1>;
});

/// The sensor's row length, px.
pub const WIDTH: usize = 752;
/// Rows per frame.
pub const HEIGHT: usize = 480;
/// Bits per pixel on the 8-bit DCMI (the MT9V034's D9..D2: its 10-bit ADC
/// companded to 8 bits, see `camera.rs`).
pub const BITS: u8 = 8;
/// MT9V034 7-bit I²C address with S_CTRL_ADR1/0 tied low.
pub const SENSOR_I2C_ADDR: u8 = 0x48;
/// MT9V034 pixel clock from the module's oscillator, Hz (26.6 MHz gives
/// 60 frames/s at full resolution with the default blanking).
pub const PIXCLK_HZ: u32 = 26_666_666;
/// Horizontal blanking, pixel clocks (sensor default, R0x05 = 94).
pub const HBLANK: u32 = 94;
/// Row time, ns: (752 + 94) pixel clocks.
pub const ROW_TIME_NS: u32 = ((WIDTH as u64 + HBLANK as u64) * 1_000_000_000 / PIXCLK_HZ as u64) as u32;

/// Flash offsets (from 0x0800_0000) of the two 128 KB settings slots: the
/// last two sectors of bank 2, outside the image (see `memory.x`).
pub const STORE_SLOTS: [u32; 2] = [0x1C_0000, 0x1E_0000];
/// Slot size: one sector.
pub const STORE_SLOT_SIZE: u32 = 0x2_0000;

/// Encoder: a 200 mm wheel with a 2500-line encoder, ×4 quadrature, is
/// 62 832 nm per count (set from the trolley's calibration).
pub const ENCODER_NM_PER_COUNT: u32 = 62_832;
/// Whether the encoder counts down when the trolley moves forward.
pub const ENCODER_REVERSE: bool = false;

/// Silicon revision from DBGMCU_IDC (0x2003 = V, 0x1003 = Y).
pub fn silicon_revision() -> u16 {
    pac::DBGMCU.idc().read().rev_id()
}

/// Core clock for this silicon revision, Hz.
pub fn sysclk_hz(rev: u16) -> u32 {
    if rev >= 0x2003 { 480_000_000 } else { 400_000_000 }
}

/// Clock tree: HSI 64 MHz / 4 = 16 MHz → PLL1 × 60 (rev V, 960 MHz VCO) or
/// × 50 (800 MHz) → P / 2 = 480 or 400 MHz. HSI rather than HSE because the
/// crystal is board specific; USB runs from HSI48 trimmed by the CRS on USB
/// SOF packets.
pub fn clock_config(rev: u16) -> embassy_stm32::Config {
    use embassy_stm32::rcc::{
        AHBPrescaler, APBPrescaler, HSIPrescaler, Pll, PllDiv, PllMul, PllPreDiv, PllSource, Sysclk, VoltageScale, mux,
    };
    let fast = sysclk_hz(rev) == 480_000_000;
    let mut config = embassy_stm32::Config::default();
    config.rcc.hsi = Some(HSIPrescaler::DIV1);
    config.rcc.pll1 = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV4,
        mul: if fast { PllMul::MUL60 } else { PllMul::MUL50 },
        fracn: None,
        divp: Some(PllDiv::DIV2),
        divq: Some(PllDiv::DIV8), // 120 / 100 MHz kernel clocks
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.ahb_pre = AHBPrescaler::DIV2; // 240 / 200 MHz (AXI, AHB: DCMI, DMA)
    config.rcc.apb1_pre = APBPrescaler::DIV2; // 120 / 100 MHz
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.apb3_pre = APBPrescaler::DIV2;
    config.rcc.apb4_pre = APBPrescaler::DIV2;
    config.rcc.voltage_scale = if fast { VoltageScale::Scale0 } else { VoltageScale::Scale1 };
    config.rcc.mux.usbsel = mux::Usbsel::HSI48;
    config
}

/// Drives the laser enables low before anything else runs: clocks the GPIO
/// port (nothing else is initialised yet) and forces the pins to outputs,
/// low. Called first thing in [`setup`], before `embassy_stm32::init`.
fn lasers_off_at_reset() {
    pac::RCC.ahb4enr().modify(|w| w.set_gpioden(true));
    // Read back: the write must reach the RCC before the port is touched.
    let _ = pac::RCC.ahb4enr().read();
    crate::lasers::force_off();
}

/// The sensor's buses and control lines (the MT9V034 driver takes them once
/// the sensor is out of reset).
pub struct SensorParts {
    /// The register bus, 100 kHz.
    pub i2c: I2c<'static, Blocking, Master>,
    /// The 8-bit parallel capture.
    pub dcmi: dcmi::Dcmi<'static, DCMI>,
    /// The snapshot trigger (EXPOSURE), low.
    pub exposure: Output<'static>,
    /// The wheel encoder's quadrature counter.
    pub encoder: Qei<'static, TIM5>,
    /// RESET_BAR, held high (released) while the sensor is in use.
    pub reset: Output<'static>,
    /// STANDBY, held low (awake).
    pub standby: Output<'static>,
}

/// What `main` runs the head with: the board's devices, pins assigned.
pub struct Devices {
    /// Silicon revision (DBGMCU_IDC).
    pub silicon_revision: u16,
    /// Core clock, Hz.
    pub sysclk_hz: u32,
    /// The laser driver, owning the enables (off).
    pub lasers: Lasers,
    /// Status LED (green, off).
    pub status_led: Output<'static>,
    /// Fault LED (red, off).
    pub fault_led: Output<'static>,
    /// The independent watchdog, not started.
    pub watchdog: IndependentWatchdog<'static, IWDG1>,
    /// The internal flash (the settings slots).
    pub flash: Flash<'static, FlashBlocking>,
    /// The sensor's parts.
    pub sensor: SensorParts,
    /// The USB full-speed device driver.
    pub usb: UsbDriver,
}

/// Brings the board up, in the order the laser-safety rules need: laser
/// enables low through the registers first ([`lasers_off_at_reset`]), then
/// the clocks ([`clock_config`]), then the laser driver takes the pins (and
/// is checked off), then the instruction cache and the cycle counter, then
/// every other device. Nothing is started: the watchdog is created
/// stopped, the USB device and the sensor are `main`'s to run.
pub fn setup(watchdog_us: u32) -> Devices {
    lasers_off_at_reset();
    let silicon_revision = silicon_revision();
    let sysclk_hz = sysclk_hz(silicon_revision);
    let p = embassy_stm32::init(clock_config(silicon_revision));
    let lasers = Lasers::new(p.PD12, p.PD13, p.PD14);
    defmt::assert!(lasers.all_are_off(), "laser enables not low after init");
    enable_core_features();
    let status_led = Output::new(p.PC1, Level::High, Speed::Low);
    let fault_led = Output::new(p.PC0, Level::High, Speed::Low);
    let watchdog = IndependentWatchdog::new(p.IWDG1, watchdog_us);
    let flash = Flash::new_blocking(p.FLASH);
    let dcmi = dcmi::Dcmi::new_8bit(
        p.DCMI,
        p.DMA1_CH0,
        Irqs,
        p.PC6,
        p.PC7,
        p.PE0,
        p.PE1,
        p.PE4,
        p.PB6,
        p.PE5,
        p.PE6,
        p.PB7,
        p.PA4,
        p.PA6,
        dcmi::Config::default(),
    );
    let mut i2c_config = i2c::Config::default();
    i2c_config.frequency = embassy_stm32::time::Hertz(100_000);
    let i2c = I2c::new_blocking(p.I2C1, p.PB8, p.PB9, i2c_config);
    let sensor = SensorParts {
        i2c,
        dcmi,
        exposure: Output::new(p.PD6, Level::Low, Speed::VeryHigh),
        encoder: Qei::new(p.TIM5, p.PA0, p.PA1, timer::qei::Config::default()),
        reset: Output::new(p.PA10, Level::High, Speed::Low),
        standby: Output::new(p.PD7, Level::Low, Speed::Low),
    };
    static EP_OUT: StaticCell<[u8; 256]> = StaticCell::new();
    let mut usb_config = usb::Config::default();
    usb_config.vbus_detection = false; // bus powered
    let usb = usb::Driver::new_fs(p.USB_OTG_FS, Irqs, p.PA12, p.PA11, EP_OUT.init([0; 256]), usb_config);
    Devices { silicon_revision, sysclk_hz, lasers, status_led, fault_led, watchdog, flash, sensor, usb }
}

/// Instruction cache and the DWT cycle counter. The data cache stays off:
/// the DCMI ring is read while DMA writes it (no cache maintenance needed).
fn enable_core_features() {
    match cortex_m::Peripherals::take() {
        Some(mut cp) => {
            cp.SCB.enable_icache();
            cp.DCB.enable_trace();
            cortex_m::peripheral::DWT::unlock();
            cp.DWT.enable_cycle_counter();
        }
        None => defmt::warn!("core peripherals already taken: no I-cache, no cycle counts"),
    }
}
