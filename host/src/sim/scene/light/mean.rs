//! The expected intensity of the coherent image, `Ī = A² ⊗ |h|²`: the
//! illumination imaged incoherently through the lens (`h` the pupil
//! filter's impulse response, `A` the field's amplitude), what a source of
//! many independent patterns converges to and what its few rendered
//! patterns fluctuate about ([`super::RENDERED_PATTERNS`]).
//!
//! Along the rows (the rail) the line's illumination varies only slowly
//! against the lens's blur, so each grid row is convolved across with the
//! line-spread function `LSF(u) = Σ_v |h(u, v)|²` (the blur along the rows
//! of a patch's edge is left out: under a pixel at F/2.8, where a patch's
//! reflectance changes over its edge).

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

use super::coherent::Filter;

/// The line-spread function's transfer, divided by `w` (the unnormalised
/// inverse transform): real, as `|h|²` is even about the origin under a
/// pupil with defocus alone. `field` and `scratch` are working buffers.
pub(super) fn lsf_transfer(
    filter: &Filter<f32>,
    planner: &mut FftPlanner<f32>,
    (w, h): (usize, usize),
    field: &mut Vec<Complex<f32>>,
    scratch: &mut Vec<Complex<f32>>,
) -> Vec<f32> {
    field.clear();
    field.resize(w * h, Complex::new(0.0, 0.0));
    field[0] = Complex::new(1.0, 0.0);
    filter.apply_with(field, scratch);
    let mut lsf: Vec<Complex<f32>> = (0..w)
        .map(|u| {
            let s: f64 = field[u..].iter().step_by(w).map(|f| f64::from(f.norm_sqr())).sum();
            Complex::new(s as f32, 0.0)
        })
        .collect();
    planner.plan_fft_forward(w).process(&mut lsf);
    lsf.iter().map(|c| c.re / w as f32).collect()
}

/// The expected intensity of grid rows of amplitude `amp` (`lit_w`
/// samples a row, the rest of the grid's `w` dark), summed over each
/// pixel's `q` columns into `colsum` (a row of `lit_w / q` a grid row).
/// Two real rows go through one complex transform (the transfer is real).
pub(super) fn expected_colsums(
    amp: &[f32],
    lit_w: usize,
    q: usize,
    transfer: &[f32],
    planner: &mut FftPlanner<f32>,
    row: &mut Vec<Complex<f32>>,
    colsum: &mut [f32],
) {
    let w = transfer.len();
    let (fwd, inv) = (planner.plan_fft_forward(w), planner.plan_fft_inverse(w));
    let ncols = lit_w / q;
    let rows = amp.len() / lit_w;
    row.resize(w, Complex::new(0.0, 0.0));
    for i in (0..rows).step_by(2) {
        let a = &amp[i * lit_w..(i + 1) * lit_w];
        let b = amp.get((i + 1) * lit_w..(i + 2) * lit_w);
        for (j, r) in row.iter_mut().enumerate() {
            let re = a.get(j).map_or(0.0, |x| x * x);
            let im = b.and_then(|b| b.get(j)).map_or(0.0, |x| x * x);
            *r = Complex::new(re, im);
        }
        fwd.process(row);
        for (r, t) in row.iter_mut().zip(transfer) {
            *r *= *t;
        }
        inv.process(row);
        for (k, part) in [(i, 0), (i + 1, 1)] {
            let Some(out) = colsum.get_mut(k * ncols..(k + 1) * ncols) else { continue };
            for (c, o) in out.iter_mut().enumerate() {
                *o = row[c * q..(c + 1) * q].iter().map(|z| if part == 0 { z.re } else { z.im }).sum();
            }
        }
    }
}
