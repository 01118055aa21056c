//! UART0 of the mps2 boards: an ARM CMSDK APB UART (Cortex-M System Design
//! Kit, ARM DDI 0479) at 0x4000_4000, receive interrupt IRQ 0. QEMU connects
//! it to its first `-serial` backend (a pseudo-terminal for `cms-host`).
//!
//! * Transmit is polled: a byte is written when `STATE.TXFULL` is clear.
//!   QEMU passes each byte on at once (it does not model the baud rate) and
//!   holds `TXFULL` while the pty is full, so nothing is lost and the head
//!   simply waits for a slow reader — as the real head's DMA would.
//! * Receive is interrupt-driven: the UART holds one byte, so the handler
//!   moves it into a 1 KB ring buffer and wakes the task waiting in
//!   [`readable`]. While the ring is full the handler leaves the byte in the
//!   UART, and QEMU keeps further bytes in the pty (it offers a byte only
//!   when `RXFULL` is clear): flow control, no loss.
//!
//! Cost: one volatile store per transmitted byte (plus QEMU's exit to its
//! device model); one interrupt per received byte.

use core::cell::RefCell;
use core::future::poll_fn;
use core::task::Poll;

use critical_section::Mutex;
use embassy_sync::waitqueue::AtomicWaker;
use heapless::Deque;

/// Base address of UART0.
const BASE: usize = 0x4000_4000;
/// Register offsets.
const DATA: usize = 0x00;
const STATE: usize = 0x04;
const CTRL: usize = 0x08;
const INTCLEAR: usize = 0x0c;
const BAUDDIV: usize = 0x10;
/// `STATE` bits.
const STATE_TXFULL: u32 = 1 << 0;
const STATE_RXFULL: u32 = 1 << 1;
/// `CTRL` bits.
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;
const CTRL_RX_INT_EN: u32 = 1 << 3;
/// `INTSTATUS` / `INTCLEAR` bit of the receive interrupt.
const INT_RX: u32 = 1 << 1;
/// NVIC line of UART0's receive interrupt on mps2-an385/386/500.
pub const RX_IRQ: u16 = 0;

/// Bytes received and not yet read.
static RX: Mutex<RefCell<Deque<u8, 1024>>> = Mutex::new(RefCell::new(Deque::new()));
static RX_WAKER: AtomicWaker = AtomicWaker::new();

fn read_reg(off: usize) -> u32 {
    // SAFETY: BASE + off is one of UART0's documented 32-bit registers,
    // always mapped on the mps2 boards; reading it has no side effect on
    // memory this program owns.
    unsafe { core::ptr::read_volatile((BASE + off) as *const u32) }
}

fn write_reg(off: usize, v: u32) {
    // SAFETY: as in `read_reg`; the UART is this module's alone.
    unsafe { core::ptr::write_volatile((BASE + off) as *mut u32, v) }
}

/// An NVIC interrupt number.
#[derive(Clone, Copy)]
struct Irq(u16);

// SAFETY: `number` returns the IRQ's fixed line number.
unsafe impl cortex_m::interrupt::InterruptNumber for Irq {
    fn number(self) -> u16 {
        self.0
    }
}

/// Enables the UART at `baud` (QEMU ignores the rate, a terminal sees it) with
/// the receive interrupt.
pub fn init(pclk_hz: u32, baud: u32) {
    write_reg(BAUDDIV, (pclk_hz / baud).max(16));
    write_reg(CTRL, CTRL_TX_EN | CTRL_RX_EN | CTRL_RX_INT_EN);
    // SAFETY: the handler (`uart0_rx`) only touches the ring buffer through
    // its critical-section mutex and the atomic waker.
    unsafe { cortex_m::peripheral::NVIC::unmask(Irq(RX_IRQ)) };
}

/// Writes `bytes`, waiting for room.
pub fn write_all(bytes: &[u8]) {
    for &b in bytes {
        while read_reg(STATE) & STATE_TXFULL != 0 {}
        write_reg(DATA, b as u32);
    }
}

/// `core::fmt::Write` on the UART (for text: the benchmark, the panic handler).
pub struct Writer;

impl core::fmt::Write for Writer {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        write_all(s.as_bytes());
        Ok(())
    }
}

/// Moves received bytes into `buf`; returns how many.
pub fn read(buf: &mut [u8]) -> usize {
    let n = critical_section::with(|cs| {
        let mut rx = RX.borrow_ref_mut(cs);
        let mut n = 0;
        while n < buf.len()
            && let Some(b) = rx.pop_front()
        {
            buf[n] = b;
            n += 1;
        }
        n
    });
    // The handler may have left a byte in the UART while the ring was full.
    if n > 0 {
        cortex_m::peripheral::NVIC::pend(Irq(RX_IRQ));
    }
    n
}

/// Waits until at least one received byte can be read.
pub async fn readable() {
    poll_fn(|cx| {
        RX_WAKER.register(cx.waker());
        if critical_section::with(|cs| RX.borrow_ref(cs).is_empty()) { Poll::Pending } else { Poll::Ready(()) }
    })
    .await
}

/// UART0 receive interrupt (bound in [`crate::vectors`]).
pub extern "C" fn uart0_rx() {
    write_reg(INTCLEAR, INT_RX);
    critical_section::with(|cs| {
        let mut rx = RX.borrow_ref_mut(cs);
        while !rx.is_full() && read_reg(STATE) & STATE_RXFULL != 0 {
            let _ = rx.push_back(read_reg(DATA) as u8);
        }
    });
    RX_WAKER.wake();
}
