//! An analysis as one JSON object (`cms-host analyze --json`).

use std::path::Path;

use serde_json::{Value, json};

use crate::analyze::floor::{BandFloor, BandJudgement};
use crate::analyze::standards::{StandardsError, en13231, en15610};
use crate::analyze::stitch::{Direction, Registration};
use crate::analyze::{
    Analysis, LaserAnalysis, Recording, Source, chainage, iso3095_not_evaluated, reprofiling, spectrum_peak, survey,
};

fn verdict_json(v: &reprofiling::ReprofilingVerdict) -> Value {
    let e = v.options.edition;
    json!({
        "edition": e.name(),
        "source": e.source(),
        "reprofile_mm": v.reprofile_mm,
        "measured_mm": v.measured_mm,
        "bands": v.rows.iter().map(|r| json!({
            "lo_mm": r.band.lo_mm,
            "hi_mm": r.band.hi_mm,
            "limit_mm": r.limit_mm,
            "measured_mm": r.measured_mm,
            "exceeding_mm": r.exceeding_mm,
            "exceeding_percent": r.exceeding_percent(),
            "passes": r.passes(e),
            "not_evaluated": r.not_evaluated,
            "judged": r.limit_mm.is_some() && r.not_evaluated.is_none() && r.judgement.not_judged.is_none(),
            "not_judged": r.judgement.not_judged,
            "floor": floor_json(r.judgement.floor.as_ref()),
        })).collect::<Vec<_>>(),
        "zones": v.zones.iter().map(|z| json!({
            "lo_mm": z.band.lo_mm,
            "hi_mm": z.band.hi_mm,
            "start_mm": z.start_mm,
            "end_mm": z.end_mm,
            "start_chainage": chainage(z.start_mm),
            "end_chainage": chainage(z.end_mm),
            "exceeding_mm": z.exceeding_mm,
            "worst_pp_mm": z.worst_pp_mm,
        })).collect::<Vec<_>>(),
        "block_mm": v.options.block_mm,
        "blocks": v.blocks.iter().map(|b| json!({
            "start_mm": b.start_mm,
            "end_mm": b.end_mm,
            "rms_mm": b.rms_mm,
            "floor_rms_mm": b.floor_rms_mm,
            "iso3095": b.iso3095.as_ref().map(iso3095_json),
            "lines": b.iso3095_lines.iter().map(|(laser, i)| json!({
                "laser": laser,
                "iso3095": iso3095_json(i),
            })).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
    })
}

/// A spectrum's ISO 3095 verdict and its third octaves by verdict.
fn iso3095_json(i: &reprofiling::Iso3095) -> Value {
    json!({
        "verdict": i.verdict().map(|v| v.name()),
        "within_mm": i.within_mm,
        "exceeded_mm": i.exceeded_mm,
        "not_judged_mm": i.not_judged_mm,
        "bands": third_octaves_json(&i.bands),
    })
}

fn floor_json(f: Option<&BandFloor>) -> Value {
    match f {
        Some(f) => json!({
            "rms_mm": num(f.rms_mm),
            "average_mean_pp_mm": num(f.average_mean_pp_mm),
            "worst_mean_pp_mm": num(f.worst_mean_pp_mm),
            "peak_mm": num(f.peak_mm),
            "coherence": num(f.coherence),
            "stitch_rms_mm": num(f.stitch_rms_mm),
        }),
        None => Value::Null,
    }
}

/// The survey's noise floor (one line's) and each section's running band.
fn survey_floor_json(a: &Analysis) -> Value {
    let floor = a.floor.as_ref().map(|f| {
        json!({
            "lines": f.lines,
            "measured_mm": f.measured_mm,
            "bands": f.bands.iter().zip(&en13231::BANDS).map(|(b, band)| {
                let mut o = floor_json(b.as_ref());
                if let Value::Object(m) = &mut o {
                    m.insert("lo_mm".into(), json!(band.lo_mm));
                    m.insert("hi_mm".into(), json!(band.hi_mm));
                }
                o
            }).collect::<Vec<_>>(),
            "en15610": f.spectrum.as_ref().map(|s| s.bands.iter().map(|b| json!({
                "nominal_wavelength_mm": b.nominal_wavelength_mm,
                "floor_db": num(b.level_db),
            })).collect::<Vec<_>>()),
            "spikes_per_m": num(f.spikes_per_m),
            "lines_own": f.lines_own.iter().map(|l| json!({
                "laser": l.laser,
                "bands": l.bands.iter().zip(&en13231::BANDS).map(|(b, band)| {
                    let mut o = floor_json(b.as_ref());
                    if let Value::Object(m) = &mut o {
                        m.insert("lo_mm".into(), json!(band.lo_mm));
                        m.insert("hi_mm".into(), json!(band.hi_mm));
                    }
                    o
                }).collect::<Vec<_>>(),
                "en15610": l.spectrum.as_ref().map(|s| s.bands.iter().map(|b| json!({
                    "nominal_wavelength_mm": b.nominal_wavelength_mm,
                    "floor_db": num(b.level_db),
                    "dof": num(b.dof),
                })).collect::<Vec<_>>()),
                "clipped": l.clipped,
            })).collect::<Vec<_>>(),
            "standing_out": f.standing_out().map(|(laser, db)| json!({
                "laser": laser,
                "over_others_db": num(db),
                "likely": crate::analyze::line_floor::LIKELY_CAUSES,
            })),
        })
    });
    let stitch = a.stitching.share.map(|s| {
        en13231::BANDS
            .iter()
            .enumerate()
            .map(|(b, band)| json!({ "lo_mm": band.lo_mm, "hi_mm": band.hi_mm, "rms_mm": s.rms_mm(b).map(num) }))
            .collect::<Vec<_>>()
    });
    json!({
        "floor": floor,
        "stitch": stitch,
        "predicted": super::optics::json(a),
        "running_bands": a.running_bands.iter().map(|rb| json!({
            "section": rb.section,
            "lines": rb.lines,
            "en13231": bands_json(&rb.bands, &rb.judgements),
            "en15610": rb.roughness.as_ref().map(|s| json!({
                "segments": s.segments,
                "bands": third_octaves_json(&s.bands),
            })),
        })).collect::<Vec<_>>(),
    })
}

fn third_octaves_json(bands: &[en15610::ThirdOctave]) -> Vec<Value> {
    bands
        .iter()
        .map(|b| {
            json!({
                "nominal_wavelength_mm": b.nominal_wavelength_mm,
                "wavelength_mm": b.wavelength_mm,
                "level_db": num(b.level_db),
                "iso3095_limit_db": b.iso3095_limit_db,
                "floor_db": b.floor_db.map(num),
                "floor_dof": b.floor_dof.map(num),
                "dof": num(b.dof),
                "decision": b.decision().map(|d| json!({
                    "verdict": d.verdict.name(),
                    "level_hi_db": d.level_hi_db.map(num),
                    "rail_db": d.rail.db.map(num),
                    "rail_lo_db": d.rail.lo_db.map(num),
                    "rail_hi_db": d.rail.hi_db.map(num),
                    "confidence_percent": crate::analyze::standards::detection::CONFIDENCE_PERCENT,
                    "settle": d.settle,
                })),
            })
        })
        .collect()
}

fn num(v: f64) -> Value {
    if v.is_finite() { json!(v) } else { Value::Null }
}

/// How a run was placed with a track register: by what, GNSS's fit or why
/// there is none, the typed start and whether it is disputed.
pub(crate) fn placing_json(p: &crate::analyze::placing::GnssPlacing) -> Value {
    let (fit, why) = match &p.fit {
        Ok(f) => (
            json!({
                "start_m": f.start_m,
                "start_chainage": survey::Chainage(f.start_m).to_string(),
                "heading": f.heading.name(),
                "tolerance_m": f.tolerance_m,
                "fixes": f.fixes,
                "disagreeing": f.disagreeing,
            }),
            Value::Null,
        ),
        Err(why) => (Value::Null, json!(why)),
    };
    json!({
        "run": p.run,
        "placed_by": p.used.name(),
        "gnss": fit,
        "gnss_unavailable": why,
        "typed_start_m": p.typed.start_m,
        "typed_heading": p.typed.heading.map(|h| h.name()),
        "typed_tolerance_m": p.typed_tolerance_m,
        "start_difference_m": p.start_difference_m().map(|(d, _)| d),
        "combined_tolerance_m": p.start_difference_m().map(|(_, t)| t),
        "start_disputed": p.start_disputed(),
        "heading_disputed": p.heading_disputed(),
        "summary": p.to_string(),
    })
}

/// The analysis as one JSON object.
pub fn to_json(source: &Source, a: &Analysis) -> Value {
    let lasers: Vec<Value> = a.lasers.iter().map(laser_json).collect();
    let mut o = source_json(source, a);
    o["dx_mm"] = json!(a.options.stitch.dx_mm);
    o["gnss_placing"] = json!(a.gnss_placing.iter().map(placing_json).collect::<Vec<_>>());
    o["run_joins"] = json!(
        a.joins
            .iter()
            .map(|j| json!({
                "run": j.run,
                "section": j.section,
                "registered": j.registered(),
                "heading": j.heading.name(),
                "heading_found": j.heading_found,
                "heading_disputed": j.heading_disputed.map(|(g, o)| json!({ "given_um": g, "other_um": o })),
                "chainage_disputed": j.elsewhere.map(|(m, c)| json!({ "registration_moved_mm": m, "correlation": c })),
                "direction": match j.direction {
                    Direction::Reverse => "reverse",
                    _ => "forward",
                },
                "direction_disputed": j.direction_disputed.map(|(o, u)| json!({ "other_um": o, "given_um": u })),
                "start_m": j.start_m,
                "start_chainage": survey::Chainage(j.start_m).to_string(),
                "moved_mm": j.moved_mm,
                "overlap_mm": j.overlap_mm,
                "residual_um": j.residual_um,
                "correlation": j.correlation.map(|(b, s)| json!({ "best": b, "second": s })),
                "ambiguous": j.ambiguous(),
            }))
            .collect::<Vec<_>>()
    );
    o["lasers"] = json!(lasers);
    o["sections"] = json!(
        a.sections()
            .iter()
            .map(|sec| {
                let (x0, x1) = sec.span_mm();
                json!({
                    "section": sec.number,
                    "start_mm": x0,
                    "end_mm": x1,
                    "start_chainage": chainage(x0),
                    "end_chainage": chainage(x1),
                    "lasers": sec.lasers.iter().map(|l| l.stitched.laser).collect::<Vec<_>>(),
                    "runs": a.joins.iter().filter(|j| j.section == sec.number).map(|j| j.run).collect::<Vec<_>>(),
                    "runs_averaged": sec.lasers.iter().map(|l| num(l.stitched.runs_averaged)).collect::<Vec<_>>(),
                })
            })
            .collect::<Vec<_>>()
    );
    o["noise"] = survey_floor_json(a);
    o["verdict"] = verdict_json(&a.verdict);
    if matches!(source, Source::Recordings(_)) {
        o["marks"] = super::marks::to_json(&super::marks::of(source, a));
    }
    o
}

/// One laser's stitched profile, EN 13231-3 bands and EN 15610 roughness.
fn laser_json(l: &LaserAnalysis) -> Value {
    let s = &l.stitched;
    json!({
        "laser": s.laser,
        "section": s.section,
        "x0_mm": s.x0_mm,
        "dx_mm": s.dx_mm,
        "samples": s.z.len(),
        "length_mm": s.length_mm(),
        "covered_mm": s.covered_mm(),
        "frames": s.frames,
        "points": s.points,
        "runs_averaged": s.runs_averaged,
        "registered": s.fits.len(),
        "registration_residual_median_um": s.median_residual_um(),
        "offset_rms_um": s.fits.offset_rms_um(),
        "tilt_rms_um_per_mm": s.fits.tilt_rms_um_per_mm(),
        "unregistered_joins": s.joins.iter().map(|j| json!({
            "seq": j.seq, "at_mm": j.at_mm, "overlap_mm": j.overlap_mm,
        })).collect::<Vec<_>>(),
        "gaps": s.gaps.iter().map(|g| json!({ "start_mm": g.start_mm, "length_mm": g.length_mm })).collect::<Vec<_>>(),
        "en13231": bands_json(&l.bands, &l.judgements),
        "en15610": roughness_json(l),
    })
}

/// The EN 13231-3 band analysis of one profile, each band with its floor.
fn bands_json(b: &Result<en13231::BandAnalysis, StandardsError>, judgements: &[BandJudgement]) -> Value {
    match b {
        Ok(b) => json!({
            "record_mm": b.record_mm,
            "runs": b.runs,
            "bands": b.bands.iter().enumerate().map(|(k, r)| {
                let mut o = json!({
                    "lo_mm": r.band.lo_mm, "hi_mm": r.band.hi_mm, "window_mm": r.band.window_mm,
                    "mean_pp_limit_mm": r.band.mean_pp_limit_mm, "edge_mm": r.edge_mm,
                });
                let j = judgements.get(k);
                o["floor"] = floor_json(j.and_then(|j| j.floor.as_ref()));
                o["not_judged"] = json!(j.and_then(|j| j.not_judged.clone()));
                match &r.outcome {
                    Ok(st) => {
                        o["average_mean_pp_mm"] = num(st.average_mean_pp_mm);
                        o["worst_mean_pp_mm"] = num(st.worst_mean_pp_mm);
                        o["worst_max_pp_mm"] = num(st.worst_max_pp_mm);
                        o["rms_mm"] = num(st.rms_mm);
                        o["exceeding_percent"] = num(st.exceeding_percent);
                        o["exceeding_mm"] = num(st.exceeding_mm);
                        o["windows"] = json!(st.windows);
                        let judged = j.is_none_or(|j| j.not_judged.is_none());
                        o["judged"] = json!(judged);
                        o["passes"] = if judged { json!(st.passes) } else { Value::Null };
                        if let Some(p) = st.abs_exceeding_percent {
                            o["abs_limit_mm"] = json!(r.band.abs_limit_mm);
                            o["abs_exceeding_percent"] = num(p);
                        }
                    }
                    Err(e) => o["error"] = json!(e.to_string()),
                }
                o
            }).collect::<Vec<_>>(),
        }),
        Err(e) => json!({ "error": e.to_string() }),
    }
}

/// The EN 15610 roughness of one laser.
fn roughness_json(l: &LaserAnalysis) -> Value {
    match &l.roughness {
        Ok(r) => json!({
            "segments": r.spectrum.segments,
            "segment_mm": r.spectrum.segment_mm,
            "spikes_removed": r.spikes_removed,
            "bands": third_octaves_json(&r.spectrum.bands),
            "not_evaluated": iso3095_not_evaluated(r).iter().map(|(w, why)| json!({
                "nominal_wavelength_mm": w, "why": why,
            })).collect::<Vec<_>>(),
            "peak_wavelength_mm": spectrum_peak(r).map(|p| p.nominal_wavelength_mm),
        }),
        Err(e) => json!({ "error": e.to_string() }),
    }
}

/// What was analysed: the recordings (with the stitching's choices) or
/// the profile file.
fn source_json(source: &Source, a: &Analysis) -> Value {
    match source {
        Source::Recordings(runs) => {
            let mut o = json!({ "runs": runs.iter().map(|(p, r)| recording_json(p, r)).collect::<Vec<_>>() });
            // One recording: its fields at the top as well (as before runs).
            if let [(p, r)] = runs.as_slice()
                && let (Value::Object(top), Value::Object(one)) = (&mut o, recording_json(p, r))
            {
                top.extend(one);
            }
            o["direction"] = json!(match a.stitching.direction {
                Direction::Reverse => "reverse",
                _ => "forward",
            });
            o["direction_given"] = json!(a.stitching.direction_given);
            o["direction_residuals_um"] =
                json!(a.stitching.direction_residuals_um.map(|(f, r)| json!({ "forward": f, "reverse": r })));
            o["registration"] = json!(match a.options.stitch.registration {
                Registration::OffsetTilt => "offset-tilt",
                Registration::Offset => "offset",
                Registration::None => "none",
                Registration::Joint => "joint",
                Registration::JointPitch => "joint-pitch",
            });
            o
        }
        Source::Profile(p, f) => json!({
            "profile": p.display().to_string(),
            "rows": f.rows,
            "columns": f.columns,
            "data_dx_mm": f.data_dx_mm,
            "resampled": f.resampled,
        }),
    }
}

fn recording_json(path: &Path, rec: &Recording) -> Value {
    let (olo, ohi) = rec.odometer_range_mm.unwrap_or((f64::NAN, f64::NAN));
    json!({
        "recording": path.display().to_string(),
        "frames": rec.frames,
        "profiles": rec.profiles,
        "calibrated_points": rec.calibrated_points,
        "uncalibrated_points": rec.uncalibrated_points,
        "calibration_id": rec.calibration_id,
        "slid_across_frames": rec.slid_across.as_ref().map(|(n, _)| n),
        "odometer_mm": [num(olo), num(ohi)],
        "damaged_frames": rec.stats.damaged,
        "duplicate_profiles": rec.stats.duplicates,
        "survey": rec.survey,
        "repeats_run": rec.repeats,
        "other_head_than_run": rec.other_head.as_ref().map(|(k, how)| json!({ "run": k, "difference": how })),
    })
}
