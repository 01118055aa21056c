//! The rail top's finish: a reflectance over `(x, y)` (along the rail from
//! the odometer's origin, across from the rail's axis, mm) from oxidation
//! and rust patches, grease films and the running band; and the glints of
//! each line. Every patch and glint is drawn from the seed and its cell
//! along the rail, so the surface is the same whichever frame sees it.

use super::super::stripe::erf;
use super::coherent::phasor;
use super::{Glints, LightModel, Patches, RunningBand};

const OXIDATION_STREAM: u64 = 0x4f58_4944;
const GREASE_STREAM: u64 = 0x4752_4541;
const GLINT_STREAM: u64 = 0x474c_494e;

/// Uniform in [0, 1) from one cell's hash (the phasor's angle, reused as a
/// uniform draw).
fn uniform(seed: u64, stream: u64, cell: i64, k: i64) -> f64 {
    let p = phasor(seed, stream, cell, k);
    (p.im.atan2(p.re) / std::f64::consts::TAU).rem_euclid(1.0)
}

/// A standard normal from two uniforms (Box–Muller).
fn normal(seed: u64, stream: u64, cell: i64, k: i64) -> f64 {
    let u1 = uniform(seed, stream, cell, k).max(1e-300);
    let u2 = uniform(seed, stream, cell, k + 1);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

fn lerp(r: [f64; 2], t: f64) -> f64 {
    r[0] + (r[1] - r[0]) * t
}

/// How much of a patch covers a point `d` mm inside its edge (negative:
/// outside), over an edge of `edge_mm`.
fn coverage(d: f64, edge_mm: f64) -> f64 {
    if edge_mm <= 0.0 {
        if d >= 0.0 { 1.0 } else { 0.0 }
    } else {
        // A smooth step over the edge (C¹).
        let t = (d / edge_mm + 0.5).clamp(0.0, 1.0);
        t * t * (3.0 - 2.0 * t)
    }
}

/// The factor one family of patches puts on the reflectance at `(x, y)`.
fn patches_at(p: &Patches, seed: u64, stream: u64, x: f64, y: f64) -> f64 {
    if p.per_m <= 0.0 {
        return 1.0;
    }
    let cell_mm = 1000.0 / p.per_m;
    let reach = p.length_mm[1] / 2.0 + p.edge_mm;
    let (c0, c1) = (((x - reach) / cell_mm).floor() as i64, ((x + reach) / cell_mm).floor() as i64);
    let mut r = 1.0;
    for cell in c0..=c1 {
        let xc = (cell as f64 + uniform(seed, stream, cell, 0)) * cell_mm;
        let yc = (2.0 * uniform(seed, stream, cell, 1) - 1.0) * p.spread_mm;
        let a = lerp(p.length_mm, uniform(seed, stream, cell, 2)) / 2.0;
        let b = lerp(p.width_mm, uniform(seed, stream, cell, 3)) / 2.0;
        let rho = (((x - xc) / a).powi(2) + ((y - yc) / b).powi(2)).sqrt();
        // Distance inside the ellipse's edge, near enough at the edge.
        let d = (1.0 - rho) * a.min(b);
        let c = coverage(d, p.edge_mm);
        if c > 0.0 {
            let refl = lerp(p.reflectance, uniform(seed, stream, cell, 4));
            r *= 1.0 - (1.0 - refl) * c;
        }
    }
    r
}

fn band_at(b: &RunningBand, y: f64) -> f64 {
    let d = b.half_width_mm - (y - b.centre_mm).abs();
    b.outside + (1.0 - b.outside) * coverage(d, b.edge_mm)
}

/// The rail top's reflectance at `(x, y)`, relative to clean steel.
pub(crate) fn reflectance(light: &LightModel, seed: u64, x_mm: f64, y_mm: f64) -> f64 {
    let mut r = patches_at(&light.oxidation, seed, OXIDATION_STREAM, x_mm, y_mm);
    r *= patches_at(&light.grease, seed, GREASE_STREAM, x_mm, y_mm);
    if let Some(b) = &light.band {
        r *= band_at(b, y_mm);
    }
    r
}

/// One line's row for the glints: where the line is and what it looks like.
#[derive(Clone, Copy, Debug)]
pub(crate) struct GlintRow {
    /// The laser (each line has its own glints).
    pub laser: usize,
    /// The line's centre and σ there, px, and its peak, electrons.
    pub column_px: f64,
    pub sigma_px: f64,
    pub peak_e: f64,
    /// Along-rail position the row sees: `x = x0_mm + mm_per_row·(r − row)` near it.
    pub x0_mm: f64,
    pub mm_per_row: f64,
    /// Travel during the exposure, mm (a glint streaks over it).
    pub travel_mm: f64,
}

/// Adds the glints of one line near a row to `buf` (electrons).
pub(crate) fn add_glints(g: &Glints, seed: u64, at: &GlintRow, buf: &mut [f64]) {
    if g.per_m <= 0.0 || at.mm_per_row == 0.0 || at.peak_e <= 0.0 {
        return;
    }
    let cell_mm = 1000.0 / g.per_m;
    let streak_rows = (at.travel_mm / at.mm_per_row).abs();
    // The glint's σ along the rows, lengthened by the streak (a box of its
    // length: variance L²/12), its peak lowered to keep its light.
    let sv = (g.sigma_px * g.sigma_px + streak_rows * streak_rows / 12.0).sqrt();
    let reach_rows = 5.0 * sv + 1.0;
    let reach_mm = reach_rows * at.mm_per_row.abs();
    let stream = GLINT_STREAM ^ (at.laser as u64) << 40;
    let (c0, c1) = (((at.x0_mm - reach_mm) / cell_mm).floor() as i64, ((at.x0_mm + reach_mm) / cell_mm).floor() as i64);
    let box_px = |d: f64, s: f64| {
        let k = std::f64::consts::FRAC_1_SQRT_2 / s;
        0.5 * (erf((d + 0.5) * k) - erf((d - 0.5) * k))
    };
    for cell in c0..=c1 {
        let xg = (cell as f64 + uniform(seed, stream, cell, 0)) * cell_mm;
        let dv = (xg - at.x0_mm) / at.mm_per_row;
        if dv.abs() > reach_rows {
            continue;
        }
        let ug = at.column_px + 0.7 * at.sigma_px * normal(seed, stream, cell, 1);
        let gain = lerp(g.gain, uniform(seed, stream, cell, 3));
        // Light of a glint of σ px and the given peak, spread over σ × sv.
        let light = at.peak_e * gain * 2.0 * std::f64::consts::PI * g.sigma_px * g.sigma_px;
        let wv = box_px(dv, sv);
        let lo = ((ug - 5.0 * g.sigma_px - 1.0).floor().max(0.0)) as usize;
        let hi = ((ug + 5.0 * g.sigma_px + 1.0).ceil() as usize).min(buf.len().saturating_sub(1));
        for (i, b) in buf.iter_mut().enumerate().take(hi + 1).skip(lo) {
            *b += light * wv * box_px(i as f64 - ug, g.sigma_px);
        }
    }
}
