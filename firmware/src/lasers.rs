//! The three 50 mW line lasers: off by default, off on every fault.
//!
//! # Wiring (sensor head)
//! Each laser driver's ENABLE input is wired to one GPIO, active high:
//!
//! | laser | pin  | OpenMV-Cam-H7 header | note                         |
//! |-------|------|----------------------|------------------------------|
//! | 0     | PD12 | P7                   | TIM4_CH1 (AF2)               |
//! | 1     | PD13 | P8                   | TIM4_CH2 (AF2)               |
//! | 2     | PD14 | P9                   | TIM4_CH3 (AF2)               |
//!
//! None of them is a DCMI pin (docs/reference.md §5: D0–D7 = PC6 PC7 PE0 PE1 PE4 PB6 PE5
//! PE6, VSYNC PB7, HSYNC PA4, PIXCLK PA6), nor USB (PA11/PA12), SWD or the
//! camera's I2C (PB8/PB9).
//!
//! # Safety chain
//! 1. **Reset → firmware init**: after any reset the STM32H7 leaves every
//!    GPIO in analog mode (high impedance). The laser board MUST pull each
//!    ENABLE line down (e.g. 10 kΩ to GND at the driver input); that pull-down
//!    is what keeps the lasers off until the first statement of `main`
//!    (`board::lasers_off_at_reset`, before clocks or any other init) drives
//!    the lines low through the registers.
//! 2. **Init**: [`Lasers::new`] sets the output latch low *before* switching
//!    the pin to output mode (embassy's `Output::new` does it in that order),
//!    so there is no glitch.
//! 3. **Faults**: [`force_off`] drives the lines low straight through the GPIO
//!    registers, without owning the pins, from the panic handler, HardFault
//!    and any unexpected interrupt (see `fault.rs`). It also forces the pins
//!    back to push-pull output mode, so it overrides a later TIM4 PWM setup.
//! 4. **Drop**: dropping [`Lasers`] drives the lines low and then embassy
//!    returns the pins to high impedance, where the pull-down holds them.
//!
//! What the firmware cannot do: while a debugger holds the core halted
//! (breakpoint, `probe-rs` stop) the outputs keep their last state. Keep the
//! lasers' hardware interlock (key switch / enclosure) in the loop.

use cms_core::pipeline::LaserDriver;
use embassy_stm32::Peri;
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::pac;
use embassy_stm32::peripherals::{PD12, PD13, PD14};

/// GPIO port of the laser enables (must match the pin types in [`Lasers::new`]).
const PORT: pac::gpio::Gpio = pac::GPIOD;
/// Pin numbers of the laser enables within [`PORT`].
const PINS: [usize; 3] = [12, 13, 14];

/// Number of laser lines on the head.
pub const COUNT: usize = PINS.len();

/// Owns the three laser-enable outputs; all lasers off while it exists unless
/// switched on by the head (`cms_core::pipeline::Head`, the only caller of
/// [`LaserDriver::set`], which applies the safety rules: strobe during
/// exposures only, duty-cycle limit, heartbeat).
pub struct Lasers {
    enable: [Output<'static>; COUNT],
}

impl Lasers {
    /// Takes the enable pins and drives them low (lasers off).
    pub fn new(l0: Peri<'static, PD12>, l1: Peri<'static, PD13>, l2: Peri<'static, PD14>) -> Self {
        let off = Level::Low;
        Lasers {
            enable: [
                Output::new(l0, off, Speed::Low),
                Output::new(l1, off, Speed::Low),
                Output::new(l2, off, Speed::Low),
            ],
        }
    }

    /// Switches every laser off.
    pub fn all_off(&mut self) {
        for pin in &mut self.enable {
            pin.set_low();
        }
    }

    /// Whether every enable line is driven low.
    pub fn all_are_off(&self) -> bool {
        self.enable.iter().all(|pin| pin.is_set_low())
    }
}

impl LaserDriver for Lasers {
    fn set(&mut self, mask: u8) {
        for (k, pin) in self.enable.iter_mut().enumerate() {
            pin.set_level(if mask & (1 << k) != 0 { Level::High } else { Level::Low });
        }
    }
}

impl Drop for Lasers {
    fn drop(&mut self) {
        self.all_off();
    }
}

/// Drives every laser-enable line low without owning the pins: for the
/// fault paths (panic, HardFault, stray interrupt), where the [`Lasers`] value
/// is out of reach.
///
/// Idempotent and lock-free (plain register writes, no critical section); does
/// nothing harmful if the GPIO port is not clocked yet (the writes are then
/// ignored and the pins are still high impedance, held off by the pull-downs).
pub fn force_off() {
    // Output latch low first (BSRR is write-only and atomic)...
    PORT.bsrr().write(|w| {
        for &n in &PINS {
            w.set_br(n, true);
        }
    });
    // ...then push-pull, no pull, general-purpose output mode, in case the
    // pin had been handed to a timer (PWM) or left floating.
    PORT.otyper().modify(|w| {
        for &n in &PINS {
            w.set_ot(n, pac::gpio::vals::Ot::PUSH_PULL);
        }
    });
    PORT.moder().modify(|w| {
        for &n in &PINS {
            w.set_moder(n, pac::gpio::vals::Moder::OUTPUT);
        }
    });
}
