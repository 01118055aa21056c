//! The noise floor the optics predict, and the survey's own floor checked
//! against it (docs/noise-floor.md#the-floor-the-optics-predict).
//!
//! The floor [`crate::analyze::floor`] measures on the survey's own data
//! sees everything that differs between the lines. What the optics alone
//! would leave — speckle at the recorded aperture and wavelength, the
//! sensor's noise — is predicted here from physics, so that a floor far
//! over it says something besides them is in the data (vibration, grease,
//! a glint, the stitch), and a floor far under it that the optics recorded
//! are not the optics used, or the rail is not the rough steel speckle
//! assumes.
//!
//! # The model
//!
//! * **A point's error at rest**: the detector reads the stripe's centre
//!   `k` times the bound of Dorsch, Häusler & Herrmann (Appl. Opt. 33(7),
//!   1994), `δz = λ / (2π · sin u · sin θ)`, `sin u = f / (2N · d)` the
//!   observation aperture, `θ` the triangulation angle; `k` =
//!   [`DETECTOR_OVER_DORSCH`], measured (`bench speckle`).
//! * **Along the rail**, a point's error stays correlated over the larger
//!   of a row's footprint on the rail `d · pitch / f` and a speckle's,
//!   `2.44 λ N (1 + M) / M` (the pixel integrates the speckle finer than
//!   itself): the correlation length `L₀`.
//! * **Speckle diversity**: `K` independent patterns summed within an
//!   exposure ([`HeadLens::speckle_patterns`]: several diodes, a moving
//!   diffuser, a broad-area source) lower the contrast as `1/√K`, the
//!   variance of a point's error as `1/K`, at the same correlation length.
//! * **Motion** during the exposure (travel `t = v · T`) averages
//!   `K = 1 + t / L₀` patterns (variance `/K`) and stretches the
//!   correlation to `L₀ + t`: the speckle is tied to the rail, so the
//!   power at low wavenumbers is unchanged, and the travel is a moving
//!   average over `t` along the rail (`sinc²(f·t)`).
//! * A stitched line is then noise of one-sided spectral density
//!   `S(f) = 2 · (kδz)² · L₀ · sinc²(f·t) + S_sensor` (µm² · mm; the mean
//!   of a sample's rows keeps `2σ²L` whatever the sample spacing), with
//!   `S_sensor` = [`SENSOR_PSD_UM2_MM`], measured in incoherent light.
//! * A band's RMS is `√∫ S(f) · |H(f)|⁴ df` with the EN 13231-3 band
//!   filter's forward–backward Butterworth response ([`band_power_gain`]).
//!
//! * An EN 15610 one-third octave's level is `10 log₁₀ ∫ S(f) df` over
//!   its edges `f_c · 10^(±1/20)` (dB re 1 µm), as the Welch spectrum
//!   sums its bins ([`Budget::third_octave_db`]). The noise passes EN 15610's
//!   steps linearly ([`crate::analyze::standards::wheel`]: spike removal
//!   and the wheel act on the rail, their effect added to each line), so
//!   the line's floor in a third octave is this level.
//!
//! Not in it: the stitch's own error (a per-frame offset, which grows in
//! the long bands; the bands' check adds its propagated share, the third
//! octaves' does not), a vibration, the rail's own finish.

use crate::analyze::floor::Floor;
use crate::analyze::standards::en13231::{self, Band};
pub use crate::model::head::HeadLens;
use crate::model::optics::Optics;

/// The detector's scatter per point under speckle at rest over the Dorsch
/// bound: 1.64–1.74 at F/2.8–F/5.6 (`bench speckle`, docs/light.md's
/// aperture table; an independent coherent renderer found 1.7).
pub const DETECTOR_OVER_DORSCH: f64 = 1.7;

/// The sensor's noise on a stitched line, one-sided spectral density,
/// µm² · mm: incoherent light (no speckle) reads 0.32 µm RMS in the
/// 10–30 mm band (`bench floor`, docs/benchmarks.md#the-noise-floor),
/// `0.32² / (1/10 − 1/30)`.
pub const SENSOR_PSD_UM2_MM: f64 = 1.5;

/// Within this many dB of the prediction the floor agrees with it.
pub const AGREES_DB: f64 = 6.0;

/// The head's motion during an exposure, as the recording says.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Motion {
    /// The frames' mean exposure, µs.
    pub exposure_us: f64,
    /// The mean speed along the rail while recording, mm/s.
    pub speed_mm_s: f64,
}

impl Motion {
    /// Travel during an exposure, mm.
    pub fn travel_mm(&self) -> f64 {
        (self.speed_mm_s * self.exposure_us * 1e-6).abs()
    }
}

/// What the optics predict, figure by figure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Budget {
    /// The Dorsch bound per point, µm.
    pub dorsch_um: f64,
    /// The detector's scatter per point at rest, µm.
    pub point_um: f64,
    /// A speckle on the sensor, px.
    pub speckle_px: f64,
    /// Correlation length of a point's error along the rail at rest, mm.
    pub correlation_mm: f64,
    /// Travel during an exposure, mm.
    pub travel_mm: f64,
    /// Patterns the motion averages, `1 + t / L₀`.
    pub patterns: f64,
    /// Speckle's spectral density on a stitched line at low wavenumbers
    /// (the source's independent patterns averaged), µm² · mm.
    pub speckle_psd_um2_mm: f64,
    /// Runs averaged on the lines ([`crate::analyze::stitch::Stitched::runs_averaged`]):
    /// the speckle and sensor noise of runs that see independent speckle
    /// (lines on other strips of the rail head) average, power `/ N`.
    pub runs_averaged: f64,
}

/// The prediction's figures for `optics` on the head `head` moving as `motion`.
pub fn budget(optics: Optics, head: &HeadLens, motion: Motion) -> Budget {
    let lambda_um = optics.wavelength_nm() * 1e-3;
    let n = optics.f_number();
    let sin_u = head.focal_mm() / (2.0 * n * head.standoff_mm());
    let dorsch_um = lambda_um / (2.0 * std::f64::consts::PI * sin_u * head.triangulation_deg().to_radians().sin());
    let point_um = DETECTOR_OVER_DORSCH * dorsch_um;
    let m = head.magnification();
    let speckle_px = 2.44 * lambda_um * n * (1.0 + m) / head.pixel_um;
    let correlation_mm = head.row_mm() * speckle_px.max(1.0);
    let travel_mm = motion.travel_mm();
    Budget {
        dorsch_um,
        point_um,
        speckle_px,
        correlation_mm,
        travel_mm,
        patterns: 1.0 + travel_mm / correlation_mm,
        speckle_psd_um2_mm: 2.0 * point_um * point_um * correlation_mm / f64::from(head.speckle_patterns.max(1)),
        runs_averaged: 1.0,
    }
}

impl Budget {
    /// One-sided spectral density of a stitched line's noise at `f` cycles/mm, µm² · mm.
    pub fn psd_um2_mm(&self, f_per_mm: f64) -> f64 {
        let x = std::f64::consts::PI * f_per_mm * self.travel_mm;
        let smear = if x.abs() < 1e-9 { 1.0 } else { (x.sin() / x).powi(2) };
        (self.speckle_psd_um2_mm * smear + SENSOR_PSD_UM2_MM) / self.runs_averaged.max(1.0)
    }

    /// One line's predicted RMS in `band`, µm.
    pub fn band_rms_um(&self, band: &Band) -> f64 {
        // A log grid over two decades either side of the band: the filter's
        // skirts fall as f^±24 there.
        let (lo, hi) = (0.1 / band.hi_mm, 10.0 / band.lo_mm);
        let steps = 4000;
        let r = (hi / lo).ln() / steps as f64;
        let mut sum = 0.0;
        for i in 0..steps {
            let f = lo * ((i as f64 + 0.5) * r).exp();
            sum += self.psd_um2_mm(f) * band_power_gain(band, f) * f * r;
        }
        sum.sqrt()
    }

    /// One line's predicted level in the one-third octave of centre
    /// `centre_per_m` (cycles/m), dB re 1 µm: the density integrated
    /// over the band's edges.
    pub fn third_octave_db(&self, centre_per_m: f64) -> f64 {
        let (lo, hi) = (centre_per_m * 1e-3 * 10f64.powf(-0.05), centre_per_m * 1e-3 * 10f64.powf(0.05));
        let steps = 200;
        let r = (hi / lo).ln() / steps as f64;
        let power: f64 = (0..steps)
            .map(|i| {
                let f = lo * ((i as f64 + 0.5) * r).exp();
                self.psd_um2_mm(f) * f * r
            })
            .sum();
        10.0 * power.log10()
    }
}

/// The EN 13231-3 band filter's power gain at `f` cycles/mm: a 6th-order
/// Butterworth high-pass and low-pass, run forward and backward, each
/// 3 dB down at the band's edge (as [`en13231::band_pass`] designs them).
pub fn band_power_gain(band: &Band, f_per_mm: f64) -> f64 {
    let (shift, order) = (en13231::edge_shift(), 2 * en13231::ORDER as i32);
    let (f_hp, f_lp) = (shift / band.hi_mm, 1.0 / (band.lo_mm * shift));
    let hp = 1.0 / (1.0 + (f_hp / f_per_mm).powi(order));
    let lp = 1.0 / (1.0 + (f_per_mm / f_lp).powi(order));
    (hp * lp).powi(2)
}

/// How a measured floor stands to the prediction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Agreement {
    /// Within [`AGREES_DB`].
    Agrees,
    /// More than [`AGREES_DB`] over it.
    Over,
    /// More than [`AGREES_DB`] under it.
    Under,
}

impl Agreement {
    /// The word the outputs carry.
    pub fn name(self) -> &'static str {
        match self {
            Agreement::Agrees => "agrees",
            Agreement::Over => "over",
            Agreement::Under => "under",
        }
    }
}

/// One band's floor against the prediction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandCheck {
    /// What the optics predict for one line, with the stitch's propagated
    /// share in quadrature, RMS, mm.
    pub predicted_rms_mm: f64,
    /// One line's floor the survey measured, RMS, mm.
    pub measured_rms_mm: f64,
    /// `20 log₁₀(measured / predicted)`.
    pub ratio_db: f64,
    pub agreement: Agreement,
}

impl BandCheck {
    /// The measured floor `measured_rms_mm` against `predicted_rms_mm`.
    pub fn of(predicted_rms_mm: f64, measured_rms_mm: f64) -> BandCheck {
        let ratio_db = 20.0 * (measured_rms_mm / predicted_rms_mm).log10();
        let agreement = if ratio_db > AGREES_DB {
            Agreement::Over
        } else if ratio_db < -AGREES_DB {
            Agreement::Under
        } else {
            Agreement::Agrees
        };
        BandCheck { predicted_rms_mm, measured_rms_mm, ratio_db, agreement }
    }

    /// What it says, in words: never a verdict on the rail.
    pub fn says(&self) -> String {
        match self.agreement {
            Agreement::Agrees => format!("agrees with the optics ({:+.1} dB)", self.ratio_db),
            Agreement::Over => format!(
                "the floor is {:.1} dB over what the optics predict: something besides speckle and sensor noise (vibration, grease, a glint, the stitch, or repeat runs whose lines read the same strip of rail: the same speckle)",
                self.ratio_db
            ),
            Agreement::Under => format!(
                "the floor is {:.1} dB under the prediction (a specular or polished rail, or other optics than recorded)",
                -self.ratio_db
            ),
        }
    }
}

/// Third octaves' floors against the prediction: (nominal wavelength,
/// mm; the check, its RMS the level's `10^(dB/20)` µm), long to short.
pub type OctaveChecks = Vec<(f64, BandCheck)>;

/// Each one-third octave of `spectrum` (a floor's) against `budget`.
fn octave_checks(budget: &Budget, spectrum: Option<&crate::analyze::standards::en15610::Spectrum>) -> OctaveChecks {
    let rms_mm = |db: f64| 10f64.powf(db / 20.0) * 1e-3;
    spectrum
        .map(|s| {
            s.bands
                .iter()
                .map(|b| {
                    (
                        b.nominal_wavelength_mm,
                        BandCheck::of(rms_mm(budget.third_octave_db(b.centre_per_m)), rms_mm(b.level_db)),
                    )
                })
                .collect()
        })
        .unwrap_or_default()
}

/// Where the optics of a check come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OpticsSource {
    /// The recording's survey block.
    Recorded,
    /// `analyze --optics`.
    Given,
}

/// The survey's floor checked against the optics.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum OpticsCheck {
    /// The recording does not say what optics it was made with, and none were given.
    #[default]
    NotRecorded,
    /// Runs of different optics: no one prediction holds for the survey's floor.
    Mixed(String),
    /// Checked (per band; `None` where the floor of the band is not known).
    Checked {
        optics: Optics,
        source: OpticsSource,
        /// The head predicted for, and where its figures come from (boxed:
        /// it is most of the variant's size).
        head: Box<HeadLens>,
        motion: Motion,
        budget: Budget,
        bands: Vec<Option<BandCheck>>,
        /// Each line's own floor against the same prediction (laser, per
        /// band); empty where the lines' own floors are not known.
        lines: Vec<(usize, Vec<Option<BandCheck>>)>,
        /// One line's EN 15610 floor per one-third octave against the
        /// prediction (empty: the record holds no segment).
        octaves: OctaveChecks,
        /// Each line's own third-octave floor against it (laser, checks).
        line_octaves: Vec<(usize, OctaveChecks)>,
    },
}

impl OpticsCheck {
    /// The floor `floor` (`None`: not known) against what `optics` predict
    /// on the head `head` moving as `motion`, for one run.
    pub fn of(
        optics: Optics,
        source: OpticsSource,
        head: HeadLens,
        motion: Motion,
        floor: Option<&Floor>,
    ) -> OpticsCheck {
        OpticsCheck::of_runs(optics, source, (head, motion), 1.0, floor)
    }

    /// [`OpticsCheck::of`] for lines that average `runs_averaged` runs
    /// ([`Budget::runs_averaged`]).
    pub fn of_runs(
        optics: Optics,
        source: OpticsSource,
        (head, motion): (HeadLens, Motion),
        runs_averaged: f64,
        floor: Option<&Floor>,
    ) -> OpticsCheck {
        let budget = Budget { runs_averaged: runs_averaged.max(1.0), ..budget(optics, &head, motion) };
        // The measured floor holds the stitch's propagated share
        // (`BandFloor::with_stitch`): the prediction holds it too.
        let check = |b: usize, f: Option<&crate::analyze::floor::BandFloor>| {
            let f = f?;
            Some(BandCheck::of((budget.band_rms_um(&en13231::BANDS[b]) * 1e-3).hypot(f.stitch_rms_mm), f.rms_mm))
        };
        let bands = (0..en13231::BANDS.len()).map(|b| check(b, floor?.band(b))).collect();
        let lines = floor
            .map(|f| {
                f.lines_own
                    .iter()
                    .map(|l| (l.laser, (0..en13231::BANDS.len()).map(|b| check(b, l.bands[b].as_ref())).collect()))
                    .collect()
            })
            .unwrap_or_default();
        let octaves = octave_checks(&budget, floor.and_then(|f| f.spectrum.as_ref()));
        let line_octaves = floor
            .map(|f| f.lines_own.iter().map(|l| (l.laser, octave_checks(&budget, l.spectrum.as_ref()))).collect())
            .unwrap_or_default();
        OpticsCheck::Checked {
            optics,
            source,
            head: Box::new(head),
            motion,
            budget,
            bands,
            lines,
            octaves,
            line_octaves,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn motion(speed_mm_s: f64) -> Motion {
        Motion { exposure_us: 100.0, speed_mm_s }
    }

    /// The push-trolley setting worked by hand: sin u = 8.4/(2·2.8·200) =
    /// 0.0075, δz = 0.685/(2π·0.0075·sin 35°) = 25.34 µm, 1.7× = 43.08 µm;
    /// a speckle of 2.44·0.685·2.8·(1 + 8.4/191.6)/6 = 0.814 px, under a
    /// row, so L₀ = 200·0.006/8.4 = 0.14286 mm; S = 2·43.08²·0.14286 =
    /// 530.2 µm²·mm, plus the sensor's 1.5; the 10–30 mm band's noise
    /// bandwidth about 1/10 − 1/30 = 0.0667 /mm: 5.96 µm RMS.
    #[test]
    fn the_prediction_is_the_hand_computation() {
        let b = budget(Optics::new(2.8, 685.0).unwrap(), &HeadLens::reference(), motion(1500.0));
        assert!((b.dorsch_um - 25.34).abs() < 0.01, "{b:?}");
        assert!((b.point_um - 43.08).abs() < 0.01, "{b:?}");
        assert!((b.speckle_px - 0.814).abs() < 0.001, "{b:?}");
        assert!((b.correlation_mm - 0.142_86).abs() < 1e-5, "{b:?}");
        assert!((b.speckle_psd_um2_mm - 530.2).abs() < 0.2, "{b:?}");
        assert!((b.travel_mm - 0.15).abs() < 1e-12);
        let by_hand = ((530.2f64 + 1.5) * (1.0 / 10.0 - 1.0 / 30.0)).sqrt();
        let rms = b.band_rms_um(&en13231::BANDS[0]);
        // The filter's skirts and the smear: within 3 % of the ideal band.
        assert!((rms / by_hand - 1.0).abs() < 0.03, "{rms} against {by_hand}");
        // The 30–100 mm band has 0.35 of the 10–30's bandwidth.
        let r1 = b.band_rms_um(&en13231::BANDS[1]);
        assert!((r1 / rms - (0.7f64 / 2.0).sqrt()).abs() < 0.02, "{r1} {rms}");
    }

    /// Speckle tied to the rail: speed moves the band's floor only by the
    /// smear; aperture and wavelength move it as λN.
    #[test]
    fn speed_barely_moves_it_and_aperture_does() {
        let band = &en13231::BANDS[0];
        let at = |f: f64, nm: f64, v: f64| {
            budget(Optics::new(f, nm).unwrap(), &HeadLens::reference(), motion(v)).band_rms_um(band)
        };
        let (rest, walk, vehicle) = (at(4.0, 685.0, 0.0), at(4.0, 685.0, 1500.0), at(4.0, 685.0, 5000.0));
        assert!(walk / rest > 0.99 && vehicle / rest > 0.95 && vehicle < rest, "{rest} {walk} {vehicle}");
        // Both speckles under a row: the floor goes as λN.
        let ratio = at(2.8, 405.0, 1500.0) / at(2.8, 685.0, 1500.0);
        assert!((ratio - 405.0 / 685.0).abs() < 0.02, "{ratio}");
    }

    /// K independent patterns: speckle's density a K-th, the sensor's kept.
    #[test]
    fn independent_patterns_divide_speckle_power() {
        let o = Optics::new(2.8, 685.0).unwrap();
        let one = budget(o, &HeadLens::reference(), motion(0.0));
        let four = budget(o, &HeadLens { speckle_patterns: 4, ..HeadLens::reference() }, motion(0.0));
        assert!((four.speckle_psd_um2_mm * 4.0 / one.speckle_psd_um2_mm - 1.0).abs() < 1e-12);
        let band = &en13231::BANDS[0];
        let want =
            ((one.band_rms_um(band).powi(2) - SENSOR_PSD_UM2_MM * 0.0667) / 4.0 + SENSOR_PSD_UM2_MM * 0.0667).sqrt();
        assert!((four.band_rms_um(band) / want - 1.0).abs() < 0.02, "{} vs {want}", four.band_rms_um(band));
    }

    /// The 25 mm third octave by hand: edges 40·10^(∓1/20) cycles/m, a
    /// width of 0.009267 /mm; the push-trolley density 530.2 + 1.5 µm²·mm
    /// (the smear at 0.15 mm of travel is 0.02 % there): 4.927 µm², 6.93 dB.
    #[test]
    fn a_third_octave_is_the_density_over_its_width() {
        let b = budget(Optics::new(2.8, 685.0).unwrap(), &HeadLens::reference(), motion(1500.0));
        let width = 0.04 * (10f64.powf(0.05) - 10f64.powf(-0.05));
        let by_hand = 10.0 * ((530.2 + 1.5) * width).log10();
        assert!((b.third_octave_db(40.0) - by_hand).abs() < 0.02, "{} {by_hand}", b.third_octave_db(40.0));
        // Ten times the frequency, ten times the width: +10 dB but for the smear.
        let smear = {
            let x = std::f64::consts::PI * 0.4 * 0.15;
            (530.2 * (x.sin() / x).powi(2) + 1.5) / 531.7
        };
        let d = b.third_octave_db(400.0) - b.third_octave_db(40.0);
        assert!((d - 10.0 - 10.0 * smear.log10()).abs() < 0.02, "{d}");
    }

    #[test]
    fn a_floor_is_checked_band_by_band() {
        let c = BandCheck::of(0.006, 0.007);
        assert_eq!(c.agreement, Agreement::Agrees);
        assert!((c.ratio_db - 1.339).abs() < 0.001, "{c:?}");
        assert!(c.says().starts_with("agrees"));
        let over = BandCheck::of(0.006, 0.020);
        assert_eq!(over.agreement, Agreement::Over);
        assert!(over.says().contains("10.5 dB over what the optics predict"), "{}", over.says());
        let under = BandCheck::of(0.006, 0.001);
        assert_eq!(under.agreement, Agreement::Under);
        assert!(under.says().contains("15.6 dB under the prediction"), "{}", under.says());
        // No floor: every band unchecked, the budget still there.
        let o = Optics::new(4.0, 685.0).unwrap();
        match OpticsCheck::of(o, OpticsSource::Given, HeadLens::reference(), motion(1000.0), None) {
            OpticsCheck::Checked { bands, budget, octaves, .. } => {
                assert!(bands.iter().all(Option::is_none) && octaves.is_empty());
                assert!(budget.point_um > 60.0);
            }
            other => panic!("{other:?}"),
        }
    }
}
