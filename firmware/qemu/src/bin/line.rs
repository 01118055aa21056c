//! `cms-qemu-line`: instructions of the head's line pass
//! (`cms_core::pipeline::line`) over one frame of the reference head (three
//! lasers × 480 rows) on the Cortex-M instruction set (QEMU `-icount
//! shift=0`, as `cms-qemu-bench`):
//!
//! ```text
//! cd firmware/qemu && cargo run --release --bin cms-qemu-line
//! ```
//!
//! The frame: each laser's line slanted and bent, a detector's scatter of
//! ±0.6 px, one outlier in 40 rows, and second candidates in `seconds`
//! rows of laser 1 (a ghost 12 px beside it). The pass runs on a fresh copy
//! of the frame each time; the copy alone is timed too and taken off. Each
//! is run 2 then 2 + 8 times, and the difference / 8 is one call.

#![no_std]
#![no_main]

use core::fmt::Write as _;
use core::hint::black_box;

use cms_core::fixed::Px;
use cms_core::peak::Flags;
use cms_core::pipeline::default_detector;
use cms_core::pipeline::line::{Counts, LineCheck, Rules, Seconds};
use cms_core::protocol::{LASERS, LaserPoints, MAX_ROWS_PER_PROFILE, Point};
use cms_qemu::board::SYSCLK_HZ;
use cms_qemu::{clock, uart};
use heapless::Vec;
use static_cell::StaticCell;

type Lasers = Vec<LaserPoints, LASERS>;

struct Bufs {
    frame: Lasers,
    work: Lasers,
    seconds: Seconds,
    check: LineCheck,
}
static BUFS: StaticCell<Bufs> = StaticCell::new();

/// Instructions of one call of `f` (2 calls, then 2 + 8).
fn per_call(mut f: impl FnMut()) -> u64 {
    let mut run = |n: usize| {
        let t0 = clock::counter();
        for _ in 0..n {
            f();
        }
        clock::elapsed_ticks(t0) as u64 * clock::NS_PER_TICK
    };
    let short = run(2);
    (run(10) - short) / 8
}

/// A uniform scatter in ±`amp_q16` (Q16.16 px), deterministic.
fn scatter(state: &mut u32, amp_q16: i32) -> i32 {
    *state ^= *state << 13;
    *state ^= *state >> 17;
    *state ^= *state << 5;
    ((i64::from(*state) * 2 * i64::from(amp_q16)) >> 32) as i32 - amp_q16
}

fn point(row: u16, position: Px) -> Point {
    Point { row, position, strength: 1000, width: Px::from_int(2), flags: Flags::NONE, metric: None }
}

/// The frame and `n_seconds` second candidates of laser 1.
fn build(frame: &mut Lasers, seconds: &mut Seconds, n_seconds: usize) {
    let mut s = 0x9e37_79b9u32;
    frame.clear();
    seconds.clear();
    for k in 0..LASERS as u8 {
        let mut points = Vec::new();
        for r in 0..MAX_ROWS_PER_PROFILE as u16 {
            let rr = i32::from(r);
            // 200 + 180 k px, 0.05 px a row, a crown of 5 px.
            let mut x =
                ((200 + 180 * i32::from(k)) << 16) + rr * 3277 - ((rr - 240) * (rr - 240) * 5) / 58 * 65536 / 1000;
            x += scatter(&mut s, 39_322);
            if r % 40 == 17 {
                x += 6 << 16;
            }
            let _ = points.push(point(r, Px(x)));
        }
        let _ = frame.push(LaserPoints { laser: k, points });
    }
    for i in 0..n_seconds {
        let r = (i * MAX_ROWS_PER_PROFILE / n_seconds.max(1)) as u16;
        let p = frame[1].points[usize::from(r)];
        let _ = seconds.push((1, point(r, p.position + Px::from_int(12))));
    }
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let Some(cp) = cortex_m::Peripherals::take() else { panic!("the core peripherals") };
    let _syst = clock::free_running(cp.SYST);
    uart::init(SYSCLK_HZ, 115_200);
    let mut w = uart::Writer;
    let _ = writeln!(w, "cms-qemu-line");
    let b =
        BUFS.init(Bufs { frame: Vec::new(), work: Vec::new(), seconds: Seconds::new(), check: LineCheck::default() });
    let rules = Rules::new(&default_detector(), None);
    for n_seconds in [0, 48, 480] {
        build(&mut b.frame, &mut b.seconds, n_seconds);
        let Bufs { frame, work, seconds, check } = &mut *b;
        let copy = per_call(|| {
            work.clone_from(frame);
            black_box(&work);
        });
        let mut counts = Counts::default();
        let pass = per_call(|| {
            work.clone_from(frame);
            counts = check.check(&rules, black_box(work.as_mut_slice()), seconds);
        });
        let line = pass.saturating_sub(copy);
        let _ = writeln!(
            w,
            "seconds={n_seconds} points={} copy={copy} frame={line} per_row={} off_line={} second_dropped={}",
            LASERS * MAX_ROWS_PER_PROFILE,
            line / MAX_ROWS_PER_PROFILE as u64,
            counts.off_line,
            counts.second_dropped
        );
    }
    let _ = writeln!(w, "done");
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
