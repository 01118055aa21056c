//! Each line's own noise floor, from the survey's own data.
//!
//! The lines see the same rail, so the difference of two lines holds
//! their two noises alone: `var(z_i − z_j) = σ_i² + σ_j²` (independent
//! noises). With three lines the three pairs give each line's own:
//! `σ_i² = P_ij + P_ik − P_jk` for the pairs' powers `P_ij = var(z_i − z_j)/2`,
//! band by band and third octave by third octave. One line crossing
//! grease or a dull patch, behind a dirty window or with its laser out of
//! focus then carries its own floor, and the others keep theirs.
//!
//! Each pair goes through exactly the processing a line's noise does (the
//! EN 13231-3 band filters; EN 15610's steps, which act on the rail the
//! lines share, so that a line's noise passes them linearly with the
//! steps' effect on the mean's noise added; the Welch spectrum), as the
//! null lines do ([`crate::analyze::floor`]).
//! A band's pair figures are exact linear combinations of the null lines'
//! band traces (the filters are linear); the third octaves' pairs are
//! built from the null lines' samples and processed on their own.
//!
//! # How well a line's floor is known
//!
//! A difference of power estimates is less certain than either: with `ν`
//! degrees of freedom per pair spectrum, and `c_x = (σ_x²/2)²` the
//! pairs' covariances (complex Gaussian: `cov(|u|², |v|²) = |E[u v*]|²`),
//! `var σ̂_i² = (2/ν)·(P_ij² + P_ik² + P_jk² + 2c_i − 2c_j − 2c_k)`, so
//! the line's floor has `ν σ̂_i⁴ / (…)` degrees of freedom — 0.4 ν for
//! equal lines, far fewer for a quiet line beside a noisy one. The
//! verdict ([`crate::analyze::standards::detection`]) carries them.
//!
//! An estimate can fall under zero (a quiet line beside a noisy one, few
//! segments): it is clipped at [`MIN_SHARE`] of the lines' mean floor
//! power and said so ([`LineFloor::clipped`]); its degrees of freedom are
//! then few and the verdict wide.
//!
//! Two lines cannot be told apart (one difference, two unknowns): each
//! carries the pair's mean, the survey's floor. More than three lines are
//! not separated here either (the head has three).

use std::collections::BTreeMap;

use super::floor::BandFloor;
use super::pieces::RunningBand;
use crate::analyze::standards::en13231;
use crate::analyze::standards::wheel::Correction;
use crate::analyze::standards::{Stretch, en15610, fmt_nominal_mm};

/// A line's floor power is at least this share of the lines' mean (−10 dB).
pub const MIN_SHARE: f64 = 0.1;

/// A line's floor stands out when it is this much over the other lines' mean, dB.
pub const STANDS_OUT_DB: f64 = 3.0;

/// What a floor standing out over the others' most likely is.
pub const LIKELY_CAUSES: &str =
    "grease or a dull patch under that line, a dirty window in front of it, or its laser out of focus";

/// One line's own floor.
#[derive(Debug, Clone, PartialEq)]
pub struct LineFloor {
    /// The laser's number.
    pub laser: usize,
    /// Per EN 13231-3 band ([`en13231::BANDS`] order; `None`: not known).
    pub bands: Vec<Option<BandFloor>>,
    /// Per one-third octave: the floor's level and degrees of freedom.
    pub spectrum: Option<en15610::Spectrum>,
    /// Bands and third octaves (nominal wavelengths, mm) where the estimate
    /// fell under [`MIN_SHARE`] of the mean and was clipped there.
    pub clipped: Vec<String>,
}

/// Per pair of lasers `(i, j)`, `i < j`, per band: its sum of squares
/// (mm²) and count.
type BandPairs = BTreeMap<(usize, usize), [(f64, usize); 4]>;

/// The pairs' EN 15610 Welch averages, in any order of pieces (their
/// band sums are [`PairBands`]).
#[derive(Default)]
pub struct PairSums {
    spectra: BTreeMap<(usize, usize), Option<en15610::Welch>>,
}

/// The pairs' band sums alone, in any order of pieces.
#[derive(Debug, Clone, Default)]
pub struct PairBands {
    pairs: BandPairs,
}

/// The weight of Helmert contrast `m` (from 1) on line `l`.
fn helmert(m: usize, l: usize) -> f64 {
    let norm = ((m * (m + 1)) as f64).sqrt();
    match l.cmp(&m) {
        std::cmp::Ordering::Less => 1.0 / norm,
        std::cmp::Ordering::Equal => -(m as f64) / norm,
        std::cmp::Ordering::Greater => 0.0,
    }
}

/// The pairs `(i, j)` of `k` lines in order, each with the weights on
/// the null combinations that make `(z_i − z_j)/√2`:
/// `Σ_m (H_m[i] − H_m[j])/√2 · n_m`.
fn pair_weights(k: usize) -> Vec<((usize, usize), Vec<f64>)> {
    let mut out = Vec::new();
    for i in 0..k {
        for j in i + 1..k {
            let c = (1..k).map(|m| (helmert(m, i) - helmert(m, j)) / std::f64::consts::SQRT_2).collect();
            out.push(((i, j), c));
        }
    }
    out
}

/// Whether a running band of lasers `lasers` can be paired: three lines.
fn pairable(band: &RunningBand, lasers: &[usize]) -> bool {
    let k = band.lines;
    k == 3 && lasers.len() == k && band.nulls.len() == k - 1
}

impl PairBands {
    /// Adds a piece's running band (lines of lasers `lasers`, in its
    /// order) over `within` (indices in the piece's core).
    pub fn add(&mut self, band: &RunningBand, lasers: &[usize], within: std::ops::Range<usize>) {
        if !pairable(band, lasers) {
            return;
        }
        for ((i, j), c) in pair_weights(band.lines) {
            let entry = self.pairs.entry((lasers[i], lasers[j])).or_insert([(0.0, 0); 4]);
            for (b, sums) in entry.iter_mut().enumerate() {
                let traces: Option<Vec<&en13231::BandTrace>> =
                    band.nulls.iter().map(|n| n.bands.get(b).and_then(Option::as_ref)).collect();
                let Some(traces) = traces else { continue };
                let len = traces.iter().map(|t| t.band_mm.len()).min().unwrap_or(0);
                for t in within.start.min(len)..within.end.min(len) {
                    // Where the filters have settled (the window statistics are there): a
                    // run's ends, where the point reflection over one noisy sample puts a
                    // step's worth of long wavelengths, would sway the lines' shares.
                    if traces.iter().any(|tr| !tr.mean_pp_mm[t].is_finite()) {
                        continue;
                    }
                    let v: f64 = traces.iter().zip(&c).map(|(tr, c)| c * tr.band_mm[t]).sum();
                    if v.is_finite() {
                        sums.0 += v * v;
                        sums.1 += 1;
                    }
                }
            }
        }
    }

    /// Adds the sums of other pieces.
    pub fn merge(&mut self, o: &PairBands) {
        for (key, theirs) in &o.pairs {
            let mine = self.pairs.entry(*key).or_insert([(0.0, 0); 4]);
            for (m, t) in mine.iter_mut().zip(theirs) {
                m.0 += t.0;
                m.1 += t.1;
            }
        }
    }

    /// Each line's own floor in the bands alone ([`PairSums::lines`]
    /// without spectra).
    pub fn lines(&self, shared: &[Option<BandFloor>]) -> Vec<LineFloor> {
        lines_of(&self.pairs, None, shared)
    }
}

impl PairSums {
    /// Adds a piece's running band (lines of lasers `lasers`, in its
    /// order) over its core; `corrections` are EN 15610's steps' effect
    /// on the mean's noise (one per null line, as the survey's floor
    /// takes them); `welch` makes a pair's spectrum accumulator.
    pub fn add(
        &mut self,
        band: &RunningBand,
        lasers: &[usize],
        core: std::ops::Range<usize>,
        opts: &en15610::Options,
        corrections: &[Correction],
        welch: &dyn Fn() -> Option<en15610::Welch>,
    ) {
        if !pairable(band, lasers) {
            return;
        }
        for (pair_index, ((i, j), c)) in pair_weights(band.lines).into_iter().enumerate() {
            let correction = &corrections[pair_index % corrections.len().max(1)];
            let entry = self.spectra.entry((lasers[i], lasers[j])).or_insert_with(welch);
            if let Some(w) = entry {
                let stretches: Vec<Stretch> = band.nulls.iter().map(|n| n.stretch(core.clone())).collect();
                let first = &stretches[0];
                let z: Vec<f64> =
                    (0..first.z_um.len()).map(|t| stretches.iter().zip(&c).map(|(s, c)| c * s.z_um[t]).sum()).collect();
                // The lines' shared correction cancels in their difference: the
                // pair's noise passes linearly, with the mean's noise's share on it.
                let pair = Stretch { z_um: &z, ..first.clone() };
                w.add_corrected(&pair, correction, opts);
            }
        }
    }

    /// Each line's own floor from the pairs' band sums `bands` and these
    /// spectra, its band figures scaled from `shared` (one line's floor
    /// averaged over the lines); empty unless exactly three lines were paired.
    pub fn lines(&self, bands: &PairBands, shared: &[Option<BandFloor>]) -> Vec<LineFloor> {
        lines_of(&bands.pairs, Some(&self.spectra), shared)
    }
}

/// Each line's own floor from the pairs' band sums and (where given)
/// spectra, its band figures scaled from `shared`.
fn lines_of(
    bands: &BandPairs,
    spectra: Option<&BTreeMap<(usize, usize), Option<en15610::Welch>>>,
    shared: &[Option<BandFloor>],
) -> Vec<LineFloor> {
    let mut lasers: Vec<usize> = bands.keys().flat_map(|&(i, j)| [i, j]).collect();
    lasers.sort_unstable();
    lasers.dedup();
    if lasers.len() != 3 || bands.len() != 3 {
        return Vec::new();
    }
    let key = |a: usize, b: usize| (a.min(b), a.max(b));
    let mut out: Vec<LineFloor> = lasers
        .iter()
        .map(|&laser| LineFloor { laser, bands: Vec::new(), spectrum: None, clipped: Vec::new() })
        .collect();
    for (b, band) in en13231::BANDS.iter().enumerate() {
        let p = |x: usize, y: usize| {
            let (sq, n) = bands[&key(lasers[x], lasers[y])][b];
            (n > 0).then(|| sq / n as f64)
        };
        let (Some(p01), Some(p02), Some(p12), Some(s)) = (p(0, 1), p(0, 2), p(1, 2), shared[b]) else {
            out.iter_mut().for_each(|l| l.bands.push(None));
            continue;
        };
        let own = separate([p01, p02, p12], f64::INFINITY);
        let mean = (p01 + p02 + p12) / 3.0;
        for (l, (v, _, clipped)) in out.iter_mut().zip(own) {
            if clipped {
                l.clipped.push(band.name());
            }
            l.bands.push(Some(s.scaled(s.rms_mm * (v / mean).sqrt())));
        }
    }
    let spectra: Vec<en15610::Spectrum> = [(0, 1), (0, 2), (1, 2)]
        .iter()
        .filter_map(|&(x, y)| spectra?.get(&key(lasers[x], lasers[y]))?.as_ref().filter(|w| w.segments() > 0))
        .map(en15610::Welch::spectrum)
        .collect();
    if let [s01, s02, s12] = &spectra[..] {
        let mut own: Vec<en15610::Spectrum> = vec![s01.clone(); 3];
        let pw = |s: &en15610::Spectrum, t: usize| 10f64.powf(s.bands[t].level_db / 10.0);
        let pairs: Vec<[f64; 3]> = (0..s01.bands.len()).map(|t| [pw(s01, t), pw(s02, t), pw(s12, t)]).collect();
        for (t, b) in s01.bands.iter().enumerate() {
            for ((o, l), (v, dof, clipped)) in own.iter_mut().zip(&mut out).zip(pooled(&pairs, &s01.bands, t)) {
                o.bands[t].level_db = 10.0 * v.max(1e-30).log10();
                o.bands[t].dof = dof;
                if clipped {
                    l.clipped.push(format!("{} mm", fmt_nominal_mm(b.nominal_wavelength_mm)));
                }
            }
        }
        for (l, s) in out.iter_mut().zip(own) {
            l.spectrum = Some(s);
        }
    }
    // Nothing measured (the common runs too short for any band or segment): nothing to tell.
    if out.iter().all(|l| l.bands.iter().all(Option::is_none) && l.spectrum.is_none()) {
        return Vec::new();
    }
    out
}

/// Third octaves either side whose lines' shares are pooled with a band's.
pub const POOL_THIRD_OCTAVES: usize = 2;

/// The three lines' own floor powers at third octave `t` from the pairs'
/// powers `pairs` (per third octave): each line's share of the lines'
/// mean pooled over [`POOL_THIRD_OCTAVES`] either side (weighted by their
/// degrees of freedom: a line's noise keeps its shape over a factor 2.5 of
/// wavelength, and a quiet line's share beside a noisy one is otherwise
/// known to a few degrees of freedom), times the band's own mean.
fn pooled(pairs: &[[f64; 3]], bands: &[en15610::ThirdOctave], t: usize) -> [(f64, f64, bool); 3] {
    let mean = |p: &[f64; 3]| (p[0] + p[1] + p[2]) / 3.0;
    let window = t.saturating_sub(POOL_THIRD_OCTAVES)..(t + POOL_THIRD_OCTAVES + 1).min(pairs.len());
    let (mut q, mut dof) = ([0.0; 3], 0.0);
    for u in window {
        let m = mean(&pairs[u]);
        if m > 0.0 {
            for (qi, p) in q.iter_mut().zip(pairs[u]) {
                *qi += bands[u].dof * p / m;
            }
            dof += bands[u].dof;
        }
    }
    let m_t = mean(&pairs[t]);
    if dof <= 0.0 || m_t <= 0.0 {
        return separate(pairs[t], bands[t].dof);
    }
    let shares = separate(q.map(|v| v / dof), dof);
    // The band's mean: Var = (2/ν)/9 · (ΣP² + 2Σc), c_x = (σ_x²/2)².
    let own: [f64; 3] = std::array::from_fn(|i| shares[i].0 * m_t);
    let c: f64 = own.iter().map(|v| (v / 2.0).powi(2)).sum();
    let sq: f64 = pairs[t].iter().map(|p| p * p).sum();
    let mean_dof = bands[t].dof * 9.0 * m_t * m_t / (sq + 2.0 * c);
    std::array::from_fn(|i| (own[i], 1.0 / (1.0 / shares[i].1 + 1.0 / mean_dof), shares[i].2))
}

/// Three lines' own powers from their pairs' `[P_01, P_02, P_12]`
/// (`P_ij = (σ_i² + σ_j²)/2`), each with its degrees of freedom (the
/// pairs having `dof` each) and whether it was clipped at [`MIN_SHARE`]
/// of the mean.
pub fn separate(p: [f64; 3], dof: f64) -> [(f64, f64, bool); 3] {
    let [p01, p02, p12] = p;
    let raw = [p01 + p02 - p12, p01 + p12 - p02, p02 + p12 - p01];
    let mean = (p01 + p02 + p12) / 3.0;
    let min = MIN_SHARE * mean;
    let s: [f64; 3] = std::array::from_fn(|i| raw[i].max(min));
    let c: [f64; 3] = std::array::from_fn(|i| (s[i] / 2.0).powi(2));
    let sq = p01 * p01 + p02 * p02 + p12 * p12;
    std::array::from_fn(|i| {
        let (j, k) = ((i + 1) % 3, (i + 2) % 3);
        let bracket = (sq + 2.0 * c[i] - 2.0 * c[j] - 2.0 * c[k]).max(1e-3 * sq);
        let own_dof = if dof.is_finite() { (dof * s[i] * s[i] / bracket).min(dof) } else { dof };
        (s[i], own_dof, raw[i] < min)
    })
}

/// The line whose floor stands out over the others' most, with by how
/// much (dB, the median over the bands known) — `None` when none stands
/// [`STANDS_OUT_DB`] over.
pub fn standing_out(lines: &[LineFloor]) -> Option<(usize, f64)> {
    let mut best: Option<(usize, f64)> = None;
    for (i, l) in lines.iter().enumerate() {
        let mut ratios: Vec<f64> = (0..en13231::BANDS.len())
            .filter_map(|b| {
                let own = l.bands.get(b).copied().flatten()?.rms_mm;
                let others: Vec<f64> = lines
                    .iter()
                    .enumerate()
                    .filter(|&(j, _)| j != i)
                    .filter_map(|(_, o)| Some(o.bands.get(b).copied().flatten()?.rms_mm.powi(2)))
                    .collect();
                let mean = others.iter().sum::<f64>() / others.len().max(1) as f64;
                (mean > 0.0 && own > 0.0).then(|| 10.0 * (own * own / mean).log10())
            })
            .collect();
        if ratios.is_empty() {
            continue;
        }
        ratios.sort_by(f64::total_cmp);
        let median = ratios[ratios.len() / 2];
        if median >= STANDS_OUT_DB && best.is_none_or(|(_, r)| median > r) {
            best = Some((l.laser, median));
        }
    }
    best
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod unit {
    use super::*;

    /// Exact pair powers give each line its own; a line whose estimate
    /// falls under the clip is clipped and said so.
    #[test]
    fn three_pairs_give_three_floors() {
        let (a, b, c) = (400.0, 25.0, 36.0);
        let p = [(a + b) / 2.0, (a + c) / 2.0, (b + c) / 2.0];
        let s = separate(p, 100.0);
        for (got, want) in s.iter().zip([a, b, c]) {
            assert!((got.0 - want).abs() < 1e-9, "{s:?}");
            assert!(!got.2 && got.1 > 0.0 && got.1 <= 100.0);
        }
        // The quiet lines' floors are far less certain than the noisy one's.
        assert!(s[1].1 < 0.2 * s[0].1, "{s:?}");
        // Equal lines: 0.4 ν each.
        let e = separate([1.0, 1.0, 1.0], 100.0);
        assert!((e[0].1 - 40.0).abs() < 1e-9, "{e:?}");
        let clipped = separate([100.0, 100.0, 0.0], 10.0);
        assert!(clipped[1].2 && clipped[2].2 && !clipped[0].2, "{clipped:?}");
    }
}
