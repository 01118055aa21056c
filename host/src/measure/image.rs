//! An image's rows as per-laser profiles: the light judged from the image,
//! the detector that light calls for, and each row's stripes given to
//! their lasers.
//!
//! # The light
//! A laser line on a rail is speckled (the steel is rough at the
//! wavelength): the stripe is a smooth envelope times a random pattern of
//! contrast near one, and the estimator that is best on white noise (the
//! CWT at its best-matching scale) then locks onto single speckles, where
//! a centroid over the stripe's known width weighs every speckle by its
//! light ([`cms_core::peak`]'s `Method::Centroid`; the figures are in
//! `docs/light.md`). Which light an image was taken in is read off the
//! image itself: the strength of each line's stripe from one sampled row
//! to the next. An incoherent line (or one whose speckle is averaged away
//! by motion or many patterns) changes by what the corrugation, the
//! surface and the sensor noise do — a few per cent on the reference
//! head; a speckled one by a fresh draw of the pattern, the median
//! relative change 0.3–0.4 at F/4–F/8. The light is taken as coherent
//! when that median change exceeds [`SPECKLE_CHANGE`] beyond what the
//! sensor noise explains.
//!
//! # Rows to lasers
//! The lasers are mounted left to right in laser order, so a row with one
//! stripe per laser gives them in position order. A row where a line is
//! missing (a dark oxidation patch, a line off the rail) or an extra stripe
//! appears (a ghost, a glint) is not thrown away whole: each stripe goes to
//! the laser whose line, followed from row to row, is nearest, when it is
//! within a third of the lines' spacing; a laser with two such stripes
//! keeps the nearer. The lanes start at the median position of each line
//! over the rows that had one stripe per laser.

use cms_core::fixed::Px;
use cms_core::peak::{Config, Detector, Method, Select, Stripes};
use cms_core::protocol::LASERS;
use serde::Serialize;

use super::{MeasureError, Measurer, Profiles};
use crate::input::detect::MAX_ROW;
use crate::input::{Row, Rows};

/// The median relative change of a line's stripe strength between sampled
/// rows, beyond the sensor noise's share, above which the light is taken
/// as coherent. The reference head measures 0.006–0.010 in incoherent
/// light at 30 dB and 0.34–0.37 under speckle at F/8; 0.1 is three times
/// the contrast motion leaves at 50 km/h and a 100 µs exposure at F/4
/// (pixel contrast 0.14) reduced by the stripe's averaging, and ten times
/// what incoherent light shows.
pub const SPECKLE_CHANGE: f64 = 0.1;

/// Rows between two samples of the light test: more than a speckle (2.3
/// px at F/8), so the samples are independent draws.
const LIGHT_ROW_STEP: usize = 4;

/// Most stripes a row reports before they are given to lasers: the lines
/// and as many strays (a ghost stronger than a line must not push it out).
const MAX_STRIPES: usize = 2 * LASERS;

/// How an image's detector is chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MethodChoice {
    /// By the light the image shows (the module docs: the strength of each
    /// line from one sampled row to the next).
    #[default]
    Auto,
    /// This method, whatever the light.
    Fixed(Method),
}

/// What the light test saw.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LightJudgement {
    /// Median relative change of the stripe strength between sampled rows.
    pub change: f64,
    /// The share of it the sensor noise explains (√2 × noise / median strength).
    pub noise_share: f64,
    /// Lines' stripes sampled.
    pub samples: usize,
    /// Whether the light is taken as coherent (speckled).
    pub speckled: bool,
}

/// An image's profiles and how they were found.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageProfiles {
    /// Per laser, its points.
    pub profiles: Profiles,
    /// Rows that gave no point to any laser.
    pub rows_skipped: usize,
    /// Rows where at least one laser had no point.
    pub rows_partial: usize,
    /// The sub-pixel method used.
    pub method: Method,
    /// The light test (with [`MethodChoice::Auto`]).
    pub light: Option<LightJudgement>,
}

impl Measurer {
    /// The image's detector for `method`.
    fn image_detector(&self, rows: &Rows, method: Method) -> Result<Box<Detector<MAX_ROW>>, MeasureError> {
        let scales = self.scales.ok_or(MeasureError::NoHead)?;
        if rows.width() > MAX_ROW {
            return Err(MeasureError::TooWide(rows.width()));
        }
        let mut cfg = Config::new(rows.bits(), scales);
        cfg.method = method;
        cfg.max_stripes = MAX_STRIPES as u8;
        cfg.select = Select::Strongest;
        Detector::<MAX_ROW>::new(cfg).map(Box::new).map_err(MeasureError::Detector)
    }

    /// Per-laser profiles of an image, with the detector `choice` gives.
    pub fn image_profiles(&self, rows: &Rows, choice: MethodChoice) -> Result<ImageProfiles, MeasureError> {
        let (method, light, lanes) = match choice {
            MethodChoice::Fixed(m) => (m, None, None),
            MethodChoice::Auto => {
                let (j, lanes) = judge_light(&mut *self.image_detector(rows, Method::Cwt)?, rows)?;
                (if j.speckled { Method::Centroid } else { Method::Cwt }, Some(j), lanes)
            }
        };
        let mut det = self.image_detector(rows, method)?;
        let lanes = match lanes {
            Some(l) => Some(l),
            None => lanes_of(&mut det, rows)?,
        };
        let mut out: Profiles = Default::default();
        let (mut skipped, mut partial) = (0, 0);
        let mut track = lanes;
        let mut stripes: Stripes<MAX_STRIPES> = Stripes::new();
        for (r, row) in rows.rows().enumerate() {
            detect(&mut det, row, &mut stripes).map_err(|source| MeasureError::Row { row: r, source })?;
            let Ok(r16) = u16::try_from(r) else { break };
            let given = assign(&stripes, track.as_mut());
            let found = given.iter().filter(|g| g.is_some()).count();
            skipped += usize::from(found == 0);
            partial += usize::from(found > 0 && found < LASERS);
            for (k, g) in given.iter().enumerate() {
                let Some(pos) = g else { continue };
                if let Some(p) = self.tri.profile(k, *pos, r16) {
                    out[k].push((f64::from(p.along_mm), f64::from(p.height_mm)));
                }
            }
        }
        Ok(ImageProfiles { profiles: out, rows_skipped: skipped, rows_partial: partial, method, light })
    }
}

fn detect(
    det: &mut Detector<MAX_ROW>,
    row: Row<'_>,
    out: &mut Stripes<MAX_STRIPES>,
) -> Result<(), cms_core::peak::Error> {
    match row {
        Row::U8(v) => det.detect(v, out),
        Row::U16(v) => det.detect(v, out),
    }
}

/// Per laser, the line's position followed from row to row (px), and the
/// largest distance at which a stripe is taken for it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Lanes {
    at_px: [f64; LASERS],
    gate_px: f64,
}

impl Lanes {
    /// From each line's median position; `None` if two lie together.
    fn new(at_px: [f64; LASERS]) -> Option<Lanes> {
        let spacing = at_px.windows(2).map(|w| w[1] - w[0]).fold(f64::INFINITY, f64::min);
        (spacing > 0.0 && spacing.is_finite()).then_some(Lanes { at_px, gate_px: spacing / 3.0 })
    }
}

/// Each laser's stripe of a row (its position): each stripe to the nearest
/// lane within its gate (a row with one stripe per laser in their lanes is
/// then in position order), the nearer of two; the lanes follow what they
/// are given. Without lanes, only a row with one stripe per laser.
fn assign<const N: usize>(stripes: &Stripes<N>, lanes: Option<&mut Lanes>) -> [Option<Px>; LASERS] {
    let mut out = [None; LASERS];
    let Some(lanes) = lanes else {
        // No lanes (no row had one stripe per laser): only complete rows,
        // in position order.
        if stripes.len() == LASERS {
            let mut sorted: Stripes<N> = stripes.clone();
            sorted.sort_unstable_by_key(|s| s.position);
            for (o, s) in out.iter_mut().zip(&sorted) {
                *o = Some(s.position);
            }
        }
        return out;
    };
    let mut dist = [f64::INFINITY; LASERS];
    for s in stripes {
        let x = s.position.to_f64();
        let (k, d) = (0..LASERS)
            .map(|k| (k, (x - lanes.at_px[k]).abs()))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .expect("LASERS > 0");
        if d <= lanes.gate_px && d < dist[k] {
            (out[k], dist[k]) = (Some(s.position), d);
        }
    }
    for (k, o) in out.iter().enumerate() {
        if let Some(p) = o {
            lanes.at_px[k] = p.to_f64();
        }
    }
    out
}

/// The lanes from the rows with one stripe per laser: each line's median
/// position (`None` if no row has one stripe per laser).
fn lanes_of(det: &mut Detector<MAX_ROW>, rows: &Rows) -> Result<Option<Lanes>, MeasureError> {
    Ok(sample_lines(det, rows)?.1)
}

/// Per line, `(row, stripe strength)` of the sampled rows, in row order.
type Strengths = [Vec<(usize, f64)>; LASERS];

/// Every [`LIGHT_ROW_STEP`]-th row's stripes where a row has one per
/// laser: per line, the strengths in row order; and the lanes.
fn sample_lines(det: &mut Detector<MAX_ROW>, rows: &Rows) -> Result<(Strengths, Option<Lanes>), MeasureError> {
    let mut strengths: Strengths = Default::default();
    let mut positions: [Vec<f64>; LASERS] = Default::default();
    let mut stripes: Stripes<MAX_STRIPES> = Stripes::new();
    for r in (0..rows.height()).step_by(LIGHT_ROW_STEP) {
        let Some(row) = rows.row(r) else { continue };
        det.refresh_noise();
        detect(det, row, &mut stripes).map_err(|source| MeasureError::Row { row: r, source })?;
        if stripes.len() != LASERS {
            continue;
        }
        stripes.sort_unstable_by_key(|s| s.position);
        for (k, s) in stripes.iter().enumerate() {
            strengths[k].push((r, f64::from(s.strength)));
            positions[k].push(s.position.to_f64());
        }
    }
    let lanes =
        if positions[0].is_empty() { None } else { Lanes::new(std::array::from_fn(|k| median(&mut positions[k]))) };
    Ok((strengths, lanes))
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The light of an image from its lines' stripes (the CWT's, at their best
/// scale, on every [`LIGHT_ROW_STEP`]-th row): speckled when the median
/// relative change of a stripe's strength between neighbouring samples
/// exceeds [`SPECKLE_CHANGE`] beyond the sensor noise's share. Also the
/// lanes, for [`Measurer::image_profiles`].
fn judge_light(det: &mut Detector<MAX_ROW>, rows: &Rows) -> Result<(LightJudgement, Option<Lanes>), MeasureError> {
    let (strengths, lanes) = sample_lines(det, rows)?;
    let noise = det.stats().noise_q8.to_f64();
    let mut changes = Vec::new();
    let mut all: Vec<f64> = Vec::new();
    for line in &strengths {
        all.extend(line.iter().map(|s| s.1));
        for w in line.windows(2) {
            let ((r0, a), (r1, b)) = (w[0], w[1]);
            if r1 - r0 == LIGHT_ROW_STEP && a + b > 0.0 {
                changes.push((a - b).abs() / (0.5 * (a + b)));
            }
        }
    }
    if changes.is_empty() {
        return Ok((LightJudgement { change: 0.0, noise_share: 0.0, samples: 0, speckled: false }, lanes));
    }
    let change = median(&mut changes);
    let noise_share = std::f64::consts::SQRT_2 * noise / median(&mut all).max(1.0);
    Ok((
        LightJudgement { change, noise_share, samples: changes.len(), speckled: change > SPECKLE_CHANGE + noise_share },
        lanes,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use cms_core::peak::{Flags, Stripe};

    fn stripes(at: &[f64]) -> Stripes<MAX_STRIPES> {
        at.iter()
            .map(|&x| Stripe { position: Px::from_f64(x), strength: 100, width: Px::from_f64(3.0), flags: Flags::NONE })
            .collect()
    }

    fn lanes() -> Lanes {
        Lanes::new([300.0, 370.0, 440.0]).unwrap()
    }

    #[test]
    fn a_complete_row_goes_in_order() {
        let mut l = lanes();
        let got = assign(&stripes(&[371.0, 301.0, 439.0]), Some(&mut l));
        assert_eq!(got.map(|p| p.map(Px::to_f64)), [Some(301.0), Some(371.0), Some(439.0)]);
        assert_eq!(l.at_px, [301.0, 371.0, 439.0]);
    }

    #[test]
    fn a_missing_line_keeps_the_others() {
        let mut l = lanes();
        let got = assign(&stripes(&[302.0, 441.0]), Some(&mut l));
        assert_eq!(got.map(|p| p.map(Px::to_f64)), [Some(302.0), None, Some(441.0)]);
        // The missing line's lane stays where it was.
        assert_eq!(l.at_px[1], 370.0);
    }

    #[test]
    fn a_stray_between_lines_or_beside_one_is_not_a_line() {
        let mut l = lanes();
        // A ghost midway between lines 0 and 1, and one 3 px beside line 2.
        let got = assign(&stripes(&[300.5, 335.0, 370.5, 440.0, 443.0]), Some(&mut l));
        assert_eq!(got.map(|p| p.map(Px::to_f64)), [Some(300.5), Some(370.5), Some(440.0)]);
    }

    #[test]
    fn without_lanes_only_complete_rows_count() {
        assert_eq!(assign(&stripes(&[300.0, 440.0]), None), [None; LASERS]);
        assert!(assign(&stripes(&[300.0, 370.0, 440.0]), None).iter().all(Option::is_some));
    }

    #[test]
    fn lanes_need_distinct_lines() {
        assert!(Lanes::new([300.0, 300.0, 440.0]).is_none());
        assert!((lanes().gate_px - 70.0 / 3.0).abs() < 1e-12);
    }
}
