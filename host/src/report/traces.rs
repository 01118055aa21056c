//! The lines' plotted traces, gathered in one walk along the survey line
//! ([`Analysis::for_each_piece`]) and thinned as they come: each
//! continuous run cut into buckets of consecutive samples, each bucket
//! kept as its lowest and highest point (in track order), so that a plot
//! of any length of track holds at most a few thousand points per line
//! and still shows every peak.

use crate::Error;
use crate::analyze::pieces::Piece;
use crate::analyze::reprofiling::Edition;
use crate::analyze::standards::en13231;
use crate::analyze::{Analysis, stitch};

/// Continuous pieces of a plotted line.
pub type Pieces = Vec<Vec<(f64, f64)>>;

/// A bucket's lowest and highest points (x, y) and its samples.
type Bucket = ((f64, f64), (f64, f64), usize);

/// One series thinned to min/max buckets of `per` samples.
struct Thinned {
    x0: f64,
    dx: f64,
    per: usize,
    /// The bucket being filled.
    bucket: Option<Bucket>,
    piece: Vec<(f64, f64)>,
    out: Pieces,
}

impl Thinned {
    fn new(per: usize) -> Thinned {
        Thinned { x0: 0.0, dx: 1.0, per: per.max(1), bucket: None, piece: Vec::new(), out: Vec::new() }
    }

    /// Sample `i` of a grid from `x0` at `dx` (a NaN ends a run).
    fn push(&mut self, i: usize, v: f64) {
        if !v.is_finite() {
            self.end_run();
            return;
        }
        let x = self.x0 + i as f64 * self.dx;
        let b = self.bucket.get_or_insert(((x, v), (x, v), 0));
        if v < b.0.1 {
            b.0 = (x, v);
        }
        if v > b.1.1 {
            b.1 = (x, v);
        }
        b.2 += 1;
        if b.2 >= self.per {
            self.flush();
        }
    }

    fn flush(&mut self) {
        if let Some((lo, hi, _)) = self.bucket.take() {
            let (a, b) = if lo.0 <= hi.0 { (lo, hi) } else { (hi, lo) };
            self.piece.push(a);
            if b != a {
                self.piece.push(b);
            }
        }
    }

    fn end_run(&mut self) {
        self.flush();
        if !self.piece.is_empty() {
            self.out.push(std::mem::take(&mut self.piece));
        }
    }

    /// Starts a grid (a section): the run before it ends.
    fn grid(&mut self, x0: f64, dx: f64) {
        self.end_run();
        (self.x0, self.dx) = (x0, dx);
    }

    fn finish(mut self) -> Pieces {
        self.end_run();
        self.out
    }
}

/// One line's plotted traces.
#[derive(Debug, Default)]
pub struct LineTraces {
    /// Heights less their median, µm, at track position mm.
    pub profile: Pieces,
    /// Per EN 13231-3 band: its values and its window mean peak-to-peak, µm, at mm.
    pub band: Vec<Pieces>,
    pub mean_pp: Vec<Pieces>,
    /// Per band: the edition's criterion, µm, at chainage m.
    pub criterion: Vec<Pieces>,
}

/// Every line's traces, in the order of [`Analysis::lasers`], the profile
/// with at most `max_points` points a line and the criterion half that:
/// a walk of its own ([`Gather`] takes part in another's).
pub fn of(a: &Analysis, max_points: usize) -> Result<Vec<LineTraces>, Error> {
    let mut g = Gather::new(a, max_points);
    a.for_each_piece(|p| {
        g.piece(p);
        Ok(())
    })?;
    Ok(g.finish())
}

/// One line's series as they are thinned.
struct Series {
    profile: Thinned,
    band: Vec<Thinned>,
    pp: Vec<Thinned>,
    criterion: Vec<Thinned>,
}

/// The traces of [`of`], gathered from the pieces of a walk along the
/// survey line ([`Analysis::for_each_piece`]) that writes other files too.
pub struct Gather {
    series: Vec<Series>,
    /// Where each section's lines start in `a.lasers`.
    first: std::collections::HashMap<usize, usize>,
    edition: Edition,
}

impl Gather {
    /// Ready for `a`'s pieces, at most `max_points` points a line.
    pub fn new(a: &Analysis, max_points: usize) -> Gather {
        let bands = en13231::BANDS.len();
        let per = |finite: usize, max: usize| (2 * finite.max(1)).div_ceil(max.max(2)).max(1);
        let series = a
            .lasers
            .iter()
            .map(|l| {
                let n = l.stitched.z.finite();
                let (p, c) = (per(n, max_points), per(n, max_points / 2));
                Series {
                    profile: Thinned::new(p),
                    band: (0..bands).map(|_| Thinned::new(p)).collect(),
                    pp: (0..bands).map(|_| Thinned::new(p)).collect(),
                    criterion: (0..bands).map(|_| Thinned::new(c)).collect(),
                }
            })
            .collect();
        let mut first = std::collections::HashMap::new();
        let mut at = 0;
        for s in &a.sections() {
            first.insert(s.number, at);
            at += s.lasers.len();
        }
        Gather { series, first, edition: a.verdict.options.edition }
    }

    /// Takes one piece's samples and band traces.
    pub fn piece(&mut self, p: &Piece) {
        let base = self.first.get(&p.section).copied().unwrap_or(0);
        let (x0, dx) = (p.grid.origin_mm, p.grid.dx_mm);
        for (k, l) in p.lines.iter().enumerate() {
            let Some(s) = self.series.get_mut(base + k) else { continue };
            let mut all: Vec<&mut Thinned> = vec![&mut s.profile];
            all.extend(s.band.iter_mut().chain(s.pp.iter_mut()));
            if p.core.start == 0 {
                all.iter_mut().for_each(|t| t.grid(x0, dx));
                s.criterion.iter_mut().for_each(|t| t.grid(x0 / 1000.0, dx / 1000.0));
            }
            for (j, &z) in l.z_um.iter().enumerate() {
                s.profile.push(p.core.start + j, z);
            }
            for (b, t) in l.bands.iter().enumerate() {
                let Some(t) = t else { continue };
                for (j, ((&v, &m), &band)) in t.band_mm.iter().zip(&t.mean_pp_mm).zip(&t.band_mm).enumerate() {
                    let i = p.core.start + j;
                    s.band[b].push(i, v * 1000.0);
                    s.pp[b].push(i, m * 1000.0);
                    let c = match self.edition {
                        Edition::En2006 => m,
                        Edition::En2012 if m.is_finite() => band.abs(),
                        Edition::En2012 => f64::NAN,
                    };
                    s.criterion[b].push(i, c * 1000.0);
                }
            }
        }
    }

    /// The traces, once every piece was taken.
    pub fn finish(self) -> Vec<LineTraces> {
        self.series
            .into_iter()
            .map(|s| {
                let mut profile = s.profile.finish();
                // The median of the thinned points: a plot's offset, not a figure.
                let m = stitch::median(profile.iter().flatten().map(|p| p.1).collect()).unwrap_or(0.0);
                profile.iter_mut().flatten().for_each(|p| p.1 -= m);
                LineTraces {
                    profile,
                    band: s.band.into_iter().map(Thinned::finish).collect(),
                    mean_pp: s.pp.into_iter().map(Thinned::finish).collect(),
                    criterion: s.criterion.into_iter().map(Thinned::finish).collect(),
                }
            })
            .collect()
    }
}
