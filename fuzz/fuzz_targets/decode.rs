//! Arbitrary bytes into the frame readers of both directions:
//! `FrameReader::<MAX_READ_FRAME>` decoding `DeviceMsg` of protocol 5, 4 or 3
//! (what the host reads) and
//! `FrameReader::<MAX_COMMAND_FRAME>` decoding `Command` (what the head reads).
//!
//! Besides "never panics", it checks that the counters account for every
//! frame handed out, and that every message that decodes re-encodes to a
//! frame that decodes to a message with the same encoding (idempotent
//! round trip; compared as bytes, so NaNs in a calibration compare equal;
//! a version-3 or version-4 profile re-encodes as version 5's, quantised,
//! and the second encoding must equal the first).

#![no_main]

use cms_core::protocol::{
    Command, DeviceMsg, FrameReader, FromFrame, MAX_COMMAND_FRAME, MAX_FRAME, MAX_READ_FRAME, WireError, decode_frame,
    encode,
};
use libfuzzer_sys::fuzz_target;
use serde::Serialize;

fn round_trip<T: Serialize + FromFrame>(m: &T, out: &mut [u8]) {
    let f1 = match encode(m, out) {
        // A version-3 profile may hold what version 5 cannot say (a laser's
        // points out of row order); every version-4 or -5 message re-encodes.
        Err(WireError::Unencodable) => return,
        r => r.expect("a decoded message encodes").to_vec(),
    };
    let mut g = f1[..f1.len() - 1].to_vec();
    let m2: T = decode_frame(&mut g).expect("its own encoding decodes");
    let f2 = encode(&m2, out).expect("encodes again");
    assert_eq!(f1, f2);
}

fn check<T: Serialize + FromFrame, const N: usize>(data: &[u8], out: &mut [u8]) {
    let mut reader: Box<FrameReader<N>> = Box::new(FrameReader::new());
    let (mut calls, mut ok) = (0u32, 0u32);
    reader.feed(data, |r: Result<T, WireError>| {
        calls += 1;
        if let Ok(m) = r {
            ok += 1;
            round_trip(&m, out);
        }
    });
    let s = reader.stats();
    assert_eq!(s.frames, ok);
    assert_eq!(s.frames + s.crc_errors + s.decode_errors + s.overflows, calls);
}

fuzz_target!(|data: &[u8]| {
    let mut out = vec![0u8; MAX_FRAME];
    check::<DeviceMsg, MAX_READ_FRAME>(data, &mut out);
    check::<Command, MAX_COMMAND_FRAME>(data, &mut out);
});
