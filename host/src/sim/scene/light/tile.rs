//! One laser's stripe over a whole shot, as the light model renders it:
//! the illumination on a grid of samples, its reflectance, the speckle of
//! the coherent image with the surface moving under the line during the
//! exposure, and the pixels' sums. A shot's tiles are made once, on its
//! first row, and kept until another shot is rendered.

use rustfft::num_complex::Complex;

use super::super::StripeTruth;
use super::coherent::{Filter, Pupil, fft_size, phasor};
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

/// The shot's tiles and the filters kept between shots.
#[derive(Default)]
pub(crate) struct LightCache {
    key: Option<(u64, u64, u64, u8)>,
    tiles: Vec<Option<LaserTile>>,
    filters: Vec<Option<(FilterKey, Filter)>>,
}

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

    /// The tiles of shot `key`, if they are the ones kept.
    pub fn tiles_for(&self, key: (u64, u64, u64, u8)) -> Option<&[Option<LaserTile>]> {
        (self.key == Some(key)).then_some(&self.tiles[..])
    }

    /// Keeps `tiles` as shot `key`'s.
    pub fn keep(&mut self, key: (u64, u64, u64, u8), tiles: Vec<Option<LaserTile>>) {
        self.key = Some(key);
        self.tiles = tiles;
    }

    /// Renders one laser's tile (`None`: its line is in no row).
    pub fn render(&mut self, s: &TileShot) -> Option<LaserTile> {
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
        let mut illum = vec![0.0f64; w * h];
        let mut lateral = if finish { vec![0.0f64; w * h] } else { Vec::new() };
        for i in 0..nrows * q {
            let v = sample_v(i);
            let Some(l) = line_at(s.lines, v, s.gain_e_per_dn) else { continue };
            let mm_per_px = l.depth_mm / s.fx_px;
            let inv = -0.5 / (l.sigma * l.sigma);
            for j in 0..ncols * q {
                let u = sample_u(j);
                let d = u - l.c;
                let mut e = l.peak_e * (inv * d * d).exp();
                for g in &ghosts {
                    let sg = l.sigma * g.sigma_factor;
                    let dg = d - g.offset_px - g.tilt_px_per_row * (v - mid_row);
                    e += g.fraction * l.peak_e * (-0.5 * dg * dg / (sg * sg)).exp();
                }
                illum[i * w + j] = e;
                if finish {
                    lateral[i * w + j] = l.y_mm + d * mm_per_px;
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
        let mut acc = vec![0.0f64; w * h];
        let reflect = |m: usize, i: usize, j: usize| {
            let x = s.odometer_mm + shift_mm(m) + a_mm + b_mm * sample_v(i);
            surface::reflectance(light, s.seed, x, lateral[i * w + j])
        };
        match pupil {
            None => {
                for m in 0..steps {
                    for i in 0..nrows * q {
                        for j in 0..ncols * q {
                            let e = illum[i * w + j];
                            if e > 0.0 {
                                acc[i * w + j] += if finish { e * reflect(m, i, j) } else { e };
                            }
                        }
                    }
                }
            }
            Some(p) => {
                let key = FilterKey { w, h, q, pupil: p };
                if self.filters.len() <= s.laser {
                    self.filters.resize_with(s.laser + 1, || None);
                }
                let slot = &mut self.filters[s.laser];
                if slot.as_ref().is_none_or(|(k, _)| *k != key) {
                    *slot = Some((key, Filter::new(&p, q, w, h)));
                }
                let filter = &mut slot.as_mut().expect("made above").1;
                // Surface cell of sample row i at sub-exposure m: i + n_m.
                let n_m: Vec<i64> = (0..steps)
                    .map(|m| ((s.odometer_mm + shift_mm(m) + a_mm) / b_mm * q as f64).round() as i64)
                    .collect();
                let amp: Vec<f64> = illum.iter().map(|e| e.sqrt()).collect();
                let mut field = vec![Complex::new(0.0, 0.0); w * h];
                let j0 = u0 * q as i64;
                for k in 0..patterns {
                    let stream = SPECKLE_STREAM ^ ((s.laser as u64) << 32) ^ ((k as u64) << 48);
                    for (m, &n0) in n_m.iter().enumerate() {
                        for i in 0..h {
                            for j in 0..w {
                                let a = amp[i * w + j];
                                field[i * w + j] = if a > 0.0 {
                                    let r = if finish { reflect(m, i, j).sqrt() } else { 1.0 };
                                    phasor(s.seed, stream, j0 + j as i64, n0 + i as i64) * (a * r)
                                } else {
                                    Complex::new(0.0, 0.0)
                                };
                            }
                        }
                        filter.apply(&mut field);
                        for (a, f) in acc.iter_mut().zip(&field) {
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
                        sum += acc[i * w + j];
                    }
                }
                *out = sum * norm;
            }
        }
        Some(LaserTile { first_col: first, width, e })
    }
}
