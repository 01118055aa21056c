//! The trolley's odometer: a quadrature wheel encoder counted by a hardware
//! timer, turned into travelled distance, and the "one frame every N mm"
//! trigger trolleys sample the rail with.
//!
//! # Design
//! * The timer is a free-running 16- or 32-bit up/down counter (STM32 timer
//!   in encoder mode, ×4 quadrature). [`Odometer::update`] takes its raw value
//!   and adds the signed difference to the last one, modulo the counter
//!   width, to a 64-bit count: the count never wraps (2⁶³ counts), and the
//!   timer may wrap as often as it likes provided it is read at least once
//!   per half its range (32 768 counts for a 16-bit timer: 3.3 m of travel at
//!   100 µm per count, 0.2 s at the fastest trolley of 15 m/s).
//! * Distance is `count × nm_per_count / 1000` computed from the exact count
//!   each time, so rounding never accumulates: after a million wraps the
//!   distance is still within 1 µm of the true one.
//! * Direction is the sign of the configured scale (`reverse` flips it when
//!   the encoder is mounted the other way round).
//! * [`DistanceTrigger`] fires once each time the travelled distance crosses
//!   the next multiple of `every_um` from where it was armed, in either
//!   direction; when several multiples are crossed between two calls it fires
//!   once and reports how many were skipped (the host sees the gap in the
//!   odometer; the head counts it as dropped).
//!
//! # Cost
//! A subtraction, a sign extension and one 64-bit multiply and divide per
//! update; nothing per encoder edge (the timer counts those).

/// Why an odometer or trigger configuration was refused.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum OdometerError {
    /// The counter width is not 16 or 32 bits.
    CounterBits(u8),
    /// The scale is zero (nm per count).
    ZeroScale,
    /// The trigger interval is zero.
    ZeroInterval,
}

impl core::fmt::Display for OdometerError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            OdometerError::CounterBits(b) => write!(f, "encoder counter width {b} bits, expected 16 or 32"),
            OdometerError::ZeroScale => f.write_str("encoder scale is 0 nm per count"),
            OdometerError::ZeroInterval => f.write_str("distance trigger interval is 0 um"),
        }
    }
}

impl core::error::Error for OdometerError {}

/// Travelled distance from a wrapping hardware counter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Odometer {
    bits: u8,
    last_raw: u32,
    count: i64,
    nm_per_count: u32,
    reverse: bool,
}

impl Odometer {
    /// An odometer at distance 0 whose counter now reads `raw`.
    ///
    /// `bits` is the counter width (16 or 32), `nm_per_count` the calibrated
    /// travel per quadrature count (wheel circumference / (4 × lines)), and
    /// `reverse` flips the direction.
    pub fn new(bits: u8, raw: u32, nm_per_count: u32, reverse: bool) -> Result<Self, OdometerError> {
        if bits != 16 && bits != 32 {
            return Err(OdometerError::CounterBits(bits));
        }
        if nm_per_count == 0 {
            return Err(OdometerError::ZeroScale);
        }
        Ok(Odometer { bits, last_raw: raw & Self::mask(bits), count: 0, nm_per_count, reverse })
    }

    fn mask(bits: u8) -> u32 {
        if bits == 32 { u32::MAX } else { (1 << bits) - 1 }
    }

    /// Takes a new raw counter value (must be read at least once per half
    /// the counter's range of travel) and returns the distance, µm.
    pub fn update(&mut self, raw: u32) -> i64 {
        let raw = raw & Self::mask(self.bits);
        let delta = raw.wrapping_sub(self.last_raw);
        // Sign-extend the difference modulo 2^bits: the shortest way round.
        let delta = if self.bits == 32 { delta as i32 as i64 } else { delta as u16 as i16 as i64 };
        self.last_raw = raw;
        self.count += if self.reverse { -delta } else { delta };
        self.distance_um()
    }

    /// Counts since construction (signed, in the configured direction).
    pub fn count(&self) -> i64 {
        self.count
    }

    /// Distance since construction, µm (rounded towards −∞).
    pub fn distance_um(&self) -> i64 {
        // |count| < 2^63 / 2^32 for any realistic run (4 × 10^9 m at 1 nm per
        // count) so the product fits i128 trivially and i64 after division.
        ((self.count as i128 * self.nm_per_count as i128).div_euclid(1000)) as i64
    }
}

/// Fires every `every_um` of travel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DistanceTrigger {
    every_um: u32,
    origin_um: i64,
    /// Index of the last interval boundary reached (floor((d − origin) / every)).
    index: i64,
}

impl DistanceTrigger {
    /// Armed at `position_um`: the first frame fires there (index 0).
    pub fn new(every_um: u32, position_um: i64) -> Result<Self, OdometerError> {
        if every_um == 0 {
            return Err(OdometerError::ZeroInterval);
        }
        Ok(DistanceTrigger { every_um, origin_um: position_um, index: 0 })
    }

    /// The interval, µm.
    pub fn every_um(&self) -> u32 {
        self.every_um
    }

    /// The trigger at `position_um`: `Some(skipped)` when a boundary was
    /// crossed since the last call (`skipped` boundaries were passed over
    /// without a frame), `None` otherwise. Either direction of travel.
    pub fn poll(&mut self, position_um: i64) -> Option<u32> {
        let d = position_um - self.origin_um;
        let e = self.every_um as i64;
        // Moving forward a boundary is reached at k·e; moving back, the
        // boundary below is reached when d ≤ (k − 1)·e: floor forward,
        // ceil backward, so jitter around a boundary fires only once.
        let forward = d.div_euclid(e);
        let backward = -((-d).div_euclid(e));
        let new = if forward > self.index {
            forward
        } else if backward < self.index {
            backward
        } else {
            return None;
        };
        let crossed = new.abs_diff(self.index);
        self.index = new;
        Some(crossed.saturating_sub(1).min(u32::MAX as u64) as u32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sixteen_bit_wrap_forward_and_back() {
        let mut o = Odometer::new(16, 65_530, 1000, false).unwrap();
        assert_eq!(o.update(4), 10); // 65530 → 65535 → 0 → 4: +10 counts of 1 µm
        assert_eq!(o.update(65_534), 4);
        assert_eq!(o.count(), 4);
    }

    #[test]
    fn refuses_bad_configuration() {
        assert_eq!(Odometer::new(24, 0, 1, false), Err(OdometerError::CounterBits(24)));
        assert_eq!(Odometer::new(16, 0, 0, false), Err(OdometerError::ZeroScale));
        assert_eq!(DistanceTrigger::new(0, 0), Err(OdometerError::ZeroInterval));
    }

    #[test]
    fn trigger_jitter_at_a_boundary_fires_once() {
        let mut t = DistanceTrigger::new(1000, 0).unwrap();
        assert_eq!(t.poll(999), None);
        assert_eq!(t.poll(1000), Some(0));
        assert_eq!(t.poll(999), None);
        assert_eq!(t.poll(1001), None);
        assert_eq!(t.poll(3500), Some(1));
        assert_eq!(t.poll(2000), Some(0));
    }
}
