//! Time on the emulated board: SysTick on the 25 MHz core clock.
//!
//! * As the `embassy-time` driver: SysTick interrupts every millisecond and
//!   counts milliseconds; [`now_us`] adds the current count within the
//!   millisecond, so time has 40 ns resolution. Alarms are checked on each
//!   tick, so a timer fires within 1 ms after its deadline (frame periods are
//!   1 ms or more). Without `-icount`, QEMU's SysTick follows the host's clock
//!   (the head keeps real time: heartbeats, frame rate); with
//!   `-icount shift=0` one instruction is one nanosecond.
//! * For the benchmark: [`free_running`] turns the interrupt off and lets the
//!   24-bit counter wrap every 0.67 s (16.7 M ticks), and [`elapsed_ticks`]
//!   measures spans shorter than that with no interrupt in them.
//!
//! Cost: one interrupt per millisecond (about 40 instructions, 0.004 % of the
//! CPU at 1 instruction per ns).

use core::cell::{Cell, RefCell};
use core::task::Waker;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{SCB, SYST};
use cortex_m_rt::exception;
use critical_section::Mutex;
use embassy_time_queue_utils::Queue;

use crate::board::SYSCLK_HZ;

/// SysTick counts per millisecond.
const TICKS_PER_MS: u32 = SYSCLK_HZ / 1000;
/// SysTick counts per microsecond.
const TICKS_PER_US: u64 = (SYSCLK_HZ / 1_000_000) as u64;
/// Nanoseconds per SysTick count.
pub const NS_PER_TICK: u64 = 1_000_000_000 / SYSCLK_HZ as u64;

/// Milliseconds since [`init`].
static MS: Mutex<Cell<u64>> = Mutex::new(Cell::new(0));

struct Alarms {
    queue: Queue,
    /// When the earliest timer is due, µs (`u64::MAX`: none).
    next_us: u64,
}

static ALARMS: Mutex<RefCell<Alarms>> = Mutex::new(RefCell::new(Alarms { queue: Queue::new(), next_us: u64::MAX }));

/// Starts the 1 kHz tick.
pub fn init(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(TICKS_PER_MS - 1);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
}

/// SysTick counts since [`init`] (25 MHz).
pub fn ticks() -> u64 {
    critical_section::with(|cs| {
        let mut ms = MS.borrow(cs).get();
        let mut v = SYST::get_current();
        // A wrap since the last interrupt (this one is masked): the count
        // read after seeing it pending is certainly past the wrap.
        if SCB::is_pendst_pending() {
            v = SYST::get_current();
            ms += 1;
        }
        ms * TICKS_PER_MS as u64 + (TICKS_PER_MS - 1 - v) as u64
    })
}

/// Microseconds since [`init`].
pub fn now_us() -> u64 {
    ticks() / TICKS_PER_US
}

/// Nanoseconds since [`init`] (40 ns steps).
pub fn now_ns() -> u64 {
    ticks() * NS_PER_TICK
}

#[exception]
fn SysTick() {
    let now = critical_section::with(|cs| {
        let ms = MS.borrow(cs);
        ms.set(ms.get() + 1);
        ms.get() * 1000
    });
    critical_section::with(|cs| {
        let mut a = ALARMS.borrow_ref_mut(cs);
        if now >= a.next_us {
            a.next_us = a.queue.next_expiration(now);
        }
    });
}

struct SysTickDriver;

impl embassy_time_driver::Driver for SysTickDriver {
    fn now(&self) -> u64 {
        now_us()
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            let mut a = ALARMS.borrow_ref_mut(cs);
            if a.queue.schedule_wake(at, waker) {
                a.next_us = a.queue.next_expiration(now_us());
            }
        });
    }
}

embassy_time_driver::time_driver_impl!(static DRIVER: SysTickDriver = SysTickDriver);

/// SysTick as a bare 24-bit down-counter at 25 MHz, no interrupt (the
/// benchmark's clock: nothing runs but the code measured).
pub fn free_running(mut syst: SYST) -> SYST {
    syst.disable_interrupt();
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(0x00ff_ffff);
    syst.clear_current();
    syst.enable_counter();
    syst
}

/// The counter of a [`free_running`] SysTick.
pub fn counter() -> u32 {
    SYST::get_current()
}

/// Counts from `start` (a [`counter`] value) to now; spans must be shorter
/// than one wrap (16.7 M counts, 0.67 s).
pub fn elapsed_ticks(start: u32) -> u32 {
    start.wrapping_sub(SYST::get_current()) & 0x00ff_ffff
}
