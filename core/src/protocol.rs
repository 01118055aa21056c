//! The wire protocol between the sensor head and the host.
//!
//! # Framing
//! Every message travels as one frame:
//!
//! ```text
//! COBS( version:u8 ‖ postcard(message) ‖ crc32(version ‖ message):u32 LE ) ‖ 0x00
//! ```
//!
//! * **postcard** encodes the message (varints, enum variants as indices): the
//!   same Rust types on both ends, no schema drift. A `Profile` is the one
//!   message with a hand-written encoding, in row order with predicted and
//!   quantised values ([`compact`]: about 5.5 bytes a point with its metric
//!   point, against 19 in version 3).
//! * **One pass, one buffer**: [`encode`] runs postcard through its own CRC
//!   and COBS flavours into the output buffer (`CrcModifier<Cobs<Slice>>`):
//!   each byte is checksummed, stuffed and written where it ends up, so the
//!   head needs one [`MAX_FRAME`] buffer, not a scratch buffer besides.
//! * **CRC-32** (ISO-HDLC, the Ethernet/zlib polynomial) over version and
//!   payload catches what USB's own CRC cannot (buffer overruns, a replugged
//!   port mid-frame, a simulator bug).
//! * **COBS** removes every 0x00 from the frame, so 0x00 is an unambiguous
//!   delimiter: after garbage or a lost byte the reader resynchronises on the
//!   next 0x00 and loses at most the frame it was in.
//! * The **version byte** comes first and outside postcard, so a reader of
//!   another version says so instead of misreading the payload. The CRC
//!   (over the version too) is checked before it: a damaged frame is a CRC
//!   error whatever its first byte, and a version mismatch is reported only
//!   for a frame that arrived intact. (This fixes the framing — version
//!   first, CRC-32/ISO-HDLC last — for every future version.)
//! * **Versions read**: commands of [`PROTOCOL_VERSION`] only; device
//!   messages of version 4 and of version 3 ([`v3`]), into the same
//!   [`DeviceMsg`] (the trait [`FromFrame`] says which a type reads), so a
//!   recording of either version, or of both, reads the same.
//!
//! # Sizes
//! [`MAX_FRAME`] bounds any encoded frame (delimiter included); the firmware
//! and the host size their buffers from it, and a test encodes the largest
//! possible message of each kind against it. A host reading recordings
//! sizes its reader by [`MAX_READ_FRAME`] (version 3's frames were larger).

pub mod compact;
pub mod packed;
pub mod v3;
pub mod v4;

use crate::fixed::Px;
use crate::peak::{ColumnWindow, Config, Flags};
use heapless::{String, Vec};
use serde::{Deserialize, Serialize};

/// The protocol version this build speaks.
pub const PROTOCOL_VERSION: u8 = 5;
/// Rows carried by one `Profile` message (a taller sensor sends several parts).
pub const MAX_ROWS_PER_PROFILE: usize = 480;
/// Lasers of the head.
pub const LASERS: usize = 3;
/// Pixel bytes carried by one `RawRows` chunk.
pub const RAW_CHUNK_BYTES: usize = 1024;

/// Largest postcard encoding of any message (the test
/// `encoded_sizes_are_bounded` encodes the largest of each kind): a
/// `Profile` ([`packed`]) of 1 440 points, each in a record of its own with
/// the largest skip and every field escaped — the variant, 128 bytes of
/// header and end, 1 440 × 179 bits = 32 220 bytes.
pub const MAX_MESSAGE: usize =
    1 + packed::MAX_HEADER_BYTES + (LASERS * MAX_ROWS_PER_PROFILE * packed::MAX_RECORD_BITS).div_ceil(8);
/// Largest frame on the wire: version, message, CRC, COBS overhead
/// (1 byte in 254, plus 1) and the delimiter.
pub const MAX_FRAME: usize = frame_bound(MAX_MESSAGE);
/// Largest frame a host reader meets: recordings may hold version-3 and
/// version-4 frames.
pub const MAX_READ_FRAME: usize = max(v3::MAX_FRAME, max(v4::MAX_FRAME, MAX_FRAME));

const fn max(a: usize, b: usize) -> usize {
    if a > b { a } else { b }
}

/// The largest frame of a message of at most `message` bytes.
pub const fn frame_bound(message: usize) -> usize {
    let raw = 1 + message + 4;
    raw + raw / 254 + 2
}
/// Largest host → device frame (commands are small; the firmware's receive
/// buffer). Checked against the largest command in a test.
pub const MAX_COMMAND_FRAME: usize = 256;

/// CRC-32/ISO-HDLC.
pub const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

// ---------------------------------------------------------------- messages

/// What the head says about itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DeviceInfo {
    /// Firmware version (semver text).
    pub firmware: String<16>,
    /// Protocol version (same as the frame's).
    pub protocol: u8,
    /// Board name.
    pub board: String<24>,
    /// Sensor width, px.
    pub sensor_width: u16,
    /// Sensor height, px (rows per frame).
    pub sensor_height: u16,
    /// Bits per pixel.
    pub bits: u8,
    /// Detector configuration in force.
    pub detector: Config,
    /// Identifier of the loaded calibration, 0 if none.
    pub calibration_id: u32,
    /// What the head found in its flash at start-up.
    pub store: StoreHealth,
}

/// What a head found in its flash at start-up (see `persist`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreHealth {
    /// A valid record, both slots sound.
    Ok,
    /// Nothing stored (a new head): defaults, no calibration.
    Missing,
    /// A write had been interrupted; the previous record is in use.
    Recovered,
    /// No valid record: defaults, no calibration. Recalibrate.
    Corrupt,
    /// A valid record whose calibration the head refused: not used.
    Refused,
    /// This head keeps nothing across restarts (the simulated head).
    Volatile,
}

/// A triangulated point in the profile frame of its laser (see
/// `triangulation`): along the laser line, and height normal to the rail
/// surface. Heights are in nanometres because the corrugation the analysis
/// fits is tens of micrometres and its error budget is a micrometre: a 1 µm
/// step would add 0.29 µm RMS of rounding noise.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Metric {
    /// Position along the laser line, µm.
    pub along_um: i32,
    /// Height normal to the rail surface (positive towards the head), nm.
    pub height_nm: i32,
}

/// One detected stripe centre.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Point {
    /// Image row.
    pub row: u16,
    /// Sub-pixel position along the row.
    pub position: Px,
    /// Peak height above background, counts (saturates at 65535).
    pub strength: u16,
    /// Stripe σ.
    pub width: Px,
    /// Detector flags.
    pub flags: Flags,
    /// Triangulated point, once a calibration is loaded.
    pub metric: Option<Metric>,
}

/// The points of one laser in one profile message.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LaserPoints {
    /// Laser index, 0..LASERS.
    pub laser: u8,
    /// Points, ascending row.
    pub points: Vec<Point, MAX_ROWS_PER_PROFILE>,
}

/// One image's stripes (or a part of them, for sensors taller than
/// [`MAX_ROWS_PER_PROFILE`] rows). Its wire encoding is [`compact`]'s: a
/// laser's points must be in ascending rows, one a row (as the head makes
/// them), or encoding fails with [`WireError::Unencodable`].
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    /// Frame sequence number (wraps).
    pub seq: u32,
    /// This part, 0-based, and the number of parts of the frame.
    pub part: u8,
    /// Number of parts.
    pub parts: u8,
    /// Exposure start, µs since the head started.
    pub timestamp_us: u64,
    /// Odometer at exposure, µm.
    pub odometer_um: i64,
    /// Exposure, µs.
    pub exposure_us: u32,
    /// Lasers lit during the exposure (bit k = laser k).
    pub laser_mask: u8,
    /// Per lit laser, its points.
    pub lasers: Vec<LaserPoints, LASERS>,
}

impl Profile {
    /// No points, built at run time: [`Profile::EMPTY`] is a constant of
    /// the type's full size (about 40 KB, mostly the points' uninitialised
    /// buffers), and every use of it by value copies it from flash — the
    /// head's firmware carried it in `.rodata`. This writes the header and
    /// the empty list's length only.
    #[inline(never)]
    pub fn empty() -> Profile {
        Profile {
            seq: 0,
            part: 0,
            parts: 1,
            timestamp_us: 0,
            odometer_um: 0,
            exposure_us: 0,
            laser_mask: 0,
            lasers: Vec::new(),
        }
    }

    /// No points (a constant, for struct-update syntax on the host; the
    /// head uses [`Profile::empty`]).
    pub const EMPTY: Profile = Profile {
        seq: 0,
        part: 0,
        parts: 1,
        timestamp_us: 0,
        odometer_um: 0,
        exposure_us: 0,
        laser_mask: 0,
        lasers: Vec::new(),
    };
}

/// Head state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum HeadState {
    /// Lasers off, waiting for commands.
    Idle,
    /// Streaming profiles.
    Streaming,
    /// Stopped by a fault; lasers off until the host starts again.
    Fault,
}

/// Periodic health report.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Status {
    /// State.
    pub state: HeadState,
    /// Lasers in use (bit mask): strobed, each lit only during its
    /// frames' exposures. 0 when not streaming.
    pub lasers_on: u8,
    /// Frames sent since start.
    pub frames: u32,
    /// Frame rate, millihertz.
    pub frame_rate_millihz: u32,
    /// Rows processed per second.
    pub rows_per_s: u32,
    /// Frames dropped (processing or link too slow, trigger faster than
    /// the rate limit, or refused by the laser duty-cycle limit).
    pub dropped_frames: u32,
    /// Mean processing time per row, ns.
    pub ns_per_row: u32,
    /// Mean processing time per row in core clock cycles (DWT counter on
    /// the head; 0 where the clock is unknown, as on the simulated head).
    pub cycles_per_row: u32,
    /// Rows lost before processing since start (camera DMA overrun).
    pub dropped_rows: u32,
    /// Bytes waiting to go out on the link when the status was made.
    pub link_backlog_bytes: u32,
    /// Laser on-time over the last status window, per mille of the time.
    pub laser_duty_permille: u16,
    /// Time since the last heartbeat from the host, ms.
    pub heartbeat_age_ms: u32,
    /// The last fault, if any.
    pub fault: Option<ErrorCode>,
}

/// Why the head refused a command or stopped.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ErrorCode {
    /// A frame from the host failed its CRC.
    Crc,
    /// A frame from the host did not decode.
    Decode,
    /// A frame from the host had another protocol version.
    Version(u8),
    /// The detector configuration was invalid.
    InvalidConfig,
    /// The command needs the head idle (stop first).
    Busy,
    /// No heartbeat from the host for more than 1 s: lasers off.
    HeartbeatLost,
    /// The camera failed to deliver a frame.
    SensorFault,
    /// A parameter is out of range (exposure, rate, mask, duty cycle,
    /// a distance trigger without an encoder).
    OutOfRange,
    /// Calibration or settings could not be written to flash.
    Storage,
}

impl core::fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ErrorCode::Crc => f.write_str("frame CRC mismatch"),
            ErrorCode::Decode => f.write_str("frame did not decode"),
            ErrorCode::Version(v) => write!(f, "protocol version {v}, expected {PROTOCOL_VERSION}"),
            ErrorCode::InvalidConfig => f.write_str("invalid detector configuration"),
            ErrorCode::Busy => f.write_str("head is streaming; stop first"),
            ErrorCode::HeartbeatLost => f.write_str("host heartbeat lost; lasers off"),
            ErrorCode::SensorFault => f.write_str("camera fault; lasers off"),
            ErrorCode::OutOfRange => f.write_str("parameter out of range"),
            ErrorCode::Storage => f.write_str("flash write failed; settings not kept"),
        }
    }
}

/// A chunk of raw pixels for image capture (little-endian `u16` per pixel
/// for bit depths above 8, one byte otherwise).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RawRows {
    /// Capture identifier (the command's sequence number).
    pub capture: u16,
    /// First row in this chunk.
    pub first_row: u16,
    /// Byte offset within the first row where this chunk starts.
    pub offset_bytes: u32,
    /// Image width, px.
    pub width: u16,
    /// Image height, px.
    pub height: u16,
    /// Bits per pixel.
    pub bits: u8,
    /// Pixel bytes.
    pub data: Vec<u8, RAW_CHUNK_BYTES>,
}

/// Device → host.
///
/// `Profile` makes this enum about 46 KB; without an allocator it cannot be
/// boxed, so the head builds one message in place and lends it by reference.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum DeviceMsg {
    /// Sent on connection and in answer to `GetInfo`.
    Hello(DeviceInfo),
    /// Stripes of one image.
    Profile(Profile),
    /// Health, about once a second while streaming and after every state change.
    Status(Status),
    /// The command with this sequence number was carried out.
    Ack(u16),
    /// The command with this sequence number (if known) failed, or a fault.
    Error {
        /// Sequence number of the failed command, if the fault answers one.
        seq: Option<u16>,
        /// What went wrong.
        code: ErrorCode,
    },
    /// Image capture data.
    RawRows(RawRows),
}

/// How the lasers are lit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum LaserPattern {
    /// All lasers of the mask in every frame.
    Simultaneous,
    /// One laser per frame, in turn.
    Sequential,
}

/// Streaming parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Start {
    /// Frames per second (1..=1000).
    pub rate_hz: u16,
    /// Lasers to use (bit k = laser k, non-zero, < 1 << LASERS).
    pub laser_mask: u8,
    /// How they are lit.
    pub pattern: LaserPattern,
}

/// What starts a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Trigger {
    /// Every `1 / rate_hz` (the `Start` rate).
    Timed,
    /// Every `every_um` of travel on the odometer (how trolleys sample the
    /// rail), at most `rate_hz` frames per second (faster travel drops frames).
    Distance {
        /// Interval, µm (non-zero).
        every_um: u32,
    },
}

/// Calibration the head uses to triangulate (camera frame, mm; see
/// `cms-host calibrate`). The head validates and keeps it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// Identifier (non-zero), echoed in `DeviceInfo`.
    pub id: u32,
    /// fx, fy, cx, cy, skew (px).
    pub intrinsics: [f32; 5],
    /// k1, k2, p1, p2, k3.
    pub distortion: [f32; 5],
    /// Per laser: nx, ny, nz (unit), d (mm): n·X = d.
    pub planes: [[f32; 4]; LASERS],
    /// The rail-top reference plane heights are measured from: nx, ny, nz
    /// (unit, pointing from the rail towards the camera), d (mm): n·X = d.
    pub datum: [f32; 4],
}

/// Host → device command body.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum HostMsg {
    /// Start streaming (lasers on).
    Start(Start),
    /// Stop streaming (lasers off).
    Stop,
    /// Exposure time (postcard encodes a one-field struct variant as a
    /// newtype variant: version 3's wire bytes are the same).
    SetExposure {
        /// Exposure, µs.
        exposure_us: u32,
    },
    /// New detector configuration (validated by the head).
    SetDetector(Config),
    /// New calibration.
    SetCalibration(Calibration),
    /// Capture one full image with these lasers lit and send it as `RawRows`
    /// (a head that cannot hold a frame exposes once per band of rows and
    /// sends each band before the next; `Stop` cancels).
    CaptureImage(u8),
    /// Ask for `Hello`.
    GetInfo,
    /// The host is alive; without one for 1 s the head turns the lasers off.
    Heartbeat,
    /// How frames are triggered from the next `Start` on (kept in flash).
    SetTrigger(Trigger),
    /// Search windows per laser from the next `Start` on
    /// (`peak::window`): laser `k`'s stripes are sought only in
    /// `windows[k]`; a lit laser without one makes every row a full-row
    /// search. Refused (`OutOfRange`) if a window is narrower than
    /// `peak::window::MIN_WINDOW_PX` or ends past the sensor's row. Not
    /// kept in flash. Appended last, so every other command's bytes are
    /// those of earlier builds (which answer it with `Decode`).
    SetWindows([Option<ColumnWindow>; LASERS]),
    /// The sensor rows a frame reads from the next `Start` on
    /// (`readout`): rows `first_row .. first_row + rows`, one in `skip`
    /// (1, 2 or 4). Points keep their sensor row. Refused (`OutOfRange`)
    /// if `readout::Readout::from_factor` refuses it against the sensor's
    /// height, and (`Busy`) while streaming. Not kept in flash; image
    /// captures read every row whatever it says. Appended last, after
    /// `SetWindows`, so every other command's bytes are unchanged.
    SetReadout {
        /// First sensor row of the window.
        first_row: u16,
        /// Sensor rows of the window (a multiple of `skip`).
        rows: u16,
        /// Read one row in `skip`: 1, 2 or 4.
        skip: u8,
    },
    /// Search windows that follow their lines from the next `Start` on
    /// (`peak::window::Track`, `peak::Detector::detect_tracked`): a row
    /// looks `half_width_px` either side of where the row before found its
    /// window's stripe, and screens the window where it finds none there
    /// (and on a frame's first row). `0`: off, the default. It applies
    /// where every lit laser has a window (`SetWindows`). Refused
    /// (`OutOfRange`) outside `peak::window::TRACK_HALF_WIDTH_PX` (and not
    /// 0), and (`Busy`) while streaming. Not kept in flash. Appended last,
    /// after `SetReadout`, so every other command's bytes are unchanged.
    SetTracking {
        /// How far from the last row's stripe a row looks, px (0: off).
        half_width_px: u16,
    },
}

/// A command: a sequence number for the acknowledgement, and the body.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Command {
    /// Echoed in `Ack` / `Error`.
    pub seq: u16,
    /// What to do.
    pub msg: HostMsg,
}

// ---------------------------------------------------------------- framing

/// Why a frame could not be written or read.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WireError {
    /// The output buffer is too small for the frame.
    BufferTooSmall,
    /// The frame exceeded the reader's buffer (bytes discarded up to the next delimiter).
    Overflow,
    /// COBS decoding failed (a stray zero or truncated frame).
    Cobs,
    /// Shorter than version + CRC.
    TooShort,
    /// Another protocol version (of an intact frame: its CRC holds).
    Version(u8),
    /// CRC mismatch (whatever the version byte says).
    Crc,
    /// The payload is not a valid message.
    Decode,
    /// The message breaks a rule of its wire encoding (a profile whose
    /// laser has two points in one row, or points out of row order).
    Unencodable,
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            WireError::BufferTooSmall => f.write_str("frame does not fit the buffer"),
            WireError::Overflow => f.write_str("frame longer than the receive buffer"),
            WireError::Cobs => f.write_str("bad COBS framing"),
            WireError::TooShort => f.write_str("frame too short"),
            WireError::Version(v) => write!(f, "protocol version {v}, expected {PROTOCOL_VERSION}"),
            WireError::Crc => f.write_str("CRC mismatch"),
            WireError::Decode => f.write_str("payload does not decode"),
            WireError::Unencodable => f.write_str("message cannot be encoded (profile points out of row order)"),
        }
    }
}

impl core::error::Error for WireError {}

impl From<WireError> for ErrorCode {
    /// How the head reports a bad frame from the host.
    fn from(e: WireError) -> ErrorCode {
        match e {
            WireError::Crc => ErrorCode::Crc,
            WireError::Version(v) => ErrorCode::Version(v),
            _ => ErrorCode::Decode,
        }
    }
}

/// Encodes `msg` as one frame into `out`, in one pass (postcard through its
/// CRC and COBS flavours). Returns the frame (delimiter included).
pub fn encode<'a, T: Serialize + ?Sized>(msg: &T, out: &'a mut [u8]) -> Result<&'a [u8], WireError> {
    encode_version(PROTOCOL_VERSION, msg, out)
}

/// [`encode`] with another version byte (version 3's test frames).
fn encode_version<'a, T: Serialize + ?Sized>(version: u8, msg: &T, out: &'a mut [u8]) -> Result<&'a [u8], WireError> {
    use postcard::ser_flavors::{Cobs, Flavor, Slice, crc::CrcModifier};
    let cobs = Cobs::try_new(Slice::new(out)).map_err(|_| WireError::BufferTooSmall)?;
    let mut flavor = CrcModifier::new(cobs, CRC.digest());
    flavor.try_push(version).map_err(|_| WireError::BufferTooSmall)?;
    match postcard::serialize_with_flavor(msg, flavor) {
        Ok(frame) => Ok(frame),
        Err(postcard::Error::SerializeBufferFull) => Err(WireError::BufferTooSmall),
        Err(_) => Err(WireError::Unencodable),
    }
}

/// A message type that frames decode into, and the protocol versions it
/// reads.
pub trait FromFrame: Sized {
    /// Decodes the payload (after the version byte, before the CRC) of an
    /// intact frame of protocol `version`.
    fn from_payload(version: u8, payload: &[u8]) -> Result<Self, WireError>;
}

/// The whole payload as one postcard `T`.
fn exactly<'de, T: Deserialize<'de>>(payload: &'de [u8]) -> Result<T, WireError> {
    let (msg, rest) = postcard::take_from_bytes(payload).map_err(|_| WireError::Decode)?;
    if !rest.is_empty() {
        return Err(WireError::Decode);
    }
    Ok(msg)
}

impl FromFrame for Command {
    /// This version only: a host of another version is told so.
    fn from_payload(version: u8, payload: &[u8]) -> Result<Command, WireError> {
        if version != PROTOCOL_VERSION {
            return Err(WireError::Version(version));
        }
        exactly(payload)
    }
}

impl FromFrame for DeviceMsg {
    /// Versions 5, 4 ([`v4`]) and 3 ([`v3`]).
    fn from_payload(version: u8, payload: &[u8]) -> Result<DeviceMsg, WireError> {
        match version {
            PROTOCOL_VERSION => exactly(payload),
            v4::VERSION => exactly::<v4::Read>(payload).map(|r| r.0),
            v3::VERSION => exactly::<v3::Read>(payload).map(|r| r.0),
            v => Err(WireError::Version(v)),
        }
    }
}

/// Decodes one frame's bytes (COBS-encoded, without the delimiter), in place.
pub fn decode_frame<T: FromFrame>(frame: &mut [u8]) -> Result<T, WireError> {
    let n = cobs::decode_in_place(frame).map_err(|_| WireError::Cobs)?;
    if n < 5 {
        return Err(WireError::TooShort);
    }
    let raw = &frame[..n];
    // The CRC first: only a frame that arrived intact can say which version
    // its sender speaks. Checked the other way round, any garbage whose
    // first byte is not the version would read as a head of another version.
    let (body, crc) = raw.split_at(n - 4);
    if CRC.checksum(body) != u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]) {
        return Err(WireError::Crc);
    }
    T::from_payload(body[0], &body[1..])
}

/// Counters of a frame reader.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkStats {
    /// Frames decoded.
    pub frames: u32,
    /// Frames with a CRC mismatch.
    pub crc_errors: u32,
    /// Frames that failed COBS, length, version or payload decoding.
    pub decode_errors: u32,
    /// Frames longer than the buffer (discarded).
    pub overflows: u32,
    /// Bytes discarded while resynchronising.
    pub discarded_bytes: u32,
}

/// Splits a byte stream into frames on 0x00 and decodes them.
///
/// `N` bounds a frame (use [`MAX_FRAME`] for device messages,
/// [`MAX_COMMAND_FRAME`] for commands). A frame that overflows is discarded up
/// to the next delimiter; the reader never needs a reset.
pub struct FrameReader<const N: usize> {
    buf: [u8; N],
    len: usize,
    overflow: bool,
    stats: LinkStats,
}

impl<const N: usize> Default for FrameReader<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameReader<N> {
    /// An empty reader.
    pub const fn new() -> Self {
        FrameReader {
            buf: [0; N],
            len: 0,
            overflow: false,
            stats: LinkStats { frames: 0, crc_errors: 0, decode_errors: 0, overflows: 0, discarded_bytes: 0 },
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// Feeds `data`; calls `on_msg` with every complete frame's result, in order.
    pub fn feed<T, F>(&mut self, data: &[u8], mut on_msg: F)
    where
        T: FromFrame,
        F: FnMut(Result<T, WireError>),
    {
        for &b in data {
            if b != 0 {
                if self.len < N {
                    self.buf[self.len] = b;
                    self.len += 1;
                } else {
                    if !self.overflow {
                        self.overflow = true;
                        self.stats.discarded_bytes = self.stats.discarded_bytes.saturating_add(self.len as u32);
                    }
                    self.stats.discarded_bytes = self.stats.discarded_bytes.saturating_add(1);
                }
                continue;
            }
            // Delimiter.
            // Counters wrap: a head may run for months at 1000 frames/s.
            if self.overflow {
                self.stats.overflows = self.stats.overflows.wrapping_add(1);
                on_msg(Err(WireError::Overflow));
            } else if self.len > 0 {
                let r = decode_frame::<T>(&mut self.buf[..self.len]);
                match &r {
                    Ok(_) => self.stats.frames = self.stats.frames.wrapping_add(1),
                    Err(WireError::Crc) => self.stats.crc_errors = self.stats.crc_errors.wrapping_add(1),
                    Err(_) => {
                        self.stats.decode_errors = self.stats.decode_errors.wrapping_add(1);
                        self.stats.discarded_bytes = self.stats.discarded_bytes.saturating_add(self.len as u32);
                    }
                }
                on_msg(r);
            }
            self.len = 0;
            self.overflow = false;
        }
    }
}
