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

use cms_core::pipeline::default_detector;
use cms_core::pipeline::line::{Counts, LineCheck, Rules, Seconds};
use cms_core::protocol::{LASERS, MAX_ROWS_PER_PROFILE};
use cms_qemu::board::SYSCLK_HZ;
use cms_qemu::line_frame::{Lasers, build};
use cms_qemu::{clock, uart};
use heapless::Vec;
use static_cell::StaticCell;

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
