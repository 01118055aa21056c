//! The joint fit itself: the usable lines, the starts, the ladder's
//! rungs refined from each start, and the joint result of the best.

use super::surface::{Surface, Terms, direction, evaluate_surface, linear_start, q, sigmas, start_detrend, surface};
use super::{Corrected, Joint, Line, spectrum};
use crate::measure::fit::{self, FitError, Options};
use crate::measure::verdict::{self, Verdict};
use crate::model::lm;

/// The F statistic above which a rung of trend terms (the crown's cubic
/// and quartic, the curvature along and the twist) is kept: p < 1e-5 for
/// two extra terms and thousands of points.
pub(super) const F_TREND: f64 = 12.0;

/// One joint fit with the rail's surface (module docs): the result, the
/// corrected profiles and the residuals in the order of the lines' points.
pub(super) fn fit_once(
    lines: &[Line],
    near_mm: Option<f64>,
    also_mm: Option<f64>,
) -> Result<(Joint, Vec<Corrected>, Vec<f64>), FitError> {
    let lines = usable_lines(lines)?;
    let s = surface(&lines)?;
    let nl = lines.len();
    let ladder = ladder(nl);
    let (per_line, omegas) = start_wavelengths(&s, nl, &[near_mm, also_mm])?;
    let mut best: Option<(lm::Lm, Vec<usize>, usize)> = None;
    // Every start's minimum: (wavelength, rss).
    let mut minima: Vec<(f64, f64)> = Vec::new();
    for &omega0 in &omegas {
        let Some((got, free, plane_len)) = fit_from(&s, &per_line, omega0, &ladder) else { continue };
        let yaw = got.p[q::KAPPA].atan2(got.p[q::OMEGA]);
        // Bounds with a meaning: the lines within 45° of the rail.
        if yaw.abs() > std::f64::consts::FRAC_PI_4 || !got.rss.is_finite() {
            continue;
        }
        let k = got.p[q::OMEGA].hypot(got.p[q::KAPPA]);
        minima.push((std::f64::consts::TAU / k, got.rss));
        if best.as_ref().is_none_or(|b| got.rss < b.0.rss) {
            best = Some((got, free, plane_len));
        }
    }
    let Some((lm, free, plane_len)) = best else {
        return Err(FitError::Degenerate("no start converged within the bounds"));
    };
    let joint = joint_of(&s, nl, &lm, &free, plane_len, &minima)?;
    let p = &lm.p;
    let mut out: Vec<Corrected> =
        lines.iter().map(|l| Corrected { laser: l.laser, s_mm: vec![], z_mm: vec![], offset_mm: p[q::C] }).collect();
    let (_, cp, sp) = direction(p[q::OMEGA], p[q::KAPPA]);
    for i in 0..s.x.len() {
        let (x, y, z, l) = (s.x[i], s.y[i], s.z[i], s.line[i]);
        let t = Terms::at(x, y, (cp, sp));
        let trend = t.trend(&p[q::C..q::N]) - p[q::C];
        let o = &mut out[l];
        o.s_mm.push(t.s);
        o.z_mm.push(z - trend);
    }
    let residuals =
        evaluate_surface(&s, p, &[]).map(|(r, _)| r.as_slice().to_vec()).ok_or(FitError::Degenerate("residuals"))?;
    Ok((joint, out, residuals))
}

/// The lines with enough points to fit (8), every coordinate finite.
pub(super) fn usable_lines(lines: &[Line]) -> Result<Vec<Line>, FitError> {
    let lines: Vec<Line> = lines.iter().filter(|l| l.points.len() >= 8).cloned().collect();
    if lines.is_empty() {
        return Err(FitError::TooFewPoints { points: 0, needed: 8 });
    }
    for l in &lines {
        if let Some(index) = l.points.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
            return Err(FitError::NonFinite { index });
        }
    }
    Ok(lines)
}

/// The nested ladder's rungs for `nl` lines, as trend terms (module docs):
/// the plane and the crown's curvature across (three lines), then the
/// crown's cubic and quartic (the lines cross it only where they are
/// yawed), then the curvature along the rail and the twist.
pub(super) fn ladder(nl: usize) -> [Vec<usize>; 3] {
    let several = nl > 1;
    let mut plane = vec![0, 1];
    if several {
        plane.push(2);
    }
    if nl > 2 {
        plane.push(3);
    }
    let mut crown = plane.clone();
    if several {
        crown.extend([4, 5]);
        if nl == 2 {
            crown.push(3);
        }
    }
    let mut along = crown.clone();
    along.push(6);
    if several {
        along.push(7);
    }
    [plane, crown, along]
}

/// One line's `(x, z, mean y)` on what a 2-D polynomial leaves of the surface.
pub(super) type Detrended = (Vec<f64>, Vec<f64>, f64);

/// The starts: on what a 2-D polynomial leaves, `fit`'s sine of every line
/// (each gives an ω), the lines' joint periodogram's peaks, and each of
/// `near_mm` given; with each line's detrended
/// profile.
pub(super) fn start_wavelengths(
    s: &Surface,
    nl: usize,
    near_mm: &[Option<f64>],
) -> Result<(Vec<Detrended>, Vec<f64>), FitError> {
    let rest = start_detrend(s, nl.min(3) - 1).ok_or(FitError::Degenerate("the lines do not span a surface"))?;
    let per_line: Vec<Detrended> = (0..nl)
        .map(|l| {
            let idx: Vec<usize> = (0..s.x.len()).filter(|&k| s.line[k] == l).collect();
            let x: Vec<f64> = idx.iter().map(|&k| s.x[k]).collect();
            let z: Vec<f64> = idx.iter().map(|&k| rest[k]).collect();
            let y = idx.iter().map(|&k| s.y[k]).sum::<f64>() / idx.len() as f64;
            (x, z, y)
        })
        .collect();
    let mut omegas: Vec<f64> = Vec::new();
    for (x, z, _) in &per_line {
        if let Ok(f) = fit::fit(x, z, &Options { model: fit::Model::Sine, components: 1 }) {
            let w = std::f64::consts::TAU / f.wavelength_mm;
            if w.is_finite() && !omegas.iter().any(|o| (o / w - 1.0).abs() < 1e-3) {
                omegas.push(w);
            }
        }
    }
    // The joint periodogram's peaks (`spectrum`): a start within a grid
    // step of one already there ends in the same basin.
    let (lo, hi) = s.x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    let near = spectrum::step(hi - lo);
    for w in spectrum::periodogram_starts(s) {
        if !omegas.iter().any(|o| (o - w).abs() < near) {
            omegas.push(w);
        }
    }
    for w in near_mm.iter().flatten().map(|l| std::f64::consts::TAU / l).filter(|w| w.is_finite() && *w > 0.0) {
        if !omegas.iter().any(|o| (o / w - 1.0).abs() < 1e-3) {
            omegas.push(w);
        }
    }
    if omegas.is_empty() {
        return Err(FitError::Degenerate("no line has a sine"));
    }
    Ok((per_line, omegas))
}

/// The fit from the start at `omega0`: κ from the lines' phases against
/// their lateral positions, then each rung of the ladder refined from its
/// own linear solution and kept only if an F test asks for it over the
/// highest kept so far. The refinement, its free parameters and the
/// plane rung's size.
pub(super) fn fit_from(
    s: &Surface,
    per_line: &[Detrended],
    omega0: f64,
    ladder: &[Vec<usize>; 3],
) -> Option<(lm::Lm, Vec<usize>, usize)> {
    let several = per_line.len() > 1;
    let starts =
        per_line.iter().map(|(x, z, y)| fit::three_param(x, z, omega0).map(|l| (l, *y))).collect::<Option<Vec<_>>>()?;
    let phase = |l: &fit::Linear| l.cos.atan2(l.sin);
    let (y0, ph0) = (starts[0].1, phase(&starts[0].0));
    let pts: Vec<(f64, f64)> = starts
        .iter()
        .map(|(l, y)| {
            let d = phase(l) - ph0;
            (*y - y0, d - std::f64::consts::TAU * (d / std::f64::consts::TAU).round())
        })
        .collect();
    let syy: f64 = pts.iter().map(|p| p.0 * p.0).sum();
    let kappa0 = if several && syy > 1e-6 { pts.iter().map(|p| p.0 * p.1).sum::<f64>() / syy } else { 0.0 };
    let mut p0 = vec![0.0; q::N];
    (p0[q::OMEGA], p0[q::KAPPA]) = (omega0, kappa0);
    let wave: Vec<usize> = if several { vec![q::A, q::B, q::OMEGA, q::KAPPA] } else { vec![q::A, q::B, q::OMEGA] };
    let free_of =
        |terms: &[usize]| -> Vec<usize> { wave.iter().copied().chain(terms.iter().map(|t| q::C + t)).collect() };
    let rungs = ladder.clone().map(|terms| free_of(&terms));
    let plane_len = rungs[0].len();
    let n_all = s.x.len();
    let mut chosen: Option<(lm::Lm, Vec<usize>)> = None;
    let mut tried: Vec<usize> = Vec::new();
    for free in rungs {
        if tried.contains(&free.len()) {
            continue;
        }
        tried.push(free.len());
        // Every rung from the start's own linear solution (a lower rung
        // that cannot represent the surface may have bent the wave off
        // its basin).
        let Some(start) = linear_start(s, &p0, &free) else { continue };
        let Some(got) = lm::levenberg_marquardt(
            start,
            &free,
            fit::MAX_ITERATIONS,
            &mut lm::WithJacobian::new(|p: &[f64]| evaluate_surface(s, p, &free)),
        ) else {
            continue;
        };
        // The start's yaw is a guess from the lines' phases: the terms
        // must still be told apart at the yaw the refinement found.
        if linear_start(s, &got.p, &free).is_none() {
            continue;
        }
        match &chosen {
            None => chosen = Some((got, free)),
            Some((below, below_free)) => {
                let extra = free.len() - below_free.len();
                let better = n_all > free.len() && got.rss < below.rss && {
                    let f = ((below.rss - got.rss) / extra as f64) / (got.rss / (n_all - free.len()) as f64);
                    f > F_TREND
                };
                // A rung that does not pay is passed over, not the end
                // of the ladder.
                if better {
                    chosen = Some((got, free));
                }
            }
        }
    }
    chosen.map(|(got, free)| (got, free, plane_len))
}

/// The joint result of the best refinement `lm` (free parameters `free`)
/// over the surface `s` of `nl` lines, with its uncertainties and, among
/// the other starts' `minima`, an alternative wavelength the data do not
/// rule out.
pub(super) fn joint_of(
    s: &Surface,
    nl: usize,
    lm: &lm::Lm,
    free: &[usize],
    plane_len: usize,
    minima: &[(f64, f64)],
) -> Result<Joint, FitError> {
    let p = &lm.p;
    let (a, b, w, kappa) = (p[q::A], p[q::B], p[q::OMEGA], p[q::KAPPA]);
    let k = w.hypot(kappa);
    let n = s.x.len();
    let tau = std::f64::consts::TAU;
    let amp = a.hypot(b);
    let sigma2 = lm.rss / n.saturating_sub(free.len()).max(1) as f64;
    let mut lgrad = vec![(q::OMEGA, -tau * w / k.powi(3))];
    if nl > 1 {
        lgrad.push((q::KAPPA, -tau * kappa / k.powi(3)));
    }
    let agrad: Vec<(usize, f64)> = if amp > 0.0 { vec![(q::A, a / amp), (q::B, b / amp)] } else { vec![] };
    let sig = sigmas(s, p, free, lm.rss, &[&lgrad, &agrad]);
    let mut joint = Joint {
        lines: nl,
        points: n,
        wavelength_mm: tau / k,
        amplitude_mm: amp,
        phase_rad: b.atan2(a),
        normal: s.normal,
        pitch_rad: s.pitch + p[q::GX].atan(),
        roll_rad: s.roll + p[q::GY].atan(),
        yaw_rad: kappa.atan2(w),
        curvature_per_mm: 2.0 * p[q::SS],
        crown_curvature_per_mm: 2.0 * p[q::U2],
        trend: free.len() > plane_len,
        rms_residual_mm: (lm.rss / n as f64).sqrt(),
        wavelength_sigma_mm: sig[0],
        amplitude_sigma_mm: if amp > 0.0 { sig[1] } else { None },
        iterations: lm.iterations,
        converged: lm.converged,
        rejected: 0,
        alternative_wavelength_mm: None,
        per_line: Vec::new(),
        birge: None,
        verdict: Verdict { level: verdict::Level::Good, reasons: Vec::new(), noise_um: None },
    };
    // Another start's minimum as good within the noise (its residual sum
    // within 9 σ² of this one's) at a wavelength more than 3 σ away: the
    // data do not decide between them.
    if let Some(sl) = joint.wavelength_sigma_mm {
        joint.alternative_wavelength_mm = minima
            .iter()
            .filter(|(l, r)| (l - joint.wavelength_mm).abs() > 3.0 * sl && r - lm.rss < 9.0 * sigma2)
            .map(|m| m.0)
            .next();
    }
    let vals = [joint.wavelength_mm, joint.amplitude_mm, joint.phase_rad, joint.yaw_rad, joint.rms_residual_mm];
    if vals.iter().any(|v| !v.is_finite()) || k <= 0.0 {
        return Err(FitError::Degenerate("values out of range"));
    }
    Ok(joint)
}
