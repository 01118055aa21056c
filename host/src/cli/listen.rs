//! `cms-host listen`: its arguments, Ctrl-C, the live status line and the
//! summary on stderr.

use std::io::{self, IsTerminal as _, Write as _};
use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use clap::{Args, ValueEnum};
use cms_core::peak::ColumnWindow;
use cms_core::peak::window::MIN_WINDOW_PX;
use cms_core::protocol::{LASERS, LaserPattern, Start};
use cms_core::readout::RowSkip;
use cms_host::analyze::live::bands::LiveOptions;
use cms_host::calib::file::CalibrationFile;
use cms_host::device::listen::LinkState;
use cms_host::device::listen::{self, ListenOptions, RowsRequest, StatusLine, Summary};
use cms_host::model::optics::Optics;
use cms_host::recording::survey_info::MAX_BYTES as MAX_SURVEY_BYTES;
use cms_host::serve::access::Token;
use cms_host::serve::{DEFAULT_ADDR, DISPLAY_HZ, Feed, LiveView, ServeOptions};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::exit::Usage;

/// `--pattern`.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum PatternArg {
    /// All lasers of the mask in every frame.
    Simultaneous,
    /// One laser per frame, in turn.
    Sequential,
}

/// Arguments of `cms-host listen`.
#[derive(Args, Debug, Clone)]
pub struct ListenArgs {
    /// The head's serial port: a device path such as /dev/ttyACM0 (or `sim`
    /// for the simulated head, `qemu` for the emulated one).
    #[arg(value_name = "PORT")]
    pub port: String,
    /// Stop after N complete frames.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub frames: Option<u64>,
    /// Stop after SECS seconds.
    #[arg(long, value_name = "SECS", value_parser = parse_secs)]
    pub duration: Option<Duration>,
    /// Record every frame into FILE (appends to an existing recording).
    /// Event marks typed on stdin, a terminal or a pipe, go into it, one a
    /// line: w (weld), j (joint), k LABEL (kilometre post), d (defect), n
    /// TEXT (note), each with optional text after it.
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    /// Print one JSON object per received profile on stdout.
    #[arg(long)]
    pub json: bool,
    /// Baud rate of a UART link (a USB head ignores it).
    #[arg(long, value_name = "B", default_value_t = 115_200, value_parser = clap::value_parser!(u32).range(1..))]
    pub baud: u32,
    /// Frames per second, 1..=1000.
    #[arg(long = "rate", value_name = "HZ", default_value_t = 30, value_parser = clap::value_parser!(u16).range(1..=1000))]
    pub rate_hz: u16,
    /// Lasers to light, a bit mask 1..=7 (decimal, 0b… or 0x…).
    #[arg(long, value_name = "MASK", default_value = "7", value_parser = parse_mask)]
    pub lasers: u8,
    /// How the lasers are lit.
    #[arg(long, value_enum, default_value_t = PatternArg::Simultaneous)]
    pub pattern: PatternArg,
    /// Exposure time to set before starting, µs (1..=1000000; the head
    /// also holds the lasers to a quarter of the time: exposure × rate at
    /// most 250 000 µs/s, and refuses more).
    #[arg(long = "exposure", value_name = "US", value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub exposure_us: Option<u32>,
    /// A search window for laser LASER: its stripes are sought in columns
    /// FIRST up to (not including) END only (`SetWindows` before `Start`;
    /// repeat for each laser, the last for a laser counts; a lit laser
    /// without one makes every row a full-row search).
    #[arg(long = "window", value_name = "LASER:FIRST-END", value_parser = parse_window)]
    pub windows: Vec<(usize, ColumnWindow)>,
    /// Search windows from a calibration file: each laser's columns
    /// between its `[head]` range_min_mm and range_max_mm, 16 px either side
    /// (a --window for a laser replaces its window).
    #[arg(long = "windows-from", value_name = "CAL")]
    pub windows_from: Option<PathBuf>,
    /// Make the search windows follow their lines: each row looks PX
    /// either side of where the row before found its window's stripe
    /// (2..=64), and screens the whole window where it finds none there
    /// (`SetTracking` before `Start`; with a --window or --windows-from for
    /// every lit laser). Cheaper rows where a line moves less than PX from
    /// row to row; a second line in a window is not sought while the track
    /// holds. 0: off.
    #[arg(long = "track", value_name = "PX", value_parser = parse_track)]
    pub track_px: Option<u16>,
    /// Read only sensor rows FIRST up to (not including) FIRST+COUNT
    /// (`SetReadout` before `Start`): a shorter stretch of rail a frame,
    /// more frames a second. Points keep their sensor rows.
    #[arg(long = "rows", value_name = "FIRST:COUNT", value_parser = parse_rows)]
    pub rows: Option<(u16, u16)>,
    /// Read one sensor row in N (1, 2 or 4; the MT9V034 bins N rows into
    /// one): N times the row pitch along the rail, about N times the
    /// frames a second. COUNT of --rows must be a multiple of N.
    #[arg(long = "row-skip", value_name = "N", value_parser = parse_row_skip)]
    pub row_skip: Option<u8>,
    /// What the recording is of: a TOML file of line, track, rail,
    /// start_chainage, chainage (up|down), operator, instrument, notes
    /// (docs/corrugation-and-standards.md), stored in a new recording's
    /// header; `analyze` places the run by it.
    #[arg(long, value_name = "FILE.toml", requires = "record")]
    pub survey: Option<PathBuf>,
    /// The lens's F-number and the lasers' wavelength this head records
    /// with (e.g. 2.8@685), stored in the recording's survey block
    /// (`[optics]`) for `analyze` to check the noise floor against; taken
    /// from --windows-from's `[head]` f_number and wavelength_nm when they
    /// are there, and with PORT `sim` from the simulated head's own light.
    #[arg(long, value_name = "F_NUMBER@WAVELENGTH_NM", value_parser = parse_optics, requires = "record")]
    pub optics: Option<Optics>,
    /// How long a lost port may stay away before giving up, seconds.
    #[arg(long, value_name = "SECS", default_value = "30", value_parser = parse_secs)]
    pub reconnect_timeout: Duration,
    /// Read a GNSS receiver's NMEA 0183 (GGA, RMC, VTG) from its own
    /// serial port GNSS_PORT, and record its fixes among the frames (`sim`
    /// with PORT `sim`: a simulated RTK receiver riding with the simulated
    /// head along examples/track-register.csv, from chainage 41+100).
    #[arg(long, value_name = "GNSS_PORT")]
    pub gnss: Option<String>,
    /// The EN 13231-3 edition whose limits the live band figures (status
    /// line, live view) are held against, as `analyze --edition`.
    #[arg(long, value_enum, default_value = "2006")]
    pub edition: super::analyze::EditionArg,
    /// Baud rate of the GNSS receiver's port (a USB receiver ignores it).
    #[arg(long, value_name = "B", default_value_t = 115_200, value_parser = clap::value_parser!(u32).range(1..), requires = "gnss")]
    pub gnss_baud: u32,
    /// Serve the live view, a read-only page for a browser, on ADDR
    /// (IP:PORT, or IP for port 8130; without ADDR 127.0.0.1:8130, this
    /// machine only; give an address to reach it from another). The
    /// recording goes on at full rate whatever the browser does.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8130", value_parser = parse_serve_addr)]
    pub serve: Option<SocketAddr>,
    /// The live view's secret (16 to 128 letters, digits, `-`, `_`, `.`,
    /// `~`): every request must carry it. Off loopback the view has one
    /// anyway (random, in the address printed); on loopback only if given.
    #[arg(long, value_name = "TOKEN", requires = "serve", value_parser = Token::given)]
    pub serve_token: Option<Token>,
    /// Serve the live view over HTTPS with the PEM certificate chain CERT
    /// and its private key KEY (the token then crosses the network
    /// encrypted; plain HTTP to the port is refused).
    #[arg(long, num_args = 2, value_names = ["CERT", "KEY"], requires = "serve")]
    pub serve_tls: Option<Vec<std::path::PathBuf>>,
}

/// `--serve ADDR`: `IP:PORT` or `IP` (port 8130).
fn parse_serve_addr(s: &str) -> Result<SocketAddr, String> {
    let t = s.trim();
    if let Ok(a) = t.parse::<SocketAddr>() {
        return Ok(a);
    }
    match t.trim_start_matches('[').trim_end_matches(']').parse::<IpAddr>() {
        Ok(ip) => Ok(SocketAddr::new(ip, DEFAULT_ADDR.port())),
        Err(_) => Err(format!("`{s}` is not an address to serve on (IP:PORT or IP, e.g. 127.0.0.1:8130 or 0.0.0.0)")),
    }
}

fn parse_secs(s: &str) -> Result<Duration, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("`{s}` is not a number of seconds"))?;
    if !(v.is_finite() && v > 0.0 && v <= 1e9) {
        return Err(format!("`{s}`: seconds must be positive and at most 1e9"));
    }
    Ok(Duration::from_secs_f64(v))
}

/// Margin of `--windows-from` either side of where a line can fall, px:
/// a stripe's half width (3σ, σ up to 4 px) and the camera model's error.
const WINDOW_MARGIN_PX: f64 = 16.0;

/// `--track PX`: 0 (off) or a half width the head takes.
fn parse_track(s: &str) -> Result<u16, String> {
    let range = cms_core::peak::window::TRACK_HALF_WIDTH_PX;
    match s.trim().parse::<u16>() {
        Ok(v) if v == 0 || range.contains(&v) => Ok(v),
        _ => Err(format!("`{s}`: a track is 0 (off) or {}..={} px either side", range.start(), range.end())),
    }
}

/// `FIRST:COUNT`, sensor rows FIRST..FIRST+COUNT.
fn parse_rows(s: &str) -> Result<(u16, u16), String> {
    let bad = || format!("`{s}`: a row window is FIRST:COUNT (sensor rows FIRST up to FIRST+COUNT, e.g. 120:240)");
    let (a, b) = s.trim().split_once(':').ok_or_else(bad)?;
    let (first, count): (u16, u16) = (a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?);
    if count == 0 {
        return Err(format!("`{s}`: a row window has at least one row"));
    }
    if u32::from(first) + u32::from(count) > u32::from(u16::MAX) {
        return Err(format!("`{s}`: a row window ends by row {}", u16::MAX));
    }
    Ok((first, count))
}

/// `--row-skip`: 1, 2 or 4.
fn parse_row_skip(s: &str) -> Result<u8, String> {
    match s.trim().parse::<u8>().map(RowSkip::new) {
        Ok(Ok(k)) => Ok(k.factor()),
        _ => Err(format!("`{s}`: the row skip is 1, 2 or 4 (read one sensor row in N)")),
    }
}

/// `LASER:FIRST-END`, columns FIRST..END of laser LASER.
fn parse_window(s: &str) -> Result<(usize, ColumnWindow), String> {
    let bad = || format!("`{s}`: a window is LASER:FIRST-END (columns FIRST up to END, e.g. 1:300-396)");
    let (k, range) = s.trim().split_once(':').ok_or_else(bad)?;
    let (a, b) = range.split_once('-').ok_or_else(bad)?;
    let k: usize = k.trim().parse().map_err(|_| bad())?;
    let (first, end): (u16, u16) = (a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?);
    if k >= LASERS {
        return Err(format!("`{s}`: no laser {k} (lasers 0..{LASERS})"));
    }
    match end.checked_sub(first) {
        Some(w) if w >= MIN_WINDOW_PX => Ok((k, ColumnWindow { first_px: first, width_px: w })),
        _ => Err(format!("`{s}`: a window ends at least {MIN_WINDOW_PX} px after its first column")),
    }
}

fn parse_mask(s: &str) -> Result<u8, String> {
    let t = s.trim();
    let v = if let Some(b) = t.strip_prefix("0b") {
        u8::from_str_radix(b, 2)
    } else if let Some(h) = t.strip_prefix("0x") {
        u8::from_str_radix(h, 16)
    } else {
        t.parse()
    };
    match v {
        Ok(m) if m != 0 && m < (1 << LASERS) => Ok(m),
        _ => Err(format!("`{s}`: a laser mask is 1..={} (bit k lights laser k)", (1 << LASERS) - 1)),
    }
}

impl ListenArgs {
    /// The options these arguments ask for.
    pub fn options(&self) -> ListenOptions {
        ListenOptions {
            frames: self.frames,
            duration: self.duration,
            record: self.record.clone(),
            survey: None,
            json: self.json,
            baud: self.baud,
            start: Start {
                rate_hz: self.rate_hz,
                laser_mask: self.lasers,
                pattern: match self.pattern {
                    PatternArg::Simultaneous => LaserPattern::Simultaneous,
                    PatternArg::Sequential => LaserPattern::Sequential,
                },
            },
            exposure_us: self.exposure_us,
            windows: (!self.windows.is_empty()).then(|| {
                let mut w = [None; LASERS];
                for &(k, cw) in &self.windows {
                    w[k] = Some(cw);
                }
                w
            }),
            readout: (self.rows.is_some() || self.row_skip.is_some()).then(|| RowsRequest {
                first_row: self.rows.map_or(0, |r| r.0),
                rows: self.rows.map(|r| r.1),
                skip: self.row_skip.unwrap_or(1),
            }),
            track_px: self.track_px,
            reconnect_timeout: self.reconnect_timeout,
            gnss: self.gnss.as_ref().map(|path| listen::GnssPort { path: path.clone(), baud: self.gnss_baud }),
            live_bands: LiveOptions { edition: self.edition.edition(), ..LiveOptions::default() },
        }
    }
}

/// The live status line on stderr: redrawn in place (an indicatif spinner
/// line) when stderr is a terminal and the JSON is not going to the same
/// terminal, otherwise a plain line a second.
struct Display {
    bar: Option<ProgressBar>,
    last: Instant,
    /// The live view's feed, and when it last had the link's state.
    view: Option<(Feed, Instant)>,
}

impl Display {
    fn new(json: bool, view: Option<Feed>) -> Display {
        let fancy = io::stderr().is_terminal() && !(json && io::stdout().is_terminal());
        let bar = fancy.then(|| {
            let b = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr_with_hz(4));
            if let Ok(style) = ProgressStyle::with_template("{spinner} {msg}") {
                b.set_style(style);
            }
            b
        });
        Display { bar, last: Instant::now(), view: view.map(|f| (f, Instant::now())) }
    }
}

impl StatusLine for Display {
    fn due(&self, now: Instant) -> bool {
        let every = if self.bar.is_some() { Duration::from_millis(250) } else { Duration::from_secs(1) };
        now.duration_since(self.last) >= every
    }

    fn show(&mut self, now: Instant, line: String) {
        self.last = now;
        match &self.bar {
            Some(b) => {
                b.set_message(line);
                b.tick();
            }
            None => {
                let _ = writeln!(io::stderr(), "{line}");
            }
        }
    }

    fn state_due(&self, now: Instant) -> bool {
        self.view.as_ref().is_some_and(|(_, last)| now.duration_since(*last).as_secs_f64() >= 1.0 / DISPLAY_HZ)
    }

    fn state(&mut self, now: Instant, state: &LinkState) {
        if let Some((feed, last)) = &mut self.view {
            feed.link(state);
            *last = now;
        }
    }

    fn finish(&mut self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

/// The flag Ctrl-C (and SIGTERM, SIGHUP) sets, installed on first use.
///
/// Every press only sets it: the listener's stop is bounded (`Stop`, at
/// most 500 ms for its `Ack`, the recording committed, the summary), so
/// there is nothing a second press needs to cut short, and exiting from
/// the handler would skip the summary and the last frames' commit (it
/// once did, 0–5 ms after the first press). Ctrl-\ (SIGQUIT) still ends
/// the process at once; even then the recording holds every frame
/// printed, since frames are written as they arrive.
pub fn interrupt_flag() -> &'static AtomicBool {
    static FLAG: AtomicBool = AtomicBool::new(false);
    static INSTALLED: OnceLock<()> = OnceLock::new();
    INSTALLED.get_or_init(|| {
        let _ = ctrlc::set_handler(|| FLAG.store(true, Ordering::SeqCst));
    });
    &FLAG
}

/// Longest line of marks read from stdin, bytes.
const MAX_MARK_LINE: u64 = 4096;
/// How long the terminal waits for the session to answer a mark.
const MARK_ANSWER: Duration = Duration::from_secs(5);

/// Whether stdin is a terminal or a pipe (or socket): where an operator
/// or a program types marks. A file or /dev/null is not read.
fn stdin_gives_lines() -> bool {
    use nix::sys::stat::{SFlag, fstat};
    if io::stdin().is_terminal() {
        return true;
    }
    fstat(io::stdin()).is_ok_and(|st| {
        let kind = SFlag::from_bits_truncate(st.st_mode) & SFlag::S_IFMT;
        kind == SFlag::S_IFIFO || kind == SFlag::S_IFSOCK
    })
}

/// Reads event marks from stdin, one a line ([`cms_host::recording::mark`]
/// has the syntax), on a thread of its own: the session only ever takes
/// what is queued, so a silent or closed stdin holds nothing. Each line is
/// answered on stderr, one line: the mark as recorded, or why not.
fn terminal_marks(marks: listen::MarkSender, bar: Option<ProgressBar>) {
    use cms_host::recording::mark::{MarkEntry, describe};
    use io::BufRead as _;
    let say = move |line: String| match &bar {
        Some(b) => b.println(line),
        None => {
            let _ = writeln!(io::stderr(), "{line}");
        }
    };
    let read = move || {
        let mut stdin = io::stdin().lock();
        let mut line = Vec::new();
        loop {
            line.clear();
            match io::Read::take(&mut stdin, MAX_MARK_LINE).read_until(b'\n', &mut line) {
                Ok(0) | Err(_) => return,
                Ok(_) => {}
            }
            if line.last() != Some(&b'\n') && line.len() as u64 >= MAX_MARK_LINE {
                // The rest of the line is dropped with it.
                let mut rest = Vec::new();
                let _ = stdin.read_until(b'\n', &mut rest);
                say(format!("listen: mark not recorded: a line of more than {MAX_MARK_LINE} bytes"));
                continue;
            }
            let entry = match std::str::from_utf8(&line).map(MarkEntry::parse_line) {
                Ok(Ok(Some(e))) => e,
                Ok(Ok(None)) => continue,
                Ok(Err(e)) => {
                    say(format!("listen: mark not recorded: {e}"));
                    continue;
                }
                Err(_) => {
                    say("listen: mark not recorded: the line is not UTF-8 text".to_string());
                    continue;
                }
            };
            let (tx, rx) = std::sync::mpsc::sync_channel(1);
            marks.send(
                entry,
                Box::new(move |r| {
                    let _ = tx.try_send(r);
                }),
            );
            match rx.recv_timeout(MARK_ANSWER) {
                Ok(Ok(m)) => say(format!("listen: mark: {}", describe(&m))),
                Ok(Err(e)) => say(format!("listen: mark not recorded: {e}")),
                Err(_) => say(format!(
                    "listen: mark not confirmed: the listener did not answer within {} s",
                    MARK_ANSWER.as_secs()
                )),
            }
        }
    };
    // Without the thread there are no terminal marks; the listening goes on.
    let _ = std::thread::Builder::new().name("cms-marks-stdin".into()).spawn(read);
}

/// Prints the summary on stderr, one `listen:` block.
pub fn print_summary(sum: &Summary) {
    let mut err = io::stderr().lock();
    for line in sum.to_string().lines() {
        let _ = writeln!(err, "listen: {line}");
    }
}

fn parse_optics(s: &str) -> Result<Optics, String> {
    s.parse().map_err(|e: cms_host::model::optics::OpticsError| e.to_string())
}

/// The optics of two sources (each named), refused when they differ.
fn merge_optics(a: Option<(Optics, String)>, b: Option<(Optics, String)>) -> Result<Option<(Optics, String)>, Usage> {
    match (a, b) {
        (Some((x, from_x)), Some((y, from_y))) if x != y => {
            Err(Usage(format!("{from_x} says the optics are {x}, {from_y} says {y}: give one")))
        }
        (a, b) => Ok(a.or(b)),
    }
}

/// The survey block a new recording carries: the survey given, with the
/// optics (refused when the survey file names others).
fn with_optics(survey: Option<String>, optics: Option<(Optics, String)>) -> Result<Option<String>, Usage> {
    let Some((o, from)) = optics else { return Ok(survey) };
    let mut sv = match &survey {
        Some(t) => cms_host::recording::survey_info::Survey::parse(t).map_err(|e| Usage(e.to_string()))?,
        None => cms_host::recording::survey_info::Survey::default(),
    };
    if let Some(theirs) = sv.optics.filter(|t| *t != o) {
        return Err(Usage(format!("--survey's [optics] are {theirs}, {from} says {o}: give one")));
    }
    sv.optics = Some(o);
    Ok(Some(sv.to_text()))
}

/// `cms-host listen` on a device path; `tls`: `--serve-tls`, loaded.
pub fn run(args: &ListenArgs, tls: Option<cms_host::serve::tls::Tls>) -> anyhow::Result<()> {
    if args.port == "sim" {
        anyhow::bail!(Usage(
            "`listen sim` needs the simulated head, which this build does not have; give a device path".to_string(),
        ));
    }
    if args.gnss.as_deref() == Some("sim") {
        anyhow::bail!(Usage("--gnss sim rides with the simulated head: give PORT `sim`".to_string()));
    }
    let mut opts = args.options();
    let mut placement = None;
    if let Some(path) = &args.survey {
        let name = path.display();
        // Read at most one byte past the limit: a device (`/dev/zero`) or a
        // huge file is refused by its size, not read without end.
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .and_then(|f| io::Read::read_to_end(&mut io::Read::take(f, MAX_SURVEY_BYTES as u64 + 1), &mut bytes))
            .map_err(|e| Usage(format!("cannot read {name}: {e}")))?;
        let text = String::from_utf8(bytes).map_err(|_| Usage(format!("{name}: not UTF-8 text")))?;
        let survey =
            cms_host::recording::survey_info::Survey::parse(&text).map_err(|e| Usage(format!("{name}: {e}")))?;
        placement = survey.placement().ok();
        opts.survey = Some(survey.to_text());
    }
    let mut optics = args.optics.map(|o| (o, "--optics".to_string()));
    if let Some(path) = &args.windows_from {
        let cal = CalibrationFile::load(path).map_err(cms_host::Error::from)?;
        let locked = cal
            .head
            .as_ref()
            .map(|h| h.optics())
            .transpose()
            .map_err(|e| Usage(format!("{}: head.{e}", path.display())))?
            .flatten();
        optics = merge_optics(optics, locked.map(|o| (o, path.display().to_string())))?;
        let mut w = cal.search_windows(WINDOW_MARGIN_PX).map_err(|e| Usage(format!("{}: {e}", path.display())))?;
        for &(k, cw) in &args.windows {
            w[k] = Some(cw);
        }
        let said: Vec<String> = (0..LASERS)
            .map(|k| match w[k] {
                Some(c) => format!("laser {k} {}–{} px", c.first_px, c.end_px()),
                None => format!("laser {k} full row"),
            })
            .collect();
        let _ = writeln!(io::stderr(), "listen: search windows from {}: {}", path.display(), said.join(", "));
        opts.windows = Some(w);
    }
    if opts.record.is_some() {
        opts.survey = with_optics(opts.survey.take(), optics)?;
    }
    if opts.track_px.is_some_and(|px| px > 0) {
        let Some(w) = &opts.windows else {
            return Err(Usage("--track follows search windows: give --window or --windows-from too".to_string()).into());
        };
        if let Some((a, b)) = listen::overlapping_windows(w) {
            let span = |k: usize| w[k].map_or(String::new(), |c| format!("{}–{} px", c.first_px, c.end_px()));
            return Err(Usage(format!(
                "--track needs search windows that do not overlap: laser {a}'s ({}) and laser {b}'s ({}) do, and a track would take both lines' stripes for one (track without --track, or give narrower --window)",
                span(a),
                span(b)
            ))
            .into());
        }
    }
    let (marks, inbox) = listen::mark_channel();
    let view = match args.serve {
        Some(addr) => {
            let opts = ServeOptions {
                addr,
                port: args.port.clone(),
                placement,
                recording: opts.record.is_some(),
                marks: Some(marks.clone()),
                token: args.serve_token.clone(),
                live_bands: opts.live_bands,
                tls,
            };
            let v = LiveView::start(&opts).map_err(cms_host::Error::from)?;
            let _ = writeln!(io::stderr(), "listen: live view on {} (read-only but for event marks)", v.url());
            Some(v)
        }
        None => None,
    };
    let feed = view.as_ref().map(LiveView::feed);
    let mut display = Display::new(opts.json, feed.clone());
    if opts.record.is_some() && stdin_gives_lines() {
        terminal_marks(marks.clone(), display.bar.clone());
    }
    let stdout = io::stdout();
    let mut observe = |m: &cms_core::protocol::DeviceMsg| {
        if let Some(f) = &feed {
            f.message(m);
        }
    };
    let outcome = listen::session_with_marks(
        &args.port,
        &opts,
        interrupt_flag(),
        &mut stdout.lock(),
        &mut observe,
        &mut display,
        Some(&inbox),
    );
    // Marks asked for from here on are refused at once (the session is over).
    drop(inbox);
    let viewed = view.map(LiveView::stop);
    // A session that ends in a failure after greeting the head (the port
    // lost for good) still says what it got, before the error line.
    if outcome.result.is_ok() || outcome.greeted() {
        print_summary(&outcome.summary);
        if let Some(v) = viewed {
            let _ = writeln!(io::stderr(), "listen: live view: {v}");
        }
    }
    Ok(outcome.result?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_parse_and_refuse() {
        assert_eq!(parse_window("1:300-396"), Ok((1, ColumnWindow { first_px: 300, width_px: 96 })));
        assert_eq!(parse_window(" 0 : 0 - 8 "), Ok((0, ColumnWindow { first_px: 0, width_px: 8 })));
        for bad in ["3:0-96", "1:300-305", "1:396-300", "1:300", "x:1-99", "1:-5-90", "1:0-70000", ""] {
            assert!(parse_window(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn rows_and_row_skip_parse_and_refuse() {
        assert_eq!(parse_rows("120:240"), Ok((120, 240)));
        assert_eq!(parse_rows(" 0 : 480 "), Ok((0, 480)));
        for bad in ["120", "120:0", "-1:20", "a:b", "65535:2", ""] {
            assert!(parse_rows(bad).is_err(), "{bad}");
        }
        assert_eq!((parse_row_skip("1"), parse_row_skip("2"), parse_row_skip("4")), (Ok(1), Ok(2), Ok(4)));
        for bad in ["0", "3", "8", "x", "-2", ""] {
            assert!(parse_row_skip(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn optics_of_two_sources_agree_or_are_refused() {
        let o = |t: &str, from: &str| Some((parse_optics(t).unwrap(), from.to_string()));
        assert_eq!(merge_optics(o("2.8@685", "--optics"), None).unwrap(), o("2.8@685", "--optics"));
        assert_eq!(merge_optics(None, o("2.8@685", "cal.toml")).unwrap(), o("2.8@685", "cal.toml"));
        assert!(merge_optics(o("2.8@685", "--optics"), o("2.8@685", "cal.toml")).is_ok());
        let e = merge_optics(o("4@685", "--optics"), o("2.8@685", "cal.toml")).unwrap_err().0;
        assert!(e.contains("--optics says the optics are F/4, 685 nm, cal.toml says F/2.8, 685 nm"), "{e}");
        // The survey block: the survey given, with the optics after it.
        let text = with_optics(Some("line = \"LN 1\"\n".into()), o("2.8@685", "--optics")).unwrap().unwrap();
        assert_eq!(text, "line = \"LN 1\"\n\n[optics]\nf_number = 2.8\nwavelength_nm = 685.0\n");
        assert_eq!(with_optics(None, None).unwrap(), None);
        let theirs = with_optics(Some(text), o("4@685", "--optics")).unwrap_err().0;
        assert!(theirs.contains("[optics] are F/2.8, 685 nm"), "{theirs}");
    }
}
