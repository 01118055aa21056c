//! What a rail does to a laser line, beyond a clean Gaussian stripe: the
//! light model of the simulated head, from physics.
//!
//! * **Speckle** (`coherent.rs`): a 685 nm line on steel rough at the
//!   wavelength's scale is imaged coherently through the lens's pupil; the
//!   pattern is tied to the surface, so motion during the exposure averages
//!   it and a head at rest sees the same one frame after frame. Several
//!   independent patterns (several diodes, a moving diffuser) add as
//!   intensities ([`Speckle::patterns`]); many of them are rendered as a
//!   few ([`RENDERED_PATTERNS`]) with the statistics of many, or, where
//!   the speckle is under a pixel, as their expected image with the
//!   stripe-centre error their speckle causes (`tile/fast.rs`).
//! * **Focus**: the coherent transfer function carries the defocus of a
//!   rail outside the plane the lens is focused on (image-side focus error
//!   `M² Δz`, wavefront error `W₀₂₀ = Δz_img / (8 N_eff²)`); a
//!   Scheimpflug sensor ([`LightModel::scheimpflug`]) makes that plane a
//!   laser's own.
//! * **Surface finish** (`surface.rs`): oxidation and rust patches, grease
//!   films and the shiny running band, as a reflectance over the rail top
//!   (5–100 %, sharp or soft edges) that multiplies the illumination.
//! * **Glints**: specular facets in the lit band, a few pixels, bright
//!   enough to saturate, not speckled.
//! * **Secondary reflections** ([`Ghost`]): a weaker line beside or
//!   crossing a laser's own, from light that bounced off the gauge corner
//!   or another surface first (speckled like any diffuse return).
//!
//! [`LightModel::incoherent`] (the default) is none of this: the stripes
//! are rendered exactly as the clean renderer always did.

pub(crate) mod coherent;
mod mean;
mod ring;
pub(crate) mod surface;
#[cfg(test)]
mod tests;
mod tile;

pub(crate) use tile::{LightCache, TileShot};

use super::{SimError, check};

/// The push-trolley aperture (`docs/light.md`, "What to set"): the
/// widest whose depth of field (18 mm) still holds a trolley's stand-off,
/// and the one that brings the 10–30 mm band's floor 6 dB under its limit.
pub const PUSH_TROLLEY_F_NUMBER: f64 = 2.8;

/// The recommended head's aperture (`docs/light.md`, "What to set"): the
/// widest a Scheimpflug sensor holds in focus on the laser's plane.
pub const RECOMMENDED_F_NUMBER: f64 = 1.4;

/// The recommended head's line source: a broad-area or multimode diode of
/// about this many independent speckle patterns (contrast 0.1).
pub const RECOMMENDED_PATTERNS: u32 = 100;

/// How the rail returns the lasers' light.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LightModel {
    /// Coherent imaging: speckle (`None`: incoherent light, no speckle).
    pub speckle: Option<Speckle>,
    /// Where the lens is focused, mm from the camera along its axis
    /// (`None`: the head's standoff). Acts through the coherent imaging.
    pub focus_mm: Option<f64>,
    /// A Scheimpflug sensor: tilted so that the plane in focus is the
    /// plane of the laser nearest the aim point (its line stays in focus
    /// whatever the rail's height and the F-number) instead of the plane
    /// across the optical axis at `focus_mm`. One sensor has one plane of
    /// focus: the other lasers' parallel planes stand off it by their
    /// lines' spacing over `tan(tilt + α)` along the axis (14 mm for the
    /// reference head's 10 mm spacing at 35°), and their lines are that
    /// far out of focus. The laser sheet's own thickness is neglected
    /// (±0.4 mm from its plane: 0.06 waves of defocus at F/1.4, under the
    /// quarter wave of Rayleigh's depth of focus). Geometry is unchanged:
    /// the tilt's keystone is taken as calibrated out.
    pub scheimpflug: bool,
    /// With [`scheimpflug`](Self::scheimpflug): a Scheimpflug sensor per
    /// laser, each tilted to its own laser's plane, so that every line is
    /// in focus (one camera per line: three for three lasers). The
    /// simulator keeps one camera's geometry and gives each line the focus
    /// of its own plane.
    pub sensor_per_line: bool,
    /// A source of many patterns rendered as speckle fields
    /// ([`RENDERED_PATTERNS`] of them with the statistics of all) where it
    /// would be rendered fast (speckle under a pixel: its expected image
    /// with the stripe-centre error emulated): the reference the fast
    /// rendering is held to, at the fields' cost.
    pub exact_speckle: bool,
    /// Oxidation and rust patches.
    pub oxidation: Patches,
    /// Grease films.
    pub grease: Patches,
    /// The shiny running band and the duller head beside it.
    pub band: Option<RunningBand>,
    /// Specular glints.
    pub glints: Glints,
    /// Secondary reflections.
    pub ghosts: Vec<Ghost>,
}

/// Coherent imaging of the lines through the lens.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Speckle {
    /// The lens's F-number (working aperture).
    pub f_number: f64,
    /// Independent speckle patterns summed in intensity within one
    /// exposure: 1 for one single-mode diode per line; `K` for `K`
    /// mutually incoherent diodes on one line or a diffuser moving through
    /// `K` independent positions, a broad-area or multimode line diode
    /// (contrast falls as `1/√K`). Up to [`RENDERED_PATTERNS`] are
    /// rendered one by one; more are rendered as that many with the
    /// statistics of `K`, or fast where the speckle is under a pixel
    /// (see [`LightModel::exact_speckle`]).
    pub patterns: u32,
}

/// Independent patterns rendered one by one; a source of more (`K`) is
/// rendered from `M` = this many, its intensity `Ī + (I_M − Ī)·√(M/K)`,
/// `I_M` the mean of the `M` patterns and `Ī` its expectation (the
/// illumination imaged incoherently through the lens). By the central
/// limit the sum of `K` patterns tends to `Ī` plus a Gaussian field whose
/// covariance is one pattern's over `K`: the rendering keeps the mean and
/// the second-order statistics exactly — the contrast `1/√K`, the
/// speckle's size and correlation, the pixel and motion averaging — and
/// these set the stripe centre's error to first order. The higher moments
/// are those of `M` patterns scaled (the skewness `√(M/K)`-fold too large
/// against the sum's, for example: `2/√M` per sample where the sum has
/// `2/√K`), which matters only for rare deep fades of the line.
pub const RENDERED_PATTERNS: u32 = 4;

/// Most independent patterns a source may have.
pub const MAX_PATTERNS: u32 = 10_000;

/// Patches of another reflectance on the rail top (oxidation, rust,
/// grease), scattered along the rail: one per `1000 / per_m` mm cell, its
/// place, size and reflectance drawn from the seed.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Patches {
    /// Patches per metre of rail (0: none).
    pub per_m: f64,
    /// Length along the rail, mm: [shortest, longest].
    pub length_mm: [f64; 2],
    /// Width across the rail, mm: [narrowest, widest].
    pub width_mm: [f64; 2],
    /// Reflectance relative to clean steel: [darkest, lightest], in [0.01, 1].
    pub reflectance: [f64; 2],
    /// Width of the edge over which the reflectance changes, mm (0: sharp).
    pub edge_mm: f64,
    /// Lateral half-range of the patches' centres about the rail's axis, mm.
    pub spread_mm: f64,
}

/// The running band: the wheel-polished strip is bright, the head beside it
/// duller.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunningBand {
    /// Centre across the rail, mm (0: the rail's axis, as the head aims).
    pub centre_mm: f64,
    /// Half-width, mm.
    pub half_width_mm: f64,
    /// Reflectance outside the band relative to inside, in [0.01, 1].
    pub outside: f64,
    /// Width of the band's edges, mm (0: sharp).
    pub edge_mm: f64,
}

/// Specular glints in the lit band of each line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Glints {
    /// Glints per metre of each line (0: none).
    pub per_m: f64,
    /// Peak as a multiple of the line's own peak: [dimmest, brightest].
    pub gain: [f64; 2],
    /// Gaussian σ of a glint's image, px.
    pub sigma_px: f64,
}

impl Default for Glints {
    fn default() -> Self {
        Glints { per_m: 0.0, gain: [3.0, 20.0], sigma_px: 0.6 }
    }
}

/// A secondary reflection of one laser: a weaker line beside its own.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ghost {
    /// The laser whose light it is.
    pub laser: usize,
    /// Its peak as a fraction of the laser's own line's.
    pub fraction: f64,
    /// Its distance from the line at the image's middle row, px.
    pub offset_px: f64,
    /// Its drift across the rows, px per row (non-zero: it crosses the
    /// line where `offset + tilt·(row − middle) = 0`).
    pub tilt_px_per_row: f64,
    /// Its width relative to the line's (a diffuse bounce spreads it).
    pub sigma_factor: f64,
}

impl LightModel {
    /// Incoherent light on a clean rail: the stripes as the clean renderer
    /// draws them (the default).
    pub fn incoherent() -> LightModel {
        LightModel::default()
    }

    /// Fully developed speckle through a lens at `f_number`, one pattern.
    pub fn speckle(f_number: f64) -> LightModel {
        LightModel { speckle: Some(Speckle { f_number, patterns: 1 }), ..LightModel::default() }
    }

    /// The push-trolley setting of docs/light.md: one laser pattern
    /// through the lens at [`PUSH_TROLLEY_F_NUMBER`] (with the reference
    /// camera's 100 µs exposure).
    pub fn push_trolley() -> LightModel {
        LightModel::speckle(PUSH_TROLLEY_F_NUMBER)
    }

    /// The head of docs/light.md that judges ISO 3095: a line source of
    /// [`RECOMMENDED_PATTERNS`] independent patterns through the lens at
    /// [`RECOMMENDED_F_NUMBER`] on a Scheimpflug sensor (the middle laser's
    /// plane in focus).
    pub fn recommended() -> LightModel {
        LightModel {
            speckle: Some(Speckle { f_number: RECOMMENDED_F_NUMBER, patterns: RECOMMENDED_PATTERNS }),
            scheimpflug: true,
            ..LightModel::default()
        }
    }

    /// Oxidation: dark patches 10–60 mm long, 5–30 mm wide, 5–40 % of the
    /// steel's reflectance, sharp edges, 8 per metre over the rail top.
    pub fn oxidation() -> Patches {
        Patches {
            per_m: 8.0,
            length_mm: [10.0, 60.0],
            width_mm: [5.0, 30.0],
            reflectance: [0.05, 0.4],
            edge_mm: 0.0,
            spread_mm: 15.0,
        }
    }

    /// Grease: large films 50–300 mm long, 40–50 % of the reflectance,
    /// soft edges (5 mm), 2 per metre.
    pub fn grease() -> Patches {
        Patches {
            per_m: 2.0,
            length_mm: [50.0, 300.0],
            width_mm: [10.0, 40.0],
            reflectance: [0.4, 0.5],
            edge_mm: 5.0,
            spread_mm: 15.0,
        }
    }

    /// A 25 mm running band, the head beside it at 50 %, 2 mm edges.
    pub fn running_band() -> RunningBand {
        RunningBand { centre_mm: 0.0, half_width_mm: 12.5, outside: 0.5, edge_mm: 2.0 }
    }

    /// Glints, 20 per metre of line, 3–20 × the line's peak, σ 0.6 px.
    pub fn glints() -> Glints {
        Glints { per_m: 20.0, ..Glints::default() }
    }

    /// A ghost of the middle laser: 30 % of its peak, 1.5 × wider, 12 px
    /// beside it and crossing it over the frame (0.05 px per row).
    pub fn ghost() -> Ghost {
        Ghost { laser: 1, fraction: 0.3, offset_px: 12.0, tilt_px_per_row: -0.05, sigma_factor: 1.5 }
    }

    /// The detector's estimator for this light: the centroid where the
    /// lines are speckled, the CWT (best under white noise) where not.
    pub fn method(&self) -> cms_core::peak::Method {
        if self.speckle.is_some() { cms_core::peak::Method::Centroid } else { cms_core::peak::Method::Cwt }
    }

    /// Whether the stripes are the clean renderer's (no speckle, no
    /// reflectance map, no ghost): glints alone still add to them.
    pub(crate) fn is_clean(&self) -> bool {
        self.speckle.is_none()
            && self.oxidation.per_m == 0.0
            && self.grease.per_m == 0.0
            && self.band.is_none()
            && self.ghosts.is_empty()
    }

    pub(crate) fn validate(&self, lasers: usize) -> Result<(), SimError> {
        if let Some(s) = &self.speckle {
            check("light.speckle.f_number", s.f_number, (1.0..=64.0).contains(&s.f_number), "in [1, 64]")?;
            let k = f64::from(s.patterns);
            check("light.speckle.patterns", k, (1.0..=f64::from(MAX_PATTERNS)).contains(&k), "in 1..=10000")?;
        }
        if self.sensor_per_line && !self.scheimpflug {
            return Err(SimError::Field {
                field: "light.sensor_per_line",
                value: 1.0,
                expected: "set only with a Scheimpflug sensor",
            });
        }
        if let Some(f) = self.focus_mm {
            check("light.focus_mm", f, f > 0.0, "finite and > 0")?;
        }
        for (name, p) in [("light.oxidation", &self.oxidation), ("light.grease", &self.grease)] {
            p.validate(name)?;
        }
        if let Some(b) = &self.band {
            check("light.band.centre_mm", b.centre_mm, b.centre_mm.is_finite(), "finite")?;
            check("light.band.half_width_mm", b.half_width_mm, b.half_width_mm > 0.0, "finite and > 0")?;
            check("light.band.outside", b.outside, (0.01..=1.0).contains(&b.outside), "in [0.01, 1]")?;
            check("light.band.edge_mm", b.edge_mm, b.edge_mm >= 0.0, "finite and ≥ 0")?;
        }
        let g = &self.glints;
        check("light.glints.per_m", g.per_m, (0.0..=1000.0).contains(&g.per_m), "in [0, 1000]")?;
        check("light.glints.gain[0]", g.gain[0], g.gain[0] >= 0.0, "finite and ≥ 0")?;
        check("light.glints.gain[1]", g.gain[1], g.gain[1] >= g.gain[0], "finite and ≥ gain[0]")?;
        check("light.glints.sigma_px", g.sigma_px, (0.2..=5.0).contains(&g.sigma_px), "in [0.2, 5]")?;
        for h in &self.ghosts {
            let l = h.laser as f64;
            check("light.ghosts.laser", l, h.laser < lasers, "one of the head's lasers")?;
            check("light.ghosts.fraction", h.fraction, (0.0..=2.0).contains(&h.fraction), "in [0, 2]")?;
            check("light.ghosts.offset_px", h.offset_px, h.offset_px.abs() <= 1000.0, "within ±1000")?;
            let t = h.tilt_px_per_row;
            check("light.ghosts.tilt_px_per_row", t, t.abs() <= 2.0, "within ±2")?;
            let s = h.sigma_factor;
            check("light.ghosts.sigma_factor", s, (0.5..=5.0).contains(&s), "in [0.5, 5]")?;
        }
        Ok(())
    }
}

impl Patches {
    fn validate(&self, name: &'static str) -> Result<(), SimError> {
        let field = |f: &'static str| -> &'static str {
            // The names are few and fixed: one static string each.
            match (name, f) {
                ("light.oxidation", "per_m") => "light.oxidation.per_m",
                ("light.oxidation", "length") => "light.oxidation.length_mm",
                ("light.oxidation", "width") => "light.oxidation.width_mm",
                ("light.oxidation", "reflectance") => "light.oxidation.reflectance",
                ("light.oxidation", _) => "light.oxidation",
                ("light.grease", "per_m") => "light.grease.per_m",
                ("light.grease", "length") => "light.grease.length_mm",
                ("light.grease", "width") => "light.grease.width_mm",
                ("light.grease", "reflectance") => "light.grease.reflectance",
                _ => "light.grease",
            }
        };
        check(field("per_m"), self.per_m, (0.0..=1000.0).contains(&self.per_m), "in [0, 1000]")?;
        if self.per_m == 0.0 {
            return Ok(());
        }
        let [l0, l1] = self.length_mm;
        check(field("length"), l0, l0 > 0.0 && l1 >= l0 && l1 <= 10_000.0, "0 < shortest ≤ longest ≤ 10 m")?;
        let [w0, w1] = self.width_mm;
        check(field("width"), w0, w0 > 0.0 && w1 >= w0 && w1.is_finite(), "0 < narrowest ≤ widest")?;
        let [r0, r1] = self.reflectance;
        check(field("reflectance"), r0, r0 >= 0.01 && r1 >= r0 && r1 <= 1.0, "0.01 ≤ darkest ≤ lightest ≤ 1")?;
        check(field("edge"), self.edge_mm, self.edge_mm >= 0.0, "finite and ≥ 0")?;
        check(field("spread"), self.spread_mm, self.spread_mm >= 0.0, "finite and ≥ 0")
    }
}
