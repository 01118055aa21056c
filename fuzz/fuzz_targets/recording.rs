//! The recording reader (`cms_host::recording::scan_reader`, `survey_from`)
//! on arbitrary bytes, and on a real recording damaged by the input.
//!
//! Each input is read twice:
//!
//! 1. as a recording itself: never a panic; an error is one line; the
//!    counts account for every message handed out;
//! 2. as edits (bit flips, overwritten, inserted and deleted bytes, a cut,
//!    a repeated span) to the reference recording
//!    `corpus/recording/sim-3-frames-survey.cmsrec` (made by the simulated
//!    head, with a survey block): the damaged file gives an error, or
//!    messages that are each one of the reference's, byte for byte — in
//!    the reference's order unless a span was repeated — and a survey that
//!    is the reference's or reported damaged (while the header still says
//!    format 3: a version byte damaged to 2 or 1 is read as that format,
//!    without the checksum, and is left to the message check).

#![no_main]

use std::path::Path;
use std::sync::OnceLock;

use cms_core::protocol::{DeviceMsg, MAX_FRAME, encode};
use cms_host::recording::{RecordError, ScanStats, parse_header, scan_reader, survey_from};
use libfuzzer_sys::fuzz_target;

const REFERENCE: &[u8] = include_bytes!("../corpus/recording/sim-3-frames-survey.cmsrec");

/// The reference's messages (as encoded) and survey text.
fn reference() -> &'static (Vec<Vec<u8>>, String) {
    static R: OnceLock<(Vec<Vec<u8>>, String)> = OnceLock::new();
    R.get_or_init(|| {
        let (stats, msgs) = read(REFERENCE).expect("the reference recording reads");
        assert_eq!((stats.damaged, stats.truncated_tail, stats.duplicates), (0, 0, 0));
        assert!(msgs.len() >= 4, "a Hello and three profiles");
        let survey = survey_from(Path::new("ref"), REFERENCE).expect("its survey").expect("a survey block");
        (msgs, survey)
    })
}

fn bytes_of(m: &DeviceMsg) -> Vec<u8> {
    let mut out = vec![0u8; MAX_FRAME];
    // Compared as encodings: a NaN in a message compares equal to itself.
    encode(m, &mut out).map(<[u8]>::to_vec).unwrap_or_else(|_| format!("{m:?}").into_bytes())
}

/// Reads `data` as a recording: its stats and the messages handed out.
fn read(data: &[u8]) -> Result<(ScanStats, Vec<Vec<u8>>), RecordError> {
    let mut msgs = Vec::new();
    let stats = scan_reader(Path::new("fuzz.cmsrec"), data, |m| {
        msgs.push(bytes_of(m));
        Ok(())
    })?;
    // Every decoded message is handed out once, duplicates aside.
    assert_eq!(stats.messages, msgs.len() as u64 + stats.duplicates, "{stats:?}");
    Ok((stats, msgs))
}

fn one_line(e: &RecordError) {
    let text = e.to_string();
    assert!(!text.contains('\n'), "{text:?}");
    assert!(matches!(e, RecordError::Format { .. }), "reading a slice fails only on its format: {e:?}");
}

/// `data` as edits to the reference; whether a span was repeated.
fn damaged(data: &[u8]) -> (Vec<u8>, bool) {
    let mut file = REFERENCE.to_vec();
    let mut repeated = false;
    for e in data.chunks_exact(4).take(16) {
        let at = usize::from(u16::from_le_bytes([e[1], e[2]]));
        let at = if file.is_empty() { 0 } else { at % (file.len() + 1) };
        let v = e[3];
        match e[0] % 6 {
            0 if at < file.len() => file[at] ^= 1 << (v % 8),
            1 if at < file.len() => file[at] = v,
            2 => file.insert(at, v),
            3 => {
                let end = (at + usize::from(v) + 1).min(file.len());
                file.drain(at..end);
            }
            4 => file.truncate(at),
            5 => {
                let end = (at + usize::from(v) * 64 + 1).min(file.len());
                let span = file[at..end].to_vec();
                let to = (at + usize::from(v) * 7) % (file.len() + 1);
                file.splice(to..to, span);
                repeated = true;
            }
            _ => {}
        }
    }
    (file, repeated)
}

/// Whether `got` is `all` with some left out, in order.
fn in_order(got: &[Vec<u8>], all: &[Vec<u8>]) -> bool {
    let mut rest = all.iter();
    got.iter().all(|g| rest.any(|a| a == g))
}

fuzz_target!(|data: &[u8]| {
    if let Err(e) = read(data) {
        one_line(&e);
    }
    if let Err(e) = survey_from(Path::new("fuzz.cmsrec"), data) {
        one_line(&e);
    }

    let (ref_msgs, ref_survey) = reference();
    let (file, repeated) = damaged(data);
    match read(&file) {
        Err(e) => one_line(&e),
        Ok((_, msgs)) => {
            for m in &msgs {
                assert!(ref_msgs.contains(m), "a message the reference does not hold");
            }
            assert!(repeated || in_order(&msgs, ref_msgs), "messages out of the reference's order");
        }
    }
    let format3 = file.len() >= 16 && parse_header(&file[..16]).is_ok_and(|h| h.format == 3);
    match survey_from(Path::new("fuzz.cmsrec"), file.as_slice()) {
        Err(e) => one_line(&e),
        Ok(s) if format3 => assert_eq!(s.as_ref(), Some(ref_survey), "a damaged survey taken as intact"),
        Ok(_) => {}
    }
});
