//! `bench speckle`: what real light does to the head's points. Per row and
//! line of simulated frames ([`crate::sim::scene::LightModel`]), the
//! detector's error against the true centre, beside a ±3σ centroid placed
//! on the true centre of the same row (what the light allows a row-by-row
//! estimator), and the speckle bound of the optics (Dorsch, Häusler &
//! Herrmann, Appl. Opt. 33(7), 1994).

use cms_core::peak::{Config, Detector, Stripes};

use super::BenchError;
use crate::sim::scene::{Scene, SimConfig};

/// Per-point scatter of one estimator.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Scatter {
    /// Points given (within 3σ of the true centre).
    pub points: usize,
    /// Points given farther than 3σ from the true centre (wrong lines).
    pub wrong: usize,
    /// RMS error of the points, px.
    pub rms_px: f64,
    /// Robust σ of the errors (1.4826 × their median absolute deviation), px.
    pub robust_px: f64,
}

impl Scatter {
    fn of(errors: &mut [f64], wrong: usize) -> Scatter {
        let n = errors.len();
        if n == 0 {
            return Scatter { wrong, ..Scatter::default() };
        }
        let rms_px = (errors.iter().map(|e| e * e).sum::<f64>() / n as f64).sqrt();
        errors.sort_by(f64::total_cmp);
        let med = errors[n / 2];
        let mut dev: Vec<f64> = errors.iter().map(|e| (e - med).abs()).collect();
        dev.sort_by(f64::total_cmp);
        Scatter { points: n, wrong, rms_px, robust_px: 1.4826 * dev[n / 2] }
    }
}

/// The detector's and the oracle centroid's scatter over some frames.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RowScatter {
    /// Rows × lines with a true stripe.
    pub lines: usize,
    /// The head's detector.
    pub detector: Scatter,
    /// The ±3σ centroid on the true centre.
    pub oracle: Scatter,
}

/// The ±3σ centroid of a row about column `c` (the row's median as its background).
pub fn centroid_at(row: &[u16], c: f64, sigma: f64, background: f64) -> Option<f64> {
    let lo = (c - 3.0 * sigma).round().max(0.0) as usize;
    let hi = ((c + 3.0 * sigma).round() as usize).min(row.len() - 1);
    let (mut s, mut sx) = (0.0, 0.0);
    for (i, &v) in row.iter().enumerate().take(hi + 1).skip(lo) {
        let w = f64::from(v) - background;
        s += w;
        sx += w * i as f64;
    }
    (s > 0.0).then(|| sx / s)
}

static SPK: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
fn centroid_k(row: &[u16], c: f64, sigma: f64, background: f64, k: f64) -> Option<f64> {
    let lo = (c - k * sigma).round().max(0.0) as usize;
    let hi = ((c + k * sigma).round() as usize).min(row.len() - 1);
    let (mut s, mut sx) = (0.0, 0.0);
    for (i, &v) in row.iter().enumerate().take(hi + 1).skip(lo) {
        let w = f64::from(v) - background;
        s += w;
        sx += w * i as f64;
    }
    (s > 0.0).then(|| sx / s)
}

/// Renders `frames` frames of `cfg` and measures every line of every row.
pub fn row_scatter(cfg: &SimConfig, frames: u64, det: Config) -> Result<RowScatter, BenchError> {
    let mut scene = Scene::new(cfg.clone()).map_err(|e| BenchError::Options(e.to_string()))?;
    let mut detector = Detector::<{ crate::input::detect::MAX_ROW }>::new(det)
        .map_err(|source| BenchError::Detector { method: det.method.name(), source })?;
    let (w, h) = (scene.width(), scene.height());
    let mut img = vec![0u16; w * h];
    let (mut de, mut oe) = (Vec::new(), Vec::new());
    let (mut dw, mut ow, mut lines) = (0, 0, 0);
    let mut sorted = vec![0u16; w];
    for f in 0..frames {
        let truth = scene.render_frame(f, scene.all_lasers_mask(), &mut img);
        detector.refresh_noise();
        for r in 0..h {
            let row = &img[r * w..(r + 1) * w];
            let mut out: Stripes<8> = Stripes::new();
            detector
                .detect(row, &mut out)
                .map_err(|source| BenchError::Detect { method: det.method.name(), source })?;
            if std::env::var("SPIKES").is_ok() {
                SPK.fetch_add(detector.stats().spikes as usize, std::sync::atomic::Ordering::Relaxed);
            }
            sorted.copy_from_slice(row);
            sorted.sort_unstable();
            let background = f64::from(sorted[w / 2]);
            for laser in 0..scene.laser_count() {
                let Some(t) = truth.stripes[laser][r] else { continue };
                lines += 1;
                let near =
                    out.iter().map(|s| s.position.to_f64() - t.column_px).min_by(|a, b| a.abs().total_cmp(&b.abs()));
                match near {
                    Some(e) if e.abs() <= 3.0 * t.sigma_px => de.push(e),
                    Some(e) if e.abs() <= 8.0 * t.sigma_px => dw += 1,
                    _ => {}
                }
                if std::env::var("PROTO").is_ok() {
                    // Prototype: iterate a ±kσ centroid from the detector's point.
                    let k: f64 = std::env::var("PROTO").unwrap().parse().unwrap();
                    if let Some(e0) = near.filter(|e| e.abs() <= 3.0 * t.sigma_px) {
                        de.pop();
                        let mut c = t.column_px + e0;
                        let s0 = cfg.nominal_sigma_px();
                        let iters: usize = std::env::var("ITER").map(|v| v.parse().unwrap()).unwrap_or(3);
                        for _ in 0..iters {
                            let lo = (c - 5.0 * s0).round().max(0.0) as usize;
                            let hi = ((c + 5.0 * s0).round() as usize).min(w - 1);
                            let side = |a: usize, b: usize| {
                                row[a..=b].iter().map(|&v| f64::from(v)).sum::<f64>() / (b + 1 - a) as f64
                            };
                            let bg = side(lo, lo + 2).min(side(hi - 2, hi));
                            if let Some(n) = centroid_k(row, c, s0, bg, k) {
                                c = n;
                            }
                        }
                        if std::env::var("DBG").is_ok() && (t.column_px + e0 - c).abs() > 0.05 {
                            println!(
                                "row {r} laser {laser} det {:.4} f64 {:.4} truth {:.4}",
                                t.column_px + e0,
                                c,
                                t.column_px
                            );
                        }
                        de.push(c - t.column_px);
                    }
                }
                match centroid_at(row, t.column_px, t.sigma_px, background) {
                    Some(c) if (c - t.column_px).abs() <= 3.0 * t.sigma_px => oe.push(c - t.column_px),
                    Some(_) => ow += 1,
                    None => {}
                }
            }
        }
    }
    Ok(RowScatter { lines, detector: Scatter::of(&mut de, dw), oracle: Scatter::of(&mut oe, ow) })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::scene::LightModel;

    #[test]
    #[ignore]
    fn explore() {
        let sp = LightModel::speckle(8.0);
        for (name, light, speed) in [
            ("clean", LightModel::incoherent(), 0.0),
            ("F/8 rest", LightModel::speckle(8.0), 0.0),
            ("F/4 rest", LightModel::speckle(4.0), 0.0),
            ("F/8 5 m/s", LightModel::speckle(8.0), 5000.0),
            ("ox", LightModel { oxidation: LightModel::oxidation(), ..sp.clone() }, 2000.0),
            (
                "grease+band",
                LightModel { grease: LightModel::grease(), band: Some(LightModel::running_band()), ..sp.clone() },
                2000.0,
            ),
            ("glints", LightModel { glints: LightModel::glints(), ..sp.clone() }, 2000.0),
            ("ghost", LightModel { ghosts: vec![LightModel::ghost()], ..sp.clone() }, 2000.0),
            ("focus 230", LightModel { focus_mm: Some(230.0), ..LightModel::speckle(4.0) }, 2000.0),
        ] {
            let cfg = SimConfig { light, speed_mm_s: speed, ..SimConfig::reference() };
            let mut det = Config::new(8, cfg.optics().scale_range().unwrap());
            if std::env::var("CENTROID").is_ok() {
                det.method = cms_core::peak::Method::Centroid;
            }
            if std::env::var("MINW").is_ok() {
                det.min_width = cms_core::fixed::Px(45875);
                det.max_width = cms_core::fixed::Px(20 << 16);
            }
            println!("scales {:?} minw {} maxw {}", det.scales, det.min_width.to_f64(), det.max_width.to_f64());
            let t = std::time::Instant::now();
            let s = row_scatter(&cfg, 2, det).unwrap();
            println!("spikes {}", SPK.swap(0, std::sync::atomic::Ordering::Relaxed));
            println!(
                "{name}: {:.1}s lines {} det {:?} oracle {:?}",
                t.elapsed().as_secs_f64(),
                s.lines,
                s.detector,
                s.oracle
            );
        }
    }
}

#[cfg(test)]
mod corr_explore {
    use crate::measure::corrugation::joint_fit;
    use crate::sim::closed_loop::profiles;
    use crate::sim::scene::{Corrugation, LightModel, SimConfig};

    #[test]
    #[ignore]
    fn corr() {
        for (name, light, speed) in [
            ("clean", LightModel::incoherent(), 2000.0),
            ("F/8 rest", LightModel::speckle(8.0), 0.0),
            ("F/4 rest", LightModel::speckle(4.0), 0.0),
            ("F/8 5m/s", LightModel::speckle(8.0), 5000.0),
            ("ox", LightModel { oxidation: LightModel::oxidation(), ..LightModel::speckle(8.0) }, 2000.0),
            ("ghost", LightModel { ghosts: vec![LightModel::ghost()], ..LightModel::speckle(8.0) }, 2000.0),
        ] {
            for (l, a) in [(15.0, 20.0), (30.0, 50.0), (50.0, 50.0)] {
                for run in 0..3u64 {
                    let mut cfg = SimConfig {
                        light: light.clone(),
                        speed_mm_s: speed,
                        seed: 100 + run,
                        ..SimConfig::reference()
                    };
                    cfg.rail.roughness_rms_um = 0.0;
                    let phase = (run as f64 * 0.618).fract() * 6.283;
                    cfg.rail.corrugation = vec![Corrugation { wavelength_mm: l, amplitude_um: a, phase_rad: phase }];
                    let r = profiles(&cfg, 1).map_err(|e| e.to_string()).and_then(|(m, p)| {
                        let n = p.iter().map(|v| v.len()).sum::<usize>();
                        joint_fit(&m.lines(&p)).map(|(j, _)| (j, n)).map_err(|e| e.to_string())
                    });
                    match r {
                        Ok((j, n)) => println!(
                            "{name} λ{l} A{a} run{run}: pts {n} λ {:+.3}±{:.3} A {:+.1}±{:.1} {}",
                            j.wavelength_mm - l,
                            j.wavelength_sigma_mm.unwrap_or(f64::NAN),
                            j.amplitude_mm * 1e3 - a,
                            j.amplitude_sigma_mm.unwrap_or(f64::NAN) * 1e3,
                            j.verdict
                        ),
                        Err(e) => println!("{name} λ{l} A{a} run{run}: {e}"),
                    }
                }
            }
        }
    }
}
