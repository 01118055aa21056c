//! A receiver's port as it is: NMEA sentences and, between them, the
//! binary frames of the receiver's own protocols, each cut out by its
//! own framing.
//!
//! A receiver with its binary protocol on sends both on one port. A
//! binary frame may hold any byte — a `$`, a line end — so lines cannot be
//! split at `\n` alone: a frame is recognised by its sync bytes where a
//! sentence could start, its length read from its header, and skipped
//! whole once its own checksum holds:
//!
//! | protocol | sync | length | checksum |
//! |---|---|---|---|
//! | u-blox UBX | `B5 62` | u16 LE at 4, payload only (+ 8) | 8-bit Fletcher over class..payload |
//! | RTCM 3 | `D3`, 6 zero bits | 10 bits after them (+ 6) | CRC-24Q over header and message |
//! | Septentrio SBF | `$@` | u16 LE at 6, the whole block | CRC-16-CCITT (XMODEM) from byte 4 |
//! | NovAtel OEM binary | `AA 44 12` | header length at 3 + u16 LE at 8 (+ 4) | NovAtel CRC-32 over header and message |
//!
//! A frame whose checksum fails was no frame (sync bytes by chance, or a
//! frame damaged on the way): its first byte is taken as stray and the
//! rest is read again, so a sentence inside is not lost. A sentence is
//! `$` to its line end in printable ASCII; a byte that cannot be in one
//! (a control byte, a byte above 0x7E, another `$`) ends it as damaged
//! and is read again as the start of what follows.

use std::collections::VecDeque;

use super::sentence::MAX_LINE_BYTES;

/// The largest frame buffered (a UBX frame's 65 535-byte payload and its 8 bytes).
const MAX_FRAME_BYTES: usize = 65_535 + 8;

const CRC24Q: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_24_LTE_A);
const CRC16_XMODEM: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_XMODEM);

/// A binary protocol sharing the receiver's port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Binary {
    /// u-blox UBX.
    Ubx,
    /// RTCM 3 (corrections, or a receiver's own observations).
    Rtcm3,
    /// Septentrio Binary Format.
    Sbf,
    /// NovAtel OEM binary (long header).
    NovAtel,
}

/// What the port delivered.
#[derive(Debug, PartialEq, Eq)]
pub enum Piece<'a> {
    /// A whole line from `$` to its line end (without it), to be parsed.
    Line(&'a str),
    /// The start of a sentence cut short (by a byte no sentence holds) or
    /// one longer than any receiver sends: damaged.
    Broken,
    /// A binary frame whose checksum holds.
    Frame(Binary),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    Idle,
    Line,
    /// Bytes of a line too long, dropped up to its end.
    Overlong,
    Frame(Binary),
}

/// Cuts a port's bytes into [`Piece`]s.
#[derive(Debug)]
pub struct Framer {
    state: State,
    buf: Vec<u8>,
    replay: VecDeque<u8>,
    /// Bytes that belonged to no sentence and no frame (line ends excepted).
    pub stray_bytes: u64,
}

impl Default for Framer {
    fn default() -> Framer {
        Framer::new()
    }
}

fn is_sync(b: u8) -> bool {
    matches!(b, b'$' | 0xB5 | 0xD3 | 0xAA)
}

/// The NovAtel CRC-32 (reflected 0x04C11DB7, initial value and final XOR 0),
/// as the OEM manuals give it.
pub fn novatel_crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    crc
}

/// UBX's 8-bit Fletcher checksum (CK_A, CK_B).
pub fn ubx_checksum(bytes: &[u8]) -> [u8; 2] {
    let (mut a, mut b) = (0u8, 0u8);
    for &x in bytes {
        a = a.wrapping_add(x);
        b = b.wrapping_add(a);
    }
    [a, b]
}

/// CRC-24Q of RTCM 3.
pub fn crc24q(bytes: &[u8]) -> u32 {
    CRC24Q.checksum(bytes)
}

/// SBF's CRC-16 (CCITT polynomial, initial value 0).
pub fn sbf_crc16(bytes: &[u8]) -> u16 {
    CRC16_XMODEM.checksum(bytes)
}

/// What a frame's bytes so far say: not this protocol, its whole length,
/// or that more header is needed.
enum Header {
    Not,
    Len(usize),
    More,
}

fn header(kind: Binary, f: &[u8]) -> Header {
    let u16_at = |i: usize| usize::from(u16::from_le_bytes([f[i], f[i + 1]]));
    match kind {
        Binary::Ubx if f.len() >= 2 && f[1] != 0x62 => Header::Not,
        Binary::Ubx if f.len() >= 6 => Header::Len(8 + u16_at(4)),
        Binary::Rtcm3 if f.len() >= 2 && f[1] & 0xFC != 0 => Header::Not,
        Binary::Rtcm3 if f.len() >= 3 => Header::Len(6 + (usize::from(f[1] & 3) << 8 | usize::from(f[2]))),
        Binary::Sbf if f.len() >= 8 => {
            let n = u16_at(6);
            if n < 8 || n % 4 != 0 { Header::Not } else { Header::Len(n) }
        }
        Binary::NovAtel if f.len() >= 3 && f[1..3] != [0x44, 0x12] => Header::Not,
        Binary::NovAtel if f.len() >= 10 => {
            let h = usize::from(f[3]);
            if h < 10 { Header::Not } else { Header::Len(h + u16_at(8) + 4) }
        }
        _ => Header::More,
    }
}

fn checksum_holds(kind: Binary, f: &[u8]) -> bool {
    let n = f.len();
    match kind {
        Binary::Ubx => ubx_checksum(&f[2..n - 2]) == [f[n - 2], f[n - 1]],
        Binary::Rtcm3 => crc24q(&f[..n - 3]).to_be_bytes()[1..] == f[n - 3..],
        Binary::Sbf => sbf_crc16(&f[4..]) == u16::from_le_bytes([f[2], f[3]]),
        Binary::NovAtel => novatel_crc32(&f[..n - 4]).to_le_bytes() == f[n - 4..],
    }
}

impl Framer {
    /// A framer at the start of a stream.
    pub fn new() -> Framer {
        Framer { state: State::Idle, buf: Vec::new(), replay: VecDeque::new(), stray_bytes: 0 }
    }

    /// Takes the port's next bytes, giving out each piece they complete.
    pub fn feed(&mut self, bytes: &[u8], out: &mut impl FnMut(Piece<'_>)) {
        for &b in bytes {
            self.step(b, out);
            while let Some(b) = self.replay.pop_front() {
                self.step(b, out);
            }
        }
    }

    /// A frame that was none: its first byte is stray, the rest read again.
    fn reject(&mut self) {
        self.stray_bytes += 1;
        for &b in self.buf[1..].iter().rev() {
            self.replay.push_front(b);
        }
        self.buf.clear();
        self.state = State::Idle;
    }

    fn step(&mut self, b: u8, out: &mut impl FnMut(Piece<'_>)) {
        match self.state {
            State::Idle => {
                self.buf.clear();
                self.state = match b {
                    b'$' => State::Line,
                    0xB5 => State::Frame(Binary::Ubx),
                    0xD3 => State::Frame(Binary::Rtcm3),
                    0xAA => State::Frame(Binary::NovAtel),
                    b'\r' | b'\n' => return,
                    _ => {
                        self.stray_bytes += 1;
                        return;
                    }
                };
                self.buf.push(b);
            }
            State::Line if b == b'@' && self.buf == b"$" => {
                self.buf.push(b);
                self.state = State::Frame(Binary::Sbf);
            }
            State::Line if b == b'\n' => {
                let line = std::str::from_utf8(&self.buf).expect("a line holds printable ASCII only");
                out(Piece::Line(line.trim_end_matches('\r')));
                self.state = State::Idle;
            }
            State::Line if (0x20..0x7F).contains(&b) && b != b'$' || b == b'\r' => {
                self.buf.push(b);
                if self.buf.len() > MAX_LINE_BYTES + 1 {
                    out(Piece::Broken);
                    self.state = State::Overlong;
                }
            }
            State::Line => {
                out(Piece::Broken);
                self.state = State::Idle;
                self.replay.push_front(b);
            }
            State::Overlong if b == b'\n' => self.state = State::Idle,
            State::Overlong if is_sync(b) => {
                self.state = State::Idle;
                self.replay.push_front(b);
            }
            State::Overlong => {}
            State::Frame(kind) => {
                self.buf.push(b);
                match header(kind, &self.buf) {
                    Header::Not => self.reject(),
                    Header::Len(n) if n > MAX_FRAME_BYTES => self.reject(),
                    Header::Len(n) if self.buf.len() == n => {
                        if checksum_holds(kind, &self.buf) {
                            out(Piece::Frame(kind));
                            self.buf.clear();
                            self.state = State::Idle;
                        } else {
                            self.reject();
                        }
                    }
                    Header::Len(_) | Header::More => {}
                }
            }
        }
    }
}

/// Frames as receivers send them, for tests and simulators: each with its
/// sync, length and checksum around `payload`.
pub mod frames {
    use super::*;

    /// A UBX frame of `class`/`id`.
    pub fn ubx(class: u8, id: u8, payload: &[u8]) -> Vec<u8> {
        let mut f = vec![0xB5, 0x62, class, id];
        f.extend_from_slice(&(payload.len() as u16).to_le_bytes());
        f.extend_from_slice(payload);
        let ck = ubx_checksum(&f[2..]);
        f.extend_from_slice(&ck);
        f
    }

    /// An RTCM 3 frame around a message (at most 1023 bytes).
    pub fn rtcm3(message: &[u8]) -> Vec<u8> {
        let n = message.len().min(1023);
        let mut f = vec![0xD3, (n >> 8) as u8, n as u8];
        f.extend_from_slice(&message[..n]);
        let crc = crc24q(&f).to_be_bytes();
        f.extend_from_slice(&crc[1..]);
        f
    }

    /// An SBF block of `id` around `body` (padded to a multiple of 4).
    pub fn sbf(id: u16, body: &[u8]) -> Vec<u8> {
        let mut f = vec![b'$', b'@', 0, 0];
        f.extend_from_slice(&id.to_le_bytes());
        let n = (8 + body.len()).div_ceil(4) * 4;
        f.extend_from_slice(&(n as u16).to_le_bytes());
        f.extend_from_slice(body);
        f.resize(n, 0);
        let crc = sbf_crc16(&f[4..]).to_le_bytes();
        f[2..4].copy_from_slice(&crc);
        f
    }

    /// A NovAtel OEM binary log of `id` (28-byte header) around `message`.
    pub fn novatel(id: u16, message: &[u8]) -> Vec<u8> {
        let mut f = vec![0xAA, 0x44, 0x12, 28];
        f.extend_from_slice(&id.to_le_bytes());
        f.extend_from_slice(&[0, 0x20]);
        f.extend_from_slice(&(message.len() as u16).to_le_bytes());
        f.resize(28, 0);
        f.extend_from_slice(message);
        let crc = novatel_crc32(&f).to_le_bytes();
        f.extend_from_slice(&crc);
        f
    }
}

#[cfg(test)]
mod tests {
    use super::frames::*;
    use super::*;

    fn pieces(bytes: &[u8], chunk: usize) -> (Vec<String>, Vec<Binary>, usize, u64) {
        let (mut lines, mut frames, mut broken) = (Vec::new(), Vec::new(), 0);
        let mut f = Framer::new();
        for c in bytes.chunks(chunk) {
            f.feed(c, &mut |p| match p {
                Piece::Line(l) => lines.push(l.to_string()),
                Piece::Frame(k) => frames.push(k),
                Piece::Broken => broken += 1,
            });
        }
        (lines, frames, broken, f.stray_bytes)
    }

    #[test]
    fn the_checksums_are_the_protocols() {
        // The check values of the CRC catalogue ("123456789").
        assert_eq!(crc24q(b"123456789"), 0xCDE703);
        assert_eq!(sbf_crc16(b"123456789"), 0x31C3);
        // NovAtel's CRC-32 is the reflected CRC-32 without its initial and
        // final inversion (the catalogue's CRC-32/JAMCRC starts from !0).
        // NovAtel's CRC-32: the reflected CRC-32 from 0, no final inversion.
        const NOVATEL: crc::Algorithm<u32> = crc::Algorithm {
            width: 32,
            poly: 0x04C1_1DB7,
            init: 0,
            refin: true,
            refout: true,
            xorout: 0,
            check: 0,
            residue: 0,
        };
        let data: Vec<u8> = (0..=255u8).cycle().take(1000).collect();
        assert_eq!(novatel_crc32(&data), crc::Crc::<u32>::new(&NOVATEL).checksum(&data));
        // UBX-ACK-ACK of CFG-PRT, as the u-blox interface description prints it.
        assert_eq!(ubx(0x05, 0x01, &[0x06, 0x00]), [0xB5, 0x62, 0x05, 0x01, 0x02, 0x00, 0x06, 0x00, 0x0E, 0x37]);
    }

    /// Frames holding `$`, line ends and sync bytes of the others are
    /// skipped whole, whatever pieces the port delivers them in.
    #[test]
    fn frames_holding_dollars_and_line_ends_are_skipped_whole() {
        let nasty = b"\r\n$GPGGA,1*00\r\n\xB5\x62\xD3\x00\xAA\x44\x12$@".repeat(3);
        let mut s = Vec::new();
        s.extend_from_slice(b"$GPGGA,a*00\r\n");
        s.extend(ubx(0x01, 0x07, &nasty));
        s.extend_from_slice(b"$GPRMC,b*00\r\n");
        s.extend(rtcm3(&nasty));
        s.extend(sbf(4007, &nasty));
        s.extend_from_slice(b"$PUBX,00,c*00\r\n");
        s.extend(novatel(42, &nasty));
        s.extend_from_slice(b"$GPVTG,d*00\r\n");
        for chunk in [1, 7, 64, 4096] {
            let (lines, frames, broken, stray) = pieces(&s, chunk);
            assert_eq!(lines, ["$GPGGA,a*00", "$GPRMC,b*00", "$PUBX,00,c*00", "$GPVTG,d*00"], "chunk {chunk}");
            assert_eq!(frames, [Binary::Ubx, Binary::Rtcm3, Binary::Sbf, Binary::NovAtel]);
            assert_eq!((broken, stray), (0, 0));
        }
    }

    /// A frame whose checksum fails is no frame: the sentences in and
    /// after it are still read.
    #[test]
    fn a_false_or_damaged_frame_gives_back_what_it_held() {
        let mut f = ubx(0x01, 0x07, b"$GPGGA,x*00\r\n");
        let n = f.len();
        f[n - 1] ^= 1;
        f.extend_from_slice(b"$GPRMC,y*00\r\n");
        // Its sync byte is stray, and what follows of its header and its
        // checksum, line ends aside (the length, 13, is a `\r`).
        let stray_bytes = 1 + f[1..6].iter().chain(&f[n - 2..n]).filter(|b| !matches!(b, b'\r' | b'\n')).count() as u64;
        let (lines, frames, broken, stray) = pieces(&f, 3);
        assert_eq!(lines, ["$GPGGA,x*00", "$GPRMC,y*00"]);
        assert!(frames.is_empty());
        assert_eq!((broken, stray), (0, stray_bytes));
        // An RTCM sync followed by a long length inside the sentences.
        let mut s = b"\xD3\x03\xFF".to_vec();
        // The sentences come out once the length it says has arrived.
        s.extend_from_slice(&b"$GPGGA,z*00\r\n".repeat(100));
        let (lines, _, _, stray) = pieces(&s, 5);
        assert_eq!((lines.len(), stray), (100, 3));
    }

    #[test]
    fn a_sentence_cut_short_is_broken_and_what_cut_it_is_read() {
        let mut s = b"$GPGGA,12".to_vec();
        s.extend(ubx(1, 2, b"ab"));
        s.extend_from_slice(b"$GPRMC,1$GPVTG,2*00\r\n");
        s.extend_from_slice(&[b'$'; 600]);
        s.extend_from_slice(b"GPGSV,4*00\r\n$");
        s.extend_from_slice(&[b'A'; 600]);
        s.extend_from_slice(b"\r\n$GPZDA,3*00\r\n");
        let (lines, frames, broken, stray) = pieces(&s, 11);
        assert_eq!(lines, ["$GPVTG,2*00", "$GPGSV,4*00", "$GPZDA,3*00"]);
        assert_eq!(frames, [Binary::Ubx]);
        // The cut GGA and RMC, 599 lone `$`s, the overlong line.
        assert_eq!((broken, stray), (2 + 599 + 1, 0));
    }
}
