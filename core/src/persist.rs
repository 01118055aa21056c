//! Calibration and settings in flash: two slots, a sequence number and a CRC,
//! so that a power cut at any moment of a write loses nothing.
//!
//! # Design
//! The store owns two erase-aligned regions ("slots") of a NOR flash (any
//! `embedded_storage::nor_flash::NorFlash`: embassy-stm32's `Flash` on the
//! head, a RAM model in the tests). A record is
//!
//! ```text
//! magic "CMS1":u32 ‖ seq:u32 ‖ len:u32 ‖ crc32(magic ‖ seq ‖ len ‖ payload):u32 ‖ payload ‖ 0xFF padding
//! ```
//!
//! all little-endian, padded to the flash's write size; the payload is the
//! postcard encoding of the value. Loading reads both slots and uses the
//! valid one with the newer sequence number (serial-number arithmetic, so the
//! sequence may wrap). Saving erases and writes the *other* slot — never the
//! one holding the newest valid record — and reads it back. A power cut while
//! erasing or writing therefore damages only the slot being written: its CRC
//! fails, and the previous record is still there and still newest.
//!
//! What a load reports ([`StoreHealth`]): both slots erased → `Missing`; a valid
//! record and a damaged slot → `Recovered` (a write was interrupted; the
//! older record is used); no valid record but damage → `Corrupt` (nothing is
//! used). A record that decodes but whose content the head refuses (a
//! calibration that does not triangulate) is the caller's to report.
//!
//! # A read that faults (STM32H7 flash ECC)
//! The H7 programs flash in 256-bit words with ECC. A power cut while a word
//! is being programmed can leave it failing its ECC, and **reading it raises
//! a bus fault** instead of returning bytes: the CRC never gets a say. The
//! head's fault handler parks and the watchdog resets it — and the next boot
//! would read the same word again, forever. So every slot read is bracketed
//! by a [`ReadMark`], a word that survives the reset (not a power cycle):
//! "reading slot i" before, cleared after. A boot that finds the mark set
//! after a fault reset tells the store that slot i is unreadable
//! ([`Slots::with_mark`]); it is then taken as `Damaged` without being read,
//! the other slot is used and the load says `Recovered`, and the next save
//! erases exactly that slot (it never holds the newest valid record) and makes
//! it readable again. Tested with a flash model whose damaged word "faults"
//! (`tests/tests/it/persist.rs`).
//!
//! # Cost
//! One erase (128 KB sector on the STM32H743: about 1–2 s, done while the
//! lasers are off and streaming is stopped) and a write of a few hundred
//! bytes per save; a load reads two headers and one record.

use crate::peak::Config;
use crate::protocol::{CRC, Calibration, StoreHealth, Trigger};
use embedded_storage::nor_flash::{NorFlash, NorFlashError, NorFlashErrorKind};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// The record's first word, "CMS1" little-endian.
pub const MAGIC: u32 = u32::from_le_bytes(*b"CMS1");
/// Header bytes before the payload.
pub const HEADER: usize = 16;
/// Scratch buffer large enough for a [`Stored`] record on any flash whose
/// write size is at most 64 bytes (checked in a test).
pub const SCRATCH: usize = 512;

/// What the head keeps across restarts.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stored {
    /// The calibration in use, if any.
    pub calibration: Option<Calibration>,
    /// Exposure, µs.
    pub exposure_us: u32,
    /// Detector configuration.
    pub detector: Config,
    /// How frames are triggered.
    pub trigger: Trigger,
}

/// Why the store could not be used.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PersistError {
    /// The slots are not erase-aligned, overlap, or do not fit the flash.
    Layout,
    /// The scratch buffer is smaller than the record (or than one write unit).
    BufferTooSmall,
    /// The value does not fit a slot.
    TooLarge,
    /// The flash reported an error.
    Flash(FlashFault),
    /// The record just written did not read back valid.
    Verify,
}

impl core::fmt::Display for PersistError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            PersistError::Layout => f.write_str("flash slots are not erase-aligned, overlap or exceed the flash"),
            PersistError::BufferTooSmall => f.write_str("scratch buffer too small for the record"),
            PersistError::TooLarge => f.write_str("record larger than a flash slot"),
            PersistError::Flash(k) => write!(f, "flash error: {k}"),
            PersistError::Verify => f.write_str("record did not read back valid"),
        }
    }
}

impl core::error::Error for PersistError {}

/// What the flash driver reported (`NorFlashErrorKind`, which has no defmt
/// support).
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlashFault {
    /// Offset or length not aligned.
    NotAligned,
    /// Outside the flash.
    OutOfBounds,
    /// Anything else (programming or erase error, power loss).
    Other,
}

impl core::fmt::Display for FlashFault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            FlashFault::NotAligned => "not aligned",
            FlashFault::OutOfBounds => "out of bounds",
            FlashFault::Other => "program/erase failed",
        })
    }
}

/// What a slot holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SlotState {
    /// Erased (all 0xFF header).
    Empty,
    /// A record that passed its CRC and decoded.
    Valid {
        /// Its sequence number.
        seq: u32,
    },
    /// Anything else: an interrupted erase or write, or worn flash.
    Damaged,
}

/// What [`Slots::load`] found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Loaded<T> {
    /// The newest valid record and its sequence number.
    pub value: Option<(T, u32)>,
    /// Both slots.
    pub slots: [SlotState; 2],
}

impl<T> Loaded<T> {
    /// The verdict for the host and the log.
    pub fn health(&self) -> StoreHealth {
        let damaged = self.slots.contains(&SlotState::Damaged);
        match (&self.value, damaged) {
            (Some(_), false) => StoreHealth::Ok,
            (Some(_), true) => StoreHealth::Recovered,
            (None, true) => StoreHealth::Corrupt,
            (None, false) => StoreHealth::Missing,
        }
    }
}

/// `a` is newer than `b` (sequence numbers wrap).
pub fn newer(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) > 0
}

/// Where a slot read that may fault leaves its trace (module docs): set to
/// `Some(slot)` before the slot's flash is read and to `None` after.
pub trait ReadMark {
    /// Records the slot being read, or that none is.
    fn set(&mut self, slot: Option<usize>);
}

/// No mark: for flash whose reads cannot fault.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NoMark;

impl ReadMark for NoMark {
    fn set(&mut self, _slot: Option<usize>) {}
}

/// Two slots of a NOR flash.
pub struct Slots<F, M = NoMark> {
    flash: F,
    base: [u32; 2],
    size: u32,
    mark: M,
    /// Slots whose read faulted before (module docs): not read until rewritten.
    unreadable: [bool; 2],
}

fn flash_err<E: NorFlashError>(e: E) -> PersistError {
    PersistError::Flash(match e.kind() {
        NorFlashErrorKind::NotAligned => FlashFault::NotAligned,
        NorFlashErrorKind::OutOfBounds => FlashFault::OutOfBounds,
        _ => FlashFault::Other,
    })
}

fn round_up(n: usize, unit: usize) -> usize {
    n.div_ceil(unit) * unit
}

impl<F: NorFlash> Slots<F> {
    /// The slots at `base[0]` and `base[1]` (flash offsets), each `size`
    /// bytes: erase-aligned, non-overlapping, inside the flash.
    pub fn new(flash: F, base: [u32; 2], size: u32) -> Result<Self, PersistError> {
        let e = F::ERASE_SIZE as u32;
        let aligned = |x: u32| x.is_multiple_of(e);
        let fits = |b: u32| b.checked_add(size).is_some_and(|end| end as usize <= flash.capacity());
        let apart = base[0].abs_diff(base[1]) >= size;
        let units = F::WRITE_SIZE.is_multiple_of(F::READ_SIZE) && F::WRITE_SIZE <= SCRATCH;
        if size == 0 || !aligned(size) || !base.iter().all(|&b| aligned(b) && fits(b)) || !apart || !units {
            return Err(PersistError::Layout);
        }
        Ok(Slots { flash, base, size, mark: NoMark, unreadable: [false; 2] })
    }
}

impl<F: NorFlash, M: ReadMark> Slots<F, M> {
    /// The same slots, every read bracketed by `mark`; `faulted`: the slot
    /// whose read the mark says was under way when the head last reset on a
    /// fault (taken as damaged, not read, until a save rewrites it).
    pub fn with_mark<N: ReadMark>(self, mark: N, faulted: Option<usize>) -> Slots<F, N> {
        let mut unreadable = self.unreadable;
        if let Some(i) = faulted.filter(|&i| i < 2) {
            unreadable[i] = true;
        }
        Slots { flash: self.flash, base: self.base, size: self.size, mark, unreadable }
    }

    /// The flash back (for a test's "power cycle").
    pub fn into_inner(self) -> F {
        self.flash
    }

    /// Reads the first `buf.len()` bytes of slot `i`, under the mark.
    fn read_marked(&mut self, i: usize, buf: &mut [u8]) -> Result<(), PersistError> {
        self.mark.set(Some(i));
        let r = self.flash.read(self.base[i], buf).map_err(flash_err);
        self.mark.set(None);
        r
    }

    /// Reads slot `i`'s record into `buf`: its state and, when valid, the
    /// payload's length.
    fn inspect(&mut self, i: usize, buf: &mut [u8]) -> Result<(SlotState, usize), PersistError> {
        let head = round_up(HEADER, F::WRITE_SIZE);
        if buf.len() < head {
            return Err(PersistError::BufferTooSmall);
        }
        if self.unreadable[i] {
            return Ok((SlotState::Damaged, 0));
        }
        self.read_marked(i, &mut buf[..head])?;
        if buf[..HEADER].iter().all(|&b| b == 0xFF) {
            return Ok((SlotState::Empty, 0));
        }
        let word = |k: usize| u32::from_le_bytes([buf[4 * k], buf[4 * k + 1], buf[4 * k + 2], buf[4 * k + 3]]);
        let (magic, seq, len, crc) = (word(0), word(1), word(2) as usize, word(3));
        let total = match HEADER.checked_add(len) {
            Some(t) if magic == MAGIC && t <= self.size as usize => round_up(t, F::WRITE_SIZE),
            _ => return Ok((SlotState::Damaged, 0)),
        };
        if total > buf.len() {
            return Ok((SlotState::Damaged, 0));
        }
        self.read_marked(i, &mut buf[..total])?;
        let mut digest = CRC.digest();
        digest.update(&buf[..12]);
        digest.update(&buf[HEADER..HEADER + len]);
        if digest.finalize() != crc {
            return Ok((SlotState::Damaged, 0));
        }
        Ok((SlotState::Valid { seq }, len))
    }

    fn read_slot<T: DeserializeOwned>(
        &mut self,
        i: usize,
        buf: &mut [u8],
    ) -> Result<(SlotState, Option<T>), PersistError> {
        let (state, len) = self.inspect(i, buf)?;
        if let SlotState::Valid { .. } = state {
            return Ok(match postcard::from_bytes::<T>(&buf[HEADER..HEADER + len]) {
                Ok(v) => (state, Some(v)),
                // A CRC-valid record of another layout: damaged for us.
                Err(_) => (SlotState::Damaged, None),
            });
        }
        Ok((state, None))
    }

    /// The newest valid record, and what each slot holds.
    pub fn load<T: DeserializeOwned>(&mut self, buf: &mut [u8]) -> Result<Loaded<T>, PersistError> {
        let (s0, v0) = self.read_slot::<T>(0, buf)?;
        let (s1, v1) = self.read_slot::<T>(1, buf)?;
        let value = match (s0, v0, s1, v1) {
            (SlotState::Valid { seq: a }, Some(x), SlotState::Valid { seq: b }, Some(y)) => {
                Some(if newer(b, a) { (y, b) } else { (x, a) })
            }
            (SlotState::Valid { seq }, Some(x), _, _) | (_, _, SlotState::Valid { seq }, Some(x)) => Some((x, seq)),
            _ => None,
        };
        Ok(Loaded { value, slots: [s0, s1] })
    }

    /// Writes `value` as the newest record, into the slot that does not hold
    /// the current newest one. Returns its sequence number.
    pub fn save<T: Serialize>(&mut self, value: &T, buf: &mut [u8]) -> Result<u32, PersistError> {
        let mut states = [SlotState::Empty; 2];
        for (i, s) in states.iter_mut().enumerate() {
            *s = self.inspect(i, buf)?.0;
        }
        let (target, seq) = match states {
            [SlotState::Valid { seq: a }, SlotState::Valid { seq: b }] => {
                if newer(b, a) {
                    (0, b.wrapping_add(1))
                } else {
                    (1, a.wrapping_add(1))
                }
            }
            [SlotState::Valid { seq }, _] => (1, seq.wrapping_add(1)),
            [_, SlotState::Valid { seq }] => (0, seq.wrapping_add(1)),
            _ => (0, 1),
        };
        if buf.len() < HEADER {
            return Err(PersistError::BufferTooSmall);
        }
        let len = postcard::to_slice(value, &mut buf[HEADER..]).map_err(|_| PersistError::BufferTooSmall)?.len();
        let total = round_up(HEADER + len, F::WRITE_SIZE);
        if total > self.size as usize {
            return Err(PersistError::TooLarge);
        }
        if total > buf.len() {
            return Err(PersistError::BufferTooSmall);
        }
        buf[0..4].copy_from_slice(&MAGIC.to_le_bytes());
        buf[4..8].copy_from_slice(&seq.to_le_bytes());
        buf[8..12].copy_from_slice(&(len as u32).to_le_bytes());
        let mut digest = CRC.digest();
        digest.update(&buf[..12]);
        digest.update(&buf[HEADER..HEADER + len]);
        buf[12..16].copy_from_slice(&digest.finalize().to_le_bytes());
        buf[HEADER + len..total].fill(0xFF);
        let at = self.base[target];
        self.flash.erase(at, at + self.size).map_err(flash_err)?;
        // Erased: whatever faulted in it is gone.
        self.unreadable[target] = false;
        self.flash.write(at, &buf[..total]).map_err(flash_err)?;
        match self.inspect(target, buf)? {
            (SlotState::Valid { seq: s }, _) if s == seq => Ok(seq),
            _ => Err(PersistError::Verify),
        }
    }
}
