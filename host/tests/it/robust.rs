//! Bad files and bad numbers: outputs only to regular files, inputs read
//! under a cap, and the messages of cases easy to get wrong (a wrong answer
//! or a confusing line). Each test runs the `cms-host` binary
//! as a user would and checks the one `error:` line and the exit status.

use crate::common::{one_line_error, run};
use std::os::unix::fs::FileTypeExt as _;
use std::path::{Path, PathBuf};

use cms_host::recording::Recorder;
use cms_host::sim::calibration::truth::truth;
use cms_host::sim::scene::{Scene, SimConfig};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The simulated reference head's true calibration, as a file in `dir`.
fn calibration(dir: &Path) -> PathBuf {
    let scene = Scene::new(SimConfig::reference()).unwrap();
    let cal = dir.join("cal.toml");
    std::fs::write(&cal, truth(&scene).to_toml()).unwrap();
    cal
}

/// A FIFO in `dir`.
fn fifo(dir: &Path) -> PathBuf {
    let p = dir.join("fifo.toml");
    nix::unistd::mkfifo(&p, nix::sys::stat::Mode::from_bits_truncate(0o600)).unwrap();
    p
}

// ------------------------------------------------------------------ outputs

/// `calibrate camera|lasers --out` on a device, a FIFO or a directory:
/// refused in one line naming the path (exit 2), the node left as it was.
/// (It once replaced /dev/full with a regular file and exited 0.)
#[test]
fn calibrate_refuses_to_write_over_what_is_not_a_regular_file() {
    let dir = tempfile::tempdir().unwrap();
    let cal = calibration(dir.path());
    let fifo = fifo(dir.path());
    let sub = dir.path().join("a-directory");
    std::fs::create_dir(&sub).unwrap();
    let image = dir.path().join("board-00.png");
    for (out, what) in [
        (Path::new("/dev/full"), "a character device"),
        (fifo.as_path(), "a FIFO (named pipe)"),
        (sub.as_path(), "a directory"),
    ] {
        let want = format!("{}: {what}, not a regular file; refusing to write over it", out.display());
        let camera = run(&["calibrate", "camera", "--board", "9x6", "--square-mm", "6", "--out", s(out), s(&image)]);
        let e = one_line_error(&camera);
        assert!(e.ends_with(&want), "{e}");
        let lasers = run(&["calibrate", "lasers", "--camera", s(&cal), "--out", s(out), "a", "b", "c", "d", "e", "f"]);
        let e = one_line_error(&lasers);
        assert!(e.ends_with(&want), "{e}");
    }
    // `-` is stdout, which carries calibrate's report: refused, not a file named `-`.
    let e = one_line_error(&run(&["calibrate", "camera", "--board", "9x6", "--square-mm", "6", "--out", "-", "x.png"]));
    assert_eq!(e, "error: -: this output cannot go to stdout; give a file name");
    assert!(std::fs::metadata("/dev/full").unwrap().file_type().is_char_device());
    assert!(std::fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
    assert!(sub.is_dir());
}

/// `export --out` is written whole: to a regular file, `-` for stdout,
/// never over a FIFO; a failed export leaves the old file.
#[test]
fn export_writes_whole_files_or_stdout() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("r.cmsrec");
    Recorder::open(&rec).unwrap().finish().unwrap();
    let out = dir.path().join("out.csv");
    let o = run(&["export", "--format", "csv", "--out", s(&out), s(&rec)]);
    assert!(o.status.success(), "{o:?}");
    let text = std::fs::read_to_string(&out).unwrap();
    assert!(text.starts_with("seq,part,"), "{text}");
    let o = run(&["export", "--format", "csv", "--out", "-", s(&rec)]);
    assert!(o.status.success(), "{o:?}");
    assert_eq!(String::from_utf8_lossy(&o.stdout), text);
    let fifo = fifo(dir.path());
    let e = one_line_error(&run(&["export", "--format", "csv", "--out", s(&fifo), s(&rec)]));
    assert!(e.contains("a FIFO (named pipe), not a regular file"), "{e}");
    // Nothing but the output is left in the directory (no temporary file).
    let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names.len(), 3, "{names:?}");
}

// ------------------------------------------------------------------ inputs

/// A calibration read from a device or a FIFO stops at the 1 MiB cap,
/// counted while reading (it once grew to 2 GB: the cap was checked
/// against the metadata length, 0 for a device).
#[test]
fn a_calibration_from_a_device_stops_at_the_cap() {
    let dir = tempfile::tempdir().unwrap();
    let image = dir.path().join("frame.png");
    let t = std::time::Instant::now();
    let e = one_line_error(&run(&["measure", "--calibration", "/dev/zero", s(&image)]));
    assert_eq!(e, "error: /dev/zero: more than 1 MiB; too big for this kind of input (a device or a wrong file?)");
    assert!(t.elapsed() < std::time::Duration::from_secs(10), "{:?}", t.elapsed());
    // A FIFO that a writer fills without end: the same.
    let fifo = fifo(dir.path());
    let writer = {
        let fifo = fifo.clone();
        std::thread::spawn(move || {
            use std::io::Write as _;
            let mut f = std::fs::OpenOptions::new().write(true).open(&fifo).unwrap();
            let block = [b'#'; 65536];
            // Until the reader has had enough and closed its end.
            while f.write_all(&block).is_ok() {}
        })
    };
    let e = one_line_error(&run(&["measure", "--calibration", s(&fifo), s(&image)]));
    writer.join().unwrap();
    assert!(e.contains("more than 1 MiB"), "{e}");
}

// ------------------------------------------------------------------ messages

/// `fit` of x near 1e300 refuses in one line instead of printing a
/// wavelength 5 times too long with a residual of 0.
#[test]
fn fit_refuses_a_profile_too_flat_for_its_length() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("far.csv");
    let mut text = String::from("x_mm,z_mm\n");
    for i in 0..400 {
        let x = 1e300 + 1e301 * i as f64 / 400.0;
        let z = 0.1 * (std::f64::consts::TAU * 5.0 * i as f64 / 400.0).sin();
        text += &format!("{x:e},{z}\n");
    }
    std::fs::write(&csv, text).unwrap();
    for model in ["rotated", "sine"] {
        let e = one_line_error(&run(&["fit", "--model", model, s(&csv)]));
        assert!(e.contains("far.csv: cannot fit a sine: z spans 2.000e-1 mm over"), "{e}");
        assert!(e.contains("less than 1e-12 of it: too flat to resolve in double precision"), "{e}");
    }
}

/// `detect --threshold 0.001` names the detector's step, 1/256 σ.
#[test]
fn detect_threshold_below_its_step_names_the_step() {
    let stripes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/stripes.png");
    let o = run(&["detect", "--threshold", "0.001", s(&stripes)]);
    assert_eq!(o.status.code(), Some(2));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("threshold 0.001 σ is below the detector's step of 1/256 σ (0.0039 σ)"), "{e}");
    let o = run(&["detect", "--threshold", "300", s(&stripes)]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("above the largest, 65535/256 σ (255.996 σ)"));
    // The smallest step itself is taken.
    let ok = run(&["detect", "--threshold", "0.00390625", s(&stripes)]);
    assert!(ok.status.success(), "{ok:?}");
}

/// A 12-bit TIFF, by hand (the encoders write 8 or 16 bits): 4 × 2 pixels,
/// one strip, uncompressed, little-endian.
fn tiff_12_bit() -> Vec<u8> {
    let entries: [(u16, u16, u32); 8] = [
        (256, 3, 4),  // ImageWidth
        (257, 3, 2),  // ImageLength
        (258, 3, 12), // BitsPerSample
        (259, 3, 1),  // Compression: none
        (262, 3, 1),  // Photometric: black is zero
        (273, 4, 0),  // StripOffsets (patched below)
        (278, 3, 2),  // RowsPerStrip
        (279, 4, 12), // StripByteCounts: 2 rows × 6 bytes
    ];
    let ifd_len = 2 + entries.len() * 12 + 4;
    let data_at = (8 + ifd_len) as u32;
    let mut b = b"II*\0".to_vec();
    b.extend_from_slice(&8u32.to_le_bytes());
    b.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    for (tag, ty, v) in entries {
        let v = if tag == 273 { data_at } else { v };
        b.extend_from_slice(&tag.to_le_bytes());
        b.extend_from_slice(&ty.to_le_bytes());
        b.extend_from_slice(&1u32.to_le_bytes());
        if ty == 3 {
            b.extend_from_slice(&(v as u16).to_le_bytes());
            b.extend_from_slice(&[0, 0]);
        } else {
            b.extend_from_slice(&v.to_le_bytes());
        }
    }
    b.extend_from_slice(&0u32.to_le_bytes());
    b.extend_from_slice(&[0x12; 12]);
    b
}

/// A 12-bit TIFF is described as packed 12-bit pixels, not "e.g. float".
#[test]
fn a_12_bit_tiff_is_not_called_float() {
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("twelve.tif");
    std::fs::write(&tif, tiff_12_bit()).unwrap();
    let e = one_line_error(&run(&["detect", s(&tif)]));
    assert!(
        e.contains(
            "twelve.tif: unsupported pixel format (12 bits per pixel, packed; save 12-bit pixels as a 16-bit image"
        ),
        "{e}"
    );
    assert!(!e.contains("float"), "{e}");
}

/// A bad calibration file is named once: not "X.toml: X.toml: …".
#[test]
fn a_bad_calibration_names_its_file_once() {
    let dir = tempfile::tempdir().unwrap();
    let cal = calibration(dir.path());
    let text = std::fs::read_to_string(&cal).unwrap();
    std::fs::write(&cal, text.replacen("version = 1", "version = 7", 1)).unwrap();
    let image = dir.path().join("frame.png");
    let name = cal.display().to_string();
    for o in
        [run(&["measure", "--calibration", s(&cal), s(&image)]), run(&["calibrate", "upload", s(&cal), "/nonexistent"])]
    {
        let e = one_line_error(&o);
        assert_eq!(e.matches(&name).count(), 1, "{e}");
        assert!(e.contains("version = 7 is not supported"), "{e}");
    }
}

/// A value that is finite in the file but not in the head's single
/// precision names its key, once (it was "calibration: calibration: a
/// parameter is not finite").
#[test]
fn a_value_too_big_for_the_head_names_its_key() {
    let dir = tempfile::tempdir().unwrap();
    let cal = calibration(dir.path());
    let text = std::fs::read_to_string(&cal).unwrap();
    let line = text.lines().find(|l| l.starts_with("k2 = ")).unwrap().to_string();
    std::fs::write(&cal, text.replacen(&line, "k2 = 1e300", 1)).unwrap();
    let image = dir.path().join("frame.png");
    let e = one_line_error(&run(&["measure", "--calibration", s(&cal), s(&image)]));
    assert!(e.contains("camera.k2 = 1e300"), "{e}");
    assert!(e.matches("calibration").count() <= 1, "{e}");
}

/// `measure` of a damaged or empty `.cmsrec` says what is wrong with the
/// recording, not "unknown file type `.cmsrec`".
#[test]
fn measure_of_a_bad_recording_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let cal = calibration(dir.path());
    let empty = dir.path().join("empty.cmsrec");
    std::fs::write(&empty, b"").unwrap();
    let damaged = dir.path().join("damaged.cmsrec");
    std::fs::write(&damaged, b"CMSREX\0\x01\x01\0\x03\0\0\0\0\0").unwrap();
    let short = dir.path().join("short.cmsrec");
    std::fs::write(&short, b"CMSREC").unwrap();
    for (f, why) in [
        (&empty, "not a CMS recording: 0 bytes, shorter than the 16-byte header"),
        (&damaged, "not a CMS recording: the file does not start with CMSREC"),
        (&short, "not a CMS recording: 6 bytes"),
    ] {
        let e = one_line_error(&run(&["measure", "--calibration", s(&cal), s(f)]));
        assert!(e.contains(why), "{e}");
        assert!(!e.contains("unknown file type"), "{e}");
        assert_eq!(e.matches(s(f)).count(), 1, "{e}");
    }
}

/// `analyze` says what it took an input for. Random bytes named `.cmsrec`,
/// or any name starting with `CMSREC`, are read as a recording, and the
/// error is a recording's; the same bytes under another name are read as
/// a profile CSV, and the error says so. One line, exit status 2.
#[test]
fn analyze_names_what_it_took_the_input_for() {
    let dir = tempfile::tempdir().unwrap();
    let mut rng = cms_study::Rng::new(0xbad_c5e);
    let noise: Vec<u8> = (0..4096).map(|_| rng.next_u64() as u8 | 0x80).collect();
    let write = |name: &str, bytes: &[u8]| {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    let as_rec = write("bad.cmsrec", &noise);
    let e = one_line_error(&run(&["analyze", s(&as_rec)]));
    assert!(e.contains("not a CMS recording: the file does not start with CMSREC"), "{e}");
    let started = write("started.dat", &[b"CMSREC\0\x01\x09\0".as_slice(), &noise].concat());
    let e = one_line_error(&run(&["analyze", s(&started)]));
    assert!(e.contains("recording format version 9"), "{e}");
    let as_csv = write("bad.bin", &noise);
    let e = one_line_error(&run(&["analyze", s(&as_csv)]));
    assert!(e.contains("bad.bin: read as a profile CSV") && !e.contains("recording format"), "{e}");
    let text = write("p.csv", b"x_mm,z_um\n0,1\nnot,numbers\n");
    let e = one_line_error(&run(&["analyze", s(&text)]));
    assert!(e.contains("p.csv: read as a profile CSV: "), "{e}");
}
