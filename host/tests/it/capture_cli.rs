//! `cms-host capture PORT --out frame.png` against the simulated head: the
//! whole frame arrives, the chosen laser shows, and bad arguments are refused
//! in one line.

use crate::common::run;

/// The PNG as 16-bit grey, checking its depth against the head's.
fn load(path: &std::path::Path, bits: u8) -> image::ImageBuffer<image::Luma<u16>, Vec<u16>> {
    let img = image::open(path).unwrap();
    let want = if bits <= 8 { image::ColorType::L8 } else { image::ColorType::L16 };
    assert_eq!(img.color(), want);
    if bits > 8 {
        // Counts shifted to fill 16 bits.
        assert!(img.as_luma16().unwrap().pixels().all(|p| p.0[0] % (1 << (16 - bits)) == 0));
    }
    img.to_luma16()
}

#[test]
fn a_capture_from_the_simulated_head_shows_the_lit_laser_only() {
    let dir = tempfile::tempdir().unwrap();
    let dark = dir.path().join("dark.png");
    let lit = dir.path().join("lit.png");
    let mut bits = 0;
    for (path, lasers) in [(&dark, "0"), (&lit, "2")] {
        let o = run(&["capture", "sim", "--sim-light=incoherent", "--out", path.to_str().unwrap(), "--lasers", lasers]);
        assert!(o.status.success(), "{o:?}");
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(out.contains("752×480 px, "), "{out}");
        bits = out.split("px, ").nth(1).and_then(|r| r.split(' ').next()).unwrap().parse().unwrap();
    }
    let (dark, lit) = (load(&dark, bits), load(&lit, bits));
    assert_eq!(lit.dimensions(), (752, 480));
    // Per row, the brightest pixel of the lit frame stands well above the
    // dark frame's: laser 1's stripe crosses every row (the reference head's
    // stripes run along the columns).
    let mut rows_with_stripe = 0;
    for y in 0..480 {
        let row_max = |img: &image::ImageBuffer<image::Luma<u16>, Vec<u16>>| {
            (0..752).map(|x| img.get_pixel(x, y).0[0] as u32).max().unwrap()
        };
        if row_max(&lit) > 2 * row_max(&dark) + 16 * 50 {
            rows_with_stripe += 1;
        }
    }
    assert!(rows_with_stripe > 400, "{rows_with_stripe} of 480 rows show the stripe");
}

#[test]
fn bad_capture_arguments_are_refused_in_one_line() {
    let o = run(&["capture", "sim", "--out", "/tmp/x.jpg"]);
    assert_eq!(o.status.code(), Some(2));
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(e.lines().count(), 1, "{e}");
    assert!(e.contains("PNG"), "{e}");
    let o = run(&["capture", "sim", "--out", "/tmp/x.png", "--lasers", "9"]);
    assert_eq!(o.status.code(), Some(2), "{o:?}");
    // A port that cannot be opened is the device's failure, not a bad argument.
    let o = run(&["capture", "/nonexistent/ttyACM9", "--out", "/tmp/x.png"]);
    assert_eq!(o.status.code(), Some(3), "{o:?}");
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("/nonexistent/ttyACM9"), "{e}");
}
