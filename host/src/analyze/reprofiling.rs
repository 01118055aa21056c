//! The survey's verdict: where the rail exceeds the EN 13231-3 criteria
//! (exceedance zones), how much of it should be reprofiled (the
//! reprofiling table), and block RMS and the EN 15610 spectrum per block
//! against ISO 3095 — the tables a grinding contract is settled on.
//!
//! # Criteria and editions
//!
//! [`Edition::En2006`] judges a position by the moving-window mean
//! peak-to-peak of its band ([`en13231::BANDS`]: windows 600 / 600 / 1000 /
//! 5000 mm, limits 0.02 / 0.02 / 0.03 / 0.15 mm); [`Edition::En2012`] by
//! the band-filtered displacement itself ("isolated points"), against the
//! Class 1 limit of ±0.010 mm in 30–100 mm — the only 2012 limit this
//! build knows, so the other bands are reported as not judged under 2012.
//! Both sets come from secondary sources (trade documentation), not the
//! standard's text: every report says so ([`Edition::source`]).
//!
//! # The profile judged, and the floor
//!
//! A rail is reprofiled across its running band, and corrugation runs
//! across it: where a section has two lines or more, the verdict judges
//! the running band's profile, the mean of its lines
//! ([`crate::analyze::pieces::RunningBand`]), whose noise is `1/√k` of a
//! line's. A band whose noise floor ([`crate::analyze::floor`]) does not
//! allow a verdict is *not judged*: no zone, no length to reprofile, the
//! floor and the limit named. A section of one line is judged on it.
//!
//! # Zones
//!
//! A position exceeds when the profile judged exceeds there. Exceeding positions
//! closer than one window of the band are one zone (the rail between
//! would be ground with it). Each zone has its start and end chainage,
//! its band and its largest peak-to-peak (the largest window max − min of
//! any line inside it).
//!
//! # Costs
//!
//! `O(N)` per band over the lines' per-sample criteria; the per-block
//! spectra `O(N log M)`.

use std::fmt::Write as _;

use super::chainage;
use super::floor::{BandJudgement, Floor};
use super::pieces::Piece;
use crate::analyze::standards::Stretch;
use crate::analyze::standards::detection::Verdict;
use crate::analyze::standards::{en13231, en15610};

pub use crate::analyze::standards::en13231::Edition;

/// Options of the verdict ([`Builder`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    pub edition: Edition,
    /// Block length for block RMS and spectra, mm.
    pub block_mm: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options { edition: Edition::En2006, block_mm: 50_000.0 }
    }
}

/// A stretch of rail over a band's limit.
#[derive(Debug, Clone, PartialEq)]
pub struct Zone {
    pub band: en13231::Band,
    /// Chainage of its first and last exceeding position, mm.
    pub start_mm: f64,
    pub end_mm: f64,
    /// Length exceeding inside it, mm (positions over the limit × spacing).
    pub exceeding_mm: f64,
    /// Largest window max − min of any line inside it, mm.
    pub worst_pp_mm: f64,
}

/// One band's row of the reprofiling table.
#[derive(Debug, Clone, PartialEq)]
pub struct BandRow {
    pub band: en13231::Band,
    /// The limit under the edition (`None`: not judged under it).
    pub limit_mm: Option<f64>,
    /// Length evaluated (positions with a criterion value on some line), mm.
    pub measured_mm: f64,
    /// Length over the limit on some line, mm.
    pub exceeding_mm: f64,
    /// Why the band has no figures (too short a record, too coarse a sampling).
    pub not_evaluated: Option<String>,
    /// The floor of the profile judged and whether it allows a verdict.
    pub judgement: BandJudgement,
}

impl BandRow {
    /// Share of the measured length exceeding, %.
    pub fn exceeding_percent(&self) -> f64 {
        if self.measured_mm > 0.0 { 100.0 * self.exceeding_mm / self.measured_mm } else { 0.0 }
    }

    /// 2006: at most 5 % of the length exceeding; 2012: no isolated point over.
    pub fn passes(&self, edition: Edition) -> Option<bool> {
        self.limit_mm?;
        if self.judgement.not_judged.is_some() {
            return None;
        }
        (self.measured_mm > 0.0).then(|| match edition {
            Edition::En2006 => self.exceeding_percent() <= en13231::MAX_EXCEEDING_PERCENT,
            Edition::En2012 => self.exceeding_mm == 0.0,
        })
    }
}

/// One block's figures.
#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    pub start_mm: f64,
    pub end_mm: f64,
    /// Per band (in [`en13231::BANDS`] order): RMS of the band-filtered
    /// displacement over the block, largest over the lines, mm (`None` where not evaluated).
    pub rms_mm: Vec<Option<f64>>,
    /// The ISO 3095 third octaves of the lines' EN 15610 spectra
    /// energy-averaged (EN 15610's lines across the running band), by
    /// verdict (`None`: no spectrum).
    pub iso3095: Option<Iso3095>,
    /// Each line's own (by laser, in the block's line order; a line
    /// without a spectrum in the block left out), judged against its own floor.
    pub iso3095_lines: Vec<(usize, Iso3095)>,
    /// Per band: one line's noise floor RMS, mm (`None`: not known).
    pub floor_rms_mm: Vec<Option<f64>>,
}

/// A spectrum's ISO 3095 third octaves by their verdict
/// ([`crate::analyze::standards::detection`]): nominal wavelengths, mm,
/// longest first.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Iso3095 {
    /// The reading, noise included, under the limit with confidence.
    pub within_mm: Vec<f64>,
    /// The rail's own level, the floor's power taken out, over the limit with confidence.
    pub exceeded_mm: Vec<f64>,
    /// Neither: the floor and the record's length cannot tell.
    pub not_judged_mm: Vec<f64>,
    /// The third octaves judged, as the spectrum holds them (its floors
    /// marked), long wavelengths first: each one's level, floor, limit and
    /// decision ([`en15610::ThirdOctave::decision`]) — what the lists above
    /// are made of.
    pub bands: Vec<en15610::ThirdOctave>,
}

impl Iso3095 {
    /// The third octaves of `s` (its floors marked) by verdict.
    pub fn of(s: &en15610::Spectrum) -> Iso3095 {
        let mut out = Iso3095::default();
        for b in &s.bands {
            let class = match b.verdict() {
                Some(Verdict::Within) => &mut out.within_mm,
                Some(Verdict::Exceeds) => &mut out.exceeded_mm,
                Some(Verdict::NotJudged) => &mut out.not_judged_mm,
                None => continue,
            };
            class.push(b.nominal_wavelength_mm);
            out.bands.push(*b);
        }
        for class in [&mut out.within_mm, &mut out.exceeded_mm, &mut out.not_judged_mm] {
            class.sort_by(|a, b| b.total_cmp(a));
        }
        out
    }

    /// The spectrum's verdict: EXCEEDS when a third octave exceeds, else
    /// not judged when one is not judged, else within (`None`: no third
    /// octave has an ISO 3095 limit).
    pub fn verdict(&self) -> Option<Verdict> {
        if !self.exceeded_mm.is_empty() {
            Some(Verdict::Exceeds)
        } else if !self.not_judged_mm.is_empty() {
            Some(Verdict::NotJudged)
        } else {
            (!self.within_mm.is_empty()).then_some(Verdict::Within)
        }
    }

    /// The verdict in words with the third octaves that make it: "within",
    /// "EXCEEDS at 50, 40 mm; not judged at 8 mm", "not judged at 8, 6.3 mm".
    pub fn words(&self) -> String {
        let list = |e: &[f64]| e.iter().map(|w| w.to_string()).collect::<Vec<_>>().join(", ");
        let mut s = match self.verdict() {
            None => return "no ISO 3095 limit".into(),
            Some(Verdict::Exceeds) => format!("{} at {} mm", Verdict::Exceeds, list(&self.exceeded_mm)),
            Some(v) => v.name().to_string(),
        };
        if !self.not_judged_mm.is_empty() {
            let sep = if self.exceeded_mm.is_empty() { " at" } else { "; not judged at" };
            let _ = write!(s, "{sep} {} mm", list(&self.not_judged_mm));
        }
        s
    }
}

/// The whole verdict.
#[derive(Debug, Clone, PartialEq)]
pub struct ReprofilingVerdict {
    pub options: Options,
    pub rows: Vec<BandRow>,
    pub zones: Vec<Zone>,
    /// Length to reprofile (exceeding any judged band on some line), and length measured, mm.
    pub reprofile_mm: f64,
    pub measured_mm: f64,
    pub blocks: Vec<Block>,
}

/// The verdict built piece by piece along the survey line
/// ([`crate::analyze::pieces`]): sections one after the other, each
/// section's pieces in chainage order. Sections lie more than a block and
/// a window apart ([`crate::analyze::survey::section_gap_mm`]), so no
/// zone or block spans two; pieces are whole blocks, and a zone that
/// runs on from one piece into the next is carried over.
pub struct Builder {
    v: ReprofilingVerdict,
    /// EN 15610's settings for the blocks' spectra: the analysis's own.
    roughness: en15610::Options,
    dx_mm: f64,
    floor: Option<Floor>,
    /// Per band: why no line evaluated it (the last reason seen).
    why: Vec<Option<String>>,
    /// Per band: the zone still open (first and last exceeding grid
    /// index, exceeding positions, worst peak-to-peak) and the section grid's origin.
    open: Vec<Option<(usize, usize, usize, f64)>>,
    origin_mm: f64,
    /// The block being summed (a block may span several pieces).
    block: Option<OpenBlock>,
}

/// A block's figures summed over the pieces that hold it.
struct OpenBlock {
    span_mm: (f64, f64),
    /// Per line (by laser): per band the band values' sum of squares and
    /// count, and its EN 15610 spectrum of the block's own samples
    /// (`None`: the block's runs cannot hold a segment).
    lines: Vec<BlockLine>,
}

/// One line's sums over a block: (laser, per band (Σ v², n), spectrum).
type BlockLine = (usize, [(f64, usize); 4], Option<en15610::Welch>);

impl Builder {
    /// A verdict judged against `floor` (one line's, of the survey):
    /// the running band's profile of `floor.lines` lines; the blocks'
    /// spectra under `roughness`, as the whole run's.
    pub fn new(opts: &Options, roughness: &en15610::Options, dx_mm: f64, floor: Option<Floor>) -> Builder {
        let rows = en13231::BANDS
            .iter()
            .enumerate()
            .map(|(b, band)| BandRow {
                band: *band,
                limit_mm: opts.edition.limit_mm(band),
                measured_mm: 0.0,
                exceeding_mm: 0.0,
                not_evaluated: None,
                judgement: BandJudgement::of(
                    floor.as_ref().and_then(|f| f.running_band(b, &f.lasers())),
                    opts.edition,
                    band,
                ),
            })
            .collect();
        Builder {
            v: ReprofilingVerdict {
                options: *opts,
                rows,
                zones: vec![],
                reprofile_mm: 0.0,
                measured_mm: 0.0,
                blocks: vec![],
            },
            roughness: roughness.clone(),
            dx_mm,
            floor,
            why: vec![None; en13231::BANDS.len()],
            open: vec![None; en13231::BANDS.len()],
            origin_mm: 0.0,
            block: None,
        }
    }

    /// Why band `b` could not be evaluated on a line (shown when no line did).
    pub fn not_evaluated(&mut self, b: usize, why: String) {
        if let Some(w) = self.why.get_mut(b) {
            *w = Some(why);
        }
    }

    /// Adds a piece of a section (the pieces of a section in order).
    pub fn piece(&mut self, p: &Piece) {
        if p.core.start == 0 {
            self.close_zones();
            self.origin_mm = p.grid.origin_mm;
        }
        let n = p.core.len();
        let edition = self.v.options.edition;
        let mut any_over = vec![false; n];
        let mut any_measured = vec![false; n];
        // The running band's profile where the section has one, else its line.
        let judged: Vec<&crate::analyze::pieces::PieceLine> = match &p.band {
            Some(band) => vec![&band.mean],
            None => p.lines.iter().collect(),
        };
        for (b, band) in en13231::BANDS.iter().enumerate() {
            // A judged band's positions exceed over its threshold (the floor's power taken out).
            let j = &self.v.rows[b].judgement;
            let limit = j.threshold_mm.filter(|_| j.not_judged.is_none());
            let (mut measured_n, mut over_n) = (0usize, 0usize);
            for i in 0..n {
                // Measured; over the limit; worst window p-p.
                let (mut measured, mut over, mut worst) = (false, false, 0.0f64);
                for t in judged.iter().filter_map(|l| l.bands.get(b).and_then(Option::as_ref)) {
                    let mean = t.mean_pp_mm[i];
                    let value = match edition {
                        Edition::En2006 => mean,
                        // Isolated points are judged where the window statistics are
                        // (inside the settled part), on the displacement itself.
                        Edition::En2012 if mean.is_finite() => t.band_mm[i].abs(),
                        Edition::En2012 => f64::NAN,
                    };
                    if !value.is_finite() {
                        continue;
                    }
                    measured = true;
                    worst = worst.max(t.max_pp_mm[i]);
                    over |= limit.is_some_and(|lim| value > lim);
                }
                measured_n += usize::from(measured);
                over_n += usize::from(over);
                if edition.limit_mm(band).is_some() {
                    any_over[i] |= over;
                    any_measured[i] |= measured;
                }
                if over {
                    self.zone_position(b, p.core.start + i, worst);
                }
            }
            let row = &mut self.v.rows[b];
            row.measured_mm += measured_n as f64 * self.dx_mm;
            row.exceeding_mm += over_n as f64 * self.dx_mm;
        }
        self.v.reprofile_mm += any_over.iter().filter(|&&o| o).count() as f64 * self.dx_mm;
        self.v.measured_mm += any_measured.iter().filter(|&&m| m).count() as f64 * self.dx_mm;
        self.blocks(p);
    }

    /// An exceeding position of band `b`: joins the open zone when within a
    /// window of its last position, else closes it and opens another.
    fn zone_position(&mut self, b: usize, i: usize, worst: f64) {
        let merge = (en13231::BANDS[b].window_mm / self.dx_mm).round() as usize;
        match &mut self.open[b] {
            Some((_, end, count, pp)) if i <= *end + merge => {
                *end = i;
                *count += 1;
                *pp = pp.max(worst);
            }
            _ => {
                self.close_zone(b);
                self.open[b] = Some((i, i, 1, worst));
            }
        }
    }

    fn close_zone(&mut self, b: usize) {
        if let Some((start, end, count, pp)) = self.open[b].take() {
            let dx = self.dx_mm;
            self.v.zones.push(Zone {
                band: en13231::BANDS[b],
                start_mm: self.origin_mm + start as f64 * dx,
                end_mm: self.origin_mm + end as f64 * dx,
                exceeding_mm: count as f64 * dx,
                worst_pp_mm: pp,
            });
        }
    }

    fn close_zones(&mut self) {
        for b in 0..self.open.len() {
            self.close_zone(b);
        }
    }

    /// The blocks a piece meets: summed in, and given out when whole.
    fn blocks(&mut self, p: &Piece) {
        let ro = self.roughness.clone();
        // EN 15610's nonlinear steps on the rail the lines share (the piece's noise measured once).
        let steps = p.band.as_ref().map(|rb| (rb.rail_steps(&ro), &rb.mean));
        for part in crate::analyze::pieces::blocks(p, self.v.options.block_mm) {
            if self.block.as_ref().is_none_or(|b| b.span_mm != part.span_mm) {
                self.close_block();
                let lines = p
                    .lines
                    .iter()
                    .map(|l| {
                        let welch = en15610::Welch::new(&l.runs_within(&part.grid), l.dx_mm(), &ro).ok();
                        (l.laser, [(0.0, 0); 4], welch)
                    })
                    .collect();
                self.block = Some(OpenBlock { span_mm: part.span_mm, lines });
            }
            let Some(open) = &mut self.block else { continue };
            let core = p.core.start + part.range.start..p.core.start + part.range.end;
            let correction = steps.as_ref().map(|(s, mean)| s.correction(&mean.masked(&part.grid), &ro));
            for l in &p.lines {
                let Some((_, sums, welch)) = open.lines.iter_mut().find(|o| o.0 == l.laser) else { continue };
                for (sum, t) in sums.iter_mut().zip(&l.bands) {
                    let Some(t) = t else { continue };
                    for v in t.band_mm[part.range.clone()].iter().filter(|v| v.is_finite()) {
                        sum.0 += v * v;
                        sum.1 += 1;
                    }
                }
                if let Some(w) = welch {
                    // The block on its own: its edges are its runs' ends.
                    let z = l.masked(&part.grid);
                    let runs = l.runs_within(&part.grid);
                    let stretch =
                        Stretch { z_um: &z, start: l.ext_start(), core: core.clone(), runs: &runs, dx_mm: l.dx_mm() };
                    match &correction {
                        Some(c) => w.add_corrected(&stretch, c, &ro),
                        None => w.add(&stretch, &ro),
                    };
                }
            }
            if part.ends {
                self.close_block();
            }
        }
    }

    /// Gives out the block being summed, if it has figures.
    fn close_block(&mut self) {
        let Some(open) = self.block.take() else { return };
        let mut rms = vec![None; en13231::BANDS.len()];
        let mut spectra = Vec::new();
        let mut iso3095_lines = Vec::new();
        for (laser, sums, welch) in &open.lines {
            for (b, &(sq, n)) in sums.iter().enumerate() {
                if n > 0 {
                    let v = (sq / n as f64).sqrt();
                    rms[b] = Some(rms[b].map_or(v, |w: f64| w.max(v)));
                }
            }
            if let Some(w) = welch
                && w.segments() > 0
            {
                let mut s = w.spectrum();
                spectra.push(s.clone());
                if let Some(f) = &self.floor {
                    f.mark_line(*laser, &mut s);
                }
                iso3095_lines.push((*laser, Iso3095::of(&s)));
            }
        }
        let mut spectrum = en15610::energy_average(&spectra);
        if let (Some(s), Some(f)) = (&mut spectrum, &self.floor) {
            f.mark(s);
        }
        if rms.iter().all(Option::is_none) && spectrum.is_none() {
            return;
        }
        let (start_mm, end_mm) = open.span_mm;
        let floor_rms_mm =
            (0..en13231::BANDS.len()).map(|b| self.floor.as_ref().and_then(|f| f.band(b)).map(|f| f.rms_mm)).collect();
        self.v.blocks.push(Block {
            start_mm,
            end_mm,
            rms_mm: rms,
            iso3095: spectrum.as_ref().map(Iso3095::of),
            iso3095_lines,
            floor_rms_mm,
        });
    }

    /// The verdict, every zone closed.
    pub fn finish(mut self) -> ReprofilingVerdict {
        self.close_zones();
        self.close_block();
        self.v.zones.sort_by(|a, b| a.start_mm.total_cmp(&b.start_mm));
        for (row, why) in self.v.rows.iter_mut().zip(self.why) {
            if row.measured_mm == 0.0 {
                row.not_evaluated = why.or_else(|| Some("no line evaluated it".into()));
            }
        }
        self.v
    }
}

fn band_name(b: &en13231::Band) -> String {
    format!("{}–{} mm", b.lo_mm, b.hi_mm)
}

/// The verdict as text: the edition and its source, the reprofiling table,
/// the zones, the blocks.
pub fn describe(v: &ReprofilingVerdict) -> String {
    let mut s = String::new();
    let e = v.options.edition;
    let _ = writeln!(s, "verdict by {} — {}", e.name(), e.source());
    if v.measured_mm > 0.0 && v.rows.iter().all(|r| r.limit_mm.is_none() || r.judgement.not_judged.is_some()) {
        let _ = writeln!(
            s,
            "reprofiling: not judged: no band's noise floor allows a verdict ({:.3} km measured; see below)",
            v.measured_mm / 1e6
        );
    } else if v.measured_mm > 0.0 {
        let _ = writeln!(
            s,
            "reprofiling: {:.3} km of {:.3} km should be reprofiled ({:.1} %)",
            v.reprofile_mm / 1e6,
            v.measured_mm / 1e6,
            100.0 * v.reprofile_mm / v.measured_mm
        );
    } else {
        let _ = writeln!(s, "reprofiling: not judged (no band could be evaluated; see below)");
    }
    let _ = writeln!(
        s,
        "{:<14} {:>9} {:>12} {:>13} {:>11} {:>6}",
        "band", "limit_mm", "measured_m", "exceeding_m", "exceeding_%", "pass"
    );
    for r in &v.rows {
        match (&r.not_evaluated, r.limit_mm, &r.judgement.not_judged) {
            (Some(why), _, _) => {
                let _ = writeln!(s, "{:<14} not evaluated: {why}", band_name(&r.band));
            }
            (None, None, _) => {
                let _ = writeln!(s, "{:<14} no {} limit known: not judged", band_name(&r.band), e.name());
            }
            (None, Some(_), Some(why)) => {
                let _ = writeln!(s, "{:<14} {why}", band_name(&r.band));
            }
            (None, Some(lim), None) => {
                let _ = writeln!(
                    s,
                    "{:<14} {:>9.3} {:>12.1} {:>13.1} {:>11.1} {:>6}{}",
                    band_name(&r.band),
                    lim,
                    r.measured_mm / 1000.0,
                    r.exceeding_mm / 1000.0,
                    r.exceeding_percent(),
                    match r.passes(e) {
                        Some(true) => "yes",
                        Some(false) => "NO",
                        None => "-",
                    },
                    r.judgement
                        .floor
                        .map_or(String::new(), |f| format!("  (floor {:.1} µm)", f.judged_quantity_mm(e) * 1000.0))
                );
            }
        }
    }
    if v.zones.is_empty() {
        let _ = writeln!(s, "exceedance zones: none");
    } else {
        let _ = writeln!(s, "exceedance zones ({}):", v.zones.len());
        for z in v.zones.iter().take(50) {
            let _ = writeln!(
                s,
                "  {} to {} ({:.1} m, {:.1} m exceeding), {} band, largest peak-to-peak {:.3} mm",
                chainage(z.start_mm),
                chainage(z.end_mm),
                (z.end_mm - z.start_mm) / 1000.0,
                z.exceeding_mm / 1000.0,
                band_name(&z.band),
                z.worst_pp_mm
            );
        }
        if v.zones.len() > 50 {
            let _ = writeln!(s, "  … and {} more (see the report)", v.zones.len() - 50);
        }
    }
    describe_blocks(v, &mut s);
    s
}

/// The blocks' lines of [`describe`].
fn describe_blocks(v: &ReprofilingVerdict, s: &mut String) {
    if v.blocks.iter().all(|b| b.rms_mm.iter().all(Option::is_none) && b.iso3095.is_none()) {
        let _ = writeln!(s, "blocks of {} m: no band or spectrum evaluated", v.options.block_mm / 1000.0);
        return;
    }
    let _ = writeln!(
        s,
        "blocks of {} m: RMS of each band (largest line, µm) and EN 15610 against ISO 3095",
        v.options.block_mm / 1000.0
    );
    for b in &v.blocks {
        let rms: Vec<String> =
            b.rms_mm.iter().map(|r| r.map_or("-".into(), |v| format!("{:.1}", v * 1000.0))).collect();
        let iso = match b.iso3095 {
            Some(_) => format!("ISO 3095 {}", block_iso3095_words(b)),
            None => block_iso3095_words(b),
        };
        let _ = writeln!(s, "  {} – {}: {}; {iso}", chainage(b.start_mm), chainage(b.end_mm), rms.join(" / "));
    }
}

/// A block's ISO 3095 verdict in words: the lines' energy average's, and
/// each line's whose verdict differs ("within; laser 2 not judged at 8
/// mm"); every line's third octaves are in `--json` and Parquet.
pub fn block_iso3095_words(b: &Block) -> String {
    let Some(avg) = &b.iso3095 else { return "no spectrum".into() };
    let mut s = avg.words();
    for (laser, l) in &b.iso3095_lines {
        if l.verdict() != avg.verdict() {
            let _ = write!(s, "; laser {laser} {}", l.words());
        }
    }
    s
}
