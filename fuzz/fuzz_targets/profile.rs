//! The profile file reader (`analyze PROFILE.csv`:
//! `cms_host::analyze::profile::parse`) on arbitrary text, with the first
//! byte choosing `--dx-mm` (none, 0.5, 1 or 2 mm).
//!
//! Besides "never panics": a profile that parses has one stitched line per
//! height column, at least two data rows, samples on its grid that are gaps
//! (NaN) or heights within ±`MAX_HEIGHT_UM`, and the spacing asked for.
//!
//! Inputs whose header has more than four columns are skipped: a grid is
//! capped at `MAX_CELLS` samples per line, not in total, so many columns
//! over a long span allocate 160 MB each (see docs/fuzzing.md).

#![no_main]

use cms_host::analyze::profile::{MAX_HEIGHT_UM, parse};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&choice, rest)) = data.split_first() else { return };
    let Ok(text) = std::str::from_utf8(rest) else { return };
    let header = text.lines().find(|l| !l.trim().is_empty() && !l.trim_start().starts_with('#')).unwrap_or("");
    if header.split([',', ';', '\t', ' ']).count() > 4 {
        return;
    }
    let dx_mm = [None, Some(0.5), Some(1.0), Some(2.0)][usize::from(choice % 4)];
    let Ok((file, st)) = parse(text, dx_mm) else { return };
    assert_eq!(st.lasers.len(), file.columns.len());
    assert!(file.rows >= 2, "{file:?}");
    for l in &st.lasers {
        if let Some(dx) = dx_mm {
            assert_eq!(l.dx_mm, dx);
        }
        assert!(l.dx_mm > 0.0 && l.x0_mm.is_finite(), "{file:?}");
        let z = l.z.to_vec().expect("a parsed profile's samples");
        assert!(z.iter().all(|z| z.is_nan() || z.abs() <= MAX_HEIGHT_UM), "{file:?}");
        assert_eq!(l.points, z.iter().filter(|z| z.is_finite()).count());
    }
});
