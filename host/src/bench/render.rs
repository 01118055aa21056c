//! `bench render`: milliseconds of rendering a frame of the reference head's
//! scene under a light model, as the simulated head renders it (every row of
//! a shot; under laser light the speckled stripes, one thread per laser).
//! Wall time and the process's CPU time (every thread's) per frame.

use std::fmt::Write as _;
use std::time::{Duration, Instant};

use crate::sim::scene::{LightModel, Scene, SimConfig};

use super::BenchError;
use super::speed::median;

/// Options of the render benchmark.
#[derive(Debug, Clone)]
pub struct RenderOptions {
    /// The light on the rail.
    pub light: LightModel,
    /// Travel speed along the rail, mm/s.
    pub speed_mm_s: f64,
    /// Frames timed, after one untimed (it makes the FFT plans and filters).
    pub frames: u64,
}

/// The process's CPU time so far, every thread.
fn process_cpu() -> Duration {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID).map(Duration::from).unwrap_or_default()
}

/// What a light model is, in words.
pub fn light_words(light: &LightModel) -> String {
    match light.speckle {
        None if light.is_clean() => "incoherent".into(),
        None => "incoherent, with a finish or ghosts".into(),
        Some(s) => {
            let plain = LightModel { speckle: None, ..light.clone() }.is_clean() && light.glints.per_m == 0.0;
            let extra = if plain { "" } else { ", with a finish, glints or ghosts" };
            format!("laser speckle F/{}, {} pattern(s){extra}", s.f_number, s.patterns)
        }
    }
}

/// Renders `frames` frames of the reference scene and reports the time.
pub fn render(o: &RenderOptions) -> Result<String, BenchError> {
    if o.frames == 0 {
        return Err(BenchError::Options("--frames: at least 1".into()));
    }
    let cfg = SimConfig { light: o.light.clone(), speed_mm_s: o.speed_mm_s, ..SimConfig::reference() };
    let exposure_us = cfg.camera.exposure_us;
    let rate_hz = cfg.frame_rate_hz;
    let mut scene = Scene::new(cfg).map_err(|e| BenchError::Options(format!("scene: {e}")))?;
    let mask = scene.all_lasers_mask();
    let mut img = vec![0u16; scene.width() * scene.height()];
    let (t0, c0) = (Instant::now(), process_cpu());
    scene.render_frame(0, mask, &mut img);
    let first_ms = t0.elapsed().as_secs_f64() * 1e3;
    let first_cpu_ms = (process_cpu() - c0).as_secs_f64() * 1e3;
    let (mut wall, mut cpu) = (Vec::new(), Vec::new());
    for f in 1..=o.frames {
        let (t, c) = (Instant::now(), process_cpu());
        scene.render_frame(f, mask, &mut img);
        wall.push(t.elapsed().as_secs_f64() * 1e3);
        cpu.push((process_cpu() - c).as_secs_f64() * 1e3);
    }
    let (lo, hi) = wall.iter().fold((f64::INFINITY, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
    let (w, c) = (median(&wall), median(&cpu));
    let mut s = String::new();
    let _ = writeln!(
        s,
        "render: reference head (752 × 480 px, 3 lasers), {}, {} mm/s, {exposure_us} µs exposure, frames every {:.1} mm",
        light_words(&o.light),
        o.speed_mm_s,
        o.speed_mm_s / rate_hz
    );
    for (k, (gw, gh, steps)) in scene.light_grids().into_iter().enumerate() {
        let _ = writeln!(s, "laser {k}: a grid of {gw} × {gh} samples, {steps} sub-exposure(s) a frame");
    }
    let _ = writeln!(s, "first frame (plans, filters): {first_ms:.1} ms wall, {first_cpu_ms:.1} ms CPU");
    let _ = writeln!(
        s,
        "{} frames: median {w:.1} ms wall (min {lo:.1}, max {hi:.1}), {c:.1} ms CPU per frame: {:.1} frames/s of rendering alone",
        o.frames,
        1e3 / w
    );
    Ok(s)
}
