//! EN 15610's nonlinear steps on the rail, not on the noise.
//!
//! Spike removal and the wheel are not linear: run on a line as measured,
//! the 0.375 m wheel rides on speckle's peaks and lifts the whole
//! spectrum of the noise, and the standard's spike criterion (a second
//! difference of a few µm at 0.5 mm) takes tens of "spikes" a metre out of
//! noise alone. The standard means them for the rail: the wheel's contact
//! with the rail's shape, the rail's dirt. So the steps are run on an
//! estimate of the rail `r̂`, and their effect `N(r̂) − r̂` is added to
//! each line ([`Correction`]): the rail gets the standard's treatment and
//! each line's own noise passes through linearly, where the noise floor
//! measured from the lines' null combinations can see it.
//!
//! The estimate ([`RailSteps`]) is the lines' mean, and
//! * its spikes are those the standard's criterion finds on it with
//!   [`en15610::SPIKE_EVIDENCE_Z`] standard deviations of the mean's noise
//!   to spare, in sharpness (second difference) and in height
//!   ([`en15610::remove_spikes_over`]): a spike the lines agree on, not
//!   speckle, nor noise pushing a rounded crest over the criterion;
//! * the wheel rolls on that despiked mean with its noise taken out by a
//!   Wiener gain per frequency, `G = max(0, 1 − β · S_n / S_mean)` with
//!   `β` = [`OVERSUBTRACTION`]: the rail's spectrum where it stands over
//!   the mean's noise (which the null combinations measure, `S_n` = their
//!   power over the number of lines), nothing where it does not. The
//!   gain is smoothed over a third of an octave and applied by overlap-add
//!   of periodic Hann segments (which sum to one), each run odd-reflected
//!   at its ends.
//!
//! A noise-free survey (or one line, whose noise nothing tells from its
//! rail: [`RailSteps::exact`]) has `G = 1` and no evidence threshold: the
//! steps are the standard's, exactly, on the rail. Costs: the gain
//! `O(N log M)` (Welch, `M` the segment), the filter the same; then the
//! standard's steps once on the estimate instead of once per line.

use std::ops::Range;

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

use super::en15610::{self, Options, SpikeNoise};
use super::{check_dx, remove_mean_and_trend, samples_for, segments};

/// Oversubtraction of the Wiener gain: a frequency reaches the wheel's
/// estimate only where the mean's power is more than this many times its
/// noise's (the rail's own power at least the noise's), so the noise's
/// estimate scattering about its truth lets almost none of it through.
pub const OVERSUBTRACTION: f64 = 2.0;

/// The nonlinear steps' effect on a rail estimate, to add to a line.
#[derive(Debug, Clone, PartialEq)]
pub struct Correction {
    /// `N(r̂) − r̂` per sample of the stretch, µm (NaN where there is no estimate).
    pub c_um: Vec<f64>,
    /// Peaks of the spikes removed, indices in the stretch, ascending.
    pub spikes_at: Vec<usize>,
}

impl Correction {
    /// No estimate anywhere in a stretch of `n` samples.
    pub fn none(n: usize) -> Correction {
        Correction { c_um: vec![f64::NAN; n], spikes_at: Vec::new() }
    }
}

/// How the steps see the rail through a stretch's noise: the Wiener
/// gain per bin of `m`-sample segments, and the noise of a spike's height.
pub struct RailSteps {
    dx_mm: f64,
    /// Per FFT bin (`None`: the estimate is the rail itself).
    gain: Option<Vec<f64>>,
    m: usize,
    spike_noise: SpikeNoise,
}

impl RailSteps {
    /// The estimate is the rail itself: no noise known (one line).
    pub fn exact(dx_mm: f64) -> RailSteps {
        RailSteps { dx_mm, gain: None, m: 0, spike_noise: SpikeNoise::default() }
    }

    /// From the lines' mean over a stretch (NaN where not every line has
    /// a sample) and their null combinations over it (each with one
    /// line's noise), `lines` lines; segments of `opt.segment_mm`.
    pub fn measure(mean_um: &[f64], nulls_um: &[&[f64]], lines: usize, dx_mm: f64, opt: &Options) -> RailSteps {
        let k = lines.max(1) as f64;
        if check_dx(dx_mm).is_err() || nulls_um.is_empty() {
            return RailSteps::exact(dx_mm);
        }
        // A spike's height over its edges' line, on white noise of σ per
        // sample: variance σ²(1 + a² + b²) ≤ 2σ², σ² from the nulls'
        // sample-to-sample differences (what a few samples' span sees);
        // the second difference's straight from the nulls'.
        let (mut d1, mut d2, mut count) = (0.0, 0.0, 0usize);
        for n in nulls_um {
            for w in n.windows(3).filter(|w| w.iter().all(|v| v.is_finite())) {
                d1 += (w[1] - w[0]).powi(2) / 2.0;
                d2 += (w[2] - 2.0 * w[1] + w[0]).powi(2);
                count += 1;
            }
        }
        let dx_m = dx_mm / 1000.0;
        let spike_noise = if count > 0 {
            SpikeNoise {
                height_um: (2.0 * d1 / count as f64 / k).sqrt(),
                curvature_um_per_m2: (d2 / count as f64 / k).sqrt() / (dx_m * dx_m),
            }
        } else {
            SpikeNoise::default()
        };
        let m = samples_for(opt.segment_mm, dx_mm).clamp(4, 1 << 40).next_multiple_of(2);
        let runs: Vec<Range<usize>> = segments(mean_um).into_iter().filter(|r| r.len() >= m).collect();
        if runs.is_empty() {
            return RailSteps { dx_mm, gain: None, m, spike_noise };
        }
        let fft = FftPlanner::<f64>::new().plan_fft_forward(m);
        let window = hann(m);
        let (mut p_mean, mut p_noise) = (vec![0.0; m / 2 + 1], vec![0.0; m / 2 + 1]);
        for run in &runs {
            psd_add(&mean_um[run.clone()], &window, fft.as_ref(), &mut p_mean, 1.0);
            for n in nulls_um {
                if n[run.clone()].iter().all(|v| v.is_finite()) {
                    psd_add(&n[run.clone()], &window, fft.as_ref(), &mut p_noise, 1.0 / (k * nulls_um.len() as f64));
                }
            }
        }
        let (s_mean, s_noise) = (third_octave_smoothed(&p_mean), third_octave_smoothed(&p_noise));
        let half: Vec<f64> =
            s_mean
                .iter()
                .zip(&s_noise)
                .enumerate()
                .map(|(b, (&sm, &sn))| {
                    if b == 0 || sn <= 0.0 {
                        1.0
                    } else {
                        (1.0 - OVERSUBTRACTION * sn / sm.max(1e-300)).clamp(0.0, 1.0)
                    }
                })
                .collect();
        let gain = (0..m).map(|b| half[b.min(m - b)]).collect();
        RailSteps { dx_mm, gain: Some(gain), m, spike_noise }
    }

    /// The standard's steps (as `opt` asks) on the estimate `est_um` (NaN
    /// for gaps), spikes decided on it and the wheel rolled on it
    /// denoised: `N(r̂) − r̂`.
    pub fn correction(&self, est_um: &[f64], opt: &Options) -> Correction {
        let mut despiked = est_um.to_vec();
        let mut spikes_at = Vec::new();
        if opt.remove_spikes {
            en15610::remove_spikes_over(&mut despiked, self.dx_mm, self.spike_noise, &mut spikes_at);
            spikes_at.sort_unstable();
        }
        let mut c_um: Vec<f64> = despiked.iter().zip(est_um).map(|(d, e)| d - e).collect();
        if opt.curvature {
            let rail = self.denoised(&despiked);
            let rolled = en15610::curvature_process(&rail, self.dx_mm, opt.wheel_radius_mm);
            for ((c, r), w) in c_um.iter_mut().zip(&rail).zip(&rolled) {
                *c += w - r;
            }
        }
        Correction { c_um, spikes_at }
    }

    /// The estimate with the gain applied, run by run (a run shorter than
    /// a segment, which holds no segment of the spectrum, as it is).
    fn denoised(&self, z_um: &[f64]) -> Vec<f64> {
        let mut out = z_um.to_vec();
        let Some(gain) = &self.gain else { return out };
        let m = self.m;
        let h = m / 2;
        let mut planner = FftPlanner::<f64>::new();
        let (fwd, inv) = (planner.plan_fft_forward(m), planner.plan_fft_inverse(m));
        let window = hann(m);
        for run in segments(z_um).into_iter().filter(|r| r.len() >= m) {
            let y = &z_um[run.clone()];
            let l = y.len();
            // Odd reflection at both ends, so that every sample lies under two windows.
            let right = (h * (h + l - 1).div_euclid(h) + m) - h - l;
            let e: Vec<f64> = (0..h + l + right)
                .map(|p| {
                    let t = p as isize - h as isize;
                    if t < 0 {
                        2.0 * y[0] - y[(-t) as usize]
                    } else if (t as usize) < l {
                        y[t as usize]
                    } else {
                        2.0 * y[l - 1] - y[2 * (l - 1) - t as usize]
                    }
                })
                .collect();
            let mut acc = vec![0.0; e.len()];
            let mut start = 0;
            while start + m <= e.len() {
                filter_segment(&e[start..start + m], &window, gain, fwd.as_ref(), inv.as_ref(), &mut acc[start..]);
                start += h;
            }
            out[run].copy_from_slice(&acc[h..h + l]);
        }
        out
    }
}

fn hann(m: usize) -> Vec<f64> {
    (0..m).map(|i| 0.5 - 0.5 * (std::f64::consts::TAU * i as f64 / m as f64).cos()).collect()
}

/// Adds `scale ·` the power per bin of `y`'s Hann segments (mean and trend removed, hop `m/2`).
fn psd_add(y: &[f64], window: &[f64], fft: &dyn Fft<f64>, power: &mut [f64], scale: f64) {
    let m = window.len();
    let mut start = 0;
    while start + m <= y.len() {
        let mut seg = y[start..start + m].to_vec();
        remove_mean_and_trend(&mut seg);
        let mut buf: Vec<Complex<f64>> = seg.iter().zip(window).map(|(v, w)| Complex::new(v * w, 0.0)).collect();
        fft.process(&mut buf);
        for (p, x) in power.iter_mut().zip(&buf) {
            *p += scale * x.norm_sqr();
        }
        start += m / 2;
    }
}

/// Each bin's power averaged over a third of an octave about it.
fn third_octave_smoothed(p: &[f64]) -> Vec<f64> {
    let mut prefix = vec![0.0; p.len() + 1];
    for (i, v) in p.iter().enumerate() {
        prefix[i + 1] = prefix[i] + v;
    }
    let r = 2f64.powf(1.0 / 6.0);
    (0..p.len())
        .map(|b| {
            let lo = ((b as f64 / r).floor() as usize).min(b);
            let hi = ((b as f64 * r).ceil() as usize).max(b).min(p.len() - 1);
            (prefix[hi + 1] - prefix[lo]) / (hi + 1 - lo) as f64
        })
        .collect()
}

/// One windowed segment through the gain, added into `acc`.
fn filter_segment(y: &[f64], window: &[f64], gain: &[f64], fwd: &dyn Fft<f64>, inv: &dyn Fft<f64>, acc: &mut [f64]) {
    let m = y.len() as f64;
    let mut buf: Vec<Complex<f64>> = y.iter().zip(window).map(|(v, w)| Complex::new(v * w, 0.0)).collect();
    fwd.process(&mut buf);
    for (x, g) in buf.iter_mut().zip(gain) {
        *x *= g;
    }
    inv.process(&mut buf);
    for (a, x) in acc.iter_mut().zip(&buf) {
        *a += x.re / m;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analyze::standards::en15610::{Spectrum, Welch, curvature_process, remove_spikes};
    use crate::analyze::standards::{Stretch, segments};

    const DX_MM: f64 = 0.5;

    use crate::analyze::seeded_gauss as gauss;

    /// Three lines of `rail` with white noise of `sigma_um` each: the
    /// lines, their mean and their Helmert nulls.
    fn lines(rail: &[f64], sigma_um: f64, seed: u64) -> (Vec<Vec<f64>>, Vec<f64>, Vec<Vec<f64>>) {
        let mut g = gauss(seed);
        let z: Vec<Vec<f64>> = (0..3).map(|_| rail.iter().map(|r| r + sigma_um * g()).collect()).collect();
        let mean = (0..rail.len()).map(|i| (z[0][i] + z[1][i] + z[2][i]) / 3.0).collect();
        let nulls = vec![
            (0..rail.len()).map(|i| (z[0][i] - z[1][i]) / 2f64.sqrt()).collect(),
            (0..rail.len()).map(|i| (z[0][i] + z[1][i] - 2.0 * z[2][i]) / 6f64.sqrt()).collect(),
        ];
        (z, mean, nulls)
    }

    fn spectrum(z: &[f64], correction: Option<&Correction>, opt: &Options) -> Spectrum {
        let runs = segments(z);
        let mut w = Welch::new(&runs, DX_MM, opt).unwrap();
        let s = Stretch { z_um: z, start: 0, core: 0..z.len(), runs: &runs, dx_mm: DX_MM };
        match correction {
            Some(c) => w.add_corrected(&s, c, opt),
            None => w.add(&s, opt),
        };
        w.spectrum()
    }

    fn corrugated(n: usize) -> Vec<f64> {
        // 8 mm at 12 µm (curvature over the wheel's: it bridges), 16–200 mm, a spike of dirt.
        let sines = [(8.0, 12.0), (16.0, 6.0), (25.0, 8.0), (50.0, 30.0), (100.0, 40.0), (200.0, 60.0)];
        let mut r: Vec<f64> = (0..n)
            .map(|i| {
                let x = i as f64 * DX_MM;
                sines.iter().map(|(l, a)| a * (x * std::f64::consts::TAU / l + l).sin()).sum()
            })
            .collect();
        r[n / 3] += 80.0;
        r
    }

    /// Noise-free lines: the mean is the rail, the gain one and no
    /// evidence asked: exactly the standard's steps on the rail.
    #[test]
    fn noise_free_lines_get_the_standards_steps() {
        let rail = corrugated(8_000);
        let zero = vec![0.0; rail.len()];
        let opt = Options::default();
        let steps = RailSteps::measure(&rail, &[&zero, &zero], 3, DX_MM, &opt);
        let c = steps.correction(&rail, &opt);
        let mut want = rail.clone();
        let spikes = remove_spikes(&mut want, DX_MM);
        let want = curvature_process(&want, DX_MM, opt.wheel_radius_mm);
        let worst = rail.iter().zip(&c.c_um).zip(&want).map(|((r, c), w)| (r + c - w).abs()).fold(0.0, f64::max);
        assert!(worst < 1e-9, "{worst} µm");
        assert_eq!((c.spikes_at.len(), spikes), (1, 1));
    }

    /// A smooth rail under noise: no spike taken, and each line's
    /// third octaves read its noise as the linear processing does (the
    /// wheel on the noise itself lifts 50–250 mm by several dB).
    #[test]
    fn noise_passes_through_linearly() {
        let n = 24_000;
        let (z, mean, nulls) = lines(&vec![0.0; n], 3.0, 11);
        let opt = Options::default();
        let nulls: Vec<&[f64]> = nulls.iter().map(Vec::as_slice).collect();
        let c = RailSteps::measure(&mean, &nulls, 3, DX_MM, &opt).correction(&mean, &opt);
        assert!(c.spikes_at.is_empty(), "{:?}", c.spikes_at);
        let linear = Options { remove_spikes: false, curvature: false, ..opt.clone() };
        let (ours, lin, own) =
            (spectrum(&z[0], Some(&c), &opt), spectrum(&z[0], None, &linear), spectrum(&z[0], None, &opt));
        for ((o, l), w) in ours.bands.iter().zip(&lin.bands).zip(&own.bands) {
            assert!(
                (o.level_db - l.level_db).abs() < 0.5,
                "{} mm: {} vs {} dB",
                o.nominal_wavelength_mm,
                o.level_db,
                l.level_db
            );
            if (50.0..=250.0).contains(&o.nominal_wavelength_mm) {
                assert!(
                    w.level_db - l.level_db > 4.0,
                    "{} mm: the wheel on the noise {} vs {} dB",
                    w.nominal_wavelength_mm,
                    w.level_db,
                    l.level_db
                );
            }
        }
    }

    /// A corrugated rail under noise: each line's third octaves, the
    /// noise's power taken out, are the standard's on the noise-free rail
    /// within the level's 99.9 % interval (its Welch degrees of freedom),
    /// and the dirt is taken out.
    #[test]
    fn the_rail_keeps_its_spectrum_under_noise() {
        let n = 24_000;
        let rail = corrugated(n);
        let (z, mean, nulls) = lines(&rail, 3.0, 5);
        let opt = Options::default();
        let nulls_ref: Vec<&[f64]> = nulls.iter().map(Vec::as_slice).collect();
        let c = RailSteps::measure(&mean, &nulls_ref, 3, DX_MM, &opt).correction(&mean, &opt);
        assert_eq!(c.spikes_at.len(), 1, "{:?}", c.spikes_at);
        let truth = spectrum(&rail, None, &opt);
        let noise: Vec<f64> = z[0].iter().zip(&rail).map(|(z, r)| z - r).collect();
        let floor = spectrum(&noise, None, &Options { remove_spikes: false, curvature: false, ..opt.clone() });
        let ours = spectrum(&z[0], Some(&c), &opt);
        let mut checked = 0;
        for ((o, t), f) in ours.bands.iter().zip(&truth.bands).zip(&floor.bands) {
            if t.level_db < f.level_db + 3.0 {
                continue;
            }
            let rail_db = 10.0 * (10f64.powf(o.level_db / 10.0) - 10f64.powf(f.level_db / 10.0)).max(1e-30).log10();
            let interval_db = 10.0 * std::f64::consts::LOG10_E * 3.29 * (2.0 / o.dof).sqrt();
            assert!(
                (rail_db - t.level_db).abs() <= interval_db.max(0.5),
                "{} mm: rail {rail_db:.2} dB vs truth {:.2} dB (±{interval_db:.2})",
                o.nominal_wavelength_mm,
                t.level_db
            );
            println!(
                "{} mm: rail {rail_db:.2} dB, truth {:.2} dB, ±{interval_db:.2}",
                o.nominal_wavelength_mm, t.level_db
            );
            checked += 1;
        }
        assert!(checked >= 8, "{checked}");
    }
}
