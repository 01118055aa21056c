//! `cms-qemu-bench`: instructions per row of every detection method on the
//! Cortex-M instruction set, counted by QEMU's `-icount shift=0` (one
//! instruction = one nanosecond of the emulated clock).
//!
//! The rows and detector configurations are `cms-host bench speed`'s (see
//! build.rs): 64 distinct 12-bit rows of 752 px with 1 and 3 stripes of
//! σ = 2.5 px at 30 dB. As in scripts/instructions.sh, each configuration
//! is timed over 64 rows and over 64 + 256 rows, and the difference divided
//! by 256 is the cost of one `Detector::detect` call (the timer reads and
//! the first pass over the rows cancel out). Each configuration is run twice:
//! a full-row search (`window=0`), `detect_in` one 96-px search window
//! per stripe, centred where the rows put the stripes (`window=96`), and
//! `detect_tracked` in the same windows with a track of ±20 px
//! (`window=96 track=20`: the rows' stripes jump up to 16 px from one row
//! to the next, a real line moves less than a pixel). SysTick counts the 25 MHz core
//! clock with its interrupt off, so the count is 40 ns — 40 instructions —
//! per step, ±0.2 instructions per row after the division.
//!
//! Last, the head's line pass (`cms_core::pipeline::line`) over one frame of
//! three lasers × 480 rows (`cms_qemu::line_frame`, no second candidates),
//! run 2 and 2 + 8 times on a fresh copy of the frame, the copy timed alone
//! and taken off: `line` gives its instructions a frame, which the head
//! spends once a frame, after its rows (`cms-host bench qemu` spreads them
//! over the frame's rows for a row's whole cost).
//!
//! And the link's encoder over the same frame calibrated (a metric point in
//! every point): `encode` (protocol 5) and, for comparison, protocol 4's,
//! run 1 and 1 + 4 times: `encode` gives their instructions a frame and
//! their frames' bytes.
//!
//! Output on UART0, one line per measurement, then QEMU is told to exit
//! (semihosting):
//!
//! ```text
//! cms-qemu-bench board=qemu-mps2-an386 cpu=cortex-m4f clock_hz=25000000
//! calibration loop_iterations=1000000 ns=2000000
//! method=cwt size=752x3 window=0 rows=256 ns_short=… ns_long=… found=320/320
//! method=cwt size=752x3 window=96 rows=256 ns_short=… ns_long=… found=320/320
//! method=cwt size=752x3 window=96 track=20 rows=256 ns_short=… ns_long=… found=320/320
//! line rows=480 frame=… off_line=36
//! encode rows=480 frame=… bytes=… v4_frame=… v4_bytes=…
//! done
//! ```

#![no_std]
#![no_main]

use core::fmt::Write as _;

use cms_core::peak::{ColumnWindow, Config, Detector, Stripes, Track, Windows};
use cms_core::pipeline::default_detector;
use cms_core::pipeline::line::{LineCheck, Rules, Seconds};
use cms_core::protocol::{DeviceMsg, MAX_FRAME, MAX_ROWS_PER_PROFILE, Profile, encode, v4};
use cms_qemu::board::{Board, SYSCLK_HZ};
use cms_qemu::line_frame::{Lasers, build, calibrate};
use cms_qemu::{clock, uart};
use static_cell::StaticCell;

mod data {
    include!(concat!(env!("OUT_DIR"), "/bench_data.rs"));
}

/// Rows of the short and the long run (as scripts/instructions.sh).
const SHORT: usize = 64;
const EXTRA: usize = 256;

/// Half width of the tracked runs' tracks, px: the rows' stripes jump up
/// to 16 px (±8 px of jitter) between consecutive rows.
const TRACK_PX: u16 = 20;

/// How a run searches its rows.
#[derive(Clone, Copy)]
enum Search<'a> {
    Full,
    Windows(&'a Windows),
    Tracked(&'a Windows),
}

/// The line pass's frame, the copy it runs on, and its scratch.
struct LineBufs {
    frame: Lasers,
    work: Lasers,
    seconds: Seconds,
    check: LineCheck,
}
static LINE_BUFS: StaticCell<LineBufs> = StaticCell::new();

/// Instructions of the line pass over one frame (see the header), and the
/// points it flagged off the line.
fn line_pass() -> (u64, u32) {
    let b = LINE_BUFS.init(LineBufs {
        frame: Lasers::new(),
        work: Lasers::new(),
        seconds: Seconds::new(),
        check: LineCheck::default(),
    });
    build(&mut b.frame, &mut b.seconds, 0);
    let rules = Rules::new(&default_detector(), None);
    let LineBufs { frame, work, seconds, check } = b;
    let mut per_call = |pass: bool| {
        let mut off_line = 0;
        let mut run = |n: usize| {
            let t0 = clock::counter();
            for _ in 0..n {
                work.clone_from(frame);
                if pass {
                    off_line = check.check(&rules, core::hint::black_box(work.as_mut_slice()), seconds).off_line;
                }
                core::hint::black_box(&work);
            }
            clock::elapsed_ticks(t0) as u64 * clock::NS_PER_TICK
        };
        let short = run(2);
        ((run(10) - short) / 8, off_line)
    };
    let (copy, _) = per_call(false);
    let (pass, off_line) = per_call(true);
    (pass.saturating_sub(copy), off_line)
}

/// The frame a calibrated head sends: the line pass's frame with a metric
/// point in every point (`line_frame::calibrate`), and the frame buffer.
struct WireBufs {
    msg: DeviceMsg,
    seconds: Seconds,
    out: [u8; MAX_FRAME],
}
static WIRE_BUFS: StaticCell<WireBufs> = StaticCell::new();

/// Instructions a frame of `encode` (protocol 5) and of `v4::encode`
/// (protocol 4, for comparison), and their frames' bytes: each run 1 and
/// 1 + 4 times, the difference divided by 4.
fn encoder() -> [(u64, usize); 2] {
    let b = WIRE_BUFS.init_with(|| WireBufs {
        msg: DeviceMsg::Profile(Profile::empty()),
        seconds: Seconds::new(),
        out: [0; MAX_FRAME],
    });
    if let DeviceMsg::Profile(p) = &mut b.msg {
        p.laser_mask = 7;
        build(&mut p.lasers, &mut b.seconds, 0);
        calibrate(&mut p.lasers);
    }
    let WireBufs { msg, out, .. } = b;
    [true, false].map(|v5| {
        let mut bytes = 0;
        let mut run = |n: usize| {
            let t0 = clock::counter();
            for _ in 0..n {
                let r = if v5 { encode(core::hint::black_box(&*msg), out) } else { v4::encode(msg, out) };
                bytes = r.map_or(0, |f| f.len());
            }
            clock::elapsed_ticks(t0) as u64 * clock::NS_PER_TICK
        };
        let short = run(1);
        ((run(5) - short) / 4, bytes)
    })
}

/// Iterations of the calibration loop (2 instructions each).
const LOOP: u32 = 1_000_000;

fn pixels(rows: &[u8], i: usize, out: &mut [u16; data::LEN]) {
    let row = &rows[(i % data::DISTINCT) * 2 * data::LEN..][..2 * data::LEN];
    for (p, b) in out.iter_mut().zip(row.chunks_exact(2)) {
        *p = u16::from_le_bytes([b[0], b[1]]);
    }
}

/// Nanoseconds (= instructions under `-icount shift=0`) of `rows` calls of
/// `detect` (or `detect_in`, `detect_tracked`: `search`), and how many
/// found exactly `stripes` stripes. A run starts with the noise to measure
/// and, tracked, with no track.
fn time(
    det: &mut Detector<{ data::LEN }>,
    rows: &[[u16; data::LEN]],
    n: usize,
    stripes: usize,
    search: Search<'_>,
) -> (u64, usize) {
    let mut out: Stripes<4> = Stripes::new();
    let mut ok = 0;
    let Ok(mut track) = Track::new(TRACK_PX) else {
        panic!("the benchmark's track width is refused");
    };
    // As the head at each frame: the noise measured on the first row and
    // then one row in `NOISE_ROWS`, so the long run holds exactly
    // `EXTRA / NOISE_ROWS` refreshes more than the short one, whatever ran
    // before (the detector is shared between the runs).
    det.refresh_noise();
    let t0 = clock::counter();
    for i in 0..n {
        let row = core::hint::black_box(&rows[i % rows.len()][..]);
        let done = match search {
            Search::Full => det.detect(row, &mut out),
            Search::Windows(w) => det.detect_in(row, w, &mut out),
            Search::Tracked(w) => det.detect_tracked(row, w, &mut track, &mut out),
        };
        // A failed call cannot happen (rows fit the detector); counted as a miss.
        if done.is_ok() && out.len() == stripes {
            ok += 1;
        }
    }
    (clock::elapsed_ticks(t0) as u64 * clock::NS_PER_TICK, ok)
}

/// A loop of exactly two instructions per iteration (`subs`, `bne`): checks
/// that the clock counts instructions.
fn calibration() -> u64 {
    let t0 = clock::counter();
    // SAFETY: the asm only decrements a scratch register to zero.
    unsafe {
        core::arch::asm!(
            "2:",
            "subs {n}, {n}, #1",
            "bne 2b",
            n = inout(reg) LOOP => _,
            options(nomem, nostack),
        );
    }
    clock::elapsed_ticks(t0) as u64 * clock::NS_PER_TICK
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let Some(cp) = cortex_m::Peripherals::take() else {
        panic!("core peripherals taken twice");
    };
    let _syst = clock::free_running(cp.SYST);
    uart::init(SYSCLK_HZ, 115_200);
    let board = Board::detect();
    let mut w = uart::Writer;
    let _ = writeln!(w, "cms-qemu-bench board={} cpu={} clock_hz={SYSCLK_HZ}", board.name(), board.cpu());
    let _ = writeln!(w, "calibration loop_iterations={LOOP} ns={}", calibration());
    // 64 rows of 752 px, decoded once (1.5 KB each).
    let mut rows = [[0u16; data::LEN]; data::DISTINCT];
    let mut det_slot: Option<Detector<{ data::LEN }>> = None;
    for set in data::SETS {
        let (stripes, raw, configs) = (set.stripes, set.rows, set.configs);
        let list: heapless::Vec<ColumnWindow, 3> =
            set.windows.iter().map(|&(first_px, width_px)| ColumnWindow { first_px, width_px }).collect();
        let windows = match Windows::new(&list, data::LEN as u16) {
            Ok(w) => w,
            Err(e) => panic!("benchmark windows: {e}"),
        };
        for (i, r) in rows.iter_mut().enumerate() {
            pixels(raw, i, r);
        }
        for bytes in configs {
            let Ok(cfg) = postcard::from_bytes::<Config>(bytes) else {
                panic!("a benchmark configuration does not decode");
            };
            let det = match Detector::new(cfg) {
                Ok(d) => det_slot.insert(d),
                Err(e) => panic!("{}: {e}", cfg.method.name()),
            };
            for search in [Search::Full, Search::Windows(&windows), Search::Tracked(&windows)] {
                let (short, _) = time(det, &rows, SHORT, stripes, search);
                let (long, ok) = time(det, &rows, SHORT + EXTRA, stripes, search);
                let (window, track) = match search {
                    Search::Full => (0, 0),
                    Search::Windows(_) => (data::WINDOW_PX, 0),
                    Search::Tracked(_) => (data::WINDOW_PX, TRACK_PX),
                };
                let _ = write!(w, "method={} size={}x{stripes} window={window}", cfg.method.name(), data::LEN);
                if track > 0 {
                    let _ = write!(w, " track={track}");
                }
                let _ = writeln!(w, " rows={EXTRA} ns_short={short} ns_long={long} found={ok}/{}", SHORT + EXTRA);
            }
        }
    }
    let (line, off_line) = line_pass();
    let _ = writeln!(w, "line rows={} frame={line} off_line={off_line}", MAX_ROWS_PER_PROFILE);
    let [(v5, bytes5), (v4, bytes4)] = encoder();
    let _ =
        writeln!(w, "encode rows={} frame={v5} bytes={bytes5} v4_frame={v4} v4_bytes={bytes4}", MAX_ROWS_PER_PROFILE);
    let _ = writeln!(w, "done");
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
