//! A thread-mode executor that sleeps with WFI.
//!
//! embassy's stock Cortex-M executor sleeps with WFE and wakes on SEV; QEMU
//! does not implement WFE as a sleep and spins at 100 % host CPU instead
//! (docs/reference.md §5). This one runs embassy's `raw::Executor` and sleeps with WFI,
//! which QEMU does honour (the vCPU halts until an interrupt). The race
//! between "nothing to do" and "an interrupt just woke a task" is closed by
//! deciding to sleep with interrupts masked: WFI still wakes on a pending
//! interrupt, which is then taken as soon as the mask is lifted.

use core::sync::atomic::{AtomicBool, Ordering};

use embassy_executor::{Spawner, raw};

/// Set by the pender (a task was woken) and cleared before each poll.
static PENDING: AtomicBool = AtomicBool::new(false);

// SAFETY: embassy-executor calls `__pender` (exactly this signature) when a
// task of an executor without a platform feature is woken; there is one
// definition in the program.
#[unsafe(export_name = "__pender")]
fn pender(_context: *mut ()) {
    PENDING.store(true, Ordering::SeqCst);
}

/// The executor.
pub struct Executor {
    inner: raw::Executor,
}

impl Default for Executor {
    fn default() -> Self {
        Self::new()
    }
}

impl Executor {
    /// A new executor.
    pub fn new() -> Self {
        Executor { inner: raw::Executor::new(core::ptr::null_mut()) }
    }

    /// Spawns the tasks `init` asks for, then runs them for ever.
    pub fn run(&'static mut self, init: impl FnOnce(Spawner)) -> ! {
        init(self.inner.spawner());
        loop {
            PENDING.store(false, Ordering::SeqCst);
            // SAFETY: `poll` is called from one context only (thread mode,
            // this loop), never re-entrantly.
            unsafe { self.inner.poll() };
            cortex_m::interrupt::free(|_| {
                if !PENDING.load(Ordering::SeqCst) {
                    cortex_m::asm::wfi();
                }
            });
        }
    }
}
