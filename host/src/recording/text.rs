//! One profile as a JSON line or CSV rows (`listen --json`, `export`).

use std::io::{self, Write};

use cms_core::pipeline::line::Counts;
use cms_core::protocol::Profile;
use serde::Serialize;
use serde::ser::{SerializeSeq, SerializeStruct, Serializer};

use super::um_to_mm;

struct JsonPoints<'a>(&'a cms_core::protocol::LaserPoints);
struct JsonLasers<'a>(&'a Profile);
/// One profile message as the JSON object of `listen --json` and
/// `export --format jsonl`.
pub struct JsonProfile<'a>(pub &'a Profile);

impl Serialize for JsonProfile<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let p = self.0;
        let mut o = s.serialize_struct("Profile", 10)?;
        o.serialize_field("seq", &p.seq)?;
        o.serialize_field("part", &p.part)?;
        o.serialize_field("parts", &p.parts)?;
        o.serialize_field("timestamp_us", &p.timestamp_us)?;
        o.serialize_field("odometer_mm", &(p.odometer_um as f64 / 1000.0))?;
        o.serialize_field("exposure_us", &p.exposure_us)?;
        o.serialize_field("laser_mask", &p.laser_mask)?;
        o.serialize_field("lasers", &JsonLasers(p))?;
        // What the head's line pass flagged in this message (the points
        // stay, flagged): a frame's counts are those of its parts.
        o.serialize_field("line", &Counts::of(&p.lasers))?;
        o.end()
    }
}

impl Serialize for JsonLasers<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(self.0.lasers.len()))?;
        for l in &self.0.lasers {
            seq.serialize_element(&JsonLaser(l))?;
        }
        seq.end()
    }
}

struct JsonLaser<'a>(&'a cms_core::protocol::LaserPoints);

impl Serialize for JsonLaser<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut o = s.serialize_struct("Laser", 2)?;
        o.serialize_field("laser", &self.0.laser)?;
        o.serialize_field("points", &JsonPoints(self.0))?;
        o.end()
    }
}

#[derive(Serialize)]
struct JsonPoint {
    row: u16,
    position_px: f64,
    strength: u16,
    width_px: f64,
    flags: u8,
    #[serde(skip_serializing_if = "Option::is_none")]
    along_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    height_um: Option<f64>,
}

impl Serialize for JsonPoints<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(self.0.points.len()))?;
        for p in &self.0.points {
            seq.serialize_element(&JsonPoint {
                row: p.row,
                position_px: p.position.to_f64(),
                strength: p.strength,
                width_px: p.width.to_f64(),
                flags: p.flags.0,
                along_mm: p.metric.map(|m| f64::from(m.along_um) / 1e3),
                height_um: p.metric.map(|m| f64::from(m.height_nm) / 1e3),
            })?;
        }
        seq.end()
    }
}

/// Writes one profile as a JSON line (the object, then `\n`).
pub fn write_json_line(out: &mut dyn Write, p: &Profile) -> io::Result<()> {
    serde_json::to_writer(&mut *out, &JsonProfile(p)).map_err(io::Error::from)?;
    out.write_all(b"\n")
}

/// The CSV header of `export --format csv`.
pub const CSV_HEADER: &str =
    "seq,part,timestamp_us,odometer_mm,laser,row,position_px,strength,width_px,flags,along_mm,height_um";

/// Writes one profile as CSV lines, one per point. Positions and widths in
/// pixels with 5 decimals (exact for Q16.16: they read back to the same value);
/// `along_mm` and `height_um` exact decimals of the wire's µm and nm, empty
/// for a head without a calibration.
pub fn write_csv(out: &mut dyn Write, p: &Profile) -> io::Result<()> {
    let odo = um_to_mm(p.odometer_um);
    for l in &p.lasers {
        for q in &l.points {
            let (along, height) = match q.metric {
                Some(m) => (um_to_mm(m.along_um.into()), um_to_mm(m.height_nm.into())),
                None => (String::new(), String::new()),
            };
            writeln!(
                out,
                "{},{},{},{odo},{},{},{},{},{},{},{along},{height}",
                p.seq, p.part, p.timestamp_us, l.laser, q.row, q.position, q.strength, q.width, q.flags.0
            )?;
        }
    }
    Ok(())
}
