//! `cms-host listen sim --serve`: the live view, in a real headless
//! Chromium ([`browser`]) and against pages that never read and hostile
//! requests ([`feed`]).
//!
//! Every test runs the binary as a user does, on an ephemeral loopback
//! port (`--serve 127.0.0.1:0`; the address is read from the
//! `listen: live view on …` line), and ends by reading the recording the
//! same run made.

mod browser;
mod feed;
mod live_bands;
mod tls;
mod token;
mod viewer;

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::thread::{self, JoinHandle};
use std::time::Duration;

use cms_core::protocol::{DeviceMsg, Profile};

use crate::common::bin;

/// A `cms-host listen sim --serve 127.0.0.1:0 --record …` process.
struct Listen {
    child: Child,
    /// The page's address as printed: `http://127.0.0.1:PORT/` (`https://`
    /// with `--serve-tls`), with `?token=…` where the view has one.
    url: String,
    /// `127.0.0.1:PORT` (also for a view bound to every address).
    host: String,
    /// The view's token, where it has one.
    token: Option<String>,
    rec: PathBuf,
    stderr: JoinHandle<String>,
}

impl Listen {
    /// Starts it with `extra` arguments, and waits for its address.
    fn start(dir: &Path, extra: &[&str]) -> Listen {
        Listen::start_on(dir, "127.0.0.1:0", extra)
    }

    /// Starts it serving on `serve` with `extra` arguments, and waits for
    /// its address.
    fn start_on(dir: &Path, serve: &str, extra: &[&str]) -> Listen {
        let rec = dir.join("live.cmsrec");
        let mut child = Command::new(bin())
            .args(["listen", "sim", "--sim-light=incoherent", "--serve", serve, "--record"])
            .arg(&rec)
            .args(extra)
            .env("CMS_SIM_STATE", dir.join("sim-state"))
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let (tx, rx) = mpsc::channel();
        let err = child.stderr.take().unwrap();
        let stderr = thread::spawn(move || {
            let mut all = String::new();
            for line in BufReader::new(err).lines().map_while(Result::ok) {
                let _ = tx.send(line.clone());
                all.push_str(&line);
                all.push('\n');
            }
            all
        });
        let url = loop {
            let line = rx.recv_timeout(Duration::from_secs(60)).expect("listen names its live view's address");
            if let Some(rest) = line.strip_prefix("listen: live view on ") {
                break rest.split_whitespace().next().unwrap().to_string();
            }
        };
        let bare = url.strip_prefix("https://").or_else(|| url.strip_prefix("http://")).unwrap();
        let (addr, query) = bare.split_once('/').unwrap();
        let host = addr.replace("0.0.0.0:", "127.0.0.1:");
        let token = query.strip_prefix("?token=").map(String::from);
        Listen { child, url, host, token, rec, stderr }
    }

    /// Ctrl-C, then its exit status and stderr.
    fn interrupt(self) -> (ExitStatus, String) {
        use nix::sys::signal::{Signal, kill};
        use nix::unistd::Pid;
        let _ = kill(Pid::from_raw(self.child.id() as i32), Signal::SIGINT);
        self.wait()
    }

    /// Its end (by `--frames` or `--duration`): exit status and stderr.
    fn wait(mut self) -> (ExitStatus, String) {
        let status = self.child.wait().unwrap();
        (status, self.stderr.join().unwrap())
    }
}

/// One recorded frame as the page shows it, per laser: kept points,
/// rejected candidates, saturated kept points, the kept points' strength
/// summed.
#[derive(Debug, Default, Clone, PartialEq)]
struct Recorded {
    odometer_um: i64,
    lasers: BTreeMap<u8, (usize, usize, usize, u64)>,
}

/// The recording's frames by sequence number, and the sequence numbers in
/// order.
fn recorded(path: &Path) -> (BTreeMap<u32, Recorded>, Vec<u32>) {
    let mut frames: BTreeMap<u32, Recorded> = BTreeMap::new();
    let mut order = Vec::new();
    cms_host::recording::scan_file(path, |m| {
        if let DeviceMsg::Profile(p) = m {
            add(frames.entry(p.seq).or_default(), p);
            if p.part == 0 {
                order.push(p.seq);
            }
        }
        Ok(())
    })
    .expect("the recording reads");
    (frames, order)
}

fn add(r: &mut Recorded, p: &Profile) {
    r.odometer_um = p.odometer_um;
    for l in &p.lasers {
        let e = r.lasers.entry(l.laser).or_default();
        for q in &l.points {
            if q.flags.rejected() {
                e.1 += 1;
            } else {
                e.0 += 1;
                e.2 += usize::from(q.flags.0 & cms_core::peak::Flags::SATURATED.0 != 0);
                e.3 += u64::from(q.strength);
            }
        }
    }
}

/// The number after `label` in the summary line starting `listen: live view:`.
fn view_figure(stderr: &str, label: &str) -> u64 {
    let line = stderr.lines().find(|l| l.starts_with("listen: live view: ")).unwrap_or_else(|| panic!("{stderr}"));
    let at = line.find(label).unwrap_or_else(|| panic!("{label}: {line}"));
    line[..at].split_whitespace().last().and_then(|n| n.parse().ok()).unwrap_or_else(|| panic!("{label}: {line}"))
}

/// Frames missing between sequence numbers in order.
fn gaps(seqs: &[u32]) -> u64 {
    seqs.windows(2).map(|w| u64::from(w[1].saturating_sub(w[0] + 1))).sum()
}

/// The simulated head's `sim: … N profiles dropped on the link` (its pty
/// full: the listener did not read in time).
fn sim_link_drops(stderr: &str) -> u64 {
    let line = stderr.lines().find(|l| l.starts_with("sim: served ")).unwrap_or_else(|| panic!("{stderr}"));
    let at = line.find(" profiles dropped on the link").unwrap_or_else(|| panic!("{line}"));
    line[..at].split_whitespace().last().and_then(|n| n.parse().ok()).unwrap_or_else(|| panic!("{line}"))
}
