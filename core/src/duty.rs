//! The lasers' enforced maximum duty cycle.
//!
//! The head strobes its 50 mW lasers only during exposures; this limit caps
//! how much of the time that may add up to, whatever the commands asked for
//! (a long exposure at a high rate, a fast trolley on a distance trigger, a
//! capture after a stream). It bounds the lasers' and drivers' heating and the
//! accessible emission averaged over the eye's time constants.
//!
//! # Rule
//! A token bucket in integer arithmetic: the bucket drains at
//! [`MAX_DUTY_PERMILLE`] µs per 1000 µs of time and each strobe adds its
//! on-time; a strobe is allowed only if it fits under the capacity
//! [`DUTY_BURST_US`]. Hence over **any** interval of length `T` the lasers
//! are on for at most `MAX_DUTY_PERMILLE/1000 · T + DUTY_BURST_US` (a
//! property test checks it on random request sequences), and on average at
//! most `MAX_DUTY_PERMILLE/1000`. A refused strobe means no exposure: the
//! frame is dropped (counted), the lasers stay off.
//!
//! # Cost
//! A multiply and a compare per strobe.

/// Long-run maximum laser duty cycle, per mille (25 %).
pub const MAX_DUTY_PERMILLE: u32 = 250;
/// Largest on-time beyond the long-run rate that a burst may use, µs.
pub const DUTY_BURST_US: u32 = 100_000;

/// The limiter. Times in µs on the head's clock.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DutyLimit {
    permille: u32,
    /// Bucket level, µs × 1000 (exact: drains `permille` per µs).
    level: u64,
    capacity: u64,
    last_us: u64,
}

impl Default for DutyLimit {
    fn default() -> Self {
        DutyLimit::new(MAX_DUTY_PERMILLE, DUTY_BURST_US)
    }
}

impl DutyLimit {
    /// A limit of `permille` (≤ 1000) with bursts of `burst_us`.
    pub const fn new(permille: u32, burst_us: u32) -> Self {
        let permille = if permille > 1000 { 1000 } else { permille };
        DutyLimit { permille, level: 0, capacity: burst_us as u64 * 1000, last_us: 0 }
    }

    /// The long-run limit, per mille.
    pub fn permille(&self) -> u32 {
        self.permille
    }

    fn drain(&mut self, now_us: u64) {
        let dt = now_us.saturating_sub(self.last_us);
        self.level = self.level.saturating_sub(dt.saturating_mul(self.permille as u64));
        self.last_us = self.last_us.max(now_us);
    }

    /// Asks to light the lasers for `on_us` starting at `now_us`; `true`
    /// (and the on-time is booked) if the limit allows it.
    pub fn request(&mut self, now_us: u64, on_us: u32) -> bool {
        self.drain(now_us);
        let need = on_us as u64 * 1000;
        if self.level + need > self.capacity {
            return false;
        }
        self.level += need;
        true
    }

    /// Whether a steady `on_us` every `period_us` stays under the long-run
    /// limit (what `Start` and `SetExposure` check before accepting).
    pub fn sustainable(&self, on_us: u32, period_us: u64) -> bool {
        (on_us as u64) * 1000 <= period_us.saturating_mul(self.permille as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steady_quarter_duty_passes_and_more_is_refused() {
        let mut d = DutyLimit::default();
        // 250 µs every 1000 µs: exactly the limit, for 10 s.
        for k in 0..10_000u64 {
            assert!(d.request(k * 1000, 250), "strobe {k}");
        }
        // 500 µs every 1000 µs: the burst allowance runs out, then refusals.
        let mut d = DutyLimit::default();
        let allowed = (0..10_000u64).filter(|k| d.request(k * 1000, 500)).count();
        assert!(allowed < 5_300 && allowed > 4_900, "{allowed}");
    }
}
