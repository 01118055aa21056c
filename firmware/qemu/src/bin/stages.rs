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
//! `refresh` is what a row that refreshes the noise estimates adds (the
//! pixel noise and the screen's σ, one row in `NOISE_ROWS`); `candidates`
//! the block screen over the row; `copy`, `load` and `window` the copy of
//! one candidate's window alone, with the spike screen's first test, and
//! with the repair (a stand-in `k_q16`); `ricker` the eight Ricker
//! responses of the scale range at the brightest pixel of the first
//! candidate; `slope_zero` the sub-pixel zero at rung 8 from there (by the
//! whole-pixel bracket); `front` a `detect` call with a threshold no
//! candidate passes; `detect` the whole call.

#![no_std]
#![no_main]

use core::fmt::Write as _;
use core::hint::black_box;

use cms_core::fixed::{Px, Q48_16};
use cms_core::peak::{Config, Detector, Stripes, coarse, cwt, kernels, screen};
use cms_qemu::board::SYSCLK_HZ;
use cms_qemu::{clock, uart};
use static_cell::StaticCell;

mod data {
    #![allow(dead_code, reason = "the search windows are cms-qemu-bench's")]
    include!(concat!(env!("OUT_DIR"), "/bench_data.rs"));
}
const N: usize = data::LEN;

/// The rows (decoded) and the stages' buffers.
struct Bufs {
    rows: [[u16; N]; data::DISTINCT],
    x: [i32; N],
    r: [i32; N],
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

/// Pixels copied around one candidate (the detector's window for these rows).
const WINDOW: usize = 71;

fn copy(row: &[u16], x: &mut [i32], sat: i32) {
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
    let bu = BUFS.init(Bufs { rows: [[0; N]; data::DISTINCT], x: [0; N], r: [0; N] });
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
        let Bufs { rows, x, r } = bu;
        let lb = screen::block_log2(Px(geo as i32));
        let refresh = per_call(|i| {
            let row = black_box(&rows[i][..]);
            black_box(screen::pixel_noise_q8(row, sat, r));
            let m = screen::responses(row, lb, r);
            black_box(screen::sigma_q8(&mut r[..m]));
        });
        let noise = screen::pixel_noise_q8(&rows[0][..], sat, r);
        let m = screen::responses(&rows[0][..], lb, r);
        let sigma = screen::sigma_q8(&mut r[..m]);
        let threshold = ((sigma.0 as i64 * cfg.threshold_sigma_q8 as i64 * 154) >> 24).max(1) as i32;
        let mut cands = heapless::Vec::new();
        let candidates = per_call(|i| {
            screen::candidates(black_box(&rows[i][..]), lb, true, threshold, &mut cands);
            black_box(cands.len());
        });
        screen::candidates(&rows[0][..], lb, true, threshold, &mut cands);
        let c0 = cands.first().map_or(N / 2, |c| c.pos);
        let (lo, hi) = (c0.saturating_sub(WINDOW / 2), (c0 + WINDOW / 2).min(N));
        let level = coarse::spike_screen_level(noise);
        let mut hits = heapless::Vec::<usize, { coarse::MAX_SPIKES }>::new();
        let load = per_call(|i| {
            let w = &mut x[..hi - lo];
            coarse::load_window(black_box(&rows[i][lo..hi]), sat, level, w, &mut hits);
            black_box(&hits);
        });
        let window = per_call(|i| {
            let w = &mut x[..hi - lo];
            coarse::load_window(black_box(&rows[i][lo..hi]), sat, level, w, &mut hits);
            black_box(coarse::repair_spikes(black_box(w), &hits, noise, Q48_16(120_000)));
        });
        let copy_only = per_call(|i| {
            let w = &mut x[..hi - lo];
            copy(black_box(&rows[i][lo..hi]), w, sat);
            black_box(w);
        });
        copy(&rows[0][..], &mut x[..], sat);
        // The brightest pixel near the candidate: where the detector starts.
        let c0 =
            (c0.saturating_sub(6)..=(c0 + 6).min(N - 1)).max_by_key(|&i| (x[i], core::cmp::Reverse(i))).unwrap_or(c0);
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
        // The front end alone: a threshold no candidate passes.
        let mut quiet = cfg;
        quiet.threshold_sigma_q8 = u16::MAX;
        quiet.min_amplitude = u16::MAX;
        let mut det = match Detector::<N>::new(quiet) {
            Ok(d) => d,
            Err(e) => panic!("{e}"),
        };
        let front = per_call(|i| {
            let _ = det.detect(black_box(&rows[i][..]), &mut out);
        });
        let _ = writeln!(
            w,
            "stripes={} refresh={refresh} candidates={candidates} copy{WINDOW}={copy_only} load{WINDOW}={load} window{WINDOW}={window} ricker={ricker} slope_zero={slope_zero} front={front} detect={detect}",
            set.stripes
        );
    }
    let _ = writeln!(w, "done");
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
