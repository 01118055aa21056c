//! A line's cells (a sum and a weight each, on an `i64` lattice) in
//! fixed-size tiles: a few in memory, least recently used first out, the
//! rest in an unlinked temporary file made when the cache first
//! overflows — a short line never touches the disk.
//!
//! Memory: [`CACHE_TILES`] tiles of [`TILE_CELLS`] cells, 12 bytes a cell
//! (≈ 1 MB), plus 16 bytes of directory per tile ever spilled (one per
//! 16 m of line at 1 mm). The sums are `f64`: an `f32` sum of ~100 frames'
//! values of up to 10⁵ µm would keep only ~0.1 µm, the size of the
//! effects the stitcher averages for.

use std::collections::HashMap;
use std::fs::File;
use std::io::{self, Read, Seek, SeekFrom, Write};
use std::ops::Range;

/// Cells per tile.
pub const TILE_CELLS: usize = 16 * 1024;

/// Tiles a store keeps in memory by default (≈ 1 MB).
pub const CACHE_TILES: usize = 5;

const TILE_BYTES: usize = TILE_CELLS * 12;

struct Tile {
    /// Tile index: cells `index · TILE_CELLS ..` of the lattice.
    index: i64,
    sum: Box<[f64]>,
    weight: Box<[u32]>,
    /// When last used (the store's clock).
    used: u64,
    /// Changed since read or written.
    dirty: bool,
}

/// Cells on an `i64` lattice, each a sum (f64) and a weight (u32), zero
/// until written; see the module docs.
pub struct Cells {
    tiles: Vec<Tile>,
    /// Slot in the file of every tile spilled.
    slots: HashMap<i64, u64>,
    file: Option<File>,
    capacity: usize,
    clock: u64,
    /// The tile used last: the hot path's check before any search.
    hot: usize,
    /// Lattice indices written (`None`: none).
    extent: Option<(i64, i64)>,
}

impl std::fmt::Debug for Cells {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Cells")
            .field("extent", &self.extent)
            .field("cached_tiles", &self.tiles.len())
            .field("spilled_tiles", &self.slots.len())
            .finish()
    }
}

impl Default for Cells {
    fn default() -> Self {
        Cells::new(CACHE_TILES)
    }
}

fn split(c: i64) -> (i64, usize) {
    let t = TILE_CELLS as i64;
    (c.div_euclid(t), c.rem_euclid(t) as usize)
}

impl Cells {
    /// An empty store keeping `capacity` tiles (at least one) in memory.
    pub fn new(capacity: usize) -> Cells {
        Cells {
            tiles: Vec::new(),
            slots: HashMap::new(),
            file: None,
            capacity: capacity.max(1),
            clock: 0,
            hot: 0,
            extent: None,
        }
    }

    /// Lattice indices `lo..=hi` written so far (`None`: none).
    pub fn extent(&self) -> Option<(i64, i64)> {
        self.extent
    }

    /// Whether any tile went to the disk.
    pub fn spilled(&self) -> bool {
        self.file.is_some()
    }

    /// The cached tile of tile index `t` (read or made), by position in
    /// the cache.
    fn tile(&mut self, t: i64) -> io::Result<usize> {
        self.clock += 1;
        if let Some(h) = self.tiles.get_mut(self.hot)
            && h.index == t
        {
            h.used = self.clock;
            return Ok(self.hot);
        }
        let at = match self.tiles.iter().position(|x| x.index == t) {
            Some(at) => at,
            None => self.load(t)?,
        };
        self.tiles[at].used = self.clock;
        self.hot = at;
        Ok(at)
    }

    /// Brings tile `t` into the cache, evicting the least recently used
    /// when it is full.
    fn load(&mut self, t: i64) -> io::Result<usize> {
        let at = if self.tiles.len() < self.capacity {
            self.tiles.push(Tile {
                index: t,
                sum: vec![0.0; TILE_CELLS].into_boxed_slice(),
                weight: vec![0; TILE_CELLS].into_boxed_slice(),
                used: 0,
                dirty: false,
            });
            self.tiles.len() - 1
        } else {
            let at = (0..self.tiles.len()).min_by_key(|&i| self.tiles[i].used).unwrap_or(0);
            self.evict(at)?;
            at
        };
        let slot = self.slots.get(&t).copied();
        let tile = &mut self.tiles[at];
        tile.index = t;
        tile.dirty = false;
        match (slot, self.file.as_mut()) {
            (Some(slot), Some(file)) => {
                let mut bytes = vec![0u8; TILE_BYTES];
                file.seek(SeekFrom::Start(slot * TILE_BYTES as u64))?;
                file.read_exact(&mut bytes)?;
                let (s, w) = bytes.split_at(TILE_CELLS * 8);
                for (x, b) in tile.sum.iter_mut().zip(s.chunks_exact(8)) {
                    *x = f64::from_le_bytes(b.try_into().unwrap_or_default());
                }
                for (x, b) in tile.weight.iter_mut().zip(w.chunks_exact(4)) {
                    *x = u32::from_le_bytes(b.try_into().unwrap_or_default());
                }
            }
            _ => {
                tile.sum.fill(0.0);
                tile.weight.fill(0);
            }
        }
        Ok(at)
    }

    /// Writes the cached tile at `at` to its slot (a new one the first
    /// time) when it changed.
    fn evict(&mut self, at: usize) -> io::Result<()> {
        let tile = &self.tiles[at];
        if !tile.dirty {
            return Ok(());
        }
        let file = match &mut self.file {
            Some(f) => f,
            None => self.file.insert(tempfile::tempfile()?),
        };
        let next = self.slots.len() as u64;
        let slot = *self.slots.entry(tile.index).or_insert(next);
        let mut bytes = Vec::with_capacity(TILE_BYTES);
        tile.sum.iter().for_each(|x| bytes.extend_from_slice(&x.to_le_bytes()));
        tile.weight.iter().for_each(|x| bytes.extend_from_slice(&x.to_le_bytes()));
        file.seek(SeekFrom::Start(slot * TILE_BYTES as u64))?;
        file.write_all(&bytes)?;
        self.tiles[at].dirty = false;
        Ok(())
    }

    /// Cell `c`: (sum, weight).
    pub fn get(&mut self, c: i64) -> io::Result<(f64, u32)> {
        let (t, i) = split(c);
        if self.tiles.get(self.hot).is_none_or(|h| h.index != t) && !self.holds(t) {
            return Ok((0.0, 0));
        }
        let at = self.tile(t)?;
        Ok((self.tiles[at].sum[i], self.tiles[at].weight[i]))
    }

    /// Whether tile `t` has ever been written (cached or spilled).
    fn holds(&self, t: i64) -> bool {
        self.slots.contains_key(&t) || self.tiles.iter().any(|x| x.index == t)
    }

    /// Adds `sum` and `weight` to cell `c` (nothing when `weight` is 0 and
    /// `sum` is 0).
    pub fn add(&mut self, c: i64, sum: f64, weight: u32) -> io::Result<()> {
        if weight == 0 && sum == 0.0 {
            return Ok(());
        }
        let (t, i) = split(c);
        let at = self.tile(t)?;
        let tile = &mut self.tiles[at];
        tile.sum[i] += sum;
        tile.weight[i] = tile.weight[i].saturating_add(weight);
        tile.dirty = true;
        self.extent = Some(match self.extent {
            Some((lo, hi)) => (lo.min(c), hi.max(c)),
            None => (c, c),
        });
        Ok(())
    }

    /// Calls `f(first cell, sums, weights)` for the cells of `range` in
    /// order, a tile's part at a time (cells never written are zero).
    pub fn for_stretch(&mut self, range: Range<i64>, mut f: impl FnMut(i64, &[f64], &[u32])) -> io::Result<()> {
        let mut c = range.start;
        while c < range.end {
            let (t, i) = split(c);
            let n = ((TILE_CELLS - i) as i64).min(range.end - c) as usize;
            if self.holds(t) {
                let at = self.tile(t)?;
                let tile = &self.tiles[at];
                f(c, &tile.sum[i..i + n], &tile.weight[i..i + n]);
            } else {
                f(c, &vec![0.0; n], &vec![0; n]);
            }
            c += n as i64;
        }
        Ok(())
    }

    /// The values (sum / weight; NaN where the weight is 0) of `range`.
    pub fn values(&mut self, range: Range<i64>) -> io::Result<Vec<f64>> {
        let mut out = Vec::with_capacity(usize::try_from(range.end - range.start).unwrap_or(0));
        self.for_stretch(range, |_, s, w| {
            out.extend(s.iter().zip(w).map(|(&s, &w)| if w > 0 { s / f64::from(w) } else { f64::NAN }));
        })?;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Random adds and reads over a lattice of several tiles, with a
        /// cache of one or two tiles forcing spills, agree with a plain
        /// vector.
        #[test]
        fn cells_agree_with_a_vector(
            cache in 1usize..3,
            ops in proptest::collection::vec((0i64..5 * TILE_CELLS as i64, -50.0f64..50.0, 0u32..4, any::<bool>()), 1..400),
        ) {
            let lo = -2 * TILE_CELLS as i64;
            let mut cells = Cells::new(cache);
            let mut model = vec![(0.0f64, 0u32); 5 * TILE_CELLS];
            for (c, v, w, read) in ops {
                let at = lo + c;
                if read {
                    let a = c.saturating_sub(40).max(0);
                    let b = (c + 3000).min(model.len() as i64);
                    let got = cells.values(lo + a..lo + b).unwrap();
                    let want: Vec<f64> = model[a as usize..b as usize]
                        .iter()
                        .map(|&(s, w)| if w > 0 { s / f64::from(w) } else { f64::NAN })
                        .collect();
                    prop_assert_eq!(got.len(), want.len());
                    for (g, w) in got.iter().zip(&want) {
                        prop_assert!(g.to_bits() == w.to_bits() || (g.is_nan() && w.is_nan()));
                    }
                    prop_assert_eq!(cells.get(at).unwrap(), model[c as usize]);
                } else {
                    cells.add(at, v * f64::from(w), w).unwrap();
                    let m = &mut model[c as usize];
                    if !(w == 0 && v * f64::from(w) == 0.0) {
                        m.0 += v * f64::from(w);
                        m.1 += w;
                    }
                }
            }
            let all = cells.values(lo..lo + model.len() as i64).unwrap();
            for (g, &(s, w)) in all.iter().zip(&model) {
                let want = if w > 0 { s / f64::from(w) } else { f64::NAN };
                prop_assert!(g.to_bits() == want.to_bits() || (g.is_nan() && want.is_nan()));
            }
        }
    }

    #[test]
    fn a_short_line_stays_in_memory_and_a_long_one_spills() {
        let mut c = Cells::default();
        for i in 0..(CACHE_TILES * TILE_CELLS) as i64 {
            c.add(i, 1.0, 1).unwrap();
        }
        assert!(!c.spilled());
        assert_eq!(c.extent(), Some((0, (CACHE_TILES * TILE_CELLS) as i64 - 1)));
        for i in 0..(2 * TILE_CELLS) as i64 {
            c.add(i + (CACHE_TILES * TILE_CELLS) as i64, 2.0, 1).unwrap();
        }
        assert!(c.spilled());
        assert_eq!(c.get(100).unwrap(), (1.0, 1));
        assert_eq!(c.values(-1..1).unwrap()[1], 1.0);
        assert!(c.values(-1..1).unwrap()[0].is_nan());
    }
}
