//! A source of many independent patterns whose speckle is under a pixel,
//! rendered in real time: the expected image `Ī` with each row's line
//! displaced by the stripe-centre error the speckle would cause.
//!
//! The sum of `K` patterns is, by the central limit, `Ī` plus a Gaussian
//! field of one pattern's covariance over `K`; with speckle under a pixel
//! and `K` large its per-pixel contrast is a few per cent, and what it does
//! to a measurement is the error it puts on each row's stripe centre. That
//! error is emulated, not the field: a Gaussian process `e` along the rail,
//! tied to the surface like the speckle's phasors (a hash of the seed, the
//! laser, the cell along the rail and the head's place across it), so the
//! same strip of rail reads the same error frame after frame and run after
//! run, and a head moved across the rail reads other cells. Its cells are
//! one speckle correlation length long along the rail (`∫|μ|²` of the
//! pupil's Airy correlation); a pixel row reads their mean over its own
//! length and over the surface's travel in the exposure (the shifts
//! [`Plan`] computes), so pixel and motion averaging, and the overlap of
//! frames, follow from the geometry as the exact rendering's do.
//!
//! The cells' variance is calibrated against the exact rendering itself,
//! once per laser and fifth of a wave of defocus (1.1 mm of depth at
//! F/1.4): the shot's tile is rendered as [`RENDERED_PATTERNS`] patterns
//! with the statistics of `K`, still, and each row's centroid over ±3σ
//! about `Ī`'s, less `Ī`'s, divided by what moving the line moves that
//! centroid (the detector re-centres its window), is the row's error. So a
//! defocused line, whose speckle is elongated across it, gets its own
//! error, measured, not modelled. The calibration costs half an exact
//! tile (its middle rows: about 0.2 s of CPU at F/1.4) per laser when a
//! head starts or its focus moves by a fifth of a wave. What is left out is the speckle's effect on
//! the line's shape and brightness (a contrast of about 2 % a pixel at
//! F/1.4 and `K` = 100); the speckle fields
//! ([`super::LightCache::rendered_patterns`],
//! [`super::super::LightModel::exact_speckle`]) keep it.

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

use super::super::coherent::{Filter, Pupil, cell_hash, fft_size};
use super::super::{RENDERED_PATTERNS, mean};
use super::{Exact, LaserState, Plan, TileShot, has_finish, line_at};

/// Widest speckle (px) rendered fast: over a pixel the sum's per-pixel
/// fluctuation is no longer small, nor its effect on the line's shape.
const MAX_SPECKLE_PX: f64 = 1.0;

/// Stream of the centre errors' cells (one sub-stream per laser).
const STREAM: u64 = 0x4641_5354;

/// Width across the rail of a cell of the centre error, px at the
/// standoff: about the line's core (±1.5σ), the surface whose speckle
/// moves the centroid.
const LATERAL_CELL_PX: f64 = 3.0;

/// Half-width of the centroid's window, the line's σ (the detector's).
const WINDOW_SIGMAS: f64 = 3.0;

/// Profiles kept per laser (one per line width to 0.005 px).
const PROFILES_KEPT: usize = 32;

/// Whether a laser's tile is rendered fast: a source of more patterns than
/// [`RENDERED_PATTERNS`], speckle under a pixel, the line alone (no finish,
/// no ghost: their speckle is the exact rendering's), no reference asked
/// for ([`super::super::LightModel::exact_speckle`]).
pub(super) fn applies(s: &TileShot, p: &Pupil, exact: Exact) -> bool {
    let many = s.light.speckle.is_some_and(|sp| sp.patterns > RENDERED_PATTERNS);
    many && !exact.patterns
        && !exact.rendered
        && !s.light.exact_speckle
        && p.speckle_px() <= MAX_SPECKLE_PX
        && !has_finish(s.light)
        && !s.light.ghosts.iter().any(|g| g.laser == s.laser)
}

/// The speckle's correlation length, px: `∫|μ(r)|² dr` along a line for
/// the Airy correlation `μ = 2J₁(x)/x`, `x = 2π f_c r`
/// (`∫₀^∞ (2J₁(x)/x)² dx = 16/(3π)`), so `16/(3π² f_c)`.
fn correlation_px(p: &Pupil) -> f64 {
    16.0 / (3.0 * std::f64::consts::PI.powi(2) * p.cutoff_per_px)
}

/// The calibration's key: the defocus to a fifth of a wave, the pupil's
/// cut-off to a hundredth of a cycle per pixel.
fn key(p: &Pupil) -> (i64, i64) {
    ((p.defocus_waves * 5.0).round() as i64, (p.cutoff_per_px * 100.0).round() as i64)
}

/// What the fast rendering keeps per laser.
#[derive(Default)]
pub(super) struct FastState {
    /// The line-spread transfer and the grid (`w`, `q`, pupil) it is for.
    lsf: Option<((usize, usize, Pupil), Vec<f32>)>,
    /// Pixel profiles of the blurred line, by width ([`Profile`]).
    profiles: Vec<Profile>,
    /// Calibrated variance of a cell's error, px², by [`key`].
    calibrations: Vec<((i64, i64), f64)>,
    /// The cells' running sums.
    prefix: Vec<f64>,
    row: Vec<Complex<f32>>,
}

/// The line of width `σ` blurred by the lens's line spread, summed over a
/// pixel: `value[j]` is a pixel's mean whose first sample stands `j − jc`
/// samples (`1/q` px) from the line's centre.
struct Profile {
    sigma_key: i64,
    jc: usize,
    value: Vec<f64>,
}

impl Profile {
    /// A pixel's mean intensity (the line's peak 1) whose first sample is
    /// `t` samples from the centre, linearly interpolated.
    fn at(&self, t: f64) -> f64 {
        let x = self.jc as f64 + t;
        if x < 0.0 {
            return 0.0;
        }
        let i = x.floor() as usize;
        let f = x - i as f64;
        match (self.value.get(i), self.value.get(i + 1)) {
            (Some(a), Some(b)) => a + (b - a) * f,
            (Some(a), None) => a * (1.0 - f),
            _ => 0.0,
        }
    }
}

/// The centre error's cells along the rail for one laser and lateral
/// place: their running sums, for means over any stretch.
struct Cells<'a> {
    n0: i64,
    len_mm: f64,
    prefix: &'a [f64],
}

impl Cells<'_> {
    /// The running sum at `y` cells from cell `n0`'s start.
    fn sum_to(&self, y: f64) -> f64 {
        let last = self.prefix.len() - 2;
        let k = (y.floor().max(0.0) as usize).min(last);
        let f = (y - k as f64).clamp(0.0, 1.0);
        self.prefix[k] + f * (self.prefix[k + 1] - self.prefix[k])
    }

    /// The mean of the cells over `[x0, x1]` mm of rail.
    fn mean(&self, x0: f64, x1: f64) -> f64 {
        let (y0, y1) = (x0 / self.len_mm - self.n0 as f64, x1 / self.len_mm - self.n0 as f64);
        (self.sum_to(y1) - self.sum_to(y0)) / (y1 - y0)
    }
}

/// The sum of the squared weights of the cells in the mean over
/// `[x0, x1]` mm (the mean's variance over one cell's).
fn weights2(len_mm: f64, x0: f64, x1: f64) -> f64 {
    let (y0, y1) = (x0 / len_mm, x1 / len_mm);
    let mut s = 0.0;
    let mut k = y0.floor();
    while k < y1 {
        let o = (y1.min(k + 1.0) - y0.max(k)) / (y1 - y0);
        s += o * o;
        k += 1.0;
    }
    s
}

/// A standard normal number from a hash (Box–Muller on its two halves).
fn gaussian(h: u64) -> f64 {
    let u1 = ((h >> 32) as f64 + 0.5) / 4_294_967_296.0;
    let u2 = (h & 0xFFFF_FFFF) as f64 / 4_294_967_296.0;
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// The centroid of `row` (pixel `j` at image column `u0 + j`) over
/// `[c − half, c + half]`, the edge pixels weighted by their part in it.
fn window_centroid(row: &[f64], u0: f64, c: f64, half: f64) -> f64 {
    let (mut s, mut sx) = (0.0, 0.0);
    for (j, v) in row.iter().enumerate() {
        let u = u0 + j as f64;
        let part = ((u + 0.5).min(c + half) - (u - 0.5).max(c - half)).clamp(0.0, 1.0);
        s += v * part;
        sx += v * part * u;
    }
    if s > 0.0 { sx / s } else { c }
}

impl LaserState {
    /// Renders a laser's tile fast into `pixels` (electrons, `h_img × ncols`).
    pub(super) fn fast(&mut self, s: &TileShot, plan: &Plan, p: Pupil) {
        let var_px2 = self.calibrated(s, p);
        let h_img = s.lines.len();
        self.pixels.clear();
        self.pixels.resize(h_img * plan.ncols, 0.0);
        let (a_mm, b_mm) = s.row_mm;
        let half_mm = 0.5 * b_mm.abs();
        let len_mm = correlation_px(&p) * b_mm.abs();
        let at = |r: usize, m: usize| s.odometer_mm + plan.shift_mm(s, m) + a_mm + b_mm * r as f64;
        let ends = [at(0, 0), at(0, plan.steps - 1), at(h_img, 0), at(h_img, plan.steps - 1)];
        let lo = ends.iter().copied().fold(f64::INFINITY, f64::min) - half_mm;
        let hi = ends.iter().copied().fold(f64::NEG_INFINITY, f64::max) + half_mm;
        let n0 = (lo / len_mm).floor() as i64 - 1;
        let n1 = (hi / len_mm).floor() as i64 + 1;
        // Across the rail, between two columns of cells (weights whose
        // squares sum to 1: the variance kept).
        let t = s.lateral_px / LATERAL_CELL_PX;
        let (col, f) = (t.floor() as i64, t - t.floor());
        let (wa, wb) = ((f * std::f64::consts::FRAC_PI_2).cos(), (f * std::f64::consts::FRAC_PI_2).sin());
        let stream = STREAM ^ ((s.laser as u64) << 32);
        let mut prefix = std::mem::take(&mut self.fast.prefix);
        prefix.clear();
        prefix.push(0.0);
        let mut sum = 0.0;
        for n in n0..=n1 {
            let z = wa * gaussian(cell_hash(s.seed, stream, col, n))
                + if wb > 0.0 { wb * gaussian(cell_hash(s.seed, stream, col + 1, n)) } else { 0.0 };
            sum += z;
            prefix.push(sum);
        }
        let cells = Cells { n0, len_mm, prefix: &prefix };
        let sigma_z = var_px2.sqrt();
        let q = plan.q as f64;
        for r in 0..h_img {
            let Some(l) = line_at(s.lines, r as f64, s.gain_e_per_dn) else { continue };
            let e: f64 = (0..plan.steps).map(|m| cells.mean(at(r, m) - half_mm, at(r, m) + half_mm)).sum::<f64>()
                * sigma_z
                / plan.steps as f64;
            let c = l.c + e;
            let i = self.profile(plan, p, l.sigma);
            let profile = &self.fast.profiles[i];
            let out = &mut self.pixels[r * plan.ncols..(r + 1) * plan.ncols];
            for (j, o) in out.iter_mut().enumerate() {
                let u = (plan.u0 + j as i64) as f64;
                *o = l.peak_e * profile.at((u - 0.5 + 0.5 / q - c) * q);
            }
        }
        self.fast.prefix = prefix;
    }

    /// The cells' variance for the shot's pupil, px²: calibrated the first
    /// time it is asked for.
    fn calibrated(&mut self, s: &TileShot, p: Pupil) -> f64 {
        let k = key(&p);
        if let Some(&(_, v)) = self.fast.calibrations.iter().find(|(c, _)| *c == k) {
            return v;
        }
        let v = self.calibrate(s, p);
        self.fast.calibrations.push((k, v));
        v
    }

    /// The shot's tile, still, rendered as [`RENDERED_PATTERNS`] patterns
    /// with `K`'s statistics: each row's centre error over the mean of the
    /// squared weights of its cells.
    fn calibrate(&mut self, s: &TileShot, p: Pupil) -> f64 {
        // The middle half of the rows: 240 of the reference head's, a
        // variance to ±9 % (1σ, ±0.4 dB), at half the whole tile's cost
        // (the first frame of a head waits for it).
        let (r0, r1) = (s.lines.len() / 4, s.lines.len() - s.lines.len() / 4);
        let (a_mm, b_mm) = s.row_mm;
        let still = TileShot { travel_mm: 0.0, lines: &s.lines[r0..r1], row_mm: (a_mm + b_mm * r0 as f64, b_mm), ..*s };
        let s = &still;
        let Some(plan) = Plan::new(s) else { return 0.0 };
        let h_img = s.lines.len();
        self.pixels.clear();
        self.pixels.resize(h_img * plan.ncols, 0.0);
        self.coherent(s, &plan, p, Exact { rendered: true, ..Exact::default() });
        let len_mm = correlation_px(&p) * b_mm.abs();
        let u0 = plan.u0 as f64;
        let (mut e2, mut w2) = (0.0, 0.0);
        for r in 0..h_img {
            let Some(l) = &s.lines[r] else { continue };
            let span = r * plan.ncols..(r + 1) * plan.ncols;
            let (mean, seen) = (&self.mean_px[span.clone()], &self.pixels[span]);
            let half = WINDOW_SIGMAS * l.sigma_px;
            let c = window_centroid(mean, u0, l.column_px, half);
            let moved = window_centroid(mean, u0, c + 0.1, half) - window_centroid(mean, u0, c - 0.1, half);
            let gain = 1.0 - moved / 0.2;
            if gain <= 0.05 {
                continue;
            }
            let e = (window_centroid(seen, u0, c, half) - c) / gain;
            let x = s.odometer_mm + a_mm + b_mm * r as f64;
            e2 += e * e;
            w2 += weights2(len_mm, x - 0.5 * b_mm.abs(), x + 0.5 * b_mm.abs());
        }
        // The exact rendering's buffers are large (a field of 26 MB at
        // F/1.4) and not needed again.
        self.filters.clear();
        for buf in [&mut self.field, &mut self.scratch, &mut self.row_c] {
            *buf = Vec::new();
        }
        for buf in [&mut self.amp, &mut self.colsum] {
            *buf = Vec::new();
        }
        self.rings.clear();
        if w2 > 0.0 { e2 / w2 } else { 0.0 }
    }

    /// The pixel profile of a line of width `sigma_px` on the plan's grid:
    /// its index in the profiles kept.
    fn profile(&mut self, plan: &Plan, p: Pupil, sigma_px: f64) -> usize {
        let (w, q) = (plan.w, plan.q);
        let grid = (w, q, p);
        if self.fast.lsf.as_ref().is_none_or(|(g, _)| *g != grid) {
            // The line spread from a filter only as tall as the point
            // spread's reach (the guards, both ways, twice).
            let h = fft_size(4 * plan.g_rows.max(2) * q);
            let planner = self.planner.get_or_insert_with(FftPlanner::new);
            let filter = Filter::planned(planner, &p, q, w, h);
            let (mut field, mut scratch) = (Vec::new(), Vec::new());
            let t = mean::lsf_transfer(&filter, planner, (w, h), &mut field, &mut scratch);
            self.fast.lsf = Some((grid, t));
            self.fast.profiles.clear();
        }
        let sigma_key = (sigma_px * 200.0).round() as i64;
        if let Some(i) = self.fast.profiles.iter().position(|pr| pr.sigma_key == sigma_key) {
            return i;
        }
        let Some((_, transfer)) = &self.fast.lsf else { unreachable!("made above") };
        let planner = self.planner.get_or_insert_with(FftPlanner::new);
        let jc = w / 2;
        let sigma = sigma_key as f64 / 200.0;
        let row = &mut self.fast.row;
        row.clear();
        row.extend((0..w).map(|j| {
            let d = (j as f64 - jc as f64) / q as f64;
            Complex::new((-0.5 * d * d / (sigma * sigma)).exp() as f32, 0.0)
        }));
        planner.plan_fft_forward(w).process(row);
        for (r, t) in row.iter_mut().zip(transfer) {
            *r *= *t;
        }
        planner.plan_fft_inverse(w).process(row);
        let value: Vec<f64> =
            (0..w - q).map(|j| row[j..j + q].iter().map(|z| f64::from(z.re)).sum::<f64>() / q as f64).collect();
        if self.fast.profiles.len() >= PROFILES_KEPT {
            self.fast.profiles.remove(0);
        }
        self.fast.profiles.push(Profile { sigma_key, jc, value });
        self.fast.profiles.len() - 1
    }
}
