//! `bench rails`: measured roughness spectra of real rails laid on the
//! simulated rail ([`RoughnessSpectrum`]), measured as `listen sim`
//! measures by default, and judged against ISO 3095 and EN 13231-3 as
//! `analyze` judges a recording.
//!
//! Per spectrum the simulated head ([`crate::sim::floor::drive`]) is
//! driven over the rail at `listen sim`'s default speed, frame rate,
//! exposure and light (or the light asked for), every frame rendered,
//! detected, triangulated and stitched; the stitching is judged with
//! `analyze`'s own code and options ([`analyze::judge`]). The rail's true
//! profile over each line's stretch (its samples where the line has them)
//! is put through the same EN 15610 chain (spikes, curvature, Welch), so
//! that every line's third octave has a true level beside its reading.
//!
//! Per rail it reports: the lines' ISO 3095 third octaves from 5 to 250 mm
//! judged (within or EXCEEDS) of all of them; the worst difference of a
//! judged level from the true one — the judged level is the rail's own
//! level, the floor's power taken out (`detection::RailLevel::db`), or
//! the reading where that is at or under the floor; the wrong verdicts (a
//! third octave whose true level is 3 dB or more over the limit read
//! "within", 3 dB or more under read "EXCEEDS"); and the EN 13231-3
//! verdict.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use super::{BenchError, put};
use crate::analyze::reprofiling::BandRow;
use crate::analyze::standards::detection::Verdict;
use crate::analyze::standards::{en15610, fmt_nominal_mm};
use crate::analyze::{self, Analysis};
use crate::sim::closed_loop::ClosedLoopError;
use crate::sim::floor::{self as sf, Setting};
use crate::sim::head::DEFAULT_SPEED_MM_S;
use crate::sim::scene::{LightModel, RailModel, RoughnessSpectrum, Scene, SimConfig};

/// `listen`'s frame rate, frames/s.
pub const LISTEN_RATE_HZ: f64 = 30.0;
/// The third octaves judged, mm: 5 to 250.
pub const WAVELENGTHS_MM: (f64, f64) = (5.0, 250.0);
/// A verdict is wrong when the true level stands this far on the other
/// side of the limit, dB.
pub const WRONG_MARGIN_DB: f64 = 3.0;

/// Options of the rails benchmark.
#[derive(Debug, Clone)]
pub struct RailsOptions {
    /// The rails: a name (the file's) and its spectrum.
    pub rails: Vec<(String, RoughnessSpectrum)>,
    /// The light on the rail.
    pub light: LightModel,
    /// Length of rail driven over, mm.
    pub length_mm: f64,
    /// Seed of the rails' phases, the speckle and the sensor noise.
    pub seed: u64,
    /// Worker threads (`None`: one a core).
    pub threads: Option<usize>,
    /// Folder of the files.
    pub out: PathBuf,
}

/// One line's third octave: its reading against the rail's truth.
#[derive(Debug, Clone, PartialEq)]
pub struct BandScore {
    /// The line (laser index).
    pub laser: usize,
    pub nominal_wavelength_mm: f64,
    /// The rail's true level over the line's stretch, dB re 1 µm.
    pub true_db: f64,
    pub limit_db: f64,
    pub verdict: Verdict,
    /// The level judged: the rail's own (floor taken out), or the
    /// reading where that is at or under the floor, dB re 1 µm.
    pub judged_db: f64,
}

impl BandScore {
    /// Whether the verdict contradicts the truth by [`WRONG_MARGIN_DB`] or more.
    pub fn wrong(&self) -> bool {
        match self.verdict {
            Verdict::Within => self.true_db >= self.limit_db + WRONG_MARGIN_DB,
            Verdict::Exceeds => self.true_db <= self.limit_db - WRONG_MARGIN_DB,
            Verdict::NotJudged => false,
        }
    }

    /// |judged − true|, dB, for a band judged.
    pub fn error_db(&self) -> Option<f64> {
        (self.verdict != Verdict::NotJudged).then(|| (self.judged_db - self.true_db).abs())
    }
}

/// One rail measured.
#[derive(Debug, Clone)]
pub struct RailScore {
    pub name: String,
    /// Track measured (the longest line's stretch), mm.
    pub measured_mm: f64,
    /// Every line's third octave from 5 to 250 mm with an ISO 3095 limit.
    pub bands: Vec<BandScore>,
    /// Lines that had no EN 15610 spectrum, with why.
    pub missing: Vec<String>,
    /// EN 13231-3: whether every band judged passes (`None`: none judged).
    pub en13231_passes: Option<bool>,
    /// EN 13231-3 in words.
    pub en13231: String,
}

impl RailScore {
    /// Third octaves judged, of all.
    pub fn judged(&self) -> (usize, usize) {
        (self.bands.iter().filter(|b| b.verdict != Verdict::NotJudged).count(), self.bands.len())
    }

    /// The band judged farthest from the truth.
    pub fn worst(&self) -> Option<&BandScore> {
        let err = |b: &BandScore| b.error_db().unwrap_or(f64::NEG_INFINITY);
        self.bands.iter().filter(|b| b.error_db().is_some()).max_by(|a, b| err(a).total_cmp(&err(b)))
    }

    /// The wrong verdicts.
    pub fn wrong(&self) -> Vec<&BandScore> {
        self.bands.iter().filter(|b| b.wrong()).collect()
    }
}

/// The setting `listen sim` measures at by default over `length_mm`:
/// 0.5 m/s, 30 frames/s, the camera's 100 µs.
pub fn listen_setting(length_mm: f64, seed: u64) -> Setting {
    Setting {
        speed_mm_s: DEFAULT_SPEED_MM_S,
        step_mm: DEFAULT_SPEED_MM_S / LISTEN_RATE_HZ,
        seed,
        ..Setting::push_trolley(length_mm)
    }
}

/// The simulated head over `spectrum` laid on the rail (its crown kept, no
/// other corrugation or roughness) under `light`.
pub fn rail_config(s: &Setting, spectrum: &RoughnessSpectrum, light: &LightModel) -> SimConfig {
    let mut cfg = s.config();
    cfg.light = light.clone();
    cfg.rail = RailModel {
        corrugation: Vec::new(),
        roughness_rms_um: 0.0,
        roughness_spectrum: Some(spectrum.clone()),
        ..RailModel::default()
    };
    cfg
}

/// Drives the head over the rail, judges it as `analyze` does and scores it.
pub fn measure(
    name: &str,
    spectrum: &RoughnessSpectrum,
    light: &LightModel,
    length_mm: f64,
    seed: u64,
) -> Result<RailScore, ClosedLoopError> {
    let s = listen_setting(length_mm, seed);
    let cfg = rail_config(&s, spectrum, light);
    let scene = Scene::new(cfg.clone())?;
    let stitching = sf::drive(&s, cfg)?;
    let opts = analyze::Options::default();
    let a = analyze::judge(stitching, Vec::new(), &opts, &crate::progress::Silent)
        .map_err(|e| ClosedLoopError::Analysis(e.to_string()))?;
    score(name, &a, &opts.roughness, |x_mm| scene.profile_um(x_mm))
}

/// Scores an analysis against the rail's true profile `truth_um(x)`.
pub fn score(
    name: &str,
    a: &Analysis,
    roughness: &en15610::Options,
    truth_um: impl Fn(f64) -> f64,
) -> Result<RailScore, ClosedLoopError> {
    let mut bands = Vec::new();
    let mut missing = Vec::new();
    let mut measured_mm: f64 = 0.0;
    for l in &a.lasers {
        let st = &l.stitched;
        let line = match &l.roughness {
            Ok(r) => &r.spectrum,
            Err(e) => {
                missing.push(format!("line {}: {e}", st.laser + 1));
                continue;
            }
        };
        let z = st.z.to_vec().map_err(|e| ClosedLoopError::Analysis(e.to_string()))?;
        measured_mm = measured_mm.max(z.len() as f64 * st.dx_mm);
        let t: Vec<f64> = z
            .iter()
            .enumerate()
            .map(|(i, v)| if v.is_finite() { truth_um(st.x0_mm + i as f64 * st.dx_mm) } else { f64::NAN })
            .collect();
        let truth =
            en15610::analyze(&t, st.dx_mm, roughness).map_err(|e| ClosedLoopError::Analysis(e.to_string()))?.spectrum;
        for b in &line.bands {
            let w = b.nominal_wavelength_mm;
            if !(WAVELENGTHS_MM.0..=WAVELENGTHS_MM.1).contains(&w) {
                continue;
            }
            let (Some(d), Some(true_band)) = (b.decision(), truth.bands.iter().find(|t| t.k == b.k)) else { continue };
            bands.push(BandScore {
                laser: st.laser,
                nominal_wavelength_mm: w,
                true_db: true_band.level_db,
                limit_db: d.limit_db,
                verdict: d.verdict,
                judged_db: d.rail.db.unwrap_or(d.level_db),
            });
        }
    }
    let (en13231_passes, en13231) = en13231_words(&a.verdict.rows, a.verdict.options.edition);
    Ok(RailScore { name: name.to_string(), measured_mm, bands, missing, en13231_passes, en13231 })
}

/// An EN 13231-3 band's name, "10–30 mm".
fn band_name(b: &crate::analyze::standards::en13231::Band) -> String {
    format!("{}–{} mm", b.lo_mm, b.hi_mm)
}

/// EN 13231-3 over the bands with a limit: passes when every band judged
/// passes; the bands failing or not judged named.
fn en13231_words(rows: &[BandRow], edition: crate::analyze::standards::en13231::Edition) -> (Option<bool>, String) {
    let (mut fails, mut open) = (Vec::new(), Vec::new());
    let mut passes = 0;
    for r in rows.iter().filter(|r| r.limit_mm.is_some()) {
        match r.passes(edition) {
            Some(true) => passes += 1,
            Some(false) => fails.push(band_name(&r.band)),
            None => open.push(band_name(&r.band)),
        }
    }
    let mut words = match (fails.is_empty(), passes) {
        (false, _) => format!("FAILS ({})", fails.join(", ")),
        (true, 0) => "not judged".to_string(),
        (true, _) => "passes".to_string(),
    };
    if !open.is_empty() && passes + fails.len() > 0 {
        let _ = write!(words, "; not judged: {}", open.join(", "));
    }
    let verdict = if !fails.is_empty() { Some(false) } else { (passes > 0).then_some(true) };
    (verdict, words)
}

/// Measures every rail on `threads` workers, in order.
pub fn sweep(o: &RailsOptions) -> Vec<Result<RailScore, ClosedLoopError>> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..super::threads(o.threads).clamp(1, o.rails.len().max(1)) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some((name, spectrum)) = o.rails.get(i) else { break };
                    let got = std::panic::catch_unwind(|| measure(name, spectrum, &o.light, o.length_mm, o.seed))
                        .unwrap_or_else(|_| Err(ClosedLoopError::Panicked(name.clone())));
                    if let Ok(mut r) = results.lock() {
                        r.push((i, got));
                    }
                }
            });
        }
    });
    let mut r = results.into_inner().unwrap_or_default();
    r.sort_by_key(|(i, _)| *i);
    r.into_iter().map(|(_, g)| g).collect()
}

/// The summary table: per rail, judged, worst error, wrong verdicts, EN 13231-3.
pub fn markdown(rows: &[RailScore]) -> String {
    let mut md = String::from(
        "| rail | track m | line third octaves 5–250 mm judged | worst \\|judged − true\\| dB | wrong verdicts | EN 13231-3 |\n|---|---:|---:|---|---:|---|\n",
    );
    let (mut judged, mut total) = (0, 0);
    for r in rows {
        let (j, n) = r.judged();
        (judged, total) = (judged + j, total + n);
        let worst = r.worst().map_or("–".into(), |b| {
            format!(
                "{:.1} (line {}, {} mm: {:.1} for {:.1})",
                b.error_db().unwrap_or_default(),
                b.laser + 1,
                fmt_nominal_mm(b.nominal_wavelength_mm),
                b.judged_db,
                b.true_db
            )
        });
        let _ = writeln!(
            md,
            "| {} | {:.1} | {j} of {n} ({:.0} %) | {worst} | {} | {} |",
            r.name,
            r.measured_mm / 1e3,
            percent(j, n),
            r.wrong().len(),
            r.en13231
        );
    }
    let _ = writeln!(md, "| all | | {judged} of {total} ({:.0} %) | | | |", percent(judged, total));
    for r in rows {
        md.push_str(&detail(r));
    }
    md
}

fn percent(a: usize, b: usize) -> f64 {
    if b == 0 { 0.0 } else { 100.0 * a as f64 / b as f64 }
}

/// One rail per third octave: its true level (the first line's stretch),
/// the limit and each line's verdict with its judged level.
fn detail(r: &RailScore) -> String {
    let mut lasers: Vec<usize> = r.bands.iter().map(|b| b.laser).collect();
    lasers.dedup();
    let mut md = format!(
        "\n#### {}\n\n| mm | true dB | limit dB | {} |\n|---:|---:|---:|{}\n",
        r.name,
        lasers.iter().map(|l| format!("line {}", l + 1)).collect::<Vec<_>>().join(" | "),
        "---|".repeat(lasers.len())
    );
    let mut waves: Vec<f64> = r.bands.iter().map(|b| b.nominal_wavelength_mm).collect();
    waves.sort_by(|a, b| b.total_cmp(a));
    waves.dedup();
    for w in waves {
        let at: Vec<&BandScore> = r.bands.iter().filter(|b| b.nominal_wavelength_mm == w).collect();
        let cells: Vec<String> = lasers
            .iter()
            .map(|l| match at.iter().find(|b| b.laser == *l) {
                Some(b) if b.verdict == Verdict::NotJudged => "not judged".into(),
                Some(b) => format!("{} {:.1}{}", b.verdict.name(), b.judged_db, if b.wrong() { " WRONG" } else { "" }),
                None => "–".into(),
            })
            .collect();
        let _ = writeln!(
            md,
            "| {} | {:.1} | {:.1} | {} |",
            fmt_nominal_mm(w),
            at[0].true_db,
            at[0].limit_db,
            cells.join(" | ")
        );
    }
    for m in &r.missing {
        let _ = writeln!(md, "\n{m}");
    }
    md
}

/// The benchmark, written into `o.out` (`rails.md`); returns the report.
pub fn rails(o: &RailsOptions) -> Result<String, BenchError> {
    super::floor::check_length(o.length_mm)?;
    if o.rails.is_empty() {
        return Err(BenchError::Options("no rail to measure: give --spectrum FILE".into()));
    }
    super::create_dir(&o.out)?;
    let t = Instant::now();
    let mut rows = Vec::new();
    for got in sweep(o) {
        rows.push(got?);
    }
    let md = format!(
        "# Measured rail roughness through the simulated head\n\n{:.1} m of each rail at {} m/s, {} frames/s, under `{}`, seed {}: {:.0} s.\n\n{}",
        o.length_mm / 1e3,
        DEFAULT_SPEED_MM_S / 1e3,
        LISTEN_RATE_HZ,
        light_words(&o.light),
        o.seed,
        t.elapsed().as_secs_f64(),
        markdown(&rows)
    );
    put(&o.out.join("rails.md"), &md)?;
    Ok(md)
}

/// A light as `--sim-light` would spell its speckle and sensor.
fn light_words(l: &LightModel) -> String {
    match l.speckle {
        None => "incoherent".into(),
        Some(s) => format!(
            "speckle={}{}{}",
            s.f_number,
            if s.patterns > 1 { format!(",patterns={}", s.patterns) } else { String::new() },
            if l.scheimpflug { ",scheimpflug" } else { "" }
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ground rail (a grinding peak at 16–20 mm 5 dB over the limit,
    /// the rest 3 dB under it) through the simulated head in incoherent
    /// light (a floor under the rail), 6 m at a frame every 30 mm: most
    /// third octaves judged, each judged level within 3 dB of the rail's
    /// true one, no verdict wrong, the peak EXCEEDS on every line.
    #[test]
    fn a_ground_rail_is_read_at_its_levels() {
        let levels: Vec<(f64, f64)> = en15610::ISO3095_LIMIT
            .iter()
            .filter(|(w, _)| (5.0..=250.0).contains(w))
            .map(|&(w, l)| (w, if (16.0..=20.0).contains(&w) { l + 5.0 } else { l - 3.0 }))
            .collect();
        let spectrum = RoughnessSpectrum::new(&levels).unwrap();
        let s = Setting { step_mm: 30.0, ..listen_setting(6000.0, 4) };
        let cfg = rail_config(&s, &spectrum, &LightModel::incoherent());
        let scene = Scene::new(cfg.clone()).unwrap();
        let stitching = sf::drive(&s, cfg).unwrap();
        let opts = analyze::Options::default();
        let a = analyze::judge(stitching, Vec::new(), &opts, &crate::progress::Silent).unwrap();
        let r = score("ground", &a, &opts.roughness, |x| scene.profile_um(x)).unwrap();
        let table = markdown(std::slice::from_ref(&r));
        let (judged, total) = r.judged();
        assert!(total == 3 * 18 && r.missing.is_empty(), "{table}");
        assert!(judged * 10 >= total * 4, "{judged} of {total}\n{table}");
        assert!(r.worst().unwrap().error_db().unwrap() <= 3.0, "{table}");
        assert!(r.wrong().is_empty(), "{table}");
        let peak = |b: &&BandScore| (16.0..=20.0).contains(&b.nominal_wavelength_mm);
        assert!(r.bands.iter().filter(peak).all(|b| b.verdict == Verdict::Exceeds), "{table}");
    }

    #[test]
    fn wrong_verdicts_are_three_db_past_the_limit() {
        let b = |true_db: f64, verdict| BandScore {
            laser: 0,
            nominal_wavelength_mm: 16.0,
            true_db,
            limit_db: -6.8,
            verdict,
            judged_db: true_db,
        };
        assert!(b(-3.8, Verdict::Within).wrong() && !b(-4.0, Verdict::Within).wrong());
        assert!(b(-9.8, Verdict::Exceeds).wrong() && !b(-9.0, Verdict::Exceeds).wrong());
        assert!(!b(10.0, Verdict::NotJudged).wrong() && b(10.0, Verdict::NotJudged).error_db().is_none());
    }
}
