//! Property tests of the input parser, in-process (many cases, no process
//! spawn): no content makes it panic, valid CSV round-trips, and a bad CSV
//! field is reported at its line and field.

use std::io::Cursor;

use cms_host::input::{CsvError, FieldError, Format, InputErrorKind, Pixels, parse};
use image::{ImageBuffer, ImageFormat, Luma};
use proptest::prelude::*;

fn config(cases: u32) -> ProptestConfig {
    ProptestConfig { cases, failure_persistence: None, ..ProptestConfig::default() }
}

/// Whatever the result, an `Ok` is a consistent grid.
fn check_consistent(bytes: &[u8], format: Format) {
    if let Ok(rows) = parse(bytes, format) {
        let n = rows.width() * rows.height();
        assert!(n > 0);
        match rows.pixels() {
            Pixels::U8(d) => assert_eq!(d.len(), n),
            Pixels::U16(d) => assert_eq!(d.len(), n),
        }
        assert!((8..=16).contains(&rows.bits()));
        assert_eq!(rows.rows().count(), rows.height());
    }
}

fn encoded(format: ImageFormat, sixteen: bool) -> Vec<u8> {
    let mut buf = Cursor::new(Vec::new());
    if sixteen {
        let img = ImageBuffer::<Luma<u16>, _>::from_fn(24, 6, |x, y| Luma([(x * 97 + y * 13) as u16 * 11]));
        img.write_to(&mut buf, format).unwrap();
    } else {
        let img = ImageBuffer::<Luma<u8>, _>::from_fn(24, 6, |x, y| Luma([(x * 7 + y * 3) as u8]));
        img.write_to(&mut buf, format).unwrap();
    }
    buf.into_inner()
}

#[test]
fn encoded_images_read_back() {
    for format in [ImageFormat::Png, ImageFormat::Tiff] {
        let f = if format == ImageFormat::Png { Format::Png } else { Format::Tiff };
        let r = parse(&encoded(format, false), f).unwrap();
        assert_eq!((r.width(), r.height(), r.bits()), (24, 6, 8));
        let r = parse(&encoded(format, true), f).unwrap();
        assert_eq!((r.width(), r.height(), r.bits()), (24, 6, 16));
        match r.pixels() {
            Pixels::U16(d) => assert_eq!(d[1], 97 * 11),
            other => panic!("{other:?}"),
        }
    }
}

/// Recomputes the CRC of every whole PNG chunk, so that a mutation reaches
/// the decoder's handling of the chunk's content instead of the CRC check.
fn fix_png_crcs(bytes: &mut [u8]) {
    let mut at = 8;
    while at + 12 <= bytes.len() {
        let len = u32::from_be_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]) as usize;
        let Some(end) = (at + 8).checked_add(len).filter(|&e| e + 4 <= bytes.len()) else { break };
        let crc = crc32(&bytes[at + 4..end]);
        bytes[end..end + 4].copy_from_slice(&crc.to_be_bytes());
        at = end + 4;
    }
}

fn crc32(data: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in data {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

#[test]
fn crc_matches_the_encoder() {
    let good = encoded(ImageFormat::Png, true);
    let mut fixed = good.clone();
    fix_png_crcs(&mut fixed);
    assert_eq!(good, fixed);
}

fn format_strategy() -> impl Strategy<Value = Format> {
    prop_oneof![Just(Format::Png), Just(Format::Tiff), Just(Format::Csv)]
}

/// A grid of values and how to write it.
fn grid(min_rows: usize) -> impl Strategy<Value = (Vec<Vec<u16>>, bool, bool, bool)> {
    (1usize..12, min_rows..8)
        .prop_flat_map(|(w, h)| {
            (
                proptest::collection::vec(proptest::collection::vec(any::<u16>(), w), h),
                any::<bool>(),
                any::<bool>(),
                any::<bool>(),
            )
        })
        .boxed()
}

fn write_csv(rows: &[Vec<u16>], crlf: bool, spaces: bool, trailing_blank: bool) -> String {
    let sep = if spaces { " , " } else { "," };
    let eol = if crlf { "\r\n" } else { "\n" };
    let mut s: String =
        rows.iter().map(|r| r.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(sep) + eol).collect();
    if trailing_blank {
        s.push_str(eol);
    }
    s
}

proptest! {
    #![proptest_config(config(2000))]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..2048), format in format_strategy()) {
        check_consistent(&bytes, format);
    }

    #[test]
    fn signature_prefixed_bytes_never_panic(tail in proptest::collection::vec(any::<u8>(), 0..512), which in 0usize..3) {
        let head: &[u8] = [&b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR"[..], b"II*\0\x08\0\0\0", b"MM\0*\0\0\0\x08"][which];
        let mut bytes = head.to_vec();
        bytes.extend_from_slice(&tail);
        check_consistent(&bytes, if which == 0 { Format::Png } else { Format::Tiff });
    }
}

proptest! {
    #![proptest_config(config(600))]

    #[test]
    fn mutated_images_never_panic(
        seed_image in 0usize..4,
        edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        cut in any::<prop::sample::Index>(),
        truncate in any::<bool>(),
    ) {
        let (format, f) = if seed_image < 2 { (ImageFormat::Png, Format::Png) } else { (ImageFormat::Tiff, Format::Tiff) };
        let mut bytes = encoded(format, seed_image % 2 == 1);
        for (at, v) in edits {
            let i = at.index(bytes.len());
            bytes[i] = v;
        }
        if truncate {
            bytes.truncate(cut.index(bytes.len()));
        }
        if f == Format::Png {
            fix_png_crcs(&mut bytes);
        }
        check_consistent(&bytes, f);
    }

    #[test]
    fn valid_csv_round_trips((rows, crlf, spaces, blank) in grid(1)) {
        let text = write_csv(&rows, crlf, spaces, blank);
        let r = parse(text.as_bytes(), Format::Csv).unwrap();
        prop_assert_eq!((r.width(), r.height()), (rows[0].len(), rows.len()));
        let flat: Vec<u16> = rows.concat();
        let max = *flat.iter().max().unwrap() as u32;
        prop_assert_eq!(r.pixels(), &Pixels::U16(flat));
        let bits = r.bits() as u32;
        prop_assert!(max < (1 << bits));
        prop_assert!(bits == 8 || max >= (1 << (bits - 2)));
    }

    #[test]
    fn bad_csv_field_is_located(
        (rows, crlf, spaces, blank) in grid(1),
        at in any::<(prop::sample::Index, prop::sample::Index)>(),
        bad in prop_oneof![
            Just(("".to_string(), FieldError::Empty)),
            (65536u64..u64::MAX).prop_map(|v| (v.to_string(), FieldError::OutOfRange)),
            (1i64..100000).prop_map(|v| ((-v).to_string(), FieldError::NotInteger)),
            "[a-zA-Z_.+-]{1,6}".prop_map(|s| (s, FieldError::NotInteger)),
            (0u16..1000, 1u16..1000).prop_map(|(a, b)| (format!("{a}.{b}"), FieldError::NotInteger)),
        ],
    ) {
        let line = at.0.index(rows.len());
        let field = at.1.index(rows[0].len());
        let mut text: Vec<Vec<String>> = rows.iter().map(|r| r.iter().map(|v| v.to_string()).collect()).collect();
        text[line][field] = bad.0.clone();
        let sep = if spaces { " , " } else { "," };
        let eol = if crlf { "\r\n" } else { "\n" };
        let mut s: String = text.iter().map(|r| r.join(sep) + eol).collect();
        if blank {
            s.push_str(eol);
        }
        // A lone empty field on a one-field row is a blank line, not an empty field.
        prop_assume!(!(bad.1 == FieldError::Empty && rows[0].len() == 1));
        match parse(s.as_bytes(), Format::Csv) {
            Err(InputErrorKind::Csv(CsvError::Field { line: l, field: f, text, reason })) => {
                prop_assert_eq!((l, f), (line + 1, field + 1));
                prop_assert_eq!(text, bad.0);
                prop_assert_eq!(reason, bad.1);
            }
            other => prop_assert!(false, "{:?}", other.map(|r| r.width())),
        }
    }

    #[test]
    fn ragged_csv_is_located(
        (rows, crlf, _s, _b) in grid(2),
        at in any::<prop::sample::Index>(),
        extra in any::<bool>(),
    ) {
        let line = 1 + at.index(rows.len() - 1);
        let mut rows = rows;
        let width = rows[0].len();
        if extra || width == 1 {
            rows[line].push(1);
        } else {
            rows[line].pop();
        }
        let text = write_csv(&rows, crlf, false, false);
        match parse(text.as_bytes(), Format::Csv) {
            Err(InputErrorKind::Csv(CsvError::Ragged { line: l, fields, expected })) => {
                prop_assert_eq!(l, line + 1);
                prop_assert_eq!(fields, rows[line].len());
                prop_assert_eq!(expected, width);
            }
            other => prop_assert!(false, "{:?}", other.map(|r| r.width())),
        }
    }
}
