//! Laser-stripe detection in one image row.
//!
//! A row of 8–16-bit pixels goes in; up to `N` stripes come out, each with a
//! sub-pixel position ([`Px`], 1/65536 px), a strength (peak height above the
//! background, counts), a width (the stripe's Gaussian σ, px) and [`Flags`].
//!
//! # Pipeline
//! Every method shares the front end, so a comparison between methods is a
//! comparison of sub-pixel estimators, not of detection luck. It is built
//! for the sensor's rate (16 667 instructions per 752-px row at 28 800
//! rows/s and 480 MHz): the only work over every pixel is the screen; the
//! rest is local to a candidate.
//!
//! 1. **Noise, per frame** ([`Detector::refresh_noise`], and every
//!    [`NOISE_ROWS`] rows): a robust pixel-noise σ (the median absolute
//!    second difference, read straight from the row: [`screen::pixel_noise_q8`],
//!    [`median`]) and the robust σ of the screen's response. Noise and fixed
//!    pattern are stationary within a frame, and a median on every row would
//!    add about a fifth to the detector's cost.
//! 2. **Screen** ([`screen`]): block sums at the stripe's scale (one load and
//!    one add per pixel, from the sensor's `u8`/`u16` row, no copy) and a
//!    difference of boxes over them; candidates are its local maxima above a
//!    constant-false-alarm threshold (0.6 × the detection threshold × its
//!    robust σ, or the absolute floor).
//! 3. **Window** ([`coarse`]): per candidate, the pixels the estimators can
//!    read are copied (values above saturation clamped) and, in the same
//!    pass, screened for hot and stuck pixels — single pixels and pairs at
//!    any level up to full scale, repaired when no Gaussian of the minimum
//!    width could be that peaked ([`coarse::repair_spikes`]). A stripe wider
//!    than the first window asks for a wider one.
//! 4. **Detection** at the candidate's brightest pixel (the multi-scale
//!    test of `cwt::confirm`: scale and position by climbing, response
//!    above `threshold ×` its noise, width in range), then the chosen
//!    [`Method`]'s sub-pixel estimate. Work per row is O(n) for the screen
//!    plus O(candidates × (window + scales × kernel)).
//! 5. **Selection**: minimum separation, then strongest / first / last / all,
//!    output in ascending position.
//!
//! Saturated stripes (a run of pixels at the saturation level) are one stripe
//! whatever the method: centred on the run, refined by the interpolated
//! crossings of the half-level on both flanks, and flagged — when their width
//! and height say they are stripes; a stuck pixel or pair at full scale is
//! repaired before it can be taken for one.

mod brightest;
mod centroid;
pub mod coarse;
mod config;
pub mod cwt;
pub mod kernels;
pub mod median;
pub mod paper;
mod plan;
mod repaired;
mod saturated;
pub mod screen;
mod select;
pub mod subpixel;
pub mod window;

use crate::fixed::{Px, Q24_8};
use brightest::{argmax_raw, brightest_of_track};
pub use config::{Config, Error, Flags, Method, RowStats, Select, Stripe, Stripes};
use heapless::Vec;
pub(crate) use plan::Plan;
use select::select;
pub use window::{ColumnWindow, Track, WindowError, Windows};

/// Most candidates refined per row (the strongest are kept).
pub const MAX_CANDIDATES: usize = 32;
/// Shortest row that can hold a stripe (shorter rows give no stripe).
pub const MIN_ROW: usize = 5;

/// A pixel type the detector reads (8- or 16-bit containers).
pub trait Pixel: Copy {
    /// The pixel's value.
    fn value(self) -> i32;

    /// The sum of four pixels that are all below 2^15 (the screen's block
    /// sums on rows of up to 15 bits; any sum the type allows otherwise).
    #[inline(always)]
    fn sum4_narrow(q: &[Self; 4]) -> i32 {
        (q[0].value() + q[1].value()) + (q[2].value() + q[3].value())
    }
}
/// A value the estimators read: a pixel of the sensor's row (read in
/// place where nothing in a candidate's window needs repair or clamping)
/// or of the detector's `i32` copy of the window.
pub trait Sample: Copy {
    /// The value.
    fn get(self) -> i32;

    /// The value read as an `i16` (the same where it is below 2^15, as
    /// every sample is on the detector's 32-bit paths: `Plan` checks the
    /// saturation level, and no sample the estimators read is above it).
    #[inline(always)]
    fn get16(self) -> i32 {
        self.get() as i16 as i32
    }

    /// Two samples below 2^16 as one word, the first in the low half (for
    /// the two-taps-a-word paths; on a row of `u16` pixels one load).
    #[inline(always)]
    fn word(pair: &[Self; 2]) -> u32 {
        (pair[0].get() as u32 & 0xFFFF) | ((pair[1].get() as u32) << 16)
    }
}
impl<P: Pixel> Sample for P {
    #[inline(always)]
    fn get(self) -> i32 {
        self.value()
    }

    #[inline(always)]
    fn word(pair: &[P; 2]) -> u32 {
        // The pixels are below 2^16: no mask (which would keep the two
        // halfword loads from becoming one word load).
        (pair[0].value() as u32) | ((pair[1].value() as u32) << 16)
    }
}
impl Sample for i32 {
    #[inline(always)]
    fn get(self) -> i32 {
        self
    }
}
impl Pixel for u8 {
    fn value(self) -> i32 {
        self as i32
    }
}
impl Pixel for u16 {
    fn value(self) -> i32 {
        self as i32
    }

    /// Two pixels per 32-bit word: the two words added lane by lane (no
    /// carry between the lanes while each pixel is below 2^15), then the
    /// lanes: two loads and three operations instead of four and three.
    #[inline(always)]
    fn sum4_narrow(q: &[u16; 4]) -> i32 {
        let lo = u32::from(q[0]) | (u32::from(q[1]) << 16);
        let hi = u32::from(q[2]) | (u32::from(q[3]) << 16);
        let s = lo.wrapping_add(hi);
        ((s & 0xffff) + (s >> 16)) as i32
    }
}

/// A candidate from the coarse pass.
#[derive(Clone, Copy, Debug)]
pub struct Candidate {
    /// Pixel index of the coarse response's local maximum.
    pub pos: usize,
    /// The coarse response there.
    pub resp: i32,
}

/// Read-only view of one candidate's window, handed to the estimators.
///
/// The window is a copy of the row around the candidate (hot and stuck
/// pixels repaired) at row offset `off`; it reaches further than any
/// estimator reads ([`Plan::reach_px`]), so within it every estimator sees
/// what it would see in the whole row, except where the window ends at the
/// row's own ends (edges replicate there, as in the whole row).
pub(crate) struct RowView<'a, S = i32> {
    /// The window (hot pixels repaired): the detector's copy, or the row
    /// itself where the copy would equal it ([`coarse::window_is_clean`]).
    pub x: &'a [S],
    /// The window low-pass filtered by the coarse box cascade (only for the
    /// methods that use it; empty otherwise).
    pub g: &'a [i32],
    pub cfg: &'a Config,
    pub plan: &'a Plan,
    /// Robust pixel-noise σ, counts × 256.
    pub noise_q8: i32,
    /// Row index of `x[0]`.
    pub off: usize,
    /// Length of the whole row.
    pub row_len: usize,
}

impl<S> RowView<'_, S> {
    /// Whether `reach` pixels either side of window index `c` run past the
    /// row's (not the window's) ends.
    pub fn clipped(&self, c: usize, reach: usize) -> bool {
        c + self.off < reach || c + self.off + reach >= self.row_len
    }

    /// Whether the window holds `reach` pixels either side of `c`, or ends
    /// where the row does on a side where it does not.
    pub fn fits(&self, c: usize, reach: usize) -> bool {
        (c >= reach || self.off == 0) && (c + reach < self.x.len() || self.off + self.x.len() == self.row_len)
    }
}

/// Rows between two refreshes of the noise estimates (pixel noise and the
/// screen's σ): they are stationary within a frame (the MT9V034's global
/// shutter exposes every row of a frame at once), so measuring them on one
/// row in 256 (and on the first row after [`Detector::refresh_noise`],
/// which the sensor head calls at every frame) costs a 256th of a refresh
/// (about 18 000 instructions on thumbv7em: two medians over the row and
/// the screen's block responses), about 70 a row (one row in 128 cost
/// about 145, one in 64 about 290). A 480-row frame refreshes twice; a
/// caller that never calls `refresh_noise` still follows a change of
/// exposure within 256 rows.
pub const NOISE_ROWS: u16 = 256;

/// The first window's reach either side of its candidate under the
/// default scales (`Plan::typ_reach_px`), px: its spike screen is compiled
/// for that length.
const CENTRED_REACH_PX: usize = 18;

/// The screen's threshold as a fraction of the detection threshold, Q8
/// (0.6): the screen only nominates; the multi-scale test at the candidate
/// decides, at the full threshold.
const SCREEN_FRACTION_Q8: i64 = 154;

/// The laser-stripe detector: configuration validated once, buffers for
/// windows of up to `W` pixels (4 × `W` × 4 bytes), and the noise
/// estimates carried from row to row.
pub struct Detector<const W: usize> {
    cfg: Config,
    plan: Plan,
    x: [i32; W],
    g: [i32; W],
    r: [i32; W],
    s: [i32; W],
    /// Robust pixel-noise σ, counts × 256 (refreshed every [`NOISE_ROWS`]).
    noise_q8: i32,
    /// The detection thresholds' factor on both σ for the number of
    /// samples they were measured on, Q8 ([`screen::detection_margin_q8`]).
    margin_q8: i32,
    /// What the thresholds use, set with the estimates (not per row): the
    /// pixel noise with its margin, counts × 256, and the screen's
    /// threshold, counts.
    detect_noise_q8: i32,
    screen_threshold: i32,
    /// The spike screen's first test for `detect_noise_q8`
    /// ([`coarse::spike_screen_level`]), counts.
    spike_level: i32,
    /// Rows until the next refresh (0: the next row refreshes).
    refresh_in: u16,
    /// Row length the estimates were made on.
    noise_len: usize,
    stats: RowStats,
}

impl<const W: usize> Detector<W> {
    /// Validates `cfg` and builds the detector.
    pub fn new(cfg: Config) -> Result<Self, Error> {
        let plan = Plan::new(&cfg)?;
        Ok(Detector {
            cfg,
            plan,
            x: [0; W],
            g: [0; W],
            r: [0; W],
            s: [0; W],
            noise_q8: 0,
            margin_q8: 256,
            detect_noise_q8: 0,
            screen_threshold: 1,
            spike_level: 1,
            refresh_in: 0,
            noise_len: 0,
            stats: RowStats::default(),
        })
    }

    /// The configuration in force.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// What the front end saw in the last row.
    pub fn stats(&self) -> RowStats {
        self.stats
    }

    /// Makes the next row measure the noise afresh (a new frame, a new
    /// exposure): the estimates otherwise last [`NOISE_ROWS`] rows.
    pub fn refresh_noise(&mut self) {
        self.refresh_in = 0;
    }

    /// Finds the stripes of `row` into `out` (cleared first), ascending position.
    pub fn detect<P: Pixel, const N: usize>(&mut self, row: &[P], out: &mut Stripes<N>) -> Result<(), Error> {
        self.detect_spans(row, None, out)
    }

    /// As [`Detector::detect`], but screening only the columns of
    /// `windows` ([`window`]): the noise is still measured on the full row
    /// (on the rows that refresh it), a candidate is refined on the full
    /// row, and only stripes positioned inside a window are kept. Windows
    /// past the row's end are clipped to it.
    pub fn detect_in<P: Pixel, const N: usize>(
        &mut self,
        row: &[P],
        windows: &Windows,
        out: &mut Stripes<N>,
    ) -> Result<(), Error> {
        self.detect_spans(row, Some(windows), out)
    }

    /// As [`Detector::detect_in`], with windows that follow their stripes
    /// ([`Track`]): in a window whose stripe the last row found at column
    /// `p`, the candidate is the brightest pixel of `p ± half_width_px`
    /// (within the window), refined as any candidate; where that pixel is
    /// at the track's edge (the stripe may have moved beyond it), or the
    /// candidate is no stripe in the window, or the window has no track
    /// yet, the window is screened as by [`Detector::detect_in`]. Afterwards each window's
    /// track is the strongest stripe kept inside it (none: the next row
    /// screens the window). A stripe of a window that the track does not
    /// follow (a second one, a reflection) is not sought while the track
    /// holds. Call [`Track::reset`] where the stripes may have jumped (a
    /// new frame, other lasers lit).
    #[inline(always)]
    pub fn detect_tracked<P: Pixel, const N: usize>(
        &mut self,
        row: &[P],
        windows: &Windows,
        track: &mut Track,
        out: &mut Stripes<N>,
    ) -> Result<(), Error> {
        if self.cfg.method == Method::Centroid {
            self.detect_tracked_centroid(row, windows, track, out)
        } else {
            self.detect_tracked_as::<P, N, false>(row, windows, track, out)
        }
    }

    /// [`Detector::detect_tracked`] for the centroid (out of line).
    #[inline(never)]
    fn detect_tracked_centroid<P: Pixel, const N: usize>(
        &mut self,
        row: &[P],
        windows: &Windows,
        track: &mut Track,
        out: &mut Stripes<N>,
    ) -> Result<(), Error> {
        self.detect_tracked_as::<P, N, true>(row, windows, track, out)
    }

    /// [`Detector::detect_tracked`], the centroid's (`CENTROID`) or any
    /// other method's: each compiled on its own, so that the default
    /// method's loop holds nothing of the centroid's.
    fn detect_tracked_as<P: Pixel, const N: usize, const CENTROID: bool>(
        &mut self,
        row: &[P],
        windows: &Windows,
        track: &mut Track,
        out: &mut Stripes<N>,
    ) -> Result<(), Error> {
        if !self.begin(row.len(), out)? {
            return Ok(());
        }
        let n = row.len();
        let lb = self.plan.block_log2;
        if !screen::screens(n, lb) {
            track.reset();
            return self.detect_spans_as::<P, N, CENTROID>(row, Some(windows), out);
        }
        self.refresh_if_due(row);
        let mut found: Vec<Stripe, MAX_CANDIDATES> = Vec::new();
        let mut runs_used: Vec<(usize, usize), MAX_CANDIDATES> = Vec::new();
        let half = track.half_width_px() as usize;
        let mut cands: Vec<Candidate, MAX_CANDIDATES> = Vec::new();
        let mut count = 0u16;
        for (w, last) in windows.as_slice().iter().zip(track.last_px()) {
            let (first, end) = (w.first_px as usize, (w.end_px() as usize).min(n));
            if first >= end {
                continue;
            }
            let before = found.len();
            if let Some(p) = *last {
                let (a, b) = ((p as usize).saturating_sub(half).max(first), (p as usize + half + 1).min(end));
                // The brightest pixel at the track's edge (not the window's):
                // the stripe may lie beyond it, so the window is screened.
                let bright = if a < b { brightest_of_track(&row[a..b]) + a } else { a };
                let edge = (bright == a && a > first) || (bright + 1 == b && b < end);
                if a < b && !edge {
                    count += 1;
                    self.candidate::<P, CENTROID>(
                        row,
                        Some((bright, bright)),
                        Some(windows),
                        &mut found,
                        &mut runs_used,
                    );
                }
            }
            let in_window = |s: &Stripe| (first..end).contains(&((s.position.0 >> 16) as usize));
            if !found[before..].iter().any(in_window) {
                window_candidates(
                    row,
                    core::slice::from_ref(w),
                    lb,
                    self.cfg.bits <= 15,
                    self.screen_threshold,
                    &mut cands,
                );
                count += cands.len() as u16;
                for c in &cands {
                    let bright = self.brightest_near(row, c.pos);
                    self.candidate::<P, CENTROID>(
                        row,
                        Some((c.pos, bright)),
                        Some(windows),
                        &mut found,
                        &mut runs_used,
                    );
                }
            }
        }
        self.stats.candidates = count;
        select(&mut found, &self.cfg, out);
        track.follow(windows, out);
        Ok(())
    }

    /// Clears `out` and the statistics for a row of `n` pixels; whether
    /// there is anything to look for (a row too long for the buffers is an
    /// error, one too short or no room for a stripe gives none).
    fn begin<const N: usize>(&mut self, n: usize, out: &mut Stripes<N>) -> Result<bool, Error> {
        out.clear();
        self.stats = RowStats::default();
        if n > W {
            return Err(Error::RowTooLong { len: n, max: W });
        }
        Ok(n >= MIN_ROW && N > 0)
    }

    /// Measures the noise afresh on the rows that refresh it (the first
    /// after [`Detector::refresh_noise`], one in [`NOISE_ROWS`], a new row
    /// length); whether the row is long enough to screen.
    fn refresh_if_due<P: Pixel>(&mut self, row: &[P]) -> bool {
        let n = row.len();
        let sat = self.cfg.saturation as i32;
        let lb = self.plan.block_log2;
        let screened = screen::screens(n, lb);
        if self.refresh_in == 0 || self.noise_len != n {
            self.noise_q8 = screen::pixel_noise_q8(row, sat, &mut self.s[..n]).to_bits();
            // Robust σ of the screen's block response, counts × 256.
            let screen_sigma_q8 = if screened {
                let m = screen::responses(row, lb, &mut self.s[..n]);
                // A short row has few blocks, and its stripes' responses can
                // be most of them: the median is then the stripes', not the
                // noise's. So at most twice what white noise of the pixels'
                // σ gives (`R` sums 4B pixels of weight ±1: σ·√(4B)); fixed
                // pattern that the difference of boxes passes stays in.
                let white_q8 = (self.noise_q8 as i64 * self.plan.screen_white_q8) >> 8;
                (screen::sigma_q8(&mut self.s[..m]).to_bits() as i64).min(2 * white_q8).clamp(0, i32::MAX as i64) as i32
            } else {
                0
            };
            if self.noise_len != n {
                // It depends on the row's length only (a square root and a
                // division in software on the M7: once per length).
                self.margin_q8 = screen::detection_margin_q8(screen::noise_samples(n)).to_bits();
            }
            // What the thresholds use: the estimates with their
            // small-sample margin (the statistics report the estimate itself).
            let margin = |q8: i32| ((q8 as i64 * self.margin_q8 as i64) >> 8).min(i32::MAX as i64) as i32;
            self.detect_noise_q8 = margin(self.noise_q8);
            self.spike_level = coarse::spike_screen_level(Q24_8(self.detect_noise_q8));
            let thr_noise =
                (margin(screen_sigma_q8) as i64 * self.cfg.threshold_sigma_q8 as i64 * SCREEN_FRACTION_Q8) >> 24;
            let thr_abs = self.cfg.min_amplitude as i64 * self.plan.smin_floor_px as i64;
            self.screen_threshold = thr_noise.max(thr_abs).max(1).min(i32::MAX as i64) as i32;
            self.refresh_in = NOISE_ROWS;
            self.noise_len = n;
        }
        self.refresh_in -= 1;
        self.stats.noise_q8 = Q24_8(self.noise_q8);
        screened
    }

    /// Whether the window `w` can be read in place, its candidate at `top`
    /// ([`coarse::window_is_clean_at`]); a window of [`CENTRED_REACH_PX`]
    /// either side of its candidate, the default scales' first window, by
    /// the screen sized for it ([`coarse::window_is_clean_centred`]).
    #[inline(always)]
    fn window_is_clean<P: Pixel>(w: &[P], sat: i32, level: i32, top: usize) -> bool {
        if top == CENTRED_REACH_PX && w.len() == 2 * CENTRED_REACH_PX + 1 {
            coarse::window_is_clean_centred::<P, CENTRED_REACH_PX>(w, sat, level)
        } else {
            coarse::window_is_clean_at(w, sat, level, top)
        }
    }

    /// The brightest pixel of the raw row where the screen responded at
    /// `pos`: its stripe peaks within the response's centre window, ±B of
    /// the block boundary (not less: a stuck pixel on a stripe's flank pulls
    /// the screen's candidate towards itself).
    #[inline(always)]
    fn brightest_near<P: Pixel>(&self, row: &[P], pos: usize) -> usize {
        let near = (1usize << self.plan.block_log2) + 1;
        let (a0, b0) = (pos.saturating_sub(near), (pos + near).min(row.len() - 1));
        argmax_raw(&row[a0..=b0]) + a0
    }

    #[inline(always)]
    fn detect_spans<P: Pixel, const N: usize>(
        &mut self,
        row: &[P],
        windows: Option<&Windows>,
        out: &mut Stripes<N>,
    ) -> Result<(), Error> {
        if self.cfg.method == Method::Centroid {
            self.detect_spans_centroid(row, windows, out)
        } else {
            self.detect_spans_as::<P, N, false>(row, windows, out)
        }
    }

    /// [`Detector::detect_spans_as`] for the centroid (out of line).
    #[inline(never)]
    fn detect_spans_centroid<P: Pixel, const N: usize>(
        &mut self,
        row: &[P],
        windows: Option<&Windows>,
        out: &mut Stripes<N>,
    ) -> Result<(), Error> {
        self.detect_spans_as::<P, N, true>(row, windows, out)
    }

    /// The full-row and the windowed search, the centroid's (`CENTROID`)
    /// or any other method's (as [`Detector::detect_tracked_as`]).
    fn detect_spans_as<P: Pixel, const N: usize, const CENTROID: bool>(
        &mut self,
        row: &[P],
        windows: Option<&Windows>,
        out: &mut Stripes<N>,
    ) -> Result<(), Error> {
        if !self.begin(row.len(), out)? {
            return Ok(());
        }
        let n = row.len();
        let lb = self.plan.block_log2;
        let screened = self.refresh_if_due(row);
        let narrow = self.cfg.bits <= 15;
        let mut cands: Vec<Candidate, MAX_CANDIDATES> = Vec::new();
        if screened {
            let threshold = self.screen_threshold;
            match windows {
                None => screen::candidates(row, lb, narrow, threshold, &mut cands),
                Some(ws) => window_candidates(row, ws.as_slice(), lb, narrow, threshold, &mut cands),
            }
        } else {
            // Too short to screen: the whole row is one candidate.
            let _ = cands.push(Candidate { pos: n / 2, resp: 0 });
        }
        self.stats.candidates = cands.len() as u16;
        let mut found: Vec<Stripe, MAX_CANDIDATES> = Vec::new();
        let mut runs_used: Vec<(usize, usize), MAX_CANDIDATES> = Vec::new();
        for c in &cands {
            if screened {
                let bright = self.brightest_near(row, c.pos);
                self.candidate::<P, CENTROID>(row, Some((c.pos, bright)), windows, &mut found, &mut runs_used);
            } else {
                self.candidate::<P, CENTROID>(row, None, windows, &mut found, &mut runs_used);
            }
        }
        select(&mut found, &self.cfg, out);
        Ok(())
    }

    /// One candidate, `at` = its position from the screen and the
    /// brightest pixel near it (`None`: the whole row, too short to
    /// screen): refined, and its stripe added to `found` if it is one
    /// (within the width limits or saturated, and inside a window if there
    /// are windows). `CENTROID`: the method is the centroid.
    #[inline(always)]
    fn candidate<P: Pixel, const CENTROID: bool>(
        &mut self,
        row: &[P],
        at: Option<(usize, usize)>,
        windows: Option<&Windows>,
        found: &mut Vec<Stripe, MAX_CANDIDATES>,
        runs_used: &mut Vec<(usize, usize), MAX_CANDIDATES>,
    ) {
        let n = row.len();
        let sat = self.cfg.saturation as i32;
        let screened = at.is_some();
        let (pos, bright) = at.unwrap_or((n / 2, n / 2));
        let lb = self.plan.block_log2;
        let near = (1usize << lb) + 1;
        let (a0, b0) = (pos.saturating_sub(near), (pos + near).min(n - 1));
        let noise_q8 = self.detect_noise_q8;
        let in_place = CENTROID || self.cfg.method == Method::Cwt;
        let level = self.spike_level;
        // The first window is centred on the brightest pixel of the raw
        // row where the screen responded: the estimators start there, so
        // it needs their reach only (a stuck pixel there moves it; the
        // start is sought again after the repair, and a window that is
        // then too short asks for the wide one).
        let mut centre = bright;
        let mut reach = self.plan.typ_reach_px;
        let stripe = loop {
            let (lo, hi) = if screened { (centre.saturating_sub(reach), (centre + reach + 1).min(n)) } else { (0, n) };
            // The default method reads a window that the copy and the
            // repair would leave as it is (the common case) in place,
            // from the row: the same values, no copy.
            // The centroid repairs nothing (see `copied`) and clamps
            // what it reads: any window it can read in place.
            let in_place = in_place
                && screened
                && (lo..hi).contains(&bright)
                && (CENTROID
                    || row[bright].value() < sat && Self::window_is_clean(&row[lo..hi], sat, level, bright - lo));
            let (got, spikes) = if in_place {
                let view = RowView {
                    x: &row[lo..hi],
                    g: &[],
                    cfg: &self.cfg,
                    plan: &self.plan,
                    noise_q8,
                    off: lo,
                    row_len: n,
                };
                let got = if CENTROID {
                    centroid::detect(&view, bright - lo)
                } else {
                    cwt::refine(&view, bright - lo, &mut self.s)
                };
                (got, 0)
            } else {
                let first_window = reach < self.plan.reach_px + near;
                self.copied(row, (lo, hi), (a0, b0), at.map(|_| bright), first_window, runs_used)
            };
            match got {
                Err(cwt::Wider) if reach < self.plan.reach_px + near => {
                    (centre, reach) = (pos, self.plan.reach_px + near);
                }
                got => {
                    self.stats.spikes = self.stats.spikes.saturating_add(spikes);
                    break got.ok().flatten().map(|mut s| {
                        s.position = Px(s.position.0 + ((lo as i32) << 16));
                        s
                    });
                }
            }
        };
        if let Some(s) = stripe
            && (s.width >= self.cfg.min_width && s.width <= self.cfg.max_width || s.flags.contains(Flags::SATURATED))
            && windows.is_none_or(|w| w.contains(s.position))
        {
            let _ = found.push(s);
        }
    }
}

/// The screen's candidates inside `windows` ([`window`]): each window is
/// screened over itself and two blocks either side (at least four blocks,
/// within the row), so that the box difference at the window's edges reads
/// real pixels; candidates in row coordinates, the strongest
/// [`MAX_CANDIDATES`] over all windows. `row` must pass [`screen::screens`].
///
/// The span starts on the full row's block grid and is whole blocks long
/// (where the row allows): inside it the blocks, their responses and so the
/// candidates are the full-row screen's, so a stripe well inside a window
/// is found and measured exactly as by a full-row search.
fn window_candidates<P: Pixel>(
    row: &[P],
    windows: &[ColumnWindow],
    lb: u32,
    narrow: bool,
    threshold: i32,
    cands: &mut Vec<Candidate, MAX_CANDIDATES>,
) {
    cands.clear();
    let n = row.len();
    let (ext, least) = (2usize << lb, 4usize << lb);
    for w in windows {
        let first = w.first_px as usize;
        if first >= n {
            continue;
        }
        let block = 1usize << lb;
        let lo = first.saturating_sub(ext) & !(block - 1);
        let hi = (lo + (w.end_px() as usize + ext - lo).next_multiple_of(block).max(least)).min(n);
        let lo = lo.min(hi - least);
        screen::candidates_at(&row[lo..hi], lo, lb, narrow, threshold, cands);
    }
}

fn refine(v: &RowView<'_>, start: usize, scratch: &mut [i32]) -> Result<Option<Stripe>, cwt::Wider> {
    Ok(match v.cfg.method {
        Method::Cwt => return cwt::refine(v, start, scratch),
        Method::Centroid => return centroid::detect(v, start),
        // The other methods detect through the same multi-scale test, then
        // apply their own sub-pixel estimate; a coarse candidate that the
        // test rejects (noise, a hot pixel, a glow) is no stripe for any.
        m => {
            let Some(ok) = cwt::confirm(v, start, scratch)? else {
                return Ok(None);
            };
            if !v.fits(ok.c, v.plan.method_reach_px) {
                return Err(cwt::Wider);
            }
            let Some(mut s) = (match m {
                Method::CwtPaper => paper::refine(v, ok.c),
                m => subpixel::refine(v, ok.c, m),
            }) else {
                return Ok(None);
            };
            s.flags.insert(Flags(ok.flags.0 & Flags::LOW_CONFIDENCE.0));
            Some(s)
        }
    })
}
