//! Cost of one calibration image of the paper's head (4752 × 3168, the
//! board with every laser on): what `cms-host calibrate render --preset
//! paper` spends per pose.
//!
//! `cargo bench -p cms-host --bench render`.

use cms_host::sim::board::{self, BoardRenderer, RenderOptions};
use cms_host::sim::{Scene, SimConfig};
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

criterion_group!(benches, paper_board_image);
criterion_main!(benches);
