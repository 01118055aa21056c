//! Frames placed along the track and stitched into one continuous
//! longitudinal profile per laser line.
//!
//! # Where a point lies on the track
//!
//! The camera sees a patch of rail head; each laser's line runs **along the
//! rail**, so one frame gives, per laser, a short longitudinal profile: the
//! calibrated points `(along_mm, height)` in that laser's profile frame
//! (`cms_core::triangulation`: `along` on the line where the laser plane
//! meets the rail-top datum, increasing with the image rows, from the point
//! nearest where the optical axis meets the datum; `height` normal to the
//! datum). The frame's odometer says where the head was. So a point lies at
//! track position
//!
//! ```text
//! x_mm = odometer_mm + s · along_mm        s = +1 (forward) or −1 (reverse)
//! ```
//!
//! `s` is how the head is mounted: +1 when image rows run in the direction
//! the odometer counts up. The origins of the three lasers' frames sit at
//! the same track position (the optical axis), so the three profiles share
//! `x`. On the simulated head `x` is exactly the rail model's track
//! coordinate (`host/tests/it/triangulate_sim.rs` checks along = x − odometer
//! to 0.5 µm). [`Direction::Auto`] picks `s` from the data: the sign whose
//! overlapping frames agree better (a corrugated rail disagrees with itself
//! when mirrored; a flat one cannot tell, and forward is kept). A direction
//! given is used as given and checked the same way: when the other sign
//! agrees clearly better, [`Stitching::direction_disputed`] says so.
//!
//! # Resampling
//!
//! The profile is a grid of cells `dx_mm` wide (cell `i` centred on
//! `x0 + i·dx`). Each frame's points in a cell give one value at the cell's
//! centre: the intercept of their least-squares line (the mean when they do
//! not spread), which is unbiased on a sloped profile; a cell whose points
//! lie all on one side of its centre (a frame's ragged end) is not used.
//!
//! # Registration
//!
//! Each frame's heights are relative to the head, which bounces and pitches
//! on the trolley: between frames the whole profile may move by an offset
//! and tilt. Frames are taken in the order they come — a recording's, the
//! order the head travelled, whichever way ([`Stitcher`]; [`stitch`] takes a
//! slice in odometer order).
//!
//! [`Registration::Joint`] (the default) solves one offset per frame,
//! common to its lines (the head is rigid), from all overlaps of all lines
//! together — each frame with every later frame it overlaps, each cell
//! weighted by its noise — by a fixed-lag least squares ([`solve`]: why,
//! and why the head's roll is left to the null lines);
//! [`Registration::JointPitch`] solves the pitch too. The solve's own
//! error, common to all lines where no null line sees it, is propagated
//! per band ([`share`], [`Stitching::share`]) for the floor to add.
//!
//! [`Registration::Offset`] and [`Registration::OffsetTilt`] register each
//! line on its own: each frame onto what has been stitched before it, by
//! the least-squares offset (and, if asked, tilt, when the overlap is at
//! least [`Options::min_tilt_overlap_mm`] long) of the frame's values minus
//! the stitched ones over the cells they share, subtracted from the whole
//! frame. This chains: each frame's error carries into the ones after it,
//! a random walk in height for offsets (measured on 2 m of synthetic rail,
//! 35 mm overlaps, 2 µm noise per point, ±20 µm of bounce: 0.67 µm RMS
//! left, against 6.5 µm without registration) and in *slope*, integrated,
//! for tilts (the same rail with ±0.2 µm/mm of pitch per frame is left
//! with 8.5 µm RMS: more than the pitch cost, 6.6 µm; figures in
//! `host/tests/it/analyze/mod.rs`). The offset-only lanes also choose the
//! direction.
//!
//! Either way a frame is then averaged in (weighted by its points per
//! cell). A frame that overlaps less than [`Options::min_overlap_mm`]
//! cannot be registered: it is added as it is, and the join is reported
//! (an *unregistered join*; across a gap it starts a new run). The
//! registration's residual RMS over the overlap (the corrected frame
//! against what was stitched before it) is kept per frame: with a rigid
//! head it is the sensor noise averaged over a cell; a wrong direction or
//! a bad odometer shows up there first.
//!
//! # Gaps
//!
//! Cells no frame covered are NaN; every stretch of them inside the profile
//! is a [`Gap`] (position, length). The standards' analyses split the profile
//! there and never interpolate across.
//!
//! # Cost
//!
//! `O(P log P)` for P points (sorting each frame's points into cells) plus
//! `O(C)` per frame for C cells it covers (the joint solve adds a few
//! hundred flops per cell and a small dense solve per frame). Memory does not grow with the
//! track: each lane (two per laser, one per direction; three or four when
//! the registration is not offset-only) keeps its cells in a
//! [`Cells`] store (≈ 1 MB in memory, the rest in a temporary file) and
//! its [`FrameFit`]s in a [`FitLog`], not the frames: [`Stitcher`]
//! streams. A grid longer than [`MAX_CELLS`] is refused; a temporary
//! file that fails is [`StitchError::Spill`].

use cms_core::protocol::LASERS;

mod assemble;
mod joint;
mod peek;
pub mod share;
pub mod solve;

pub use assemble::FrameAssembler;
pub use share::StitchShare;

use super::store::{Cells, FitLog, Samples};
pub use super::store::{Gap, gaps_in};

/// Most cells of a stitched profile (20 km at 1 mm).
pub const MAX_CELLS: usize = 20_000_000;

/// One frame's calibrated points, per laser: `(along_mm, height_um)`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FramePoints {
    /// Frame sequence number.
    pub seq: u32,
    /// Odometer at the exposure, mm.
    pub odometer_mm: f64,
    /// Per laser, its points (along the line, mm; height, µm).
    pub lasers: [Vec<(f64, f64)>; LASERS],
}

impl FramePoints {
    /// Number of points over all lasers.
    pub fn points(&self) -> usize {
        self.lasers.iter().map(Vec::len).sum()
    }
}

/// How image rows map onto the track.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// `x = odometer + along`.
    Forward,
    /// `x = odometer − along`.
    Reverse,
    /// Whichever registers better (forward when they tie).
    Auto,
}

/// What registration corrects per frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Registration {
    /// Nothing: frames averaged as they are.
    None,
    /// A height offset.
    Offset,
    /// A height offset and a tilt.
    OffsetTilt,
    /// One height offset per frame, common to its lines, solved from all
    /// overlaps of all lines together ([`solve`]).
    Joint,
    /// [`Registration::Joint`] with the head's pitch (a tilt common to the lines).
    JointPitch,
}

impl Registration {
    /// Whether frames are registered by the joint solve.
    pub fn is_joint(self) -> bool {
        matches!(self, Registration::Joint | Registration::JointPitch)
    }
}

/// Options of [`stitch`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// Grid spacing, mm.
    pub dx_mm: f64,
    pub direction: Direction,
    pub registration: Registration,
    /// Shortest overlap that registers a frame, mm.
    pub min_overlap_mm: f64,
    /// Shortest overlap that also estimates a tilt, mm.
    pub min_tilt_overlap_mm: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            dx_mm: 1.0,
            direction: Direction::Auto,
            registration: Registration::Joint,
            min_overlap_mm: 3.0,
            min_tilt_overlap_mm: 10.0,
        }
    }
}

/// Why stitching failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StitchError {
    /// The grid spacing is not a positive finite number.
    #[error("sample spacing {0} mm is not a positive finite number")]
    BadSpacing(f64),
    /// No frame has a calibrated point.
    #[error("no calibrated points (the head had no calibration loaded: see cms-host calibrate upload)")]
    NoPoints,
    /// The frames span more than [`MAX_CELLS`] cells.
    #[error("the frames span {span_mm:.0} mm of track: more than {MAX_CELLS} samples at {dx_mm} mm (odometer jumps?)")]
    TooLong { span_mm: f64, dx_mm: f64 },
    /// The temporary file holding a long profile failed (the error's text:
    /// an I/O error is not `Clone`).
    #[error("cannot keep the stitched profile in a temporary file: {0}")]
    Spill(String),
}

/// How one frame was registered.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameFit {
    pub seq: u32,
    /// Track position of the frame's centre, mm.
    pub centre_mm: f64,
    /// Length of its overlap with the frames before it, mm.
    pub overlap_mm: f64,
    /// Offset subtracted, µm (at the overlap's centre; at the frame's
    /// centre with the joint registration).
    pub offset_um: f64,
    /// Tilt subtracted, µm per mm.
    pub tilt_um_per_mm: f64,
    /// RMS of frame minus stitched over the overlap after the correction, µm.
    pub residual_um: f64,
}

/// A frame added without registration (too little overlap).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Join {
    pub seq: u32,
    /// Track position of the frame's first sample, mm.
    pub at_mm: f64,
    /// Its overlap with the frames before it, mm (0: none).
    pub overlap_mm: f64,
}

/// One laser's stitched profile.
#[derive(Debug, Clone)]
pub struct Stitched {
    pub laser: usize,
    /// The section of the survey line it lies on, from 1 (a stretch
    /// measured without a gap longer than a section gap:
    /// [`crate::analyze::survey::JoinOptions::section_gap_mm`]).
    pub section: usize,
    /// Track position of sample 0, mm.
    pub x0_mm: f64,
    pub dx_mm: f64,
    /// Heights, µm; NaN where no frame covered the track.
    pub z: Samples,
    /// Frames that contributed.
    pub frames: usize,
    /// Points that contributed.
    pub points: usize,
    /// Runs averaged on the line: the harmonic mean over its samples of
    /// how many runs' samples were averaged there, so that noise
    /// independent from run to run has `1 / runs_averaged` of one run's
    /// power (1 for one run; see [`crate::analyze::survey`]).
    pub runs_averaged: f64,
    /// Registered frames.
    pub fits: FitLog,
    /// Frames joined without registration (the first frame is not one).
    pub joins: Vec<Join>,
    pub gaps: Vec<Gap>,
}

impl Stitched {
    /// Track position of sample `i`, mm.
    pub fn x_mm(&self, i: usize) -> f64 {
        self.x0_mm + i as f64 * self.dx_mm
    }

    /// Length from the first to past the last sample, mm.
    pub fn length_mm(&self) -> f64 {
        self.z.len() as f64 * self.dx_mm
    }

    /// Length of the samples with data, mm.
    pub fn covered_mm(&self) -> f64 {
        self.z.finite() as f64 * self.dx_mm
    }

    /// Median registration residual, µm (`None` without registrations).
    pub fn median_residual_um(&self) -> Option<f64> {
        self.fits.median_residual_um()
    }
}

/// The outcome of [`stitch`]: one profile per laser that has points.
#[derive(Debug, Clone)]
pub struct Stitching {
    /// The direction used (never `Auto`).
    pub direction: Direction,
    /// Median registration residual (offsets only, busiest laser) of
    /// forward and reverse, µm: what [`Direction::Auto`] chooses by, and
    /// what a given direction is checked against (`None`: not stitched
    /// from frames).
    pub direction_residuals_um: Option<(Option<f64>, Option<f64>)>,
    /// Whether the direction was given (not [`Direction::Auto`]).
    pub direction_given: bool,
    pub lasers: Vec<Stitched>,
    /// The joint registration's own error per band, common to all lines
    /// (`None`: not registered jointly).
    pub share: Option<StitchShare>,
}

/// The direction that registers better wins when its median residual is
/// under this share of the other's (a flat rail ties: forward is kept).
const DIRECTION_AGREEMENT: f64 = 0.8;

impl Stitching {
    /// With a given direction: the other direction's median residual and
    /// the given one's, µm, when the other registered clearly better (the
    /// test [`Direction::Auto`] chooses by). The profile is stitched as the
    /// user said; the report says the frames disagree.
    pub fn direction_disputed(&self) -> Option<(f64, f64)> {
        let (Some((Some(fwd), Some(rev))), true) = (self.direction_residuals_um, self.direction_given) else {
            return None;
        };
        let (used, other) = if self.direction == Direction::Reverse { (rev, fwd) } else { (fwd, rev) };
        (other < DIRECTION_AGREEMENT * used).then_some((other, used))
    }
}

/// Median of finite values (`None` if there are none).
pub fn median(mut v: Vec<f64>) -> Option<f64> {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) })
}

/// Stitches every laser of `frames` (in any order: they are taken in
/// odometer order, as a recording of a trolley pushed one way holds them).
pub fn stitch(frames: &[FramePoints], opts: &Options) -> Result<Stitching, StitchError> {
    let mut order: Vec<&FramePoints> = frames.iter().collect();
    order.sort_by(|a, b| a.odometer_mm.total_cmp(&b.odometer_mm));
    let mut s = Stitcher::new(opts)?;
    for f in order {
        s.push(f);
    }
    s.finish()
}

/// The streaming stitcher: frames pushed one at a time, in the order the
/// head travelled (a recording's order), each registered onto what was
/// stitched before it. Memory is the grids (16 bytes per cell and lane:
/// 27 MB per lane for 1.7 km at 1 mm) and one fit per frame, not the
/// frames: a recording of any length streams through it.
///
/// A lane is one laser, one direction and one registration. Every laser
/// is stitched both ways at once, and at [`Stitcher::finish`] the
/// offset-only lanes of the busiest laser (extra lanes when the
/// registration asked for is not offset-only) choose the direction
/// ([`Direction::Auto`]) or check the one given
/// ([`Stitching::direction_disputed`]), exactly as the frames would have
/// been stitched twice.
pub struct Stitcher {
    opts: Options,
    lanes: Vec<Lane>,
    /// The joint solve of each direction a joint lane is stitched in.
    joints: Vec<joint::JointSolve>,
    /// Finite points per laser.
    points: [usize; LASERS],
    error: Option<StitchError>,
}

/// One laser stitched one way.
struct Lane {
    laser: usize,
    sign: f64,
    registration: Registration,
    /// Lattice indices (cell centre at `index · dx`) `lo..=hi` the frames
    /// covered (`None` before the first).
    span: Option<(i64, i64)>,
    /// Per cell: sum of weighted values, µm, and the weight (points).
    cells: Cells,
    fits: FitLog,
    joins: Vec<Join>,
    frames: usize,
    points: usize,
}

impl Stitcher {
    /// A stitcher for `opts` (its spacing checked here, once).
    pub fn new(opts: &Options) -> Result<Stitcher, StitchError> {
        if !(opts.dx_mm.is_finite() && opts.dx_mm > 0.0) {
            return Err(StitchError::BadSpacing(opts.dx_mm));
        }
        // (sign, registration) of the lanes, by sign (a frame's cells are
        // made once per sign). The direction is judged with offsets only:
        // a wrong sign must not be rescued by tilts.
        let mut kinds: Vec<(f64, Registration)> = vec![(1.0, Registration::Offset), (-1.0, Registration::Offset)];
        match opts.direction {
            _ if opts.registration == Registration::Offset => {}
            Direction::Auto => kinds.extend([(1.0, opts.registration), (-1.0, opts.registration)]),
            Direction::Forward => kinds.push((1.0, opts.registration)),
            Direction::Reverse => kinds.push((-1.0, opts.registration)),
        }
        kinds.sort_by(|a, b| b.0.total_cmp(&a.0));
        let mut lanes = Vec::new();
        for laser in 0..LASERS {
            for &(sign, registration) in &kinds {
                lanes.push(Lane {
                    laser,
                    sign,
                    registration,
                    span: None,
                    cells: Cells::default(),
                    fits: FitLog::default(),
                    joins: Vec::new(),
                    frames: 0,
                    points: 0,
                });
            }
        }
        let joints = if opts.registration.is_joint() {
            kinds.iter().filter(|k| k.1 == opts.registration).map(|k| joint::JointSolve::new(k.0, opts)).collect()
        } else {
            Vec::new()
        };
        Ok(Stitcher { opts: *opts, lanes, joints, points: [0; LASERS], error: None })
    }

    /// Adds one frame. A frame that would stretch a profile beyond
    /// [`MAX_CELLS`] is left out, and [`Stitcher::finish`] says so.
    pub fn push(&mut self, f: &FramePoints) {
        if !f.odometer_mm.is_finite() || self.error.is_some() {
            return;
        }
        for k in 0..LASERS {
            self.points[k] += f.lasers[k].iter().filter(|p| finite(**p)).count();
        }
        if let Err(e) = self.push_frame(f) {
            self.error = Some(e);
        }
    }

    fn push_frame(&mut self, f: &FramePoints) -> Result<(), StitchError> {
        for sign in [1.0, -1.0] {
            if !self.lanes.iter().any(|l| l.sign == sign) {
                continue;
            }
            let cells: [Vec<(i64, f64, usize)>; LASERS] =
                std::array::from_fn(|k| frame_cells(&f.lasers[k], f.odometer_mm, sign, self.opts.dx_mm));
            for lane in self.lanes.iter_mut().filter(|l| l.sign == sign && !l.registration.is_joint()) {
                if !cells[lane.laser].is_empty() {
                    lane.add(f.seq, &cells[lane.laser], &self.opts)?;
                }
            }
            if let Some(j) = self.joints.iter_mut().find(|j| j.sign == sign) {
                j.push(f.seq, cells, &mut self.lanes)?;
            }
        }
        Ok(())
    }

    /// The profiles: the direction chosen (with `Auto`), every laser that
    /// had points.
    pub fn finish(mut self) -> Result<Stitching, StitchError> {
        let (with_points, direction, residuals) = self.choice()?;
        let dx = self.opts.dx_mm;
        let sign = if direction == Direction::Reverse { -1.0 } else { 1.0 };
        let mut share = None;
        if let Some(j) = self.joints.iter_mut().find(|j| j.sign == sign) {
            share = j.finish(&mut self.lanes)?;
        }
        let registration = self.opts.registration;
        let lasers = self
            .lanes
            .into_iter()
            .filter(|l| l.sign == sign && l.registration == registration && with_points.contains(&l.laser))
            .map(|l| l.into_stitched(dx))
            .collect::<Result<Vec<Stitched>, StitchError>>()?;
        let direction_given = self.opts.direction != Direction::Auto;
        Ok(Stitching { direction, direction_residuals_um: Some(residuals), direction_given, lasers, share })
    }

    /// The lasers with points, the direction ([`Direction::Auto`] chosen)
    /// and the median residuals of forward and reverse.
    #[allow(clippy::type_complexity)]
    fn choice(&self) -> Result<(Vec<usize>, Direction, (Option<f64>, Option<f64>)), StitchError> {
        if let Some(e) = &self.error {
            return Err(e.clone());
        }
        let with_points: Vec<usize> = (0..LASERS).filter(|&k| self.points[k] > 0).collect();
        let Some(&busiest) = with_points.iter().max_by_key(|&&k| self.points[k]) else {
            return Err(StitchError::NoPoints);
        };
        let probe = |sign: f64| {
            self.lanes
                .iter()
                .find(|l| l.laser == busiest && l.sign == sign && l.registration == Registration::Offset)
                .and_then(|l| l.fits.median_residual_um())
        };
        let (fwd, rev) = (probe(1.0), probe(-1.0));
        let direction = match (self.opts.direction, fwd, rev) {
            (Direction::Auto, Some(f), Some(r)) if r < DIRECTION_AGREEMENT * f => Direction::Reverse,
            (Direction::Auto, _, _) => Direction::Forward,
            (d, _, _) => d,
        };
        Ok((with_points, direction, (fwd, rev)))
    }
}

/// One frame's cells for `x = odometer + sign·along`: (lattice index,
/// value µm, points), ascending.
fn frame_cells(pts: &[(f64, f64)], odometer_mm: f64, sign: f64, dx: f64) -> Vec<(i64, f64, usize)> {
    let mut p: Vec<(i64, f64, f64)> = pts
        .iter()
        .filter(|p| finite(**p))
        .map(|&(a, h)| {
            let x = odometer_mm + sign * a;
            let c = (x / dx).round();
            // `as` saturates: an absurd odometer lands far away, and the
            // lane's span check refuses it.
            (c as i64, x - c * dx, h)
        })
        .collect();
    p.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    let mut cells = Vec::new();
    for group in p.chunk_by(|a, b| a.0 == b.0) {
        if let Some(v) = cell_value(group, dx) {
            cells.push((group[0].0, v, group.len()));
        }
    }
    cells
}

impl Lane {
    /// Registers one frame's cells onto the lane and adds them.
    fn add(&mut self, seq: u32, cells: &[(i64, f64, usize)], opts: &Options) -> Result<(), StitchError> {
        let dx = opts.dx_mm;
        let (lo, hi) = (cells[0].0, cells[cells.len() - 1].0);
        let (new_lo, new_hi) = self.span.map_or((lo, hi), |(a, b)| (a.min(lo), b.max(hi)));
        let span = new_hi.saturating_sub(new_lo);
        if span >= MAX_CELLS as i64 - 1 {
            return Err(StitchError::TooLong { span_mm: span as f64 * dx, dx_mm: dx });
        }
        self.span = Some((new_lo, new_hi));
        let mut overlap: Vec<(f64, f64)> = Vec::with_capacity(cells.len());
        for &(c, v, _) in cells {
            let (sum, w) = self.cells.get(c).map_err(spill)?;
            if w > 0 {
                overlap.push((c as f64 * dx, v - sum / w as f64));
            }
        }
        let overlap_mm = match (overlap.first(), overlap.last()) {
            (Some(a), Some(b)) => b.0 - a.0 + dx,
            _ => 0.0,
        };
        let centre_mm = (lo as f64 + hi as f64) / 2.0 * dx;
        // The registration's correction `a + b·(x − xm)`, subtracted as the
        // cells are added (none for the first frame or a join).
        let mut correction = (0.0, 0.0, 0.0);
        if self.frames > 0 && self.registration != Registration::None {
            if overlap.len() >= 2 && overlap_mm >= opts.min_overlap_mm {
                let tilt = self.registration == Registration::OffsetTilt && overlap_mm >= opts.min_tilt_overlap_mm;
                let (xm, a, b) = line(&overlap, tilt);
                correction = (xm, a, b);
                let rss: f64 = overlap.iter().map(|&(x, d)| (d - a - b * (x - xm)).powi(2)).sum();
                self.fits.push(FrameFit {
                    seq,
                    centre_mm,
                    overlap_mm,
                    offset_um: a,
                    tilt_um_per_mm: b,
                    residual_um: (rss / overlap.len() as f64).sqrt(),
                });
                if let Some(e) = self.fits.error() {
                    return Err(StitchError::Spill(e.to_string()));
                }
            } else {
                self.joins.push(Join { seq, at_mm: lo as f64 * dx, overlap_mm });
            }
        }
        let (xm, a, b) = correction;
        for &(c, v, w) in cells {
            let v = v - (a + b * (c as f64 * dx - xm));
            // A cell holds one frame's points: far below u32::MAX.
            self.cells.add(c, v * w as f64, w as u32).map_err(spill)?;
            self.points += w;
        }
        self.frames += 1;
        Ok(())
    }

    /// The lane's profile (its cells handed over, not copied), gaps listed.
    fn into_stitched(self, dx: f64) -> Result<Stitched, StitchError> {
        // The grid only ever grows to a frame's cells, so its ends have data.
        let (lo, hi) = self.span.unwrap_or((0, -1));
        let x0_mm = lo as f64 * dx;
        let z = Samples::from_cells(self.cells, lo, (hi - lo + 1) as usize, 0);
        let (gaps, finite) = gaps_in(x0_mm, dx, &z).map_err(spill)?;
        Ok(Stitched {
            laser: self.laser,
            section: 1,
            x0_mm,
            dx_mm: dx,
            z: z.counted(finite),
            frames: self.frames,
            points: self.points,
            runs_averaged: 1.0,
            fits: self.fits,
            joins: self.joins,
            gaps,
        })
    }
}

fn spill(e: std::io::Error) -> StitchError {
    StitchError::Spill(e.to_string())
}

/// The runs of missing samples of a profile.
pub fn gaps(x0_mm: f64, dx_mm: f64, z_um: &[f64]) -> Vec<Gap> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < z_um.len() {
        if z_um[i].is_finite() {
            i += 1;
            continue;
        }
        let s = i;
        while i < z_um.len() && !z_um[i].is_finite() {
            i += 1;
        }
        out.push(Gap { start_mm: x0_mm + s as f64 * dx_mm, length_mm: (i - s) as f64 * dx_mm });
    }
    out
}

fn finite(p: (f64, f64)) -> bool {
    p.0.is_finite() && p.1.is_finite()
}

/// A cell's value at its centre from its points `(cell, x − centre, h)`
/// (sorted by x): the least-squares line's intercept, or the mean when the
/// points do not spread; `None` when they lie all on one side of the centre.
fn cell_value(group: &[(i64, f64, f64)], dx: f64) -> Option<f64> {
    let (first, last) = (group[0].1, group[group.len() - 1].1);
    let tol = 1e-9 * dx;
    if first > tol || last < -tol {
        return None;
    }
    let n = group.len() as f64;
    let mx = group.iter().map(|p| p.1).sum::<f64>() / n;
    let mh = group.iter().map(|p| p.2).sum::<f64>() / n;
    let (mut sxx, mut sxh) = (0.0, 0.0);
    for p in group {
        sxx += (p.1 - mx).powi(2);
        sxh += (p.1 - mx) * (p.2 - mh);
    }
    if group.len() < 3 || sxx < 1e-6 * dx * dx * n {
        return Some(mh);
    }
    Some(mh - sxh / sxx * mx)
}

/// Least-squares `d ≈ a + b·(x − xm)` (b = 0 unless `tilt`); returns (xm, a, b).
fn line(pts: &[(f64, f64)], tilt: bool) -> (f64, f64, f64) {
    let n = pts.len() as f64;
    let xm = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let a = pts.iter().map(|p| p.1).sum::<f64>() / n;
    if !tilt {
        return (xm, a, 0.0);
    }
    let (mut sxx, mut sxd) = (0.0, 0.0);
    for &(x, d) in pts {
        sxx += (x - xm) * (x - xm);
        sxd += (x - xm) * (d - a);
    }
    let b = if sxx > 0.0 { sxd / sxx } else { 0.0 };
    (xm, a, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame of `len_mm` of a sine profile seen from odometer `o`, points every `step` mm.
    fn frame(seq: u32, o: f64, len_mm: f64, step: f64, z: impl Fn(f64) -> f64) -> FramePoints {
        let mut f = FramePoints { seq, odometer_mm: o, ..FramePoints::default() };
        let n = (len_mm / step) as usize;
        f.lasers[1] = (0..=n).map(|i| -len_mm / 2.0 + i as f64 * step).map(|a| (a, z(o + a))).collect();
        f
    }

    #[test]
    fn cell_value_is_the_intercept_on_a_slope() {
        let g: Vec<(i64, f64, f64)> =
            (0..7).map(|i| (0, -0.4 + 0.13 * i as f64, 3.0 + 2.0 * (-0.4 + 0.13 * i as f64))).collect();
        assert!((cell_value(&g, 1.0).unwrap() - 3.0).abs() < 1e-12);
        // All on one side: not used.
        assert_eq!(cell_value(&g[4..], 1.0), None);
    }

    #[test]
    fn overlapping_frames_of_a_rigid_head_stitch_exactly() {
        let z = |x: f64| 30.0 * (x * std::f64::consts::TAU / 50.0).sin();
        let frames: Vec<FramePoints> = (0..20).map(|i| frame(i, 33.0 * i as f64, 68.0, 0.143, z)).collect();
        let s = stitch(&frames, &Options::default()).unwrap();
        assert_eq!(s.direction, Direction::Forward);
        let l = &s.lasers[0];
        assert!(l.gaps.is_empty() && l.joins.is_empty() && l.fits.len() == 19, "{l:?}");
        let worst = (0..l.z.len()).map(|i| (l.z.to_vec().unwrap()[i] - z(l.x_mm(i))).abs()).fold(0.0, f64::max);
        // The cell intercept is exact on a line; the sine's curvature over ±0.5 mm leaves < 0.1 µm.
        assert!(worst < 0.1, "{worst}");
    }

    #[test]
    fn a_trolley_pushed_backwards_stitches_the_same_profile() {
        let z = |x: f64| 30.0 * (x * std::f64::consts::TAU / 50.0).sin() + 10.0 * (x / 23.0).cos();
        let frames: Vec<FramePoints> = (0..30).map(|i| frame(i, 1000.0 + 25.0 * i as f64, 68.0, 0.143, z)).collect();
        let opts = Options { direction: Direction::Forward, ..Options::default() };
        let mut ahead = Stitcher::new(&opts).unwrap();
        let mut back = Stitcher::new(&opts).unwrap();
        frames.iter().for_each(|f| ahead.push(f));
        frames.iter().rev().for_each(|f| back.push(f));
        let (a, b) = (ahead.finish().unwrap(), back.finish().unwrap());
        let (a, b) = (&a.lasers[0], &b.lasers[0]);
        assert_eq!((a.x0_mm, a.z.len(), a.fits.len()), (b.x0_mm, b.z.len(), b.fits.len()));
        let worst =
            a.z.to_vec().unwrap().iter().zip(&b.z.to_vec().unwrap()).map(|(p, q)| (p - q).abs()).fold(0.0, f64::max);
        // Registration order differs; the cells' curvature error (< 0.1 µm) then does too.
        assert!(worst < 0.01, "{worst}");
        let truth = (0..b.z.len()).map(|i| (b.z.to_vec().unwrap()[i] - z(b.x_mm(i))).abs()).fold(0.0, f64::max);
        assert!(truth < 0.1, "{truth}");
    }

    #[test]
    fn absurd_odometers_are_refused_not_allocated() {
        let z = |_: f64| 0.0;
        for far in [9.0e15, 1.0e300, -1.0e300] {
            let frames = [frame(0, 100.0, 68.0, 0.143, z), frame(1, far, 68.0, 0.143, z)];
            let mut s = Stitcher::new(&Options::default()).unwrap();
            frames.iter().for_each(|f| s.push(f));
            assert!(matches!(s.finish(), Err(StitchError::TooLong { .. })), "{far}");
        }
    }

    #[test]
    fn reversed_mounting_is_found() {
        let z = |x: f64| 30.0 * (x * std::f64::consts::TAU / 50.0).sin() + 10.0 * (x / 23.0).cos();
        let frames: Vec<FramePoints> = (0..20)
            .map(|i| {
                let mut f = frame(i, 30.0 * i as f64, 68.0, 0.2, z);
                // The head sees the rail mirrored: along = odometer − x.
                for p in &mut f.lasers[1] {
                    p.0 = -p.0;
                }
                f
            })
            .collect();
        let s = stitch(&frames, &Options::default()).unwrap();
        assert_eq!(s.direction, Direction::Reverse, "{:?}", s.direction_residuals_um);
    }

    #[test]
    fn assembler_joins_parts_and_skips_uncalibrated_points() {
        use cms_core::fixed::Px;
        use cms_core::peak::Flags;
        use cms_core::protocol::{LaserPoints, Metric, Point, Profile};
        let pt = |m: Option<Metric>| Point {
            row: 0,
            position: Px::from_f64(1.0),
            strength: 1,
            width: Px::from_f64(1.0),
            flags: Flags::NONE,
            metric: m,
        };
        let msg = |seq: u32, part: u8, metric: Option<Metric>| {
            let mut p = Profile { seq, part, parts: 2, odometer_um: 1500, ..Profile::EMPTY };
            let mut lp = LaserPoints { laser: 2, points: heapless::Vec::new() };
            lp.points.push(pt(metric)).unwrap();
            p.lasers.push(lp).unwrap();
            p
        };
        let m = Some(Metric { along_um: -2500, height_nm: 12_000 });
        let mut a = FrameAssembler::default();
        assert!(a.push(&msg(7, 0, m)).is_none());
        assert!(a.push(&msg(7, 1, None)).is_none());
        let f = a.push(&msg(8, 0, m)).unwrap();
        assert_eq!((f.seq, f.odometer_mm, f.lasers[2].clone()), (7, 1.5, vec![(-2.5, 12.0)]));
        assert_eq!((a.calibrated_points, a.uncalibrated_points), (2, 1));
        assert_eq!(a.finish().unwrap().seq, 8);
    }
}
