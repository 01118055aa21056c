//! `cms-host bench qemu`: instructions per row of the firmware's detector on
//! the emulated board, and the bytes per point of its frames on the wire.

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use super::{BENCH_BIN, BENCH_TIMEOUT, Machine, QemuError, find_image, spawn_qemu, tail};
use cms_core::protocol::PROTOCOL_VERSION;

/// Options of `cms-host bench qemu`.
#[derive(Debug, Clone, Default)]
pub struct BenchOptions {
    /// The emulated board.
    pub machine: Machine,
    /// The benchmark's image (`None`: found as [`find_image`] says).
    pub image: Option<PathBuf>,
    /// Clock of the implied rows per second, MHz (1 instruction per cycle).
    pub clock_mhz: u32,
}

/// One configuration's count.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchRow {
    /// Method name.
    pub method: String,
    /// Row length, px.
    pub len: usize,
    /// Stripes per row.
    pub stripes: usize,
    /// Width of the search window per stripe, px (`detect_in`); 0: a
    /// full-row search (`detect`).
    pub window_px: usize,
    /// Half width of the windows' tracks, px (`detect_tracked`); 0: not
    /// tracked.
    pub track_px: usize,
    /// Instructions per `detect` call.
    pub instructions: f64,
    /// Rows (of the long run) with exactly `stripes` stripes, and rows.
    pub found: (u64, u64),
}

/// What the benchmark image reported.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchReport {
    /// Board and CPU line.
    pub board: String,
    /// The calibration loop: iterations, and nanoseconds counted.
    pub calibration: (u64, u64),
    /// Every configuration.
    pub rows: Vec<BenchRow>,
    /// The line pass: rows of its frame, and its instructions a frame
    /// (`None`: an image from before it was counted).
    pub line: Option<(u64, u64)>,
    /// The link's encoder over a calibrated frame (`None`: an image from
    /// before it was counted).
    pub encode: Option<EncodeCost>,
}

/// The link's encoder over one calibrated frame, this protocol's and
/// protocol 4's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EncodeCost {
    /// Rows of the frame.
    pub rows: u64,
    /// Instructions a frame, and the frame's bytes.
    pub frame: (u64, u64),
    /// The same in protocol 4.
    pub v4_frame: (u64, u64),
}

/// The methods the head runs, and under which light: the centroid under
/// laser light (the real head's), the CWT under incoherent light
/// (docs/light.md).
pub const HEAD_METHODS: [(&str, &str); 2] = [("centroid", "laser"), ("cwt", "incoherent")];
/// A row's whole cost the head may spend (detection and its share of the
/// line pass), instructions: three stripes over the full row, and tracked.
/// Half of 480 MHz at the sensor's 28 800 rows/s is 8 333.
pub const WHOLE_BUDGET: [u64; 2] = [8_000, 6_000];

fn field<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    line.split_whitespace().find_map(|w| w.strip_prefix(key)?.strip_prefix('='))
}

fn num(line: &str, key: &str) -> Result<u64, QemuError> {
    field(line, key)
        .and_then(|v| v.parse().ok())
        .ok_or_else(|| QemuError::Bench(format!("no number {key}= in {:?}", crate::input::one_line(line, 200))))
}

/// Parses the benchmark image's output (see firmware/qemu/src/bin/bench.rs).
pub fn parse_bench(text: &str) -> Result<BenchReport, QemuError> {
    let mut lines = text.lines().map(str::trim).filter(|l| !l.is_empty());
    let board = lines
        .by_ref()
        .find(|l| l.starts_with("cms-qemu-bench "))
        .ok_or_else(|| QemuError::Bench("no `cms-qemu-bench` header in the output".into()))?
        .trim_start_matches("cms-qemu-bench ")
        .to_string();
    let mut calibration = None;
    let mut line = None;
    let mut encode = None;
    let mut rows = Vec::new();
    let mut done = false;
    for l in lines {
        if l.starts_with("calibration ") {
            calibration = Some((num(l, "loop_iterations")?, num(l, "ns")?));
        } else if l.starts_with("method=") {
            let method = field(l, "method").unwrap_or_default().to_string();
            let size = field(l, "size").unwrap_or_default();
            let (len, stripes) = size
                .split_once('x')
                .and_then(|(a, b)| Some((a.parse().ok()?, b.parse().ok()?)))
                .ok_or_else(|| QemuError::Bench(format!("bad size in {l:?}")))?;
            let (n, short, long) = (num(l, "rows")?, num(l, "ns_short")?, num(l, "ns_long")?);
            let found = field(l, "found")
                .and_then(|f| f.split_once('/'))
                .and_then(|(a, b)| Some((a.parse().ok()?, b.parse().ok()?)))
                .ok_or_else(|| QemuError::Bench(format!("bad found= in {l:?}")))?;
            if n == 0 || long < short {
                return Err(QemuError::Bench(format!("inconsistent counts in {l:?}")));
            }
            // Images from before search windows print no `window=`: full rows.
            let window_px = match field(l, "window") {
                None => 0,
                Some(w) => w.parse().map_err(|_| QemuError::Bench(format!("bad window= in {l:?}")))?,
            };
            // Images from before tracking print no `track=`: not tracked.
            let track_px = match field(l, "track") {
                None => 0,
                Some(t) => t.parse().map_err(|_| QemuError::Bench(format!("bad track= in {l:?}")))?,
            };
            let instructions = (long - short) as f64 / n as f64;
            rows.push(BenchRow { method, len, stripes, window_px, track_px, instructions, found });
        } else if l.starts_with("line ") {
            let (n, frame) = (num(l, "rows")?, num(l, "frame")?);
            if n == 0 {
                return Err(QemuError::Bench(format!("a line pass over no rows in {l:?}")));
            }
            line = Some((n, frame));
        } else if l.starts_with("encode ") {
            let rows = num(l, "rows")?;
            let (frame, v4_frame) = ((num(l, "frame")?, num(l, "bytes")?), (num(l, "v4_frame")?, num(l, "v4_bytes")?));
            if rows == 0 {
                return Err(QemuError::Bench(format!("an encoder over no rows in {l:?}")));
            }
            encode = Some(EncodeCost { rows, frame, v4_frame });
        } else if l == "done" {
            done = true;
        } else if l.starts_with("panic") || l.contains("panic:") {
            return Err(QemuError::Bench(format!("the image panicked: {}", crate::input::one_line(l, 300))));
        }
    }
    let calibration = calibration.ok_or_else(|| QemuError::Bench("no calibration line".into()))?;
    if !done {
        return Err(QemuError::Bench("the output ends before `done`".into()));
    }
    Ok(BenchReport { board, calibration, rows, line, encode })
}

/// Runs the benchmark image under `-icount shift=0,sleep=off` and returns its
/// output.
pub fn run_bench_image(machine: Machine, image: &Path) -> Result<String, QemuError> {
    let flags = ["-icount", "shift=0,sleep=off", "-monitor", "none", "-serial", "stdio"];
    let (mut child, rx, erx) = spawn_qemu(machine, image, &flags, Stdio::null(), false)?;
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().map_err(|e| QemuError::Io("waiting for qemu-system-arm", e))? {
            break s;
        }
        if t0.elapsed() > BENCH_TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            return Err(QemuError::Bench(format!("no end after {} s", BENCH_TIMEOUT.as_secs())));
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    // The reader threads end with the pipes.
    let out: Vec<String> = rx.iter().collect();
    if !status.success() {
        let errs: Vec<String> = erx.iter().collect();
        let mut all = out.clone();
        all.extend(errs);
        return Err(QemuError::Exited { status, stderr: tail(&all) });
    }
    Ok(out.join("\n"))
}

/// The table of `cms-host bench qemu`.
pub fn bench_table(r: &BenchReport, clock_mhz: u32) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Instructions per row on thumbv7em ({}), QEMU -icount shift=0: 1 instruction = 1 emulated ns",
        r.board
    );
    let _ = writeln!(
        s,
        "# calibration: {} iterations of a 2-instruction loop counted as {} instructions",
        r.calibration.0, r.calibration.1
    );
    let _ = writeln!(
        s,
        "# rows/s at {clock_mhz} MHz assume 1 instruction per cycle (a Cortex-M7 dual-issues some pairs and stalls on others)"
    );
    let _ = writeln!(
        s,
        "# travel speed for continuous sampling = rows/s × the row pitch along the rail: {REFERENCE_ROW_PITCH_MM} mm \
         (the reference head: 69 mm over 480 rows) and 1 mm (row skip or binning)"
    );
    let mut sizes: Vec<(usize, usize, usize, usize)> =
        r.rows.iter().map(|b| (b.len, b.stripes, b.window_px, b.track_px)).collect();
    sizes.sort_unstable();
    sizes.dedup();
    let head = |(l, k, w, t): (usize, usize, usize, usize)| match (w, t) {
        (0, _) => format!("{l} px × {k}"),
        (w, 0) => format!("{l} px × {k}, {w}-px windows"),
        (w, t) => format!("{l} px × {k}, {w}-px windows tracked ±{t} px"),
    };
    let find = |m: &str, (l, k, w, t): (usize, usize, usize, usize)| {
        r.rows.iter().find(|b| b.method == m && b.len == l && b.stripes == k && b.window_px == w && b.track_px == t)
    };
    let mut methods: Vec<&str> = Vec::new();
    for b in &r.rows {
        if !methods.contains(&b.method.as_str()) {
            methods.push(&b.method);
        }
    }
    let rate = |b: &BenchRow| clock_mhz as f64 * 1e6 / b.instructions;
    s.push_str("\n| method |");
    for &z in &sizes {
        let _ = write!(s, " {} | rows/s |", head(z));
    }
    s.push_str("\n|---|");
    for _ in &sizes {
        s.push_str("---:|---:|");
    }
    s.push('\n');
    for m in &methods {
        let _ = write!(s, "| {m} |");
        for &z in &sizes {
            match find(m, z) {
                Some(b) => {
                    let _ =
                        write!(s, " {} | {} |", group(b.instructions.round() as u64), group(rate(b).round() as u64));
                }
                None => s.push_str(" — | — |"),
            }
        }
        s.push('\n');
    }
    let _ = write!(
        s,
        "\nTravel speed for continuous sampling, m/s at {REFERENCE_ROW_PITCH_MM} mm / 1 mm per row\n\n| method |"
    );
    for &z in &sizes {
        let _ = write!(s, " {} |", head(z));
    }
    s.push_str("\n|---|");
    for _ in &sizes {
        s.push_str("---:|");
    }
    s.push('\n');
    for m in &methods {
        let _ = write!(s, "| {m} |");
        for &z in &sizes {
            match find(m, z) {
                Some(b) => {
                    let v = rate(b) * 1e-3;
                    let _ = write!(s, " {:.2} / {:.1} |", v * REFERENCE_ROW_PITCH_MM, v);
                }
                None => s.push_str(" — |"),
            }
        }
        s.push('\n');
    }
    if let Some(w) = whole_table(r) {
        s.push_str(&w);
    }
    s + &misses(r)
}

/// The line naming the configurations whose rows did not all give the
/// expected stripes (empty if there is none).
fn misses(r: &BenchReport) -> String {
    let misses: Vec<String> = r
        .rows
        .iter()
        .filter(|b| b.found.0 != b.found.1)
        .map(|b| {
            let w = match (b.window_px, b.track_px) {
                (0, _) => String::new(),
                (w, 0) => format!(" ({w} px windows)"),
                (w, t) => format!(" ({w} px windows tracked ±{t} px)"),
            };
            format!("{} {}x{}{w}: {}/{}", b.method, b.len, b.stripes, b.found.0, b.found.1)
        })
        .collect();
    if misses.is_empty() {
        String::new()
    } else {
        format!("\n# rows without exactly the expected stripes: {}\n", misses.join(", "))
    }
}

/// A row's whole cost for the methods the head runs ([`HEAD_METHODS`]):
/// detection of three stripes over the full row and tracked, plus the line
/// pass's instructions a frame over the frame's rows; `None` without a line
/// pass in the report.
fn whole_table(r: &BenchReport) -> Option<String> {
    use std::fmt::Write as _;
    let (rows, frame) = r.line?;
    let line = frame as f64 / rows as f64;
    let mut s = format!(
        "\n# A row's whole cost on the head: detection (752 px × 3) + the line pass ({} instructions a frame of {rows} rows \
         = {} a row); budget {} full row, {} tracked\n\n\
         | method | light | full row | + line pass | whole | tracked ±20 px | + line pass | whole | within budget |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---|\n",
        group(frame),
        group(line.round() as u64),
        group(WHOLE_BUDGET[0]),
        group(WHOLE_BUDGET[1])
    );
    for (m, light) in HEAD_METHODS {
        let of = |tracked: bool| {
            r.rows.iter().find(|b| {
                b.method == m
                    && b.len == 752
                    && b.stripes == 3
                    && (b.window_px > 0 && b.track_px > 0) == tracked
                    && (tracked || b.window_px == 0)
            })
        };
        let (Some(full), Some(tracked)) = (of(false), of(true)) else {
            continue;
        };
        let whole = [full.instructions + line, tracked.instructions + line];
        let ok = whole[0] <= WHOLE_BUDGET[0] as f64 && whole[1] <= WHOLE_BUDGET[1] as f64;
        let n = |v: f64| group(v.round() as u64);
        let _ = writeln!(
            s,
            "| {m} | {light} | {} | {} | {} | {} | {} | {} | {} |",
            n(full.instructions),
            n(line),
            n(whole[0]),
            n(tracked.instructions),
            n(line),
            n(whole[1]),
            if ok { "yes" } else { "no" }
        );
    }
    Some(s)
}

/// 12345678 → "12 345 678" (the thin grouping of the docs' tables).
pub(super) fn group(v: u64) -> String {
    let d = v.to_string();
    let mut out = String::new();
    for (i, c) in d.chars().enumerate() {
        if i > 0 && (d.len() - i).is_multiple_of(3) {
            out.push(' ');
        }
        out.push(c);
    }
    out
}

/// The reference head's row pitch along the rail, mm: each laser's line
/// covers about 69 mm of rail over the sensor's 480 rows
/// (docs/corrugation-and-standards.md).
pub const REFERENCE_ROW_PITCH_MM: f64 = 0.144;

/// What the emulated head's profiles cost on the wire.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WireCost {
    /// Frames encoded.
    pub frames: u64,
    /// Points in them.
    pub points: u64,
    /// Their frames' bytes, delimiters included.
    pub bytes: u64,
}

impl WireCost {
    /// Bytes a point, frame overhead included.
    pub fn bytes_per_point(&self) -> f64 {
        self.bytes as f64 / self.points.max(1) as f64
    }
}

/// The laser enables of the host's run of the head (nothing to drive).
struct NoLasers;

impl cms_core::pipeline::LaserDriver for NoLasers {
    fn set(&mut self, _mask: u8) {}
}

/// The wire cost of `frames` frames of the emulated head: its scene's rows
/// (`cms_core::synthetic`, seed 1, three lasers lit) through the host's run
/// of the same `Head` (the end-to-end test shows the emulated head sends
/// these profiles bit for bit), each profile encoded as the head encodes it.
/// Uncalibrated, as the emulated head is.
pub fn wire_cost(frames: u32) -> Result<WireCost, QemuError> {
    use cms_core::pipeline::{Head, Identity, default_detector};
    use cms_core::protocol::{Command as HeadCommand, DeviceMsg, HostMsg, LaserPattern, MAX_FRAME, Start, encode};
    use cms_core::synthetic::{Scene, SceneCamera, SceneConfig};
    let fail = |what: String| QemuError::Bench(what);
    let identity = Identity { firmware: "host", board: "host" };
    let mut head: Box<Head<752, NoLasers>> =
        Box::new(Head::new(NoLasers, default_detector(), identity).map_err(|e| fail(format!("detector: {e}")))?);
    let scene = Scene::new(SceneConfig::reference(1)).map_err(|e| fail(format!("scene: {e:?}")))?;
    let mut camera = SceneCamera::new(scene);
    let start = Start { rate_hz: 30, laser_mask: 0b111, pattern: LaserPattern::Simultaneous };
    let mut sink = |_: &DeviceMsg| {};
    head.handle(HeadCommand { seq: 1, msg: HostMsg::Start(start) }, 0, &camera, &mut sink);
    let mut out = vec![0u8; MAX_FRAME];
    let mut cost = WireCost::default();
    let mut failed = None;
    for i in 0..u64::from(frames) {
        let t = (i + 1) * 1_000_000 / u64::from(start.rate_hz);
        camera.travel_to(i as i64 * 2_000);
        head.handle(HeadCommand { seq: 2, msg: HostMsg::Heartbeat }, t, &camera, &mut sink);
        head.poll(t, &mut camera, &mut || 0, &mut |m| {
            if let DeviceMsg::Profile(p) = m {
                match encode(m, &mut out) {
                    Ok(f) => {
                        cost.frames += 1;
                        cost.points += p.lasers.iter().map(|l| l.points.len() as u64).sum::<u64>();
                        cost.bytes += f.len() as u64;
                    }
                    Err(e) => failed = Some(e),
                }
            }
        });
    }
    match failed {
        Some(e) => Err(fail(format!("encoding a profile: {e}"))),
        None => Ok(cost),
    }
}

/// The wire section of `cms-host bench qemu`.
pub fn wire_table(c: &WireCost) -> String {
    let per_frame = c.bytes as f64 / c.frames.max(1) as f64;
    let points = c.points as f64 / c.frames.max(1) as f64;
    format!(
        "\n# Wire (protocol {PROTOCOL_VERSION}): the emulated head's frames, {} frames of {points:.0} points, no calibration\n\n\
         | bytes/point | bytes/frame | at 60 frames/s |\n|---:|---:|---:|\n| {:.2} | {per_frame:.0} | {:.0} kB/s |\n",
        c.frames,
        c.bytes_per_point(),
        60.0 * per_frame / 1000.0
    )
}

/// The encoder's section of `cms-host bench qemu` (empty without it in the
/// report): instructions a frame and a row, and bytes a point.
pub fn encode_table(r: &BenchReport) -> String {
    let Some(e) = r.encode else { return String::new() };
    let points = 3 * e.rows;
    let line = |name: &str, (ins, bytes): (u64, u64)| {
        format!(
            "| {name} | {} | {} | {} | {:.2} |\n",
            group(ins),
            group((ins as f64 / e.rows as f64).round() as u64),
            group(bytes),
            bytes as f64 / points as f64
        )
    };
    format!(
        "\n# The link's encoder: one calibrated frame of {points} points ({} rows, three lasers, a metric point in each)\n\n\
         | protocol | instructions a frame | a row | bytes a frame | bytes/point |\n|---|---:|---:|---:|---:|\n{}{}",
        e.rows,
        line(&PROTOCOL_VERSION.to_string(), e.frame),
        line("4", e.v4_frame)
    )
}

/// `cms-host bench qemu`: the table on stdout.
pub fn bench(a: &BenchOptions) -> Result<String, QemuError> {
    let image = find_image(BENCH_BIN, a.image.as_deref())?;
    let out = run_bench_image(a.machine, &image)?;
    let report = parse_bench(&out)?;
    let (iters, ns) = report.calibration;
    if ns != 2 * iters {
        return Err(QemuError::Bench(format!(
            "the clock does not count instructions: {iters} iterations of 2 instructions took {ns} ns"
        )));
    }
    Ok(bench_table(&report, a.clock_mhz) + &encode_table(&report) + &wire_table(&wire_cost(10)?))
}
