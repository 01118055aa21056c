//! One laser's stripe over a whole shot, as the light model renders it:
//! the illumination on a grid of samples, its reflectance, the speckle of
//! the coherent image with the surface moving under the line during the
//! exposure, and the pixels' sums. A shot's tiles are made once, on its
//! first row, and kept until another shot is rendered.

use rustfft::num_complex::Complex;

use super::super::StripeTruth;
use super::coherent::{Filter, Pupil, fft_size};
use super::ring::PhasorRing;
use super::{LightModel, surface};

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
}

/// One laser's filter, phasor rings and buffers, kept between shots.
#[derive(Default)]
struct LaserState {
    filter: Option<(FilterKey, Filter<f32>)>,
    /// Pattern `k`'s surface cells in ring `min(k, RINGS − 1)`: the first
    /// patterns are kept from shot to shot, the others drawn each shot.
    rings: Vec<PhasorRing>,
    illum: Vec<f64>,
    lateral: Vec<f64>,
    amp: Vec<f32>,
    field: Vec<Complex<f32>>,
    acc: Vec<f32>,
    /// The last tile's grid: samples across, along, sub-exposures.
    grid: (usize, usize, usize),
}

/// Phasor rings per laser (their memory: a shot's cells, about 4 MB at F/4).
const RINGS: usize = 3;

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

    /// Renders the tiles of shot `key`, one per laser (`None`: the laser is
    /// off or its line in no row), and keeps them. The lasers render on
    /// threads of their own when the host has cores for them; each tile
    /// depends only on its laser's shot, so the pixels are the same either way.
    pub fn render_shot(&mut self, key: (u64, u64, u64, u8), shots: &[Option<TileShot>]) {
        if self.lasers.len() < shots.len() {
            self.lasers.resize_with(shots.len(), LaserState::default);
        }
        let lit = shots.iter().flatten().count();
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let tiles = if lit < 2 || cores < 2 {
            self.lasers.iter_mut().zip(shots).map(|(st, s)| s.as_ref().and_then(|s| st.render(s))).collect()
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
                                let tile = st.render(s);
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

impl LaserState {
    /// Renders one laser's tile (`None`: its line is in no row).
    fn render(&mut self, s: &TileShot) -> Option<LaserTile> {
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
            let defocus_um = m * m * (depth - s.focus_mm) * 1e3;
            Pupil::new(s.wavelength_um, sp.f_number, m, s.pixel_pitch_um, defocus_um)
        });
        let q = pupil.map_or(4, |p| p.samples_per_px());
        // Guards: the field's reach (a few speckles and the defocus blur)
        // beyond the light, so the FFT's wrap-round meets darkness.
        let guard_px = pupil.map_or(1, |p| {
            let blur = (p.defocus_waves.abs() * 8.0 / (2.0 * p.cutoff_per_px)).ceil();
            (3.0 * p.speckle_px() + blur).ceil() as i64 + 3
        });
        let ghosts: Vec<_> = light.ghosts.iter().filter(|g| g.laser == s.laser).collect();
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (r, l) in s.lines.iter().enumerate() {
            let Some(l) = l else { continue };
            lo = lo.min(l.column_px - 6.0 * l.sigma_px);
            hi = hi.max(l.column_px + 6.0 * l.sigma_px);
            for g in &ghosts {
                let c = l.column_px + g.offset_px + g.tilt_px_per_row * (r as f64 - mid_row);
                lo = lo.min(c - 6.0 * l.sigma_px * g.sigma_factor);
                hi = hi.max(c + 6.0 * l.sigma_px * g.sigma_factor);
            }
        }
        let u0 = lo.floor() as i64 - guard_px;
        let u1 = hi.ceil() as i64 + guard_px;
        let g_rows = if pupil.is_some() { guard_px } else { 0 };
        let (ncols, nrows) = ((u1 - u0 + 1) as usize, h_img + 2 * g_rows as usize);
        let (w, h) = if pupil.is_some() { (fft_size(ncols * q), fft_size(nrows * q)) } else { (ncols * q, nrows * q) };
        let (a_mm, b_mm) = s.row_mm;
        let sample_u = |j: usize| u0 as f64 + (j as f64 + 0.5) / q as f64 - 0.5;
        let sample_v = |i: usize| -(g_rows as f64) + (i as f64 + 0.5) / q as f64 - 0.5;
        // The geometric illumination (fixed to the head) and, per sample,
        // where on the rail top it falls (for the reflectance).
        let finish = light.oxidation.per_m > 0.0 || light.grease.per_m > 0.0 || light.band.is_some();
        let illum = &mut self.illum;
        illum.clear();
        illum.resize(w * h, 0.0);
        let lateral = &mut self.lateral;
        lateral.clear();
        if finish {
            lateral.resize(w * h, 0.0);
        }
        for i in 0..nrows * q {
            let v = sample_v(i);
            let Some(l) = line_at(s.lines, v, s.gain_e_per_dn) else { continue };
            let mm_per_px = l.depth_mm / s.fx_px;
            let out = &mut illum[i * w..i * w + ncols * q];
            let d0 = sample_u(0) - l.c;
            gaussian_row(out, l.peak_e, d0, 1.0 / q as f64, l.sigma, false);
            for g in &ghosts {
                let dg0 = d0 - g.offset_px - g.tilt_px_per_row * (v - mid_row);
                gaussian_row(out, g.fraction * l.peak_e, dg0, 1.0 / q as f64, l.sigma * g.sigma_factor, true);
            }
            if finish {
                for (j, y) in lateral[i * w..i * w + ncols * q].iter_mut().enumerate() {
                    *y = l.y_mm + (sample_u(j) - l.c) * mm_per_px;
                }
            }
        }
        // Sub-exposures: the surface slides under the line by the travel.
        let travel_rows = s.travel_mm / b_mm;
        let spacing_rows = pupil.map_or(0.5, |p| p.speckle_px() / 4.0);
        let steps = if travel_rows.abs() < spacing_rows {
            1
        } else {
            ((travel_rows.abs() / spacing_rows).ceil() as usize + 1).min(MAX_STEPS)
        };
        let shift_mm = |m: usize| {
            if steps == 1 { 0.0 } else { s.travel_mm * (m as f64 / (steps - 1) as f64 - 0.5) }
        };
        let patterns = light.speckle.map_or(1, |sp| sp.patterns as usize);
        self.grid = (w, h, steps);
        let reflect = |m: usize, i: usize, j: usize| {
            let x = s.odometer_mm + shift_mm(m) + a_mm + b_mm * sample_v(i);
            surface::reflectance(light, s.seed, x, lateral[i * w + j])
        };
        let acc = &mut self.acc;
        acc.clear();
        acc.resize(w * h, 0.0);
        match pupil {
            None => {
                for m in 0..steps {
                    for i in 0..nrows * q {
                        for j in 0..ncols * q {
                            let e = illum[i * w + j];
                            if e > 0.0 {
                                acc[i * w + j] += (if finish { e * reflect(m, i, j) } else { e }) as f32;
                            }
                        }
                    }
                }
            }
            Some(p) => {
                let key = FilterKey { w, h, q, pupil: p };
                if self.filter.as_ref().is_none_or(|(k, _)| *k != key) {
                    self.filter = Some((key, Filter::new(&p, q, w, h)));
                }
                let filter = &mut self.filter.as_mut().expect("made above").1;
                // Surface cell of sample row i at sub-exposure m: i + n_m.
                let n_m: Vec<i64> = (0..steps)
                    .map(|m| ((s.odometer_mm + shift_mm(m) + a_mm) / b_mm * q as f64).round() as i64)
                    .collect();
                let amp = &mut self.amp;
                amp.clear();
                amp.extend(illum.iter().map(|e| e.sqrt() as f32));
                let field = &mut self.field;
                field.clear();
                field.resize(w * h, Complex::new(0.0, 0.0));
                let j0 = u0 * q as i64;
                let (lit_w, lit_h) = (ncols * q, nrows * q);
                let n_lo = n_m.iter().copied().min().unwrap_or(0);
                let n_hi = n_m.iter().copied().max().unwrap_or(0) + lit_h as i64;
                if self.rings.is_empty() {
                    self.rings.resize_with(RINGS, PhasorRing::new);
                }
                for k in 0..patterns {
                    let stream = SPECKLE_STREAM ^ ((s.laser as u64) << 32) ^ ((k as u64) << 48);
                    let ring = &mut self.rings[k.min(RINGS - 1)];
                    ring.prepare(s.seed, stream, j0..j0 + lit_w as i64, n_lo..n_hi, q as i64);
                    for (m, &n0) in n_m.iter().enumerate() {
                        for i in 0..lit_h {
                            let cells = ring.row(n0 + i as i64, j0);
                            let (f_row, a_row) = (&mut field[i * w..i * w + lit_w], &amp[i * w..i * w + lit_w]);
                            for (j, ((f, &a), c)) in f_row.iter_mut().zip(a_row).zip(cells).enumerate() {
                                let r = if finish && a > 0.0 { reflect(m, i, j).sqrt() as f32 } else { 1.0 };
                                *f = c * (a * r);
                            }
                            field[i * w + lit_w..(i + 1) * w].fill(Complex::new(0.0, 0.0));
                        }
                        field[lit_h * w..].fill(Complex::new(0.0, 0.0));
                        filter.apply(field);
                        for (a, f) in acc.iter_mut().zip(field.iter()) {
                            *a += f.norm_sqr();
                        }
                    }
                }
            }
        }
        // Pixel sums over the image's rows and columns.
        let first = u0.max(0) as usize;
        let last = (u1.min(s.width_px as i64 - 1)).max(u0.max(0)) as usize;
        let width = last + 1 - first;
        let norm = 1.0 / ((steps * patterns * q * q) as f64);
        let mut e = vec![0.0; width * h_img];
        for r in 0..h_img {
            for (cc, out) in e[r * width..(r + 1) * width].iter_mut().enumerate() {
                let col = (first + cc) as i64 - u0;
                let mut sum = 0.0;
                for i in (r + g_rows as usize) * q..(r + g_rows as usize + 1) * q {
                    for j in col as usize * q..(col as usize + 1) * q {
                        sum += f64::from(acc[i * w + j]);
                    }
                }
                *out = sum * norm;
            }
        }
        Some(LaserTile { first_col: first, width, e })
    }
}
