//! Time per row of every detection method: 640-, 752- and 1280-px 12-bit rows
//! with 1 and 3 stripes (σ = 2.5 px, 30 dB measured over the row), the same
//! rows as `cms-host bench speed` (`cms_study::montecarlo::speed_rows`).
//!
//! `cargo bench -p cms-host --bench detect` (criterion; filter with e.g.
//! `-- 1280x3`). Each iteration detects one row, cycling through 64 distinct
//! rows so branch predictors do not learn one row.

use cms_core::peak::{Detector, Method, Stripes};
use cms_study::montecarlo::{SPEED_LENGTHS, SPEED_MAX_LEN, SPEED_STRIPES, speed_config, speed_rows};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use std::time::Duration;

const BITS: u8 = 12;
const ROWS: usize = 64;

fn detect(c: &mut Criterion) {
    for &len in &SPEED_LENGTHS {
        for &stripes in &SPEED_STRIPES {
            let rows = speed_rows(len, stripes, BITS, ROWS, 1);
            let mut group = c.benchmark_group(format!("detect/{len}x{stripes}"));
            group.throughput(Throughput::Elements(1));
            for m in Method::ALL {
                let mut det = Detector::<SPEED_MAX_LEN>::new(speed_config(m, BITS, stripes)).expect("valid config");
                let mut out: Stripes<4> = Stripes::new();
                let mut i = 0;
                group.bench_function(m.name(), |b| {
                    b.iter(|| {
                        i = (i + 1) % ROWS;
                        det.detect(black_box(rows[i].as_slice()), &mut out).expect("row fits");
                        black_box(out.len())
                    })
                });
            }
            group.finish();
        }
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(30)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_millis(1000));
    targets = detect
}
criterion_main!(benches);
