//! `cms-qemu-head`: the emulated sensor head.
//!
//! The main loop of a head: read the host's bytes from UART0, decode
//! commands (`FrameReader`), let `cms_core::pipeline::Head` handle them, poll
//! it (heartbeat watchdog, due frames, status) and send its replies as
//! frames on UART0. The camera is `cms_core::synthetic::SceneCamera` on the
//! reference scene (752 × 480, 12 bits, three stripes over a corrugated
//! rail), exposed at the odometer of a head travelling at 1 m/s on its own
//! clock. A host regenerates any received frame's rows from the frame alone
//! (its odometer, laser mask and exposure), which is how the end-to-end test
//! checks every peak bit for bit.
//!
//! The loop sleeps (WFI) until a byte arrives or the next poll is due: every
//! millisecond while streaming, every 50 ms when idle.

#![no_std]
#![no_main]

use cms_core::pipeline::{Head, Identity, default_detector};
use cms_core::protocol::{Command, DeviceMsg, FrameReader, HeadState, MAX_COMMAND_FRAME, MAX_FRAME, encode};
use cms_core::synthetic::{Scene, SceneCamera, SceneConfig};
use cms_qemu::board::{Board, Lasers, SYSCLK_HZ};
use cms_qemu::executor::Executor;
use cms_qemu::{clock, uart};
use embassy_futures::select::select;
use embassy_time::{Duration, Timer};
use static_cell::StaticCell;

/// Row length of the emulated sensor (the MT9V034's).
const WIDTH: usize = 752;
/// Seed of the scene's noise (the host's replay uses the same).
pub const SCENE_SEED: u32 = 1;
/// UART rate (QEMU ignores it; a terminal on the pty sees it).
const BAUD: u32 = 115_200;

/// Encodes a reply and sends it: one frame buffer (postcard writes the
/// frame in place through its CRC and COBS flavours).
struct Link {
    frame: [u8; MAX_FRAME],
}

impl Link {
    fn send(&mut self, msg: &DeviceMsg) {
        // MAX_FRAME bounds every message (cms-core checks the worst case).
        if let Ok(bytes) = encode(msg, &mut self.frame) {
            uart::write_all(bytes);
        }
    }
}

#[embassy_executor::task]
async fn run(board: Board) {
    static LINK: StaticCell<Link> = StaticCell::new();
    static HEAD: StaticCell<Head<WIDTH, Lasers>> = StaticCell::new();
    static READER: StaticCell<FrameReader<MAX_COMMAND_FRAME>> = StaticCell::new();
    let link = LINK.init_with(|| Link { frame: [0; MAX_FRAME] });
    let identity = Identity { firmware: env!("CARGO_PKG_VERSION"), board: board.name() };
    let Ok(head) = Head::new(Lasers, default_detector(), identity) else {
        panic!("the default detector configuration is refused");
    };
    let head = HEAD.init(head);
    let Ok(scene) = Scene::new(SceneConfig::reference(SCENE_SEED)) else {
        panic!("the reference scene is refused");
    };
    let mut camera = SceneCamera::new(scene);
    let reader = READER.init(FrameReader::new());
    let mut rx = [0u8; 64];
    let mut clock_ns = clock::now_ns;
    loop {
        let n = uart::read(&mut rx);
        let now_us = clock::now_us();
        reader.feed::<Command, _>(&rx[..n], |r| match r {
            Ok(cmd) => head.handle(cmd, now_us, &camera, &mut |m| link.send(m)),
            Err(e) => head.link_error(e.into(), &mut |m| link.send(m)),
        });
        if n == rx.len() {
            continue; // more bytes may be waiting
        }
        camera.travel_to(camera.odometer_at(now_us));
        head.poll(now_us, &mut camera, &mut clock_ns, &mut |m| link.send(m));
        let tick = if head.state() == HeadState::Streaming { 1 } else { 50 };
        select(uart::readable(), Timer::after(Duration::from_millis(tick))).await;
    }
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let Some(cp) = cortex_m::Peripherals::take() else {
        panic!("core peripherals taken twice");
    };
    clock::init(cp.SYST);
    uart::init(SYSCLK_HZ, BAUD);
    let board = Board::detect();
    static EXECUTOR: StaticCell<Executor> = StaticCell::new();
    EXECUTOR.init(Executor::new()).run(|spawner| match run(board) {
        Ok(token) => spawner.spawn(token),
        Err(_) => panic!("head task not spawned"),
    })
}
