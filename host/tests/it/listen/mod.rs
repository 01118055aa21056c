//! `cms-host listen` through a real pseudo-terminal.
//!
//! A device thread runs `cms_core::pipeline::Head` (the firmware's own logic,
//! laser-safety rules included) with a test camera that renders rows of three
//! Gaussian stripes, on the master side of a pty. On their way to the pty the
//! head's frames pass an injector that inserts garbage, flips bits, truncates
//! a frame, unplugs the device and plugs it back, or goes silent.
//!
//! **The replug trick.** A pty's slave path (`/dev/pts/N`) cannot be created
//! again under the same name, so the listener is given a symlink inside a
//! temporary directory. Unplugging removes the symlink and closes the master
//! (the listener's reads fail, the path is gone); plugging back opens a new
//! pty and points the symlink at it (created beside and renamed over, so the
//! listener never sees a half-made link). To the listener it is one path that
//! disappears and comes back, as `/dev/ttyACM0` does on a USB replug.
//!
//! Before unplugging, the device waits until the listener has handed on
//! every frame it wrote intact (the listener's `observe` callback counts
//! them into a [`Tally`] the device waits on): the frames "in the cable" at
//! the moment of the unplug are then none, and every frame the device wrote
//! intact can be required at the other end. (On a real unplug the frame in
//! flight is lost; it arrives truncated or not at all, and is counted or
//! simply absent.)
//!
//! **No sleeps.** Every wait is for an event, with a deadline: the device
//! blocks in `poll(2)` on its pty (for a command, or room to write) with
//! the head's frame tick as the timeout; the test waits for the listener's
//! messages on the tally's condition variable and for the device's first
//! plug on a channel; the unplug lasts until the head has turned its lasers
//! off, the silence until the listener asks again. The only timed waits
//! left are the head's own clock while nothing is connected to it, and the
//! listener's protocol timeouts the tests are about.

mod cli;
mod device;
mod robustness;
mod session;

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, mpsc};
use std::thread;
use std::time::{Duration, Instant};

use cms_core::protocol::DeviceMsg;
use cms_host::device::listen::{ListenError, ListenOptions, Summary, listen_with};
use cms_host::recording;

use device::*;

struct Run {
    summary: Result<Summary, ListenError>,
    /// Profile sequence numbers the listener handed on, in order.
    seen: Vec<u32>,
    json: Vec<u8>,
    report: Report,
    /// CPU time of the listener's thread, s.
    cpu_s: f64,
    wall_s: f64,
}

fn thread_cpu_s() -> f64 {
    use nix::sys::resource::{UsageWho, getrusage};
    match getrusage(UsageWho::RUSAGE_THREAD) {
        Ok(u) => {
            let t = |tv: nix::sys::time::TimeVal| tv.tv_sec() as f64 + tv.tv_usec() as f64 * 1e-6;
            t(u.user_time()) + t(u.system_time())
        }
        Err(_) => f64::NAN,
    }
}

/// Runs the device with `plan` and the listener with `opts` until the
/// listener has handed on `want` profiles (or `limit` passed), then stops both.
fn run(dir: &Path, plan: Plan, opts: ListenOptions, want: u64, limit: Duration) -> Run {
    let link = dir.join("ttyCMS");
    let dev_stop = Arc::new(AtomicBool::new(false));
    let tally = Arc::new(Tally::default());
    let (plugged, is_plugged) = mpsc::channel();
    let dev = {
        let (link, stop) = (link.clone(), dev_stop.clone());
        let hooks = Hooks { plugged, listener: Some(tally.clone()) };
        thread::Builder::new().stack_size(16 << 20).spawn(move || device(link, plan, stop, hooks)).unwrap()
    };
    is_plugged.recv_timeout(Duration::from_secs(10)).expect("the device creates the link");
    let stop = Arc::new(AtomicBool::new(false));
    let listener = {
        let (stop, tally, port) = (stop.clone(), tally.clone(), link.to_string_lossy().into_owned());
        thread::Builder::new()
            .stack_size(16 << 20)
            .spawn(move || {
                let mut seen = Vec::new();
                let mut json = Vec::new();
                let c0 = thread_cpu_s();
                let t0 = Instant::now();
                let summary = listen_with(&port, &opts, &stop, &mut json, &mut |m| {
                    if let DeviceMsg::Profile(p) = m {
                        seen.push(p.seq);
                    }
                    let profile = matches!(m, DeviceMsg::Profile(_));
                    tally.update(|s| {
                        s.messages += 1;
                        s.profiles += u64::from(profile);
                    });
                });
                let cpu = thread_cpu_s() - c0;
                tally.update(|s| s.done = true);
                (summary, seen, json, cpu, t0.elapsed().as_secs_f64())
            })
            .unwrap()
    };
    tally.wait_until(Instant::now() + limit, |s| s.profiles >= want || s.done);
    stop.store(true, Ordering::SeqCst);
    let (summary, seen, json, cpu_s, wall_s) = listener.join().expect("the listener panicked");
    // The listener has waited for the head's Ack of its Stop and the Status
    // after it, so the head's state is final: end the device.
    dev_stop.store(true, Ordering::SeqCst);
    let report = dev.join().expect("the device panicked");
    Run { summary, seen, json, report, cpu_s, wall_s }
}

fn recorded_profiles(path: &Path) -> (Vec<u32>, recording::ScanStats, usize) {
    let mut seqs = Vec::new();
    let mut hellos = 0;
    let stats = recording::scan_file(path, |m| {
        match m {
            DeviceMsg::Profile(p) => seqs.push(p.seq),
            DeviceMsg::Hello(_) => hellos += 1,
            _ => {}
        }
        Ok(())
    })
    .expect("recording reads");
    (seqs, stats, hellos)
}
