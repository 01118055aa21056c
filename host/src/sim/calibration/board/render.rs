//! The renderer: a board pose's image, lamp and lasers, integrated over each pixel, blurred by the lens.

use super::{BOARD_NOISE_STREAM, BoardImage, BoardRenderer, LaserOnBoard, RenderOptions};
use crate::model::board::{Board, BoardPose};
use crate::model::vec3::{cross, dot, normalized, sub};
use crate::sim::scene::geom::mat_t_vec;
use crate::sim::scene::noise::{Rng, SensorPattern, ziggurat};
use crate::sim::scene::{Scene, ScenePlane, SimConfig};

impl BoardRenderer {
    /// A renderer for `scene`'s head (its camera, lasers, noise and seed).
    pub fn new(scene: &Scene, opts: RenderOptions) -> BoardRenderer {
        let cfg = scene.config().clone();
        let planes = scene.laser_planes().to_vec();
        let head = &cfg.head;
        let (st, ct) = head.camera_tilt_deg.to_radians().sin_cos();
        // Nominal head (no misalignment), camera frame: the rail axis is the
        // camera's y, the rail-top normal (up) is (sin tilt, 0, −cos tilt),
        // the aim point is on the optical axis at the standoff.
        let rail_normal = [st, 0.0, -ct];
        let aim = [0.0, 0.0, head.standoff_mm];
        let along = normalized(cross(rail_normal, [0.0, 1.0, 0.0]));
        let sin_alpha = head.alpha_deg.to_radians().sin();
        let mut beams = Vec::new();
        let mut sheet_sigma_mm = Vec::new();
        let mut rail_incidence = Vec::new();
        for p in &planes {
            let mut b = normalized(cross([0.0, 1.0, 0.0], p.normal));
            if b[2] < 0.0 {
                b = [-b[0], -b[1], -b[2]];
            }
            beams.push(b);
            rail_incidence.push(dot(b, rail_normal).abs().max(1e-6));
            // The laser's point on the nominal rail top in the plane y = 0:
            // aim + τ·along with n·(aim + τ·along) = d.
            let tau = (p.d_mm - dot(p.normal, aim)) / dot(p.normal, along);
            let q = [aim[0] + tau * along[0], aim[1] + tau * along[1], aim[2] + tau * along[2]];
            // dδ/dx_n along the rail top: the sheet σ that images to the sim's
            // σ = fx·d·sin α / depth there.
            let dd_dtau = dot(p.normal, along);
            let dxn_dtau = (along[0] * q[2] - q[0] * along[2]) / (q[2] * q[2]);
            let sigma = head.laser_diameter_mm * sin_alpha / q[2] * (dd_dtau / dxn_dtau).abs();
            sheet_sigma_mm.push(sigma);
        }
        let cam = &cfg.camera;
        let sensor = SensorPattern::new(&cfg.noise, cam.width_px(), cam.height_px(), cfg.seed);
        BoardRenderer { cfg, planes, beams, sheet_sigma_mm, rail_incidence, sensor, opts }
    }

    /// The options.
    pub fn options(&self) -> &RenderOptions {
        &self.opts
    }

    /// The configuration of the head.
    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// The laser planes, camera frame (as [`Scene::laser_planes`]).
    pub fn laser_planes(&self) -> &[ScenePlane] {
        &self.planes
    }

    /// Per laser, the σ of its sheet across the plane, mm.
    pub fn sheet_sigma_mm(&self) -> &[f64] {
        &self.sheet_sigma_mm
    }

    /// The reflectance of square `(a, b)`; `None` off the paper.
    pub(super) fn square(&self, board: &Board, a: i64, b: i64) -> Option<f64> {
        let m = self.opts.margin_squares.max(1) as i64;
        let (c, r) = (board.cols as i64, board.rows as i64);
        if a < -1 - m || a > c - 1 + m || b < -1 - m || b > r - 1 + m {
            return None;
        }
        let checker = (-1..c).contains(&a) && (-1..r).contains(&b);
        Some(if checker && (a + b).rem_euclid(2) == 0 { self.opts.black } else { self.opts.white })
    }

    pub(super) fn lasers_for(&self, pose: &BoardPose, laser_mask: u8) -> Vec<LaserOnBoard> {
        let r = &pose.rot;
        let (nb, _) = pose.plane();
        let exposure = self.cfg.camera.exposure_us;
        self.planes
            .iter()
            .enumerate()
            .filter(|(k, _)| *k < 8 && laser_mask & (1 << k) != 0)
            .filter_map(|(k, p)| {
                let l = self.cfg.lasers.get(k)?;
                let n = p.normal;
                let g = [
                    dot(n, pose.t_mm) - p.d_mm,
                    n[0] * r[0][0] + n[1] * r[1][0] + n[2] * r[2][0],
                    n[0] * r[0][1] + n[1] * r[1][1] + n[2] * r[2][1],
                ];
                let incidence = dot(self.beams[k], nb).abs() / self.rail_incidence[k];
                let peak_e = self.cfg.signal_e_per_mw_us
                    * l.power_mw
                    * l.brightness
                    * exposure
                    * self.opts.laser_gain
                    * incidence
                    / self.cfg.head.standoff_mm;
                Some(LaserOnBoard { plane: *p, g, sigma_mm: self.sheet_sigma_mm[k], peak_e })
            })
            .collect()
    }

    /// The noise-free photo-signal of the board, electrons per pixel
    /// (row-major, after the lens blur; without the sensor's ambient light,
    /// dark signal and banding): lamp × reflectance + the lasers of
    /// `laser_mask`.
    pub fn signal_e(&self, board: &Board, pose: &BoardPose, laser_mask: u8) -> Vec<f32> {
        let cam = &self.cfg.camera;
        let (w, h) = (cam.width_px(), cam.height_px());
        let lasers = self.lasers_for(pose, laser_mask);
        let stride = 3 + lasers.len();
        let lamp_e = self.opts.lamp_fraction * cam.full_well_e;
        let bg = self.opts.background;
        let mut out = vec![0f32; w * h];
        let mut top = Vec::with_capacity((w + 1) * stride);
        let mut bottom = Vec::with_capacity((w + 1) * stride);
        self.corner_row(pose, &lasers, -0.5, &mut top);
        for r in 0..h {
            self.corner_row(pose, &lasers, r as f64 + 0.5, &mut bottom);
            let row_out = &mut out[r * w..(r + 1) * w];
            for (c, o) in row_out.iter_mut().enumerate() {
                // Corners around the pixel: 00 top-left, 10 top-right, 11, 01.
                let p = [
                    &top[c * stride..(c + 1) * stride],
                    &top[(c + 1) * stride..(c + 2) * stride],
                    &bottom[(c + 1) * stride..(c + 2) * stride],
                    &bottom[c * stride..(c + 1) * stride],
                ];
                if p.iter().any(|q| q[0].is_nan()) {
                    *o = (lamp_e * bg) as f32;
                    continue;
                }
                let quad = p.map(|q| [q[0], q[1]]);
                let Some((rho_lamp, rho_laser, moment)) = self.footprint(board, &quad) else {
                    *o = (lamp_e * bg) as f32;
                    continue;
                };
                let mut e = lamp_e * rho_lamp;
                if rho_laser > 0.0 {
                    add_laser_light(&mut e, &lasers, p, rho_laser, moment);
                }
                *o = e as f32;
            }
            std::mem::swap(&mut top, &mut bottom);
        }
        blur(&mut out, w, h, self.opts.psf_sigma_px);
        out
    }

    /// The pixel corners of image row `v` (half-integer) on the board:
    /// board x, y (mm), depth (mm) and δ per lit laser (mm) each; NaN where
    /// the ray misses the board.
    fn corner_row(&self, pose: &BoardPose, lasers: &[LaserOnBoard], v: f64, out: &mut Vec<f64>) {
        let cam = &self.cfg.camera;
        let stride = 3 + lasers.len();
        let (nb, db) = pose.plane();
        out.clear();
        for j in 0..=cam.width_px() {
            let ray = cam.intrinsics.unproject(j as f64 - 0.5, v);
            let den = dot(nb, ray);
            let s = if den.abs() < 1e-12 { f64::NAN } else { db / den };
            if !(s > 0.0 && s.is_finite()) {
                out.extend(std::iter::repeat_n(f64::NAN, stride));
                continue;
            }
            let x = [ray[0] * s, ray[1] * s, ray[2] * s];
            let b = mat_t_vec(&pose.rot, sub(x, pose.t_mm));
            out.extend_from_slice(&[b[0], b[1], x[2]]);
            for l in lasers {
                out.push(l.plane.distance_mm(x));
            }
        }
    }

    /// Over a pixel's footprint `quad` on the board (mm): the mean
    /// reflectance for the lamp (backdrop included), the mean reflectance
    /// of the paper for the lasers, and the paper's reflectance moment about
    /// the footprint's centroid (mm). `None` for a degenerate footprint.
    fn footprint(&self, board: &Board, quad: &[[f64; 2]; 4]) -> Option<(f64, f64, [f64; 2])> {
        let sq = board.square_mm;
        let inv_sq = 1.0 / sq;
        let bg = self.opts.background;
        let cells = quad.map(|q| ((q[0] * inv_sq).floor() as i64, (q[1] * inv_sq).floor() as i64));
        if cells.iter().all(|&x| x == cells[0]) {
            return Some(match self.square(board, cells[0].0, cells[0].1) {
                Some(rho) => (rho, rho, [0.0, 0.0]),
                None => (bg, 0.0, [0.0, 0.0]),
            });
        }
        let (area, cen) = polygon_area_centroid(quad);
        if area.abs() < 1e-300 {
            return None;
        }
        let m = self.opts.margin_squares.max(1) as i64;
        let (a_min, a_max) = (-1 - m, board.cols as i64 - 1 + m);
        let (b_min, b_max) = (-1 - m, board.rows as i64 - 1 + m);
        let alo = cells.iter().map(|x| x.0).min().unwrap_or(0).max(a_min);
        let ahi = cells.iter().map(|x| x.0).max().unwrap_or(0).min(a_max);
        let blo = cells.iter().map(|x| x.1).min().unwrap_or(0).max(b_min);
        let bhi = cells.iter().map(|x| x.1).max().unwrap_or(0).min(b_max);
        let (mut paper_area, mut rho_a) = (0.0, 0.0);
        let mut mom = [0.0, 0.0];
        for b in blo..=bhi {
            for a in alo..=ahi {
                let rect = [a as f64 * sq, (a + 1) as f64 * sq, b as f64 * sq, (b + 1) as f64 * sq];
                let Some((ca, cc)) = clip_area_centroid(quad, rect) else { continue };
                let rho = self.square(board, a, b).unwrap_or(0.0);
                paper_area += ca;
                rho_a += rho * ca;
                mom[0] += rho * ca * (cc[0] - cen[0]);
                mom[1] += rho * ca * (cc[1] - cen[1]);
            }
        }
        Some(((rho_a + bg * (area - paper_area)) / area, rho_a / area, [mom[0] / area, mom[1] / area]))
    }

    /// Reads a photo-signal out through the sensor: ambient light, hot
    /// pixels, column and row banding, shot and read noise (drawn from
    /// `shot`'s stream), saturation, quantisation.
    pub fn read_out(&self, signal: &[f32], shot: u64) -> BoardImage {
        let cam = &self.cfg.camera;
        let nm = &self.cfg.noise;
        let (w, h) = (cam.width_px(), cam.height_px());
        assert_eq!(signal.len(), w * h, "read_out: the signal must hold width × height pixels");
        let exposure = cam.exposure_us;
        let gain = cam.gain_e_per_dn();
        let inv_gain = 1.0 / gain;
        let max = cam.max_dn() as f64;
        let quantise = |e: f64| (e * inv_gain + 0.5).clamp(0.0, max) as u16;
        let a0 = nm.ambient_e_per_us * exposure;
        let slope = a0 * nm.ambient_gradient_per_px[0];
        let read2 = nm.read_noise_e * nm.read_noise_e;
        let shot_k = if nm.shot_noise { 1.0 } else { 0.0 };
        let zig = ziggurat();
        let mut pixels = vec![0u16; w * h];
        let mut buf = vec![0.0f64; w];
        for r in 0..h {
            let base = a0 * (1.0 + nm.ambient_gradient_per_px[1] * (r as f64 - cam.intrinsics.cy_px));
            for (i, (b, &s)) in buf.iter_mut().zip(&signal[r * w..(r + 1) * w]).enumerate() {
                *b = (base + slope * (i as f64 - cam.intrinsics.cx_px)).max(0.0) + s as f64;
            }
            for &(c, e) in self.sensor.hot_in_row(r) {
                buf[c as usize] += e * exposure;
            }
            let out = &mut pixels[r * w..(r + 1) * w];
            let col = &self.sensor.column_offset_e;
            if !nm.is_random() {
                for ((o, &s), &c) in out.iter_mut().zip(&buf).zip(col) {
                    *o = quantise(s + c);
                }
                continue;
            }
            let mut rng = Rng::for_stream(self.cfg.seed, BOARD_NOISE_STREAM, shot, r as u64);
            let row_offset = if nm.row_banding_e > 0.0 { nm.row_banding_e * rng.normal() } else { 0.0 };
            for ((o, &s), &c) in out.iter_mut().zip(&buf).zip(col) {
                let sd = (read2 + shot_k * s).sqrt();
                *o = quantise(s + sd * rng.normal_with(zig) + row_offset + c);
            }
        }
        BoardImage { width: w, height: h, bits: cam.bits, pixels }
    }

    /// Renders the board at `pose` with the lasers of `laser_mask` on; the
    /// random noise is that of `shot` (render two images of one pose with
    /// different shots for independent noise).
    pub fn render(&self, board: &Board, pose: &BoardPose, laser_mask: u8, shot: u64) -> BoardImage {
        self.read_out(&self.signal_e(board, pose, laser_mask), shot)
    }
}

/// Renders `board` at `pose` as `scene`'s camera sees it, lit by the lamp and
/// the lasers of `laser_mask`, with the noise of `shot`
/// ([`RenderOptions::default`]).
pub fn render_board(scene: &Scene, board: &Board, pose: &BoardPose, laser_mask: u8, shot: u64) -> BoardImage {
    BoardRenderer::new(scene, RenderOptions::default()).render(board, pose, laser_mask, shot)
}

/// Signed area and centroid of a simple polygon.
pub(super) fn polygon_area_centroid(p: &[[f64; 2]]) -> (f64, [f64; 2]) {
    let n = p.len();
    let (mut a, mut cx, mut cy) = (0.0, 0.0, 0.0);
    // Relative to the first vertex, for precision.
    let o = p[0];
    for i in 0..n {
        let (x0, y0) = (p[i][0] - o[0], p[i][1] - o[1]);
        let (x1, y1) = (p[(i + 1) % n][0] - o[0], p[(i + 1) % n][1] - o[1]);
        let c = x0 * y1 - x1 * y0;
        a += c;
        cx += (x0 + x1) * c;
        cy += (y0 + y1) * c;
    }
    let a = 0.5 * a;
    if a == 0.0 {
        let m = p.iter().fold([0.0, 0.0], |s, q| [s[0] + q[0], s[1] + q[1]]);
        return (0.0, [m[0] / n as f64, m[1] / n as f64]);
    }
    (a, [o[0] + cx / (6.0 * a), o[1] + cy / (6.0 * a)])
}

/// Area (signed as the quad's) and centroid of a convex quadrilateral's
/// part inside the rectangle `[x0, x1] × [y0, y1]`; `None` if empty.
pub(super) fn clip_area_centroid(quad: &[[f64; 2]; 4], rect: [f64; 4]) -> Option<(f64, [f64; 2])> {
    let mut a = [[0.0; 2]; 12];
    let mut b = [[0.0; 2]; 12];
    a[..4].copy_from_slice(quad);
    let mut n = 4;
    // (axis, bound, keep ≥ bound?)
    for (axis, bound, keep_above) in [(0, rect[0], true), (0, rect[1], false), (1, rect[2], true), (1, rect[3], false)]
    {
        let inside = |p: &[f64; 2]| if keep_above { p[axis] >= bound } else { p[axis] <= bound };
        let mut m = 0;
        for i in 0..n {
            let (p, q) = (a[i], a[(i + 1) % n]);
            let (ip, iq) = (inside(&p), inside(&q));
            if ip {
                b[m] = p;
                m += 1;
            }
            if ip != iq {
                let t = (bound - p[axis]) / (q[axis] - p[axis]);
                let mut x = [p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])];
                x[axis] = bound;
                b[m] = x;
                m += 1;
            }
        }
        n = m;
        if n < 3 {
            return None;
        }
        a[..n].copy_from_slice(&b[..n]);
    }
    let (area, c) = polygon_area_centroid(&a[..n]);
    (area != 0.0).then_some((area, c))
}

/// Separable Gaussian blur (σ px, kernel ±⌈4σ⌉, edges replicated).
pub(super) fn blur(img: &mut [f32], w: usize, h: usize, sigma: f64) {
    if sigma.is_nan() || sigma <= 0.0 {
        return;
    }
    let r = (4.0 * sigma).ceil() as isize;
    let mut k: Vec<f32> = (-r..=r).map(|i| (-0.5 * (i as f64 / sigma).powi(2)).exp() as f32).collect();
    let s: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    let mut line = vec![0f32; w.max(h) + 2 * r as usize];
    // Rows.
    for row in img.chunks_exact_mut(w) {
        for (i, v) in line.iter_mut().take(w + 2 * r as usize).enumerate() {
            *v = row[(i as isize - r).clamp(0, w as isize - 1) as usize];
        }
        for (x, o) in row.iter_mut().enumerate() {
            *o = k.iter().zip(&line[x..]).map(|(a, b)| a * b).sum();
        }
    }
    // Columns, a row at a time (cache-friendly on large images).
    let src = img.to_vec();
    for y in 0..h {
        let out = &mut img[y * w..(y + 1) * w];
        out.iter_mut().for_each(|v| *v = 0.0);
        for (j, &kj) in k.iter().enumerate() {
            let sy = (y as isize + j as isize - r).clamp(0, h as isize - 1) as usize;
            for (o, &s) in out.iter_mut().zip(&src[sy * w..(sy + 1) * w]) {
                *o += kj * s;
            }
        }
    }
}

/// Adds the lasers' light on one pixel to `e`, electrons: each sheet's Gaussian
/// profile across its plane averaged over the pixel's footprint (3 × 3
/// Gauss–Legendre on the corners' distances `p[k][3 + laser]`), with the
/// first-order term of the paper's reflectance `moment` across it.
fn add_laser_light(e: &mut f64, lasers: &[LaserOnBoard], p: [&[f64]; 4], rho_laser: f64, moment: [f64; 2]) {
    // 3-point Gauss–Legendre on [0, 1].
    let gl_x = [0.5 - 0.5 * 0.6f64.sqrt(), 0.5, 0.5 + 0.5 * 0.6f64.sqrt()];
    let gl_w = [5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0];
    let [p00, p10, p11, p01] = p;
    let depth = 0.25 * (p00[2] + p10[2] + p11[2] + p01[2]);
    for (k, l) in lasers.iter().enumerate() {
        let d = [p00[3 + k], p10[3 + k], p11[3 + k], p01[3 + k]];
        let reach = 6.0 * l.sigma_mm;
        let (dmin, dmax) =
            (d.iter().copied().fold(f64::INFINITY, f64::min), d.iter().copied().fold(f64::NEG_INFINITY, f64::max));
        if dmin > reach || dmax < -reach {
            continue;
        }
        let inv2 = -0.5 / (l.sigma_mm * l.sigma_mm);
        let mut mean = 0.0;
        for (i, &t) in gl_x.iter().enumerate() {
            for (j, &s) in gl_x.iter().enumerate() {
                let dd = (1.0 - t) * ((1.0 - s) * d[0] + s * d[1]) + t * ((1.0 - s) * d[3] + s * d[2]);
                mean += gl_w[i] * gl_w[j] * (inv2 * dd * dd).exp();
            }
        }
        let dc = 0.25 * (d[0] + d[1] + d[2] + d[3]);
        let slope = 2.0 * inv2 * dc * (inv2 * dc * dc).exp();
        let cov = slope * (l.g[1] * moment[0] + l.g[2] * moment[1]);
        *e += l.peak_e * depth * (rho_laser * mean + cov);
    }
}
