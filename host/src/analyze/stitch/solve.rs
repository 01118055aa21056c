//! The joint registration: every frame's offset (and, if asked, pitch)
//! solved from all overlaps of all lines together, each overlap weighted
//! by its lines' noise.
//!
//! # The model
//!
//! The head is rigid: between frames it bounces (an offset) and pitches
//! (a tilt along the rail), and the three lines, parallel along the rail,
//! share both. A roll of the head would move each line by an offset
//! linear in its lateral position; it is not solved for: the stitcher does
//! not know the lines' lateral positions, a roll of a trolley riding both
//! rails is small beside its bounce, and what a roll leaves differs from
//! line to line, where the null lines see it (the floor is then too high,
//! never too low). So frame `f` reads, on line `k` at cell `c`,
//!
//! ```text
//! v_fk(c) = z_k(c) + o_f + p_f·(x_c − centre_f) + noise,   Var = σ_fk² / n_fkc
//! ```
//!
//! with `n_fkc` the frame's points in the cell and `σ_fk` the line's noise
//! per point, from the frame's overlap with the frame before it (half the
//! variance of their difference: speckle, tied to the rail, cancels there,
//! so this is the noise registration has to live with). The rail `z_k(c)`
//! is eliminated cell by cell: a cell seen by frames `G` adds
//! `Σ_G w_i (v_i − a_i)² − (Σ_G w_i (v_i − a_i))² / Σ_G w_i` to the sum of
//! squares (`w = n/σ²`, `a_i` the frame's correction there), which is every
//! pair of frames that overlap there (`i` with `i+1`, `i+2`, … as far as they
//! reach), each weighted as the least squares of the whole problem weighs it.
//!
//! # A fixed-lag information smoother
//!
//! The normal equations are banded (a frame meets only the frames that
//! overlap it), so the solve streams: the information matrix of the
//! frames in a window, a cell's terms added when no newer frame covers it,
//! and the oldest frame committed — its correction taken from the window's
//! solution, then marginalised out (Schur complement), which carries what
//! it knew into the frames after it — once its cells are all closed and
//! [`LAG_FRAMES`] newer frames have been seen. A Kalman filter would
//! commit each frame on the frames before it alone; the lag lets the
//! overlaps after a frame correct it too, and beyond a few frames they no
//! longer do (their information reaches a frame through ever more noisy
//! links). Memory is the window: at most [`MAX_WINDOW`] frames' cells and
//! a matrix of their parameters.
//!
//! A frame that overlaps nothing (the first, or one across a gap) is held
//! where it was measured by a tight prior ([`ANCHOR`]), as the chained
//! registration leaves it: that fixes the gauge (the profile's height and
//! slope, which no overlap can see). Every other frame carries a loose
//! prior ([`LOOSE`]), only so that the newest frames, whose cells are
//! still open, keep the matrix positive definite.
//!
//! # What the solve's errors cost
//!
//! The solve is linear in the frames' values, so its error is the solve of
//! their noise alone. [`REPLICAS`] replicas of that noise (Gaussian, each
//! cell of each frame and line with its own variance `σ_fk²/n_fkc`) are
//! solved beside the data, as extra right-hand sides of the same matrix;
//! each committed frame carries its replicas' correction errors, whose
//! effect on the profile ([`super::share`]) is the stitch's own share of
//! the noise — common to all lines, so no null line can see it.

use std::collections::{BTreeMap, VecDeque};

use cms_core::protocol::LASERS;

/// One frame's cell: (lattice index, value µm, points).
pub type Cell = (i64, f64, usize);

/// Frames newer than a frame before it is committed.
pub const LAG_FRAMES: usize = 8;

/// Most frames in the window: the oldest is committed then whatever its
/// cells (a head standing still sees the same cells frame after frame).
pub const MAX_WINDOW: usize = 32;

/// Replicas of the noise solved beside the data.
pub const REPLICAS: usize = 4;

/// Prior σ of the offset (µm) and pitch (µm per mm) of a frame that
/// overlaps nothing: it stays where it was measured.
pub const ANCHOR: (f64, f64) = (1e-3, 1e-5);

/// Prior σ of the offset (µm) and pitch (µm per mm) of a frame that
/// overlaps others: far beyond any bounce or pitch (its pull on the
/// pitch, which overlaps pin only softly over many frames, stays under
/// 1e-9 µm/mm over a few hundred frames).
pub const LOOSE: (f64, f64) = (1e6, 1e4);

/// Smallest noise per point a line is weighted by, µm (a perfect overlap
/// must not take all the weight).
const MIN_SIGMA_UM: f64 = 0.05;

/// A line's noise per point before any overlap has measured it, µm.
const DEFAULT_SIGMA_UM: f64 = 1.0;

/// A frame committed: its cells and its correction `o + p·(x − centre)`.
#[derive(Debug, Clone)]
pub struct Committed {
    pub seq: u32,
    pub centre_mm: f64,
    pub cells: [Vec<Cell>; LASERS],
    /// Offset at the centre, µm, and pitch, µm per mm.
    pub correction: (f64, f64),
    /// Each replica's error of the correction (offset, pitch).
    pub errors: [(f64, f64); REPLICAS],
    /// Per line, the length it overlapped the frames before it, mm.
    pub overlap_mm: [f64; LASERS],
    /// Whether any line overlapped enough to register the frame.
    pub registered: bool,
    /// Per line, its weight per point, 1/µm².
    pub inv_var: [f64; LASERS],
}

struct WinFrame {
    id: u64,
    c: Committed,
    /// Its cells not yet closed.
    open: usize,
}

/// One frame's value in an open cell.
#[derive(Clone, Copy)]
struct Member {
    id: u64,
    x_mm: f64,
    v: f64,
    w: f64,
    e: [f64; REPLICAS],
}

/// The streaming joint solve of one direction (see the module docs).
pub struct Solver {
    dx_mm: f64,
    /// Parameters per frame: 1 (offset) or 2 (offset, pitch).
    m: usize,
    min_overlap_mm: f64,
    window: VecDeque<WinFrame>,
    next_id: u64,
    /// Per line, its open cells.
    open: [BTreeMap<i64, Vec<Member>>; LASERS],
    /// Information matrix (row-major, `n × n`, `n = m·window`) and vectors
    /// (the data's, then each replica's).
    info: Vec<f64>,
    rhs: Vec<[f64; 1 + REPLICAS]>,
    /// Per line, the last noise measured, µm.
    sigma_um: [f64; LASERS],
    rng: u64,
}

impl Solver {
    pub fn new(dx_mm: f64, pitch: bool, min_overlap_mm: f64, seed: u64) -> Solver {
        Solver {
            dx_mm,
            m: if pitch { 2 } else { 1 },
            min_overlap_mm,
            window: VecDeque::new(),
            next_id: 0,
            open: Default::default(),
            info: Vec::new(),
            rhs: Vec::new(),
            sigma_um: [DEFAULT_SIGMA_UM; LASERS],
            rng: seed | 1,
        }
    }

    /// Adds one frame's cells (per line, ascending); returns the frames
    /// committed, oldest first.
    pub fn push(&mut self, seq: u32, cells: [Vec<Cell>; LASERS]) -> Vec<Committed> {
        let dx = self.dx_mm;
        let (lo, hi) = extent(&cells);
        let centre_mm = (lo as f64 + hi as f64) / 2.0 * dx;
        let mut overlap_mm = [0.0; LASERS];
        let mut inv_var = [0.0; LASERS];
        for (k, line) in cells.iter().enumerate() {
            let shared: Vec<i64> = line.iter().map(|c| c.0).filter(|c| self.open[k].contains_key(c)).collect();
            overlap_mm[k] = match (shared.first(), shared.last()) {
                (Some(a), Some(b)) if shared.len() >= 2 => (b - a + 1) as f64 * dx,
                _ => 0.0,
            };
            if let Some(s) = self.window.back().and_then(|g| noise_per_point(line, &g.c.cells[k])) {
                self.sigma_um[k] = s.max(MIN_SIGMA_UM);
            }
            inv_var[k] = 1.0 / (self.sigma_um[k] * self.sigma_um[k]);
        }
        let registered = overlap_mm.iter().any(|&o| o >= self.min_overlap_mm);
        for (k, line) in cells.iter().enumerate() {
            let range = line.first().zip(line.last()).map(|(a, b)| (a.0, b.0));
            self.close_outside(k, range);
        }
        let id = self.next_id;
        self.next_id += 1;
        self.grow(if registered { LOOSE } else { ANCHOR });
        let mut open = 0;
        for (k, line) in cells.iter().enumerate() {
            for &(c, v, n) in line {
                let w = n as f64 * inv_var[k];
                let sd = 1.0 / w.sqrt();
                let e = std::array::from_fn(|_| sd * self.gauss());
                self.open[k].entry(c).or_default().push(Member { id, x_mm: c as f64 * dx, v, w, e });
                open += 1;
            }
        }
        let c = Committed {
            seq,
            centre_mm,
            cells,
            correction: (0.0, 0.0),
            errors: [(0.0, 0.0); REPLICAS],
            overlap_mm,
            registered,
            inv_var,
        };
        self.window.push_back(WinFrame { id, c, open });
        let mut out = Vec::new();
        while self.window.len() > MAX_WINDOW || (self.window.len() > LAG_FRAMES && self.window[0].open == 0) {
            out.push(self.commit());
        }
        out
    }

    /// Closes every cell and commits every frame left.
    pub fn finish(&mut self) -> Vec<Committed> {
        for k in 0..LASERS {
            self.close_outside(k, None);
        }
        let mut out = Vec::new();
        while !self.window.is_empty() {
            out.push(self.commit());
        }
        out
    }

    /// Frames in the window, not yet committed.
    pub fn pending(&self) -> usize {
        self.window.len()
    }

    /// Adds a frame's parameters to the window, with their prior σ.
    fn grow(&mut self, (offset_um, pitch_um_per_mm): (f64, f64)) {
        let (n, m) = (self.rhs.len(), self.m);
        let nn = n + m;
        let mut info = vec![0.0; nn * nn];
        for r in 0..n {
            info[r * nn..r * nn + n].copy_from_slice(&self.info[r * n..(r + 1) * n]);
        }
        info[n * nn + n] = offset_um.powi(-2);
        if m == 2 {
            info[(n + 1) * nn + n + 1] = pitch_um_per_mm.powi(-2);
        }
        self.info = info;
        self.rhs.resize(nn, [0.0; 1 + REPLICAS]);
    }

    /// Closes line `k`'s open cells outside `range` (all with `None`),
    /// adding their terms to the normal equations.
    fn close_outside(&mut self, k: usize, range: Option<(i64, i64)>) {
        let keys: Vec<i64> = match range {
            Some((lo, hi)) => self.open[k].range(..lo).chain(self.open[k].range(hi + 1..)).map(|(&c, _)| c).collect(),
            None => self.open[k].keys().copied().collect(),
        };
        let first = self.window.front().map_or(self.next_id, |f| f.id);
        for c in keys {
            let Some(members) = self.open[k].remove(&c) else { continue };
            let live: Vec<Member> = members.into_iter().filter(|m| m.id >= first).collect();
            for m in &live {
                self.window[(m.id - first) as usize].open -= 1;
            }
            if live.len() >= 2 {
                self.add_cell(&live, first);
            }
        }
    }

    /// A cell's terms: `Σ w φφᵀ − (Σ wφ)(Σ wφ)ᵀ/W` and the matching right-hand sides.
    fn add_cell(&mut self, members: &[Member], first: u64) {
        let (m, n) = (self.m, self.rhs.len());
        let total: f64 = members.iter().map(|p| p.w).sum();
        // (parameter index, its coefficient w·φ) of every member's parameters.
        let mut terms: Vec<(usize, f64, usize)> = Vec::with_capacity(members.len() * m);
        for (j, p) in members.iter().enumerate() {
            let at = (p.id - first) as usize * m;
            terms.push((at, p.w, j));
            if m == 2 {
                let centre = self.window[(p.id - first) as usize].c.centre_mm;
                terms.push((at + 1, p.w * (p.x_mm - centre), j));
            }
        }
        let mut mean = [0.0; 1 + REPLICAS];
        for p in members {
            mean[0] += p.w * p.v / total;
            for r in 0..REPLICAS {
                mean[1 + r] += p.w * p.e[r] / total;
            }
        }
        for &(a, sa, ja) in &terms {
            let pa = &members[ja];
            for &(b, sb, jb) in &terms {
                let own = if ja == jb { sa * sb / pa.w } else { 0.0 };
                self.info[a * n + b] += own - sa * sb / total;
            }
            let rhs = &mut self.rhs[a];
            rhs[0] += sa * (pa.v - mean[0]);
            for r in 0..REPLICAS {
                rhs[1 + r] += sa * (pa.e[r] - mean[1 + r]);
            }
        }
    }

    /// Commits the oldest frame: its correction from the window's
    /// solution, then its parameters marginalised out.
    fn commit(&mut self) -> Committed {
        let (m, n) = (self.m, self.rhs.len());
        let x = solve(&self.info, &self.rhs, n);
        let mut f = self.window.pop_front().expect("a frame to commit");
        let pitch = |col: usize| if m == 2 { x[1][col] } else { 0.0 };
        f.c.correction = (x[0][0], pitch(0));
        f.c.errors = std::array::from_fn(|r| (x[0][1 + r], pitch(1 + r)));
        // Schur complement: Λ_bb − Λ_ba Λ_aa⁻¹ Λ_ab, η_b − Λ_ba Λ_aa⁻¹ η_a.
        let inv = inverse_small(&self.info, n, m);
        let nb = n - m;
        let mut info = vec![0.0; nb * nb];
        let mut rhs = vec![[0.0; 1 + REPLICAS]; nb];
        for i in 0..nb {
            // g = Λ_ia Λ_aa⁻¹ (a row of m).
            let g: Vec<f64> =
                (0..m).map(|a| (0..m).map(|b| self.info[(m + i) * n + b] * inv[b * m + a]).sum()).collect();
            for j in 0..nb {
                let corr: f64 = (0..m).map(|a| g[a] * self.info[a * n + m + j]).sum();
                info[i * nb + j] = self.info[(m + i) * n + m + j] - corr;
            }
            for (col, r) in rhs[i].iter_mut().enumerate() {
                let corr: f64 = (0..m).map(|a| g[a] * self.rhs[a][col]).sum();
                *r = self.rhs[m + i][col] - corr;
            }
        }
        self.info = info;
        self.rhs = rhs;
        f.c
    }

    /// A standard normal deviate (xorshift64*, Box–Muller).
    fn gauss(&mut self) -> f64 {
        let mut uniform = || {
            self.rng ^= self.rng << 13;
            self.rng ^= self.rng >> 7;
            self.rng ^= self.rng << 17;
            ((self.rng >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (u, v) = (uniform(), uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// The lattice indices a frame's lines cover (lowest, highest).
fn extent(cells: &[Vec<Cell>; LASERS]) -> (i64, i64) {
    let lo = cells.iter().filter_map(|l| l.first()).map(|c| c.0).min().unwrap_or(0);
    let hi = cells.iter().filter_map(|l| l.last()).map(|c| c.0).max().unwrap_or(0);
    (lo, hi)
}

/// A line's noise per point, µm, from two frames' cells: the spread of
/// their difference over the cells they share (its mean taken out), with
/// the two frames' noises alike: `Var(d) = σ²·(1/n_a + 1/n_b)`. `None`
/// over fewer than 3 shared cells.
fn noise_per_point(a: &[Cell], b: &[Cell]) -> Option<f64> {
    let (mut j, mut d, mut share) = (0, Vec::new(), 0.0);
    for &(c, v, n) in a {
        while j < b.len() && b[j].0 < c {
            j += 1;
        }
        if j < b.len() && b[j].0 == c {
            d.push(v - b[j].1);
            share += 1.0 / n as f64 + 1.0 / b[j].2 as f64;
        }
    }
    if d.len() < 3 {
        return None;
    }
    let k = d.len() as f64;
    let mean = d.iter().sum::<f64>() / k;
    let var = d.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (k - 1.0);
    Some((var / (share / k)).sqrt())
}

/// The first frame's `m` parameters of `Λ x = η` (each right-hand side),
/// by Cholesky: `x[p][col]`.
fn solve(info: &[f64], rhs: &[[f64; 1 + REPLICAS]], n: usize) -> Vec<[f64; 1 + REPLICAS]> {
    let mut l = info.to_vec();
    for j in 0..n {
        let mut d = l[j * n + j];
        for k in 0..j {
            d -= l[j * n + k] * l[j * n + k];
        }
        // The priors keep Λ positive definite; rounding could not take
        // that much away.
        let d = d.max(f64::MIN_POSITIVE).sqrt();
        l[j * n + j] = d;
        for i in j + 1..n {
            let mut s = l[i * n + j];
            for k in 0..j {
                s -= l[i * n + k] * l[j * n + k];
            }
            l[i * n + j] = s / d;
        }
    }
    let mut y = rhs.to_vec();
    for i in 0..n {
        let (done, rest) = y.split_at_mut(i);
        for (col, v) in rest[0].iter_mut().enumerate() {
            let s: f64 = done.iter().enumerate().map(|(k, d)| l[i * n + k] * d[col]).sum();
            *v = (*v - s) / l[i * n + i];
        }
    }
    for i in (0..n).rev() {
        let (head, after) = y.split_at_mut(i + 1);
        for (col, v) in head[i].iter_mut().enumerate() {
            let s: f64 = after.iter().enumerate().map(|(j, d)| l[(i + 1 + j) * n + i] * d[col]).sum();
            *v = (*v - s) / l[i * n + i];
        }
    }
    y
}

/// The inverse of the leading `m × m` block (m ≤ 2) of an `n × n` matrix.
fn inverse_small(a: &[f64], n: usize, m: usize) -> Vec<f64> {
    if m == 1 {
        return vec![1.0 / a[0]];
    }
    let (p, q, r, s) = (a[0], a[1], a[n], a[n + 1]);
    let det = p * s - q * r;
    vec![s / det, -q / det, -r / det, p / det]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames of a rail `z(x)` every `step_mm`, `len_mm` long, 1 mm cells
    /// of `n` points, each frame moved by `bounce(i)` (offset, pitch) and
    /// each cell by Gaussian noise of `sigma/√n`.
    fn frames(
        count: usize,
        step_mm: f64,
        len_mm: f64,
        sigma: f64,
        bounce: impl Fn(usize) -> (f64, f64),
    ) -> Vec<[Vec<Cell>; LASERS]> {
        let z = |x: f64| 20.0 * (x / 37.0).sin() + 5.0 * (x / 11.0).cos();
        let mut s = Solver::new(1.0, false, 3.0, 99);
        (0..count)
            .map(|i| {
                let lo = (i as f64 * step_mm).round() as i64;
                let hi = lo + len_mm as i64;
                let centre = (lo + hi) as f64 / 2.0;
                let (o, p) = bounce(i);
                std::array::from_fn(|k| {
                    (lo..=hi)
                        .map(|c| {
                            let x = c as f64;
                            (c, z(x) + k as f64 + o + p * (x - centre) + sigma / 7f64.sqrt() * s.gauss(), 7)
                        })
                        .collect()
                })
            })
            .collect()
    }

    fn run(fr: Vec<[Vec<Cell>; LASERS]>, pitch: bool) -> Vec<Committed> {
        let mut s = Solver::new(1.0, pitch, 3.0, 5);
        let mut out: Vec<Committed> = fr.into_iter().enumerate().flat_map(|(i, f)| s.push(i as u32, f)).collect();
        out.extend(s.finish());
        out
    }

    /// Without noise the bounces come back (up to the gauge: the first frame's).
    #[test]
    fn bounces_and_pitches_are_recovered_without_noise() {
        let bounce = |i: usize| (15.0 * ((i * 7919) % 13) as f64 - 90.0, 0.02 * ((i * 31) % 7) as f64 - 0.06);
        let out = run(frames(60, 30.0, 68.0, 0.0, bounce), true);
        assert_eq!(out.len(), 60);
        assert_eq!(out.iter().map(|c| c.seq).collect::<Vec<_>>(), (0..60).collect::<Vec<_>>());
        let (o0, p0) = (out[0].correction.0 - bounce(0).0, out[0].correction.1 - bounce(0).1);
        for (i, c) in out.iter().enumerate() {
            // The gauge: one offset and one slope for the whole profile (the
            // loose priors pull the slope by ~1e-9 µm/mm over the record).
            let want_o = bounce(i).0 + o0 + p0 * (c.centre_mm - out[0].centre_mm);
            assert!((c.correction.0 - want_o).abs() < 1e-3, "frame {i}: {:?} vs {want_o}", c.correction);
            assert!(
                (c.correction.1 - bounce(i).1 - p0).abs() < 1e-6,
                "frame {i}: {:?} {:?} {p0}",
                c.correction,
                bounce(i)
            );
            assert!(c.registered == (i > 0) && c.overlap_mm[1] == if i == 0 { 0.0 } else { 39.0 });
        }
    }

    /// With noise, the offsets' errors between frames match what the
    /// replicas say they are: the propagated σ is the real one.
    #[test]
    fn the_replicas_carry_the_real_error() {
        let bounce = |i: usize| (40.0 * ((i * 7919) % 11) as f64, 0.0);
        let out = run(frames(400, 20.0, 68.0, 2.0, bounce), false);
        let err: Vec<f64> = out.iter().enumerate().map(|(i, c)| c.correction.0 - bounce(i).0).collect();
        // Steps between neighbours: the gauge cancels.
        let rms = |v: &mut dyn Iterator<Item = f64>| {
            let v: Vec<f64> = v.collect();
            (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
        };
        let real = rms(&mut err.windows(2).map(|w| w[1] - w[0]));
        let replica =
            rms(&mut (0..REPLICAS).flat_map(|r| out.windows(2).map(move |w| w[1].errors[r].0 - w[0].errors[r].0)));
        assert!(real > 0.01 && (0.75..1.33).contains(&(replica / real)), "real {real} replicas {replica}");
        // The noise per point is measured: 2 µm.
        assert!(out[10..].iter().all(|c| (c.inv_var[0].sqrt().recip() - 2.0).abs() < 1.0), "{:?}", out[10].inv_var);
    }

    /// A frame that overlaps nothing is not registered and stays as measured.
    #[test]
    fn a_frame_across_a_gap_is_left_as_it_is() {
        let mut fr = frames(20, 30.0, 68.0, 0.0, |i| (if i >= 10 { 50.0 } else { 0.0 }, 0.0));
        for f in &mut fr[10..] {
            for l in f.iter_mut() {
                for c in l.iter_mut() {
                    c.0 += 1000;
                }
            }
        }
        let out = run(fr, false);
        assert!(!out[10].registered && out[11].registered);
        // Each stretch's first frame stays as measured, and its others with it.
        assert!(
            out.iter().all(|c| c.correction.0.abs() < 1e-4),
            "{:?}",
            out.iter().map(|c| c.correction).collect::<Vec<_>>()
        );
    }
}
