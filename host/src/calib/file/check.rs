//! Validation of a calibration file: every value finite and in range, the
//! plane normals unit vectors, and what the head itself will check.

use cms_core::protocol::LASERS;

use super::{CalibrationFile, FILE_VERSION, FileError, LaserSection, UNIT_TOLERANCE};
use crate::model::camera::Intrinsics;

fn finite(key: &str, v: f64) -> Result<(), String> {
    if v.is_finite() { Ok(()) } else { Err(format!("{key} = {v} is not a finite number")) }
}

fn positive(key: &str, v: f64) -> Result<(), String> {
    if v.is_finite() && v > 0.0 { Ok(()) } else { Err(format!("{key} = {v} must be a finite number > 0")) }
}

fn unit(section: &str, n: [f64; 3]) -> Result<[f64; 3], String> {
    for (k, v) in ["nx", "ny", "nz"].iter().zip(n) {
        finite(&format!("{section}.{k}"), v)?;
    }
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if (len - 1.0).abs() > UNIT_TOLERANCE {
        return Err(format!("{section}: (nx, ny, nz) must be a unit vector, its length is {len:.6}"));
    }
    // Renormalise only what is off by more than rounding, so that a file
    // written and read back is unchanged.
    if (len - 1.0).abs() < 1e-9 {
        return Ok(n);
    }
    Ok([n[0] / len, n[1] / len, n[2] / len])
}

impl CalibrationFile {
    /// Checks every value, and renormalises the plane normals.
    pub(super) fn validate(&mut self) -> Result<(), String> {
        if self.version != FILE_VERSION {
            return Err(format!(
                "version = {} is not supported (this cms-host reads version {FILE_VERSION})",
                self.version
            ));
        }
        if self.id == Some(0) {
            return Err("id must be non-zero".into());
        }
        let (c, rms_px) = (&self.camera.intrinsics, self.camera.rms_px);
        if c.width_px == 0 || c.width_px > u16::MAX as u32 {
            return Err(format!("camera.width = {} must be in 1..=65535", c.width_px));
        }
        if c.height_px == 0 || c.height_px > u16::MAX as u32 {
            return Err(format!("camera.height = {} must be in 1..=65535", c.height_px));
        }
        positive("camera.fx", c.fx_px)?;
        positive("camera.fy", c.fy_px)?;
        for (k, v) in [("cx", c.cx_px), ("cy", c.cy_px), ("skew", c.skew_px), ("k1", c.k1), ("k2", c.k2)]
            .into_iter()
            .chain([("p1", c.p1), ("p2", c.p2), ("k3", c.k3), ("rms_px", rms_px)])
        {
            finite(&format!("camera.{k}"), v)?;
        }
        if rms_px < 0.0 {
            return Err(format!("camera.rms_px = {rms_px} must be ≥ 0"));
        }
        if let Some(b) = &self.board {
            if b.cols < 2 || b.rows < 2 {
                return Err(format!("board: {}×{} inner corners; at least 2×2", b.cols, b.rows));
            }
            positive("board.square_mm", b.square_mm)?;
        }
        if let Some(d) = &mut self.datum {
            let n = unit("datum", [d.nx, d.ny, d.nz])?;
            finite("datum.d_mm", d.d_mm)?;
            if d.d_mm >= 0.0 {
                return Err(format!(
                    "datum.d_mm = {} must be < 0: the normal points from the rail towards the camera, which is above the rail",
                    d.d_mm
                ));
            }
            [d.nx, d.ny, d.nz] = n;
        }
        if let Some(h) = &self.head {
            positive("head.laser_diameter_mm", h.laser_diameter_mm)?;
            positive("head.range_min_mm", h.range_min_mm)?;
            positive("head.range_max_mm", h.range_max_mm)?;
            if h.range_max_mm <= h.range_min_mm {
                return Err(format!("head.range_max_mm = {} must be above range_min_mm", h.range_max_mm));
            }
            h.optics().map_err(|e| format!("head.{e}"))?;
        }
        let mut seen = [false; LASERS];
        for (i, l) in self.lasers.iter_mut().enumerate() {
            let at = format!("laser #{} (id {})", i + 1, l.id);
            let Some(slot) = seen.get_mut(l.id as usize) else {
                return Err(format!("{at}: id must be in 0..{LASERS}"));
            };
            if std::mem::replace(slot, true) {
                return Err(format!("{at}: id {} appears twice", l.id));
            }
            let n = unit(&at, [l.nx, l.ny, l.nz])?;
            finite(&format!("{at}: d_mm"), l.d_mm)?;
            if l.d_mm.abs() < 1.0 {
                return Err(format!("{at}: d_mm = {} puts the camera on the laser plane", l.d_mm));
            }
            finite(&format!("{at}: rms_mm"), l.rms_mm)?;
            if l.rms_mm < 0.0 {
                return Err(format!("{at}: rms_mm = {} must be ≥ 0", l.rms_mm));
            }
            [l.nx, l.ny, l.nz] = n;
        }
        if !self.lasers.is_empty() && self.lasers.len() != LASERS {
            return Err(format!("{} [[laser]] entries; a head has {LASERS}", self.lasers.len()));
        }
        if let Some(sg) = &self.camera_sigma {
            for (k, v) in sg.entries() {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(format!("camera_sigma.{k} = {v} must be a finite number ≥ 0"));
                }
            }
        }
        for l in &self.lasers {
            let at = format!("laser {}", l.id);
            for (k, v) in
                [("spread_mm", l.spread_mm), ("depth_min_mm", l.depth_min_mm), ("depth_max_mm", l.depth_max_mm)]
            {
                if let Some(v) = v
                    && !(v.is_finite() && v >= 0.0)
                {
                    return Err(format!("{at}: {k} = {v} must be a finite number ≥ 0"));
                }
            }
        }
        self.check_head()
    }

    /// With a datum and the lasers: what the head checks of the calibration
    /// message ([`cms_core::pipeline::triangulator`]), the laser lines apart
    /// over the `[head]` working range too (the head checks its default
    /// depth only: it is not told the range), and the detector's scale range
    /// of `[head]`, as `measure` and `upload` form it.
    fn check_head(&self) -> Result<(), String> {
        if self.datum.is_none() || self.lasers.len() != LASERS {
            return Ok(());
        }
        let msg = self.to_head().map_err(|e| e.0)?;
        let tri = cms_core::pipeline::triangulator(&msg).map_err(|e| e.to_string())?;
        if let Some(h) = &self.head {
            let range = format!("range {:?}–{:?} mm", h.range_min_mm, h.range_max_mm);
            // The range first: a range the camera cannot see is the
            // range's fault, not the lines' nor the detector's.
            for l in &self.lasers {
                let seen = depths_in_view(&self.camera.intrinsics, l);
                if seen.is_none_or(|(lo, hi)| h.range_min_mm < lo || h.range_max_mm > hi) {
                    let seen = match seen {
                        Some((lo, hi)) if hi.is_finite() => format!("{lo:.1}–{hi:.1} mm"),
                        Some((lo, _)) => format!("beyond {lo:.1} mm"),
                        None => "at no depth".into(),
                    };
                    return Err(format!(
                        "[head] {range} reaches beyond the depths at which the camera sees laser {}'s line \
                         ({seen} along the optical axis, in the image's middle row): narrow range_min_mm/range_max_mm",
                        l.id
                    ));
                }
            }
            tri.scale_range(h.laser_diameter_mm, (h.range_min_mm, h.range_max_mm)).map_err(|e| {
                format!(
                    "[head]: no detector scale range for laser_diameter_mm = {:?}, {range}: {e}",
                    h.laser_diameter_mm
                )
            })?;
            cms_core::pipeline::check_laser_lines(&msg, (h.range_min_mm, h.range_max_mm))
                .map_err(|e| format!("[head] {range}: {e}"))?;
        }
        Ok(())
    }
}

impl CalibrationFile {
    /// The first value the head's `f32` cannot hold, by its key.
    pub(super) fn fits_single_precision(&self) -> Result<(), FileError> {
        let c = &self.camera.intrinsics;
        let mut values: Vec<(String, f64)> = [
            ("fx", c.fx_px),
            ("fy", c.fy_px),
            ("cx", c.cx_px),
            ("cy", c.cy_px),
            ("skew", c.skew_px),
            ("k1", c.k1),
            ("k2", c.k2),
            ("p1", c.p1),
            ("p2", c.p2),
            ("k3", c.k3),
        ]
        .into_iter()
        .map(|(k, v)| (format!("camera.{k}"), v))
        .collect();
        if let Some(d) = &self.datum {
            values.push(("datum.d_mm".into(), d.d_mm));
        }
        for (i, l) in self.lasers.iter().enumerate() {
            values.push((format!("laser #{} (id {}) d_mm", i + 1, l.id), l.d_mm));
        }
        match values.into_iter().find(|(_, v)| !(*v as f32).is_finite()) {
            Some((key, v)) => Err(FileError(format!(
                "{key} = {v:e} is beyond the head's single precision (at most {:e} in magnitude)",
                f32::MAX
            ))),
            None => Ok(()),
        }
    }
}

/// The depths along the optical axis (mm) at which laser `l`'s line, in
/// the image's middle row (the principal point's), falls between the
/// image's first and last column, distortion ignored: on the plane
/// `n·(x z, 0, z) = d` the column goes as `x = (d/z − n_z)/n_x`, so the
/// depths where `x` is in view form one interval of `1/z` (its upper end
/// infinite when the line stays in view however far). `None` if the line
/// is in view at no positive depth.
fn depths_in_view(i: &Intrinsics, l: &LaserSection) -> Option<(f64, f64)> {
    let (x_lo, x_hi) = (-i.cx_px / i.fx_px, (f64::from(i.width_px) - i.cx_px) / i.fx_px);
    let (a, b) = ((l.nz + l.nx * x_lo) / l.d_mm, (l.nz + l.nx * x_hi) / l.d_mm);
    let (r, s) = (a.min(b), a.max(b));
    // Not positive, or NaN (a degenerate section).
    if s.is_nan() || s <= 0.0 {
        return None;
    }
    Some((1.0 / s, if r > 0.0 { 1.0 / r } else { f64::INFINITY }))
}
