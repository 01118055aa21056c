//! Fault paths: every one of them switches the lasers off first.
//!
//! * `panic!` (core or defmt): interrupts off → lasers off → red LED on →
//!   the message over defmt → `udf` → HardFault. This is panic-probe's
//!   sequence with the lasers switched off *before* anything that could block
//!   (a defmt-rtt write blocks while a probe has put the channel in blocking
//!   mode and stopped reading), which is why the firmware carries its own
//!   panic handler instead of linking `panic-probe`.
//! * HardFault (including the `udf` above, bus/memory/usage faults, which
//!   escalate to HardFault because they are not enabled separately): lasers
//!   off, red LED on, then the core parks. No logging here: the fault may
//!   have happened inside the logger. `probe-rs run` catches the HardFault
//!   vector and prints a backtrace, so a panic still ends a `cargo run` with
//!   a non-zero exit status.
//! * Any interrupt without a handler (`DefaultHandler`): treated as a fault.
//!
//! After a reset the pins are high impedance and the laser board's pull-downs
//! keep the lasers off (see `lasers.rs`).

use core::panic::PanicInfo;
use core::sync::atomic::{AtomicBool, Ordering};

use cortex_m_rt::{ExceptionFrame, exception};
use embassy_stm32::pac;

use crate::lasers;

/// The red LED of the OpenMV-Cam-H7 RGB LED (PC0, active low): steady on
/// means "halted on a fault".
const FAULT_LED_PORT: pac::gpio::Gpio = pac::GPIOC;
const FAULT_LED_PIN: usize = 0;

/// Lasers off and the fault LED on, through the registers only.
fn safe_state() {
    lasers::force_off();
    FAULT_LED_PORT.bsrr().write(|w| w.set_br(FAULT_LED_PIN, true));
    FAULT_LED_PORT.moder().modify(|w| w.set_moder(FAULT_LED_PIN, pac::gpio::vals::Moder::OUTPUT));
}

/// Ends in a HardFault, the way panic-probe does, so that probe-rs reports it.
fn trap() -> ! {
    // With UsageFault enabled `udf` would raise that instead of HardFault.
    let scb = cortex_m::peripheral::SCB::PTR;
    // SAFETY: SHCSR read-modify-write with interrupts disabled; clearing
    // USGFAULTENA only changes which handler the next fault enters.
    unsafe { (*scb).shcsr.modify(|v| v & !(1 << 18)) };
    cortex_m::asm::udf()
}

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    static PANICKED: AtomicBool = AtomicBool::new(false);
    cortex_m::interrupt::disable();
    safe_state();
    // Guard against a panic while printing the panic.
    if !PANICKED.swap(true, Ordering::Relaxed) {
        defmt::error!("panic (lasers forced off): {}", defmt::Display2Format(info));
    }
    trap()
}

/// `defmt::panic!` / `defmt::unwrap!` (also used inside embassy) have already
/// printed their message when they get here.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    cortex_m::interrupt::disable();
    safe_state();
    trap()
}

#[exception]
unsafe fn HardFault(_frame: &ExceptionFrame) -> ! {
    safe_state();
    loop {
        cortex_m::asm::nop();
    }
}

#[exception]
unsafe fn DefaultHandler(_irqn: i16) {
    cortex_m::interrupt::disable();
    safe_state();
    trap()
}
