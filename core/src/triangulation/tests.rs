use super::*;
extern crate std;
use std::println;

const A: f64 = 42.0 * core::f64::consts::PI / 180.0;

/// A pinhole at the paper's focal length with an integer principal point,
/// a flat datum 450 mm below and sheets at α = 42° through (x_k, 0, 450):
/// then `O_k = (x_k, 0, 450)` exactly and lies in image row 1584.
fn simple() -> (CameraModel, [Plane; LASERS], Plane) {
    let cam = CameraModel::pinhole(5106.0, 5107.0, 2376.0, 1584.0);
    let (c, s) = (sin(core::f64::consts::FRAC_PI_2 - A), sin(A));
    let lasers = core::array::from_fn(|k| {
        let xk = 25.0 * (k as f64 - 1.0);
        Plane { normal: [-c as f32, 0.0, s as f32], d_mm: (-c * xk + s * 450.0) as f32 }
    });
    (cam, lasers, Plane { normal: [0.0, 0.0, -1.0], d_mm: -450.0 })
}

fn distorted() -> CameraModel {
    let mut cam = simple().0;
    (cam.k1, cam.k2, cam.p1, cam.p2, cam.k3, cam.skew) = (-0.1, 0.05, 1e-4, -1e-4, 0.01, 0.8);
    cam
}

#[test]
fn distort_undistort_round_trip() {
    let (_, lasers, datum) = simple();
    let cam = distorted();
    let t = Triangulator::new(&cam, &lasers, &datum).unwrap();
    let mut worst = 0.0f32;
    for i in -12..=12 {
        for j in -8..=8 {
            let (x, y) = (i as f32 * 0.038, j as f32 * 0.038);
            let [xd, yd] = cam.distort(x, y);
            let u = cam.fx as f64 * xd as f64 + cam.skew as f64 * yd as f64 + cam.cx as f64;
            let v = cam.fy as f64 * yd as f64 + cam.cy as f64;
            let [xu, yu] = t.undistort(Px::from_f64(u), Px::from_f64(v)).unwrap();
            worst = worst.max((xu - x).abs()).max((yu - y).abs());
        }
    }
    // Q16.16 (1.5e-5 px / 5106) plus f32 rounding of the forward model.
    assert!(worst < 2e-7, "{worst}");
}

/// The iteration count: steps until the iterate is within 2 ulp of the
/// f32 fixed point, over |k1| ≤ 0.5, k2, k3 ∈ {0, ±0.05}, |p| ≤ 1e-3 and
/// undistorted radius ≤ 0.7 (every direction).
#[test]
fn undistort_convergence() {
    let mut worst = 0;
    let mut worst_paper = 0;
    let mut worst_clear = 0;
    for k1 in [-0.5f32, -0.3, -0.1, 0.0, 0.1, 0.3, 0.5] {
        for k2 in [-0.05f32, 0.0, 0.05] {
            for k3 in [-0.05f32, 0.0, 0.05] {
                for (p1, p2) in [(0.0f32, 0.0f32), (1e-3, -1e-3), (-1e-3, 1e-3)] {
                    let mut cam = simple().0;
                    (cam.k1, cam.k2, cam.k3, cam.p1, cam.p2) = (k1, k2, k3, p1, p2);
                    for ir in 1..=28 {
                        let r = ir as f32 * 0.025;
                        for ia in 0..24 {
                            let a = ia as f32 * (core::f32::consts::PI / 12.0);
                            let (x, y) = (r * F32(a).cos().0, r * F32(a).sin().0);
                            let [xd, yd] = cam.distort(x, y);
                            let mut e = [0.0f32; 2];
                            let mut path = [[0.0f32; 2]; 12];
                            for p in path.iter_mut() {
                                e = undistort_step(&cam, xd, yd, e).0;
                                *p = e;
                            }
                            let fix = path[11];
                            let tol = 2.0 * f32::EPSILON * (xd + fix[0]).abs().max((yd + fix[1]).abs());
                            let steps = 1 + path
                                .iter()
                                .position(|p| (p[0] - fix[0]).abs() <= tol && (p[1] - fix[1]).abs() <= tol)
                                .unwrap();
                            worst = worst.max(steps);
                            let r2 = r * r;
                            let slope = 1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2 + 7.0 * k3 * r2 * r2 * r2;
                            if slope >= 1.0 / 3.0 {
                                worst_clear = worst_clear.max(steps);
                            }
                            if k1 == -0.1 && r <= 0.56 && p1.abs() <= 1e-3 {
                                worst_paper = worst_paper.max(steps);
                            }
                        }
                    }
                }
            }
        }
    }
    println!(
        "undistortion: ≤ {worst_clear} steps where d r_d/d r ≥ 1/3, ≤ {worst} over the whole grid, \
         ≤ {worst_paper} for k1 = −0.1, r ≤ 0.56"
    );
    assert!(worst_clear < UNDISTORT_STEPS, "{worst_clear}");
    assert!(worst_paper < UNDISTORT_STEPS - 1, "{worst_paper}");
}

#[test]
fn point_on_plane_projects_to_its_pixel() {
    let (_, lasers, datum) = simple();
    for cam in [simple().0, distorted()] {
        let t = Triangulator::new(&cam, &lasers, &datum).unwrap();
        for (k, laser) in lasers.iter().enumerate() {
            let n = laser.normal.map(|v| v as f64);
            for (z, y) in [(350.0, -80.0), (450.0, 10.0), (550.0, 150.0), (400.0, 0.0)] {
                let x = (laser.d_mm as f64 - n[2] * z - n[1] * y) / n[0];
                let [u, v] = cam.project([x as f32, y as f32, z as f32]);
                // Move along the sheet to the integer row.
                let row = v.round();
                let p0 = t.point_mm(k, Px::from_f64(u as f64), row as u16).unwrap();
                let [u1, v1] = cam.project(p0);
                assert!((v1 - row).abs() < 2e-3, "{v1} vs {row}");
                assert!((u1 - u).abs() < 2e-3, "{u1} vs {u}");
                let on_plane = n[0] * p0[0] as f64 + n[1] * p0[1] as f64 + n[2] * p0[2] as f64 - laser.d_mm as f64;
                assert!(on_plane.abs() < 1e-3, "{on_plane}");
                assert!((p0[2] as f64 - z).abs() < 5.0 && (p0[1] as f64 - y).abs() < 5.0);
            }
        }
    }
}

#[test]
fn origin_reads_zero() {
    let (cam, lasers, datum) = simple();
    let t = Triangulator::new(&cam, &lasers, &datum).unwrap();
    for k in 0..LASERS {
        let f = t.frame(k).unwrap();
        let xk = 25.0 * (k as f64 - 1.0);
        assert!(
            (f.origin_mm[0] - xk).abs() < 1e-4 && f.origin_mm[1].abs() < 1e-9 && (f.origin_mm[2] - 450.0).abs() < 1e-4
        );
        assert!(f.along[1] > 0.999);
        let u = 2376.0 + 5106.0 * f.origin_mm[0] / f.origin_mm[2];
        let p = t.profile(k, Px::from_f64(u), 1584).unwrap();
        assert!(p.along_mm.abs() < 1e-4 && p.height_mm.abs() < 1e-4, "{p:?}");
        let x = t.point_mm(k, Px::from_f64(u), 1584).unwrap();
        assert!((x[0] as f64 - f.origin_mm[0]).abs() < 1e-4 && (x[2] as f64 - f.origin_mm[2]).abs() < 1e-4, "{x:?}");
        // One row down: along the line by 450/5107 mm, still on the datum.
        let p = t.profile(k, Px::from_f64(u), 1585).unwrap();
        assert!((p.along_mm - 450.0 / 5107.0).abs() < 1e-4 && p.height_mm.abs() < 1e-4, "{p:?}");
    }
    assert_eq!(t.frame(LASERS), None);
    assert_eq!(t.profile(LASERS, Px::ZERO, 0), None);
}

#[test]
fn misses_give_none() {
    let (cam, lasers, datum) = simple();
    let t = Triangulator::new(&cam, &lasers, &datum).unwrap();
    // Laser 1 is x = 0.9 (z − 450): rays with x/z ≥ 0.9 never meet it in front.
    assert_eq!(t.point_mm(1, Px::from_int(2376 + 5106), 1584), None);
    assert_eq!(t.point_mm(1, Px::from_int(2376 + 5500), 1584), None);
    assert!(t.point_mm(1, Px::from_int(2376 - 5106), 1584).is_some());
    let t = Triangulator::new(&distorted(), &lasers, &datum).unwrap();
    assert_eq!(t.undistort(Px::from_int(30000), Px::from_int(30000)), None);
}

#[test]
fn alpha_and_scale_range() {
    let (cam, lasers, datum) = simple();
    let t = Triangulator::new(&cam, &lasers, &datum).unwrap();
    assert!((t.alpha_deg(0).unwrap() - 42.0).abs() < 1e-5);
    let o = t.optics(1, 2.0, (350.0, 550.0)).unwrap();
    assert_eq!(o.margin, 0.25);
    let r = t.scale_range(2.0, (350.0, 550.0)).unwrap();
    assert!((r.min().to_f64() - 10.649).abs() < 0.003 && (r.max().to_f64() - 21.298).abs() < 0.003, "{r:?}");
    assert_eq!(t.optics(LASERS, 2.0, (350.0, 550.0)), Err(Error::Laser));
    assert_eq!(t.optics(0, 2.0, (550.0, 350.0)), Err(Error::Optics(OpticsError::RangeOrder)));
    assert!((asin(0.5) - core::f64::consts::PI / 6.0).abs() < 1e-15);
    assert!((sqrt64(2.0) - core::f64::consts::SQRT_2).abs() < 1e-15);
}

#[test]
fn validation() {
    let (cam, lasers, datum) = simple();
    let new = |c: &CameraModel, l: &[Plane; LASERS], d: &Plane| Triangulator::new(c, l, d).err();
    assert_eq!(new(&cam, &lasers, &datum), None);

    let mut c = cam;
    c.k2 = f32::NAN;
    assert_eq!(new(&c, &lasers, &datum), Some(Error::NotFinite));
    let mut l = lasers;
    l[2].d_mm = f32::INFINITY;
    assert_eq!(new(&cam, &l, &datum), Some(Error::NotFinite));
    c = cam;
    c.fy = 0.0;
    assert_eq!(new(&c, &lasers, &datum), Some(Error::FocalLength));
    c = cam;
    c.cx = 40000.0;
    assert_eq!(new(&c, &lasers, &datum), Some(Error::PrincipalPoint));

    let mut d = datum;
    d.normal = [0.0, 0.0, -1.01];
    assert_eq!(new(&cam, &lasers, &d), Some(Error::NotUnit { laser: None }));
    l = lasers;
    l[1].normal[0] *= 0.99;
    assert_eq!(new(&cam, &l, &datum), Some(Error::NotUnit { laser: Some(1) }));
    // Within tolerance: renormalised (d scaled alike, same plane).
    l = lasers;
    l[1].normal = l[1].normal.map(|v| v * 1.0005);
    l[1].d_mm *= 1.0005;
    let t = Triangulator::new(&cam, &l, &datum).unwrap();
    let t0 = Triangulator::new(&cam, &lasers, &datum).unwrap();
    let (a, b) = (t.point_mm(1, Px::from_int(2000), 100).unwrap(), t0.point_mm(1, Px::from_int(2000), 100).unwrap());
    assert!((0..3).all(|i| (a[i] - b[i]).abs() < 1e-4), "{a:?} {b:?}");

    // Datum above the camera (normal towards it): d > 0.
    d = datum;
    d.d_mm = 450.0;
    assert_eq!(new(&cam, &lasers, &d), Some(Error::DatumNotBelow));
    // Normal pointing away from the camera.
    d = Plane { normal: [0.0, 0.0, 1.0], d_mm: -450.0 };
    assert_eq!(new(&cam, &lasers, &d), Some(Error::DatumAxis));
    // Datum containing the optical axis direction.
    d = Plane { normal: [0.0, -1.0, 0.0], d_mm: -100.0 };
    assert_eq!(new(&cam, &lasers, &d), Some(Error::DatumAxis));

    l = lasers;
    l[2] = Plane { normal: [0.0, 0.0, -1.0], d_mm: -400.0 };
    assert_eq!(new(&cam, &l, &datum), Some(Error::ParallelToDatum { laser: 2 }));
    l = lasers;
    l[0].d_mm = 0.5;
    assert_eq!(new(&cam, &l, &datum), Some(Error::ThroughCamera { laser: 0 }));
    // A sheet meeting the datum only behind the camera: the laser plane
    // x = −600 (normal −x) meets z = 450 ... in front; make the datum
    // tilted so that their line lies at z < 0.
    d = Plane { normal: [-0.6, 0.0, -0.8], d_mm: -100.0 };
    l = lasers;
    l[0] = Plane { normal: [1.0, 0.0, 0.0], d_mm: 600.0 };
    assert_eq!(new(&cam, &l, &d), Some(Error::OriginBehind { laser: 0 }));
}

#[test]
fn error_display() {
    use std::string::ToString;
    assert!(Error::ParallelToDatum { laser: 2 }.to_string().contains("laser 2"));
    assert!(Error::Optics(OpticsError::Angle).to_string().contains("angle"));
}
