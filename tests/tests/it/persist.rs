//! Calibration and settings in flash (`cms_core::persist`): a power cut at
//! any byte of a save loses nothing, damage is reported and not used.
//!
//! The flash model behaves like NOR flash as the STM32H743 has it: erase
//! sets a sector to 0xFF, a write can only clear bits, writes and erases are
//! aligned to 32 bytes and 128 KB sectors (scaled down to 4 KB here to keep
//! the test fast; the store only sees `ERASE_SIZE`). A "power cut" after `n`
//! bytes of erase or write work leaves the operation in progress half done
//! (bytes erased or written in address order up to the cut, the byte at the
//! cut scrambled) and fails every later operation, as a dead supply would.

use cms_core::persist::{MAGIC, ReadMark, SCRATCH, SlotState, Slots, Stored, newer};
use cms_core::pipeline::default_detector;
use cms_core::protocol::{Calibration, LASERS, StoreHealth, Trigger};
use embedded_storage::nor_flash::{ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};
use proptest::prelude::*;

const SECTOR: usize = 4096;
const WRITE: usize = 32;

#[derive(Debug)]
struct PowerLost;
impl NorFlashError for PowerLost {
    fn kind(&self) -> NorFlashErrorKind {
        NorFlashErrorKind::Other
    }
}

/// NOR flash in RAM with a budget of bytes of work before the power fails,
/// and optionally one write unit whose ECC fails (STM32H7: reading it is a
/// bus fault, modelled as a panic; erasing its sector clears it).
#[derive(Clone)]
struct RamFlash {
    mem: Vec<u8>,
    budget: Option<usize>,
    dead: bool,
    ecc_bad: Option<usize>,
}

impl RamFlash {
    fn new(sectors: usize) -> RamFlash {
        RamFlash { mem: vec![0xFF; sectors * SECTOR], budget: None, dead: false, ecc_bad: None }
    }
    /// Power fails after `n` more bytes of erase/write work.
    fn cut_after(mut self, n: usize) -> RamFlash {
        self.budget = Some(n);
        self
    }
    /// Power back on: the memory as it was left.
    fn power_on(mut self) -> RamFlash {
        self.budget = None;
        self.dead = false;
        self
    }
    /// Spends one byte of work; false when the power has just failed.
    fn spend(&mut self) -> bool {
        match &mut self.budget {
            Some(0) => {
                self.dead = true;
                false
            }
            Some(n) => {
                *n -= 1;
                true
            }
            None => true,
        }
    }
}

impl ErrorType for RamFlash {
    type Error = PowerLost;
}

impl ReadNorFlash for RamFlash {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), PowerLost> {
        if self.dead {
            return Err(PowerLost);
        }
        let o = offset as usize;
        if let Some(bad) = self.ecc_bad
            && (o..o + bytes.len()).contains(&bad)
        {
            panic!("bus fault: double ECC error reading flash at {bad:#x}");
        }
        bytes.copy_from_slice(&self.mem[o..o + bytes.len()]);
        Ok(())
    }
    fn capacity(&self) -> usize {
        self.mem.len()
    }
}

impl NorFlash for RamFlash {
    const WRITE_SIZE: usize = WRITE;
    const ERASE_SIZE: usize = SECTOR;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), PowerLost> {
        assert!((from as usize).is_multiple_of(SECTOR) && (to as usize).is_multiple_of(SECTOR), "unaligned erase");
        if self.dead {
            return Err(PowerLost);
        }
        if self.ecc_bad.is_some_and(|b| (from as usize..to as usize).contains(&b)) {
            self.ecc_bad = None;
        }
        for a in from as usize..to as usize {
            if !self.spend() {
                self.mem[a] = 0x5A; // an erase cut short leaves undefined bits
                return Err(PowerLost);
            }
            self.mem[a] = 0xFF;
        }
        Ok(())
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), PowerLost> {
        assert!((offset as usize).is_multiple_of(WRITE) && bytes.len().is_multiple_of(WRITE), "unaligned write");
        if self.dead {
            return Err(PowerLost);
        }
        for (i, &b) in bytes.iter().enumerate() {
            let a = offset as usize + i;
            if !self.spend() {
                self.mem[a] &= b ^ 0x0F; // a byte half programmed
                return Err(PowerLost);
            }
            self.mem[a] &= b; // NOR: programming only clears bits
        }
        Ok(())
    }
}

/// Slots at sectors 1 and 3 of a 4-sector flash, one sector each.
fn slots(f: RamFlash) -> Slots<RamFlash> {
    Slots::new(f, [SECTOR as u32, 3 * SECTOR as u32], SECTOR as u32).unwrap()
}

fn calibration(id: u32) -> Calibration {
    Calibration {
        id,
        intrinsics: [1400.0 + id as f32, 1400.0, 376.0, 240.0, 0.0],
        distortion: [0.01, -0.002, 0.0, 0.0, 0.0],
        planes: [[0.0, 0.6691306, 0.7431448, 300.0]; LASERS],
        datum: [0.0, 0.0, -1.0, -200.0],
    }
}

fn stored(id: u32) -> Stored {
    Stored {
        calibration: Some(calibration(id)),
        exposure_us: 100 + id,
        detector: default_detector(),
        trigger: Trigger::Distance { every_um: 5000 },
    }
}

fn load<M: ReadMark>(s: &mut Slots<RamFlash, M>) -> (Option<(Stored, u32)>, StoreHealth, [SlotState; 2]) {
    let mut buf = [0u8; SCRATCH];
    let l = s.load::<Stored>(&mut buf).unwrap();
    (l.value, l.health(), l.slots)
}

#[test]
fn a_new_flash_is_missing_and_saves_alternate_slots() {
    let mut s = slots(RamFlash::new(4));
    assert_eq!(load(&mut s).1, StoreHealth::Missing);
    let mut buf = [0u8; SCRATCH];
    for id in 1..=5 {
        let seq = s.save(&stored(id), &mut buf).unwrap();
        assert_eq!(seq, id);
        let (v, h, states) = load(&mut s);
        assert_eq!(v, Some((stored(id), id)));
        assert_eq!(h, StoreHealth::Ok);
        // The previous record is still in the other slot.
        if id > 1 {
            assert!(states.contains(&SlotState::Valid { seq: id - 1 }), "{states:?}");
        }
    }
    // Sectors 0 and 2 (not ours) were never touched.
    let mem = s.into_inner().mem;
    assert!(mem[..SECTOR].iter().chain(&mem[2 * SECTOR..3 * SECTOR]).all(|&b| b == 0xFF));
}

/// The done-when case: a power cut at every byte of a calibration save
/// leaves the previous calibration loadable (or the new one, once complete).
#[test]
fn a_power_cut_at_any_byte_of_a_save_keeps_the_previous_calibration() {
    let mut base = slots(RamFlash::new(4));
    let mut buf = [0u8; SCRATCH];
    base.save(&stored(1), &mut buf).unwrap();
    base.save(&stored(2), &mut buf).unwrap();
    let base = base.into_inner();
    // The work of one save: the sector erase plus the record.
    let work = SECTOR + 2 * WRITE * 8;
    let mut outcomes = [0usize; 2];
    for cut in 0..work {
        let mut s = slots(base.clone().cut_after(cut));
        let result = s.save(&stored(3), &mut buf);
        let (v, h, _) = load(&mut slots(s.into_inner().power_on()));
        let (value, seq) = v.expect("a record survives every cut");
        if result.is_ok() {
            assert_eq!((value, seq), (stored(3), 3), "cut {cut}: completed save");
            assert_eq!(h, StoreHealth::Ok);
            outcomes[1] += 1;
        } else if cut < SECTOR || seq == 2 {
            // Cut during the erase or the record: the previous record.
            assert_eq!((value, seq), (stored(2), 2), "cut {cut}: the previous record");
            // The damaged slot is reported (an erased-through slot is only
            // "Empty" if the cut came after the erase and before any byte).
            assert!(matches!(h, StoreHealth::Recovered | StoreHealth::Ok), "cut {cut}: {h:?}");
            outcomes[0] += 1;
        } else {
            // Cut in the padding after the record, or during the read-back:
            // the new record is whole (its CRC passed), so it is used.
            assert_eq!((value, seq), (stored(3), 3), "cut {cut}");
            assert!(cut >= SECTOR + 16 + 100, "cut {cut}: a new record this early cannot be whole");
        }
    }
    assert!(outcomes[0] > SECTOR && outcomes[1] > 0, "{outcomes:?}");
}

#[test]
fn a_corrupt_record_is_reported_and_not_used() {
    let mut s = slots(RamFlash::new(4));
    let mut buf = [0u8; SCRATCH];
    s.save(&stored(1), &mut buf).unwrap();
    let mut f = s.into_inner();
    // One flipped bit in the payload of the only record.
    f.mem[SECTOR + 40] ^= 0x04;
    let (v, h, states) = load(&mut slots(f.clone()));
    assert_eq!(v, None);
    assert_eq!(h, StoreHealth::Corrupt);
    assert_eq!(states, [SlotState::Damaged, SlotState::Empty]);
    // A header that claims more than a slot holds is damage, not a panic.
    f.mem[SECTOR + 8..SECTOR + 12].copy_from_slice(&u32::MAX.to_le_bytes());
    assert_eq!(load(&mut slots(f.clone())).1, StoreHealth::Corrupt);
    // The next save goes to a slot and is used again.
    let mut s = slots(f);
    s.save(&stored(4), &mut buf).unwrap();
    let (v, h, _) = load(&mut s);
    assert_eq!(v, Some((stored(4), 1)));
    assert_eq!(h, StoreHealth::Ok, "with no valid record the damaged slot is the one rewritten");
}

/// The head's mark word: it survives the watchdog reset that follows a
/// fault (a `.noinit` RAM word on the board; shared here).
#[derive(Clone, Default)]
struct Mark(std::rc::Rc<std::cell::Cell<Option<usize>>>);
impl ReadMark for Mark {
    fn set(&mut self, slot: Option<usize>) {
        self.0.set(slot);
    }
}

/// STM32H7: a power cut while a save programs slot 1 leaves a word whose
/// ECC fails, and reading it faults the CPU (the model panics; the
/// `catch_unwind` plays the watchdog reset). The first boot faults with the
/// mark on slot 1; the next one, told so, does not read slot 1, uses the
/// previous calibration and reports the damage; the next save rewrites
/// slot 1 and everything is readable again.
#[test]
fn a_slot_whose_read_faults_is_skipped_after_the_reset() {
    let mut s = slots(RamFlash::new(4));
    let mut buf = [0u8; SCRATCH];
    s.save(&stored(1), &mut buf).unwrap();
    // Slot 1's save cut 100 bytes into its record, a word there left bad.
    let mut cut = slots(s.into_inner().cut_after(SECTOR + 100));
    assert!(cut.save(&stored(2), &mut buf).is_err());
    let mut f = cut.into_inner().power_on();
    f.ecc_bad = Some(3 * SECTOR + 96);

    // Boot 1: the read of slot 1 faults with the mark set.
    let mark = Mark::default();
    let mut boot = slots(f.clone()).with_mark(mark.clone(), None);
    let faulted = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| load(&mut boot)));
    assert!(faulted.is_err(), "the damaged word faults");
    assert_eq!(mark.0.get(), Some(1), "the mark names the slot being read");

    // Boot 2: the mark says slot 1; it is not read (no fault), slot 0 is used.
    let mut boot = slots(f).with_mark(mark.clone(), mark.0.take());
    let (v, h, states) = load(&mut boot);
    assert_eq!(v, Some((stored(1), 1)));
    assert_eq!(h, StoreHealth::Recovered);
    assert_eq!(states, [SlotState::Valid { seq: 1 }, SlotState::Damaged]);
    assert_eq!(mark.0.get(), None, "the mark is cleared after every read");

    // The next save erases slot 1 (never the newest valid one) and verifies it.
    assert_eq!(boot.save(&stored(3), &mut buf), Ok(2));
    let (v, h, _) = load(&mut slots(boot.into_inner()));
    assert_eq!(v, Some((stored(3), 2)));
    assert_eq!(h, StoreHealth::Ok);
}

#[test]
fn bad_layouts_are_refused() {
    let f = RamFlash::new(4);
    let bad = [
        ([0, 0], SECTOR as u32),                     // overlap
        ([100, 2 * SECTOR as u32], SECTOR as u32),   // unaligned
        ([0, 3 * SECTOR as u32], 2 * SECTOR as u32), // past the end
        ([0, SECTOR as u32], 0),                     // empty
        ([0, 2 * SECTOR as u32], SECTOR as u32 + 1), // not whole sectors
    ];
    for (base, size) in bad {
        assert!(Slots::new(f.clone(), base, size).is_err(), "{base:?} {size}");
    }
    // The magic is "CMS1" as bytes in flash.
    assert_eq!(MAGIC.to_le_bytes(), *b"CMS1");
}

proptest! {
    /// Sequence numbers compare across the wrap.
    #[test]
    fn newer_is_antisymmetric_across_the_wrap(a in any::<u32>(), d in 1u32..0x7FFF_FFFF) {
        let b = a.wrapping_add(d);
        prop_assert!(newer(b, a));
        prop_assert!(!newer(a, b));
        prop_assert!(!newer(a, a));
    }

    /// Any pattern of random damage to either slot: whatever loads passed
    /// its CRC and is one of the records written, never garbage.
    #[test]
    fn random_damage_never_loads_garbage(hits in proptest::collection::vec((0usize..2, 0usize..160, 0u8..8), 1..6)) {
        let mut s = slots(RamFlash::new(4));
        let mut buf = [0u8; SCRATCH];
        s.save(&stored(1), &mut buf).unwrap();
        s.save(&stored(2), &mut buf).unwrap();
        let mut f = s.into_inner();
        for (slot, byte, bit) in hits {
            f.mem[[SECTOR, 3 * SECTOR][slot] + byte] ^= 1 << bit;
        }
        let (v, _, _) = load(&mut slots(f));
        if let Some((value, seq)) = v {
            prop_assert!(value == stored(seq) && (seq == 1 || seq == 2));
        }
    }
}
