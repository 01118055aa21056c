//! Calibration and settings in flash: `cms_core::persist`'s two slots over
//! embassy-stm32's blocking flash driver, in the last two 128 KB sectors of
//! bank 2 (`board::STORE_SLOTS`).
//!
//! A save erases one sector (the STM32H743 data sheet gives seconds, not
//! milliseconds, for a 128 KB sector) with the CPU stalled on the flash
//! bank, so the independent watchdog's period is stretched to 16 s for the
//! save and put back afterwards. Saves happen only while the head is idle
//! (`Head::take_store_request`), so the lasers are off throughout.

use cms_core::persist::{PersistError, SCRATCH, Slots, Stored};
use cms_core::protocol::StoreHealth;
use embassy_stm32::flash::Blocking;
use embassy_stm32::flash::Flash;
use embassy_stm32::pac;
use embassy_stm32::pac::iwdg::vals::{Key, Pr};

use crate::board;

/// Normal watchdog period: prescaler /32 (1 kHz from the 32 kHz LSI), 500 counts.
pub const WATCHDOG_MS: u16 = 500;

/// The two slots.
pub struct Store {
    slots: Slots<Flash<'static, Blocking>>,
}

impl Store {
    /// The slots of this board.
    pub fn new(flash: Flash<'static, Blocking>) -> Result<Self, PersistError> {
        Ok(Store { slots: Slots::new(flash, board::STORE_SLOTS, board::STORE_SLOT_SIZE)? })
    }

    /// The newest valid record and what the slots held.
    pub fn load(&mut self) -> (Option<Stored>, StoreHealth) {
        let mut buf = [0u8; SCRATCH];
        match self.slots.load::<Stored>(&mut buf) {
            Ok(l) => {
                let health = l.health();
                (l.value.map(|v| v.0), health)
            }
            Err(_) => (None, StoreHealth::Corrupt),
        }
    }

    /// Writes `s` as the newest record (watchdog stretched meanwhile).
    pub fn save(&mut self, s: &Stored) -> Result<u32, PersistError> {
        let mut buf = [0u8; SCRATCH];
        watchdog_period(Pr::DIVIDE_BY256, 2000); // 16 s
        let r = self.slots.save(s, &mut buf);
        watchdog_period(Pr::DIVIDE_BY32, WATCHDOG_MS);
        r
    }
}

/// Reprograms IWDG1's prescaler and reload (allowed at any time after the
/// unlock key) and reloads the counter.
pub fn watchdog_period(pr: Pr, reload: u16) {
    let w = pac::IWDG1;
    w.kr().write(|k| k.set_key(Key::RESET)); // reload first: the old period restarts
    w.kr().write(|k| k.set_key(Key::ENABLE));
    while w.sr().read().pvu() || w.sr().read().rvu() {}
    w.pr().write(|p| p.set_pr(pr));
    w.rlr().write(|r| r.set_rl(reload));
    while w.sr().read().pvu() || w.sr().read().rvu() {}
    w.kr().write(|k| k.set_key(Key::RESET));
}
