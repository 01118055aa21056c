//! `bench floor`: the instrument's noise floor against the head's optics
//! and timing, and whether the floor `analyze` reports is the floor a
//! smooth rail really reads.
//!
//! Each setting drives the simulated head ([`crate::sim::floor`]) over a
//! smooth rail (no corrugation, no roughness: everything it reads is the
//! instrument's own) and judges it as `analyze` does. Per EN 13231-3
//! band it reports one line's reported floor beside what the smooth rail
//! reads on a line (their ratio is the floor estimator's error), the
//! running band's floor (the mean of the lines, the profile the verdict
//! judges) against `1/√2` of the 2006 limit (what it takes to be judged),
//! and the minimum detectable
//! corrugation: the peak-to-peak of a sine whose band power equals the
//! running band's noise power (ISO 11843's detection limit with the
//! judging rule of [`crate::analyze::floor`]: a level 3 dB over the
//! floor). Per one-third octave, the same against ISO 3095.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use super::{BenchError, put};
use crate::analyze::Analysis;
use crate::analyze::optics_floor::{BandCheck, Motion, OpticsCheck, OpticsSource};
use crate::analyze::standards::{en13231, en15610};
use crate::model::optics::Optics;
use crate::sim::closed_loop::ClosedLoopError;
use crate::sim::floor::{self as sf, Sensor, Setting};
use crate::sim::scene::LightModel;

/// Options of the floor benchmark.
#[derive(Debug, Clone)]
pub struct FloorOptions {
    /// The reduced sweep: the push-trolley setting alone, 1.5 m of rail.
    pub reduced: bool,
    /// Only the settings whose name holds this text.
    pub only: Option<String>,
    /// Heads to measure instead of the sweep: the push-trolley setting
    /// under each of these lights (speckle's F-number and patterns, a
    /// Scheimpflug sensor, or incoherent light).
    pub lights: Vec<LightModel>,
    /// With `lights`: travel between frames, mm (`None`: the push
    /// trolley's 30; a frame every 10 mm at 1.5 m/s is 150 frames/s).
    pub step_mm: Option<f64>,
    /// With `lights`: the sensor and lasers ([`Sensor::reference`]: the
    /// reference head's).
    pub sensor: Sensor,
    /// Length of rail per setting, mm.
    pub length_mm: f64,
    /// Worker threads (`None`: one a core).
    pub threads: Option<usize>,
    /// Folder of the files.
    pub out: PathBuf,
}

/// One row of the sweep: what was set, and the smooth rail judged.
#[derive(Debug, Clone)]
pub struct FloorRow {
    pub name: String,
    pub setting: Setting,
    pub analysis: Analysis,
}

/// The sweep's settings: the recommended push-trolley setting, then a
/// base (F/4, 100 µs, 1.5 m/s) and one thing changed at a time from it —
/// aperture, speed (motion averaging), exposure, frame overlap, rows per
/// millimetre, the laser's wavelength. `only`: the settings whose name
/// holds that text.
pub fn settings(reduced: bool, length_mm: f64, only: Option<&str>) -> Vec<(String, Setting)> {
    let trolley = ("push trolley: F/2.8, 100 µs, 1.5 m/s".to_string(), Setting::push_trolley(length_mm));
    if reduced {
        return vec![trolley];
    }
    let base = Setting { f_number: Some(4.0), ..Setting::push_trolley(length_mm) };
    let with = |name: &str, f: &dyn Fn(&mut Setting)| {
        let mut s = base.clone();
        f(&mut s);
        (name.to_string(), s)
    };
    let all = vec![
        trolley,
        with("F/4, 100 µs, 1.5 m/s", &|_| {}),
        with("F/5.6", &|s| s.f_number = Some(5.6)),
        with("F/8", &|s| s.f_number = Some(8.0)),
        with("F/4, 0.5 m/s", &|s| s.speed_mm_s = 500.0),
        with("F/4, 5 m/s (vehicle)", &|s| s.speed_mm_s = 5000.0),
        with("F/4, exposure 30 µs", &|s| s.exposure_us = 30.0),
        with("F/4, exposure 300 µs", &|s| s.exposure_us = 300.0),
        with("F/4, a frame every 10 mm", &|s| s.step_mm = 10.0),
        with("F/4, a frame every 60 mm", &|s| s.step_mm = 60.0),
        with("F/4, every 2nd row", &|s| s.row_step = 2),
        with("405 nm lasers, F/4", &|s| s.wavelength_nm = 405.0),
        with("405 nm, F/2.8", &|s| {
            s.wavelength_nm = 405.0;
            s.f_number = Some(2.8);
        }),
        with("405 nm, F/5.6, 5 m/s (vehicle)", &|s| {
            s.wavelength_nm = 405.0;
            s.f_number = Some(5.6);
            s.speed_mm_s = 5000.0;
        }),
        with("incoherent light (no speckle)", &|s| s.f_number = None),
    ];
    match only {
        Some(text) => all.into_iter().filter(|(name, _)| name.contains(text)).collect(),
        None => all,
    }
}

/// Runs the settings on `threads` workers, in order.
pub fn sweep(settings: &[(String, Setting)], threads: usize) -> Vec<Result<FloorRow, ClosedLoopError>> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..threads.clamp(1, settings.len().max(1)) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some((name, s)) = settings.get(i) else { break };
                    let got = std::panic::catch_unwind(|| sf::run(s))
                        .unwrap_or_else(|_| Err(ClosedLoopError::Panicked(name.clone())))
                        .map(|analysis| FloorRow { name: name.clone(), setting: s.clone(), analysis });
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

/// What a smooth rail reads in band `b`, averaged over its lines: RMS and
/// the average mean peak-to-peak, mm.
pub fn measured(a: &Analysis, b: usize) -> Option<(f64, f64)> {
    let stats: Vec<&en13231::BandStats> =
        a.lasers.iter().filter_map(|l| l.bands.as_ref().ok()?.bands.get(b)?.outcome.as_ref().ok()).collect();
    if stats.is_empty() {
        return None;
    }
    let n = stats.len() as f64;
    let rms = (stats.iter().map(|s| s.rms_mm * s.rms_mm).sum::<f64>() / n).sqrt();
    Some((rms, stats.iter().map(|s| s.average_mean_pp_mm).sum::<f64>() / n))
}

/// What a smooth rail reads in each one-third octave, the lines' spectra
/// energy-averaged (the running band's EN 15610 spectrum).
pub fn measured_spectrum(a: &Analysis) -> Option<&en15610::Spectrum> {
    a.running_bands.first()?.roughness.as_ref()
}

/// The sweep as Markdown: per setting and band, the floor reported and
/// measured, the running band's floor against half the limit and the
/// minimum detectable corrugation; then the EN 15610 floor.
pub fn markdown(rows: &[FloorRow]) -> String {
    let mut md = String::from(
        "| setting | band mm | floor RMS µm (reported / smooth rail) | predicted by the optics, RMS µm | reported / predicted dB | floor mean p-p µm (reported / smooth rail) | running band mean p-p µm | 0.71 × the 2006 limit µm | judged | detectable p-p µm |\n|---|---|---:|---:|---:|---:|---:|---:|---|---:|\n",
    );
    for r in rows {
        let Some(f) = &r.analysis.floor else {
            let _ = writeln!(md, "| {} | – | floor not known | | | | | |", r.name);
            continue;
        };
        let check = predicted(&r.setting, Some(f));
        for (b, band) in en13231::BANDS.iter().enumerate().take(3) {
            let (Some(fl), Some((rms, pp))) = (f.band(b), measured(&r.analysis, b)) else { continue };
            let mean = fl.of_mean(f.lines);
            let judged = r.analysis.verdict.rows[b].judgement.not_judged.is_none();
            let (pred, db) = match check.as_ref().and_then(|c| c.get(b).copied().flatten()) {
                Some(c) => {
                    (format!("{:.2}", c.predicted_rms_mm * 1e3), format!("{:+.1} ({})", c.ratio_db, c.agreement.name()))
                }
                None => ("–".into(), "–".into()),
            };
            let _ = writeln!(
                md,
                "| {} | {}–{} | {:.2} / {:.2} | {pred} | {db} | {:.1} / {:.1} | {:.1} | {:.0} | {} | {:.1} |",
                r.name,
                band.lo_mm,
                band.hi_mm,
                fl.rms_mm * 1e3,
                rms * 1e3,
                fl.average_mean_pp_mm * 1e3,
                pp * 1e3,
                mean.average_mean_pp_mm * 1e3,
                band.mean_pp_limit_mm * 1e3 * crate::analyze::floor::JUDGED_SHARE_OF_LIMIT,
                if judged { "yes" } else { "no" },
                detectable_pp_mm(mean.rms_mm) * 1e3,
            );
        }
    }
    md.push_str(
        "\n### EN 15610: one line's floor per one-third octave (reported / smooth rail, dB re 1 µm) against ISO 3095\n\n",
    );
    let waves = [250.0, 100.0, 50.0, 25.0, 10.0, 5.0];
    let _ = writeln!(
        md,
        "| setting | {} |\n|---|{}",
        waves.iter().map(|w| format!("{w} mm")).collect::<Vec<_>>().join(" | "),
        "---:|".repeat(waves.len())
    );
    for r in rows {
        let cells: Vec<String> = waves
            .iter()
            .map(|&w| {
                let at = |s: Option<&en15610::Spectrum>| {
                    s.and_then(|s| s.bands.iter().find(|b| (b.nominal_wavelength_mm - w).abs() < 1e-6))
                        .map(|b| b.level_db)
                };
                match (
                    at(r.analysis.floor.as_ref().and_then(|f| f.spectrum.as_ref())),
                    at(measured_spectrum(&r.analysis)),
                ) {
                    (Some(f), Some(m)) => format!("{f:.1} / {m:.1}"),
                    _ => "–".into(),
                }
            })
            .collect();
        let _ = writeln!(md, "| {} | {} |", r.name, cells.join(" | "));
    }
    let limits: Vec<String> =
        waves.iter().map(|&w| en15610::iso3095_limit_db(w).map_or("–".into(), |l| format!("{l:.1}"))).collect();
    let _ = writeln!(md, "| ISO 3095 limit | {} |", limits.join(" | "));
    md
}

/// The floor `floor` checked against what the setting's optics predict
/// ([`crate::analyze::optics_floor`]), per EN 13231-3 band (`None`:
/// incoherent light, no speckle to predict).
pub fn predicted(s: &Setting, floor: Option<&crate::analyze::floor::Floor>) -> Option<Vec<Option<BandCheck>>> {
    let optics = Optics::new(s.f_number?, s.wavelength_nm).ok()?;
    let motion = Motion { exposure_us: s.exposure_us, speed_mm_s: s.speed_mm_s };
    match OpticsCheck::of(optics, OpticsSource::Given, s.config().head_lens(), motion, floor) {
        OpticsCheck::Checked { bands, .. } => Some(bands),
        _ => None,
    }
}

/// The peak-to-peak of a sine whose band RMS is `rms_mm`: `2√2 · rms`.
pub fn detectable_pp_mm(rms_mm: f64) -> f64 {
    2.0 * std::f64::consts::SQRT_2 * rms_mm
}

/// A length of rail the closed loop drives: at least
/// [`sf::MIN_LENGTH_MM`], at most 100 m.
pub(crate) fn check_length(length_mm: f64) -> Result<(), BenchError> {
    if !(sf::MIN_LENGTH_MM..=100_000.0).contains(&length_mm) {
        return Err(BenchError::Options(format!(
            "{} m of rail: at least {} m and at most 100 m",
            length_mm / 1e3,
            sf::MIN_LENGTH_MM / 1e3
        )));
    }
    Ok(())
}

/// The sweep, written into `a.out` (`floor.md`); returns the report.
pub fn floor(a: &FloorOptions) -> Result<String, BenchError> {
    check_length(a.length_mm)?;
    a.sensor.check().map_err(|e| BenchError::Options(e.to_string()))?;
    if a.lights.is_empty() && (a.step_mm.is_some() || a.sensor != Sensor::reference()) {
        return Err(BenchError::Options(
            "--step-mm, --power-mw, --read-noise-e, --focal-px and --no-sensor-noise change the heads of --light: give one"
                .into(),
        ));
    }
    super::create_dir(&a.out)?;
    let t = Instant::now();
    let set = if a.lights.is_empty() {
        settings(a.reduced, a.length_mm, a.only.as_deref())
    } else {
        let step_mm = a.step_mm.unwrap_or(Setting::push_trolley(a.length_mm).step_mm);
        a.lights.iter().map(|l| head_setting(l, a.length_mm, step_mm, a.sensor)).collect::<Result<Vec<_>, _>>()?
    };
    if set.is_empty() {
        return Err(BenchError::Options(format!(
            "--only {:?}: no setting's name holds it (`bench floor` without --only lists them in floor.md)",
            a.only.as_deref().unwrap_or_default()
        )));
    }
    let mut rows = Vec::new();
    for got in sweep(&set, super::threads(a.threads)) {
        rows.push(got?);
    }
    let heads = if a.lights.is_empty() { String::new() } else { heads_markdown(&rows) };
    let md = format!(
        "# The noise floor against the head's optics and timing\n\n`cms-host bench floor{}` ({:.1} m of smooth rail per setting, a frame every 30 mm unless set): {:.0} s.\n\n{}{heads}",
        if a.reduced { " --reduced" } else { "" },
        a.length_mm / 1e3,
        t.elapsed().as_secs_f64(),
        markdown(&rows)
    );
    put(&a.out.join("floor.md"), &md)?;
    Ok(md)
}

/// The push-trolley setting (100 µs, 1.5 m/s) under `light`, a frame
/// every `step_mm`, with `sensor`, named by what differs from the
/// reference head; a light `bench floor` cannot drive (a finish, glints,
/// ghosts, another focus) is refused.
pub fn head_setting(
    light: &LightModel,
    length_mm: f64,
    step_mm: f64,
    sensor: Sensor,
) -> Result<(String, Setting), BenchError> {
    let bare = LightModel {
        speckle: light.speckle,
        scheimpflug: light.scheimpflug,
        sensor_per_line: light.sensor_per_line,
        exact_speckle: light.exact_speckle,
        ..LightModel::incoherent()
    };
    if *light != bare {
        return Err(BenchError::Options(
            "--light: bench floor drives speckle=F, patterns=K, scheimpflug[=each], exact or incoherent only".into(),
        ));
    }
    let trolley = Setting::push_trolley(length_mm);
    let mut name = match light.speckle {
        None => "incoherent light (no speckle)".to_string(),
        Some(s) => format!(
            "F/{}, K = {}{}{}",
            s.f_number,
            s.patterns,
            match (light.scheimpflug, light.sensor_per_line) {
                (true, true) => ", a Scheimpflug sensor per line",
                (true, false) => ", Scheimpflug sensor",
                _ => "",
            },
            if light.exact_speckle { ", speckle fields" } else { "" }
        ),
    };
    let reference = Sensor::reference();
    if step_mm != trolley.step_mm {
        let _ = write!(name, ", a frame every {step_mm} mm");
    }
    if sensor.power_mw != reference.power_mw {
        let _ = write!(name, ", {} mW a line", sensor.power_mw);
    }
    if !sensor.noise {
        name.push_str(", no sensor noise");
    } else if sensor.read_noise_e != reference.read_noise_e {
        let _ = write!(name, ", {} e⁻ read noise", sensor.read_noise_e);
    }
    if sensor.focal_px != reference.focal_px {
        let _ = write!(name, ", f = {} px", sensor.focal_px);
    }
    let setting = Setting {
        f_number: light.speckle.map(|s| s.f_number),
        patterns: light.speckle.map_or(1, |s| s.patterns),
        scheimpflug: light.scheimpflug,
        sensor_per_line: light.sensor_per_line,
        exact_speckle: light.exact_speckle,
        step_mm,
        sensor,
        ..trolley
    };
    Ok((name, setting))
}

/// Each head's smooth rail per ISO 3095 third octave, 5–250 mm: each
/// line's level (in the head's order: the middle one is the reference
/// head's line 2), the worst line's and the lines' energy average (EN
/// 15610's), dB re 1 µm, each with its margin to the limit (negative:
/// under it).
pub fn heads_markdown(rows: &[FloorRow]) -> String {
    let waves: Vec<f64> =
        en15610::ISO3095_LIMIT.iter().map(|&(w, _)| w).filter(|w| (5.0..=250.0).contains(w)).collect();
    let mut md =
        String::from("\n### Each head's smooth rail against ISO 3095: level dB re 1 µm (margin to the limit, dB)\n\n");
    let _ = writeln!(
        md,
        "| head | lines | {} |\n|---|---|{}",
        waves.iter().map(|w| format!("{w} mm")).collect::<Vec<_>>().join(" | "),
        "---:|".repeat(waves.len())
    );
    let level = |s: &en15610::Spectrum, w: f64| {
        s.bands.iter().find(|b| (b.nominal_wavelength_mm - w).abs() < 1e-6 * w).map(|b| b.level_db)
    };
    let cell = |l: Option<f64>, w: f64| match (l, en15610::iso3095_limit_db(w)) {
        (Some(l), Some(lim)) => format!("{l:.1} ({:+.1})", l - lim),
        _ => "–".into(),
    };
    for r in rows {
        let lines: Vec<&en15610::Spectrum> =
            r.analysis.lasers.iter().filter_map(|l| l.roughness.as_ref().ok().map(|r| &r.spectrum)).collect();
        let worst: Vec<String> =
            waves.iter().map(|&w| cell(lines.iter().filter_map(|s| level(s, w)).max_by(f64::total_cmp), w)).collect();
        let mean: Vec<String> =
            waves.iter().map(|&w| cell(measured_spectrum(&r.analysis).and_then(|s| level(s, w)), w)).collect();
        for (k, l) in r.analysis.lasers.iter().enumerate() {
            let s = l.roughness.as_ref().ok().map(|r| &r.spectrum);
            let row: Vec<String> = waves.iter().map(|&w| cell(s.and_then(|s| level(s, w)), w)).collect();
            let _ = writeln!(md, "| {} | line {} | {} |", r.name, k + 1, row.join(" | "));
        }
        let _ = writeln!(md, "| {} | worst line | {} |", r.name, worst.join(" | "));
        let _ = writeln!(md, "| {} | energy average | {} |", r.name, mean.join(" | "));
    }
    let limits: Vec<String> =
        waves.iter().map(|&w| en15610::iso3095_limit_db(w).map_or("–".into(), |l| format!("{l:.1}"))).collect();
    let _ = writeln!(md, "| ISO 3095 limit | | {} |", limits.join(" | "));
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The head flags change the heads of `--light` and name what they
    /// change; without a light, or out of range, they are refused before
    /// anything renders.
    #[test]
    fn the_head_flags_name_the_head_and_are_checked() {
        let light = crate::sim::scene::LightModel {
            scheimpflug: true,
            sensor_per_line: true,
            ..crate::sim::scene::LightModel::speckle(1.4)
        };
        let sensor = Sensor { focal_px: 2800.0, power_mw: 70.0, ..Sensor::reference() };
        let (name, s) = head_setting(&light, 2000.0, 7.5, sensor).unwrap();
        assert_eq!(
            name,
            "F/1.4, K = 1, a Scheimpflug sensor per line, a frame every 7.5 mm, 70 mW a line, f = 2800 px"
        );
        assert!(s.sensor_per_line && s.step_mm == 7.5);
        let cfg = s.config();
        assert_eq!((cfg.camera.intrinsics.fx_px, cfg.lasers[2].power_mw), (2800.0, 70.0));
        assert!(cfg.light.sensor_per_line);
        let out = std::env::temp_dir().join("cms-floor-flags-never-written");
        let base = FloorOptions {
            reduced: true,
            only: None,
            lights: Vec::new(),
            step_mm: Some(10.0),
            sensor: Sensor::reference(),
            length_mm: 2000.0,
            threads: Some(1),
            out: out.clone(),
        };
        assert!(matches!(floor(&base), Err(BenchError::Options(_))), "a step without a head");
        let dark =
            FloorOptions { lights: vec![light], sensor: Sensor { power_mw: 0.0, ..Sensor::reference() }, ..base };
        assert!(matches!(floor(&dark), Err(BenchError::Options(_))), "no light");
        assert!(!out.exists());
    }
}
