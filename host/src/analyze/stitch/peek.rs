//! The profiles stitched so far, read without ending the stitching: what
//! a live view judges while frames still arrive.

use super::{Direction, Registration, StitchError, Stitched, Stitcher, Stitching, gaps, spill};
use crate::analyze::store::Samples;

impl Stitcher {
    /// The profiles of the frames pushed so far, as [`Stitcher::finish`]
    /// would give them (the direction chosen the same way), each lane's
    /// cells copied out; the stitcher goes on taking frames. Cost: one
    /// read of the cells, `O(C)` for C cells of the lanes chosen.
    pub fn peek(&mut self) -> Result<Stitching, StitchError> {
        let (with_points, direction, residuals) = self.choice()?;
        let dx = self.opts.dx_mm;
        let sign = if direction == Direction::Reverse { -1.0 } else { 1.0 };
        let registration: Registration = self.opts.registration;
        let mut lasers = Vec::new();
        for l in self
            .lanes
            .iter_mut()
            .filter(|l| l.sign == sign && l.registration == registration && with_points.contains(&l.laser))
        {
            let Some((lo, hi)) = l.span else { continue };
            let z = l.cells.values(lo..hi + 1).map_err(spill)?;
            let x0_mm = lo as f64 * dx;
            let gaps = gaps(x0_mm, dx, &z);
            lasers.push(Stitched {
                laser: l.laser,
                section: 1,
                x0_mm,
                dx_mm: dx,
                z: Samples::from_vec(z),
                frames: l.frames,
                points: l.points,
                runs_averaged: 1.0,
                fits: l.fits.clone(),
                joins: l.joins.clone(),
                gaps,
            });
        }
        let direction_given = self.opts.direction != Direction::Auto;
        Ok(Stitching { direction, direction_residuals_um: Some(residuals), direction_given, lasers, share: None })
    }

    /// The frames each laser's lane in `direction` joined without
    /// registration so far (too little overlap), in the order pushed
    /// (forward for [`Direction::Auto`]).
    pub fn joins(&self, laser: usize, direction: Direction) -> &[super::Join] {
        let sign = if direction == Direction::Reverse { -1.0 } else { 1.0 };
        self.lanes
            .iter()
            .find(|l| l.laser == laser && l.sign == sign && l.registration == self.opts.registration)
            .map_or(&[], |l| &l.joins)
    }
}
