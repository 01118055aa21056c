//! The emulated board: its identity, the lasers' stand-in, and the panic
//! handler.
//!
//! QEMU's mps2 boards have no laser enables; [`Lasers`] keeps the mask the
//! head drives in [`LIT`] (what a debugger or a test would inspect), and the
//! panic handler clears it first, as the real head's handler drives its
//! enable pins low before anything else.

use core::sync::atomic::{AtomicU8, Ordering};

use cms_core::pipeline::LaserDriver;

/// The CPU and bus clock of QEMU's mps2 boards (`SYSCLK`), Hz: SysTick and the
/// UART count it.
pub const SYSCLK_HZ: u32 = 25_000_000;

/// The lasers the head has lit (bit k = laser k).
pub static LIT: AtomicU8 = AtomicU8::new(0);

/// The laser driver of the emulated head.
#[derive(Debug, Default)]
pub struct Lasers;

impl LaserDriver for Lasers {
    fn set(&mut self, mask: u8) {
        LIT.store(mask, Ordering::SeqCst);
    }
}

/// Which emulated board runs this image, from the CPUID part number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Board {
    /// `mps2-an386`: Cortex-M4F.
    An386,
    /// `mps2-an500`: Cortex-M7.
    An500,
    /// Another Cortex-M (the image was started on a board it was not made for).
    Other,
}

impl Board {
    /// Reads SCB.CPUID.
    pub fn detect() -> Board {
        // SAFETY: CPUID is a read-only identification register; reading it
        // has no side effects and needs no ownership of the SCB.
        let cpuid = unsafe { (*cortex_m::peripheral::CPUID::PTR).base.read() };
        match (cpuid >> 4) & 0xfff {
            0xc24 => Board::An386,
            0xc27 => Board::An500,
            _ => Board::Other,
        }
    }

    /// The name the head reports in `Hello` (at most 24 bytes).
    pub const fn name(self) -> &'static str {
        match self {
            Board::An386 => "qemu-mps2-an386",
            Board::An500 => "qemu-mps2-an500",
            Board::Other => "qemu-mps2",
        }
    }

    /// The CPU's name.
    pub const fn cpu(self) -> &'static str {
        match self {
            Board::An386 => "cortex-m4f",
            Board::An500 => "cortex-m7",
            Board::Other => "cortex-m",
        }
    }
}

/// Lasers off, the message on the UART (a host's deframer skips it as
/// garbage), then ends the emulation with a failure status when QEMU runs with
/// semihosting (`cms-host` starts it so), otherwise halts.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    LIT.store(0, Ordering::SeqCst);
    let mut w = crate::uart::Writer;
    let _ = core::fmt::Write::write_fmt(&mut w, format_args!("\0panic: {info}\n\0"));
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
