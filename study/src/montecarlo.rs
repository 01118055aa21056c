//! Monte-Carlo accuracy study and synthetic speed rows, shared by
//! `cms-host bench` and the criterion benchmark (one implementation).
//!
//! # Accuracy protocol
//! Every (stripe σ, SNR) *scenario* draws its own rows from a generator seeded
//! by `(seed, scenario index)`; every method sees the *same* rows (common
//! random numbers), so differences between methods are not sampling luck, and
//! the result does not depend on how scenarios are spread over threads.
//!
//! A trial: true centre `x0` drawn by a [`Placement`] (uniform over sub-pixel
//! offsets, never only .0 or .5), the clean stripe `A·exp(−(i−x0)²/(2σ²))`,
//! white noise of σn from [`awgn_sigma`] (MATLAB `awgn(…, snr, 'measured')`
//! over the whole row, background excluded), then the background added and
//! the row quantised to `bits`. The Cramér–Rao bound uses the effective noise
//! `sqrt(σn² + 1/12)` (quantisation as uniform white noise of 1/12 LSB²).
//!
//! Levels: by default amplitude = 2^(bits−1) and background = 2^(bits−2)
//! (2048 and 1024 at 12 bits): at the worst cell (σ = 10 px, 10 dB) the noise
//! is σn ≈ 124 counts, so both the floor (8 σn below the background) and the
//! saturation level (8.8 σn above the peak) are out of the noise's reach.
//! [`CellStats::clipped`] counts the samples that reached 0 or full scale.

use crate::{Gauss, Rng, awgn_sigma, clean_row, crlb, quantise};
use cms_core::fixed::Px;
use cms_core::optics::ScaleRange;
use cms_core::peak::{Config, Detector, Method, Stripes};
use std::fmt::Write as _;

/// Samples per row of the accuracy study (the paper's 480).
pub const ROW_LEN: usize = 480;
/// Stripe widths (Gaussian σ, px) of the study.
pub const SIGMAS: [f64; 4] = [1.5, 2.5, 4.0, 10.0];
/// SNRs (dB, measured over the whole row) of the study.
pub const SNRS_DB: [f64; 4] = [10.0, 20.0, 30.0, 40.0];
/// Trials per cell needed for the full study.
pub const FULL_TRIALS: usize = 200;
/// Where the true centre is drawn in the study: uniform over this range.
pub const STUDY_X0: (f64, f64) = (100.0, 380.0);

/// The paper's synthetic protocol (§6.2, Table 3).
pub mod paper {
    /// Stripe σ, px.
    pub const SIGMA: f64 = 10.0;
    /// Scale range, px.
    pub const SCALES: (f64, f64) = (5.0, 15.0);
    /// True centre, px.
    pub const X0: f64 = 107.5;
    /// SNR, dB (measured over the row).
    pub const SNR_DB: f64 = 30.0;
    /// Trials.
    pub const TRIALS: usize = 100;
    /// Table 3 as printed: (method, the paper's label, accuracy ± px).
    pub const TABLE3: [(cms_core::peak::Method, &str, f64); 3] = [
        (cms_core::peak::Method::Cog, "Center of gravity", 0.0154),
        (cms_core::peak::Method::CogFiltered, "Center of gravity after filtering", 0.0121),
        (cms_core::peak::Method::CwtPaper, "Proposed (CWT, Eq. 12-13)", 0.0062),
    ];
    /// The methods of the paper-protocol comparison.
    pub const METHODS: [cms_core::peak::Method; 4] = [
        cms_core::peak::Method::CwtPaper,
        cms_core::peak::Method::Cog,
        cms_core::peak::Method::CogFiltered,
        cms_core::peak::Method::Cwt,
    ];
}

/// Amplitude and background of a synthetic row, counts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Levels {
    /// Stripe peak height above the background.
    pub amplitude: f64,
    /// Constant pedestal.
    pub background: f64,
}

impl Levels {
    /// Half and a quarter of full scale (see the module doc).
    pub fn for_bits(bits: u8) -> Levels {
        let fs = (1u64 << bits) as f64;
        Levels { amplitude: fs / 2.0, background: fs / 4.0 }
    }
}

/// How the true centre of each trial is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Placement {
    /// Always here (the paper's 107.5: a symmetry point, see docs/reference.md §1).
    Fixed(f64),
    /// Uniform over `[lo, hi)`.
    Uniform(f64, f64),
}

impl Placement {
    fn draw(self, rng: &mut Rng) -> f64 {
        match self {
            Placement::Fixed(x) => x,
            Placement::Uniform(lo, hi) => lo + (hi - lo) * rng.uniform(),
        }
    }
}

/// One simulated condition; every method is run on the same rows.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scenario {
    /// Stripe σ, px.
    pub sigma: f64,
    /// SNR, dB, measured over the whole row.
    pub snr_db: f64,
    /// The detector's scale range, px.
    pub scales: (f64, f64),
    /// Where the true centre falls.
    pub placement: Placement,
    /// Row length, samples (at most [`ROW_LEN`]).
    pub len: usize,
    /// Bit depth, 8..=16.
    pub bits: u8,
    /// Amplitude and background.
    pub levels: Levels,
    /// Rows drawn.
    pub trials: usize,
}

impl Scenario {
    /// The study's scenario: scales [max(σ/2, 1), 1.5σ] (the paper's 5–15 for
    /// σ = 10), x0 uniform over [`STUDY_X0`].
    pub fn study(sigma: f64, snr_db: f64, bits: u8, levels: Levels, trials: usize) -> Scenario {
        Scenario {
            sigma,
            snr_db,
            scales: study_scales(sigma),
            placement: Placement::Uniform(STUDY_X0.0, STUDY_X0.1),
            len: ROW_LEN,
            bits,
            levels,
            trials,
        }
    }

    /// The paper's protocol (§6.2) with the given placement.
    pub fn paper(placement: Placement, bits: u8, levels: Levels, trials: usize) -> Scenario {
        Scenario {
            sigma: paper::SIGMA,
            snr_db: paper::SNR_DB,
            scales: paper::SCALES,
            placement,
            len: ROW_LEN,
            bits,
            levels,
            trials,
        }
    }
}

/// The study's scale range for a stripe σ: [max(σ/2, 1), 1.5σ].
pub fn study_scales(sigma: f64) -> (f64, f64) {
    ((sigma / 2.0).max(1.0), 1.5 * sigma)
}

/// Detector configuration: `bits`, the scale range, `method`, at most
/// `max_stripes`; everything else `Config::new`'s defaults.
pub fn detector_config(method: Method, bits: u8, scales: (f64, f64), max_stripes: u8) -> Config {
    let range = ScaleRange::new(Px::from_f64(scales.0), Px::from_f64(scales.1)).expect("valid scale range");
    let mut cfg = Config::new(bits, range);
    cfg.method = method;
    cfg.max_stripes = max_stripes;
    cfg
}

/// Statistics of one method in one scenario. Errors are detected − true, px,
/// over the trials with exactly one stripe.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellStats {
    /// Estimator.
    pub method: Method,
    /// Stripe σ, px.
    pub sigma: f64,
    /// SNR, dB (measured over the row).
    pub snr_db: f64,
    /// Rows drawn.
    pub trials: usize,
    /// Rows without exactly one stripe (none, or a wrong count).
    pub misses: usize,
    /// Detections more than one stripe σ from the truth (counted in the stats).
    pub gross: usize,
    /// Mean error.
    pub bias: f64,
    /// Standard deviation of the error (n − 1).
    pub std: f64,
    /// Root mean square error.
    pub rms: f64,
    /// Mean absolute error.
    pub mean_abs: f64,
    /// Largest absolute error.
    pub max_abs: f64,
    /// Pixel noise σn added (RMS over trials), counts.
    pub noise: f64,
    /// Amplitude over σn.
    pub a_over_noise: f64,
    /// Cramér–Rao bound with the effective noise sqrt(σn² + 1/12), px.
    pub crlb: f64,
    /// Samples that reached 0 or full scale (all rows of the scenario).
    pub clipped: usize,
}

impl CellStats {
    /// RMS / CRLB.
    pub fn ratio(&self) -> f64 {
        self.rms / self.crlb
    }
    /// Trials with exactly one stripe.
    pub fn detected(&self) -> usize {
        self.trials - self.misses
    }
}

fn summarise(method: Method, scn: &Scenario, errors: &[f64], noise_sq: f64, crlb_sq: f64, clipped: usize) -> CellStats {
    let n = errors.len();
    let nf = n as f64;
    let (bias, rms, mean_abs, max_abs, std) = if n == 0 {
        (f64::NAN, f64::NAN, f64::NAN, f64::NAN, f64::NAN)
    } else {
        let bias = errors.iter().sum::<f64>() / nf;
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / nf).sqrt();
        let mean_abs = errors.iter().map(|e| e.abs()).sum::<f64>() / nf;
        let max_abs = errors.iter().fold(0.0f64, |m, e| m.max(e.abs()));
        let std = if n > 1 {
            (errors.iter().map(|e| (e - bias) * (e - bias)).sum::<f64>() / (nf - 1.0)).sqrt()
        } else {
            f64::NAN
        };
        (bias, rms, mean_abs, max_abs, std)
    };
    let t = scn.trials.max(1) as f64;
    let noise = (noise_sq / t).sqrt();
    CellStats {
        method,
        sigma: scn.sigma,
        snr_db: scn.snr_db,
        trials: scn.trials,
        misses: scn.trials - n,
        gross: errors.iter().filter(|e| e.abs() > scn.sigma).count(),
        bias,
        std,
        rms,
        mean_abs,
        max_abs,
        noise,
        a_over_noise: scn.levels.amplitude / noise,
        crlb: (crlb_sq / t).sqrt(),
        clipped,
    }
}

/// Runs `methods` on the rows of one scenario drawn from `seed`; one
/// [`CellStats`] per method, in the order given.
pub fn run_scenario(scn: &Scenario, methods: &[Method], seed: u64) -> Vec<CellStats> {
    assert!(scn.len <= ROW_LEN, "rows longer than {ROW_LEN} samples");
    let mut dets: Vec<Detector<ROW_LEN>> = methods
        .iter()
        .map(|&m| Detector::new(detector_config(m, scn.bits, scn.scales, 1)).expect("valid detector config"))
        .collect();
    let mut errors: Vec<Vec<f64>> = vec![Vec::with_capacity(scn.trials); methods.len()];
    let full = ((1u64 << scn.bits) - 1) as u16;
    let (mut noise_sq, mut crlb_sq, mut clipped) = (0.0, 0.0, 0usize);
    let mut rng = Rng::new(seed);
    let mut out: Stripes<4> = Stripes::new();
    for _ in 0..scn.trials {
        let x0 = scn.placement.draw(&mut rng);
        let mut row = clean_row(scn.len, 0.0, &[Gauss { x0, sigma: scn.sigma, amplitude: scn.levels.amplitude }]);
        let noise = awgn_sigma(&row, scn.snr_db);
        row.iter_mut().for_each(|v| *v += scn.levels.background);
        let q = quantise(&row, noise, scn.bits, &mut rng);
        clipped += q.iter().filter(|&&v| v == 0 || v == full).count();
        noise_sq += noise * noise;
        let c = crlb(scn.sigma, scn.levels.amplitude, (noise * noise + 1.0 / 12.0).sqrt());
        crlb_sq += c * c;
        for (det, errs) in dets.iter_mut().zip(errors.iter_mut()) {
            det.detect(&q, &mut out).expect("row fits the detector");
            if out.len() == 1 {
                errs.push(out[0].position.to_f64() - x0);
            }
        }
    }
    methods.iter().zip(&errors).map(|(&m, e)| summarise(m, scn, e, noise_sq, crlb_sq, clipped)).collect()
}

/// The seed of scenario `index` of a run seeded by `seed` (splitmix64 of both).
pub fn scenario_seed(seed: u64, index: u64) -> u64 {
    let mut z = seed ^ index.wrapping_mul(0xD6E8_FEB8_6659_FD93);
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Runs `f(i)` for `i` in `0..n` on up to `threads` threads; results in index
/// order, whatever the scheduling.
pub fn par_map<T: Send>(n: usize, threads: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    let threads = threads.clamp(1, n.max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut done: Vec<(usize, T)> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        if i >= n {
                            break mine;
                        }
                        mine.push((i, f(i)));
                    }
                })
            })
            .collect();
        workers.into_iter().flat_map(|w| w.join().expect("worker panicked")).collect()
    });
    done.sort_by_key(|(i, _)| *i);
    done.into_iter().map(|(_, t)| t).collect()
}

/// Parameters of the accuracy study.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Study {
    /// Master seed.
    pub seed: u64,
    /// Trials per cell.
    pub trials: usize,
    /// Bit depth.
    pub bits: u8,
    /// Amplitude and background.
    pub levels: Levels,
    /// Worker threads (the result does not depend on it).
    pub threads: usize,
}

impl Study {
    /// Every method × [`SIGMAS`] × [`SNRS_DB`], ordered method, σ, SNR.
    /// Scenario `i = σ index × 4 + SNR index` is seeded by
    /// `scenario_seed(seed, i)`.
    pub fn run(&self) -> Vec<CellStats> {
        let n = SIGMAS.len() * SNRS_DB.len();
        let per_scenario = par_map(n, self.threads, |i| {
            let scn = Scenario::study(
                SIGMAS[i / SNRS_DB.len()],
                SNRS_DB[i % SNRS_DB.len()],
                self.bits,
                self.levels,
                self.trials,
            );
            run_scenario(&scn, &Method::ALL, scenario_seed(self.seed, i as u64))
        });
        (0..Method::ALL.len()).flat_map(|m| per_scenario.iter().map(move |cells| cells[m])).collect()
    }

    /// The paper's protocol for [`paper::METHODS`]: first at x0 = 107.5 as
    /// published, then x0 uniform over [107, 108) (same noise generator seed).
    pub fn paper_protocol(&self, trials: usize) -> (Vec<CellStats>, Vec<CellStats>) {
        let seed = scenario_seed(self.seed, 1000);
        let fixed = Scenario::paper(Placement::Fixed(paper::X0), self.bits, self.levels, trials);
        let random = Scenario::paper(Placement::Uniform(107.0, 108.0), self.bits, self.levels, trials);
        let mut both =
            par_map(2, self.threads, |i| run_scenario(if i == 0 { &fixed } else { &random }, &paper::METHODS, seed));
        let random = both.pop().unwrap_or_default();
        let fixed = both.pop().unwrap_or_default();
        (fixed, random)
    }
}

/// Header of [`csv`].
pub const CSV_HEADER: &str = "method,sigma_px,snr_db,trials,detected,misses,gross,bias_px,std_px,rms_px,\
mean_abs_px,max_abs_px,noise_counts,a_over_noise,crlb_px,rms_over_crlb,clipped_samples";

/// The cells as CSV ([`CSV_HEADER`], one line per cell, `\n` endings, NaN
/// where a cell has too few detections).
pub fn csv(cells: &[CellStats]) -> String {
    let mut s = String::from(CSV_HEADER);
    s.push('\n');
    for c in cells {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{:.7},{:.7},{:.7},{:.7},{:.7},{:.4},{:.2},{:.7},{:.4},{}",
            c.method.name(),
            c.sigma,
            c.snr_db,
            c.trials,
            c.detected(),
            c.misses,
            c.gross,
            c.bias,
            c.std,
            c.rms,
            c.mean_abs,
            c.max_abs,
            c.noise,
            c.a_over_noise,
            c.crlb,
            c.ratio(),
            c.clipped
        );
    }
    s
}

/// Stripe σ of the speed rows, px.
pub const SPEED_SIGMA: f64 = 2.5;
/// SNR of the speed rows, dB (measured over the row).
pub const SPEED_SNR_DB: f64 = 30.0;
/// Row lengths of the speed benchmark, px.
pub const SPEED_LENGTHS: [usize; 3] = [640, 752, 1280];
/// Stripes per row of the speed benchmark.
pub const SPEED_STRIPES: [usize; 2] = [1, 3];
/// Longest speed row (the detector's capacity there).
pub const SPEED_MAX_LEN: usize = 1280;

/// `count` distinct `bits`-deep rows of `len` px with `stripes` stripes of σ =
/// [`SPEED_SIGMA`] at [`SPEED_SNR_DB`]: stripe k near `len·(k + ½)/stripes`
/// with a random sub-pixel offset and ±8 px jitter, levels of [`Levels::for_bits`].
pub fn speed_rows(len: usize, stripes: usize, bits: u8, count: usize, seed: u64) -> Vec<Vec<u16>> {
    let levels = Levels::for_bits(bits);
    let mut rng = Rng::new(seed ^ ((len as u64) << 8) ^ stripes as u64);
    (0..count)
        .map(|_| {
            let gs: Vec<Gauss> = (0..stripes)
                .map(|k| Gauss {
                    x0: len as f64 * (k as f64 + 0.5) / stripes as f64 + 16.0 * rng.uniform() - 8.0,
                    sigma: SPEED_SIGMA,
                    amplitude: levels.amplitude * (0.8 + 0.2 * rng.uniform()),
                })
                .collect();
            let mut row = clean_row(len, 0.0, &gs);
            let noise = awgn_sigma(&row, SPEED_SNR_DB);
            row.iter_mut().for_each(|v| *v += levels.background);
            quantise(&row, noise, bits, &mut rng)
        })
        .collect()
}

/// The speed benchmark's detector: scales of [`study_scales`] for
/// [`SPEED_SIGMA`], at most `stripes` stripes.
pub fn speed_config(method: Method, bits: u8, stripes: usize) -> Config {
    detector_config(method, bits, study_scales(SPEED_SIGMA), stripes.clamp(1, 255) as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quick(seed: u64, threads: usize) -> Study {
        Study { seed, trials: 6, bits: 12, levels: Levels::for_bits(12), threads }
    }

    #[test]
    fn csv_has_every_cell_and_the_header() {
        let cells = quick(7, 2).run();
        let text = csv(&cells);
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some(CSV_HEADER));
        let rows: Vec<&str> = lines.collect();
        assert_eq!(rows.len(), Method::ALL.len() * SIGMAS.len() * SNRS_DB.len());
        let cols = CSV_HEADER.split(',').count();
        for m in Method::ALL {
            for s in SIGMAS {
                for n in SNRS_DB {
                    let key = format!("{},{},{},", m.name(), s, n);
                    let hits: Vec<&&str> = rows.iter().filter(|r| r.starts_with(&key)).collect();
                    assert_eq!(hits.len(), 1, "cell {key}");
                    assert_eq!(hits[0].split(',').count(), cols);
                }
            }
        }
    }

    #[test]
    fn same_seed_same_csv_whatever_the_threads() {
        let a = csv(&quick(11, 1).run());
        let b = csv(&quick(11, 2).run());
        let c = csv(&quick(11, 3).run());
        assert_eq!(a, b);
        assert_eq!(a, c);
        assert_ne!(a, csv(&quick(12, 2).run()));
    }

    #[test]
    fn levels_keep_the_noise_off_the_rails() {
        let s = Study { seed: 3, trials: 20, bits: 12, levels: Levels::for_bits(12), threads: 2 };
        for c in s.run() {
            assert_eq!(c.clipped, 0, "σ {} {} dB clipped", c.sigma, c.snr_db);
        }
    }

    #[test]
    fn paper_protocol_rows_are_methods_in_order() {
        let (fixed, random) = quick(5, 2).paper_protocol(10);
        let names = |v: &[CellStats]| v.iter().map(|c| c.method).collect::<Vec<_>>();
        assert_eq!(names(&fixed), paper::METHODS);
        assert_eq!(names(&random), paper::METHODS);
        assert!(fixed.iter().all(|c| c.misses == 0));
    }

    #[test]
    fn speed_rows_hold_the_stripes() {
        for &len in &SPEED_LENGTHS {
            for &k in &SPEED_STRIPES {
                let rows = speed_rows(len, k, 12, 4, 1);
                let mut det = Detector::<SPEED_MAX_LEN>::new(speed_config(Method::Cwt, 12, k)).unwrap();
                let mut out: Stripes<4> = Stripes::new();
                for r in &rows {
                    assert_eq!(r.len(), len);
                    det.detect(r, &mut out).unwrap();
                    assert_eq!(out.len(), k, "{len} px, {k} stripes");
                }
            }
        }
    }
}
