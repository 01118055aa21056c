//! The sensor head's geometry: one model that the simulator builds its
//! scene from (`crate::sim::scene`) and the optics prediction of the noise
//! floor reads (`crate::analyze::optics_floor`), so that both speak of the
//! same head.
//!
//! * [`HeadGeometry`] — how the camera and the lasers sit on the rail.
//! * [`HeadLens`] — that geometry with the lens and sensor that image it:
//!   what sets the speckle's effect on a point (aperture, triangulation
//!   angle, rows per millimetre), and where the figures came from
//!   ([`HeadSource`]).

/// How the camera and the lasers sit on the rail (paper §2.2, Fig. 8, Table 4).
///
/// Rail frame: `x` along the track (direction of travel, 0 below the aim
/// point), `y` across the rail head from its centreline (the crown's apex),
/// `z` up from the nominal rail top. The camera (OpenCV axes) has `x_cam =
/// +y` (columns cross the rail), `y_cam = +x` (rows run along the rail) and
/// looks down; so each image row sees one position along the rail and the
/// laser lines, which run along the rail, are near-vertical stripes.
///
/// The laser planes contain the rail direction and make the angle
/// `alpha_deg` with the optical axis: a point of the rail top that rises by
/// Δz moves its line sideways by Δz·tan(tilt + α) and its stripe by about
/// `f_x·Δz·tan(tilt + α)/standoff` columns. They are fixed to the head:
/// `yaw_deg`, `pitch_deg` and `roll_deg` turn the whole head (camera and
/// lasers together) about the aim point, as a misaligned mount would
/// (paper §2.2), and leave the planes in the camera frame unchanged.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeadGeometry {
    /// Working distance: camera centre to the aim point on the nominal rail
    /// top, along the optical axis, mm.
    pub standoff_mm: f64,
    /// Angle between the optical axis and each laser plane (paper α), degrees, in (0, 80).
    pub alpha_deg: f64,
    /// Tilt of the optical axis from the rail-top normal about the rail axis,
    /// degrees (0 = looking straight down; `-alpha_deg` = vertical laser
    /// planes and an oblique camera). The laser planes lean by
    /// `camera_tilt_deg + alpha_deg` from the vertical.
    pub camera_tilt_deg: f64,
    /// Lateral position of the aim point from the rail centreline, mm.
    pub lateral_offset_mm: f64,
    /// Head yaw about the vertical through the aim point, degrees (lines not
    /// parallel to the rail).
    pub yaw_deg: f64,
    /// Head pitch about the lateral axis through the aim point, degrees.
    pub pitch_deg: f64,
    /// Head roll about the rail axis through the aim point, degrees (camera
    /// and lasers together; not perpendicular to the rail top).
    pub roll_deg: f64,
    /// Laser line thickness `d` (Table 4 "laser diameter"), mm: the stripe σ
    /// is `f_x·d·sin α / depth` px (paper Eq. 10–11).
    pub laser_diameter_mm: f64,
    /// Working range `[r_min, r_max]` (Table 4), mm: the detector's scale
    /// range comes from it (see `SimConfig::optics`).
    pub working_range_mm: [f64; 2],
}

impl HeadGeometry {
    /// The reference head: 200 mm standoff, α = 35°, camera straight down,
    /// 0.75 mm line (σ ≈ 3.0 px at f = 1400 px), range 170–230 mm.
    pub fn reference() -> HeadGeometry {
        HeadGeometry {
            standoff_mm: 200.0,
            alpha_deg: 35.0,
            camera_tilt_deg: 0.0,
            lateral_offset_mm: 0.0,
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            laser_diameter_mm: 0.75,
            working_range_mm: [170.0, 230.0],
        }
    }

    /// The paper's prototype (Table 4): α = 42°, 2 mm line, range 350–550 mm,
    /// standoff at the middle of the range (450 mm), camera straight down.
    pub fn paper() -> HeadGeometry {
        HeadGeometry {
            standoff_mm: 450.0,
            alpha_deg: 42.0,
            camera_tilt_deg: 0.0,
            lateral_offset_mm: 0.0,
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            laser_diameter_mm: 2.0,
            working_range_mm: [350.0, 550.0],
        }
    }
}

/// The pixel pitch of the reference sensor, µm (an MT9V034-class 752 × 480
/// sensor): what is taken where a calibration does not say (a calibration
/// gives the focal length in pixels, not the pitch).
pub const REFERENCE_PIXEL_UM: f64 = 6.0;

/// The reference lens's focal length in pixels: 8.4 mm over 6 µm.
pub const REFERENCE_FOCAL_PX: f64 = 1400.0;

/// Where the figures of a [`HeadLens`] come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HeadSource {
    /// The reference head (nothing said of the head that was used).
    Reference,
    /// The head's calibration file: its focal length, datum and laser
    /// planes (the reference sensor's pixel pitch).
    Calibration,
    /// The simulated head's configuration.
    Simulated,
}

impl HeadSource {
    /// The words the outputs carry.
    pub fn name(self) -> &'static str {
        match self {
            HeadSource::Reference => "the reference head",
            HeadSource::Calibration => "the head's calibration",
            HeadSource::Simulated => "the simulated head",
        }
    }
}

/// A head's geometry with the lens and sensor that image it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeadLens {
    /// Where the camera and the lasers sit.
    pub geometry: HeadGeometry,
    /// The lens's focal length, px.
    pub focal_px: f64,
    /// The sensor's pixel pitch, µm.
    pub pixel_um: f64,
    /// Independent speckle patterns the line source sums within an
    /// exposure (1: one single-mode diode a line; several diodes, a
    /// moving diffuser or a broad-area source more): speckle's variance
    /// falls as their number.
    pub speckle_patterns: u32,
    /// Where these figures come from.
    pub source: HeadSource,
}

impl HeadLens {
    /// The reference head: [`HeadGeometry::reference`] behind an 8.4 mm
    /// lens on 6 µm pixels.
    pub fn reference() -> HeadLens {
        HeadLens {
            geometry: HeadGeometry::reference(),
            focal_px: REFERENCE_FOCAL_PX,
            pixel_um: REFERENCE_PIXEL_UM,
            speckle_patterns: 1,
            source: HeadSource::Reference,
        }
    }

    /// The lens's focal length, mm.
    pub fn focal_mm(&self) -> f64 {
        self.focal_px * self.pixel_um * 1e-3
    }

    /// Stand-off from the lens to the rail, mm.
    pub fn standoff_mm(&self) -> f64 {
        self.geometry.standoff_mm
    }

    /// The triangulation angle: between the camera's axis and the laser
    /// sheets, degrees.
    pub fn triangulation_deg(&self) -> f64 {
        self.geometry.alpha_deg
    }

    /// The lens's magnification `f / (d − f)`.
    pub fn magnification(&self) -> f64 {
        let f = self.focal_mm();
        f / (self.standoff_mm() - f)
    }

    /// A sensor row's footprint on the rail, mm.
    pub fn row_mm(&self) -> f64 {
        self.standoff_mm() / self.focal_px
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reference_lens_is_8_4_mm_on_6_um() {
        let h = HeadLens::reference();
        assert!((h.focal_mm() - 8.4).abs() < 1e-12);
        assert!((h.row_mm() - 200.0 * 0.006 / 8.4).abs() < 1e-12);
        assert!((h.magnification() - 8.4 / 191.6).abs() < 1e-12);
        assert_eq!((h.triangulation_deg(), h.source.name()), (35.0, "the reference head"));
    }
}
