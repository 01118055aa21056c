//! The joint registration's lanes: one solve per direction
//! ([`super::solve`]) whose committed frames go, corrected, into that
//! direction's lane of every line, and whose errors make the stitch's
//! share ([`super::share`]).

use cms_core::protocol::LASERS;

use super::share::{ShareBuilder, StitchShare};
use super::solve::{Cell, Committed, Solver};
use super::{FrameFit, Join, Lane, Options, Registration, StitchError, spill};

/// One direction's joint solve.
pub(super) struct JointSolve {
    pub sign: f64,
    dx_mm: f64,
    solver: Solver,
    share: Option<ShareBuilder>,
}

impl std::fmt::Debug for JointSolve {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("JointSolve").field("sign", &self.sign).field("pending", &self.solver.pending()).finish()
    }
}

impl JointSolve {
    pub fn new(sign: f64, opts: &Options) -> JointSolve {
        let pitch = opts.registration == Registration::JointPitch;
        // One seed per direction: the replicas are the same from run to run.
        let seed = if sign > 0.0 { 0x5eed_f0a4 } else { 0x5eed_0e4e };
        JointSolve {
            sign,
            dx_mm: opts.dx_mm,
            solver: Solver::new(opts.dx_mm, pitch, opts.min_overlap_mm, seed),
            share: Some(ShareBuilder::new(opts.dx_mm)),
        }
    }

    /// Adds a frame's cells (per line); the frames it commits go into `lanes`.
    pub fn push(&mut self, seq: u32, cells: [Vec<Cell>; LASERS], lanes: &mut [Lane]) -> Result<(), StitchError> {
        let done = self.solver.push(seq, cells);
        self.place(&done, lanes)
    }

    /// Commits every frame left; the stitch's share.
    pub fn finish(&mut self, lanes: &mut [Lane]) -> Result<Option<StitchShare>, StitchError> {
        let done = self.solver.finish();
        self.place(&done, lanes)?;
        Ok(self.share.take().map(ShareBuilder::finish))
    }

    fn place(&mut self, done: &[Committed], lanes: &mut [Lane]) -> Result<(), StitchError> {
        for c in done {
            if let Some(s) = &mut self.share {
                s.add(c);
            }
            for lane in lanes.iter_mut().filter(|l| l.sign == self.sign && l.registration.is_joint()) {
                lane.add_committed(c, self.dx_mm)?;
            }
        }
        Ok(())
    }
}

impl Lane {
    /// Adds a committed frame's cells of this lane's line, its correction
    /// subtracted; a fit (residual: the corrected cells against what was
    /// stitched before them) or, when no line overlapped, a join.
    fn add_committed(&mut self, c: &Committed, dx: f64) -> Result<(), StitchError> {
        let cells = &c.cells[self.laser];
        if cells.is_empty() {
            return Ok(());
        }
        let (lo, hi) = (cells[0].0, cells[cells.len() - 1].0);
        self.span = Some(self.span.map_or((lo, hi), |(a, b)| (a.min(lo), b.max(hi))));
        let (o, p) = c.correction;
        let (mut rss, mut n) = (0.0, 0usize);
        for &(cell, v, w) in cells {
            let v = v - (o + p * (cell as f64 * dx - c.centre_mm));
            let (sum, weight) = self.cells.get(cell).map_err(spill)?;
            if weight > 0 {
                rss += (v - sum / weight as f64).powi(2);
                n += 1;
            }
            self.cells.add(cell, v * w as f64, w as u32).map_err(spill)?;
            self.points += w;
        }
        if self.frames > 0 {
            if c.registered {
                self.fits.push(FrameFit {
                    seq: c.seq,
                    centre_mm: c.centre_mm,
                    overlap_mm: c.overlap_mm[self.laser],
                    offset_um: o,
                    tilt_um_per_mm: p,
                    residual_um: if n > 0 { (rss / n as f64).sqrt() } else { f64::NAN },
                });
                if let Some(e) = self.fits.error() {
                    return Err(StitchError::Spill(e.to_string()));
                }
            } else {
                self.joins.push(Join { seq: c.seq, at_mm: lo as f64 * dx, overlap_mm: c.overlap_mm[self.laser] });
            }
        }
        self.frames += 1;
        Ok(())
    }
}
