//! `cms_core::triangulation` (f32, on the head) against an independent f64
//! reference at the paper's geometry (Table 4): 4752 × 3168 px, fx = 5106,
//! fy = 5107, principal point at the centre, α = 42°, camera 450 mm above the
//! rail, working range 350–550 mm.
//!
//! Each sample: a random laser, image row and depth in the working range; the
//! point of that laser plane at that depth seen in that row is projected
//! (f64) to its column, quantised to Q16.16, and that same `Px` is fed to the
//! core and to the reference. Done when max |Δalong|, |Δheight| and |ΔX| are
//! all ≤ 0.1 µm. Run with `--nocapture` to see the measured max and RMS.

use cms_core::fixed::Px;
use cms_core::protocol::LASERS;
use cms_core::triangulation::{CameraModel, Plane, Triangulator};
use cms_tests::Rng;
use proptest::prelude::*;

const WIDTH: f64 = 4752.0;
const HEIGHT: f64 = 3168.0;
const LIMIT_MM: f64 = 1e-4; // 0.1 µm

fn camera(distorted: bool) -> CameraModel {
    let mut c = CameraModel::pinhole(5106.0, 5107.0, ((WIDTH - 1.0) / 2.0) as f32, ((HEIGHT - 1.0) / 2.0) as f32);
    if distorted {
        c.k1 = -0.1;
        c.k2 = 0.05;
        c.p1 = 1e-4;
        c.p2 = -1e-4;
        c.k3 = 0.0;
        c.skew = 0.8;
    }
    c
}

fn unit(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The datum: slightly tilted, through (0, 0, 450), normal towards the camera.
fn datum() -> Plane {
    let n = unit([0.02, -0.03, -1.0]);
    Plane { normal: n.map(|v| v as f32), d_mm: (n[2] * 450.0) as f32 }
}

/// Three laser sheets at α = 42° to the optical axis, nearly containing the
/// image's y direction, crossing the optical axis region at x = −25, 0, 25 mm.
fn lasers() -> [Plane; LASERS] {
    let a = 42f64.to_radians();
    core::array::from_fn(|k| {
        let yaw = 0.03 * (k as f64 - 1.0);
        let n = unit([-a.cos() * yaw.cos(), a.cos() * yaw.sin(), a.sin()]);
        let p = [25.0 * (k as f64 - 1.0), 0.0, 450.0];
        Plane { normal: n.map(|v| v as f32), d_mm: dot(n, p) as f32 }
    })
}

/// f64 model from the same f32 parameters.
struct Reference {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    skew: f64,
    k: [f64; 5], // k1 k2 p1 p2 k3
    planes: [([f64; 3], f64); LASERS],
    up: [f64; 3],
    d_r: f64,
    frames: [([f64; 3], [f64; 3]); LASERS], // origin, along
}

fn f64s<const N: usize>(a: [f32; N]) -> [f64; N] {
    a.map(|v| v as f64)
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn det3(m: [[f64; 3]; 3]) -> f64 {
    dot(m[0], cross(m[1], m[2]))
}

impl Reference {
    fn new(c: &CameraModel, lasers: &[Plane; LASERS], datum: &Plane) -> Self {
        let nr_raw = f64s(datum.normal);
        let len = dot(nr_raw, nr_raw).sqrt();
        let up = nr_raw.map(|v| v / len);
        let d_r = datum.d_mm as f64 / len;
        let planes = lasers.map(|p| (f64s(p.normal), p.d_mm as f64));
        let p_axis = [0.0, 0.0, d_r / up[2]];
        let frames = planes.map(|(n, d)| {
            let mut a = unit(cross(n, up));
            if a[1] < 0.0 {
                a = a.map(|v| -v);
            }
            // The point of the line with a·X = a·P: the closest one to P.
            // Cramer's rule on [n; up; a] X = [d, d_r, a·P].
            let rows = [n, up, a];
            let rhs = [d, d_r, dot(a, p_axis)];
            let det = det3(rows);
            let col = |j: usize| {
                let mut m = rows;
                for i in 0..3 {
                    m[i][j] = rhs[i];
                }
                det3(m) / det
            };
            ([col(0), col(1), col(2)], a)
        });
        Reference {
            fx: c.fx as f64,
            fy: c.fy as f64,
            cx: c.cx as f64,
            cy: c.cy as f64,
            skew: c.skew as f64,
            k: f64s([c.k1, c.k2, c.p1, c.p2, c.k3]),
            planes,
            up,
            d_r,
            frames,
        }
    }

    fn distort(&self, x: f64, y: f64) -> [f64; 2] {
        let [k1, k2, p1, p2, k3] = self.k;
        let r2 = x * x + y * y;
        let k = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
        [x * k + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x), y * k + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y]
    }

    fn project(&self, p: [f64; 3]) -> [f64; 2] {
        let [xd, yd] = self.distort(p[0] / p[2], p[1] / p[2]);
        [self.fx * xd + self.skew * yd + self.cx, self.fy * yd + self.cy]
    }

    /// Undistortion by Newton with a central-difference Jacobian, to f64 precision.
    fn undistort(&self, u: f64, v: f64) -> [f64; 2] {
        let yd = (v - self.cy) / self.fy;
        let xd = (u - self.cx - self.skew * yd) / self.fx;
        let (mut x, mut y) = (xd, yd);
        for _ in 0..100 {
            let [fx, fy] = self.distort(x, y);
            let (rx, ry) = (fx - xd, fy - yd);
            let h = 1e-6;
            let [a, b] = self.distort(x + h, y);
            let [c, d] = self.distort(x - h, y);
            let [e, f] = self.distort(x, y + h);
            let [g, i] = self.distort(x, y - h);
            let (j11, j21, j12, j22) =
                ((a - c) / (2.0 * h), (b - d) / (2.0 * h), (e - g) / (2.0 * h), (f - i) / (2.0 * h));
            let det = j11 * j22 - j12 * j21;
            let dx = (j22 * rx - j12 * ry) / det;
            let dy = (j11 * ry - j21 * rx) / det;
            x -= dx;
            y -= dy;
            if dx.abs() < 1e-17 && dy.abs() < 1e-17 {
                break;
            }
        }
        [x, y]
    }

    /// Naive: X = t r, t = d / (n·r).
    fn point(&self, laser: usize, u: f64, row: f64) -> [f64; 3] {
        let [x, y] = self.undistort(u, row);
        let (n, d) = self.planes[laser];
        let r = [x, y, 1.0];
        let t = d / dot(n, r);
        r.map(|v| v * t)
    }

    fn profile(&self, laser: usize, p: [f64; 3]) -> (f64, f64) {
        let (o, a) = self.frames[laser];
        let rel = [p[0] - o[0], p[1] - o[1], p[2] - o[2]];
        (dot(a, rel), dot(self.up, p) - self.d_r)
    }

    /// The column where laser `laser`'s sheet at depth `z` is seen in image
    /// row `row` (None if out of the image).
    fn column(&self, laser: usize, row: f64, z: f64) -> Option<f64> {
        let (n, d) = self.planes[laser];
        // On the plane at depth z: x = (d/z − n_z − n_y y) / n_x; find y so
        // that the projection is in `row` (secant on y).
        let at = |y: f64| {
            let x = (d / z - n[2] - n[1] * y) / n[0];
            self.project([x * z, y * z, z])
        };
        let (mut y0, mut y1) = ((row - self.cy) / self.fy, (row - self.cy) / self.fy + 1e-4);
        let (mut f0, mut f1) = (at(y0)[1] - row, at(y1)[1] - row);
        for _ in 0..60 {
            if f1 == f0 {
                break;
            }
            let y2 = y1 - f1 * (y1 - y0) / (f1 - f0);
            (y0, f0) = (y1, f1);
            y1 = y2;
            f1 = at(y1)[1] - row;
            if f1.abs() < 1e-12 {
                break;
            }
        }
        assert!(f1.abs() < 1e-9, "row not reached: {f1}");
        let u = at(y1)[0];
        (0.0..=WIDTH - 1.0).contains(&u).then_some(u)
    }
}

#[derive(Default)]
struct Stat {
    max: f64,
    sum2: f64,
    n: usize,
}

impl Stat {
    fn add(&mut self, e: f64) {
        self.max = self.max.max(e.abs());
        self.sum2 += e * e;
        self.n += 1;
    }
    fn rms(&self) -> f64 {
        (self.sum2 / self.n as f64).sqrt()
    }
}

fn run(distorted: bool, samples: usize, seed: u64) {
    let cam = camera(distorted);
    let lasers = lasers();
    let datum = datum();
    let tri = Triangulator::new(&cam, &lasers, &datum).unwrap();
    let reference = Reference::new(&cam, &lasers, &datum);
    let mut rng = Rng::new(seed);
    let (mut along, mut height, mut point, mut naive) =
        (Stat::default(), Stat::default(), Stat::default(), Stat::default());
    let (mut naive_along, mut naive_height) = (Stat::default(), Stat::default());
    let mut depth_range = (f64::MAX, f64::MIN);
    let mut skipped = 0;
    while point.n < samples {
        let laser = (rng.next_u64() % LASERS as u64) as usize;
        let row = (rng.next_u64() % HEIGHT as u64) as u16;
        let z = 350.0 + 200.0 * rng.uniform();
        let Some(u) = reference.column(laser, row as f64, z) else {
            skipped += 1;
            continue;
        };
        let px = Px::from_f64(u);
        let want = reference.point(laser, px.to_f64(), row as f64);
        let (want_along, want_height) = reference.profile(laser, want);
        depth_range = (depth_range.0.min(want[2]), depth_range.1.max(want[2]));

        let got = tri.point_mm(laser, px, row).expect("point in range");
        let prof = tri.profile(laser, px, row).expect("profile in range");
        let d: Vec<f64> = (0..3).map(|i| got[i] as f64 - want[i]).collect();
        point.add((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt());
        along.add(prof.along_mm as f64 - want_along);
        height.add(prof.height_mm as f64 - want_height);

        // The naive f32 formula on the core's own undistorted point, for comparison.
        let [x, y] = tri.undistort(px, Px::from_int(row as i32)).unwrap();
        let n = lasers[laser].normal;
        let t = lasers[laser].d_mm / (n[0] * x + n[1] * y + n[2]);
        let nv = [t * x, t * y, t];
        let dn: Vec<f64> = (0..3).map(|i| nv[i] as f64 - want[i]).collect();
        naive.add((dn[0] * dn[0] + dn[1] * dn[1] + dn[2] * dn[2]).sqrt());
        // … and its profile coordinates in f32 from the absolute point.
        let f = tri.frame(laser).unwrap();
        let (o, a, up) = (f.origin_mm.map(|v| v as f32), f.along.map(|v| v as f32), f.up.map(|v| v as f32));
        let rel = [nv[0] - o[0], nv[1] - o[1], nv[2] - o[2]];
        naive_along.add((a[0] * rel[0] + a[1] * rel[1] + a[2] * rel[2]) as f64 - want_along);
        let h = up[0] * nv[0] + up[1] * nv[1] + up[2] * nv[2]
            - datum.d_mm / dot(f64s(datum.normal), f64s(datum.normal)).sqrt() as f32;
        naive_height.add(h as f64 - want_height);
    }
    let um = |s: &Stat| format!("max {:.4} µm, RMS {:.4} µm", s.max * 1e3, s.rms() * 1e3);
    println!(
        "{} ({} points, depth {:.1}–{:.1} mm, {} out of image):\n  along  {}\n  height {}\n  |ΔX|   {}\n  naive f32 t = d/(n·r) on the same ray: |ΔX| {}; along {}; height {}",
        if distorted { "distorted (k1 −0.1, k2 0.05, p1 1e-4, p2 −1e-4, skew 0.8)" } else { "pinhole" },
        point.n,
        depth_range.0,
        depth_range.1,
        skipped,
        um(&along),
        um(&height),
        um(&point),
        um(&naive),
        um(&naive_along),
        um(&naive_height),
    );
    assert!(along.max <= LIMIT_MM, "along {}", um(&along));
    assert!(height.max <= LIMIT_MM, "height {}", um(&height));
    assert!(point.max <= LIMIT_MM, "point {}", um(&point));
}

#[test]
fn f64_reference_pinhole() {
    run(false, 200_000, 1);
}

#[test]
fn f64_reference_distorted() {
    run(true, 200_000, 2);
}

/// The profile origin is where the reference puts it, and a point there
/// reads (0, 0).
#[test]
fn frame_matches_reference() {
    for distorted in [false, true] {
        let cam = camera(distorted);
        let tri = Triangulator::new(&cam, &lasers(), &datum()).unwrap();
        let reference = Reference::new(&cam, &lasers(), &datum());
        for k in 0..LASERS {
            let f = tri.frame(k).unwrap();
            let (o, a) = reference.frames[k];
            for i in 0..3 {
                assert!((f.origin_mm[i] - o[i]).abs() < 1e-9, "{k}: {:?} vs {:?}", f.origin_mm, o);
                assert!((f.along[i] - a[i]).abs() < 1e-12);
            }
        }
    }
}

/// Eq. 10–11 with α from the planes: 42° for these sheets (yaw only tilts
/// them about the optical axis), so the paper's 10.65–21.30 px.
#[test]
fn scale_range_of_table4() {
    let tri = Triangulator::new(&camera(false), &lasers(), &datum()).unwrap();
    for k in 0..LASERS {
        assert!((tri.alpha_deg(k).unwrap() - 42.0).abs() < 1e-5, "{}", tri.alpha_deg(k).unwrap());
    }
    let r = tri.scale_range(2.0, (350.0, 550.0)).unwrap();
    assert!((r.min().to_f64() - 10.649).abs() < 0.003, "{r:?}");
    assert!((r.max().to_f64() - 21.298).abs() < 0.003, "{r:?}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4096))]
    /// Any column, any row, any laser index: no panic, finite or None.
    #[test]
    fn profile_total(pos in any::<i32>(), row in any::<u16>(), laser in 0usize..LASERS + 2, distorted in any::<bool>()) {
        let tri = Triangulator::new(&camera(distorted), &lasers(), &datum()).unwrap();
        if let Some(p) = tri.profile(laser, Px(pos), row) {
            prop_assert!(p.along_mm.is_finite() && p.height_mm.is_finite());
        }
        if let Some(p) = tri.point_mm(laser, Px(pos), row) {
            prop_assert!(p.iter().all(|v| v.is_finite()));
            prop_assert!(p[2] > 0.0);
        }
        if let Some([x, y]) = tri.undistort(Px(pos), Px(row as i32)) {
            prop_assert!(x.is_finite() && y.is_finite());
        }
    }
}
