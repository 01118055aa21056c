//! Profile messages gathered into frames.

use cms_core::protocol::Profile;

use super::FramePoints;

/// Gathers the calibrated points of profile messages into frames (the parts
/// of one frame share its `seq` and odometer). Points without a metric
/// (no calibration loaded) and points the head's line pass rejected
/// ([`Flags::rejected`](cms_core::peak::Flags::rejected)) are counted and
/// left out.
#[derive(Debug, Default)]
pub struct FrameAssembler {
    current: Option<FramePoints>,
    /// Points without a triangulated position.
    pub uncalibrated_points: u64,
    /// Points with one.
    pub calibrated_points: u64,
    /// Points the line pass rejected.
    pub rejected_points: u64,
}

impl FrameAssembler {
    /// Feeds one profile message; returns the previous frame when this one
    /// starts a new frame.
    pub fn push(&mut self, p: &Profile) -> Option<FramePoints> {
        let odometer_mm = p.odometer_um as f64 / 1000.0;
        let done = match &self.current {
            Some(f) if f.seq == p.seq && f.odometer_mm == odometer_mm && p.part != 0 => None,
            _ => self.current.take(),
        };
        let f = self.current.get_or_insert_with(|| FramePoints { seq: p.seq, odometer_mm, ..FramePoints::default() });
        for l in &p.lasers {
            let Some(dst) = f.lasers.get_mut(l.laser as usize) else { continue };
            for pt in &l.points {
                match pt.metric {
                    _ if pt.flags.rejected() => self.rejected_points += 1,
                    Some(m) => {
                        dst.push((m.along_um as f64 / 1000.0, m.height_nm as f64 / 1000.0));
                        self.calibrated_points += 1;
                    }
                    None => self.uncalibrated_points += 1,
                }
            }
        }
        done.filter(|f| f.points() > 0)
    }

    /// The last frame, if it has points.
    pub fn finish(&mut self) -> Option<FramePoints> {
        self.current.take().filter(|f| f.points() > 0)
    }
}
