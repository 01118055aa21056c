//! `cms-host analyze PROFILE.csv`: a longitudinal rail profile from any
//! instrument (a trolley's export, a CMM-measured reference beam, another
//! program's output, our own `profile.csv`), put through the same standards
//! code as a recording.
//!
//! # Format
//!
//! Text, one sample per line, the first non-comment line a header naming
//! the columns:
//!
//! * `x_mm` or `x_m` — position along the rail (optional: without it the
//!   samples are `--dx-mm` apart from 0). Strictly increasing.
//! * every column whose name ends in `_um` (or `_um_N`) is one line's
//!   height in micrometres (`height_um`, `height_um_0,height_um_1,…`, our own
//!   export's `laser_0_um,…`); `_mm` columns other than `x_mm` are heights
//!   in mm.
//!
//! Separators: comma, semicolon, tab or spaces (the header's decides).
//! Lines starting with `#` and blank lines are skipped. An empty cell, `nan`
//! or `-` is a missing sample (a gap, never interpolated across).
//!
//! # Sampling
//!
//! The standards need a uniform grid. When the positions are uniform (every
//! step within 1 % of a whole multiple of the median step) and no other
//! spacing is asked for, the samples are used as they are, a step of `k`
//! spacings leaving `k − 1` missing samples. Otherwise (or with `--dx-mm`
//! different from the data's spacing) each grid point is interpolated
//! linearly between the two samples around it, when both are present and
//! at most two median steps apart; anything else is a gap. A grid point
//! within 10⁻⁶ of a step of a sample takes the sample as it is.
//!
//! Cost: the file is read once, `O(rows × columns)`.

use std::path::Path;

use super::stitch::{Direction, MAX_CELLS};
use super::stitch::{Stitched, Stitching};
use super::store::{FitLog, Samples};
use crate::Error;

/// What the file held and how it was gridded.
#[derive(Debug, Clone, PartialEq)]
pub struct ProfileFile {
    /// Data rows read.
    pub rows: usize,
    /// The height columns, in order.
    pub columns: Vec<String>,
    /// Median step of the positions, mm (the `--dx-mm` given without `x`).
    pub data_dx_mm: f64,
    /// Whether the samples were interpolated onto another grid.
    pub resampled: bool,
    /// Whether the file had a position column.
    pub has_x: bool,
}

/// Reads a profile file; `dx_mm` is the grid asked for (`None`: the data's
/// own spacing, which needs an `x` column).
pub fn read(path: &Path, dx_mm: Option<f64>) -> Result<(ProfileFile, Stitching), Error> {
    let name = path.display();
    let text = std::fs::read(path).map_err(|e| Error::Input(format!("cannot read {name}: {e}")))?;
    // Neither named .cmsrec nor starting with CMSREC, so taken for a
    // profile CSV: the error says so, as a recording's says it was one.
    let text = String::from_utf8(text).map_err(|_| {
        Error::Input(format!("{name}: read as a profile CSV (not a .cmsrec recording): not a text file"))
    })?;
    parse(&text, dx_mm).map_err(|e| Error::Input(format!("{name}: read as a profile CSV: {e}")))
}

/// Largest height a profile may hold, µm: 100 mm, beyond the range of any
/// profiler of a rail head — a larger value is a unit or a file gone wrong,
/// and would otherwise overflow the spectra into a meaningless verdict.
pub const MAX_HEIGHT_UM: f64 = 1e5;

fn split(line: &str, sep: Option<char>) -> Vec<&str> {
    match sep {
        Some(c) => line.split(c).map(str::trim).collect(),
        None => line.split_whitespace().collect(),
    }
}

/// What is wrong with a profile CSV: the line, column or rule, in words.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ProfileError {
    /// The text is not a profile this reader takes.
    #[error("{0}")]
    Format(String),
}

/// Parses a profile's text (see the module docs); errors say where.
pub fn parse(text: &str, dx_mm: Option<f64>) -> Result<(ProfileFile, Stitching), ProfileError> {
    parse_text(text, dx_mm).map_err(ProfileError::Format)
}

/// [`parse`], its errors as text.
fn parse_text(text: &str, dx_mm: Option<f64>) -> Result<(ProfileFile, Stitching), String> {
    // Spreadsheets write a byte-order mark before the header.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let Some((_, header)) = lines.next() else { return Err("no header line (and no data)".into()) };
    let sep = [',', ';', '\t'].into_iter().find(|c| header.contains(*c));
    let names: Vec<String> = split(header, sep).iter().map(|s| s.trim_matches('"').to_string()).collect();
    // (column, scale to mm) of the position; (column, scale to µm) of each height.
    let mut x_col: Option<(usize, f64)> = None;
    let mut heights: Vec<(usize, f64, String)> = Vec::new();
    for (i, n) in names.iter().enumerate() {
        let lower = n.to_ascii_lowercase();
        // `height_um_2`: the unit before a line number.
        let unit = match lower.rsplit_once('_') {
            Some((head, tail)) if !tail.is_empty() && tail.bytes().all(|b| b.is_ascii_digit()) => head,
            _ => lower.as_str(),
        };
        match lower.as_str() {
            "x_mm" | "x_m" => {
                if x_col.is_some() {
                    return Err(format!("two position columns (`{n}` and another)"));
                }
                x_col = Some((i, if lower == "x_m" { 1000.0 } else { 1.0 }));
            }
            _ if unit.ends_with("_um") => heights.push((i, 1.0, n.clone())),
            _ if unit.ends_with("_mm") => heights.push((i, 1000.0, n.clone())),
            _ => {
                return Err(format!(
                    "column `{n}` is neither a position (x_mm, x_m) nor a height (a name ending in _um or _mm)"
                ));
            }
        }
    }
    if heights.is_empty() {
        return Err("no height column (a name ending in _um, e.g. height_um)".into());
    }
    if x_col.is_none() && dx_mm.is_none() {
        return Err("no position column (x_mm or x_m): give the sample spacing with --dx-mm".into());
    }
    let mut xs: Vec<f64> = Vec::new();
    let mut zs: Vec<Vec<f64>> = vec![Vec::new(); heights.len()];
    for (ln, line) in lines {
        let cells = split(line, sep);
        if cells.len() != names.len() {
            return Err(format!("line {}: {} fields where the header has {}", ln + 1, cells.len(), names.len()));
        }
        let number = |i: usize, missing_ok: bool| -> Result<f64, String> {
            let c = cells[i].trim_matches('"');
            if missing_ok && (c.is_empty() || c == "-" || c.eq_ignore_ascii_case("nan")) {
                return Ok(f64::NAN);
            }
            match c.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => Err(format!("line {}, column `{}`: `{c}` is not a number", ln + 1, names[i])),
            }
        };
        let x = match x_col {
            Some((i, scale)) => number(i, false)? * scale,
            None => xs.len() as f64 * dx_mm.unwrap_or(1.0),
        };
        if let Some(&prev) = xs.last()
            && x <= prev
        {
            return Err(format!(
                "line {}: position {x} mm does not increase (the one before is {prev} mm); sort the file by position",
                ln + 1
            ));
        }
        xs.push(x);
        for (z, &(i, scale, _)) in zs.iter_mut().zip(&heights) {
            let h_um = number(i, true)? * scale;
            if h_um.abs() > MAX_HEIGHT_UM {
                return Err(format!(
                    "line {}, column `{}`: {h_um:e} µm is beyond any rail profile's ±{MAX_HEIGHT_UM:e} µm",
                    ln + 1,
                    names[i]
                ));
            }
            z.push(h_um);
        }
    }
    if xs.len() < 2 {
        return Err(format!("{} data rows: a profile needs at least 2", xs.len()));
    }
    let mut steps: Vec<f64> = xs.windows(2).map(|w| w[1] - w[0]).collect();
    steps.sort_by(f64::total_cmp);
    let data_dx = steps[steps.len() / 2];
    let dx = dx_mm.unwrap_or(data_dx);
    let span = xs[xs.len() - 1] - xs[0];
    if span / dx >= MAX_CELLS as f64 {
        return Err(format!("{span:.0} mm at {dx} mm spacing is more than {MAX_CELLS} samples"));
    }
    let uniform = xs.windows(2).all(|w| {
        let k = ((w[1] - w[0]) / data_dx).round();
        k >= 1.0 && ((w[1] - w[0]) - k * data_dx).abs() <= 0.01 * data_dx
    });
    let resampled = !(uniform && (dx - data_dx).abs() <= 1e-9 * data_dx);
    let x0 = xs[0];
    let n = (span / dx + 1e-6).floor() as usize + 1;
    let lasers = zs
        .iter()
        .enumerate()
        .map(|(k, z)| {
            let grid = if resampled { interpolate(&xs, z, x0, dx, n, 2.0 * data_dx) } else { place(&xs, z, x0, dx, n) };
            stitched(k, x0, dx, grid)
        })
        .collect();
    let info = ProfileFile {
        rows: xs.len(),
        columns: heights.into_iter().map(|h| h.2).collect(),
        data_dx_mm: data_dx,
        resampled,
        has_x: x_col.is_some(),
    };
    Ok((
        info,
        Stitching {
            direction: Direction::Forward,
            direction_residuals_um: None,
            direction_given: false,
            lasers,
            share: None,
        },
    ))
}

/// Uniform samples put on their grid points (a longer step leaves gaps).
fn place(xs: &[f64], z: &[f64], x0: f64, dx: f64, n: usize) -> Vec<f64> {
    let mut out = vec![f64::NAN; n];
    for (&x, &v) in xs.iter().zip(z) {
        let i = ((x - x0) / dx).round() as usize;
        if let Some(o) = out.get_mut(i) {
            *o = v;
        }
    }
    out
}

/// Linear interpolation onto the grid between neighbours at most `max_step` apart.
fn interpolate(xs: &[f64], z: &[f64], x0: f64, dx: f64, n: usize, max_step: f64) -> Vec<f64> {
    let mut out = vec![f64::NAN; n];
    let mut j = 0;
    for (i, o) in out.iter_mut().enumerate() {
        let x = x0 + i as f64 * dx;
        while j + 1 < xs.len() && xs[j + 1] <= x {
            j += 1;
        }
        let tol = 1e-6 * dx;
        if (xs[j] - x).abs() <= tol {
            *o = z[j];
        } else if j + 1 < xs.len() && (xs[j + 1] - x).abs() <= tol {
            *o = z[j + 1];
        } else if j + 1 < xs.len() && xs[j] <= x && xs[j + 1] - xs[j] <= max_step {
            let t = (x - xs[j]) / (xs[j + 1] - xs[j]);
            *o = z[j] + t * (z[j + 1] - z[j]);
        }
    }
    out
}

/// A profile as one line's stitched result: no frames, its gaps listed.
pub fn stitched(line: usize, x0_mm: f64, dx_mm: f64, z_um: Vec<f64>) -> Stitched {
    let gaps = super::stitch::gaps(x0_mm, dx_mm, &z_um);
    Stitched {
        laser: line,
        section: 1,
        x0_mm,
        dx_mm,
        points: z_um.iter().filter(|v| v.is_finite()).count(),
        z: Samples::from_vec(z_um),
        frames: 0,
        runs_averaged: 1.0,
        fits: FitLog::default(),
        joins: Vec::new(),
        gaps,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analyze::stitch::Gap;

    #[test]
    fn uniform_samples_are_kept_as_they_are_and_steps_leave_gaps() {
        let (info, s) = parse("# a comment\nx_mm,height_um\n0,1.5\n1,2\n2,\n3,4\n5,6\n", None).unwrap();
        assert!(!info.resampled);
        assert_eq!(info.data_dx_mm, 1.0);
        let z = &s.lasers[0].z.to_vec().unwrap();
        assert_eq!(z.len(), 6);
        assert_eq!((z[0], z[1], z[3], z[5]), (1.5, 2.0, 4.0, 6.0));
        assert!(z[2].is_nan() && z[4].is_nan());
        assert_eq!(
            s.lasers[0].gaps,
            vec![Gap { start_mm: 2.0, length_mm: 1.0 }, Gap { start_mm: 4.0, length_mm: 1.0 }]
        );
    }

    #[test]
    fn several_lines_metres_and_separators() {
        let (info, s) = parse("x_m\theight_um_0\theight_um_1\n10\t1\t2\n10.002\t3\t4\n10.004\t5\t6\n", None).unwrap();
        assert_eq!(info.columns, vec!["height_um_0", "height_um_1"]);
        assert_eq!(s.lasers.len(), 2);
        assert!((s.lasers[1].x0_mm - 10_000.0).abs() < 1e-9 && (s.lasers[1].dx_mm - 2.0).abs() < 1e-9);
        assert_eq!(s.lasers[1].z.to_vec().unwrap(), vec![2.0, 4.0, 6.0]);
        let (_, s) = parse("height_um height_mm\n1 0.001\n2 0.002\n", Some(0.5)).unwrap();
        assert_eq!(s.lasers[1].z.to_vec().unwrap(), vec![1.0, 2.0]);
        assert_eq!(s.lasers[0].dx_mm, 0.5);
    }

    #[test]
    fn other_spacings_are_interpolated_never_across_a_gap() {
        let (info, s) = parse("x_mm,height_um\n0,0\n2,2\n4,4\n10,10\n12,12\n", Some(1.0)).unwrap();
        assert!(info.resampled);
        let z = &s.lasers[0].z.to_vec().unwrap();
        assert_eq!(z.len(), 13);
        for (i, v) in [(0, 0.0), (1, 1.0), (3, 3.0), (4, 4.0), (10, 10.0), (11, 11.0), (12, 12.0)] {
            assert!((z[i] - v).abs() < 1e-12, "{i}: {}", z[i]);
        }
        assert!(z[5..10].iter().all(|v| v.is_nan()), "{z:?}");
    }

    #[test]
    fn a_byte_order_mark_is_not_part_of_the_header() {
        let (info, s) = parse("\u{feff}x_mm,height_um\n0,1\n1,2\n", None).unwrap();
        assert!(info.has_x);
        assert_eq!((info.rows, s.lasers[0].z.to_vec().unwrap()), (2, vec![1.0, 2.0]));
    }

    #[test]
    fn bad_files_are_named_where_they_are_wrong() {
        for (text, dx, want) in [
            ("", None, "no header"),
            ("x_mm,speed\n0,1\n", None, "column `speed`"),
            ("x_mm\n0\n1\n", None, "no height column"),
            ("height_um\n1\n2\n", None, "--dx-mm"),
            ("x_mm,height_um\n0,1\n1,2,3\n", None, "line 3: 3 fields"),
            ("x_mm,height_um\n0,1\n1,abc\n", None, "line 3, column `height_um`: `abc`"),
            ("x_mm,height_um\n0,1\n0,2\n", None, "does not increase"),
            ("x_mm,height_um\n0,1\n", None, "at least 2"),
            ("x_mm,height_um\n0,1\n1e9,2\n", Some(1e-3), "more than"),
            ("x_mm,height_um\n,1\n1,2\n", None, "column `x_mm`"),
            ("x_mm,height_um\n0,1\n1,1e300\n", None, "line 3, column `height_um`: 1e300 µm is beyond"),
            ("x_mm,height_mm\n0,-1e300\n1,2\n", None, "line 2, column `height_mm`: -1e303 µm"),
        ] {
            let e = parse(text, dx).unwrap_err();
            assert!(e.to_string().contains(want), "{text:?}: {e}");
        }
    }
}
