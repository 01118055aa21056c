//! A row's stripes to the lit lasers' points, and their triangulation.

use super::line;
use crate::fixed::{Px, Q16_16, Q48_16};
use crate::peak::Stripes;
use crate::protocol::{LASERS, LaserPoints, Metric, Point};
use crate::triangulation::Triangulator;
use heapless::Vec;

/// Assigns a row's stripes to the lit lasers: in order when every lit laser
/// has one stripe (the lasers are mounted left to right in laser order),
/// otherwise each stripe to the lit laser whose last position is nearest.
/// A stripe for a laser that already has this row's point is a second
/// candidate (the weaker of the two), kept in `seconds` for the line pass
/// ([`line::LineCheck`]) to judge; with `seconds` full it is dropped and the kept point says so
/// ([`Flags::SECOND_DROPPED`](crate::peak::Flags::SECOND_DROPPED)).
/// The head's assignment, public so that a simulation can give its points
/// to the lasers as the head does.
pub fn assign<const N: usize>(
    stripes: &Stripes<N>,
    lit: usize,
    track: &mut [Px; LASERS],
    out: &mut Vec<LaserPoints, LASERS>,
    row: u16,
    seconds: &mut line::Seconds,
) {
    let point = |s: &crate::peak::Stripe| Point {
        row,
        position: s.position,
        strength: s.strength.min(u16::MAX as u32) as u16,
        width: s.width,
        flags: s.flags,
        metric: None,
    };
    if stripes.len() == lit {
        for (s, lp) in stripes.iter().zip(out.iter_mut()) {
            track[lp.laser as usize] = s.position;
            let _ = lp.points.push(point(s));
        }
        return;
    }
    for s in stripes {
        let Some(lp) = out.iter_mut().min_by_key(|lp| track[lp.laser as usize].abs_diff(s.position)) else {
            continue;
        };
        match lp.points.last_mut() {
            Some(p) if p.row == row => {
                // The stronger is the row's point (a secondary reflection
                // is weaker than the line, but for speckle): the line pass
                // then has the line in most rows to judge the others by.
                let mut second = point(s);
                if second.strength > p.strength {
                    core::mem::swap(p, &mut second);
                    track[lp.laser as usize] = s.position;
                }
                if seconds.push((lp.laser, second)).is_err() {
                    p.flags.insert(crate::peak::Flags::SECOND_DROPPED);
                }
            }
            _ => {
                track[lp.laser as usize] = s.position;
                let _ = lp.points.push(point(s));
            }
        }
    }
}

/// Fills in the triangulated point of each laser's point of this row, and
/// of the row's second candidates (sensor row `row`, its centre `centre`
/// rows below: a binned row's).
pub(super) fn triangulate(
    t: &Triangulator,
    out: &mut Vec<LaserPoints, LASERS>,
    seconds: &mut line::Seconds,
    row: u16,
    centre: Q16_16,
) {
    let metric = |laser: u8, p: &Point| {
        let at = if centre == Q16_16::ZERO {
            t.profile(laser as usize, p.position, row)
        } else {
            t.profile_at(laser as usize, p.position, Q48_16((i64::from(row) << 16) + i64::from(centre.0)))
        };
        at.map(|q| Metric { along_um: round_i32(q.along_mm * 1e3), height_nm: round_i32(q.height_mm * 1e6) })
    };
    for lp in out.iter_mut() {
        if let Some(p) = lp.points.last_mut()
            && p.row == row
        {
            p.metric = metric(lp.laser, p);
        }
    }
    for (laser, p) in seconds.iter_mut().rev().take_while(|(_, p)| p.row == row) {
        p.metric = metric(*laser, p);
    }
}

/// Nearest integer, saturating (`as` saturates and truncates towards zero;
/// `core` has no `f32::round`).
fn round_i32(v: f32) -> i32 {
    if v >= 0.0 { (v + 0.5) as i32 } else { (v - 0.5) as i32 }
}
