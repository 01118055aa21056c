//! Search windows: the columns of a row where stripes are looked for (the
//! profilers' "active area").
//!
//! A head whose lasers each fall in a known band of columns — set by the
//! host (`protocol::HostMsg::SetWindows`; `cms-host listen --windows-from`
//! derives them from the calibration and the working range) — need not
//! screen the whole row. With
//! [`Windows`] the detector ([`super::Detector::detect_in`]) runs the
//! screen only inside each window (extended by two blocks each side, so a
//! stripe at a window's edge sees real pixels in its box difference, not
//! the replicated edge the row's own ends get), refines the candidates
//! found there on the whole row as usual, and keeps only the stripes whose
//! position lies inside a window.
//!
//! # Noise: once on the full row, not per window
//! The thresholds need the pixel noise and the screen response's σ. They
//! are measured **on the full row**, on the rows that refresh them (the
//! first of a frame and one in [`super::NOISE_ROWS`]), and reused for every
//! window of every row until the next refresh:
//!
//! * The sensor reads the whole row whatever the windows, so the pixels are
//!   there; a 752-px row gives 250 samples (every third triple) and 94
//!   block responses, so the small-sample margin
//!   ([`super::screen::detection_margin_q8`]) stays 1 and the thresholds
//!   are the configured ones.
//! * A 96-px window holds its laser's stripe by construction: a stripe of
//!   σ 2.5 px covers ±3σ ≈ 16 of its pixels, a sixth of the samples, and
//!   every one of them reads high — the median moves up and the threshold
//!   with it. The stripe-free rest of the row is the better noise sample.
//! * Per window, each estimate would cost a median on 94 samples three
//!   times a row instead of one on 250 every 32 rows, and would need the
//!   ×1.14 margin of 94 samples, costing sensitivity.
//! * The union of the windows (288 px, all 286 triples) would cost as much
//!   as the full row's 250 and hold all three stripes.
//!
//! The full-row estimate is the one a full-row search uses, so a window
//! changes only where candidates are sought, never how a stripe is judged.
//!
//! # Tracking
//! A [`Track`] makes the windows follow their lines
//! ([`super::Detector::detect_tracked`]): where the row before found a
//! window's stripe at `p`, the next row's candidate is the brightest pixel
//! of `p ± half_width_px`, and the window is screened only where that finds
//! no stripe (or the pixel is at the track's edge, or there is no track).
//! The lines of a rail move well under a pixel from one row (0.14 mm along
//! the rail) to the next, so the track holds and each window costs a
//! brightest-pixel search of `half_width_px + 1` pixels instead of its
//! screen.
//!
//! # Cost
//! The screen costs about 2.9 instructions per pixel on thumbv7em: three
//! 96-px windows (128 px screened each) cost about a third of a 752-px
//! row's. What a stripe costs is the same as in a full-row search. A track
//! of ±20 px costs well under 100 instructions a window (the brightest of
//! one column in four, then ±3 px) where the screen cost about 500
//! (docs/benchmarks.md).

use crate::fixed::Px;
use heapless::Vec;

/// Most windows per row (one per laser of the head).
pub const MAX_WINDOWS: usize = 3;

/// Narrowest window, px: less than two of the screen's largest blocks is
/// no search.
pub const MIN_WINDOW_PX: u16 = 8;

/// One window: columns `first_px .. first_px + width_px` of the row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ColumnWindow {
    /// First column, px.
    pub first_px: u16,
    /// Width, px.
    pub width_px: u16,
}

impl ColumnWindow {
    /// One past the last column, px.
    pub const fn end_px(self) -> u32 {
        self.first_px as u32 + self.width_px as u32
    }

    /// The window `centre_px ± half_width_px` (clipped at column 0).
    pub fn around(centre_px: u16, half_width_px: u16) -> ColumnWindow {
        let first = centre_px.saturating_sub(half_width_px);
        ColumnWindow { first_px: first, width_px: (centre_px - first).saturating_add(half_width_px) }
    }
}

/// Narrowest and widest half width of a [`Track`], px.
pub const TRACK_HALF_WIDTH_PX: core::ops::RangeInclusive<u16> = 2..=64;

/// Windows that follow their stripes ([`super::Detector::detect_tracked`]):
/// per window, the column where the last row found its stripe, and how far
/// from it the next row looks (the profilers' tracking window). Where the
/// line moves less than `half_width_px` from row to row, each row costs the
/// brightest pixel of `2·half_width_px + 1` columns instead of the
/// window's screen; where it is lost, the window is screened.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Track {
    half_width_px: u16,
    last_px: [Option<u16>; MAX_WINDOWS],
}

impl Track {
    /// A track looking `half_width_px` either side of the last stripe
    /// (within [`TRACK_HALF_WIDTH_PX`]), holding no stripe yet.
    pub fn new(half_width_px: u16) -> Result<Track, WindowError> {
        if !TRACK_HALF_WIDTH_PX.contains(&half_width_px) {
            return Err(WindowError::TrackWidth(half_width_px));
        }
        Ok(Track { half_width_px, last_px: [None; MAX_WINDOWS] })
    }

    /// Forgets every stripe: the next row screens every window.
    pub fn reset(&mut self) {
        self.last_px = [None; MAX_WINDOWS];
    }

    /// How far from the last stripe a row looks, px.
    pub fn half_width_px(&self) -> u16 {
        self.half_width_px
    }

    /// The column of each window's stripe in the last row (in the order of
    /// [`Windows::as_slice`]; `None`: not found, or not yet).
    pub fn last_px(&self) -> &[Option<u16>; MAX_WINDOWS] {
        &self.last_px
    }

    /// After a row: each window's stripe is the strongest of `stripes`
    /// inside it.
    #[inline(always)]
    pub(crate) fn follow(&mut self, windows: &Windows, stripes: &[super::Stripe]) {
        for (w, last) in windows.as_slice().iter().zip(self.last_px.iter_mut()) {
            let (first, end) = (w.first_px as i32, w.end_px() as i32);
            let (mut best, mut strength) = (None, 0);
            for s in stripes {
                // Positions are ≥ 0 and below 2^15 px (a row of `u16` columns).
                let px = s.position.0 >> 16;
                if px >= first && px < end && (best.is_none() || s.strength > strength) {
                    (best, strength) = (Some(px as u16), s.strength);
                }
            }
            *last = best;
        }
    }
}

/// Why a set of windows (or a track) was refused.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WindowError {
    /// No window (a full-row search is [`super::Detector::detect`], not
    /// an empty set of windows).
    Empty,
    /// More than [`MAX_WINDOWS`].
    TooMany(usize),
    /// A window narrower than [`MIN_WINDOW_PX`].
    TooNarrow {
        /// Its first column.
        first_px: u16,
        /// Its width.
        width_px: u16,
    },
    /// A window that ends past the row (`u16` columns).
    PastRow {
        /// Its first column.
        first_px: u16,
        /// Its width.
        width_px: u16,
        /// The row length it was checked against.
        row_px: u16,
    },
    /// A [`Track`] half width outside [`TRACK_HALF_WIDTH_PX`].
    TrackWidth(u16),
}

impl core::fmt::Display for WindowError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            WindowError::Empty => f.write_str("no search window"),
            WindowError::TooMany(n) => write!(f, "{n} search windows, at most {MAX_WINDOWS}"),
            WindowError::TooNarrow { first_px, width_px } => {
                write!(f, "search window at column {first_px} is {width_px} px wide, at least {MIN_WINDOW_PX} needed")
            }
            WindowError::PastRow { first_px, width_px, row_px } => {
                write!(f, "search window of {width_px} px at column {first_px} ends past the {row_px}-px row")
            }
            WindowError::TrackWidth(px) => write!(
                f,
                "tracking half width of {px} px, {}–{} px allowed",
                TRACK_HALF_WIDTH_PX.start(),
                TRACK_HALF_WIDTH_PX.end()
            ),
        }
    }
}

impl core::error::Error for WindowError {}

/// A validated set of search windows, ascending by first column
/// (overlapping windows are allowed: a stripe in two is found once).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Windows {
    list: Vec<ColumnWindow, MAX_WINDOWS>,
}

impl Windows {
    /// Validates `windows` for rows of `row_px` pixels.
    pub fn new(windows: &[ColumnWindow], row_px: u16) -> Result<Windows, WindowError> {
        if windows.is_empty() {
            return Err(WindowError::Empty);
        }
        let mut list: Vec<ColumnWindow, MAX_WINDOWS> = Vec::new();
        for &w in windows {
            if w.width_px < MIN_WINDOW_PX {
                return Err(WindowError::TooNarrow { first_px: w.first_px, width_px: w.width_px });
            }
            if w.end_px() > row_px as u32 {
                return Err(WindowError::PastRow { first_px: w.first_px, width_px: w.width_px, row_px });
            }
            list.push(w).map_err(|_| WindowError::TooMany(windows.len()))?;
        }
        list.sort_unstable_by_key(|w| w.first_px);
        Ok(Windows { list })
    }

    /// The windows, ascending by first column.
    pub fn as_slice(&self) -> &[ColumnWindow] {
        &self.list
    }

    /// Whether the column at `position` lies inside a window.
    pub fn contains(&self, position: Px) -> bool {
        // `first ≤ position < end` in Q16.16 is `first ≤ ⌊position⌋ < end`
        // for a position ≥ 0 (and no window holds a negative one).
        let Ok(px) = u32::try_from(position.floor()) else {
            return false;
        };
        self.list.iter().any(|w| (w.first_px as u32..w.end_px()).contains(&px))
    }

    /// Pixels the windows cover (overlaps counted once).
    pub fn covered_px(&self) -> u32 {
        let mut total = 0u32;
        let mut end = 0u32;
        for w in &self.list {
            let a = (w.first_px as u32).max(end);
            if w.end_px() > a {
                total += w.end_px() - a;
            }
            end = end.max(w.end_px());
        }
        total
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_are_validated_and_sorted() {
        let w = |first_px, width_px| ColumnWindow { first_px, width_px };
        assert_eq!(Windows::new(&[], 752), Err(WindowError::Empty));
        assert_eq!(Windows::new(&[w(0, 7)], 752), Err(WindowError::TooNarrow { first_px: 0, width_px: 7 }));
        assert_eq!(
            Windows::new(&[w(700, 53)], 752),
            Err(WindowError::PastRow { first_px: 700, width_px: 53, row_px: 752 })
        );
        assert_eq!(Windows::new(&[w(0, 8); 4], 752), Err(WindowError::TooMany(4)));
        let ok = Windows::new(&[w(600, 96), w(10, 96), w(50, 96)], 752).unwrap();
        assert_eq!(ok.as_slice(), &[w(10, 96), w(50, 96), w(600, 96)]);
        assert_eq!(ok.covered_px(), 136 + 96);
        assert!(ok.contains(Px::from_int(10)) && !ok.contains(Px::from_int(9)) && !ok.contains(Px::from_int(146)));
        assert!(Windows::new(&[w(656, 96)], 752).is_ok());
        assert_eq!(ColumnWindow::around(20, 48), w(0, 68));
        assert_eq!(ColumnWindow::around(376, 48), w(328, 96));
    }
}
