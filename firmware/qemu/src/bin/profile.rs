//! `cms-qemu-profile`: `cwt` (or another method: `--method`) on the
//! benchmark's three-stripe rows with their
//! three 96-px search windows (`Detector::detect_in`), 64 rows between two
//! marker functions, for a trace of every instruction under QEMU; where the
//! instructions go is then read off the trace:
//!
//! ```text
//! scripts/qemu_profile.py            # builds this, runs QEMU, prints the profile
//! scripts/qemu_profile.py --full     # the full-row search (`detect`) instead
//! scripts/qemu_profile.py --track    # `detect_tracked`, a track of ±20 px
//! scripts/qemu_profile.py --method centroid   # another method's configuration
//! scripts/qemu_profile.py --method line       # the line pass over one frame
//! scripts/qemu_profile.py --method encode     # the link's encoder over one calibrated frame
//! ```
//!
//! `--method line` profiles the head's line pass instead
//! (`cms_core::pipeline::line`, `cms-qemu-line`'s frame without second
//! candidates), run once over the frame: the script gives its
//! instructions per row of the frame (480).
//!
//! QEMU runs with `-singlestep -d exec,nochain` (one translation block per
//! instruction, each logged with its address); the script counts the
//! addresses between `marker_start` and `marker_end` and maps them to
//! functions (`llvm-nm`) and source lines (`llvm-objdump -l`). Inlined code
//! counts where it was inlined to, so the per-function figures are
//! exclusive of called, not inlined, functions.

#![no_std]
#![no_main]

use cms_core::peak::{ColumnWindow, Config, Detector, Stripes, Track, Windows};
use cms_qemu::board::SYSCLK_HZ;
use cms_qemu::line_frame::{Lasers, build};
use cms_qemu::uart;
use static_cell::StaticCell;

mod data {
    #![allow(dead_code, reason = "only the three-stripe rows are profiled")]
    include!(concat!(env!("OUT_DIR"), "/bench_data.rs"));
}

/// Rows profiled (a multiple of 64: one noise refresh each 64).
const ROWS: usize = 64;

static ROW_BUF: StaticCell<[[u16; data::LEN]; data::DISTINCT]> = StaticCell::new();

/// Where the profile starts (three no-ops, so that it is not folded with
/// `marker_end`).
#[inline(never)]
fn marker_start() {
    cortex_m::asm::nop();
    cortex_m::asm::nop();
    cortex_m::asm::nop();
}

/// Where the profile ends.
#[inline(never)]
fn marker_end() {
    cortex_m::asm::nop();
}

/// The line pass over one frame between the markers.
fn line_pass() {
    use cms_core::pipeline::default_detector;
    use cms_core::pipeline::line::{LineCheck, Rules, Seconds};
    static BUFS: StaticCell<(Lasers, Seconds, LineCheck)> = StaticCell::new();
    let (frame, seconds, check) = BUFS.init((Lasers::new(), Seconds::new(), LineCheck::default()));
    build(frame, seconds, 0);
    let rules = Rules::new(&default_detector(), None);
    marker_start();
    let _ = check.check(&rules, core::hint::black_box(frame.as_mut_slice()), seconds);
    marker_end();
}

/// The link's encoder over the line pass's frame, calibrated, between the
/// markers.
fn encoder() {
    use cms_core::pipeline::line::Seconds;
    use cms_core::protocol::{DeviceMsg, MAX_FRAME, Profile, encode};
    static BUFS: StaticCell<(DeviceMsg, Seconds, [u8; MAX_FRAME])> = StaticCell::new();
    let (msg, seconds, out) = BUFS.init_with(|| (DeviceMsg::Profile(Profile::empty()), Seconds::new(), [0; MAX_FRAME]));
    if let DeviceMsg::Profile(p) = msg {
        build(&mut p.lasers, seconds, 0);
        cms_qemu::line_frame::calibrate(&mut p.lasers);
    }
    marker_start();
    let _ = encode(core::hint::black_box(&*msg), out);
    marker_end();
}

#[cortex_m_rt::entry]
fn main() -> ! {
    uart::init(SYSCLK_HZ, 115_200);
    if option_env!("CMS_PROFILE_METHOD") == Some("encode") {
        encoder();
        cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_SUCCESS);
    }
    if option_env!("CMS_PROFILE_METHOD") == Some("line") {
        line_pass();
        cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_SUCCESS);
    }
    let Some(set) = data::SETS.iter().find(|s| s.stripes == 3) else {
        panic!("no three-stripe rows");
    };
    let rows = ROW_BUF.init([[0; data::LEN]; data::DISTINCT]);
    for (i, r) in rows.iter_mut().enumerate() {
        let raw = &set.rows[i * 2 * data::LEN..][..2 * data::LEN];
        for (p, b) in r.iter_mut().zip(raw.chunks_exact(2)) {
            *p = u16::from_le_bytes([b[0], b[1]]);
        }
    }
    let list: heapless::Vec<ColumnWindow, 3> =
        set.windows.iter().map(|&(first_px, width_px)| ColumnWindow { first_px, width_px }).collect();
    let windows = match Windows::new(&list, data::LEN as u16) {
        Ok(w) => w,
        Err(e) => panic!("benchmark windows: {e}"),
    };
    // The method profiled (`--method`; `cwt` by default): the set's
    // configuration of that name.
    let method = option_env!("CMS_PROFILE_METHOD").unwrap_or("cwt");
    let Some(cfg) =
        set.configs.iter().filter_map(|c| postcard::from_bytes::<Config>(c).ok()).find(|c| c.method.name() == method)
    else {
        panic!("no configuration of that method");
    };
    let mut det = match Detector::<{ data::LEN }>::new(cfg) {
        Ok(d) => d,
        Err(e) => panic!("{e}"),
    };
    let mut out: Stripes<4> = Stripes::new();
    let full_row = option_env!("CMS_PROFILE_FULL_ROW").is_some();
    // A track of ±20 px (`--track`; the benchmark's, see bench.rs).
    let tracked = option_env!("CMS_PROFILE_TRACK").is_some();
    let Ok(mut track) = Track::new(20) else {
        panic!("the track width is refused");
    };
    marker_start();
    for i in 0..ROWS {
        let row = core::hint::black_box(&rows[i % data::DISTINCT][..]);
        let _ = if full_row {
            det.detect(row, &mut out)
        } else if tracked {
            det.detect_tracked(row, &windows, &mut track, &mut out)
        } else {
            det.detect_in(row, &windows, &mut out)
        };
    }
    marker_end();
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
