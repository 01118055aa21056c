//! `cms-host capture PORT --out frame.png`: one full frame from a sensor head
//! as the sensor sees it (for calibration and for diagnosing a site).
//!
//! The exchange: `GetInfo` → `Hello` (protocol and image size), optionally
//! `SetExposure`, then `CaptureImage(lasers)` → `Ack` and the frame as
//! `RawRows` chunks of the capture's sequence number, until every byte of
//! every row has arrived. The head lights the chosen lasers for that one
//! exposure only (and refuses while streaming: stop first).
//!
//! The PNG is 8-bit grey for an 8-bit sensor; deeper pixels are written as
//! 16-bit grey shifted left to fill 16 bits (`v << (16 − bits)`: exact and
//! reversible, and viewers show it at the right brightness).

use std::time::Duration;

use cms_core::protocol::{DeviceInfo, DeviceMsg, HostMsg, RawRows};

use crate::Error;
use crate::link::{Client, ClientError, Handshake, Wait};

/// Longest silence from the head before the capture is abandoned.
const SILENCE: Duration = Duration::from_secs(10);

/// What to capture, and how to reach the head.
#[derive(Debug, Clone)]
pub struct Options {
    /// Lasers lit during the exposure, as a bit mask.
    pub lasers: u8,
    /// Exposure, µs (`None`: the head's own).
    pub exposure_us: Option<u32>,
    /// Baud rate (ignored by USB CDC heads).
    pub baud: u32,
}

/// A captured frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Bits per pixel.
    pub bits: u8,
    /// Row-major pixels.
    pub pixels: Vec<u16>,
}

/// Writes the frame as PNG (see the module docs for the bit depth),
/// atomically and only as a regular file ([`crate::output`]).
pub fn save_png(frame: &Frame, path: &std::path::Path) -> Result<(), Error> {
    let png = encode_png(frame).map_err(|e| Error::Output(std::io::Error::other(e)))?;
    Ok(crate::output::write_atomically(path, |w| w.write_all(&png))?)
}

/// The frame as PNG bytes.
fn encode_png(frame: &Frame) -> Result<Vec<u8>, image::ImageError> {
    let mut png = std::io::Cursor::new(Vec::new());
    if frame.bits <= 8 {
        let data = frame.pixels.iter().map(|&p| p as u8).collect();
        let img = image::GrayImage::from_raw(frame.width, frame.height, data).expect("size checked when assembled");
        img.write_to(&mut png, image::ImageFormat::Png)?;
    } else {
        let shift = 16 - u32::from(frame.bits.min(16));
        let data = frame.pixels.iter().map(|&p| p << shift).collect();
        let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(frame.width, frame.height, data)
            .expect("size checked when assembled");
        img.write_to(&mut png, image::ImageFormat::Png)?;
    }
    Ok(png.into_inner())
}

/// One frame from the head on `port`: the conversation of the module docs.
pub fn capture(port: &str, args: &Options) -> Result<Frame, Error> {
    let mut client = Client::open(port, args.baud).map_err(ClientError::from)?;
    // Every wait is for the head's silence: the image comes in many frames
    // and may take longer in all than any fixed limit over a slow UART.
    let info = client.handshake(Handshake { tries: 1, wait: Wait::Silence(SILENCE) })?;
    if let Some(us) = args.exposure_us {
        client.request(HostMsg::SetExposure { exposure_us: us }, "SetExposure", Wait::Silence(SILENCE)).map_err(
            |e| match e {
                ClientError::Refused { code, .. } => Error::Input(format!("the head refused --exposure: {code}")),
                e => e.into(),
            },
        )?;
    }
    let seq = client.send(HostMsg::CaptureImage(args.lasers))?;
    // The Ack and the first chunks may come in one read: one loop takes
    // both (the Ack is implied by the data; a refusal is an Error).
    let mut asm = Assembly::new(&info);
    client.until("the image data", Wait::Silence(SILENCE), |m| match m {
        DeviceMsg::RawRows(r) if r.capture == seq => asm.add(&r).map(|done| done.then_some(())),
        DeviceMsg::Error { seq: Some(q), code } if q == seq => {
            Err(Error::Input(format!("{port}: the head refused the capture: {code}")))
        }
        _ => Ok(None),
    })?;
    Ok(asm.frame)
}

/// A frame being put together from chunks (which may come in any order).
struct Assembly {
    frame: Frame,
    bpp: usize,
    got: Vec<bool>,
    missing: usize,
}

impl Assembly {
    fn new(info: &DeviceInfo) -> Assembly {
        let (w, h) = (u32::from(info.sensor_width), u32::from(info.sensor_height));
        let bpp = if info.bits > 8 { 2 } else { 1 };
        let bytes = w as usize * h as usize * bpp;
        Assembly {
            frame: Frame { width: w, height: h, bits: info.bits, pixels: vec![0; w as usize * h as usize] },
            bpp,
            got: vec![false; bytes],
            missing: bytes,
        }
    }

    /// Takes one chunk; `Ok(true)` once every byte has arrived.
    fn add(&mut self, r: &RawRows) -> Result<bool, Error> {
        let f = &mut self.frame;
        if (u32::from(r.width), u32::from(r.height), r.bits) != (f.width, f.height, f.bits) {
            return Err(Error::Input(format!(
                "the head sent a {}×{} {}-bit chunk for a {}×{} {}-bit sensor",
                r.width, r.height, r.bits, f.width, f.height, f.bits
            )));
        }
        let row_bytes = f.width as usize * self.bpp;
        let start = r.first_row as usize * row_bytes + r.offset_bytes as usize;
        let end = start + r.data.len();
        if end > self.got.len() || !start.is_multiple_of(self.bpp) || !r.data.len().is_multiple_of(self.bpp) {
            return Err(Error::Input(format!(
                "the head sent a chunk outside the image (row {}, offset {}, {} bytes)",
                r.first_row,
                r.offset_bytes,
                r.data.len()
            )));
        }
        for (i, px) in r.data.chunks_exact(self.bpp).enumerate() {
            let k = start / self.bpp + i;
            f.pixels[k] = if self.bpp == 2 { u16::from_le_bytes([px[0], px[1]]) } else { u16::from(px[0]) };
        }
        for g in &mut self.got[start..end] {
            if !*g {
                *g = true;
                self.missing -= 1;
            }
        }
        Ok(self.missing == 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cms_core::pipeline::default_detector;
    use cms_core::protocol::PROTOCOL_VERSION;

    fn info(w: u16, h: u16, bits: u8) -> DeviceInfo {
        DeviceInfo {
            firmware: heapless::String::new(),
            protocol: PROTOCOL_VERSION,
            board: heapless::String::new(),
            sensor_width: w,
            sensor_height: h,
            bits,
            detector: default_detector(),
            calibration_id: 0,
            store: cms_core::protocol::StoreHealth::Volatile,
        }
    }

    fn chunk(first_row: u16, offset_bytes: u32, data: &[u8]) -> RawRows {
        RawRows {
            capture: 1,
            first_row,
            offset_bytes,
            width: 3,
            height: 2,
            bits: 12,
            data: heapless::Vec::from_slice(data).unwrap(),
        }
    }

    #[test]
    fn chunks_in_any_order_fill_the_frame_once() {
        let mut a = Assembly::new(&info(3, 2, 12));
        assert!(!a.add(&chunk(1, 0, &[1, 0, 2, 0, 3, 0])).unwrap());
        assert!(!a.add(&chunk(0, 2, &[5, 0, 6, 0])).unwrap());
        assert!(!a.add(&chunk(0, 2, &[5, 0, 6, 0])).unwrap(), "a repeat does not complete it");
        assert!(a.add(&chunk(0, 0, &[0xff, 0x0f])).unwrap());
        assert_eq!(a.frame.pixels, vec![4095, 5, 6, 1, 2, 3]);
        assert!(a.add(&chunk(1, 4, &[0, 0, 0, 0])).is_err(), "past the end");
        assert!(a.add(&chunk(0, 1, &[0, 0])).is_err(), "half a pixel");
    }
}
