//! One laser's stripe over a whole shot, as the light model renders it:
//! the illumination on a grid of samples, its reflectance, the speckle of
//! the coherent image with the surface moving under the line during the
//! exposure, and the pixels' sums. A shot's tiles are made once, on its
//! first row, and kept until another shot is rendered.

use rustfft::num_complex::Complex;

use super::super::StripeTruth;
use super::coherent::{Filter, Pupil, fft_size};
use super::ring::PhasorRing;
use super::{LightModel, RENDERED_PATTERNS, mean, surface};

mod fast;

/// Stream of the speckle phases (one sub-stream per laser and pattern).
const SPECKLE_STREAM: u64 = 0x5350_4543;

/// Most sub-exposures of a moving surface averaged in one exposure.
const MAX_STEPS: usize = 64;

/// A laser's stripe in one shot: electrons per pixel over a band of columns.
#[derive(Clone, Debug)]
pub(crate) struct LaserTile {
    first_col: usize,
    width: usize,
    e: Vec<f64>,
}

impl LaserTile {
    /// Adds row `row` of the stripe to `buf`.
    pub fn add_row(&self, row: usize, buf: &mut [f64]) {
        if let Some(src) = self.e.get(row * self.width..(row + 1) * self.width) {
            for (b, s) in buf[self.first_col..].iter_mut().zip(src) {
                *b += s;
            }
        }
    }

    /// Row `row` of the stripe, electrons per pixel from column `first_col` on.
    #[cfg(test)]
    pub fn row(&self, row: usize) -> (usize, &[f64]) {
        (self.first_col, &self.e[row * self.width..(row + 1) * self.width])
    }
}

/// Everything a laser's tile depends on.
pub(crate) struct TileShot<'a> {
    pub light: &'a LightModel,
    pub seed: u64,
    pub laser: usize,
    pub wavelength_um: f64,
    pub pixel_pitch_um: f64,
    pub fx_px: f64,
    /// Where the lens is focused, mm.
    pub focus_mm: f64,
    /// The head's place across the rail in image columns at the standoff:
    /// the surface's cells (its speckle phases) are the rail's, so a head
    /// moved across sees other cells under the same image columns.
    pub lateral_px: f64,
    /// The laser's line in each row of the image (`None`: not in that row).
    pub lines: &'a [Option<StripeTruth>],
    pub gain_e_per_dn: f64,
    pub odometer_mm: f64,
    /// Travel of the head during the exposure, mm (signed).
    pub travel_mm: f64,
    /// Along-rail position of a row from the odometer: `a + b·row`, mm.
    pub row_mm: (f64, f64),
    pub width_px: usize,
}

/// The line (and its ghosts) at a fractional row: centre, σ, peak
/// (electrons), lateral position (mm) and depth (mm).
#[derive(Clone, Copy, Debug)]
struct Line {
    c: f64,
    sigma: f64,
    peak_e: f64,
    y_mm: f64,
    depth_mm: f64,
}

fn line_at(lines: &[Option<StripeTruth>], v: f64, gain: f64) -> Option<Line> {
    let last = lines.len().checked_sub(1)? as f64;
    let v = v.clamp(0.0, last);
    let i0 = v.floor() as usize;
    let i1 = (i0 + 1).min(lines.len() - 1);
    let t = v - i0 as f64;
    let mk = |s: &StripeTruth| Line {
        c: s.column_px,
        sigma: s.sigma_px,
        peak_e: s.peak_dn * gain,
        y_mm: s.y_mm,
        depth_mm: s.depth_mm,
    };
    match (lines[i0].as_ref(), lines[i1].as_ref()) {
        (Some(a), Some(b)) => {
            let (a, b) = (mk(a), mk(b));
            let l = |p: f64, q: f64| p + (q - p) * t;
            Some(Line {
                c: l(a.c, b.c),
                sigma: l(a.sigma, b.sigma),
                peak_e: l(a.peak_e, b.peak_e),
                y_mm: l(a.y_mm, b.y_mm),
                depth_mm: l(a.depth_mm, b.depth_mm),
            })
        }
        (Some(a), None) if t < 0.5 => Some(mk(a)),
        (None, Some(b)) if t >= 0.5 => Some(mk(b)),
        _ => None,
    }
}

/// `peak · exp(−d²/(2σ²))` at `d = d0 + j·step` into (`add`: onto) `out[j]`,
/// by the recurrence `g(d + δ) = g(d) · exp(−(2dδ + δ²)/(2σ²))` from the
/// peak outwards on either side (three `exp` a side instead of one a sample;
/// each step's relative error is the rounding's, 10⁻¹⁶).
fn gaussian_row(out: &mut [f64], peak: f64, d0: f64, step: f64, sigma: f64, add: bool) {
    let inv = -0.5 / (sigma * sigma);
    // The sample nearest the peak, then outwards.
    let n = out.len();
    let jc = ((-d0 / step).round().max(0.0) as usize).min(n.saturating_sub(1));
    let mut put = |j: usize, g: f64| {
        if add {
            out[j] += g;
        } else {
            out[j] = g;
        }
    };
    let d = d0 + jc as f64 * step;
    for dir in [1.0f64, -1.0] {
        let mut j = jc;
        let mut g = peak * (inv * d * d).exp();
        // g(d ± δ) / g(d) = exp(inv (±2dδ + δ²)); its own ratio exp(2 inv δ²).
        let mut ratio = (inv * (dir * 2.0 * d * step + step * step)).exp();
        let growth = (2.0 * inv * step * step).exp();
        if dir > 0.0 {
            put(j, g);
        }
        loop {
            if dir > 0.0 {
                if j + 1 >= n {
                    break;
                }
                j += 1;
            } else {
                if j == 0 {
                    break;
                }
                j -= 1;
            }
            g *= ratio;
            ratio *= growth;
            put(j, g);
        }
    }
}

/// The shot's tiles and, per laser, what is kept between shots.
#[derive(Default)]
pub(crate) struct LightCache {
    key: Option<(u64, u64, u64, u8)>,
    tiles: Vec<Option<LaserTile>>,
    lasers: Vec<LaserState>,
    /// CPU time of the lasers' threads, summed.
    threads_cpu: std::time::Duration,
    /// Every sub-exposure imaged under its own illumination instead of one
    /// field read at each sub-exposure's place (the reference the light
    /// model's tests hold the shifted reads to).
    pub exact_exposure: bool,
    /// Every one of a source's independent patterns rendered, not
    /// [`RENDERED_PATTERNS`] with the statistics of all (the reference the
    /// light model's tests hold the fast rendering to).
    pub exact_patterns: bool,
    /// A source of many patterns with speckle under a pixel rendered as
    /// [`RENDERED_PATTERNS`] with the statistics of all, not as its
    /// expected image with the stripe-centre error emulated (`fast.rs`):
    /// the reference the emulation is calibrated against and held to.
    pub rendered_patterns: bool,
}

/// How faithfully a tile is rendered (the tests' references).
#[derive(Clone, Copy, Debug, Default)]
struct Exact {
    exposure: bool,
    patterns: bool,
    rendered: bool,
}

/// One laser's filters, phasor rings and buffers, kept between shots.
#[derive(Default)]
struct LaserState {
    /// The last filters made, the latest first ([`FILTERS_KEPT`]), with
    /// their line-spread transfer once a source of many patterns asked for
    /// it ([`mean::lsf_transfer`]).
    filters: Vec<(FilterKey, Filter<f32>, Option<Vec<f32>>)>,
    /// Their transforms' plans, made once a size.
    planner: Option<rustfft::FftPlanner<f32>>,
    /// The pupil's columns of the field, transposed.
    scratch: Vec<Complex<f32>>,
    /// Pattern `k`'s surface cells in ring `min(k, RINGS − 1)`: the first
    /// patterns are kept from shot to shot, the others drawn each shot.
    rings: Vec<PhasorRing>,
    /// A row of the illumination, and where its samples fall across the rail.
    row_e: Vec<f64>,
    row_y: Vec<f64>,
    /// The field's amplitude on the grid's lit samples.
    amp: Vec<f32>,
    field: Vec<Complex<f32>>,
    /// Per sample row, the intensity summed over each pixel's columns.
    colsum: Vec<f32>,
    /// The tile's pixel sums, before normalising.
    pixels: Vec<f64>,
    /// Their expectation (a source of more patterns than rendered).
    mean_px: Vec<f64>,
    /// A row of the expectation's transform.
    row_c: Vec<Complex<f32>>,
    /// The last tile's grid: samples across, along, sub-exposures.
    grid: (usize, usize, usize),
    /// The last shot's tile's pixels, made again into this shot's (a
    /// tile's worth of fresh pages a frame costs as much as its sums).
    spare: Vec<f64>,
    /// The fast rendering's profiles, calibrations and cells.
    fast: fast::FastState,
}

/// Phasor rings per laser (their memory: a shot's cells, about 4 MB at F/4).
const RINGS: usize = 3;

/// Filters kept per laser (3.8 MB each at F/2.8). A filter is made for the
/// line's mean depth to 0.1 mm: as the rail's height wanders across a
/// tenth's boundary from frame to frame, the filters on either side are
/// made once, not each time it crosses.
const FILTERS_KEPT: usize = 3;

/// What a filter was made for: grid size, samples per pixel, pupil.
#[derive(Clone, Copy, Debug, PartialEq)]
struct FilterKey {
    w: usize,
    h: usize,
    q: usize,
    pupil: Pupil,
}

impl Clone for LightCache {
    /// A copy starts empty: the cache is made again from the scene.
    fn clone(&self) -> Self {
        LightCache::default()
    }
}

impl LightCache {
    /// The key of a shot: frame, odometer, exposure, lasers.
    pub fn key(frame_index: u64, odometer_mm: f64, exposure_us: f64, mask: u8) -> (u64, u64, u64, u8) {
        (frame_index, odometer_mm.to_bits(), exposure_us.to_bits(), mask)
    }

    /// Each laser's last tile's grid: samples across the line, along it,
    /// and sub-exposures.
    pub fn grids(&self) -> Vec<(usize, usize, usize)> {
        self.lasers.iter().map(|l| l.grid).collect()
    }

    /// CPU time the lasers' threads have spent so far (not the caller's).
    pub fn threads_cpu(&self) -> std::time::Duration {
        self.threads_cpu
    }

    /// The tiles of shot `key`, if they are the ones kept.
    pub fn tiles_for(&self, key: (u64, u64, u64, u8)) -> Option<&[Option<LaserTile>]> {
        (self.key == Some(key)).then_some(&self.tiles[..])
    }

    /// The tiles kept, whichever shot they are of.
    #[cfg(test)]
    pub fn tiles(&self) -> &[Option<LaserTile>] {
        &self.tiles
    }

    /// Renders the tiles of shot `key`, one per laser (`None`: the laser is
    /// off or its line in no row), and keeps them. The lasers render on
    /// threads of their own when the host has cores for them; each tile
    /// depends only on its laser's shot, so the pixels are the same either way.
    pub fn render_shot(&mut self, key: (u64, u64, u64, u8), shots: &[Option<TileShot>]) {
        if self.lasers.len() < shots.len() {
            self.lasers.resize_with(shots.len(), LaserState::default);
        }
        // The last shot's tiles' memory, for this shot's.
        for (st, old) in self.lasers.iter_mut().zip(std::mem::take(&mut self.tiles)) {
            if let Some(t) = old {
                st.spare = t.e;
            }
        }
        let lit = shots.iter().flatten().count();
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let exact =
            Exact { exposure: self.exact_exposure, patterns: self.exact_patterns, rendered: self.rendered_patterns };
        let tiles = if lit < 2 || cores < 2 {
            self.lasers.iter_mut().zip(shots).map(|(st, s)| s.as_ref().and_then(|s| st.render(s, exact))).collect()
        } else {
            let (tiles, cpu): (Vec<_>, Vec<_>) = std::thread::scope(|scope| {
                let jobs: Vec<_> = self
                    .lasers
                    .iter_mut()
                    .zip(shots)
                    .map(|(st, s)| {
                        s.as_ref().map(|s| {
                            scope.spawn(move || {
                                let t0 = thread_cpu();
                                let tile = st.render(s, exact);
                                (tile, thread_cpu().saturating_sub(t0))
                            })
                        })
                    })
                    .collect();
                jobs.into_iter()
                    .map(|j| {
                        j.map_or((None, std::time::Duration::ZERO), |j| {
                            j.join().unwrap_or_else(|p| std::panic::resume_unwind(p))
                        })
                    })
                    .unzip()
            });
            self.threads_cpu += cpu.into_iter().sum();
            tiles
        };
        self.key = Some(key);
        self.tiles = tiles;
    }
}

/// CPU time of the calling thread so far.
fn thread_cpu() -> std::time::Duration {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map(std::time::Duration::from)
        .unwrap_or_default()
}

/// Where a shot's tile lies and how it is sampled.
struct Plan {
    pupil: Option<Pupil>,
    /// Samples per pixel, both ways.
    q: usize,
    /// The tile's first and last pixel columns (guards included).
    u0: i64,
    u1: i64,
    /// Guard rows above and below the image, px.
    g_rows: usize,
    /// Pixel columns of the tile.
    ncols: usize,
    /// Sample rows the image and its guards span (`(h_img + 2 g_rows)·q`).
    img_h: usize,
    /// Sample rows of the grid: the image's, and under laser light the
    /// surface's travel in the exposure.
    lit_h: usize,
    /// The FFT's grid (`lit_w = ncols·q` columns of it lit).
    w: usize,
    h: usize,
    /// Sub-exposures: the surface slides under the line by the travel.
    steps: usize,
    /// Under laser light, per sub-exposure, the grid row the image's first
    /// sample row sees (the surface slid by it), and the grid's first
    /// surface row.
    shifts: Vec<usize>,
    n_lo: i64,
    mid_row: f64,
}

impl Plan {
    fn new(s: &TileShot) -> Option<Plan> {
        let h_img = s.lines.len();
        let rows: Vec<&StripeTruth> = s.lines.iter().flatten().collect();
        if rows.is_empty() {
            return None;
        }
        let light = s.light;
        let mid_row = (h_img as f64 - 1.0) / 2.0;
        // The pupil at the line's mean depth (to 0.1 mm, so a filter lasts
        // while the head holds its height).
        let depth = (rows.iter().map(|l| l.depth_mm).sum::<f64>() / rows.len() as f64 * 10.0).round() / 10.0;
        let pupil = light.speckle.map(|sp| {
            let f_mm = s.fx_px * s.pixel_pitch_um * 1e-3;
            let m = f_mm / (depth - f_mm).max(f_mm);
            // The focus to 0.1 mm too (a Scheimpflug sensor's moves with
            // the line), so the filter's defocus stays from frame to frame.
            let focus = (s.focus_mm * 10.0).round() / 10.0;
            let defocus_um = m * m * (depth - focus) * 1e3;
            Pupil::new(s.wavelength_um, sp.f_number, m, s.pixel_pitch_um, defocus_um)
        });
        let q = pupil.map_or(4, |p| p.samples_per_px());
        // Guards: the field's reach (a few speckles and the defocus blur)
        // beyond the light, so the FFT's wrap-round meets darkness.
        let guard_px = pupil.map_or(1, |p| {
            let blur = (p.defocus_waves.abs() * 8.0 / (2.0 * p.cutoff_per_px)).ceil();
            (3.0 * p.speckle_px() + blur).ceil() as i64 + 3
        });
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (r, l) in s.lines.iter().enumerate() {
            let Some(l) = l else { continue };
            lo = lo.min(l.column_px - 6.0 * l.sigma_px);
            hi = hi.max(l.column_px + 6.0 * l.sigma_px);
            for g in light.ghosts.iter().filter(|g| g.laser == s.laser) {
                let c = l.column_px + g.offset_px + g.tilt_px_per_row * (r as f64 - mid_row);
                lo = lo.min(c - 6.0 * l.sigma_px * g.sigma_factor);
                hi = hi.max(c + 6.0 * l.sigma_px * g.sigma_factor);
            }
        }
        let (u0, u1) = (lo.floor() as i64 - guard_px, hi.ceil() as i64 + guard_px);
        let g_rows = if pupil.is_some() { guard_px as usize } else { 0 };
        let ncols = (u1 - u0 + 1) as usize;
        let img_h = (h_img + 2 * g_rows) * q;
        let (_, b_mm) = s.row_mm;
        let travel_rows = s.travel_mm / b_mm;
        let spacing_rows = pupil.map_or(0.5, |p| p.speckle_px() / 4.0);
        let steps = if travel_rows.abs() < spacing_rows {
            1
        } else {
            ((travel_rows.abs() / spacing_rows).ceil() as usize + 1).min(MAX_STEPS)
        };
        let mut plan = Plan {
            pupil,
            q,
            u0,
            u1,
            g_rows,
            ncols,
            img_h,
            lit_h: img_h,
            w: ncols * q,
            h: img_h,
            steps,
            shifts: vec![0; steps],
            n_lo: 0,
            mid_row,
        };
        if pupil.is_some() {
            // Surface row of the image's first sample row at sub-exposure m.
            let n_m: Vec<i64> = (0..steps)
                .map(|m| ((s.odometer_mm + plan.shift_mm(s, m) + s.row_mm.0) / b_mm * q as f64).round() as i64)
                .collect();
            plan.n_lo = n_m.iter().copied().min().unwrap_or(0);
            plan.shifts = n_m.iter().map(|n| (n - plan.n_lo) as usize).collect();
            // The travel's rows whatever the rounding of the shifts (so the
            // grid, and its filter, stay from shot to shot).
            let ext = if steps == 1 { 0 } else { (travel_rows.abs() * q as f64).ceil() as usize + 1 };
            plan.lit_h = img_h + ext.max(plan.shifts.iter().copied().max().unwrap_or(0));
            plan.w = fft_size(ncols * q);
            plan.h = fft_size(plan.lit_h);
        }
        Some(plan)
    }

    /// The surface's travel at sub-exposure `m` from the exposure's middle, mm.
    fn shift_mm(&self, s: &TileShot, m: usize) -> f64 {
        if self.steps == 1 { 0.0 } else { s.travel_mm * (m as f64 / (self.steps - 1) as f64 - 0.5) }
    }

    /// Image column of sample column `j`, px.
    fn sample_u(&self, j: usize) -> f64 {
        self.u0 as f64 + (j as f64 + 0.5) / self.q as f64 - 0.5
    }

    /// Image row of (fractional) sample row `i` of the image and its guards, px.
    fn sample_v(&self, i: f64) -> f64 {
        -(self.g_rows as f64) + (i + 0.5) / self.q as f64 - 0.5
    }
}

/// The illumination at image row `v` (fixed to the head: the line and its
/// ghosts) into `out`, electrons per sample, and where on the rail top
/// each sample falls across the rail, mm, into `lateral` (if not empty).
/// Zero where the line is in no row.
fn illumination(s: &TileShot, plan: &Plan, v: f64, out: &mut [f64], lateral: &mut [f64]) {
    let Some(l) = line_at(s.lines, v, s.gain_e_per_dn) else {
        out.fill(0.0);
        lateral.fill(0.0);
        return;
    };
    let step = 1.0 / plan.q as f64;
    let d0 = plan.sample_u(0) - l.c;
    gaussian_row(out, l.peak_e, d0, step, l.sigma, false);
    for g in s.light.ghosts.iter().filter(|g| g.laser == s.laser) {
        let dg0 = d0 - g.offset_px - g.tilt_px_per_row * (v - plan.mid_row);
        gaussian_row(out, g.fraction * l.peak_e, dg0, step, l.sigma * g.sigma_factor, true);
    }
    let mm_per_px = l.depth_mm / s.fx_px;
    for (j, y) in lateral.iter_mut().enumerate() {
        *y = l.y_mm + (plan.sample_u(j) - l.c) * mm_per_px;
    }
}

/// The square root of the line's illumination at image row `v` (no
/// ghosts): `√(peak · exp(−x²/2σ²)) = √peak · exp(−x²/(2 (σ√2)²))`, into `out`.
fn line_amplitude(s: &TileShot, plan: &Plan, v: f64, out: &mut [f64]) {
    let Some(l) = line_at(s.lines, v, s.gain_e_per_dn) else {
        out.fill(0.0);
        return;
    };
    let d0 = plan.sample_u(0) - l.c;
    gaussian_row(out, l.peak_e.sqrt(), d0, 1.0 / plan.q as f64, l.sigma * std::f64::consts::SQRT_2, false);
}

fn has_finish(light: &LightModel) -> bool {
    light.oxidation.per_m > 0.0 || light.grease.per_m > 0.0 || light.band.is_some()
}

impl LaserState {
    /// Renders one laser's tile (`None`: its line is in no row).
    fn render(&mut self, s: &TileShot, exact: Exact) -> Option<LaserTile> {
        let plan = Plan::new(s)?;
        let h_img = s.lines.len();
        self.grid = (plan.w, plan.h, plan.steps);
        self.pixels.clear();
        self.pixels.resize(h_img * plan.ncols, 0.0);
        // The pixels' sums are over sub-exposures, patterns and samples;
        // the fast rendering's are electrons already.
        let norm = match plan.pupil {
            None => {
                self.incoherent(s, &plan);
                1.0 / ((plan.steps * plan.q * plan.q) as f64)
            }
            Some(p) if fast::applies(s, &p, exact) => {
                self.fast(s, &plan, p);
                1.0
            }
            Some(p) => {
                let patterns = self.coherent(s, &plan, p, exact);
                1.0 / ((plan.steps * patterns * plan.q * plan.q) as f64)
            }
        };
        // The image's columns of the tile.
        let first = plan.u0.max(0) as usize;
        let last = (plan.u1.min(s.width_px as i64 - 1)).max(plan.u0.max(0)) as usize;
        let width = last + 1 - first;
        let mut e = std::mem::take(&mut self.spare);
        e.clear();
        e.resize(width * h_img, 0.0);
        for (out, src) in e.chunks_exact_mut(width).zip(self.pixels.chunks_exact(plan.ncols)) {
            let off = (first as i64 - plan.u0) as usize;
            for (o, p) in out.iter_mut().zip(&src[off..]) {
                *o = p * norm;
            }
        }
        Some(LaserTile { first_col: first, width, e })
    }

    /// Incoherent light: each sub-exposure's illumination times the
    /// reflectance the surface brings under it, summed over the pixels.
    fn incoherent(&mut self, s: &TileShot, plan: &Plan) {
        let (a_mm, b_mm) = s.row_mm;
        let (q, ncols, lit_w) = (plan.q, plan.ncols, plan.ncols * plan.q);
        let finish = has_finish(s.light);
        self.row_e.resize(lit_w, 0.0);
        self.row_y.resize(if finish { lit_w } else { 0 }, 0.0);
        self.colsum.clear();
        self.colsum.resize(plan.img_h * ncols, 0.0);
        for i in 0..plan.img_h {
            let v = plan.sample_v(i as f64);
            illumination(s, plan, v, &mut self.row_e, &mut self.row_y);
            let sums = &mut self.colsum[i * ncols..(i + 1) * ncols];
            for m in 0..plan.steps {
                let x = s.odometer_mm + plan.shift_mm(s, m) + a_mm + b_mm * v;
                for (c, sum) in sums.iter_mut().enumerate() {
                    for j in c * q..(c + 1) * q {
                        let e = self.row_e[j];
                        if e > 0.0 {
                            let r = if finish { surface::reflectance(s.light, s.seed, x, self.row_y[j]) } else { 1.0 };
                            *sum += (e * r) as f32;
                        }
                    }
                }
            }
        }
        add_pixels(&self.colsum, plan, 0, &mut self.pixels);
    }

    /// Laser light: the coherent image of the surface under the line, one
    /// field a shot read at each sub-exposure's place (or, `exact`, one
    /// field per sub-exposure under its own illumination), for each of the
    /// source's patterns up to [`RENDERED_PATTERNS`] (or, `exact`, all);
    /// the rendered patterns' fluctuation about their expectation scaled
    /// to the source's. Returns the patterns rendered.
    fn coherent(&mut self, s: &TileShot, plan: &Plan, p: Pupil, exact: Exact) -> usize {
        let (w, h, q) = (plan.w, plan.h, plan.q);
        let key = FilterKey { w, h, q, pupil: p };
        match self.filters.iter().position(|(k, _, _)| *k == key) {
            Some(0) => {}
            Some(i) => {
                let f = self.filters.remove(i);
                self.filters.insert(0, f);
            }
            None => {
                let planner = self.planner.get_or_insert_with(rustfft::FftPlanner::new);
                self.filters.truncate(FILTERS_KEPT - 1);
                self.filters.insert(0, (key, Filter::planned(planner, &p, q, w, h), None));
            }
        }
        let patterns = s.light.speckle.map_or(1, |sp| sp.patterns as usize);
        let rendered = if exact.patterns { patterns } else { patterns.min(RENDERED_PATTERNS as usize) };
        let many = rendered < patterns;
        if many && self.filters[0].2.is_none() {
            let planner = self.planner.get_or_insert_with(rustfft::FftPlanner::new);
            let t = mean::lsf_transfer(&self.filters[0].1, planner, (w, h), &mut self.field, &mut self.scratch);
            self.filters[0].2 = Some(t);
        }
        if many {
            self.mean_px.clear();
            self.mean_px.resize(self.pixels.len(), 0.0);
        }
        // The illumination is fixed to the head and the surface slides under
        // it: sub-exposure m sees the field of grid rows shifted by its
        // travel. Along the rows the illumination varies only slowly (the
        // line's column and brightness over the image), so one field, under
        // the illumination of the exposure's middle, serves every
        // sub-exposure.
        let groups: Vec<(f64, Vec<usize>)> = if exact.exposure {
            plan.shifts.iter().map(|&d| (d as f64, vec![d])).collect()
        } else {
            let mid = plan.shifts.iter().sum::<usize>() as f64 / plan.steps as f64;
            vec![(mid, plan.shifts.clone())]
        };
        let lit_w = plan.ncols * q;
        // The rail's lateral cell under the tile's first sample column.
        let j0 = plan.u0 * q as i64 + (s.lateral_px * q as f64).round() as i64;
        if self.rings.is_empty() {
            self.rings.resize_with(RINGS, PhasorRing::new);
        }
        self.field.resize(w * h, Complex::new(0.0, 0.0));
        self.colsum.resize(plan.lit_h * plan.ncols, 0.0);
        for (d, reads) in groups {
            self.amplitude(s, plan, d);
            for k in 0..rendered {
                let stream = SPECKLE_STREAM ^ ((s.laser as u64) << 32) ^ ((k as u64) << 48);
                let ring = &mut self.rings[k.min(RINGS - 1)];
                let rows = plan.n_lo..plan.n_lo + plan.lit_h as i64;
                ring.prepare(s.seed, stream, j0..j0 + lit_w as i64, rows, q as i64);
                let field = &mut self.field;
                for i in 0..plan.lit_h {
                    let cells = ring.row(plan.n_lo + i as i64, j0);
                    let f_row = &mut field[i * w..(i + 1) * w];
                    for ((f, &a), c) in f_row.iter_mut().zip(&self.amp[i * lit_w..(i + 1) * lit_w]).zip(cells) {
                        *f = c * a;
                    }
                    f_row[lit_w..].fill(Complex::new(0.0, 0.0));
                }
                field[plan.lit_h * w..].fill(Complex::new(0.0, 0.0));
                self.filters[0].1.apply_with(field, &mut self.scratch);
                for (sums, f_row) in self.colsum.chunks_exact_mut(plan.ncols).zip(field.chunks_exact(w)) {
                    for (sum, px) in sums.iter_mut().zip(f_row.chunks_exact(q)) {
                        *sum = px.iter().map(|f| f.norm_sqr()).sum();
                    }
                }
                for &shift in &reads {
                    add_pixels(&self.colsum, plan, shift, &mut self.pixels);
                }
            }
            if let (true, Some(t)) = (many, &self.filters[0].2) {
                let planner = self.planner.get_or_insert_with(rustfft::FftPlanner::new);
                mean::expected_colsums(&self.amp, lit_w, q, t, planner, &mut self.row_c, &mut self.colsum);
                for &shift in &reads {
                    add_pixels(&self.colsum, plan, shift, &mut self.mean_px);
                }
            }
        }
        if many {
            // Ī + (I_M − Ī)·√(M/K), in sums of M patterns.
            let (m, gain) = (rendered as f64, (rendered as f64 / patterns as f64).sqrt());
            for (p, e) in self.pixels.iter_mut().zip(&self.mean_px) {
                let mean = m * e;
                *p = mean + (*p - mean) * gain;
            }
        }
        rendered
    }

    /// The field's amplitude on the grid, √(illumination × reflectance),
    /// the illumination that of image sample row `i − d` on grid row `i`.
    fn amplitude(&mut self, s: &TileShot, plan: &Plan, d: f64) {
        let (q, lit_w) = (plan.q, plan.ncols * plan.q);
        let finish = has_finish(s.light);
        let b_mm = s.row_mm.1;
        self.row_e.resize(lit_w, 0.0);
        self.row_y.resize(if finish { lit_w } else { 0 }, 0.0);
        self.amp.resize(plan.lit_h * lit_w, 0.0);
        if !finish && !s.light.ghosts.iter().any(|g| g.laser == s.laser) {
            // The line alone: its amplitude is a Gaussian itself, drawn
            // without a square root a sample.
            for (i, amp) in self.amp.chunks_exact_mut(lit_w).enumerate() {
                line_amplitude(s, plan, plan.sample_v(i as f64 - d), &mut self.row_e);
                for (a, &e) in amp.iter_mut().zip(&self.row_e) {
                    *a = e as f32;
                }
            }
            return;
        }
        for (i, amp) in self.amp.chunks_exact_mut(lit_w).enumerate() {
            illumination(s, plan, plan.sample_v(i as f64 - d), &mut self.row_e, &mut self.row_y);
            // Where on the rail the surface row lies (the reflectance is
            // the surface's, tied to it like its phases).
            let x = b_mm * ((plan.n_lo + i as i64) as f64 + 0.5) / q as f64 - b_mm * (plan.g_rows as f64 + 0.5);
            for (j, (a, &e)) in amp.iter_mut().zip(&self.row_e).enumerate() {
                let r = if finish && e > 0.0 { surface::reflectance(s.light, s.seed, x, self.row_y[j]) } else { 1.0 };
                *a = (e * r).sqrt() as f32;
            }
        }
    }
}

/// Adds the pixel sums of the image's rows to `pixels` (`h_img × ncols`),
/// the image's sample row `i` read from grid row `i + shift` of `colsum`
/// (per sample row, the sums over each pixel's columns).
fn add_pixels(colsum: &[f32], plan: &Plan, shift: usize, pixels: &mut [f64]) {
    let (q, ncols) = (plan.q, plan.ncols);
    for (r, out) in pixels.chunks_exact_mut(ncols).enumerate() {
        let i0 = (r + plan.g_rows) * q + shift;
        for i in i0..i0 + q {
            for (o, &c) in out.iter_mut().zip(&colsum[i * ncols..(i + 1) * ncols]) {
                *o += f64::from(c);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::gaussian_row;

    /// The line's amplitude drawn as a Gaussian of its own is the square
    /// root of its illumination to the recurrence's own rounding (10⁻¹¹ in
    /// the far tail), and the `f32` field's amplitudes are the same but for
    /// a rare last bit.
    #[test]
    fn the_amplitude_gaussian_is_the_root_of_the_illumination() {
        let (n, step) = (320, 1.0 / 6.0);
        for (peak, sigma, d0) in [(180.0, 3.1, -26.0), (2.5e4, 1.2, -40.3), (7.0, 6.0, 3.0)] {
            let (mut e, mut a) = (vec![0.0; n], vec![0.0; n]);
            gaussian_row(&mut e, peak, d0, step, sigma, false);
            gaussian_row(&mut a, f64::sqrt(peak), d0, step, sigma * std::f64::consts::SQRT_2, false);
            let mut flips = 0;
            for (e, a) in e.iter().zip(&a) {
                let want = e.sqrt();
                assert!((a - want).abs() <= 1e-10 * want, "{a} vs {want}");
                flips += usize::from(*a as f32 != want as f32);
            }
            assert!(flips <= 3, "{flips} f32 amplitudes of {n} differ");
        }
    }
}
