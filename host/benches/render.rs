//! What the simulator costs: one camera frame of the reference head (752 ×
//! 480, all lasers) and of the paper's head (4752 × 3168), with and without
//! noise, its truth alone; and one calibration image of the paper's head
//! (the board with every laser on), what `cms-host calibrate render --preset
//! paper` spends per pose.
//!
//! `cargo bench -p cms-host --bench render`.

use cms_host::sim::calibration::board::{self, BoardRenderer, RenderOptions};
use cms_host::sim::scene::{NoiseModel, Scene, SimConfig};
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use std::time::Duration;

fn paper_board_image(c: &mut Criterion) {
    let scene = Scene::new(SimConfig::paper()).expect("the paper preset is valid");
    let r = BoardRenderer::new(&scene, RenderOptions::default());
    let brd = board::board_for(scene.config());
    let pose = board::calibration_poses(&scene, &brd, 1, 1)[0];
    let mut g = c.benchmark_group("calibrate render");
    g.sample_size(10).measurement_time(Duration::from_secs(20));
    g.bench_function("paper board image, lasers on", |b| {
        b.iter(|| {
            let img = r.render(&brd, &pose, scene.all_lasers_mask(), 0);
            assert_eq!((img.width, img.height), (4752, 3168));
            black_box(img)
        })
    });
    g.finish();
}

fn frames(c: &mut Criterion) {
    let quiet = |mut cfg: SimConfig| {
        cfg.noise = NoiseModel { read_noise_e: 0.0, shot_noise: false, row_banding_e: 0.0, ..cfg.noise };
        cfg
    };
    let mut g = c.benchmark_group("sim frame");
    g.sample_size(10);
    for (name, cfg) in [
        ("reference", SimConfig::reference()),
        ("reference, noise-free", quiet(SimConfig::reference())),
        ("paper", SimConfig::paper()),
    ] {
        let mut scene = Scene::new(cfg).expect("the presets are valid");
        let mut img = vec![0u16; scene.width() * scene.height()];
        let mut i = 0u64;
        g.bench_function(format!("{name}: render_frame"), |b| {
            b.iter(|| {
                i += 1;
                black_box(scene.render_frame(i, 0b111, &mut img))
            })
        });
        g.bench_function(format!("{name}: frame_truth"), |b| b.iter(|| black_box(scene.frame_truth(1, 0b111))));
    }
    g.finish();
}

criterion_group!(benches, frames, paper_board_image);
criterion_main!(benches);
