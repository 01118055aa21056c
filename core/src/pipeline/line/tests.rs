use super::*;
use crate::optics::ScaleRange;

/// Rows of the reference head's frame.
const ROWS: u16 = 480;
/// The reference head: rail per row, mm.
const MM_PER_ROW: f64 = 0.144;

/// A uniform scatter in ±`amp` px, deterministic.
struct Scatter(u32);
impl Scatter {
    fn next(&mut self, amp: f64) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 17;
        self.0 ^= self.0 << 5;
        (f64::from(self.0) / f64::from(u32::MAX) * 2.0 - 1.0) * amp
    }
}

fn point(row: u16, position_px: f64) -> Point {
    Point {
        row,
        position: Px::from_f64(position_px),
        strength: 1000,
        width: Px::from_f64(2.0),
        flags: Flags::NONE,
        metric: None,
    }
}

/// Laser `laser`'s points at `line(row)` for every row, with a uniform
/// scatter of ±`noise_px`.
fn line(laser: u8, noise_px: f64, f: impl Fn(f64) -> f64) -> LaserPoints {
    let mut s = Scatter(0x9e37_79b9 ^ u32::from(laser));
    let mut lp = LaserPoints { laser, points: Vec::new() };
    for r in 0..ROWS {
        lp.points.push(point(r, f(f64::from(r)) + s.next(noise_px))).unwrap();
    }
    lp
}

/// sin of any angle (`optics::sin` holds over ±π/2).
fn sine(x: f64) -> f64 {
    use core::f64::consts::{FRAC_PI_2, PI, TAU};
    let x = x - TAU * ((x + PI) / TAU).floor();
    crate::optics::sin(if x > FRAC_PI_2 {
        PI - x
    } else if x < -FRAC_PI_2 {
        -PI - x
    } else {
        x
    })
}

fn rules() -> Rules {
    let scales = ScaleRange::new(Px::from_f64(1.5), Px::from_f64(4.0)).unwrap();
    Rules::new(&Config::new(12, scales), None)
}

fn rejected(lp: &LaserPoints) -> usize {
    lp.points.iter().filter(|p| p.flags.rejected()).count()
}

fn check(lasers: &mut [LaserPoints], seconds: &[(u8, Point)]) -> Counts {
    let mut c = LineCheck::default();
    c.check(&rules(), lasers, seconds)
}

#[test]
fn a_clean_line_keeps_every_point() {
    // Slanted, bent by the crown, with a detector's scatter under speckle.
    let mut l = [line(0, 0.6, |r| 180.0 + 0.3 * r - 5e-5 * (r - 240.0) * (r - 240.0))];
    let c = check(&mut l, &[]);
    assert_eq!(c, Counts::default());
    // And noiseless: the floor of the bound holds the curvature.
    let mut l = [line(1, 0.0, |r| 300.0 + 0.3 * r - 5e-5 * (r - 240.0) * (r - 240.0))];
    assert_eq!(check(&mut l, &[]), Counts::default());
}

#[test]
fn an_outlier_is_rejected_and_counted() {
    for noise in [0.0, 0.3, 0.6] {
        let mut l = [line(0, noise, |r| 200.0 + 0.1 * r)];
        for (row, off) in [(3u16, 6.0), (100, 5.0), (101, 5.0), (102, -6.0), (250, -7.0), (476, 8.0)] {
            l[0].points[usize::from(row)].position = l[0].points[usize::from(row)].position + Px::from_f64(off);
        }
        let c = check(&mut l, &[]);
        assert_eq!(c.off_line, 6, "noise {noise}: {c:?}");
        for row in [3usize, 100, 101, 102, 250, 476] {
            assert!(l[0].points[row].flags.contains(Flags::OFF_LINE), "row {row}");
        }
        assert_eq!(rejected(&l[0]), 6);
    }
}

#[test]
fn a_glint_is_rejected_and_counted() {
    let mut l = [line(2, 0.2, |r| 500.0 - 0.2 * r)];
    // A specular spot: saturated, σ 0.8 px against a smallest line of 1.5,
    // a pixel off the line (too little for the continuity rule).
    let p = &mut l[0].points[77];
    p.flags = Flags::SATURATED;
    p.width = Px::from_f64(0.8);
    p.position = p.position + Px::from_f64(1.0);
    // A saturated line is as wide as a line: kept.
    let q = &mut l[0].points[300];
    q.flags = Flags::SATURATED;
    q.width = Px::from_f64(2.5);
    let c = check(&mut l, &[]);
    assert_eq!(c, Counts { glint: 1, ..Counts::default() });
    assert!(l[0].points[77].flags.contains(Flags::GLINT));
    assert!(!l[0].points[300].flags.rejected());
}

#[test]
fn a_ghost_line_beside_the_line_loses_to_it() {
    // A weaker reflection 12 px beside the line in every row: the head
    // gives the laser the stripe nearer its track, sometimes the ghost.
    let real = |r: f64| 300.0 + 0.05 * r;
    let ghost = |r: f64| 312.0 + 0.05 * r;
    let mut l = [line(1, 0.3, real)];
    let mut seconds = Seconds::new();
    let mut s = Scatter(7);
    for r in (10..ROWS).step_by(5) {
        let i = usize::from(r);
        let g = point(r, ghost(f64::from(r)) + s.next(0.3));
        // Every other time the ghost came first and took the row.
        if r % 2 == 0 {
            let real_point = l[0].points[i];
            l[0].points[i] = g;
            seconds.push((1, real_point)).unwrap();
        } else {
            seconds.push((1, g)).unwrap();
        }
    }
    let n = seconds.len() as u32;
    let c = check(&mut l, &seconds);
    assert_eq!(c.second_dropped, n);
    assert_eq!(c.rejected(), 0, "{c:?}");
    for p in &l[0].points {
        assert!((p.position.to_f64() - real(f64::from(p.row))).abs() < 1.0, "row {}", p.row);
    }
}

#[test]
fn a_ghost_line_crossing_the_line_loses_to_it() {
    // The ghost crosses the line at row 240; beside it (more than 4 px)
    // the line's candidate must stay.
    let real = |r: f64| 300.0 + 0.05 * r;
    let ghost = |r: f64| 300.0 + 0.05 * r + 0.1 * (240.0 - r);
    let mut l = [line(1, 0.3, real)];
    let mut seconds = Seconds::new();
    for r in (0..ROWS).step_by(6) {
        let g = point(r, ghost(f64::from(r)));
        if (g.position.to_f64() - real(f64::from(r))).abs() < 4.0 {
            continue;
        }
        // The stripe of lower position comes first.
        let i = usize::from(r);
        if g.position < l[0].points[i].position {
            let real_point = l[0].points[i];
            l[0].points[i] = g;
            seconds.push((1, real_point)).unwrap();
        } else {
            seconds.push((1, g)).unwrap();
        }
    }
    let n = seconds.len() as u32;
    let c = check(&mut l, &seconds);
    assert_eq!((c.second_dropped, c.rejected()), (n, 0), "{c:?}");
    for p in &l[0].points {
        assert!((p.position.to_f64() - real(f64::from(p.row))).abs() < 1.0, "row {}", p.row);
    }
}

#[test]
fn a_short_ghost_run_is_off_the_line() {
    // Three rows where the ghost took the line's place (the line was dark).
    let mut l = [line(1, 0.4, |r| 300.0 + 0.05 * r)];
    for r in 200..203 {
        l[0].points[r].position = l[0].points[r].position + Px::from_f64(10.0);
    }
    let c = check(&mut l, &[]);
    assert_eq!(c.off_line, 3, "{c:?}");
}

#[test]
fn a_ghost_outside_the_band_is_rejected() {
    let mut r = rules();
    r.bands[0] = Some(Band { lo_px: Px::from_int(150), hi_px: Px::from_int(250), slope_q16: Px::from_f64(0.1).0 });
    let mut l = [line(0, 0.2, |r| 200.0 + 0.1 * r)];
    // Another laser's stripe taken for this one's: 60 px right.
    l[0].points[50].position = l[0].points[50].position + Px::from_int(60);
    let c = LineCheck::default().check(&r, &mut l, &[]);
    assert_eq!(c, Counts { ghost: 1, ..Counts::default() });
    assert!(l[0].points[50].flags.contains(Flags::GHOST));
    assert!(r.bands[0].unwrap().contains(479, Px::from_f64(247.0 + 47.9)));
    assert!(!r.bands[0].unwrap().contains(479, Px::from_f64(253.0 + 47.9)));
}

#[test]
fn a_real_step_is_kept() {
    for step in [-8.0, 3.0, 6.0, 20.0] {
        let mut l = [line(0, 0.4, move |r| 200.0 + 0.1 * r + if r >= 240.0 { step } else { 0.0 })];
        assert_eq!(check(&mut l, &[]), Counts::default(), "step {step}");
    }
}

#[test]
fn a_steep_smooth_corrugation_is_kept() {
    // 10 mm wavelength, 200 µm amplitude at 0.144 mm per row, seen at the
    // reference head's 4.9 px per mm and at the synthetic scene's 20.
    for px_per_mm in [4.9, 20.0] {
        for noise in [0.0, 0.3] {
            let a = 0.2 * px_per_mm;
            let w = core::f64::consts::TAU * MM_PER_ROW / 10.0;
            let mut l = [line(0, noise, move |r| 200.0 + 0.1 * r + a * sine(w * r))];
            assert_eq!(check(&mut l, &[]), Counts::default(), "{px_per_mm} px/mm, noise {noise}");
        }
    }
}

#[test]
fn few_points_are_not_judged() {
    let mut l = [line(0, 0.0, |r| 200.0 + 0.1 * r)];
    l[0].points.truncate(12);
    l[0].points[5].position = Px::from_int(260);
    assert_eq!(check(&mut l, &[]), Counts::default());
    let mut empty = [LaserPoints { laser: 0, points: Vec::new() }];
    assert_eq!(check(&mut empty, &[]), Counts::default());
}

#[test]
fn the_reference_calibration_bands_hold_its_lines() {
    // Laser k's plane tilted in x, the camera 300 mm above a flat datum.
    let c = Calibration {
        id: 1,
        intrinsics: [1400.0, 1400.0, 376.0, 240.0, 0.0],
        distortion: [0.0; 5],
        planes: [[0.9397, 0.0, 0.342, 90.0], [0.9397, 0.0, 0.342, 102.6], [0.9397, 0.0, 0.342, 115.2]],
        datum: [0.0, 0.0, 1.0, 300.0],
    };
    let b = bands(&c);
    for (k, band) in b.iter().enumerate() {
        let band = band.unwrap();
        let [nx, _, nz, d] = c.planes[k];
        let u = |z: f32| 376.0 + 1400.0 * (d / z - nz) / nx;
        // The working depth: 300 mm ± 25 %.
        for z in [225.0f32, 300.0, 375.0] {
            assert!(band.contains(0, Px::from_f64(f64::from(u(z)))), "laser {k}, z {z}");
            assert!(band.contains(479, Px::from_f64(f64::from(u(z)))), "laser {k}, z {z}");
        }
        assert!(!band.contains(0, Px::from_f64(f64::from(u(225.0)) + 9.0)));
        assert!(!band.contains(0, Px::from_f64(f64::from(u(375.0)) - 9.0)));
    }
}
