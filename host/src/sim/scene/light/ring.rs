//! The surface's speckle phasors along the rail, kept in a bounded ring.
//!
//! A surface cell's phase is a hash of the seed, the pattern's stream and
//! the cell (`coherent::phase_turns`): the same whichever frame sees it.
//! The cells a shot needs are a band of rows along the rail (the image's
//! rows, the guards, and the travel in the exposure) times a band of
//! columns about the line, and overlapping frames see the same stretch of
//! rail again: each row of cells is drawn once, kept in a ring indexed by
//! its position along the rail, and reused until the rail has moved on by
//! the ring's length. The values are the hash's, so a cell reads the same
//! whether it came from the ring or was drawn anew.

use rustfft::num_complex::Complex;

#[cfg(test)]
use super::coherent::phasor;
use super::coherent::{column_hash, phase_turns, phasor_of_turns};

/// Columns of cells kept beside the band a shot asked for, in samples per
/// pixel (`q`) units: the line moves by a few pixels as the head's height
/// changes without the ring being drawn again.
const MARGIN_PX: i64 = 2;

/// A ring of rows of surface cells for one pattern.
pub(crate) struct PhasorRing {
    seed: u64,
    stream: u64,
    /// First lateral cell of every row.
    lat0: i64,
    /// Lateral cells per row.
    lat_w: usize,
    /// The hash of each lateral cell's column, shared by its rows.
    columns: Vec<u64>,
    /// A row's phases, 2⁻²⁴ turns.
    turns: Vec<i32>,
    /// The along-rail cell each slot holds (`None`: not drawn).
    keys: Vec<Option<i64>>,
    cells: Vec<Complex<f32>>,
}

impl PhasorRing {
    /// An empty ring.
    pub fn new() -> PhasorRing {
        PhasorRing {
            seed: 0,
            stream: 0,
            lat0: 0,
            lat_w: 0,
            columns: Vec::new(),
            turns: Vec::new(),
            keys: Vec::new(),
            cells: Vec::new(),
        }
    }

    /// Makes the ring hold lateral cells `lat` of every row in `rows` at
    /// once, for pattern `stream` of `seed` (emptying it if it cannot).
    /// `q` is the cells per pixel.
    pub fn prepare(&mut self, seed: u64, stream: u64, lat: std::ops::Range<i64>, rows: std::ops::Range<i64>, q: i64) {
        let span = (rows.end - rows.start).max(0) as usize;
        let covers = self.lat0 <= lat.start && lat.end <= self.lat0 + self.lat_w as i64;
        if seed == self.seed && stream == self.stream && covers && span <= self.keys.len() {
            return;
        }
        let margin = MARGIN_PX * q;
        self.seed = seed;
        self.stream = stream;
        self.lat0 = lat.start - margin;
        self.lat_w = (lat.end - lat.start + 2 * margin).max(0) as usize;
        self.columns = (0..self.lat_w).map(|j| column_hash(seed, stream, self.lat0 + j as i64)).collect();
        // A quarter more than one shot's rows: the next frame's rows that
        // overlap this one's are still there.
        let slots = span + span / 4 + 1;
        self.keys.clear();
        self.keys.resize(slots, None);
        self.cells.clear();
        self.cells.resize(slots * self.lat_w, Complex::new(0.0, 0.0));
    }

    /// Row `n` of cells (along the rail), from lateral cell `lat_start` on, drawn
    /// if the ring does not hold it.
    pub fn row(&mut self, n: i64, lat_start: i64) -> &[Complex<f32>] {
        let slot = n.rem_euclid(self.keys.len() as i64) as usize;
        let cells = &mut self.cells[slot * self.lat_w..(slot + 1) * self.lat_w];
        if self.keys[slot] != Some(n) {
            // The hashes, then their phasors (a loop that vectorises).
            self.turns.clear();
            self.turns.extend(self.columns.iter().map(|&column| phase_turns(column, n)));
            for (c, &u) in cells.iter_mut().zip(&self.turns) {
                *c = phasor_of_turns(u);
            }
            self.keys[slot] = Some(n);
        }
        &cells[(lat_start - self.lat0) as usize..]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cell_reads_the_same_from_the_ring_as_drawn_anew() {
        let mut ring = PhasorRing::new();
        let q = 5;
        ring.prepare(7, 3, 100..160, 0..40, q);
        let first: Vec<Complex<f32>> = ring.row(12, 110).iter().take(30).copied().collect();
        // The rail moves on past the ring's length; row 12 is drawn again.
        ring.prepare(7, 3, 100..160, 60..100, q);
        for n in 60..100 {
            ring.row(n, 100);
        }
        ring.prepare(7, 3, 102..150, 0..40, q);
        let again: Vec<Complex<f32>> = ring.row(12, 110).iter().take(30).copied().collect();
        assert_eq!(first, again);
        for (j, c) in first.iter().enumerate() {
            let p = phasor(7, 3, 110 + j as i64, 12);
            assert!((f64::from(c.re) - p.re).abs() < 1e-6 && (f64::from(c.im) - p.im).abs() < 1e-6, "{c} {p}");
        }
        // Another pattern's stream, another surface.
        ring.prepare(7, 4, 100..160, 0..40, q);
        assert_ne!(ring.row(12, 110)[0], first[0]);
    }
}
