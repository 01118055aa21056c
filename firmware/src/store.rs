//! Calibration and settings in flash: `cms_core::persist`'s two slots over
//! embassy-stm32's blocking flash driver, in the last two 128 KB sectors of
//! bank 2 (`board::STORE_SLOTS`).
//!
//! A power cut while a word is programmed can leave it failing its ECC, and
//! reading it is a bus fault: the HardFault handler parks with the lasers
//! off and the watchdog resets the head. Every slot read is therefore
//! bracketed by a mark in `.uninit` RAM ([`FlashMark`], `cms_core::persist`'s
//! `ReadMark`), which survives that reset; the next boot, after a watchdog
//! or software reset, finds the slot named there and does not read it again
//! (`Recovered`, the other slot in use) until a save rewrites it. After a
//! power-on reset the RAM holds noise and the mark is ignored.
//!
//! A save erases one sector (the STM32H743 data sheet gives seconds, not
//! milliseconds, for a 128 KB sector) with the CPU stalled on the flash
//! bank, so the independent watchdog's period is stretched to 16 s for the
//! save and put back afterwards. Saves happen only while the head is idle
//! (`Head::take_store_request`), so the lasers are off throughout.

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;

use cms_core::persist::{PersistError, ReadMark, SCRATCH, Slots, Stored};
use cms_core::protocol::StoreHealth;
use embassy_stm32::flash::Blocking;
use embassy_stm32::flash::Flash;
use embassy_stm32::pac;
use embassy_stm32::pac::iwdg::vals::{Key, Pr};

use crate::board;

/// Normal watchdog period: prescaler /32 (1 kHz from the 32 kHz LSI), 500 counts.
pub const WATCHDOG_MS: u16 = 500;

/// The mark's two words: [`MARK_MAGIC`] and the slot being read, or zeros.
#[unsafe(link_section = ".uninit.STORE_MARK")]
static mut MARK: MaybeUninit<[u32; 2]> = MaybeUninit::uninit();
/// "STMK": the mark is set (anything else is no mark, or power-on noise).
const MARK_MAGIC: u32 = u32::from_le_bytes(*b"STMK");

/// The read mark in `.uninit` RAM (module docs).
pub struct FlashMark;

impl ReadMark for FlashMark {
    fn set(&mut self, slot: Option<usize>) {
        let v = slot.map_or([0, 0], |i| [MARK_MAGIC, i as u32]);
        // SAFETY: only the head loop (one task, before and between its own
        // flash reads) touches MARK; a volatile write of plain words to a
        // static in RAM. The barrier makes it land before the flash read
        // that may fault.
        unsafe { addr_of_mut!(MARK).cast::<[u32; 2]>().write_volatile(v) };
        cortex_m::asm::dsb();
    }
}

/// The slot whose read was under way when the head last reset on a fault,
/// if this boot follows a watchdog or software reset; clears the mark and
/// the reset flags.
fn faulted_slot() -> Option<usize> {
    let rsr = pac::RCC.rsr().read();
    let after_fault = !rsr.porrstf() && !rsr.borrstf() && (rsr.iwdg1rstf() || rsr.sftrstf());
    pac::RCC.rsr().modify(|w| w.set_rmvf(true));
    // SAFETY: as in `FlashMark::set`; after a power-on reset the words are
    // noise, which is why they are only believed after a fault reset.
    let v = unsafe { addr_of_mut!(MARK).cast::<[u32; 2]>().read_volatile() };
    FlashMark.set(None);
    (after_fault && v[0] == MARK_MAGIC && v[1] < 2).then_some(v[1] as usize)
}

/// The two slots.
pub struct Store {
    slots: Slots<Flash<'static, Blocking>, FlashMark>,
    /// The slot the mark named at boot (logged by the caller).
    pub faulted: Option<usize>,
}

impl Store {
    /// The slots of this board (call once, at boot: it reads the mark).
    pub fn new(flash: Flash<'static, Blocking>) -> Result<Self, PersistError> {
        let faulted = faulted_slot();
        let slots = Slots::new(flash, board::STORE_SLOTS, board::STORE_SLOT_SIZE)?.with_mark(FlashMark, faulted);
        Ok(Store { slots, faulted })
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
