//! Which sensor rows a frame reads: a row window and a row skip.
//!
//! # What
//! Each image row crosses the laser lines; consecutive rows lie along the
//! rail (the reference head: 480 rows over about 69 mm, 0.144 mm a row). A
//! [`Readout`] reads the `rows` sensor rows from `first_row` on, one in
//! [`RowSkip`] of them: output row `i` is sensor row
//! `first_row + skip · i` ([`Readout::sensor_row`]).
//!
//! # Why
//! A frame costs its rows: the sensor's readout (a row time each) and the
//! detector (the head's processing time per row). Fewer rows a frame give
//! more frames a second, so the head covers the rail continuously at a
//! higher travel speed, at a coarser pitch along the rail (skip) or over a
//! shorter stretch of it (window). `docs/firmware.md` ("Row window and row
//! skip") gives the figures.
//!
//! # Rows on the wire
//! A profile's points carry the sensor row they were found in
//! (`protocol::Point::row`), not their index in the readout, so the
//! triangulation and every host tool that maps a row to a position along
//! the rail see the same rows as with a full readout: a skipped readout's
//! points are a subset of a full one's rows. Recordings of either protocol
//! version decode alike; a profile of a skipped readout spends a skip
//! byte on each row record (`protocol::compact`).
//!
//! # Validation
//! [`Readout::new`] checks a readout once against the sensor's height; the
//! command (`protocol::HostMsg::SetReadout`) carries the plain numbers and
//! the head builds the [`Readout`] from them, refusing (`OutOfRange`) what
//! [`ReadoutError`] names.

use crate::fixed::Q16_16;

/// Read one sensor row in 1, 2 or 4 (the MT9V034's read mode offers ×2
/// and ×4; `firmware/src/camera.rs` says how it does it).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RowSkip {
    /// Every row.
    X1,
    /// One row in two.
    X2,
    /// One row in four.
    X4,
}

impl RowSkip {
    /// The skip of `factor` rows (1, 2 or 4).
    pub const fn new(factor: u8) -> Result<RowSkip, ReadoutError> {
        match factor {
            1 => Ok(RowSkip::X1),
            2 => Ok(RowSkip::X2),
            4 => Ok(RowSkip::X4),
            f => Err(ReadoutError::Skip(f)),
        }
    }

    /// Sensor rows per output row: 1, 2 or 4.
    pub const fn factor(self) -> u8 {
        match self {
            RowSkip::X1 => 1,
            RowSkip::X2 => 2,
            RowSkip::X4 => 4,
        }
    }
}

/// Why a readout was refused.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ReadoutError {
    /// A skip other than 1, 2 or 4.
    Skip(u8),
    /// No rows.
    Empty,
    /// The window's rows are not a whole number of skips (the MT9V034 bins
    /// whole groups of rows).
    Ragged {
        /// Rows of the window.
        rows: u16,
        /// The skip factor.
        skip: u8,
    },
    /// The window ends past the sensor's last row.
    PastSensor {
        /// Its first row.
        first_row: u16,
        /// Its rows.
        rows: u16,
        /// The sensor's height it was checked against.
        sensor_rows: u16,
    },
}

impl core::fmt::Display for ReadoutError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ReadoutError::Skip(s) => write!(f, "row skip {s}: the sensor reads one row in 1, 2 or 4"),
            ReadoutError::Empty => f.write_str("a row window of no rows"),
            ReadoutError::Ragged { rows, skip } => {
                write!(f, "a row window of {rows} rows is not a whole number of row skips of {skip}")
            }
            ReadoutError::PastSensor { first_row, rows, sensor_rows } => {
                write!(f, "a row window of {rows} rows from row {first_row} ends past the sensor's {sensor_rows} rows")
            }
        }
    }
}

impl core::error::Error for ReadoutError {}

/// A validated readout: sensor rows `first_row .. first_row + rows`, one in
/// `skip` of them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Readout {
    first_row: u16,
    rows: u16,
    skip: RowSkip,
}

impl Readout {
    /// Every row of a sensor `sensor_rows` high (what a head reads unless
    /// told otherwise).
    pub const fn full(sensor_rows: u16) -> Readout {
        Readout { first_row: 0, rows: sensor_rows, skip: RowSkip::X1 }
    }

    /// Rows `first_row .. first_row + rows` of a sensor `sensor_rows` high,
    /// one in `skip`: at least one row, a whole number of skips, inside the
    /// sensor.
    pub const fn new(first_row: u16, rows: u16, skip: RowSkip, sensor_rows: u16) -> Result<Readout, ReadoutError> {
        if rows == 0 {
            return Err(ReadoutError::Empty);
        }
        if !rows.is_multiple_of(skip.factor() as u16) {
            return Err(ReadoutError::Ragged { rows, skip: skip.factor() });
        }
        if first_row as u32 + rows as u32 > sensor_rows as u32 {
            return Err(ReadoutError::PastSensor { first_row, rows, sensor_rows });
        }
        Ok(Readout { first_row, rows, skip })
    }

    /// [`Readout::new`] with the skip as a factor (the command's form).
    pub const fn from_factor(first_row: u16, rows: u16, skip: u8, sensor_rows: u16) -> Result<Readout, ReadoutError> {
        match RowSkip::new(skip) {
            Ok(s) => Readout::new(first_row, rows, s, sensor_rows),
            Err(e) => Err(e),
        }
    }

    /// The window's first sensor row.
    pub const fn first_row(&self) -> u16 {
        self.first_row
    }

    /// The window's sensor rows (read or skipped).
    pub const fn rows(&self) -> u16 {
        self.rows
    }

    /// The skip.
    pub const fn skip(&self) -> RowSkip {
        self.skip
    }

    /// One past the window's last sensor row.
    pub const fn end_row(&self) -> u16 {
        self.first_row + self.rows
    }

    /// Rows a frame delivers: `rows / skip`.
    pub const fn rows_read(&self) -> u16 {
        self.rows / self.skip.factor() as u16
    }

    /// The sensor row of output row `i` (`i < rows_read`; saturating
    /// beyond).
    pub const fn sensor_row(&self, i: u16) -> u16 {
        self.first_row.saturating_add(i.saturating_mul(self.skip.factor() as u16))
    }

    /// Whether sensor row `row` is one this readout reads.
    pub const fn reads(&self, row: u16) -> bool {
        row >= self.first_row
            && row < self.end_row()
            && (row - self.first_row).is_multiple_of(self.skip.factor() as u16)
    }
}

/// How a camera honours a readout ([`crate::pipeline::Camera::set_readout`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RowSampling {
    /// It reads whole frames whatever the readout: the head passes over the
    /// rows the readout does not read (the detector's time is saved, the
    /// sensor's is not).
    WholeFrame,
    /// It gives exactly the readout's rows: output row `i` is sensor row
    /// [`Readout::sensor_row`]`(i)`.
    Skip,
    /// It gives one row per group of `skip` sensor rows, their mean (the
    /// MT9V034's binning): output row `i` is the mean of sensor rows
    /// `sensor_row(i) .. sensor_row(i) + skip`, centred
    /// [`Readout::bin_centre_q16`] below `sensor_row(i)`. Points keep
    /// `sensor_row(i)` as their row; the head triangulates them at the
    /// centre.
    Bin,
}

impl Readout {
    /// Where a binned output row's centre lies below its first sensor row,
    /// rows: `(skip − 1) / 2`.
    pub const fn bin_centre_q16(&self) -> Q16_16 {
        Q16_16((self.skip.factor() as i32 - 1) << 15)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_of_a_skipped_window() {
        let r = Readout::new(40, 400, RowSkip::X2, 480).unwrap();
        assert_eq!((r.rows_read(), r.sensor_row(0), r.sensor_row(199), r.end_row()), (200, 40, 438, 440));
        assert!(r.reads(40) && r.reads(42) && !r.reads(41) && !r.reads(440) && !r.reads(38));
        assert_eq!(Readout::full(480).rows_read(), 480);
        assert_eq!(Readout::new(0, 480, RowSkip::X4, 480).unwrap().bin_centre_q16(), Q16_16(3 << 15));
    }

    #[test]
    fn refusals_are_typed() {
        assert_eq!(RowSkip::new(3), Err(ReadoutError::Skip(3)));
        assert_eq!(Readout::new(0, 0, RowSkip::X1, 480), Err(ReadoutError::Empty));
        assert_eq!(Readout::new(0, 6, RowSkip::X4, 480), Err(ReadoutError::Ragged { rows: 6, skip: 4 }));
        assert_eq!(
            Readout::new(400, 96, RowSkip::X1, 480),
            Err(ReadoutError::PastSensor { first_row: 400, rows: 96, sensor_rows: 480 })
        );
        assert_eq!(
            Readout::from_factor(u16::MAX, 2, 2, u16::MAX).map(|r| r.rows()),
            Err(ReadoutError::PastSensor { first_row: u16::MAX, rows: 2, sensor_rows: u16::MAX })
        );
    }
}
