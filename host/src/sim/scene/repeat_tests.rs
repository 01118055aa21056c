//! Repeat runs over the same rail: the speckle is the surface's, so a run
//! whose lines fall on the same strip of the rail head sees the same
//! speckle, and one standing a stripe's width or more across sees other.

use super::{LightModel, Scene, SimConfig};

/// The rail as the push trolley reads it (laser speckle at its setting),
/// the head `lateral_mm` across, run `run`.
fn run(lateral_mm: f64, run: u64) -> SimConfig {
    let mut cfg = SimConfig { light: LightModel::push_trolley(), speed_mm_s: 500.0, run, ..SimConfig::reference() };
    cfg.head.lateral_offset_mm = lateral_mm;
    cfg
}

/// Per row of frame 0, each line's centroid within ±3σ of its true centre
/// (background taken out) less that centre, px; each line's mean taken out
/// (the window's own bias is common to every run).
fn centroid_errors(cfg: SimConfig) -> Vec<f64> {
    let mut scene = Scene::new(cfg).unwrap();
    let (w, h) = (scene.width(), scene.height());
    let mut img = vec![0u16; w * h];
    let t = scene.render_frame(0, scene.all_lasers_mask(), &mut img);
    let mut all = Vec::new();
    for line in &t.stripes {
        let mut e: Vec<f64> = (0..h)
            .map(|r| {
                let s = line[r].expect("every row sees every line");
                let (lo, hi) =
                    ((s.column_px - 3.0 * s.sigma_px) as usize, (s.column_px + 3.0 * s.sigma_px) as usize + 1);
                let px = &img[r * w..(r + 1) * w];
                let bg = (f64::from(px[lo]) + f64::from(px[hi])) / 2.0;
                let (mut m0, mut m1) = (0.0, 0.0);
                for (c, &v) in px.iter().enumerate().take(hi + 1).skip(lo) {
                    let v = (f64::from(v) - bg).max(0.0);
                    m0 += v;
                    m1 += v * c as f64;
                }
                m1 / m0 - s.column_px
            })
            .collect();
        let mean = e.iter().sum::<f64>() / e.len() as f64;
        e.iter_mut().for_each(|x| *x -= mean);
        all.extend(e);
    }
    all
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let dot = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(p, q)| p * q).sum::<f64>();
    dot(a, b) / (dot(a, a) * dot(b, b)).sqrt()
}

/// The centroid's speckle error correlates between runs as the
/// autocorrelation of its weight `u·g(u)` across the stripe (g the line's
/// Gaussian of σ): `ρ(δ) = (1 − δ²/2σ²)·exp(−δ²/4σ²)` for a shift δ of
/// the surface under it. The same strip read again (another run's sensor
/// noise) is the same speckle; 3 mm across (7 σ on the rail) is another.
#[test]
fn a_repeat_run_sees_the_same_speckle_unless_the_head_stands_elsewhere() {
    let first = centroid_errors(run(0.0, 0));
    let again = centroid_errors(run(0.0, 1));
    let across = centroid_errors(run(3.0, 1));
    let (same, other) = (correlation(&first, &again), correlation(&first, &across));
    // 3 × 480 rows of speckles about 2 rows long: ~700 independent
    // samples, σ(ρ) ≈ 0.04 where the truth is 0.
    assert!(same > 0.8, "the same strip, another run: ρ = {same}");
    assert!(other.abs() < 0.15, "3 mm across: ρ = {other}");
    // Between: σ of the line on the rail is 3.0 px × 0.143 mm; at
    // δ = 2σ the theory says ρ = −e⁻¹ = −0.37.
    let sigma_mm = run(0.0, 0).nominal_sigma_px() * 200.0 / 1400.0;
    let near = correlation(&first, &centroid_errors(run(2.0 * sigma_mm, 1)));
    assert!((-0.6..-0.15).contains(&near), "2σ across: ρ = {near}, theory −0.37");
    eprintln!("centroid errors between runs: same strip ρ = {same:.3}, 2σ across {near:.3}, 3 mm across {other:.3}");
}

/// Another run's frames read other sensor noise on the same rail; the
/// same run rendered again is the same image.
#[test]
fn each_run_reads_its_own_frame_noise() {
    let image = |run: u64| {
        let cfg = SimConfig { run, ..SimConfig::reference() };
        let mut scene = Scene::new(cfg).unwrap();
        let mut img = vec![0u16; scene.width() * scene.height()];
        let t = scene.render_frame(0, scene.all_lasers_mask(), &mut img);
        (img, t.stripes[1][240].unwrap().profile_um)
    };
    let ((a, rail_a), (again, _), (b, rail_b)) = (image(0), image(0), image(1));
    assert_eq!(a, again);
    assert_eq!(rail_a, rail_b, "the same rail");
    let differ = a.iter().zip(&b).filter(|(x, y)| x != y).count();
    assert!(differ > a.len() / 2, "{differ} of {} pixels differ", a.len());
}
