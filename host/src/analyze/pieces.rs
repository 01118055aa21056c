//! A survey line walked along the track in pieces, so that its analysis
//! and everything written from it run in memory set by the standards'
//! windows and the verdict's blocks, never by the length of track.
//!
//! Each section ([`super::Section`]) is cut into *pieces*: whole blocks
//! of the verdict (at least [`CORE_MM`] of track), or, for a block longer
//! than that, equal parts of one block, whose figures the verdict sums
//! over its pieces ([`BlockPart`]). A piece's lines are read with a margin on either side
//! ([`margin_mm`]: half the longest EN 13231-3 window and 20 of the
//! band's longest wavelengths for its filters to settle, or an EN 15610
//! segment and the wheel's reach) and each band is filtered over the
//! whole stretch; only the core's values are kept. The figures summed
//! over the pieces are those of the whole line (the band filters' cut
//! transients are down by e⁻³² at the core, `pieces_equal_the_whole_line`
//! below); windows and spectrum segments are placed by the line's own
//! runs, not by where a piece is cut.
//!
//! Cost: each sample is filtered `(core + 2·margin) / core` times (1.45
//! for the default 50 m blocks: two blocks a piece); memory is one piece's
//! stretch per line and its traces.

use std::ops::Range;

use super::stitch::Stitched;
use super::store::ScratchError;
use super::{Grid, Options};
use crate::Error;
use crate::analyze::standards::en13231::{self, BandTrace};
use crate::analyze::standards::{Stretch, en15610, wheel};

/// Shortest core of a piece, mm (whole blocks are added until it is reached).
pub const CORE_MM: f64 = 100_000.0;

/// How far beyond its core a piece is read, mm.
pub fn margin_mm(opts: &Options) -> f64 {
    en13231::margin_mm().max(en15610::Welch::margin_mm(&opts.roughness))
}

/// One piece of a section: its lines over the core, on the section's grid.
#[derive(Debug)]
pub struct Piece {
    /// The section's number, from 1.
    pub section: usize,
    pub grid: Grid,
    /// Grid indices of the piece's own samples.
    pub core: Range<usize>,
    /// The section's lines, in its order (empty when not [`Wanted::lines`]).
    pub lines: Vec<PieceLine>,
    /// The running band's profile and the lines' null combinations, when
    /// [`Wanted`] and the section has two lines or more.
    pub band: Option<RunningBand>,
}

impl Piece {
    /// A piece of nothing (a table's columns without rows).
    pub fn empty() -> Piece {
        Piece {
            section: 0,
            grid: Grid { origin_mm: 0.0, dx_mm: 1.0, len: 0 },
            core: 0..0,
            lines: Vec::new(),
            band: None,
        }
    }
}

/// What a walk builds of each piece.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Wanted {
    /// Each line, with its band traces.
    pub lines: bool,
    /// The mean of the lines (the running band's profile), with its band traces.
    pub mean: bool,
    /// The lines' null combinations, with their band traces.
    pub nulls: bool,
}

impl Wanted {
    /// The lines alone (what plots and exports are written from).
    pub const LINES: Wanted = Wanted { lines: true, mean: false, nulls: false };
}

/// The running band seen through all its lines at once: their mean, and
/// their null combinations (Helmert contrasts: orthonormal, each line's
/// weight summing to zero). Rail that is common to the lines is in the
/// mean alone; a null combination holds only what differs among them —
/// speckle and sensor noise (independent on each line) and rail that is
/// not common across the band — with the statistics of one line's noise
/// when the lines' noises are alike. Both are defined where every line
/// of the section has a sample.
#[derive(Debug)]
pub struct RunningBand {
    /// How many lines were combined.
    pub lines: usize,
    /// Their mean (`laser` is [`MEAN_LINE`]; empty traces when not wanted).
    pub mean: PieceLine,
    /// `lines − 1` null combinations (`laser` is [`MEAN_LINE`] + 1 + j).
    pub nulls: Vec<PieceLine>,
}

/// The `laser` number of the running band's mean line (the nulls follow it).
pub const MEAN_LINE: usize = 1000;

/// One line of a piece.
#[derive(Debug)]
pub struct PieceLine {
    pub laser: usize,
    /// Heights over the core, µm (NaN where the line has none).
    pub z_um: Vec<f64>,
    /// Per EN 13231-3 band, its trace over the core (`None`: not evaluated).
    pub bands: Vec<Option<BandTrace>>,
    ext_z_um: Vec<f64>,
    ext_start: usize,
    /// The line's continuous runs (grid indices), all of them.
    runs: Vec<Range<usize>>,
    dx_mm: f64,
}

impl PieceLine {
    /// The stretch read for the piece: its core and margins.
    pub fn stretch(&self, core: Range<usize>) -> Stretch<'_> {
        Stretch { z_um: &self.ext_z_um, start: self.ext_start, core, runs: &self.runs, dx_mm: self.dx_mm }
    }

    /// The heights over the stretch read for the piece, µm.
    pub fn ext_z_um(&self) -> &[f64] {
        &self.ext_z_um
    }

    /// The line's runs cut to the grid indices `within`.
    pub fn runs_within(&self, within: &Range<usize>) -> Vec<Range<usize>> {
        self.runs.iter().map(|r| r.start.max(within.start)..r.end.min(within.end)).filter(|r| !r.is_empty()).collect()
    }

    /// The stretch read, with every sample outside the grid indices
    /// `within` a gap (a block seen on its own: its edges are run ends).
    pub fn masked(&self, within: &Range<usize>) -> Vec<f64> {
        let mut z = self.ext_z_um.clone();
        for (i, v) in z.iter_mut().enumerate() {
            if !within.contains(&(self.ext_start + i)) {
                *v = f64::NAN;
            }
        }
        z
    }

    pub fn dx_mm(&self) -> f64 {
        self.dx_mm
    }

    /// Grid index of the stretch's first sample.
    pub fn ext_start(&self) -> usize {
        self.ext_start
    }
}

/// A line's continuous runs, indices of its own samples (from its gaps).
pub fn runs(s: &Stitched) -> Vec<Range<usize>> {
    let mut out = Vec::new();
    let mut at = 0usize;
    for g in &s.gaps {
        let lo = ((g.start_mm - s.x0_mm) / s.dx_mm).round().max(0.0) as usize;
        let n = (g.length_mm / s.dx_mm).round() as usize;
        if lo > at {
            out.push(at..lo.min(s.z.len()));
        }
        at = (lo + n).min(s.z.len());
    }
    if at < s.z.len() {
        out.push(at..s.z.len());
    }
    out
}

/// The pieces' cores of a section on `grid`, from chainage multiples of
/// the block `opts.verdict.block_mm`: whole blocks, at least [`CORE_MM`]
/// each; a block longer than that is cut into equal pieces of at most
/// [`CORE_MM`], so that block edges are always piece edges.
pub fn cores(grid: &Grid, opts: &Options) -> Vec<Range<usize>> {
    let block = opts.verdict.block_mm;
    let first = (grid.origin_mm / block).floor() * block;
    let unit = if block <= CORE_MM { block * (CORE_MM / block).ceil() } else { block / (block / CORE_MM).ceil() };
    let at = |k: f64| (((first + k * unit - grid.origin_mm) / grid.dx_mm).ceil().max(0.0) as usize).min(grid.len);
    let mut out = Vec::new();
    let mut k = 0.0;
    let mut lo = 0;
    while lo < grid.len {
        k += 1.0;
        let hi = at(k);
        if hi > lo {
            out.push(lo..hi);
            lo = hi;
        }
    }
    out
}

/// Walks the lines of one section (`lines`, each with which bands to
/// trace) piece by piece, handing each piece to `f` with what `wanted`
/// asks for.
pub fn walk_section(
    section: usize,
    lines: &[(&Stitched, [bool; 4])],
    opts: &Options,
    wanted: Wanted,
    f: &mut dyn FnMut(&Piece) -> Result<(), Error>,
) -> Result<(), Error> {
    walk_section_weighted(section, lines, opts, wanted, None, f)
}

/// [`walk_section`], the running band's profile in each EN 13231-3 band
/// the lines weighted as `weights` says (per line, per band, summing to
/// one over the lines: [`crate::analyze::floor::Floor::running_band_weights`]);
/// `None`: their plain mean.
pub fn walk_section_weighted(
    section: usize,
    lines: &[(&Stitched, [bool; 4])],
    opts: &Options,
    wanted: Wanted,
    weights: Option<&[[f64; 4]]>,
    f: &mut dyn FnMut(&Piece) -> Result<(), Error>,
) -> Result<(), Error> {
    let Some(mut s) = Laid::new(section, lines, wanted) else { return Ok(()) };
    s.weights = weights.filter(|w| w.len() == lines.len()).map(<[[f64; 4]]>::to_vec);
    let margin = (margin_mm(opts) / s.grid.dx_mm).ceil() as usize;
    for core in cores(&s.grid, opts) {
        let ext = core.start.saturating_sub(margin)..(core.end + margin).min(s.grid.len);
        f(&s.piece(core, ext)?)?;
    }
    Ok(())
}

/// One piece of a section's lines (as [`walk_section`] makes them): the
/// grid indices `core`, read over `ext` (which holds it; cut to the
/// grid); `None` without lines. A stretch seen on its own, as the live
/// view sees the last one stitched, is one piece whose `ext` is all of it.
/// The running band's profile weighted as [`walk_section_weighted`]'s.
pub fn piece_of(
    section: usize,
    lines: &[(&Stitched, [bool; 4])],
    wanted: Wanted,
    core: Range<usize>,
    ext: Range<usize>,
    weights: Option<&[[f64; 4]]>,
) -> Result<Option<Piece>, Error> {
    let Some(mut s) = Laid::new(section, lines, wanted) else { return Ok(None) };
    s.weights = weights.filter(|w| w.len() == lines.len()).map(<[[f64; 4]]>::to_vec);
    let ext = ext.start.min(core.start)..ext.end.max(core.end).min(s.grid.len);
    let core = core.start.max(ext.start)..core.end.min(ext.end);
    s.piece(core, ext).map(Some)
}

/// A section's lines laid on their grid, with their runs.
struct Laid<'a> {
    section: usize,
    lines: &'a [(&'a Stitched, [bool; 4])],
    wanted: Wanted,
    grid: Grid,
    line_runs: Vec<Vec<Range<usize>>>,
    combine: bool,
    common: Vec<Range<usize>>,
    common_bands: [bool; 4],
    /// Per line, per band: its weight in the running band's profile (`None`: the plain mean).
    weights: Option<Vec<[f64; 4]>>,
}

impl<'a> Laid<'a> {
    fn new(section: usize, lines: &'a [(&'a Stitched, [bool; 4])], wanted: Wanted) -> Option<Laid<'a>> {
        let (first, _) = lines.first()?;
        let dx = first.dx_mm;
        let stitched: Vec<&Stitched> = lines.iter().map(|l| l.0).collect();
        let grid = Grid::of_lines(&stitched, dx);
        let line_runs: Vec<Vec<Range<usize>>> = stitched
            .iter()
            .map(|s| {
                let off = grid.offset(s);
                runs(s).into_iter().map(|r| r.start + off..r.end + off).collect()
            })
            .collect();
        let combine = (wanted.mean || wanted.nulls) && lines.len() >= 2;
        let common = if combine { common_runs(&line_runs) } else { Vec::new() };
        let common_bands = evaluated_on(&common, dx);
        Some(Laid { section, lines, wanted, grid, line_runs, combine, common, common_bands, weights: None })
    }

    /// The piece of `core`, its lines read over `ext`.
    fn piece(&self, core: Range<usize>, ext: Range<usize>) -> Result<Piece, Error> {
        let (grid, dx) = (self.grid, self.grid.dx_mm);
        let mut piece = Piece { section: self.section, grid, core: core.clone(), lines: Vec::new(), band: None };
        let mut read = Vec::new();
        for ((s, evaluate), runs) in self.lines.iter().zip(&self.line_runs) {
            let off = grid.offset(s);
            let mut z = vec![f64::NAN; ext.len()];
            // The line's own samples within the stretch.
            let (lo, hi) = (ext.start.max(off), ext.end.min(off + s.z.len()));
            if lo < hi {
                let v = s.z.read(lo - off..hi - off).map_err(ScratchError)?;
                z[lo - ext.start..lo - ext.start + v.len()].copy_from_slice(&v);
            }
            if self.combine {
                read.push(z.clone());
            }
            if self.wanted.lines {
                piece.lines.push(PieceLine::traced(s.laser, z, &ext, &core, runs.clone(), dx, evaluate));
            }
        }
        if self.combine {
            let weights = self.weights.as_deref();
            piece.band =
                Some(running_band(&read, &ext, &core, &self.common, dx, &self.common_bands, self.wanted, weights));
        }
        Ok(piece)
    }
}

impl PieceLine {
    /// A line over a stretch `ext` (grid indices) of heights `z`, with
    /// the traces of the bands `evaluate` names.
    fn traced(
        laser: usize,
        z: Vec<f64>,
        ext: &Range<usize>,
        core: &Range<usize>,
        runs: Vec<Range<usize>>,
        dx_mm: f64,
        evaluate: &[bool; 4],
    ) -> PieceLine {
        let mut line = PieceLine {
            laser,
            z_um: z[core.start - ext.start..core.end - ext.start].to_vec(),
            bands: Vec::new(),
            ext_z_um: z,
            ext_start: ext.start,
            runs,
            dx_mm,
        };
        let stretch = line.stretch(core.clone());
        line.bands = en13231::BANDS
            .iter()
            .zip(evaluate)
            .map(|(band, &yes)| if yes { en13231::trace(&stretch, band).ok() } else { None })
            .collect();
        line
    }
}

/// The runs every line has a sample in (grid indices, in order).
pub fn common_runs(line_runs: &[Vec<Range<usize>>]) -> Vec<Range<usize>> {
    let mut common = line_runs.first().cloned().unwrap_or_default();
    for runs in &line_runs[1.min(line_runs.len())..] {
        let mut next = Vec::new();
        for a in &common {
            for b in runs {
                let r = a.start.max(b.start)..a.end.min(b.end);
                if !r.is_empty() {
                    next.push(r);
                }
            }
        }
        common = next;
    }
    common
}

/// Which EN 13231-3 bands runs sampled `dx_mm` apart can evaluate.
pub fn evaluated_on(runs: &[Range<usize>], dx_mm: f64) -> [bool; 4] {
    let mut out = [false; 4];
    let samples = runs.last().map_or(0, |r| r.end);
    if let Ok(plan) = en13231::plan(runs, samples, dx_mm) {
        for (o, r) in out.iter_mut().zip(&plan.bands) {
            *o = r.outcome.is_ok();
        }
    }
    out
}

/// The running band of a piece from its lines' stretches `z` (each over
/// `ext`): the mean (in each band the lines weighted by `weights` where
/// given) and the Helmert contrasts
/// `n_j = (z_0 + … + z_{j−1} − j·z_j) / √(j(j+1))`, NaN where a line has none.
#[allow(clippy::too_many_arguments)]
fn running_band(
    z: &[Vec<f64>],
    ext: &Range<usize>,
    core: &Range<usize>,
    common: &[Range<usize>],
    dx_mm: f64,
    evaluate: &[bool; 4],
    wanted: Wanted,
    weights: Option<&[[f64; 4]]>,
) -> RunningBand {
    let k = z.len();
    let none = [false; 4];
    let combine = |weights: &dyn Fn(usize) -> f64| -> Vec<f64> {
        (0..ext.len())
            .map(|i| {
                let mut v = 0.0;
                for (line, zl) in z.iter().enumerate() {
                    v += weights(line) * zl[i];
                }
                v
            })
            .collect()
    };
    let plain = combine(&|_| 1.0 / k as f64);
    let mean = match weights {
        Some(w) if wanted.mean => {
            // Each band traced from its own weighted profile (the filters are per band).
            let mut mean = PieceLine::traced(MEAN_LINE, plain, ext, core, common.to_vec(), dx_mm, &none);
            for (b, &yes) in evaluate.iter().enumerate() {
                let only: [bool; 4] = std::array::from_fn(|c| c == b && yes);
                if !yes {
                    continue;
                }
                let weighted = combine(&|line| w[line][b]);
                let mut t = PieceLine::traced(MEAN_LINE, weighted, ext, core, common.to_vec(), dx_mm, &only);
                mean.bands[b] = t.bands[b].take();
            }
            mean
        }
        _ => PieceLine::traced(
            MEAN_LINE,
            plain,
            ext,
            core,
            common.to_vec(),
            dx_mm,
            if wanted.mean { evaluate } else { &none },
        ),
    };
    // The nulls are always formed (EN 15610's steps read the mean's noise
    // off them), traced only when wanted.
    let nulls = (1..k)
        .map(|j| {
            let norm = ((j * (j + 1)) as f64).sqrt();
            let n = combine(&|line| match line.cmp(&j) {
                std::cmp::Ordering::Less => 1.0 / norm,
                std::cmp::Ordering::Equal => -(j as f64) / norm,
                std::cmp::Ordering::Greater => 0.0,
            });
            let trace = if wanted.nulls { evaluate } else { &none };
            PieceLine::traced(MEAN_LINE + j, n, ext, core, common.to_vec(), dx_mm, trace)
        })
        .collect();
    RunningBand { lines: k, mean, nulls }
}

impl RunningBand {
    /// How EN 15610's nonlinear steps see the rail through the piece's
    /// noise (the mean's spectrum against its noise's, which the nulls
    /// measure: [`wheel`]).
    pub fn rail_steps(&self, opt: &en15610::Options) -> wheel::RailSteps {
        let nulls: Vec<&[f64]> = self.nulls.iter().map(|n| n.ext_z_um.as_slice()).collect();
        wheel::RailSteps::measure(&self.mean.ext_z_um, &nulls, self.lines, self.mean.dx_mm, opt)
    }

    /// The mean's noise to put through EN 15610's steps for the floor of
    /// the null `j`: `n_{j+1}/√k` (the next null, cyclically: the null
    /// `j` itself passes linearly, as a line's noise does, and its
    /// correction comes from noise independent of it with the mean's
    /// statistics; two lines, one null: `n_1/√2`). Over the stretch, NaN
    /// where not every line has a sample.
    pub fn mean_noise(&self, j: usize) -> Vec<f64> {
        let k = self.lines.max(2) as f64;
        let other = &self.nulls[(j + 1) % self.nulls.len().max(1)].ext_z_um;
        other.iter().map(|v| v / k.sqrt()).collect()
    }
}

/// A block of the verdict met by a piece.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockPart {
    /// Its samples in the piece (indices in the core).
    pub range: Range<usize>,
    /// Its chainage from and to, mm.
    pub span_mm: (f64, f64),
    /// All its samples (grid indices): a block longer than a piece is met
    /// by several, in order.
    pub grid: Range<usize>,
    /// Whether the piece holds its last sample.
    pub ends: bool,
}

/// The blocks a piece meets (blocks of `block_mm` from chainage multiples
/// of it, whole in a piece or spanning several whole pieces: [`cores`]).
pub fn blocks(p: &Piece, block_mm: f64) -> Vec<BlockPart> {
    let (dx, origin) = (p.grid.dx_mm, p.grid.origin_mm);
    let index = |x: f64| (((x - origin) / dx).ceil().max(0.0) as usize).min(p.grid.len);
    // The block holding the piece's first sample (its chainage divided
    // by the block length may round either way).
    let mut start = ((origin + p.core.start as f64 * dx) / block_mm).floor() * block_mm;
    if index(start + block_mm) <= p.core.start {
        start += block_mm;
    }
    if index(start) > p.core.start {
        start -= block_mm;
    }
    let mut out = Vec::new();
    while index(start) < p.core.end {
        let end = start + block_mm;
        let (lo, hi) = (index(start).max(p.core.start), index(end).min(p.core.end));
        if hi > lo {
            out.push(BlockPart {
                range: lo - p.core.start..hi - p.core.start,
                span_mm: (start, end),
                grid: index(start)..index(end),
                ends: index(end) <= p.core.end,
            });
        }
        start = end;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analyze::stitch::{Direction, Stitching};
    use crate::analyze::{judge, profile};

    /// A line judged in pieces has the figures of the whole line judged at
    /// once: the band filters' cut transients are gone at the core, and
    /// windows and spectrum segments are placed by the line's runs.
    #[test]
    fn pieces_equal_the_whole_line() {
        // 260 m (four pieces: 41–100, –200, –300, –301 m) of corrugation over broadband roughness, with a gap.
        let n = 260_000;
        let mut seed = 7u64;
        let mut noise = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut z: Vec<f64> = (0..n)
            .map(|i| {
                let x = i as f64;
                12.0 * (x * std::f64::consts::TAU / 47.0).sin() + 30.0 * (x / 900.0).sin() + 3.0 * noise()
            })
            .collect();
        z[150_000..150_700].iter_mut().for_each(|v| *v = f64::NAN);
        let opts = Options::default();
        let a = judged(&z, &opts);
        assert_eq!(cores(&Grid::of(&a.lasers, 1.0), &opts).len(), 4);
        let whole = en13231::analyze(&z, 1.0).unwrap();
        let got = a.lasers[0].bands.as_ref().unwrap();
        for (w, g) in whole.bands.iter().zip(&got.bands) {
            let (w, g) = (w.outcome.as_ref().unwrap(), g.outcome.as_ref().unwrap());
            assert_eq!((w.windows, w.exceeding_mm), (g.windows, g.exceeding_mm), "{w:?} {g:?}");
            for (p, q) in [
                (w.average_mean_pp_mm, g.average_mean_pp_mm),
                (w.worst_mean_pp_mm, g.worst_mean_pp_mm),
                (w.worst_max_pp_mm, g.worst_max_pp_mm),
                (w.rms_mm, g.rms_mm),
            ] {
                assert!((p - q).abs() <= 1e-7 * p.abs() + 1e-12, "{p} vs {q}");
            }
        }
        let wr = en15610::analyze(&z, 1.0, &opts.roughness).unwrap();
        let gr = a.lasers[0].roughness.as_ref().unwrap();
        assert_eq!((wr.spikes_removed, wr.spectrum.segments), (gr.spikes_removed, gr.spectrum.segments));
        for (p, q) in wr.spectrum.bands.iter().zip(&gr.spectrum.bands) {
            assert!((p.level_db - q.level_db).abs() < 1e-9, "{p:?} vs {q:?}");
        }
        // Blocks of 50 m from chainage multiples: 41 m to 50 m, then every 50 m.
        let b = &a.verdict.blocks;
        assert_eq!((b[0].start_mm, b[1].start_mm, b.len()), (0.0, 50_000.0, 7));
        blocks_are_the_whole_lines(&z, &a);
        // Blocks longer than a piece (150 m: two pieces of 75 m each) sum over their pieces.
        let mut opts = Options::default();
        opts.verdict.block_mm = 150_000.0;
        let a = judged(&z, &opts);
        assert_eq!(cores(&Grid::of(&a.lasers, 1.0), &opts).len(), 5);
        assert_eq!(a.verdict.blocks.iter().map(|b| b.start_mm).collect::<Vec<_>>(), [0.0, 150_000.0, 300_000.0]);
        blocks_are_the_whole_lines(&z, &a);
    }

    /// One line of heights `z` from chainage 41 m, 1 mm apart, judged.
    fn judged(z: &[f64], opts: &Options) -> crate::analyze::Analysis {
        let line = profile::stitched(1, 41_000.0, 1.0, z.to_vec());
        let stitching = Stitching {
            direction: Direction::Forward,
            direction_residuals_um: None,
            direction_given: true,
            lasers: vec![line],
            share: None,
        };
        judge(stitching, Vec::new(), opts, &crate::progress::Silent).unwrap()
    }

    /// Each block's RMS per band and ISO 3095 verdict as the whole line's
    /// samples of the block give them (the line starts at 41 m, 1 mm apart).
    fn blocks_are_the_whole_lines(z: &[f64], a: &crate::analyze::Analysis) {
        let (_, traces) = en13231::analyze_traced(z, 1.0).unwrap();
        for b in &a.verdict.blocks {
            let lo = (b.start_mm - 41_000.0).max(0.0) as usize;
            let hi = ((b.end_mm - 41_000.0) as usize).min(z.len());
            for (k, t) in traces.iter().enumerate() {
                let v: Vec<f64> =
                    t.as_ref().unwrap().band_mm[lo..hi].iter().copied().filter(|v| v.is_finite()).collect();
                let rms = (v.iter().map(|v| v * v).sum::<f64>() / v.len() as f64).sqrt();
                let got = b.rms_mm[k].unwrap();
                assert!((got - rms).abs() <= 1e-7 * rms + 1e-12, "block {} band {k}: {got} vs {rms}", b.start_mm);
            }
            let whole = en15610::analyze(&z[lo..hi], 1.0, &en15610::Options::default()).ok().map(|r| {
                let mut e: Vec<f64> = r
                    .spectrum
                    .bands
                    .iter()
                    .filter(|b| b.verdict() == Some(crate::analyze::standards::detection::Verdict::Exceeds))
                    .map(|b| b.nominal_wavelength_mm)
                    .collect();
                e.sort_by(|a, b| b.total_cmp(a));
                e
            });
            assert_eq!(b.iso3095.as_ref().map(|i| i.exceeded_mm.clone()), whole, "block {}", b.start_mm);
        }
    }
}
