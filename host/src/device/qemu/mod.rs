//! The emulated sensor head: `cms-host listen qemu` and `cms-host bench qemu`.
//!
//! The head's firmware for QEMU's `mps2-an386` (Cortex-M4F) and `mps2-an500`
//! (Cortex-M7) boards lives in `firmware/qemu/` (its own cargo workspace).
//! This module finds or builds its images, starts `qemu-system-arm`, and
//! hands the listener a serial port:
//!
//! 1. **Image** ([`find_image`]), the first of:
//!    * `--qemu-image FILE` (`bench qemu --image FILE`);
//!    * the environment variable [`HEAD_IMAGE_ENV`] (`CMS_QEMU_IMAGE`;
//!      [`BENCH_IMAGE_ENV`], `CMS_QEMU_BENCH_IMAGE`, for the benchmark);
//!    * `cms-qemu-head` (`cms-qemu-bench`) in the directory of the running
//!      `cms-host`, for an installed copy;
//!    * built in the checkout this is run from: the first of the current
//!      directory, the binary's directory and their parents that holds
//!      `firmware/qemu/Cargo.toml`. `cargo build --release` is run there
//!      each time (a no-op when nothing changed), so the image is never
//!      stale.
//!
//!    Nothing about the checkout is compiled into the binary, so an
//!    installed `cms-host` works anywhere given an image, and says in one
//!    line how to get one when it has none.
//! 2. **Start paused**: `qemu-system-arm -machine mps2-an386 -display none
//!    -nodefaults -nic none -S -monitor stdio -serial pty -semihosting-config
//!    enable=on,target=native -kernel IMAGE`. QEMU prints the pseudo-terminal
//!    it gave UART0 (`char device redirected to /dev/pts/N (label serial0)`)
//!    on its monitor, which is a pipe of this process.
//! 3. **Attach, then continue**: the pty's slave is opened (and kept open for
//!    QEMU's lifetime, so QEMU sees a reader from the first byte on), then
//!    `cont` goes to the monitor. Nothing the head sends can be lost before
//!    the listener is there.
//! 4. **Listen** on the pty path exactly as on `/dev/ttyACM0`
//!    ([`crate::device::listen`]).
//! 5. **Stop**: `quit` on the monitor; killed if it has not exited after 2 s
//!    (and on drop, whatever happened).
//!
//! Without `-icount` QEMU's clocks follow the host's, so the head keeps real
//! time (frame rate, the 1 s heartbeat watchdog) while it computes at the
//! emulator's speed. The benchmark runs with `-icount shift=0,sleep=off`
//! instead: one instruction per emulated nanosecond, exact and repeatable.
//! (`sleep=off` lets the clock leap over idle time, which would trip the
//! head's heartbeat watchdog between two host heartbeats: it is not for
//! `listen`.)

mod bench;

pub use bench::{
    BenchOptions, BenchReport, BenchRow, EncodeCost, WireCost, bench, bench_table, encode_table, parse_bench,
    run_bench_image, wire_cost, wire_table,
};

use std::fmt;
use std::fs::{File, OpenOptions};
use std::io::{self, BufRead, BufReader, Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// The emulator.
pub const QEMU: &str = "qemu-system-arm";
/// The head's image (a binary of `firmware/qemu`).
pub const HEAD_BIN: &str = "cms-qemu-head";
/// The benchmark's image.
pub const BENCH_BIN: &str = "cms-qemu-bench";
/// The firmware's target.
pub const TARGET: &str = "thumbv7em-none-eabihf";
/// The environment variable naming the head's image.
pub const HEAD_IMAGE_ENV: &str = "CMS_QEMU_IMAGE";
/// The environment variable naming the benchmark's image.
pub const BENCH_IMAGE_ENV: &str = "CMS_QEMU_BENCH_IMAGE";
/// How to build the images, in a checkout.
pub const BUILD_COMMAND: &str = "cd firmware/qemu && cargo build --release";
/// How long QEMU may take to print its pseudo-terminal.
pub const START_TIMEOUT: Duration = Duration::from_secs(10);
/// How long the benchmark may run.
pub const BENCH_TIMEOUT: Duration = Duration::from_secs(600);

/// The emulated board.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Machine {
    /// mps2-an386: Cortex-M4F.
    #[default]
    An386,
    /// mps2-an500: Cortex-M7.
    An500,
}

impl Machine {
    /// QEMU's machine name.
    pub fn qemu_name(self) -> &'static str {
        match self {
            Machine::An386 => "mps2-an386",
            Machine::An500 => "mps2-an500",
        }
    }
}

/// Why the emulated head could not run.
#[derive(Debug, thiserror::Error)]
pub enum QemuError {
    /// `qemu-system-arm` is not on PATH.
    #[error("{QEMU} not found on PATH: install it (Debian/Ubuntu: apt-get install qemu-system-arm)")]
    NotInstalled,
    /// No image given, none beside the binary, and not run from a
    /// checkout to build one in.
    #[error("{}", no_source(bin))]
    NoSource {
        /// The image's name.
        bin: &'static str,
    },
    /// The given or built image does not exist.
    #[error("emulated head image {} does not exist", .0.display())]
    NoImage(PathBuf),
    /// `cargo build` of the image failed.
    #[error("building the emulated head failed ({why}); run `{command}`")]
    Build {
        /// The command that failed, to run by hand.
        command: String,
        /// Why.
        why: String,
    },
    /// A system call failed.
    #[error("{0}: {1}")]
    Io(&'static str, #[source] io::Error),
    /// QEMU did not print a pseudo-terminal.
    #[error("{QEMU} printed no pseudo-terminal within {} s: {output}", START_TIMEOUT.as_secs())]
    NoPty {
        /// The end of what it printed.
        output: String,
    },
    /// QEMU exited unexpectedly.
    #[error("{QEMU} exited ({status}): {stderr}")]
    Exited {
        /// Its status.
        status: ExitStatus,
        /// The end of its error output.
        stderr: String,
    },
    /// The benchmark's output was not as expected.
    #[error("qemu benchmark: {0}")]
    Bench(String),
    /// Options that do not go together.
    #[error("{0}")]
    Usage(String),
}

impl crate::error::Classify for QemuError {
    fn class(&self) -> crate::Class {
        match self {
            QemuError::Usage(_) => crate::Class::Input,
            QemuError::Build { .. } | QemuError::Io(..) | QemuError::Bench(_) => crate::Class::Other,
            _ => crate::Class::Device,
        }
    }
}

/// What to do without an image, in one line.
fn no_source(bin: &str) -> String {
    let flag = if bin == BENCH_BIN { "--image" } else { "--qemu-image" };
    format!(
        "no emulated head image {bin}: give {flag} FILE, set {}, or put {bin} beside cms-host \
         (build it in a checkout of the source: `{BUILD_COMMAND}`, or run cms-host from the checkout)",
        image_env(bin)
    )
}

/// The `firmware/qemu` directory of the checkout this is run from, found
/// at run time: the first of the current directory, the running binary's
/// directory and their parents that holds `firmware/qemu/Cargo.toml`.
pub fn checkout_source() -> Option<PathBuf> {
    let exe_dir = std::env::current_exe().ok().and_then(|e| e.parent().map(Path::to_path_buf));
    let starts = [std::env::current_dir().ok(), exe_dir];
    starts.into_iter().flatten().find_map(|start| {
        start.ancestors().map(|d| d.join("firmware").join("qemu")).find(|d| d.join("Cargo.toml").is_file())
    })
}

/// The environment variable naming `bin`'s image.
fn image_env(bin: &str) -> &'static str {
    if bin == BENCH_BIN { BENCH_IMAGE_ENV } else { HEAD_IMAGE_ENV }
}

/// The image `bin` of `firmware/qemu`, found as the module docs say:
/// `explicit` if given, the environment variable, beside the binary, or
/// built (or found up to date) by cargo in the checkout (cargo's messages
/// go to stderr). A named image must exist.
pub fn find_image(bin: &'static str, explicit: Option<&Path>) -> Result<PathBuf, QemuError> {
    let named = explicit
        .map(Path::to_path_buf)
        .or_else(|| std::env::var_os(image_env(bin)).filter(|v| !v.is_empty()).map(PathBuf::from));
    if let Some(p) = named {
        return if p.is_file() { Ok(p) } else { Err(QemuError::NoImage(p)) };
    }
    let beside = std::env::current_exe().ok().and_then(|e| Some(e.parent()?.join(bin)));
    if let Some(p) = beside.filter(|p| p.is_file()) {
        return Ok(p);
    }
    let Some(dir) = checkout_source() else {
        return Err(QemuError::NoSource { bin });
    };
    let dir = dir.canonicalize().map_err(|e| QemuError::Io("resolving firmware/qemu", e))?;
    let target_dir = dir.join("target");
    let built = target_dir.join(TARGET).join("release").join(bin);
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let command = format!("cd {} && cargo build --release --bin {bin}", dir.display());
    let fresh = !built.is_file();
    if fresh {
        let _ = writeln!(io::stderr(), "qemu: building the emulated head ({command})");
    }
    // From inside firmware/qemu, so that its .cargo/config.toml and the
    // repository's rust-toolchain.toml apply; an explicit target dir so that
    // a CARGO_TARGET_DIR meant for the host crates is not used.
    let mut cmd = Command::new(&cargo);
    cmd.current_dir(&dir)
        .args(["build", "--release", "--target", TARGET, "--bin", bin, "--target-dir"])
        .arg(&target_dir)
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("CARGO_BUILD_TARGET_DIR")
        .env_remove("RUSTFLAGS")
        .env_remove("CARGO_ENCODED_RUSTFLAGS")
        .stdin(Stdio::null())
        .stdout(Stdio::null());
    if !fresh {
        cmd.arg("--quiet");
    }
    match cmd.status() {
        Ok(s) if s.success() => {}
        Ok(s) => return Err(QemuError::Build { command, why: format!("cargo: {s}") }),
        Err(e) if e.kind() == io::ErrorKind::NotFound && built.is_file() => {
            let _ = writeln!(io::stderr(), "qemu: cargo not found; using {} as it is", built.display());
        }
        Err(e) => return Err(QemuError::Build { command, why: format!("cannot run cargo: {e}") }),
    }
    if built.is_file() { Ok(built) } else { Err(QemuError::NoImage(built)) }
}

/// The emulated head's options of `cms-host listen` (they apply only to PORT
/// `qemu`).
#[derive(Clone, Debug, Default)]
pub struct QemuPort {
    /// With PORT `qemu`: the emulated board.
    pub qemu_machine: Option<Machine>,
    /// With PORT `qemu`: the head's image (`None`: found as [`find_image`] says).
    pub qemu_image: Option<PathBuf>,
}

/// A running `qemu-system-arm`. Dropping it ends QEMU.
pub struct Qemu {
    child: Child,
    monitor: Option<ChildStdin>,
    pty: PathBuf,
    // Held open for QEMU's lifetime: QEMU drops what UART0 sends while no
    // one has the slave open, and only notices a new reader once a second.
    _keeper: File,
    stderr: mpsc::Receiver<String>,
    resumed: bool,
}

impl fmt::Debug for Qemu {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Qemu").field("pid", &self.child.id()).field("pty", &self.pty).finish_non_exhaustive()
    }
}

fn spawn_lines(r: impl Read + Send + 'static, tx: mpsc::Sender<String>) {
    std::thread::spawn(move || {
        for line in BufReader::new(r).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                // Nobody listens any more: keep draining so QEMU never blocks.
                continue;
            }
        }
    });
}

/// Starts QEMU on `machine` with `image` and `flags` (the board without
/// display, default devices or network; semihosting on, so that a panicking
/// image ends QEMU). Its stdout and stderr come line by line on the channels.
pub(super) fn spawn_qemu(
    machine: Machine,
    image: &Path,
    flags: &[&str],
    stdin: Stdio,
    own_group: bool,
) -> Result<(Child, mpsc::Receiver<String>, mpsc::Receiver<String>), QemuError> {
    let mut cmd = Command::new(QEMU);
    if own_group {
        // Ctrl-C at the terminal goes to the foreground process group: in a
        // group of its own QEMU outlives it, so that the listener can stop
        // the head (lasers off) before QEMU is told to quit.
        cmd.process_group(0);
    }
    let mut child = match cmd
        .args(["-machine", machine.qemu_name(), "-display", "none", "-nodefaults", "-nic", "none"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .args(flags)
        .arg("-kernel")
        .arg(image)
        .stdin(stdin)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
    {
        Ok(c) => c,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Err(QemuError::NotInstalled),
        Err(e) => return Err(QemuError::Io("starting qemu-system-arm", e)),
    };
    let (out_tx, out_rx) = mpsc::channel();
    let (err_tx, err_rx) = mpsc::channel();
    if let Some(o) = child.stdout.take() {
        spawn_lines(o, out_tx);
    }
    if let Some(e) = child.stderr.take() {
        spawn_lines(e, err_tx);
    }
    Ok((child, out_rx, err_rx))
}

pub(super) fn tail(lines: &[String]) -> String {
    let s = lines.iter().rev().take(3).rev().cloned().collect::<Vec<_>>().join(" | ");
    crate::input::one_line(&s, 400)
}

impl Qemu {
    /// Starts `image` on `machine`, paused, and opens UART0's pseudo-terminal.
    /// Call [`Qemu::resume`] once the listener is ready.
    pub fn start(machine: Machine, image: &Path) -> Result<Qemu, QemuError> {
        let (mut child, out_rx, err_rx) =
            spawn_qemu(machine, image, &["-S", "-monitor", "stdio", "-serial", "pty"], Stdio::piped(), true)?;
        let monitor = child.stdin.take();
        let deadline = Instant::now() + START_TIMEOUT;
        let mut seen = Vec::new();
        let pty = loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match out_rx.recv_timeout(left.min(Duration::from_millis(100))) {
                Ok(line) => {
                    if let Some(p) = pty_of(&line) {
                        break p;
                    }
                    seen.push(line);
                }
                Err(mpsc::RecvTimeoutError::Timeout) if !left.is_zero() => {}
                Err(_) => {
                    let _ = child.kill();
                    let status = child.wait();
                    let errs: Vec<String> = err_rx.try_iter().collect();
                    return Err(match status {
                        Ok(status) if !errs.is_empty() || left.is_zero() => {
                            QemuError::Exited { status, stderr: tail(&errs) }
                        }
                        _ => QemuError::NoPty { output: tail(&seen) },
                    });
                }
            }
            if let Ok(Some(status)) = child.try_wait() {
                let errs: Vec<String> = err_rx.iter().take(20).collect();
                return Err(QemuError::Exited { status, stderr: tail(&errs) });
            }
        };
        let keeper = OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(nix::libc::O_NOCTTY)
            .open(&pty)
            .map_err(|e| QemuError::Io("opening QEMU's pseudo-terminal", e));
        let keeper = match keeper {
            Ok(k) => k,
            Err(e) => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(e);
            }
        };
        Ok(Qemu { child, monitor, pty, _keeper: keeper, stderr: err_rx, resumed: false })
    }

    /// UART0's pseudo-terminal: open it like a serial port.
    pub fn pty(&self) -> &Path {
        &self.pty
    }

    /// QEMU's process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Lets the CPU run (`cont` on the monitor).
    pub fn resume(&mut self) -> Result<(), QemuError> {
        self.monitor_command("cont")?;
        self.resumed = true;
        Ok(())
    }

    fn monitor_command(&mut self, cmd: &str) -> Result<(), QemuError> {
        let Some(m) = self.monitor.as_mut() else {
            return Err(QemuError::Io("QEMU monitor", io::Error::other("closed")));
        };
        m.write_all(format!("{cmd}\n").as_bytes())
            .and_then(|_| m.flush())
            .map_err(|e| QemuError::Io("writing to QEMU's monitor", e))
    }

    /// `Some(status)` once QEMU has exited.
    pub fn exited(&mut self) -> Option<ExitStatus> {
        self.child.try_wait().ok().flatten()
    }

    /// What QEMU printed on stderr so far (its last lines).
    pub fn stderr_tail(&self) -> String {
        tail(&self.stderr.try_iter().collect::<Vec<_>>())
    }

    /// Ends QEMU: `quit` on the monitor, killed after 2 s. Returns its status.
    pub fn stop(mut self) -> Option<ExitStatus> {
        self.shutdown()
    }

    fn shutdown(&mut self) -> Option<ExitStatus> {
        if let Ok(Some(s)) = self.child.try_wait() {
            return Some(s);
        }
        let _ = self.monitor_command("quit");
        self.monitor = None;
        let deadline = Instant::now() + Duration::from_secs(2);
        while Instant::now() < deadline {
            if let Ok(Some(s)) = self.child.try_wait() {
                return Some(s);
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = self.child.kill();
        self.child.wait().ok()
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// The path in QEMU's `char device redirected to /dev/pts/N (label serial0)`.
fn pty_of(line: &str) -> Option<PathBuf> {
    let rest = line.split("char device redirected to ").nth(1)?;
    let (path, label) = rest.split_once(' ')?;
    label.contains("serial0").then(|| PathBuf::from(path))
}

/// Starts the emulated head for `cms-host listen qemu`: the image, QEMU
/// paused, the pty opened, then running. Returns QEMU (drop it to end it).
pub fn start_head(args: &QemuPort) -> Result<Qemu, QemuError> {
    let image = find_image(HEAD_BIN, args.qemu_image.as_deref())?;
    let mut q = Qemu::start(args.qemu_machine.unwrap_or_default(), &image)?;
    q.resume()?;
    Ok(q)
}

/// Runs `f` on the device path of a `listen` PORT: `qemu` starts the
/// emulated head (and ends it afterwards, with a `qemu:` line on stderr);
/// anything else is passed through (the `--qemu-*` options then are an error).
/// `stop` is the Ctrl-C flag: set while QEMU starts, it abandons the start.
pub fn with_port<T>(
    port: &str,
    args: &QemuPort,
    stop: &std::sync::atomic::AtomicBool,
    f: impl FnOnce(&str) -> T,
) -> Result<T, QemuError> {
    if port != "qemu" {
        if args.qemu_machine.is_some() || args.qemu_image.is_some() {
            return Err(QemuError::Usage("--qemu-machine and --qemu-image need PORT `qemu`".into()));
        }
        return Ok(f(port));
    }
    let mut q = start_head(args)?;
    if stop.load(std::sync::atomic::Ordering::SeqCst) {
        q.stop();
        return Err(QemuError::Usage("interrupted while starting the emulated head".into()));
    }
    let Some(path) = q.pty().to_str().map(str::to_string) else {
        return Err(QemuError::Io("QEMU's pty path", io::Error::other("not UTF-8")));
    };
    let r = f(&path);
    let early = q.exited();
    let tail = q.stderr_tail();
    let status = q.stop();
    let _ = match (early, status) {
        (Some(s), _) => writeln!(io::stderr(), "qemu: the emulated head exited by itself ({s}) {tail}"),
        (None, Some(s)) => writeln!(io::stderr(), "qemu: stopped ({s})"),
        (None, None) => writeln!(io::stderr(), "qemu: could not be stopped"),
    };
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::bench::group;
    use super::*;

    /// The emulated head's frames: 1 440 points, under 6 bytes each.
    #[test]
    fn wire_cost_counts_the_profiles() {
        let c = wire_cost(2).unwrap();
        assert_eq!((c.frames, c.points), (2, 2 * 1440));
        assert!(c.bytes_per_point() < 6.0, "{c:?}");
        assert!(wire_table(&c).contains("| bytes/point |"));
    }

    #[test]
    fn the_pty_line_is_found() {
        assert_eq!(
            pty_of("(qemu) char device redirected to /dev/pts/7 (label serial0)"),
            Some(PathBuf::from("/dev/pts/7"))
        );
        assert_eq!(pty_of("char device redirected to /dev/pts/8 (label serial1)"), None);
        assert_eq!(pty_of("QEMU 7.2.22 monitor - type 'help' for more information"), None);
    }

    #[test]
    fn bench_output_parses_and_tabulates() {
        let text = "cms-qemu-bench board=qemu-mps2-an386 cpu=cortex-m4f clock_hz=25000000\n\
                    calibration loop_iterations=1000 ns=2000\n\
                    method=cwt size=752x1 rows=256 ns_short=640 ns_long=3200 found=320/320\n\
                    method=cwt size=752x3 rows=256 ns_short=640 ns_long=25600640 found=319/320\n\
                    method=cwt size=752x3 window=96 rows=256 ns_short=640 ns_long=1280640 found=320/320\n\
                    method=cwt size=752x3 window=96 track=20 rows=256 ns_short=640 ns_long=640640 found=320/320\n\
                    line rows=480 frame=960000 off_line=36\n\
                    encode rows=480 frame=720000 bytes=3000 v4_frame=1440000 v4_bytes=8000\n\
                    done\n";
        let r = parse_bench(text).unwrap();
        assert_eq!(r.calibration, (1000, 2000));
        assert_eq!(r.rows[0].instructions, 10.0);
        assert_eq!(r.rows[1].instructions, 100_000.0);
        assert_eq!((r.rows[1].window_px, r.rows[2].window_px), (0, 96));
        let t = bench_table(&r, 480);
        assert_eq!((r.rows[2].track_px, r.rows[3].track_px), (0, 20));
        let head =
            "| 752 px × 3 | rows/s | 752 px × 3, 96-px windows | rows/s | 752 px × 3, 96-px windows tracked ±20 px |";
        assert!(t.contains(head), "{t}");
        assert!(t.contains("| cwt | 10 | 48 000 000 | 100 000 | 4 800 | 5 000 | 96 000 | 2 500 | 192 000 |"), "{t}");
        // 4 800 rows/s × 0.144 mm = 0.69 m/s; × 1 mm = 4.8 m/s.
        assert!(t.contains("| cwt | 6912.00 / 48000.0 | 0.69 / 4.8 | 13.82 / 96.0 | 27.65 / 192.0 |"), "{t}");
        assert!(t.contains("cwt 752x3: 319/320"), "{t}");
        // The whole cost: 100 000 + 960 000 / 480 full, 2 500 + 2 000 tracked.
        assert_eq!(r.line, Some((480, 960_000)));
        assert!(t.contains("| cwt | incoherent | 100 000 | 2 000 | 102 000 | 2 500 | 2 000 | 4 500 | no |"), "{t}");
        // The encoder: 720 000 / 480 = 1 500 a row, 3 000 B / 1 440 points.
        assert_eq!(r.encode, Some(EncodeCost { rows: 480, frame: (720_000, 3000), v4_frame: (1_440_000, 8000) }));
        let e = encode_table(&r);
        assert!(
            e.contains("| 5 | 720 000 | 1 500 | 3 000 | 2.08 |")
                && e.contains("| 4 | 1 440 000 | 3 000 | 8 000 | 5.56 |"),
            "{e}"
        );
        let old = text.replace("line rows=480 frame=960000 off_line=36\n", "");
        assert!(!bench_table(&parse_bench(&old).unwrap(), 480).contains("whole cost"));
        for bad in
            ["", "calibration loop_iterations=1 ns=2\ndone", "cms-qemu-bench x\ncalibration loop_iterations=1 ns=2"]
        {
            assert!(parse_bench(bad).is_err(), "{bad:?}");
        }
        let panicked = "cms-qemu-bench b\ncalibration loop_iterations=1 ns=2\n\0panic: boom\ndone";
        assert!(parse_bench(panicked).unwrap_err().to_string().contains("boom"));
    }

    #[test]
    fn thousands_are_grouped() {
        assert_eq!(group(0), "0");
        assert_eq!(group(999), "999");
        assert_eq!(group(1000), "1 000");
        assert_eq!(group(1234567), "1 234 567");
    }
}
