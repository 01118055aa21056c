//! `cms-host detect` as a user runs it: the shipped examples against their
//! ground truth, the options, and every kind of bad input (exit status 2, one
//! `error: ` line naming the file, never a panic).

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use image::{ImageBuffer, Luma, Rgb};

const HEADER: &str = "source,row,stripe,position_px,strength,width_px,flags";

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("host/ has a parent").to_path_buf()
}

/// `cms-host detect ARGS…` run from the workspace root.
fn detect<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cms-host"))
        .current_dir(workspace())
        .arg("detect")
        .args(args)
        .output()
        .expect("cms-host runs")
}

#[derive(Debug, Clone, PartialEq)]
struct Line {
    source: String,
    row: usize,
    stripe: usize,
    position: f64,
    strength: u32,
    width: f64,
    flags: String,
}

/// The CSV lines after the header (which must be there, once).
fn lines(out: &Output) -> Vec<Line> {
    let text = String::from_utf8(out.stdout.clone()).expect("UTF-8 output");
    let mut it = text.lines();
    assert_eq!(it.next(), Some(HEADER), "header; stderr: {}", String::from_utf8_lossy(&out.stderr));
    it.map(|l| {
        // The source may hold commas (quoted): split the six numeric fields off the right.
        let f: Vec<&str> = l.rsplitn(7, ',').collect();
        assert_eq!(f.len(), 7, "{l}");
        Line {
            source: f[6].to_string(),
            row: f[5].parse().expect("row"),
            stripe: f[4].parse().expect("stripe"),
            position: f[3].parse().expect("position"),
            strength: f[2].parse().expect("strength"),
            width: f[1].parse().expect("width"),
            flags: f[0].to_string(),
        }
    })
    .collect()
}

/// (row, stripe) → position from a `*.truth.csv` of the generator.
fn truth(name: &str) -> Vec<(usize, usize, f64)> {
    let text = std::fs::read_to_string(workspace().join("examples").join(name)).expect("truth file");
    let mut it = text.lines();
    assert!(it.next().expect("header").starts_with("row,stripe,position_px"));
    it.map(|l| {
        let f: Vec<&str> = l.split(',').collect();
        (f[0].parse().unwrap(), f[1].parse().unwrap(), f[2].parse().unwrap())
    })
    .collect()
}

/// Every truth stripe found once, in order, within `tol` px; returns the RMS error.
fn check_against_truth(found: &[Line], truth: &[(usize, usize, f64)], tol: f64) -> f64 {
    assert_eq!(found.len(), truth.len(), "one line per true stripe");
    let mut sq = 0.0;
    for (l, &(row, stripe, pos)) in found.iter().zip(truth) {
        assert_eq!((l.row, l.stripe), (row, stripe), "{l:?}");
        let e = l.position - pos;
        assert!(e.abs() < tol, "row {row} stripe {stripe}: {} vs truth {pos:.5} (error {e:+.4} px)", l.position);
        assert_eq!(l.flags, "", "{l:?}");
        sq += e * e;
    }
    (sq / found.len() as f64).sqrt()
}

fn assert_ok(out: &Output) {
    assert!(out.status.success(), "status {:?}, stderr: {}", out.status, String::from_utf8_lossy(&out.stderr));
}

/// Exit status 2, one `error: ` line on stderr containing every `needles`.
fn assert_error(out: &Output, needles: &[&str]) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_ne!(out.status.code(), Some(101), "panicked: {err}");
    assert_eq!(out.status.code(), Some(2), "stderr: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(err.lines().count(), 1, "one line: {err:?}");
    assert!(err.starts_with("error: "), "{err}");
    for n in needles {
        assert!(err.contains(n), "{err:?} lacks {n:?}");
    }
    err
}

#[test]
fn example_png_matches_truth() {
    let out = detect(&["examples/stripes.png"]);
    assert_ok(&out);
    assert!(out.stderr.is_empty(), "{}", String::from_utf8_lossy(&out.stderr));
    let found = lines(&out);
    assert!(found.iter().all(|l| l.source == "examples/stripes.png"));
    let t = truth("stripes.truth.csv");
    assert_eq!(t.len(), 64 * 3);
    let rms = check_against_truth(&found, &t, 0.1);
    eprintln!("examples/stripes.png: RMS {rms:.4} px over {} stripes", found.len());
    // Widths: the generator's σ are 2.2, 2.6 and 3.0 px.
    for l in &found {
        let sigma = [2.2, 2.6, 3.0][l.stripe];
        assert!((l.width - sigma).abs() < 0.3, "{l:?}");
    }
}

#[test]
fn example_csv_matches_truth() {
    let out = detect(&["examples/rows.csv"]);
    assert_ok(&out);
    let found = lines(&out);
    let rms = check_against_truth(&found, &truth("rows.truth.csv"), 0.1);
    eprintln!("examples/rows.csv: RMS {rms:.4} px");
}

#[test]
fn every_method_runs_on_the_example() {
    for m in
        ["cwt", "cwt-paper", "max", "cog", "cog-filtered", "gaussian", "parabolic", "blais-rioux", "linear", "fir-zero"]
    {
        let out = detect(&["--method", m, "examples/stripes.png"]);
        assert_ok(&out);
        let found = lines(&out);
        // Integer `max` is the coarsest: every method within a pixel of the truth.
        check_against_truth(&found, &truth("stripes.truth.csv"), 1.0);
    }
}

fn load_example() -> ImageBuffer<Luma<u16>, Vec<u16>> {
    image::open(workspace().join("examples/stripes.png")).expect("example decodes").into_luma16()
}

#[test]
fn columns_axis_on_transposed_image_gives_same_stripes() {
    let img = load_example();
    let (w, h) = img.dimensions();
    let t = ImageBuffer::<Luma<u16>, _>::from_fn(h, w, |x, y| *img.get_pixel(y, x));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("transposed.png");
    t.save(&path).unwrap();
    let by_rows = lines(&detect(&["examples/stripes.png"]));
    let by_cols = detect(&[OsArg::from("--axis"), "columns".into(), path.as_os_str().into()]);
    assert_ok(&by_cols);
    let by_cols = lines(&by_cols);
    assert_eq!(by_rows.len(), by_cols.len());
    for (a, b) in by_rows.iter().zip(&by_cols) {
        assert_eq!(Line { source: b.source.clone(), ..a.clone() }, *b);
    }
}

type OsArg = std::ffi::OsString;

#[test]
fn tiff_16_bit_gives_same_stripes_as_png() {
    let img = load_example();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stripes.tif");
    img.save(&path).unwrap();
    let png = lines(&detect(&["examples/stripes.png"]));
    let tif = detect(&[&path]);
    assert_ok(&tif);
    let tif = lines(&tif);
    assert_eq!(png.len(), tif.len());
    for (a, b) in png.iter().zip(&tif) {
        assert_eq!(Line { source: b.source.clone(), ..a.clone() }, *b);
    }
}

#[test]
fn eight_bit_png_default_bits_and_saturation() {
    // An 8-bit image: bits default to 8, so a stripe clipped at 255 is saturated.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sat8.png");
    let img = ImageBuffer::<Luma<u8>, _>::from_fn(200, 4, |x, _| {
        let d = x as f64 - 100.3;
        Luma([(10.0 + 400.0 * (-d * d / (2.0 * 2.5 * 2.5)).exp()).min(255.0) as u8])
    });
    img.save(&path).unwrap();
    let out = detect(&[&path]);
    assert_ok(&out);
    let found = lines(&out);
    assert_eq!(found.len(), 4);
    for l in &found {
        assert!(l.flags.split('|').any(|f| f == "saturated"), "{l:?}");
        assert!((l.position - 100.3).abs() < 0.2, "{l:?}");
    }
    // --bits 16: 255 is not the saturation level.
    let out = detect(&[OsArg::from("--bits"), "16".into(), path.as_os_str().into()]);
    assert!(lines(&out).iter().all(|l| !l.flags.contains("saturated")));
}

#[test]
fn stripes_and_select_options() {
    let all = lines(&detect(&["examples/stripes.png"]));
    let row0: Vec<f64> = all.iter().filter(|l| l.row == 0).map(|l| l.position).collect();
    assert_eq!(row0.len(), 3);

    // The brightest is the leftmost (1800 counts), then the middle (1100).
    let one = lines(&detect(&["--stripes", "1", "examples/stripes.png"]));
    assert_eq!(one.len(), 64);
    assert_eq!(one[0].position, row0[0]);
    let two = lines(&detect(&["--stripes", "2", "--select", "strongest", "examples/stripes.png"]));
    assert_eq!(two.iter().filter(|l| l.row == 0).map(|l| l.position).collect::<Vec<_>>(), row0[..2]);
    let last = lines(&detect(&["--stripes", "1", "--select", "last", "examples/stripes.png"]));
    assert_eq!(last[0].position, row0[2]);
    assert_eq!(last[0].stripe, 0);
    let first = lines(&detect(&["--stripes", "2", "--select", "first", "examples/stripes.png"]));
    assert_eq!(first.iter().filter(|l| l.row == 0).map(|l| l.position).collect::<Vec<_>>(), row0[..2]);
    let every = lines(&detect(&["--select", "all", "--stripes", "1", "examples/stripes.png"]));
    assert_eq!(every.len(), 192);
    // Rows without stripe print nothing: header only (and short rows are fine).
    let dir = tempfile::tempdir().unwrap();
    let flat = dir.path().join("flat.csv");
    std::fs::write(&flat, "5,5,5,5,5,5,5,5,5,5\n9,9,9,9,9,9,9,9,9,9\n").unwrap();
    let short = dir.path().join("short.csv");
    std::fs::write(&short, "1,200,1\n").unwrap();
    let none = detect(&[&flat, &short]);
    assert_ok(&none);
    assert!(lines(&none).is_empty());
    // Other valid spellings.
    assert_ok(&detect(&["--scales", "2:3.5", "--threshold", "4.5", "--bits", "12", "examples/stripes.png"]));
}

#[test]
fn several_inputs_one_header() {
    let out = detect(&["examples/rows.csv", "examples/stripes.png", "examples/rows.csv"]);
    assert_ok(&out);
    let text = String::from_utf8(out.stdout.clone()).unwrap();
    assert_eq!(text.matches("source,").count(), 1);
    let found = lines(&out);
    assert_eq!(found.len(), 12 + 192 + 12);
    assert_eq!(found[0].source, "examples/rows.csv");
    assert_eq!(found[12].source, "examples/stripes.png");
    assert_eq!(found[204].source, "examples/rows.csv");
}

#[test]
fn source_with_comma_is_quoted() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a,b.csv");
    std::fs::copy(workspace().join("examples/rows.csv"), &path).unwrap();
    let out = detect(&[&path]);
    assert_ok(&out);
    let found = lines(&out);
    assert_eq!(found.len(), 12);
    assert_eq!(found[0].source, format!("\"{}\"", path.display()));
}

#[test]
fn bits_below_the_data_warn_but_run() {
    let out = detect(&["--bits", "8", "examples/stripes.png"]);
    assert_ok(&out);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.starts_with("warning: examples/stripes.png: values up to"), "{err}");
}

/// A bad input file in `dir`, the extra options, and what the message must say.
struct Case {
    file: &'static str,
    content: Content,
    opts: &'static [&'static str],
    needles: &'static [&'static str],
}

enum Content {
    Bytes(Vec<u8>),
    Text(&'static str),
    Image(image::DynamicImage),
    Palette,
    GrayFloatTiff,
    Dir,
    Missing,
}

fn palette_png() -> Vec<u8> {
    let mut buf = Vec::new();
    let mut enc = png::Encoder::new(&mut buf, 8, 2);
    enc.set_color(png::ColorType::Indexed);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_palette(vec![0, 0, 0, 255, 255, 255]);
    let mut w = enc.write_header().unwrap();
    w.write_image_data(&[0, 1, 0, 1, 0, 1, 0, 1, 1, 0, 1, 0, 1, 0, 1, 0]).unwrap();
    w.finish().unwrap();
    buf
}

fn gray_float_tiff() -> Vec<u8> {
    let mut buf = std::io::Cursor::new(Vec::new());
    let mut enc = tiff::encoder::TiffEncoder::new(&mut buf).unwrap();
    let data: Vec<f32> = (0..64).map(|i| i as f32 / 64.0).collect();
    enc.write_image::<tiff::encoder::colortype::Gray32Float>(16, 4, &data).unwrap();
    buf.into_inner()
}

fn write_case(dir: &Path, c: &Case) -> PathBuf {
    let path = dir.join(c.file);
    match &c.content {
        Content::Bytes(b) => std::fs::write(&path, b).unwrap(),
        Content::Text(t) => std::fs::write(&path, t).unwrap(),
        Content::Image(img) => img.save(&path).unwrap(),
        Content::Palette => std::fs::write(&path, palette_png()).unwrap(),
        Content::GrayFloatTiff => std::fs::write(&path, gray_float_tiff()).unwrap(),
        Content::Dir => std::fs::create_dir(&path).unwrap(),
        Content::Missing => {}
    }
    path
}

fn bad_cases() -> Vec<Case> {
    use Content::*;
    use image::DynamicImage as D;
    let rgb = D::ImageRgb8(ImageBuffer::from_fn(32, 8, |x, _| Rgb([x as u8, 0, 0])));
    let rgba = D::ImageRgba8(ImageBuffer::from_pixel(32, 8, image::Rgba([1, 2, 3, 255])));
    let la = D::ImageLumaA8(ImageBuffer::from_pixel(32, 8, image::LumaA([1, 255])));
    let rgb16 = D::ImageRgb16(ImageBuffer::from_pixel(32, 8, Rgb([1000u16, 2, 3])));
    let rgbf = D::ImageRgb32F(ImageBuffer::from_pixel(32, 8, Rgb([0.5f32, 0.2, 0.1])));
    let mut truncated = std::fs::read(workspace().join("examples/stripes.png")).unwrap();
    truncated.truncate(5000);
    let long_row = format!("{}\n", vec!["7"; 8193].join(","));
    let tall = "1,2,3\n".repeat(8193);
    vec![
        Case { file: "rgb.png", content: Image(rgb.clone()), opts: &[], needles: &["rgb.png", "colour (RGB) 8-bit"] },
        Case { file: "rgba.png", content: Image(rgba), opts: &[], needles: &["rgba.png", "RGBA"] },
        Case { file: "grey-alpha.png", content: Image(la), opts: &[], needles: &["grey-alpha.png", "alpha"] },
        Case { file: "palette.png", content: Palette, opts: &[], needles: &["palette.png", "palette"] },
        Case { file: "rgb16.tif", content: Image(rgb16), opts: &[], needles: &["rgb16.tif", "colour"] },
        Case { file: "rgb.tiff", content: Image(rgb), opts: &[], needles: &["rgb.tiff", "colour"] },
        Case { file: "rgbf.tif", content: Image(rgbf), opts: &[], needles: &["rgbf.tif", "float"] },
        Case { file: "grayf.tif", content: GrayFloatTiff, opts: &[], needles: &["grayf.tif", "32 bits per pixel"] },
        Case { file: "empty.png", content: Bytes(vec![]), opts: &[], needles: &["empty.png", "empty file"] },
        Case { file: "empty.tif", content: Bytes(vec![]), opts: &[], needles: &["empty.tif", "empty file"] },
        Case { file: "empty.csv", content: Bytes(vec![]), opts: &[], needles: &["empty.csv", "empty file"] },
        Case { file: "blank.csv", content: Text("\n\n"), opts: &[], needles: &["blank.csv", "empty file"] },
        Case { file: "truncated.png", content: Bytes(truncated), opts: &[], needles: &["truncated.png", "PNG"] },
        Case { file: "garbage.tif", content: Text("not a tiff at all"), opts: &[], needles: &["garbage.tif", "TIFF"] },
        Case { file: "text.png", content: Text("1,2,3\n"), opts: &[], needles: &["text.png", "PNG"] },
        Case {
            file: "ragged.csv",
            content: Text("1,2,3\n4,5,6\n7,8\n"),
            opts: &[],
            needles: &["ragged.csv", "line 3", "2 fields, expected 3"],
        },
        Case {
            file: "float.csv",
            content: Text("1,2,3\n4,5.5,6\n"),
            opts: &[],
            needles: &["float.csv", "line 2", "field 2", "\"5.5\"", "not a non-negative integer"],
        },
        Case {
            file: "negative.csv",
            content: Text("1,2,3\n4,5,6\n7,8,-9\n"),
            opts: &[],
            needles: &["negative.csv", "line 3", "field 3", "\"-9\""],
        },
        Case {
            file: "big.csv",
            content: Text("1,65536,3\n"),
            opts: &[],
            needles: &["big.csv", "line 1", "field 2", "\"65536\"", "out of range"],
        },
        Case {
            file: "word.csv",
            content: Text("1,2\nhello,world\n"),
            opts: &[],
            needles: &["word.csv", "line 2", "field 1", "\"hello\""],
        },
        Case {
            file: "hole.csv",
            content: Text("1,,3\n"),
            opts: &[],
            needles: &["hole.csv", "line 1", "field 2", "empty field"],
        },
        Case {
            file: "gap.csv",
            content: Text("1,2\n\n3,4\n"),
            opts: &[],
            needles: &["gap.csv", "line 2", "blank line"],
        },
        Case {
            file: "binary.csv",
            content: Bytes(vec![b'1', b',', 0xff, 0xfe, b'\n']),
            opts: &[],
            needles: &["binary.csv", "line 1", "field 2"],
        },
        Case {
            file: "image.bmp",
            content: Text("BM"),
            opts: &[],
            needles: &["image.bmp", "unknown file type", ".bmp"],
        },
        Case { file: "noext", content: Text("1,2,3\n"), opts: &[], needles: &["noext", "no file extension"] },
        Case { file: "missing.png", content: Missing, opts: &[], needles: &["missing.png", "cannot read file"] },
        Case { file: "dir.csv", content: Dir, opts: &[], needles: &["dir.csv", "cannot read file"] },
        Case {
            file: "long.csv",
            content: Bytes(long_row.into_bytes()),
            opts: &[],
            needles: &["long.csv", "8193", "8192"],
        },
        Case {
            file: "tall.csv",
            content: Bytes(tall.into_bytes()),
            opts: &["--axis", "columns"],
            needles: &["tall.csv", "columns of 8193 px"],
        },
    ]
}

#[test]
fn bad_inputs_exit_2_with_one_line_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    for c in bad_cases() {
        let path = write_case(dir.path(), &c);
        let mut args: Vec<OsArg> = c.opts.iter().map(OsArg::from).collect();
        args.push(path.into());
        let out = detect(&args);
        assert_error(&out, c.needles);
        assert!(out.stdout.is_empty(), "{}: stdout {:?}", c.file, String::from_utf8_lossy(&out.stdout));
    }
}

#[test]
fn first_bad_input_stops_the_run_after_earlier_output() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "1,2\n3,x\n").unwrap();
    let out = detect(&[OsArg::from("examples/rows.csv"), bad.clone().into(), "examples/stripes.png".into()]);
    assert_error(&out, &["bad.csv", "line 2", "field 2", "\"x\""]);
    let found = lines(&out);
    assert_eq!(found.len(), 12, "rows.csv printed, stripes.png never reached");
    assert!(found.iter().all(|l| l.source == "examples/rows.csv"));
}

#[test]
fn bad_options_exit_2() {
    for opts in [
        &["--stripes", "0"][..],
        &["--stripes", "17"],
        &["--stripes", "three"],
        &["--scales", "4:1.5"],
        &["--scales", "2:2"],
        &["--scales", "0.5:4"],
        &["--scales", "2:30"],
        &["--scales", "abc"],
        &["--scales", "-1:4"],
        &["--method", "foo"],
        &["--bits", "7"],
        &["--bits", "17"],
        &["--threshold", "0"],
        &["--threshold", "-3"],
        &["--select", "best"],
        &["--axis", "diagonal"],
        &["--no-such-option"],
    ] {
        let mut args: Vec<&str> = opts.to_vec();
        args.push("examples/rows.csv");
        let out = detect(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{opts:?}: {err}");
        assert!(err.starts_with("error: "), "{opts:?}: {err}");
        assert!(out.stdout.is_empty(), "{opts:?}");
    }
    // No input at all.
    let out = detect::<&str>(&[]);
    assert_eq!(out.status.code(), Some(2));
    // The scale error is the detector's own text.
    let err = String::from_utf8_lossy(&detect(&["--scales", "0.5:4", "examples/rows.csv"]).stderr).into_owned();
    assert!(err.contains("smallest scale must be at least 1 px"), "{err}");
    let err = String::from_utf8_lossy(&detect(&["--scales", "4:1.5", "examples/rows.csv"]).stderr).into_owned();
    assert!(err.contains("s_min must be below s_max"), "{err}");
    let err = String::from_utf8_lossy(&detect(&["--stripes", "17", "examples/rows.csv"]).stderr).into_owned();
    assert!(err.contains("at most 16"), "{err}");
}

#[test]
fn help_lists_every_method() {
    let out = detect(&["--help"]);
    assert_ok(&out);
    let help = String::from_utf8_lossy(&out.stdout);
    for m in
        ["cwt", "cwt-paper", "max", "cog", "cog-filtered", "gaussian", "parabolic", "blais-rioux", "linear", "fir-zero"]
    {
        assert!(help.contains(m), "{m}");
    }
}

#[test]
fn closed_pipe_exits_quietly() {
    // ~40 copies of the example: far more output than a pipe buffers.
    let mut child = Command::new(env!("CARGO_BIN_EXE_cms-host"))
        .current_dir(workspace())
        .arg("detect")
        .args(std::iter::repeat_n("examples/stripes.png", 40))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut first).unwrap();
    assert_eq!(first.trim_end(), HEADER);
    // The reader is dropped here: the pipe is closed under the writer.
    let mut err = String::new();
    child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    let status = child.wait().unwrap();
    assert_ne!(status.code(), Some(101), "panicked: {err}");
    assert_eq!(status.code(), Some(0), "{err}");
    assert!(err.is_empty(), "{err}");
}

mod random_files {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        // Each case spawns a process: keep it modest (the parser itself is
        // fuzzed much harder in host/tests/it/input_props.rs, in-process).
        #![proptest_config(ProptestConfig { cases: 48, failure_persistence: None, ..ProptestConfig::default() })]
        #[test]
        fn random_bytes_exit_0_or_2(bytes in proptest::collection::vec(any::<u8>(), 0..600), ext in 0usize..3) {
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join(["r.png", "r.tif", "r.csv"][ext]);
            std::fs::write(&path, &bytes).unwrap();
            let out = detect(&[&path]);
            let code = out.status.code();
            prop_assert!(code == Some(0) || code == Some(2), "{code:?}: {}", String::from_utf8_lossy(&out.stderr));
            if code == Some(2) {
                let err = String::from_utf8_lossy(&out.stderr);
                prop_assert_eq!(err.lines().count(), 1);
                prop_assert!(err.starts_with("error: ") && err.contains("r."), "{}", err);
            }
        }
    }
}
