//! `cms-qemu-stages`: instructions per 752-px row of each stage of the
//! detector's front end on the Cortex-M instruction set (QEMU `-icount
//! shift=0`, as `cms-qemu-bench`), on the benchmark's `cwt` rows:
//!
//! ```text
//! cd firmware/qemu && cargo run --release --bin cms-qemu-stages
//! ```
//!
//! Each stage is called alone on the same 64 rows, 64 then 64 + 256 times,
//! and the difference / 256 is one call (the loop and timer cancel out).
//! `load_row` is the copy with the noise samples and their median;
//! `screen` is `remove_spikes` less a plain copy (it mutates its row, so a
//! fresh copy precedes each call; a stand-in `k_q16`, which only the pixels
//! that pass the screen would meet); `response` the box cascade and second
//! difference; `sigma` the response's median; `candidates` the scan; `ricker`
//! the eight Ricker responses of the scale range at the first candidate;
//! `slope_zero` the sub-pixel zero at rung 8; `detect` the whole call.

#![no_std]
#![no_main]

use core::fmt::Write as _;
use core::hint::black_box;

use cms_core::peak::{Config, Detector, Stripes, coarse, cwt, kernels};
use cms_qemu::board::SYSCLK_HZ;
use cms_qemu::{clock, uart};
use static_cell::StaticCell;

mod data {
    include!(concat!(env!("OUT_DIR"), "/bench_data.rs"));
}
const N: usize = data::LEN;

/// The rows (decoded) and the stages' buffers.
struct Bufs {
    rows: [[u16; N]; data::DISTINCT],
    x: [i32; N],
    r: [i32; N],
    b: [i32; N],
    g: [i32; N],
}
static BUFS: StaticCell<Bufs> = StaticCell::new();

/// Instructions of one call of `f` (over 64 rows, then 64 + 256).
fn per_call(mut f: impl FnMut(usize)) -> u64 {
    let mut run = |n: usize| {
        let t0 = clock::counter();
        for i in 0..n {
            f(i % data::DISTINCT);
        }
        clock::elapsed_ticks(t0) as u64 * clock::NS_PER_TICK
    };
    let short = run(64);
    (run(320) - short) / 256
}

fn copy(row: &[u16; N], x: &mut [i32; N], sat: i32) {
    for (d, &p) in x.iter_mut().zip(row) {
        *d = (p as i32).min(sat);
    }
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let Some(cp) = cortex_m::Peripherals::take() else {
        panic!("core peripherals taken twice");
    };
    let _syst = clock::free_running(cp.SYST);
    uart::init(SYSCLK_HZ, 115_200);
    let mut w = uart::Writer;
    let _ = writeln!(w, "cms-qemu-stages");
    let bu = BUFS.init(Bufs { rows: [[0; N]; data::DISTINCT], x: [0; N], r: [0; N], b: [0; N], g: [0; N] });
    for set in data::SETS {
        for (i, r) in bu.rows.iter_mut().enumerate() {
            let raw = &set.rows[i * 2 * N..][..2 * N];
            for (p, b) in r.iter_mut().zip(raw.chunks_exact(2)) {
                *p = u16::from_le_bytes([b[0], b[1]]);
            }
        }
        let Ok(cfg) = postcard::from_bytes::<Config>(set.configs[0]) else {
            panic!("the cwt configuration does not decode");
        };
        let sat = cfg.saturation as i32;
        let geo = ((cfg.scales.min().0 as u64) * (cfg.scales.max().0 as u64)).isqrt();
        let rung = &kernels::RUNGS[kernels::nearest_rung(geo as i32)];
        let Bufs { rows, x, r, b, g } = bu;
        let load = per_call(|i| {
            black_box(coarse::load_row(black_box(&rows[i][..]), sat, x, r));
        });
        let plain_copy = per_call(|i| {
            copy(black_box(&rows[i]), x, sat);
            black_box(&x);
        });
        let noise_q8 = coarse::pixel_noise_q8(x, r);
        let screen = per_call(|i| {
            copy(black_box(&rows[i]), x, sat);
            black_box(coarse::remove_spikes(black_box(x), noise_q8, 120_000, sat));
        }) - plain_copy;
        let response = per_call(|_| {
            coarse::response(black_box(x), r, b, g, rung);
        });
        let sigma = per_call(|_| {
            black_box(coarse::abs_median_sigma_q8(black_box(r), b));
        });
        coarse::response(x, r, b, g, rung);
        let sigma_q8 = coarse::abs_median_sigma_q8(r, b);
        let threshold = ((sigma_q8 as i64 * cfg.threshold_sigma_q8 as i64) >> 16).max(1) as i32;
        let candidates = per_call(|_| {
            black_box(coarse::candidates(black_box(r), threshold).len());
        });
        let c0 = coarse::candidates(r, threshold).first().map_or(N / 2, |c| c.pos);
        let ricker = per_call(|_| {
            for k in 1..=8 {
                black_box(cwt::response_q8(black_box(x), c0, k));
            }
        });
        let slope_zero = per_call(|_| {
            black_box(cwt::slope_zero(black_box(x), c0, kernels::deriv(8)));
        });
        let mut det = match Detector::<N>::new(cfg) {
            Ok(d) => d,
            Err(e) => panic!("{e}"),
        };
        let mut out: Stripes<4> = Stripes::new();
        let detect = per_call(|i| {
            let _ = det.detect(black_box(&rows[i][..]), &mut out);
        });
        let _ = writeln!(
            w,
            "stripes={} load_row={load} screen={screen} response={response} sigma={sigma} candidates={candidates} ricker={ricker} slope_zero={slope_zero} detect={detect}",
            set.stripes
        );
    }
    let _ = writeln!(w, "done");
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
