//! The calibration file: TOML, versioned, units in the key names, validated
//! on load with an error that names the bad key.
//!
//! ```toml
//! version = 1
//! id = 1234                 # optional: the identifier the head echoes (non-zero)
//!
//! [camera]                  # cms-host calibrate camera
//! width = 752               # px
//! height = 480              # px
//! fx = 1400.2               # focal lengths, principal point and skew: px
//! fy = 1400.1
//! cx = 379.3
//! cy = 236.7
//! skew = 0.0
//! k1 = -0.09                # Brown–Conrady distortion (OpenCV's model and order)
//! k2 = 0.12
//! p1 = 0.0002
//! p2 = -0.00015
//! k3 = 0.0
//! rms_px = 0.08             # RMS reprojection error of the calibration
//!
//! [camera_sigma]            # optional: one standard deviation of each [camera] value,
//! fx_px = 0.41              # from the Jacobian of the fit (σ²·(JᵀJ)⁻¹); a value
//! fy_px = 0.40              # held fixed has no key
//! cx_px = 0.35
//! cy_px = 0.33
//! k1 = 0.0011
//! k2 = 0.006
//! p1 = 0.00004
//! p2 = 0.00005
//!
//! [board]                   # optional: the checkerboard used
//! cols = 9                  # inner corners per row
//! rows = 6                  # inner corners per column
//! square_mm = 25.0
//!
//! [datum]                   # the rail-top reference plane heights are measured from
//! nx = 0.0                  # unit normal, pointing from the rail towards the camera
//! ny = 0.0
//! nz = -1.0
//! d_mm = -200.0             # n·X = d, camera frame
//!
//! [head]                    # optional: the detector's scale range (paper Eq. 10–11)
//! laser_diameter_mm = 0.75
//! range_min_mm = 170.0
//! range_max_mm = 230.0
//! f_number = 2.8            # optional, with wavelength_nm: the lens's iris, set and
//! wavelength_nm = 685.0     # locked at calibration, and the lasers' wavelength
//!                           # (listen records them: crate::model::optics)
//!
//! [[laser]]                 # cms-host calibrate lasers: three entries, id 0, 1, 2
//! id = 0                    # laser index: left to right in the image
//! nx = 0.7431               # unit normal, camera frame
//! ny = 0.0
//! nz = -0.6691
//! d_mm = -141.26            # n·X = d
//! rms_mm = 0.004            # RMS distance of the fitted points from the plane
//! points = 5120             # points the plane was fitted to
//! spread_mm = 14.2          # optional: the points' spread across the laser line
//!                           # (σ of their second principal direction)
//! depth_min_mm = 160.2      # optional: the nearest and farthest point along the
//! depth_max_mm = 241.7      # optical axis
//! ```
//!
//! The camera frame is OpenCV's: `x` right, `y` down, `z` forward, mm.
//! A file from `calibrate camera` has `[camera]` (and `[board]`) only; the
//! head needs all of `[camera]`, `[datum]` and three `[[laser]]`s.
//!
//! **Validation** is what every reader needs, in one place ([`CalibrationFile::parse`]):
//! each value, and with the datum and the lasers the head's own check of the
//! calibration message (`cms_core::pipeline::triangulator`: the planes
//! usable, distinct, in laser order left to right and not crossing in the
//! working depth) and, with `[head]`, the detector's scale range from it —
//! so a file that loads is one `measure`, `analyze` and the head accept.
//! [`CalibrationFile::save`] parses the text it is about to write with the
//! same code and writes nothing that would not load. Old files (without
//! `[camera_sigma]` or the per-laser spread) load as before.

mod check;
mod head;

use std::fmt;
use std::path::Path;

use serde::de::{self, MapAccess, Visitor};
use serde::ser::SerializeStruct;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::model::board::Board;
use crate::model::camera::Intrinsics;

/// The file format version this build reads and writes.
pub const FILE_VERSION: u32 = 1;

/// Tolerance on `|n| = 1` for the plane normals of a file (they are
/// renormalised on load).
const UNIT_TOLERANCE: f64 = 1e-3;

/// A calibration file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationFile {
    /// Format version: [`FILE_VERSION`].
    pub version: u32,
    /// Identifier the head echoes in its `Hello` (non-zero); derived from
    /// the content when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub id: Option<u32>,
    /// Camera intrinsics and distortion.
    pub camera: CameraSection,
    /// Their standard deviations.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_sigma: Option<SigmaSection>,
    /// The checkerboard the camera was calibrated with.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub board: Option<BoardSection>,
    /// The rail-top reference plane.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub datum: Option<PlaneSection>,
    /// Optics of the head, for the detector's scale range.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub head: Option<HeadSection>,
    /// Laser planes.
    #[serde(default, rename = "laser", skip_serializing_if = "Vec::is_empty")]
    pub lasers: Vec<LaserSection>,
}

/// `[camera]`: the camera model (its keys are [`Intrinsics`]'s) and how
/// well it was fitted.
///
/// One flat TOML table holds both. Its serde impls are written out rather
/// than derived with `#[serde(flatten)]` over [`Intrinsics`]: flatten
/// buffers the table, which loses toml's spans (errors would name the
/// `[camera]` line, not the bad key's) and `deny_unknown_fields`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraSection {
    /// Image size, intrinsics and distortion.
    pub intrinsics: Intrinsics,
    /// RMS reprojection error of the calibration, px.
    pub rms_px: f64,
}

/// The keys of `[camera]`, in the order they are written.
const CAMERA_KEYS: [&str; 13] =
    ["width", "height", "fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3", "rms_px"];

impl Serialize for CameraSection {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let i = &self.intrinsics;
        let mut t = s.serialize_struct("CameraSection", CAMERA_KEYS.len())?;
        t.serialize_field("width", &i.width_px)?;
        t.serialize_field("height", &i.height_px)?;
        for (k, v) in CAMERA_KEYS[2..].iter().zip([
            i.fx_px,
            i.fy_px,
            i.cx_px,
            i.cy_px,
            i.skew_px,
            i.k1,
            i.k2,
            i.p1,
            i.p2,
            i.k3,
            self.rms_px,
        ]) {
            t.serialize_field(k, &v)?;
        }
        t.end()
    }
}

impl<'de> Deserialize<'de> for CameraSection {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        /// A key of `[camera]`: deserialised as an identifier, so that an
        /// unknown key is reported at its own span.
        struct Key(usize);
        impl<'de> Deserialize<'de> for Key {
            fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                struct KeyVisitor;
                impl Visitor<'_> for KeyVisitor {
                    type Value = Key;
                    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                        f.write_str("a [camera] key")
                    }
                    fn visit_str<E: de::Error>(self, v: &str) -> Result<Key, E> {
                        CAMERA_KEYS
                            .iter()
                            .position(|k| *k == v)
                            .map(Key)
                            .ok_or_else(|| E::unknown_field(v, &CAMERA_KEYS))
                    }
                }
                d.deserialize_identifier(KeyVisitor)
            }
        }
        struct SectionVisitor;
        impl<'de> Visitor<'de> for SectionVisitor {
            type Value = CameraSection;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("the [camera] table")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<CameraSection, A::Error> {
                let mut size: [Option<u32>; 2] = [None; 2];
                let mut num: [Option<f64>; 11] = [None; 11];
                while let Some(Key(k)) = map.next_key()? {
                    let taken = match k {
                        0 | 1 => size[k].replace(map.next_value()?).is_some(),
                        _ => num[k - 2].replace(map.next_value()?).is_some(),
                    };
                    if taken {
                        return Err(de::Error::duplicate_field(CAMERA_KEYS[k]));
                    }
                }
                let missing = |k: usize| de::Error::missing_field(CAMERA_KEYS[k]);
                let width_px = size[0].ok_or_else(|| missing(0))?;
                let height_px = size[1].ok_or_else(|| missing(1))?;
                let mut v = [0.0; 11];
                for (k, (slot, got)) in v.iter_mut().zip(num).enumerate() {
                    *slot = got.ok_or_else(|| missing(k + 2))?;
                }
                let [fx_px, fy_px, cx_px, cy_px, skew_px, k1, k2, p1, p2, k3, rms_px] = v;
                let intrinsics =
                    Intrinsics { width_px, height_px, fx_px, fy_px, cx_px, cy_px, skew_px, k1, k2, p1, p2, k3 };
                Ok(CameraSection { intrinsics, rms_px })
            }
        }
        d.deserialize_struct("CameraSection", &CAMERA_KEYS, SectionVisitor)
    }
}

/// `[camera_sigma]`: one standard deviation of each `[camera]` value; a
/// value held fixed has none.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs)]
pub struct SigmaSection {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fx_px: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fy_px: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cx_px: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cy_px: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub skew_px: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k1: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k2: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p1: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p2: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k3: Option<f64>,
}

impl SigmaSection {
    /// From σ in `calib::camera::INTRINSIC_NAMES` order.
    pub fn from_array(v: [Option<f64>; 10]) -> SigmaSection {
        let [fx_px, fy_px, cx_px, cy_px, skew_px, k1, k2, p1, p2, k3] = v;
        SigmaSection { fx_px, fy_px, cx_px, cy_px, skew_px, k1, k2, p1, p2, k3 }
    }

    /// `(key, σ)` of the values present.
    pub fn entries(&self) -> Vec<(&'static str, f64)> {
        [
            ("fx_px", self.fx_px),
            ("fy_px", self.fy_px),
            ("cx_px", self.cx_px),
            ("cy_px", self.cy_px),
            ("skew_px", self.skew_px),
            ("k1", self.k1),
            ("k2", self.k2),
            ("p1", self.p1),
            ("p2", self.p2),
            ("k3", self.k3),
        ]
        .into_iter()
        .filter_map(|(k, v)| v.map(|v| (k, v)))
        .collect()
    }
}

/// `[board]`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoardSection {
    /// Inner corners per row.
    pub cols: u32,
    /// Inner corners per column.
    pub rows: u32,
    /// Square side, mm.
    pub square_mm: f64,
}

/// `[datum]`: a plane `n·X = d_mm` in the camera frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneSection {
    /// Unit normal, x.
    pub nx: f64,
    /// Unit normal, y.
    pub ny: f64,
    /// Unit normal, z.
    pub nz: f64,
    /// Offset, mm.
    pub d_mm: f64,
}

/// `[head]`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeadSection {
    /// Thickness of the laser sheet (Table 4 "laser diameter"), mm.
    pub laser_diameter_mm: f64,
    /// Nearest working distance, mm.
    pub range_min_mm: f64,
    /// Farthest working distance, mm.
    pub range_max_mm: f64,
    /// The lens's F-number, set and locked at calibration (with `wavelength_nm`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub f_number: Option<f64>,
    /// The lasers' wavelength, nm (with `f_number`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wavelength_nm: Option<f64>,
}

impl HeadSection {
    /// The optics the head records with, when the table gives them (both
    /// keys, or neither: checked when the file is read).
    pub fn optics(&self) -> Result<Option<crate::model::optics::Optics>, crate::model::optics::OpticsError> {
        match (self.f_number, self.wavelength_nm) {
            (None, None) => Ok(None),
            (Some(f), Some(nm)) => crate::model::optics::Optics::new(f, nm).map(Some),
            _ => Err(crate::model::optics::OpticsError::Unpaired),
        }
    }
}

/// One `[[laser]]`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaserSection {
    /// Laser index, `0..3`, left to right in the image.
    pub id: u32,
    /// Unit normal, x.
    pub nx: f64,
    /// Unit normal, y.
    pub ny: f64,
    /// Unit normal, z.
    pub nz: f64,
    /// Offset, mm: `n·X = d_mm`.
    pub d_mm: f64,
    /// RMS distance of the fitted points from the plane, mm.
    pub rms_mm: f64,
    /// Points the plane was fitted to.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub points: Option<u64>,
    /// The points' spread across the laser line (σ along their second
    /// principal direction), mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spread_mm: Option<f64>,
    /// Nearest point along the optical axis, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_min_mm: Option<f64>,
    /// Farthest point along the optical axis, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_max_mm: Option<f64>,
}

/// What a recording says of the head that made it: the calibration ids
/// and sensor sizes of its `Hello`s, and the largest row and column of its
/// points (what a recording without a `Hello` still tells of the camera).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RecordedHeads {
    /// Distinct non-zero calibration ids of the `Hello`s, in order.
    pub calibration_ids: Vec<u32>,
    /// Distinct sensor sizes (width, height) of the `Hello`s, px.
    pub sensors: Vec<(u32, u32)>,
    /// Largest point row and column, px.
    pub max_row_px: Option<u32>,
    /// Largest point column, px.
    pub max_column_px: Option<f64>,
}

impl RecordedHeads {
    /// Notes a `Hello`.
    pub fn hello(&mut self, info: &cms_core::protocol::DeviceInfo) {
        let id = info.calibration_id;
        if id != 0 && !self.calibration_ids.contains(&id) {
            self.calibration_ids.push(id);
        }
        let size = (u32::from(info.sensor_width), u32::from(info.sensor_height));
        if !self.sensors.contains(&size) {
            self.sensors.push(size);
        }
    }

    /// Notes a profile's points.
    pub fn profile(&mut self, p: &cms_core::protocol::Profile) {
        for q in p.lasers.iter().flat_map(|l| l.points.iter()) {
            self.max_row_px = Some(self.max_row_px.map_or(u32::from(q.row), |r| r.max(u32::from(q.row))));
            let c = q.position.to_f64();
            self.max_column_px = Some(self.max_column_px.map_or(c, |m| m.max(c)));
        }
    }
}

/// What is wrong with a calibration file: one line naming the file and the key.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FileError(pub String);

impl fmt::Display for FileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for FileError {}

impl From<FileError> for crate::Error {
    fn from(e: FileError) -> Self {
        crate::Error::Input(e.0)
    }
}

/// Largest calibration file read, bytes (a real one is under 2 KB).
const MAX_FILE_BYTES: u64 = 1 << 20;

impl CalibrationFile {
    /// A camera-only file.
    pub fn camera_only(intr: &Intrinsics, rms_px: f64, board: Option<&Board>) -> CalibrationFile {
        CalibrationFile {
            version: FILE_VERSION,
            id: None,
            camera: CameraSection { intrinsics: *intr, rms_px },
            camera_sigma: None,
            board: board.map(|b| BoardSection { cols: b.cols as u32, rows: b.rows as u32, square_mm: b.square_mm }),
            datum: None,
            head: None,
            lasers: Vec::new(),
        }
    }

    /// Parses and validates the text of a file; `name` prefixes the errors.
    pub fn parse(text: &str, name: &str) -> Result<CalibrationFile, FileError> {
        let mut f: CalibrationFile = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
            let msg = crate::input::one_line(e.message(), 300);
            FileError(match line {
                Some(l) => format!("{name}:{l}: {msg}"),
                None => format!("{name}: {msg}"),
            })
        })?;
        f.validate().map_err(|m| FileError(format!("{name}: {m}")))?;
        Ok(f)
    }

    /// Reads (at most 1 MiB, counted while reading: a device or FIFO is
    /// stopped there), parses and validates a file.
    pub fn load(path: &Path) -> Result<CalibrationFile, FileError> {
        let name = path.display().to_string();
        // The input error names the file already.
        let bytes = crate::input::read_capped(path, MAX_FILE_BYTES).map_err(|e| FileError(e.to_string()))?;
        let text = String::from_utf8(bytes).map_err(|_| FileError(format!("{name}: not UTF-8 text")))?;
        CalibrationFile::parse(&text, &name)
    }

    /// The TOML text, with a header comment.
    pub fn to_toml(&self) -> String {
        let body = toml::to_string(self).unwrap_or_default();
        format!(
            "# Calibration of a rail corrugation sensor head (cms-host calibrate).\n\
             # Camera frame: x right, y down, z forward, mm; pixel centres at integers.\n{body}"
        )
    }

    /// Writes the file after reading its text back with
    /// [`CalibrationFile::parse`] (what every reader would refuse is not
    /// written), atomically and only as a regular file
    /// ([`crate::output::write_atomically`]): a failure never leaves half a
    /// file, and a device, FIFO or directory is refused, not replaced.
    pub fn save(&self, path: &Path) -> Result<(), crate::Error> {
        let text = self.to_toml();
        let name = path.display().to_string();
        CalibrationFile::parse(&text, &name)
            .map_err(|e| crate::Error::Input(format!("{e}; not written: its readers would refuse it")))?;
        Ok(crate::output::write_atomically(path, |w| w.write_all(text.as_bytes()))?)
    }

    /// Refuses to pair this calibration (`cal_name`) with a recording
    /// (`rec_name`) of another head: a `Hello` with another calibration id
    /// (`0`, no calibration, is not another one: its raw peaks are
    /// triangulated with this file), or another sensor size, or points
    /// beyond this camera's image.
    pub fn check_recording(&self, cal_name: &str, rec_name: &str, heads: &RecordedHeads) -> Result<(), crate::Error> {
        let bad = |m: String| Err(crate::Error::Input(m));
        let id = self.head_id();
        if let Some(rid) = heads.calibration_ids.iter().find(|&&r| r != id) {
            return bad(format!(
                "{cal_name} is calibration {id:#010x}, but {rec_name} was recorded with calibration {rid:#010x}"
            ));
        }
        let (w, h) = (self.camera.intrinsics.width_px, self.camera.intrinsics.height_px);
        if let Some(&(sw, sh)) = heads.sensors.iter().find(|&&s| s != (w, h)) {
            return bad(format!("{cal_name} is for a {w}×{h} camera, but {rec_name} was recorded by a {sw}×{sh} one"));
        }
        if let Some(r) = heads.max_row_px.filter(|&r| r >= h) {
            return bad(format!("{cal_name} is for a {w}×{h} camera, but {rec_name} has points in row {r}"));
        }
        if let Some(c) = heads.max_column_px.filter(|&c| c > f64::from(w)) {
            return bad(format!("{cal_name} is for a {w}×{h} camera, but {rec_name} has points at column {c:.1}"));
        }
        Ok(())
    }

    /// Refuses to pair this calibration (`cal_name`) with an image
    /// (`image_name`) of another size than its camera's.
    pub fn check_image(
        &self,
        cal_name: &str,
        image_name: &str,
        width: usize,
        height: usize,
    ) -> Result<(), crate::Error> {
        let (w, h) = (self.camera.intrinsics.width_px, self.camera.intrinsics.height_px);
        if (width, height) != (w as usize, h as usize) {
            return Err(crate::Error::Input(format!(
                "{image_name} is {width}×{height} px, but {cal_name} is for a {w}×{h} camera"
            )));
        }
        Ok(())
    }

    /// The camera's intrinsics.
    pub fn intrinsics(&self) -> Intrinsics {
        self.camera.intrinsics
    }

    /// The board, if the file names one.
    pub fn board(&self) -> Option<Board> {
        self.board.map(|b| Board { cols: b.cols as usize, rows: b.rows as usize, square_mm: b.square_mm })
    }

    /// The identifier sent to the head: `id`, or else a CRC-32 of the
    /// calibration's numbers (never 0).
    pub fn head_id(&self) -> u32 {
        if let Some(id) = self.id {
            return id;
        }
        let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
        let mut d = crc.digest();
        d.update(self.to_toml().as_bytes());
        d.finalize().max(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The simulated head's true calibration (range 170–230 mm): each
    /// window holds its line at the rail's 200 mm (columns 310, 379, 450),
    /// lies within the row, and widens with the margin.
    #[test]
    fn search_windows_hold_the_lines() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/v3/cal.toml");
        let cal = CalibrationFile::load(&path).unwrap();
        let w = cal.search_windows(16.0).unwrap();
        for (k, col) in [(0, 310), (1, 379), (2, 450)] {
            let c = w[k].unwrap();
            assert!(u32::from(c.first_px) < col && col < c.end_px() && c.end_px() <= 752, "laser {k}: {c:?}");
            let narrow = cal.search_windows(0.0).unwrap()[k].unwrap();
            assert!(c.first_px <= narrow.first_px && narrow.end_px() <= c.end_px() && c.width_px > narrow.width_px);
        }
        let mut no_head = cal.clone();
        no_head.head = None;
        assert!(no_head.search_windows(16.0).unwrap_err().0.contains("[head]"));
    }

    const FULL: &str = "version = 1
[camera]
width = 752
height = 480
fx = 1400.0
fy = 1400.0
cx = 379.2
cy = 236.8
skew = 0.0
k1 = -0.09
k2 = 0.12
p1 = 0.0002
p2 = -0.00015
k3 = 0.0
rms_px = 0.1
[datum]
nx = 0.0
ny = 0.0
nz = -1.0
d_mm = -200.0
[[laser]]
id = 0
nx = 0.7431448
ny = 0.0
nz = -0.6691306
d_mm = -141.25757
rms_mm = 0.003
[[laser]]
id = 1
nx = 0.7431448
ny = 0.0
nz = -0.6691306
d_mm = -133.82612
rms_mm = 0.003
[[laser]]
id = 2
nx = 0.7431448
ny = 0.0
nz = -0.6691306
d_mm = -126.39467
rms_mm = 0.003
";

    #[test]
    fn round_trip_and_head_message() {
        let f = CalibrationFile::parse(FULL, "cal.toml").unwrap();
        let again = CalibrationFile::parse(&f.to_toml(), "again").unwrap();
        assert_eq!(f, again);
        let c = f.to_head().unwrap();
        assert_ne!(c.id, 0);
        assert_eq!(c.intrinsics, [1400.0, 1400.0, 379.2, 236.8, 0.0]);
        assert_eq!(c.planes[2][3], -126.39467);
        assert_eq!(c.datum, [0.0, 0.0, -1.0, -200.0]);
        assert!(cms_core::pipeline::calibration_is_valid(&c));
    }

    fn err(text: &str) -> String {
        CalibrationFile::parse(text, "cal.toml").unwrap_err().0
    }

    #[test]
    fn errors_name_the_key() {
        assert_eq!(
            err(&FULL.replace("fx = 1400.0", "fx = -3.0")),
            "cal.toml: camera.fx = -3 must be a finite number > 0"
        );
        assert!(err(&FULL.replace("fy = 1400.0", "fy = nan")).contains("camera.fy"));
        assert!(err(&FULL.replace("version = 1", "version = 7")).contains("version = 7"));
        let e = err(&FULL.replace("k3 = 0.0", "k3 = 0.0\nk4 = 1.0"));
        assert!(e.starts_with("cal.toml:15:") && e.contains("k4"), "{e}");
        let e = err(&FULL.replace("cy = 236.8\n", ""));
        assert!(e.contains("cy"), "{e}");
        let e = err(&FULL.replace("id = 2", "id = 1"));
        assert_eq!(e, "cal.toml: laser #3 (id 1): id 1 appears twice");
        let e = err(&FULL.replacen("nx = 0.7431448", "nx = 0.5", 1));
        assert!(e.starts_with("cal.toml: laser #1 (id 0): (nx, ny, nz) must be a unit vector"), "{e}");
        assert!(err(&FULL.replace("d_mm = -200.0", "d_mm = 200.0")).contains("datum.d_mm"));
        let e = err(&FULL.replace("width = 752", "width = \"752\""));
        assert!(e.starts_with("cal.toml:3:"), "{e}");
        assert!(err("version = 1").contains("camera"));
        assert!(!err("[camera\n").is_empty());
        for e in [err(&FULL.replace("k1 = -0.09", "k1 = [1, 2]")), err("\u{0}\u{1}"), err("")] {
            assert!(!e.contains('\n'), "{e}");
        }
    }

    #[test]
    fn camera_only_files_do_not_make_a_head_calibration() {
        let end = FULL.find("[datum]").unwrap();
        let f = CalibrationFile::parse(&FULL[..end], "cam.toml").unwrap();
        assert!(f.to_head().unwrap_err().0.contains("[datum]"));
        let two = FULL.rfind("[[laser]]").unwrap();
        assert!(err(&FULL[..two]).contains("2 [[laser]] entries"));
    }

    #[test]
    fn camera_sigma_round_trips_and_old_files_still_load() {
        // FULL is a file of before [camera_sigma] and the laser spread.
        let mut f = CalibrationFile::parse(FULL, "cal.toml").unwrap();
        assert!(f.camera_sigma.is_none());
        f.camera_sigma = Some(SigmaSection { fx_px: Some(0.23), k1: Some(1.5e-3), ..SigmaSection::default() });
        f.lasers[1].spread_mm = Some(12.5);
        let text = f.to_toml();
        assert!(text.contains("[camera_sigma]\nfx_px = 0.23\nk1 = 0.0015\n"), "{text}");
        assert_eq!(CalibrationFile::parse(&text, "again").unwrap(), f);
        let e = err(&text.replace("fx_px = 0.23", "fx_px = -1.0"));
        assert_eq!(e, "cal.toml: camera_sigma.fx_px = -1 must be a finite number ≥ 0");
        let e = err(&text.replace("spread_mm = 12.5", "spread_mm = nan"));
        assert!(e.contains("laser 1: spread_mm = NaN"), "{e}");
    }

    #[test]
    fn normals_are_renormalised() {
        let f = CalibrationFile::parse(&FULL.replace("nz = -1.0", "nz = -1.0005"), "cal.toml").unwrap();
        assert_eq!(f.datum.unwrap().nz, -1.0);
    }
}
