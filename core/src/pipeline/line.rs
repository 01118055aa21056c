//! The line pass: what one frame's points of a laser say about each other.
//!
//! A row-by-row detector sees one row; the laser line is smooth over rows
//! (the rail under it is), speckle and the things real light adds are not.
//! After a frame's rows (a profile part: every row of the reference head),
//! [`LineCheck::check`] looks at each laser's points together and flags, by
//! rule, the ones that are not its line:
//!
//! * **Glint** ([`Flags::GLINT`]): a saturated stripe narrower than the
//!   line allows: narrower than the narrowest line the optics give in the
//!   working range (the detector's smallest scale, [`Rules::glint_width`]),
//!   or than [`GLINT_WIDTH_Q8`] of the line's own width at this range (the
//!   median σ of the laser's unsaturated stripes in the frame). A saturated
//!   line is measured by its half-level crossings, which err wide
//!   (`peak::saturated`), so a real line is never narrower than its σ; a
//!   specular facet is a spot of about the diffraction limit, far narrower
//!   than the line.
//! * **Ghost** ([`Flags::GHOST`]): a stripe outside the band of columns the
//!   laser's calibration allows in its row over the working depth
//!   ([`Band`]: the plane's line at both ends of
//!   [`working_depth_mm`](super::working_depth_mm), widened by
//!   [`BAND_MARGIN`] for the distortion the band ignores). A second
//!   candidate for one laser in one row (the head keeps it aside,
//!   [`Seconds`]) is compared with the line the neighbouring rows draw: the
//!   nearer stays, the other is dropped and the kept point carries
//!   [`Flags::SECOND_DROPPED`] (the wire carries one point a row a laser).
//! * **Off the line** ([`Flags::OFF_LINE`]): a point farther from the local
//!   line than the frame's own scatter allows. The local line is drawn
//!   through the medians of blocks of [`BLOCK_POINTS`] points: one line
//!   through the two blocks just before the point, one through the two just
//!   after, one through the block either side. A point is kept when one of
//!   them passes within the bound of it, so a real step (the rows after it
//!   continue each other) and the crest of a corrugation (the line either
//!   side) are kept, and a lone outlier or a short run of them (no line
//!   continues it) is not. The bound is
//!   [`BOUND_MADS_Q8`] median absolute deviations of every point from the
//!   line through the blocks either side of it (≈ 4 σ of a normal scatter),
//!   at least [`MIN_BOUND`]: the scatter is measured in the frame itself, so
//!   the rule holds under any light, and the floor keeps a clean line's
//!   curvature (a corrugation bends it by a fraction of a pixel over a
//!   block) from counting as scatter.
//!
//! Rejected points stay in the profile, flagged ([`Flags::REJECTED`]):
//! nothing is lost, the wire format is the same, and a host that builds a
//! profile leaves them out ([`Flags::rejected`]) and counts them
//! ([`Counts::of`]).
//!
//! # Cost
//! Per laser and frame: a running median of [`BLOCK_POINTS`] positions (one
//! value out and one in per point), a prediction and a comparison per point
//! (two more for the few off the line either side), and one selection (the
//! median absolute deviation) over the points: O(points), once per frame,
//! not per row. Scratch: [`LineCheck`], 7 KB, and the head's
//! [`Seconds`], 15 KB.
//!
//! # Scaling
//! Positions are [`Px`] (Q16.16 px), rows whole rows; block centres are
//! kept as twice the row (the mean of the two middle rows of a block of an
//! even number of points, exactly); predictions are formed in `i64`.

use crate::fixed::Px;
use crate::peak::{Config, Flags};
use crate::protocol::{Calibration, LASERS, LaserPoints, MAX_ROWS_PER_PROFILE, Point};
use heapless::Vec;

/// Points per block of the local line's medians.
pub const BLOCK_POINTS: usize = 8;
/// The off-line bound in median absolute deviations of the frame's
/// residuals, Q8 (6 MAD: 4.0 σ of a normal scatter).
pub const BOUND_MADS_Q8: i64 = 6 * 256;
/// Smallest off-line bound (Q16.16 px): 0.5 px.
pub const MIN_BOUND: Px = Px(1 << 15);
/// Fewest residuals the bound is measured on; with fewer points the
/// continuity rule does not judge.
pub const MIN_SCATTER_POINTS: usize = 2 * BLOCK_POINTS;
/// A saturated stripe narrower than this fraction of its line's own width
/// (Q8: 3/4) is a glint. A saturated line is measured at least as wide as
/// it is; a glint on the line is measured wider than the glint (the line
/// under it lifts its flanks), so the bound sits below the line, not at
/// the glint.
pub const GLINT_WIDTH_Q8: i64 = 192;
/// Margin on each side of a laser's calibrated band (Q16.16 px): 8 px, what
/// lens distortion and the stripe's half-width move a line by.
pub const BAND_MARGIN: Px = Px(8 << 16);
/// Second candidates a head keeps for one profile part: one a row (one
/// laser lit with a ghost beside its line in every row). Beyond them a
/// second candidate is dropped unjudged; the kept point says so.
pub const MAX_SECONDS: usize = MAX_ROWS_PER_PROFILE;

/// Second candidates: a laser and a stripe in a row where that laser
/// already has its point.
pub type Seconds = Vec<(u8, Point), MAX_SECONDS>;

/// The columns a laser's line can take in the image: between two lines of
/// slope `slope_q16` (the plane's line at both ends of the working depth).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Band {
    /// Left edge at row 0, Q16.16 px.
    pub lo_px: Px,
    /// Right edge at row 0, Q16.16 px.
    pub hi_px: Px,
    /// Change of both edges per row, Q16.16 px per row.
    pub slope_q16: i32,
}

impl Band {
    /// Whether column `position` of row `row` is inside the band.
    pub fn contains(&self, row: u16, position: Px) -> bool {
        let q = i64::from(position.0) - i64::from(self.slope_q16) * i64::from(row);
        (i64::from(self.lo_px.0)..=i64::from(self.hi_px.0)).contains(&q)
    }
}

/// Each laser's band: in the undistorted normalised image, the plane
/// `n·X = d` on a surface at depth `z` is the line `x = (d/z − n_y·y −
/// n_z)/n_x` (see [`check_laser_lines`](super::check_laser_lines)), so in
/// pixels `u = c_x + f_x·x + skew·y` with `y = (row − c_y)/f_y`: a line in
/// the row whose offset moves with `1/z`. The band spans it over the
/// working depth, plus [`BAND_MARGIN`]; `None` for a plane that gives no
/// finite line.
pub fn bands(c: &Calibration) -> [Option<Band>; LASERS] {
    let [fx, fy, cx, cy, skew] = c.intrinsics.map(f64::from);
    let (z0, z1) = super::working_depth_mm(c);
    let margin = BAND_MARGIN.to_f64();
    core::array::from_fn(|k| {
        let [nx, ny, nz, d] = c.planes[k].map(f64::from);
        let slope = (skew - fx * ny / nx) / fy;
        let at_row0 = |z: f64| cx + fx * (d / z - nz) / nx - slope * cy;
        let (a, b) = (at_row0(z0), at_row0(z1));
        let (lo, hi) = (a.min(b) - margin, a.max(b) + margin);
        let fits = |v: f64| v.is_finite() && v.abs() < 30_000.0;
        (fits(lo) && fits(hi) && fits(slope)).then(|| Band {
            lo_px: Px::from_f64(lo),
            hi_px: Px::from_f64(hi),
            slope_q16: Px::from_f64(slope).0,
        })
    })
}

/// What the pass judges by: the glint width and the lasers' bands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rules {
    /// A saturated stripe narrower than this (Gaussian σ, Q16.16 px) is a
    /// glint: the detector's smallest scale, the narrowest line its optics
    /// give in the working range.
    pub glint_width: Px,
    /// Each laser's band (`None`: no calibration, no band rule).
    pub bands: [Option<Band>; LASERS],
}

impl Rules {
    /// The rules of a detector configuration and, if there is one, a
    /// calibration.
    pub fn new(detector: &Config, calibration: Option<&Calibration>) -> Rules {
        Rules { glint_width: detector.scales.min(), bands: calibration.map_or([None; LASERS], bands) }
    }
}

/// What the pass rejected (or dropped) in one frame part.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Counts {
    /// Points flagged [`Flags::GLINT`].
    pub glint: u32,
    /// Points flagged [`Flags::GHOST`] (outside their laser's band).
    pub ghost: u32,
    /// Points flagged [`Flags::OFF_LINE`].
    pub off_line: u32,
    /// Points flagged [`Flags::SECOND_DROPPED`] (kept; a second candidate
    /// of their row was dropped).
    pub second_dropped: u32,
}

impl Counts {
    /// The counts of the flags of `lasers`' points: what the pass reports,
    /// read back from a profile (a host's count per frame).
    pub fn of(lasers: &[LaserPoints]) -> Counts {
        let mut c = Counts::default();
        const COUNTED: u8 = Flags::REJECTED.0 | Flags::SECOND_DROPPED.0;
        for p in lasers.iter().flat_map(|l| l.points.iter()).filter(|p| p.flags.0 & COUNTED != 0) {
            c.add_flags(p.flags);
        }
        c
    }

    /// Counts one point's flags.
    pub fn add_flags(&mut self, f: Flags) {
        self.glint += u32::from(f.contains(Flags::GLINT));
        self.ghost += u32::from(f.contains(Flags::GHOST));
        self.off_line += u32::from(f.contains(Flags::OFF_LINE));
        self.second_dropped += u32::from(f.contains(Flags::SECOND_DROPPED));
    }

    /// The sum of two counts (saturating).
    pub fn plus(self, o: Counts) -> Counts {
        Counts {
            glint: self.glint.saturating_add(o.glint),
            ghost: self.ghost.saturating_add(o.ghost),
            off_line: self.off_line.saturating_add(o.off_line),
            second_dropped: self.second_dropped.saturating_add(o.second_dropped),
        }
    }

    /// Points rejected (glint, ghost or off the line).
    pub fn rejected(&self) -> u32 {
        self.glint + self.ghost + self.off_line
    }
}

/// The pass's scratch (one per head: no allocation).
pub struct LineCheck {
    /// Indices into the laser's points of those not rejected, ascending.
    good: [u16; MAX_ROWS_PER_PROFILE],
    /// The good points' positions, Q16.16 px, and rows, in the order of
    /// `good`: the loops read them contiguously instead of through `good`.
    pos: [i32; MAX_ROWS_PER_PROFILE],
    row: [u16; MAX_ROWS_PER_PROFILE],
    /// Twice the centre row of the block starting at each good index (the
    /// sum of its two middle rows).
    c2: [i32; MAX_ROWS_PER_PROFILE],
    /// Median position of the block of `BLOCK_POINTS` good points starting
    /// at each good index, Q16.16 px.
    med: [i32; MAX_ROWS_PER_PROFILE],
    /// Residuals for the bound, Q16.16 px.
    res: [i32; MAX_ROWS_PER_PROFILE],
    /// Each good point's distance from the line either side, Q16.16 px
    /// (negative: none, or the point's verdict).
    off: [i32; MAX_ROWS_PER_PROFILE],
    n_good: usize,
}

impl Default for LineCheck {
    fn default() -> Self {
        LineCheck {
            good: [0; MAX_ROWS_PER_PROFILE],
            pos: [0; MAX_ROWS_PER_PROFILE],
            row: [0; MAX_ROWS_PER_PROFILE],
            c2: [0; MAX_ROWS_PER_PROFILE],
            med: [0; MAX_ROWS_PER_PROFILE],
            res: [0; MAX_ROWS_PER_PROFILE],
            off: [0; MAX_ROWS_PER_PROFILE],
            n_good: 0,
        }
    }
}

/// The median of a block (the mean of its two middle values), sorting it.
fn block_median(v: &mut [i32; BLOCK_POINTS]) -> i32 {
    // Insertion sort: 8 values, nearly sorted along a line.
    for i in 1..BLOCK_POINTS {
        let x = v[i];
        let mut j = i;
        while j > 0 && v[j - 1] > x {
            v[j] = v[j - 1];
            j -= 1;
        }
        v[j] = x;
    }
    ((i64::from(v[BLOCK_POINTS / 2 - 1]) + i64::from(v[BLOCK_POINTS / 2])) >> 1) as i32
}

impl LineCheck {
    /// Judges every laser's points of one frame part (`lasers`, each in
    /// ascending rows, one point a row), with the second candidates the
    /// head kept aside (`seconds`), and flags what the rules reject.
    /// Returns the counts (those of [`Counts::of`] on the result).
    pub fn check(&mut self, rules: &Rules, lasers: &mut [LaserPoints], seconds: &[(u8, Point)]) -> Counts {
        for lp in lasers.iter_mut() {
            let k = usize::from(lp.laser);
            let band = rules.bands.get(k).copied().flatten();
            let points = lp.points.as_mut_slice();
            let mine = |(l, _): &&(u8, Point)| usize::from(*l) == k;
            // The glint width matters to saturated stripes only (a second
            // candidate may be one): without any, the median is not sought,
            // and without a band either no point can be flagged alone.
            let saturated = points.iter().any(|p| p.flags.contains(Flags::SATURATED));
            let glint = if saturated || seconds.iter().any(|s| mine(&s)) {
                self.glint_width(rules, points)
            } else {
                rules.glint_width
            };
            if saturated || band.is_some() {
                for p in points.iter_mut() {
                    p.flags.insert(single_rule(glint, band, p));
                }
            }
            self.index(points);
            let mut swapped = false;
            for (_, alt) in seconds.iter().filter(mine) {
                swapped |= self.second(glint, band, points, alt);
            }
            if swapped {
                self.index(points);
            }
            self.continuity(points);
        }
        Counts::of(lasers)
    }

    /// The width below which a saturated stripe of this laser is a glint:
    /// the optics' smallest, or [`GLINT_WIDTH_Q8`] of the line's own
    /// (the median σ of the laser's unsaturated stripes in the frame: the
    /// line at this range), whichever is wider.
    fn glint_width(&mut self, rules: &Rules, points: &[Point]) -> Px {
        let mut n = 0;
        for p in points.iter().filter(|p| !p.flags.contains(Flags::SATURATED)) {
            self.res[n] = p.width.0;
            n += 1;
        }
        if n < MIN_SCATTER_POINTS {
            return rules.glint_width;
        }
        let (_, &mut median, _) = self.res[..n].select_nth_unstable(n / 2);
        Px(((i64::from(median) * GLINT_WIDTH_Q8) >> 8) as i32).max(rules.glint_width)
    }

    /// The good points' list, positions and rows, and their blocks'
    /// medians and centres.
    fn index(&mut self, points: &[Point]) {
        let mut n = 0;
        for (i, p) in points.iter().enumerate() {
            if !p.flags.rejected() {
                self.good[n] = i as u16;
                self.pos[n] = p.position.0;
                self.row[n] = p.row;
                n += 1;
            }
        }
        self.n_good = n;
        if n < BLOCK_POINTS {
            return;
        }
        let (pos, row) = (&self.pos[..n], &self.row[..n]);
        let h = BLOCK_POINTS / 2;
        for ((c, a), b) in self.c2.iter_mut().zip(&row[h - 1..n - h]).zip(&row[h..=n - h]) {
            *c = i32::from(*a) + i32::from(*b);
        }
        // The block slides one point at a time: its sorted positions lose
        // the point that leaves and take the one that enters.
        let mut v = [0i32; BLOCK_POINTS];
        v.copy_from_slice(&pos[..BLOCK_POINTS]);
        self.med[0] = block_median(&mut v);
        let med = &mut self.med[1..=n - BLOCK_POINTS];
        for ((m, &out), &new) in med.iter_mut().zip(pos).zip(&pos[BLOCK_POINTS..]) {
            let mut h = v.iter().position(|&x| x == out).unwrap_or(0);
            while h + 1 < BLOCK_POINTS && v[h + 1] < new {
                v[h] = v[h + 1];
                h += 1;
            }
            while h > 0 && v[h - 1] > new {
                v[h] = v[h - 1];
                h -= 1;
            }
            v[h] = new;
            *m = ((i64::from(v[BLOCK_POINTS / 2 - 1]) + i64::from(v[BLOCK_POINTS / 2])) >> 1) as i32;
        }
    }

    /// The line through the medians of blocks `a` and `b` (`a` before `b`)
    /// at `row`, Q16.16 px.
    #[inline(always)]
    fn line_at(&self, (a, b): (usize, usize), row: u16) -> Option<i64> {
        let (ca, cb) = (self.c2[a], self.c2[b]);
        let (ma, mb) = (self.med[a], self.med[b]);
        line_through((ca, ma), (cb, mb), row)
    }

    /// The local lines' predictions at `row`, whose good points before it
    /// are `good[..before]` and after it `good[after..]`: the line through
    /// the two blocks just before, the one through the two just after, and
    /// the one through the block either side.
    fn predictions(&self, row: u16, before: usize, after: usize) -> [Option<i64>; 3] {
        let [left, right] = self.sides(row, before, after);
        [left, right, self.centred(row, before, after)]
    }

    /// The line through the two blocks just before `row`, and the one
    /// through the two just after ([`LineCheck::predictions`]).
    fn sides(&self, row: u16, before: usize, after: usize) -> [Option<i64>; 2] {
        let k = BLOCK_POINTS;
        let left = (before >= 2 * k).then(|| self.line_at((before - 2 * k, before - k), row)).flatten();
        let right = (after + 2 * k <= self.n_good).then(|| self.line_at((after, after + k), row)).flatten();
        [left, right]
    }

    /// The line through the block either side of `row`.
    fn centred(&self, row: u16, before: usize, after: usize) -> Option<i64> {
        let k = BLOCK_POINTS;
        (before >= k && after + k <= self.n_good).then(|| self.line_at((before - k, after), row)).flatten()
    }

    /// Where `row` falls in the good list: `(before, after)`.
    fn split(&self, row: u16) -> (usize, usize) {
        let rows = &self.row[..self.n_good];
        (rows.partition_point(|&r| r < row), rows.partition_point(|&r| r <= row))
    }

    /// Judges a second candidate `alt` against the point of its row: the
    /// one nearer the local line stays, flagged [`Flags::SECOND_DROPPED`].
    /// Returns whether the second replaced the point.
    fn second(&mut self, glint: Px, band: Option<Band>, points: &mut [Point], alt: &Point) -> bool {
        let Ok(i) = points.binary_search_by_key(&alt.row, |p| p.row) else { return false };
        let mut alt = *alt;
        alt.flags.insert(single_rule(glint, band, &alt));
        let (before, after) = self.split(alt.row);
        let [left, right, centred] = self.predictions(alt.row, before, after);
        let swap = match centred.or(left).or(right) {
            _ if alt.flags.rejected() => false,
            _ if points[i].flags.rejected() => true,
            Some(line) => {
                let off = |p: &Point| (i64::from(p.position.0) - line).abs();
                off(&alt) < off(&points[i])
            }
            None => false,
        };
        if swap {
            alt.flags.insert(Flags::SECOND_DROPPED);
            points[i] = alt;
        } else {
            points[i].flags.insert(Flags::SECOND_DROPPED);
        }
        swap
    }

    /// Flags the good points off the local line by more than the bound.
    fn continuity(&mut self, points: &mut [Point]) {
        let n = self.n_good;
        let k = BLOCK_POINTS;
        // Each point's distance from the line through the blocks either
        // side (−1: none, the first and last `k` points), and those
        // distances for the bound.
        let judged = if n > 2 * k { k..n - k } else { 0..0 };
        self.off[..judged.start.max(n.min(k))].fill(-1);
        self.off[judged.end.max(judged.start)..n].fill(-1);
        let mut m = 0;
        // Point i against the blocks i − k and i + 1, as slices zipped
        // from i = k (no index to test per point).
        let (before, after) = (0..judged.len(), k + 1..k + 1 + judged.len());
        let (c2, med) = (&self.c2, &self.med);
        let blocks = c2[before.clone()].iter().zip(&c2[after.clone()]).zip(med[before].iter().zip(&med[after]));
        let at = self.row[judged.clone()].iter().zip(&self.pos[judged.clone()]);
        for ((((&ca, &cb), (&ma, &mb)), (&row, &pos)), off) in blocks.zip(at).zip(&mut self.off[judged]) {
            let d = distance_to_line((ca, ma), (cb, mb), row, pos);
            *off = d;
            if d >= 0 {
                self.res[m] = d;
                m += 1;
            }
        }
        if m < MIN_SCATTER_POINTS {
            return;
        }
        let (_, &mut mad, _) = self.res[..m].select_nth_unstable(m / 2);
        let bound = ((i64::from(mad) * BOUND_MADS_Q8) >> 8).max(i64::from(MIN_BOUND.0));
        // The medians are of the points as they came (flags do not move
        // them), so one outlier cannot hide another.
        for i in 0..n {
            let off = self.off[i];
            if off >= 0 && i64::from(off) <= bound {
                continue;
            }
            let [left, right] = self.sides(self.row[i], i, i + 1);
            let at = i64::from(self.pos[i]);
            let near = |line: &Option<i64>| line.is_some_and(|l| (at - l).abs() <= bound);
            let judged = off >= 0 || left.is_some() || right.is_some();
            if judged && !near(&left) && !near(&right) {
                points[usize::from(self.good[i])].flags.insert(Flags::OFF_LINE);
            }
        }
    }
}

/// |`at` − `line`| (Q16.16 px), at most `i32::MAX`.
#[inline(always)]
fn distance(at: i32, line: i64) -> i32 {
    match i32::try_from(line) {
        Ok(l) => at.abs_diff(l).min(i32::MAX as u32) as i32,
        Err(_) => (i64::from(at) - line).unsigned_abs().min(i32::MAX as u64) as i32,
    }
}

/// [`distance`] of `at` from [`line_through`] (−1: no line), in 32 bits
/// where the line's offset fits them (its sum with `ma` is then the same
/// `i32` as the `i64` made by `line_through`).
#[inline(always)]
fn distance_to_line((ca, ma): (i32, i32), (cb, mb): (i32, i32), row: u16, at: i32) -> i32 {
    if cb <= ca {
        return -1;
    }
    let (d, t) = (cb - ca, 2 * i32::from(row) - ca);
    if let Some(num) = mb.checked_sub(ma).and_then(|dm| dm.checked_mul(t))
        && let Some(line) = ma.checked_add(num / d)
    {
        return at.abs_diff(line).min(i32::MAX as u32) as i32;
    }
    line_through((ca, ma), (cb, mb), row).map_or(-1, |line| distance(at, line))
}

/// The line through the block medians `(ca, ma)` and `(cb, mb)` (twice the
/// centre row, Q16.16 px) at `row`, Q16.16 px; `None` unless `cb > ca`.
#[inline(always)]
fn line_through((ca, ma): (i32, i32), (cb, mb): (i32, i32), row: u16) -> Option<i64> {
    if cb <= ca {
        return None;
    }
    let (d, t) = (cb - ca, 2 * i32::from(row) - ca);
    // 32-bit products and division where they fit (the common case: block
    // medians a few pixels apart; a hardware divide on a Cortex-M, where
    // the 64-bit one is a library call ten times slower).
    if let Some(num) = mb.checked_sub(ma).and_then(|dm| dm.checked_mul(t)) {
        return Some(i64::from(ma) + i64::from(num / d));
    }
    let num = (i64::from(mb) - i64::from(ma)) * i64::from(t);
    Some(i64::from(ma) + num / i64::from(d))
}

/// The rules that judge a point alone: glint (narrower than `glint`),
/// then band.
fn single_rule(glint: Px, band: Option<Band>, p: &Point) -> Flags {
    if p.flags.contains(Flags::SATURATED) && p.width < glint {
        Flags::GLINT
    } else if band.is_some_and(|b| !b.contains(p.row, p.position)) {
        Flags::GHOST
    } else {
        Flags::NONE
    }
}

#[cfg(test)]
mod tests;
