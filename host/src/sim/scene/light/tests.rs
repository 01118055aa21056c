//! The light model against theory and against the clean renderer.

use super::coherent::{Pupil, pixel_contrast};
use super::*;
use crate::sim::scene::{NoiseModel, Scene, SimConfig};

fn quiet(light: LightModel, speed_mm_s: f64) -> SimConfig {
    SimConfig { light, speed_mm_s, noise: NoiseModel::none(), ..SimConfig::reference() }
}

fn frame(cfg: &SimConfig, index: u64) -> (Vec<u16>, crate::sim::scene::FrameTruth) {
    let mut scene = Scene::new(cfg.clone()).unwrap();
    let mut img = vec![0u16; scene.width() * scene.height()];
    let t = scene.render_frame(index, scene.all_lasers_mask(), &mut img);
    (img, t)
}

/// Sum of a line's pixels within ±4σ of its true centre, per row.
fn line_sums(img: &[u16], t: &crate::sim::scene::FrameTruth, laser: usize, w: usize) -> Vec<f64> {
    (0..t.stripes[laser].len())
        .filter_map(|r| {
            let s = t.stripes[laser][r]?;
            let (lo, hi) = ((s.column_px - 4.0 * s.sigma_px) as usize, (s.column_px + 4.0 * s.sigma_px) as usize);
            Some((lo..=hi).map(|c| f64::from(img[r * w + c])).sum())
        })
        .collect()
}

#[test]
fn the_incoherent_tile_path_is_the_clean_renderer() {
    // A running band of reflectance 1 on both sides: the tile path (sampled
    // illumination, pixel sums) with nothing to change.
    let band = RunningBand { centre_mm: 0.0, half_width_mm: 10.0, outside: 1.0, edge_mm: 0.0 };
    let light = LightModel { band: Some(band), ..LightModel::default() };
    assert!(!light.is_clean());
    let (a, _) = frame(&quiet(LightModel::incoherent(), 2000.0), 3);
    let (b, _) = frame(&quiet(light, 2000.0), 3);
    let worst = a.iter().zip(&b).map(|(x, y)| x.abs_diff(*y)).max().unwrap();
    assert!(worst <= 1, "largest difference {worst} codes");
    assert!(a.iter().zip(&b).filter(|(x, y)| x != y).count() < a.len() / 500);
}

#[test]
fn speckle_keeps_the_light_and_is_fully_developed() {
    // A short exposure (the lines peak at 30–50 codes), so that no speckle
    // clips at 255.
    let dim = |light: LightModel| {
        let mut c = quiet(light, 0.0);
        c.camera.exposure_us = 30.0;
        c
    };
    let (clean, t) = frame(&dim(LightModel::incoherent()), 0);
    let (speckled, _) = frame(&dim(LightModel::speckle(8.0)), 0);
    let w = 752;
    for laser in 0..3 {
        let (a, b) = (line_sums(&clean, &t, laser, w), line_sums(&speckled, &t, laser, w));
        let (sa, sb) = (a.iter().sum::<f64>(), b.iter().sum::<f64>());
        // 480 rows of speckles 2.3 rows long, about 4 across: ±2 %.
        assert!((sb / sa - 1.0).abs() < 0.03, "laser {laser}: {sb} vs {sa}");
    }
    // The peak pixels of the brightest line, row to row: contrast as the
    // pupil and the pixel predict (0.70 at F/8) within sampling.
    let p = Pupil::new(0.685, 8.0, 1400.0 * 6e-3 / (200.0 - 8.4), 6.0, 0.0);
    let (mut s, mut s2, mut n) = (0.0, 0.0, 0.0);
    let (img, _) = frame(&quiet(LightModel::speckle(8.0), 0.0), 0);
    for r in 0..480 {
        let Some(st) = t.stripes[1][r] else { continue };
        let c = st.column_px.round() as usize;
        // Scaled to the line's clean value at that pixel (below clipping:
        // the middle line peaks at 133 codes).
        let v = f64::from(img[r * w + c]) / f64::from(clean[r * w + c]);
        s += v;
        s2 += v * v;
        n += 1.0;
    }
    let mean = s / n;
    let contrast = (s2 / n - mean * mean).sqrt() / mean;
    let want = pixel_contrast(&p, 1.0, 1.0);
    // 480 rows of speckles 2.3 rows long: about 200 independent samples.
    assert!((contrast / want - 1.0).abs() < 0.2, "{contrast} vs {want}");
}

/// The contrast of the third line's peak pixels, row to row, each scaled
/// to its value in incoherent light.
fn peak_contrast(cfg: &SimConfig) -> f64 {
    let (img, t) = frame(cfg, 0);
    let (clean, _) = frame(&SimConfig { light: LightModel::incoherent(), ..cfg.clone() }, 0);
    let (mut s, mut s2, mut n) = (0.0, 0.0, 0.0);
    for (r, st) in t.stripes[2].iter().enumerate() {
        let Some(st) = st else { continue };
        let c = st.column_px.round() as usize;
        let v = f64::from(img[r * 752 + c]) / f64::from(clean[r * 752 + c]);
        (s, s2, n) = (s + v, s2 + v * v, n + 1.0);
    }
    let m = s / n;
    (s2 / n - m * m).sqrt() / m
}

/// K independent patterns summed in intensity (several diodes, a moving
/// diffuser): the contrast falls as 1/√K (Goodman, Speckle Phenomena in
/// Optics §5.2), the variance the prediction carries as a K-th.
#[test]
fn independent_patterns_lower_the_contrast_as_one_over_root_k() {
    let at = |patterns: u32| {
        let light = LightModel { speckle: Some(Speckle { f_number: 8.0, patterns }), ..LightModel::default() };
        peak_contrast(&quiet(light, 0.0))
    };
    let (one, four) = (at(1), at(4));
    // About 200 independent rows: the ratio within 20 %.
    assert!(((four / one) / 0.5 - 1.0).abs() < 0.2, "{one} {four}: {} vs 0.5", four / one);
}

/// The peak pixels' contrast of the third line between two surfaces (two
/// seeds): each pixel scaled to its value in incoherent light, the
/// variance from their difference — so that what the two share (the lens's
/// blur of the line against the clean renderer's, which changes with the
/// line's sub-pixel place) is no part of it.
fn seeds_contrast(light: LightModel) -> f64 {
    let scaled = |seed: u64| {
        let cfg = SimConfig { seed, ..quiet(light.clone(), 0.0) };
        let (img, t) = frame(&cfg, 0);
        let (clean, _) = frame(&SimConfig { light: LightModel::incoherent(), ..cfg.clone() }, 0);
        let peaks = t.stripes[2]
            .iter()
            .enumerate()
            .filter_map(|(r, st)| Some(r * 752 + st.as_ref()?.column_px.round() as usize));
        peaks.map(|k| f64::from(img[k]) / f64::from(clean[k])).collect::<Vec<f64>>()
    };
    let (a, b) = (scaled(1), scaled(2));
    let n = a.len() as f64;
    let var = a.iter().zip(&b).map(|(x, y)| (x - y) * (x - y) / 2.0).sum::<f64>() / n;
    let mean = a.iter().zip(&b).map(|(x, y)| (x + y) / 2.0).sum::<f64>() / n;
    var.sqrt() / mean
}

/// A source of many patterns, rendered from a few with the statistics of
/// all: the contrast still falls as 1/√K.
#[test]
fn many_patterns_rendered_as_few_keep_the_contrast_one_over_root_k() {
    let at = |patterns: u32| {
        seeds_contrast(LightModel { speckle: Some(Speckle { f_number: 8.0, patterns }), ..LightModel::default() })
    };
    let one = at(1);
    for k in [16u32, 100] {
        let want = 1.0 / f64::from(k).sqrt();
        let got = at(k) / one;
        // About 200 independent rows a seed: the ratio within 10 %.
        assert!((got / want - 1.0).abs() < 0.15, "K = {k}: {got} vs {want}");
    }
}

/// Per row and line, the centroid of the noise-free tile's pixels within
/// ±4σ of the true centre, less the true centre, px.
fn centroid_errors(cfg: &SimConfig, exact_patterns: bool) -> Vec<f64> {
    let mut scene = Scene::new(cfg.clone()).unwrap();
    scene.light_cache.exact_patterns = exact_patterns;
    let mut img = vec![0u16; scene.width() * scene.height()];
    let t = scene.render_frame(0, scene.all_lasers_mask(), &mut img);
    let mut errors = Vec::new();
    for (laser, tile) in scene.light_cache.tiles().iter().enumerate() {
        let Some(tile) = tile else { continue };
        for (r, st) in t.stripes[laser].iter().enumerate() {
            let Some(st) = st else { continue };
            let (c0, row) = tile.row(r);
            let (mut s, mut sx) = (0.0, 0.0);
            for (j, e) in row.iter().enumerate() {
                let c = (c0 + j) as f64;
                if (c - st.column_px).abs() <= 4.0 * st.sigma_px {
                    (s, sx) = (s + e, sx + e * c);
                }
            }
            if s > 0.0 {
                errors.push(sx / s - st.column_px);
            }
        }
    }
    errors
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

/// What the stripe centre's error depends on to first order (the
/// intensity's mean and covariance) the fast rendering of many patterns
/// keeps: its RMS is brute force's, every one of 16 patterns filtered.
#[test]
fn the_centroid_error_of_many_patterns_is_brute_forces() {
    let light = LightModel { speckle: Some(Speckle { f_number: 8.0, patterns: 16 }), ..LightModel::default() };
    let cfg = quiet(light, 0.0);
    let (fast, brute) = (rms(&centroid_errors(&cfg, false)), rms(&centroid_errors(&cfg, true)));
    // About 600 independent speckles along the three lines: ±3 % each.
    assert!((fast / brute - 1.0).abs() < 0.15, "fast {fast:.4} px vs brute force {brute:.4} px");
    // And a quarter of one pattern's (1/√16).
    let one = rms(&centroid_errors(&quiet(LightModel::speckle(8.0), 0.0), false));
    assert!((brute / one / 0.25 - 1.0).abs() < 0.2, "{brute} of {one}");
}

/// The RMS width of each line across the rows (its pixels within ±4σ of
/// the true centre about their centroid), px, of a noise-free frame.
fn stripe_widths(cfg: &SimConfig) -> Vec<f64> {
    let mut scene = Scene::new(cfg.clone()).unwrap();
    let mut img = vec![0u16; scene.width() * scene.height()];
    let t = scene.render_frame(0, scene.all_lasers_mask(), &mut img);
    let mut widths = Vec::new();
    for (laser, tile) in scene.light_cache.tiles().iter().enumerate() {
        let Some(tile) = tile else { continue };
        let (mut var, mut n) = (0.0, 0.0);
        for (r, st) in t.stripes[laser].iter().enumerate() {
            let Some(st) = st else { continue };
            let (c0, row) = tile.row(r);
            let near = |j: usize| ((c0 + j) as f64 - st.column_px).abs() <= 4.0 * st.sigma_px;
            let (s, sx) = row
                .iter()
                .enumerate()
                .filter(|(j, _)| near(*j))
                .fold((0.0, 0.0), |(s, sx), (j, e)| (s + e, sx + e * (c0 + j) as f64));
            let m = sx / s;
            let sxx: f64 =
                row.iter().enumerate().filter(|(j, _)| near(*j)).map(|(j, e)| e * ((c0 + j) as f64 - m).powi(2)).sum();
            (var, n) = (var + sxx / s, n + 1.0);
        }
        widths.push((var / n).sqrt());
    }
    widths
}

/// At F/1.4 a rail 5 mm over the standoff is out of the lens's focus and
/// its lines widen; a Scheimpflug sensor holds the middle laser's plane in
/// focus, so that line stays as sharp as a lens focused on it — and the
/// outer lines, whose parallel planes stand 14 mm off that plane along the
/// axis, are blurred more. A sensor per line holds each line in its own
/// focus: the outer line as sharp as a lens focused on its plane.
#[test]
fn a_scheimpflug_sensor_keeps_the_laser_plane_in_focus() {
    let at = |focus_mm: Option<f64>, scheimpflug: bool, sensor_per_line: bool| {
        // Many patterns: the lines nearly their expected intensity.
        let speckle = Some(Speckle { f_number: 1.4, patterns: 10_000 });
        let light = LightModel { speckle, focus_mm, scheimpflug, sensor_per_line, ..LightModel::default() };
        let mut cfg = quiet(light, 0.0);
        let up = crate::sim::scene::Corrugation {
            wavelength_mm: 1e7,
            amplitude_um: 5000.0,
            phase_rad: std::f64::consts::FRAC_PI_2,
        };
        cfg.rail.corrugation = vec![up];
        cfg.camera.exposure_us = 30.0;
        // The middle laser's plane is in focus; one outer line shows the others'.
        cfg.lasers.truncate(2);
        stripe_widths(&cfg)
    };
    let focused = at(Some(195.0), false, false);
    let standoff = at(None, false, false);
    let tilted = at(None, true, false);
    for k in 0..2 {
        assert!(standoff[k] > focused[k] + 0.01, "laser {k}: {} px against {} px in focus", standoff[k], focused[k]);
    }
    assert!((tilted[1] - focused[1]).abs() < 0.003, "{} px against {} px in focus", tilted[1], focused[1]);
    assert!(tilted[0] > standoff[0] + 0.01, "the outer line: {} px against {} px", tilted[0], standoff[0]);
    // The outer line lies at the raised rail's depth too (the crown drops
    // it by a fraction of a mm): its own sensor holds it as sharp as the
    // lens focused at 195 mm does.
    let each = at(None, true, true);
    assert!((each[1] - tilted[1]).abs() < 1e-9, "the middle line: {} px against {} px", each[1], tilted[1]);
    assert!(
        (each[0] - focused[0]).abs() < 0.01 && each[0] < tilted[0] - 0.01,
        "the outer line: {} px with its own sensor, {} px in focus, {} px under one sensor",
        each[0],
        focused[0],
        tilted[0]
    );
    let mut lone = quiet(LightModel { sensor_per_line: true, ..LightModel::speckle(1.4) }, 0.0);
    assert!(crate::sim::scene::Scene::new(lone.clone()).is_err(), "a sensor per line without a Scheimpflug tilt");
    lone.light.scheimpflug = true;
    assert!(crate::sim::scene::Scene::new(lone).is_ok());
}

#[test]
fn speckle_is_frozen_at_rest_and_averages_out_in_motion() {
    let still = quiet(LightModel::speckle(8.0), 0.0);
    let (a, _) = frame(&still, 0);
    let (b, _) = frame(&still, 5);
    assert_eq!(a, b, "a head at rest sees the same speckle every frame");
    let contrast = |speed: f64| peak_contrast(&quiet(LightModel::speckle(8.0), speed));
    // 20 m/s × 100 µs = 2 mm = 14 rows of travel: the window 1 × 15 px.
    let p = Pupil::new(0.685, 8.0, 8.4 / (200.0 - 8.4), 6.0, 0.0);
    let rows = 2000.0 * 1e-3 / 0.1429;
    let want = pixel_contrast(&p, 1.0, 1.0 + rows) / pixel_contrast(&p, 1.0, 1.0);
    let got = contrast(20_000.0) / contrast(0.0);
    assert!((got / want - 1.0).abs() < 0.3, "{got} vs {want}");
    assert!(got < 0.45, "{got}");
}

/// The speckled tiles of frame `index` (noise-free electrons per pixel),
/// every sub-exposure imaged on its own (`exact`) or read from one field.
fn tiles(cfg: &SimConfig, index: u64, exact: bool) -> Vec<Vec<(usize, Vec<f64>)>> {
    let mut scene = Scene::new(cfg.clone()).unwrap();
    scene.light_cache.exact_exposure = exact;
    let mut img = vec![0u16; scene.width() * scene.height()];
    scene.render_frame(index, scene.all_lasers_mask(), &mut img);
    let tiles = scene.light_cache.tiles();
    tiles.iter().flatten().map(|t| (0..480).map(|r| (t.row(r).0, t.row(r).1.to_vec())).collect()).collect()
}

#[test]
fn one_field_read_at_each_sub_exposure_is_the_exact_image() {
    // The surface slides under the head-fixed line by up to 14 rows in the
    // exposure (20 m/s), the line's column and brightness changing along
    // the rows only slowly: one field read at each sub-exposure's place
    // differs from every sub-exposure imaged under its own illumination by
    // a small fraction of the speckle's own fluctuation (measured: 1·10⁻⁴ at
    // F/2.8 and 2 m/s, 4·10⁻³ at F/8 and 20 m/s).
    for (f_number, speed) in [(2.8, 2000.0), (8.0, 20_000.0)] {
        let cfg = quiet(LightModel::speckle(f_number), speed);
        let (fast, exact) = (tiles(&cfg, 1, false), tiles(&cfg, 1, true));
        let (mut diff2, mut fluct2) = (0.0, 0.0);
        for (a, b) in fast.iter().zip(&exact) {
            let at = |r: usize, col: usize| b[r].1.get(col - b[r].0).copied().unwrap_or(0.0);
            for r in 8..472 {
                let ((c0, ra), rb) = (&a[r], &b[r].1);
                // The line's three brightest pixels; the speckle's
                // fluctuation about the mean of 17 rows there.
                let peak = (0..rb.len()).max_by(|&i, &j| rb[i].total_cmp(&rb[j])).unwrap_or(0);
                for k in peak.saturating_sub(1)..(peak + 2).min(rb.len()) {
                    let env = (r - 8..=r + 8).map(|rr| at(rr, c0 + k)).sum::<f64>() / 17.0;
                    diff2 += (ra[k] - rb[k]).powi(2);
                    fluct2 += (rb[k] - env).powi(2);
                }
            }
        }
        let rel = (diff2 / fluct2).sqrt();
        assert!(rel < 0.01, "F/{f_number}, {speed} mm/s: {rel:.2e} of the speckle's fluctuation");
    }
}

#[test]
fn oxidation_darkens_the_lines_where_patches_are() {
    let light = LightModel { oxidation: LightModel::oxidation(), ..LightModel::default() };
    let (clean, t) = frame(&quiet(LightModel::incoherent(), 2000.0), 0);
    let mut darkest: f64 = 1.0;
    let mut touched = 0;
    for f in 0..4 {
        let (img, t2) = frame(&quiet(light.clone(), 2000.0), f);
        let (c2, _) = frame(&quiet(LightModel::incoherent(), 2000.0), f);
        for laser in 0..3 {
            let (a, b) = (line_sums(&c2, &t2, laser, 752), line_sums(&img, &t2, laser, 752));
            for (x, y) in a.iter().zip(&b) {
                let r = y / x;
                assert!(r <= 1.01 && r > 0.0, "{r}");
                darkest = darkest.min(r);
                touched += usize::from(r < 0.95);
            }
        }
    }
    let _ = (clean, t);
    // Patches 5–40 % bright over about 8 % of the rail top.
    assert!(darkest < 0.45, "{darkest}");
    assert!(touched > 20, "{touched}");
}

#[test]
fn glints_are_small_bright_and_saturate() {
    let light = LightModel { glints: Glints { per_m: 200.0, ..LightModel::glints() }, ..LightModel::default() };
    let (img, t) = frame(&quiet(light, 0.0), 0);
    let (clean, _) = frame(&quiet(LightModel::incoherent(), 0.0), 0);
    let changed: Vec<(usize, usize)> =
        (0..480 * 752).filter(|&k| img[k] > clean[k] + 20).map(|k| (k / 752, k % 752)).collect();
    assert!(!changed.is_empty());
    assert!(changed.iter().any(|&(r, c)| img[r * 752 + c] == 255), "no glint saturates");
    // Every changed pixel is within a few σ of a line, and few are changed:
    // 200 glints a metre over 68 mm is about 14 per line, a few pixels each.
    for &(r, c) in &changed {
        let near = t.stripes.iter().any(|l| l[r].is_some_and(|s| (s.column_px - c as f64).abs() < 4.0 * s.sigma_px));
        assert!(near, "glint at ({r}, {c}) off the lines");
    }
    assert!(changed.len() < 3 * 14 * 12, "{}", changed.len());
}

#[test]
fn a_ghost_line_stands_beside_its_laser() {
    let light =
        LightModel { ghosts: vec![Ghost { tilt_px_per_row: 0.0, ..LightModel::ghost() }], ..LightModel::default() };
    let (img, t) = frame(&quiet(light, 2000.0), 0);
    let (clean, _) = frame(&quiet(LightModel::incoherent(), 2000.0), 0);
    let r = 240;
    let s = t.stripes[1][r].unwrap();
    let c = (s.column_px + 12.0).round() as usize;
    let extra = f64::from(img[r * 752 + c]) - f64::from(clean[r * 752 + c]);
    let peak = f64::from(clean[r * 752 + s.column_px.round() as usize]) - 13.0;
    // 30 % of the line's peak (sampled within half a pixel of its centre).
    assert!((extra / peak - 0.3).abs() < 0.05, "{extra} of {peak}");
}

#[test]
fn nonsense_is_refused() {
    let bad = [
        LightModel::speckle(0.5),
        LightModel { speckle: Some(Speckle { f_number: 8.0, patterns: 0 }), ..LightModel::default() },
        LightModel { focus_mm: Some(-1.0), ..LightModel::default() },
        LightModel {
            oxidation: Patches { reflectance: [0.5, 0.2], ..LightModel::oxidation() },
            ..LightModel::default()
        },
        LightModel { glints: Glints { sigma_px: 0.0, ..LightModel::glints() }, ..LightModel::default() },
        LightModel { ghosts: vec![Ghost { laser: 3, ..LightModel::ghost() }], ..LightModel::default() },
    ];
    for light in bad {
        assert!(Scene::new(SimConfig { light: light.clone(), ..SimConfig::reference() }).is_err(), "{light:?}");
    }
}

/// The recommended head: F/1.4, a line source of 100 patterns, a
/// Scheimpflug sensor (the middle line in focus, the outer two 14 mm off
/// it), at 1.5 m/s.
fn recommended(exposure_us: f64) -> SimConfig {
    let speckle = Some(Speckle { f_number: 1.4, patterns: 100 });
    let mut cfg = quiet(LightModel { speckle, scheimpflug: true, ..LightModel::default() }, 1500.0);
    cfg.camera.exposure_us = exposure_us;
    cfg
}

/// A scene rendering many patterns fast or (`rendered`) as four.
fn scene_of(cfg: &SimConfig, rendered: bool) -> Scene {
    let mut scene = Scene::new(cfg.clone()).unwrap();
    scene.light_cache.rendered_patterns = rendered;
    scene
}

/// Per line and row of frame `index`'s noise-free tiles, the error of a
/// centroid over ±3σ re-centred on itself (the detector's), px.
fn row_errors(scene: &mut Scene, index: u64) -> Vec<Vec<Option<f64>>> {
    let mut img = vec![0u16; scene.width() * scene.height()];
    let t = scene.render_frame(index, scene.all_lasers_mask(), &mut img);
    let mut out = Vec::new();
    for (laser, tile) in scene.light_cache.tiles().iter().enumerate() {
        let Some(tile) = tile else { continue };
        let rows = t.stripes[laser].iter().enumerate().map(|(r, st)| {
            let st = st.as_ref()?;
            let (c0, row) = tile.row(r);
            let half = 3.0 * st.sigma_px;
            let mut c = st.column_px;
            for _ in 0..12 {
                let (mut s, mut sx) = (0.0, 0.0);
                for (j, e) in row.iter().enumerate() {
                    let u = (c0 + j) as f64;
                    let part = ((u + 0.5).min(c + half) - (u - 0.5).max(c - half)).clamp(0.0, 1.0);
                    (s, sx) = (s + e * part, sx + e * part * u);
                }
                c = sx / s;
            }
            Some(c - st.column_px)
        });
        out.push(rows.collect());
    }
    out
}

/// The standard deviation of the errors and the correlation of
/// neighbouring rows' (rows `lag` apart), over the rows where both are.
fn spread(e: &[Option<f64>], lag: usize) -> (f64, f64) {
    correlation(&pairs(e, &e[lag..]))
}

/// The standard deviation of the pairs' first members and their correlation.
fn correlation(pairs: &[(f64, f64)]) -> (f64, f64) {
    let n = pairs.len() as f64;
    let (ma, mb) = (pairs.iter().map(|p| p.0).sum::<f64>() / n, pairs.iter().map(|p| p.1).sum::<f64>() / n);
    let (mut saa, mut sbb, mut sab) = (0.0, 0.0, 0.0);
    for (a, b) in pairs {
        (saa, sbb, sab) = (saa + (a - ma) * (a - ma), sbb + (b - mb) * (b - mb), sab + (a - ma) * (b - mb));
    }
    ((saa / n).sqrt(), sab / (saa * sbb).sqrt())
}

/// The fast rendering of many patterns holds each line's stripe-centre
/// error to the patterns' own, rendered as four: its spread and the
/// correlation of neighbouring rows, still and at 1.5 m/s with 100 µs, the
/// middle line in focus and the outer one 14 mm out of it, on stretches of
/// rail other than the one it was calibrated on. And the error is the
/// rail's: two overlapping frames read the same strip's errors as the
/// patterns do, and a head 3 mm across reads others.
#[test]
fn the_fast_rendering_holds_the_centre_error_of_many_patterns() {
    let mut cfg = recommended(1.0);
    // The middle line and one outer line.
    cfg.lasers.truncate(2);
    let (mut fast, mut rendered) = (scene_of(&cfg, false), scene_of(&cfg, true));
    // Calibrated 1 m on.
    row_errors(&mut fast, 40);
    for exposure_us in [1.0, 100.0] {
        fast.cfg.camera.exposure_us = exposure_us;
        rendered.cfg.camera.exposure_us = exposure_us;
        // Two frames 100 mm apart (independent rail): 960 rows a line.
        let (mut a, mut b) = (vec![Vec::new(); 2], vec![Vec::new(); 2]);
        for index in [0, 4] {
            let (ea, eb) = (row_errors(&mut fast, index), row_errors(&mut rendered, index));
            for (laser, (ea, eb)) in ea.into_iter().zip(eb).enumerate() {
                a[laser].extend(ea);
                b[laser].extend(eb);
            }
        }
        for laser in 0..2 {
            let ((sa, ra), (sb, rb)) = (spread(&a[laser], 1), spread(&b[laser], 1));
            // 960 rows: the ratio of spreads within ±3 % (1σ), the
            // correlations within ±0.045.
            assert!((sa / sb - 1.0).abs() < 0.1, "{exposure_us} µs, line {laser}: {sa:.4} px against {sb:.4} px");
            assert!((ra - rb).abs() < 0.12, "{exposure_us} µs, line {laser}: rows correlate {ra:.3} against {rb:.3}");
        }
    }
    // 25 mm a frame: the next frame's row r sees this one's r + 175.
    let lag = 175;
    let overlap = |scene: &mut Scene| -> Vec<f64> {
        let (e0, e1) = (row_errors(scene, 0), row_errors(scene, 1));
        e0.iter().zip(&e1).map(|(a, b)| correlation(&pairs(&a[lag..], b)).1).collect()
    };
    let (a, b) = (overlap(&mut fast), overlap(&mut rendered));
    for laser in 0..2 {
        assert!(
            b[laser] > 0.5 && (a[laser] - b[laser]).abs() < 0.15,
            "line {laser}: overlapping frames correlate {:.3} against {:.3}",
            a[laser],
            b[laser]
        );
    }
    // The head moved across the rail (its speckle's cells, not its lines).
    let here = row_errors(&mut fast, 0);
    fast.cfg.head.lateral_offset_mm += 3.0;
    // Another shot first: the last one's tiles are kept.
    row_errors(&mut fast, 4);
    let there = row_errors(&mut fast, 0);
    for laser in 0..2 {
        let r = correlation(&pairs(&here[laser], &there[laser])).1;
        // 480 rows: ±0.05.
        assert!(r.abs() < 0.2, "line {laser}: 3 mm across correlates {r:.3}");
    }
}

/// The rows where both have an error, paired.
fn pairs(a: &[Option<f64>], b: &[Option<f64>]) -> Vec<(f64, f64)> {
    a.iter().zip(b).filter_map(|(x, y)| Some(((*x)?, (*y)?))).collect()
}
