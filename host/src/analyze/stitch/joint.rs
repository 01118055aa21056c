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

#[cfg(test)]
mod tests {
    use super::super::{FramePoints, Options, Registration, stitch};
    use crate::analyze::standards::en13231;

    /// Frames of 68 mm every 33 mm along 4 m of rail, three lines, 2 µm
    /// of noise a point; each frame moved by `bounce(i)` (all its lines).
    fn frames(bounce: &dyn Fn(usize) -> f64) -> Vec<FramePoints> {
        let rail = |x: f64| 30.0 * (x / 50.0 * std::f64::consts::TAU).sin() + 8.0 * (x / 173.0).cos();
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut gauss = move || {
            let mut u = || {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                ((s >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (a, b) = (u(), u());
            (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        };
        (0..120)
            .map(|i| {
                let o = 33.0 * i as f64;
                let mut f = FramePoints { seq: i as u32, odometer_mm: o, ..FramePoints::default() };
                for line in &mut f.lasers {
                    *line = (0..476)
                        .map(|j| -34.0 + j as f64 * 0.143)
                        .map(|a| (a, rail(o + a) + bounce(i) + 2.0 * gauss()))
                        .collect();
                }
                f
            })
            .collect()
    }

    /// A bouncing head (±20 µm a frame): the joint solve takes the bounce
    /// out, and what it leaves in the lines' mean — the stitched profile
    /// against the same frames unbounced and unregistered — is what its
    /// propagated share says, band by band.
    #[test]
    fn a_bouncing_head_is_recovered_to_its_propagated_share() {
        let bounce = |i: usize| 20.0 * (((i * 7919) % 17) as f64 / 8.0 - 1.0);
        let joint = Options { registration: Registration::Joint, ..Options::default() };
        let none = Options { registration: Registration::None, ..Options::default() };
        let got = stitch(&frames(&bounce), &joint).unwrap();
        let truth = stitch(&frames(&|_| 0.0), &none).unwrap();
        let share = got.share.expect("a joint solve's share");
        let mean = |s: &super::super::Stitching| -> Vec<f64> {
            let z: Vec<Vec<f64>> = s.lasers.iter().map(|l| l.z.to_vec().unwrap()).collect();
            (0..z[0].len()).map(|i| z.iter().map(|l| l[i]).sum::<f64>() / 3.0).collect()
        };
        let diff: Vec<f64> = mean(&got).iter().zip(mean(&truth)).map(|(a, b)| a - b).collect();
        for (b, band) in en13231::BANDS.iter().enumerate().take(3) {
            let f = en13231::band_pass(&diff, 1.0, band.lo_mm, band.hi_mm).unwrap();
            let rms = (f.iter().map(|v| v * v).sum::<f64>() / f.len() as f64).sqrt() / 1000.0;
            let want = share.rms_mm(b).unwrap();
            eprintln!("band {b}: error {rms:.2e} mm, propagated {want:.2e} mm");
            assert!((0.5..2.0).contains(&(rms / want)), "band {b}: error {rms} mm, propagated {want} mm");
        }
    }

    /// Per band, the RMS (mm) of line `k` (or of the lines' mean, `None`)
    /// of `got` minus `truth`.
    fn band_error(got: &super::super::Stitching, truth: &super::super::Stitching, k: Option<usize>) -> Vec<f64> {
        let line = |s: &super::super::Stitching| -> Vec<f64> {
            let z: Vec<Vec<f64>> = s.lasers.iter().map(|l| l.z.to_vec().unwrap()).collect();
            match k {
                Some(k) => z[k].clone(),
                None => (0..z[0].len()).map(|i| z.iter().map(|l| l[i]).sum::<f64>() / 3.0).collect(),
            }
        };
        let diff: Vec<f64> = line(got).iter().zip(line(truth)).map(|(a, b)| a - b).collect();
        en13231::BANDS
            .iter()
            .take(3)
            .map(|band| {
                let f = en13231::band_pass(&diff, 1.0, band.lo_mm, band.hi_mm).unwrap();
                (f.iter().map(|v| v * v).sum::<f64>() / f.len() as f64).sqrt() / 1000.0
            })
            .collect()
    }

    /// The same bouncing head through each registration: the joint solve
    /// leaves each line less than registering each line on its own does
    /// (three lines' overlaps estimate one offset), and the lines' mean
    /// no more.
    #[test]
    fn the_joint_solve_leaves_each_line_less_than_lines_on_their_own() {
        let bounce = |i: usize| 20.0 * (((i * 7919) % 17) as f64 / 8.0 - 1.0);
        let truth =
            stitch(&frames(&|_| 0.0), &Options { registration: Registration::None, ..Options::default() }).unwrap();
        let run = |registration| {
            let s = stitch(&frames(&bounce), &Options { registration, ..Options::default() }).unwrap();
            let (line, mean) = (band_error(&s, &truth, Some(0)), band_error(&s, &truth, None));
            eprintln!("{registration:?}: line 0 {line:?} mm, mean {mean:?} mm");
            (line, mean)
        };
        let (offset, joint) = (run(Registration::Offset), run(Registration::Joint));
        for b in 0..3 {
            assert!(joint.0[b] < 0.8 * offset.0[b], "band {b}: line 0 {} vs {}", joint.0[b], offset.0[b]);
            assert!(joint.1[b] < 1.2 * offset.1[b], "band {b}: mean {} vs {}", joint.1[b], offset.1[b]);
        }
    }
}
