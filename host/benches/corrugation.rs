//! Cost of one update of `listen`'s live corrugation estimate
//! (`cms_host::analyze::live`): the window of recent frames stitched and one
//! rotated-sine fit per laser. The frames are those of the reference head
//! at 1 m/s and 30 frames/s (480 points per laser, 68.6 mm each, 33 mm
//! apart) over a rail with 30 µm of corrugation at 50 mm and 2 µm of noise
//! per point: the window holds 16 frames, about half a metre of rail.
//!
//! The live EN 13231-3 band figures (`cms_host::analyze::live::bands`):
//! a frame taken (stitched into one or two stretches, a stretch judged
//! when its travel ends) over 7 m of the same frames at 0.5 m/s (16.7 mm
//! apart), and the open stretch judged at its longest (4.3 m).
//!
//! The live ISO 3095 verdicts (`cms_host::analyze::live::iso3095`): a
//! frame taken (stitched into one or two stitchers) over 7 m at 1 m/s
//! (33.3 mm apart), and a stretch judged by `analyze` at the longest the
//! live view judges (30 m, 900 frames at 1 m/s).
//!
//! `cargo bench -p cms-host --bench corrugation`.

use cms_host::analyze::live::LiveEstimate;
use cms_host::analyze::live::bands::LiveBands;
use cms_host::analyze::live::iso3095::{LiveIso3095, STRETCH_MM};
use cms_host::analyze::stitch::FramePoints;
use cms_study::Rng;
use criterion::{BatchSize, Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use std::time::Duration;

/// `n` frames `step_mm` apart.
fn frames(n: u32, step_mm: f64) -> Vec<FramePoints> {
    // The studies' seeded generator: 2 µm RMS of Gaussian noise per point.
    let mut rng = Rng::new(0x9e37_79b9_7f4a_7c15);
    let mut noise = move || 2.0 * rng.normal();
    let mut out = Vec::new();
    for i in 0..n {
        let o = step_mm * i as f64;
        let mut f = FramePoints { seq: i, odometer_mm: o, ..FramePoints::default() };
        for (k, pts) in f.lasers.iter_mut().enumerate() {
            *pts = (0..480)
                .map(|r| -34.3 + 0.143 * r as f64)
                .map(|a| (a, 30.0 * (std::f64::consts::TAU * (o + a) / 50.0).sin() + 100.0 * k as f64 + noise()))
                .collect();
        }
        out.push(f);
    }
    out
}

fn window() -> LiveEstimate {
    let mut live = LiveEstimate::default();
    for f in frames(40, 33.3) {
        live.add(f);
    }
    live
}

fn bands(c: &mut Criterion) {
    let run = frames(420, 16.7);
    let mut g = c.benchmark_group("live");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    g.throughput(Throughput::Elements(run.len() as u64));
    g.bench_function("bands_add_per_frame", |b| {
        b.iter_batched(
            LiveBands::default,
            |mut live| {
                for f in &run {
                    live.add(f);
                }
                live
            },
            BatchSize::LargeInput,
        )
    });
    let mut live = LiveBands::default();
    for f in &run[..258] {
        live.add(f);
    }
    let r = live.judge_open().expect("a report").clone();
    println!("open stretch judged over {:.0} mm", r.recent_mm);
    g.throughput(Throughput::Elements(1));
    g.bench_function("bands_judge", |b| b.iter(|| black_box(live.judge_open().is_some())));
    g.finish();
}

fn iso3095(c: &mut Criterion) {
    let opts = cms_host::analyze::Options::default;
    let run = frames(210, 33.3);
    let mut g = c.benchmark_group("live");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    g.throughput(Throughput::Elements(run.len() as u64));
    g.bench_function("iso3095_add_per_frame", |b| {
        b.iter_batched(
            || LiveIso3095::new(opts()),
            |mut live| {
                for f in &run {
                    live.add(f);
                }
                live
            },
            BatchSize::LargeInput,
        )
    });
    let mut live = LiveIso3095::new(opts());
    for f in frames((STRETCH_MM / 33.3) as u32, 33.3) {
        live.add(&f);
    }
    let r = live.judge_now().expect("a report").clone();
    assert_eq!(r.state, "evaluated", "{r:?}");
    println!("stretch judged: {:.0} mm, {:.0} ms", r.stretch_mm, r.cost_ms.unwrap_or(f64::NAN));
    g.throughput(Throughput::Elements(1));
    g.bench_function("iso3095_judge", |b| b.iter(|| black_box(live.judge_now().is_some())));
    g.finish();
}

fn update(c: &mut Criterion) {
    let live = window();
    let est = live.estimate();
    assert_eq!(est.len(), 3);
    for e in &est {
        let f = e.fit.as_ref().expect("a fit");
        assert!((f.wavelength_mm - 50.0).abs() < 0.5 && (f.amplitude_um - 30.0).abs() < 2.0, "{f:?}");
    }
    println!("window: {} frames, {:.0} mm of track per laser", live.frames(), est[0].length_mm);
    let mut g = c.benchmark_group("live");
    g.sample_size(20).measurement_time(Duration::from_secs(5));
    g.bench_function("estimate", |b| b.iter(|| black_box(live.estimate())));
    g.finish();
}

criterion_group!(benches, update, bands, iso3095);
criterion_main!(benches);
