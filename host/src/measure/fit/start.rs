//! Start values of ω: the DFT peak, the ellipse of a profile against its integral, a scan of the three-parameter fit.

use super::{
    IEEE_MAX_ITERATIONS, Linear, MAX_RESAMPLED, MAX_SCAN_RESAMPLED, Start, four_param_ieee, jacquelin, three_param,
};
use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};
use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

/// The profile resampled on a uniform grid over its x span (linear
/// interpolation between x-sorted points): `(x0, dx, values)`.
pub(super) fn resample(x: &[f64], z: &[f64]) -> Option<(f64, f64, Vec<f64>)> {
    resample_to(x, z, MAX_RESAMPLED)
}

/// [`resample`] on at most `cap` samples.
pub(super) fn resample_to(x: &[f64], z: &[f64], cap: usize) -> Option<(f64, f64, Vec<f64>)> {
    let mut pts: Vec<(f64, f64)> = x.iter().copied().zip(z.iter().copied()).collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (x0, x1) = (pts.first()?.0, pts.last()?.0);
    let m = pts.len().clamp(2, cap.max(2));
    let dx = (x1 - x0) / (m - 1) as f64;
    if !(dx > 0.0 && dx.is_finite()) {
        return None;
    }
    let mut out = Vec::with_capacity(m);
    let mut j = 0;
    for i in 0..m {
        let t = x0 + dx * i as f64;
        while j + 2 < pts.len() && pts[j + 1].0 < t {
            j += 1;
        }
        let (a, b) = (pts[j], pts[(j + 1).min(pts.len() - 1)]);
        let w = if b.0 > a.0 { ((t - a.0) / (b.0 - a.0)).clamp(0.0, 1.0) } else { 0.0 };
        out.push(a.1 + w * (b.1 - a.1));
    }
    Some((x0, dx, out))
}

/// Slope and intercept of the least-squares straight line.
pub(super) fn line_fit(x: &[f64], z: &[f64]) -> Option<(f64, f64)> {
    let n = x.len() as f64;
    let (mx, mz) = (x.iter().sum::<f64>() / n, z.iter().sum::<f64>() / n);
    let sxx: f64 = x.iter().map(|x| (x - mx).powi(2)).sum();
    let sxz: f64 = x.iter().zip(z).map(|(x, z)| (x - mx) * (z - mz)).sum();
    let slope = sxz / sxx;
    (slope.is_finite() && sxx > 0.0).then_some((slope, mz - slope * mx))
}

/// ω at the interpolated peak of the DFT magnitude of the detrended,
/// uniformly resampled profile (zero-padded ×8: bins of `2π/(8·span)`),
/// over wavelengths from two samples up to twice the span.
pub fn dft_omega(x: &[f64], z: &[f64]) -> Option<f64> {
    let (_, dx, mut v) = resample(x, z)?;
    let t: Vec<f64> = (0..v.len()).map(|i| i as f64).collect();
    let (slope, icpt) = line_fit(&t, &v)?;
    for (i, v) in v.iter_mut().enumerate() {
        *v -= icpt + slope * i as f64;
    }
    let m = v.len() as f64;
    // Zero-padded ×8: bin j of the 8M-point FFT is j/8 cycles per record;
    // bins 4..=4M are 0.5 .. M/2 cycles per record in steps of 1/8.
    let len = 8 * v.len();
    let mut buf = vec![Complex::new(0.0, 0.0); len];
    for (b, &v) in buf.iter_mut().zip(&v) {
        b.re = v;
    }
    FftPlanner::<f64>::new().plan_fft_forward(len).process(&mut buf);
    let bins: Vec<f64> = (4..=(4 * v.len())).map(|j| j as f64 / 8.0).collect();
    let mag: Vec<f64> = buf[4..=(4 * v.len())].iter().map(|c| c.norm()).collect();
    let k = (0..mag.len()).max_by(|&a, &b| mag[a].total_cmp(&mag[b]))?;
    let mut f = bins[k];
    if k > 0 && k + 1 < mag.len() {
        let (a, b, c) = (mag[k - 1], mag[k], mag[k + 1]);
        let den = a - 2.0 * b + c;
        if den < 0.0 {
            f += 0.5 * (a - c) / den / 8.0;
        }
    }
    let omega = 2.0 * std::f64::consts::PI * f / (m * dx);
    (omega.is_finite() && omega > 0.0).then_some(omega)
}

/// The paper's ellipse method (docs/reference.md §3): on the uniformly resampled,
/// differenced profile `d[n] = y[n+k] − y[n]` (which removes the rotation's
/// trend), the points `(d[n], d[n+k])` lie on the ellipse
/// `u² − 2uv·cos(ωk) + v² = const`; a linear least-squares fit of that
/// symmetric conic (with a free centre) gives `cos(ωk)`. The lag k is the sample count
/// nearest a quarter of the wavelength `2π/omega_prior`, kept below half of
/// it (where `acos` is unambiguous).
pub fn ellipse_omega(x: &[f64], z: &[f64], omega_prior: f64) -> Option<f64> {
    let (_, dx, v) = resample(x, z)?;
    let quarter = std::f64::consts::FRAC_PI_2 / omega_prior / dx;
    let k = (quarter.round() as usize).max(1);
    if !(quarter.is_finite() && (k as f64) < 2.0 * quarter) || v.len() < 2 * k + 6 {
        return None;
    }
    let d: Vec<f64> = (0..v.len() - k).map(|n| v[n + k] - v[n]).collect();
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    let scale = d.iter().map(|d| (d - mean).abs()).fold(0.0, f64::max);
    if scale.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    // Both axes carry the same sinusoid, so the conic is symmetric:
    // u² + v² = 2C·uv + E·u + F·v + G, linear in (C, E, F, G), C = cos ωk.
    let mut ata = Matrix4::zeros();
    let mut atb = Vector4::zeros();
    for n in 0..d.len() - k {
        let (u, w) = ((d[n] - mean) / scale, (d[n + k] - mean) / scale);
        let row = Vector4::new(2.0 * u * w, u, w, 1.0);
        ata += row * row.transpose();
        atb += row * (u * u + w * w);
    }
    let cos_wk = ata.cholesky()?.solve(&atb)[0];
    if !cos_wk.is_finite() || cos_wk.abs() >= 1.0 {
        return None;
    }
    let omega = cos_wk.acos() / (k as f64 * dx);
    (omega.is_finite() && omega > 0.0).then_some(omega)
}

/// The fallback that cannot diverge: the three-parameter residual `S(ω)`
/// at every bin of the ×8 zero-padded spectrum (steps of `2π/(8·span)`)
/// over `[omega_lo, omega_hi]`, then golden-section search of
/// [`three_param`] on the points themselves in the bracket around the best
/// of the three deepest minima. Returns `(ω, S(ω))`.
///
/// `S(ω)` on the grid is exact for the profile resampled uniformly (on as
/// many samples as it has points, up to 2^20): with `t = i·dx` every sum
/// the normal equations need is a DFT bin (`Σ z e^{−iωt}`, one FFT for all
/// of them) or a geometric series (`Σ e^{−iωt}`, `Σ e^{−2iωt}`), so the
/// whole scan costs one FFT of 8 × the points and a 3 × 3 solve per bin,
/// not one pass over the points per grid step: 10⁶ points in well under a
/// second, where evaluating [`three_param`] on 4 096 grid steps took 95 s
/// (and under-resolved the grid besides). Points that are not evenly
/// spaced are interpolated for the grid only; the three candidates are
/// judged, and the minimum refined, on the points.
pub fn scan_omega(x: &[f64], z: &[f64], omega_lo: f64, omega_hi: f64) -> Option<(f64, f64)> {
    let (lo_x, hi_x) = x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    let span = hi_x - lo_x;
    if !(span > 0.0 && omega_hi > omega_lo && omega_lo > 0.0) {
        return None;
    }
    let (_, dx, v) = resample_to(x, z, MAX_SCAN_RESAMPLED)?;
    let m = v.len();
    let len = 8 * m;
    let mut buf = vec![Complex::new(0.0, 0.0); len];
    for (b, &v) in buf.iter_mut().zip(&v) {
        b.re = v;
    }
    FftPlanner::<f64>::new().plan_fft_forward(len).process(&mut buf);
    let (zsum, zz) = (v.iter().sum::<f64>(), v.iter().map(|v| v * v).sum::<f64>());
    let mf = m as f64;
    // Σ_{i<m} e^{iθi}, with the θ → 0 (mod 2π) limit.
    let geometric = |theta: f64| -> Complex<f64> {
        let one = Complex::new(1.0, 0.0);
        let den = one - Complex::from_polar(1.0, theta);
        if den.norm() < 1e-12 { Complex::new(mf, 0.0) } else { (one - Complex::from_polar(1.0, theta * mf)) / den }
    };
    let omega_of = |j: usize| std::f64::consts::TAU * j as f64 / (len as f64 * dx);
    let j_lo = ((omega_lo / omega_of(1)).ceil() as usize).max(1);
    let j_hi = ((omega_hi / omega_of(1)).floor() as usize).min(len / 2);
    if j_lo > j_hi {
        return None;
    }
    // S at bin j: z·z − p·(Aᵀz), (AᵀA) p = Aᵀz with A = [sin ωt, cos ωt, 1].
    let s_at = |j: usize| -> f64 {
        let theta = std::f64::consts::TAU * j as f64 / len as f64;
        let (g1, g2) = (geometric(theta), geometric(2.0 * theta));
        let (sum_c, sum_s) = (g1.re, g1.im);
        let (ss, cc, sc) = (0.5 * (mf - g2.re), 0.5 * (mf + g2.re), 0.5 * g2.im);
        // buf[j] = Σ z e^{−iθi}: Σ z cos = re, Σ z sin = −im.
        let (zc, zs) = (buf[j].re, -buf[j].im);
        let ata = Matrix3::new(ss, sc, sum_s, sc, cc, sum_c, sum_s, sum_c, mf);
        let atb = Vector3::new(zs, zc, zsum);
        ata.cholesky().map_or(f64::INFINITY, |c| zz - c.solve(&atb).dot(&atb))
    };
    let s: Vec<f64> = (j_lo..=j_hi).map(s_at).collect();
    // The three deepest local minima of the grid.
    let mut minima: Vec<usize> = (0..s.len())
        .filter(|&i| s[i].is_finite() && (i == 0 || s[i] <= s[i - 1]) && (i + 1 == s.len() || s[i] <= s[i + 1]))
        .collect();
    minima.sort_by(|&a, &b| s[a].total_cmp(&s[b]));
    minima.truncate(3);
    let rss = |w: f64| three_param(x, z, w).map_or(f64::INFINITY, |l| l.rss);
    let clamp = |w: f64| w.clamp(omega_lo, omega_hi);
    let (best_w, best_s) =
        minima.iter().map(|&i| (omega_of(j_lo + i), rss(omega_of(j_lo + i)))).min_by(|p, q| p.1.total_cmp(&q.1))?;
    if !best_s.is_finite() {
        return None;
    }
    let step = omega_of(1);
    let (mut a, mut b) = (clamp(best_w - step), clamp(best_w + step));
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (rss(c), rss(d));
    while b - a > 1e-13 * b.abs() + f64::MIN_POSITIVE {
        if fc < fd {
            (b, d, fd) = (d, c, fc);
            c = b - g * (b - a);
            fc = rss(c);
        } else {
            (a, c, fc) = (c, d, fd);
            d = a + g * (b - a);
            fd = rss(d);
        }
    }
    let w = 0.5 * (a + b);
    [(w, rss(w)), (best_w, best_s)].into_iter().min_by(|p, q| p.1.total_cmp(&q.1))
}

/// The best start of one sine on `(x, z)`: IEEE iterations from the DFT and
/// ellipse estimates and the fallback scan; the lowest three-parameter
/// residual wins.
pub(super) fn sine_start(x: &[f64], z: &[f64]) -> Option<(f64, Linear, Start)> {
    let (lo, hi) = x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    let span = hi - lo;
    let band = (std::f64::consts::PI / span, std::f64::consts::PI * (x.len() - 1) as f64 / span);
    let in_band = |w: f64| w >= band.0 * (1.0 - 1e-9) && w <= band.1 * (1.0 + 1e-9);
    let dft = dft_omega(x, z);
    let ellipse = dft.and_then(|w| ellipse_omega(x, z, w));
    let jacq = jacquelin(x, z);
    let mut best: Option<(f64, Linear, Start)> = None;
    let mut consider = |w: f64, lin: Linear, start: Start| {
        if best.as_ref().is_none_or(|b| lin.rss < b.1.rss) {
            best = Some((w, lin, start));
        }
    };
    if let Some(j) = jacq
        && in_band(j.omega)
    {
        consider(j.omega, j.linear, Start::Jacquelin);
    }
    for (w0, start) in [(dft, Start::Dft), (ellipse, Start::Ellipse), (jacq.map(|j| j.omega), Start::Jacquelin)] {
        if let Some(r) = w0.and_then(|w0| four_param_ieee(x, z, w0, IEEE_MAX_ITERATIONS))
            && r.converged
            && in_band(r.omega)
        {
            consider(r.omega, r.linear, start);
        }
    }
    if let Some((w, _)) = scan_omega(x, z, band.0, band.1)
        && let Some(lin) = three_param(x, z, w)
    {
        consider(w, lin, Start::Scan);
    }
    best
}
