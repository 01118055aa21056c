//! The head's line pass on frames with what real light adds: a ghost line
//! beside a laser's own, a few rows where the ghost outshines the line, a
//! glint. What is not a line is flagged in the profile (and counted),
//! nothing else is.

use super::*;
use cms_core::peak::Flags;
use cms_core::pipeline::line::Counts;

/// Cam's three lines, plus a ghost of laser 1 `ghost_px` beside its line (if any) at
/// 40 % of its height and 1.5 × its width; in `dark_rows` laser 1's line is
/// dimmed to `dark` (a speckle or oxidation minimum: the ghost is then the
/// stronger); a saturating glint σ 0.8 px on laser 2's line, 1.5 px off
/// its centre, in `glint_rows`.
struct GhostCam {
    rng: Rng,
    row: u16,
    mask: u8,
    ghost_px: Option<f64>,
    dark_rows: std::ops::Range<u16>,
    /// Laser 1's line's height in `dark_rows`, counts.
    dark: f64,
    glint_rows: std::ops::Range<u16>,
}

impl GhostCam {
    fn new(ghost_px: Option<f64>) -> GhostCam {
        GhostCam { rng: Rng::new(3), row: 0, mask: 0, ghost_px, dark_rows: 0..0, dark: 300.0, glint_rows: 0..0 }
    }
}

impl Camera for GhostCam {
    type Error = ();
    fn width(&self) -> u16 {
        752
    }
    fn height(&self) -> u16 {
        480
    }
    fn bits(&self) -> u8 {
        12
    }
    fn expose(&mut self, _exposure_us: u32, laser_mask: u8) -> Result<i64, ()> {
        self.row = 0;
        self.mask = laser_mask;
        Ok(0)
    }
    fn read_row(&mut self, out: &mut [u16]) -> Result<(), ()> {
        let r = self.row;
        let mut stripes: Vec<Gauss> = Vec::new();
        for k in (0..3).filter(|k| self.mask & (1 << k) != 0) {
            let mut amplitude = [2500.0, 1500.0, 900.0][k];
            if let (1, Some(g)) = (k, self.ghost_px) {
                stripes.push(Gauss { x0: Cam::truth(r, 1) + g, sigma: 3.75, amplitude: 600.0 });
                if self.dark_rows.contains(&r) {
                    amplitude = self.dark;
                }
            }
            stripes.push(Gauss { x0: Cam::truth(r, k), sigma: 2.5, amplitude });
            if k == 2 && self.glint_rows.contains(&r) {
                stripes.push(Gauss { x0: Cam::truth(r, 2) + 1.5, sigma: 0.8, amplitude: 30_000.0 });
            }
        }
        let row = quantise(&clean_row(752, 150.0, &stripes), 4.0, 12, &mut self.rng);
        out.copy_from_slice(&row);
        self.row += 1;
        Ok(())
    }
}

/// One streamed frame of `cam` with lasers `mask` lit (in turn when
/// `sequential`, the first of them), calibrated: its profile and the
/// head's counts.
fn frame(cam: &mut GhostCam, mask: u8, sequential: bool) -> (Profile, Counts) {
    let (mut h, _l) = head();
    h.handle(cmd(1, HostMsg::SetCalibration(calibration(9))), 0, cam, &mut |_| {});
    let pattern = if sequential { LaserPattern::Sequential } else { LaserPattern::Simultaneous };
    h.handle(cmd(2, start(mask, pattern)), 0, cam, &mut |_| {});
    let mut profile = None;
    h.poll(0, cam, &mut || 0, &mut |m| {
        if let DeviceMsg::Profile(p) = m {
            profile = Some(p.clone());
        }
    });
    let p = profile.expect("a profile");
    // What the head counted is what its profile's flags say, and what a
    // host decodes from the wire.
    assert_eq!(h.line_counts(), Counts::of(&p.lasers));
    let mut buf = vec![0u8; MAX_FRAME];
    let bytes = encode(&DeviceMsg::Profile(p.clone()), &mut buf).unwrap().to_vec();
    let mut f = bytes[..bytes.len() - 1].to_vec();
    match decode_frame::<DeviceMsg>(&mut f).unwrap() {
        DeviceMsg::Profile(q) => assert_eq!(Counts::of(&q.lasers), Counts::of(&p.lasers)),
        other => panic!("{other:?}"),
    }
    (p, h.line_counts())
}

/// Every point of `p` not rejected lies on its laser's true line.
fn kept_on_the_lines(p: &Profile) {
    for lp in &p.lasers {
        for q in lp.points.iter().filter(|q| !q.flags.rejected()) {
            let e = q.position.to_f64() - Cam::truth(q.row, usize::from(lp.laser));
            assert!(e.abs() < 1.0, "laser {} row {}: {e:+.2} px off, {:?}", lp.laser, q.row, q.flags);
        }
    }
}

#[test]
fn a_clean_frame_loses_nothing() {
    let (p, c) = frame(&mut GhostCam::new(None), 0b111, false);
    assert_eq!(c, Counts::default());
    assert_eq!(p.lasers.iter().map(|l| l.points.len()).sum::<usize>(), 3 * 480);
    kept_on_the_lines(&p);
}

#[test]
fn where_the_ghost_outshines_the_line_its_points_are_rejected() {
    let mut cam = GhostCam::new(Some(14.0));
    cam.dark_rows = 200..204;
    let (p, c) = frame(&mut cam, 0b111, false);
    // The head took the ghost for laser 1 in the dark rows: off the line,
    // flagged, counted; every other row's point is the line's.
    let l1 = &p.lasers[1];
    for r in 200..204u16 {
        let q = l1.points.iter().find(|q| q.row == r).expect("a point");
        assert!(q.flags.contains(Flags::OFF_LINE), "row {r}: {q:?}");
    }
    assert_eq!(c, Counts { off_line: 4, ..Counts::default() }, "{c:?}");
    assert_eq!(p.lasers.iter().map(|l| l.points.len()).sum::<usize>(), 3 * 480, "nothing dropped");
    kept_on_the_lines(&p);
}

#[test]
fn a_glint_on_the_line_is_rejected() {
    let mut cam = GhostCam::new(None);
    cam.glint_rows = 300..302;
    let (p, c) = frame(&mut cam, 0b111, false);
    for r in 300..302u16 {
        let q = p.lasers[2].points.iter().find(|q| q.row == r).expect("a point");
        assert!(q.flags.contains(Flags::SATURATED) && q.flags.contains(Flags::GLINT), "row {r}: {q:?}");
    }
    assert_eq!(c, Counts { glint: 2, ..Counts::default() }, "{c:?}");
    kept_on_the_lines(&p);
}

#[test]
fn one_laser_lit_keeps_its_line_and_drops_the_ghost_beside_it() {
    // Laser 1 alone (sequential pattern): its row has two stripes, the
    // ghost first (left of the line), and in a few rows the stronger; the
    // line pass keeps the line's.
    let mut cam = GhostCam::new(Some(-20.0));
    cam.dark_rows = 200..204;
    cam.dark = 500.0;
    let (p, c) = frame(&mut cam, 0b010, true);
    assert_eq!(p.lasers.len(), 1);
    assert_eq!(p.lasers[0].points.len(), 480);
    // The rows where the detector told the ghost from the line (most of
    // them): each kept the line's stripe and says a second was dropped.
    assert_eq!(c.rejected(), 0, "{c:?}");
    assert!(c.second_dropped >= 240, "{c:?}");
    kept_on_the_lines(&p);
}
