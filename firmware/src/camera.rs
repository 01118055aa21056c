//! The MT9V034 on the DCMI: I²C configuration, snapshot exposures, and
//! continuous capture of each frame into a small circular DMA buffer so that
//! every row is detected while the next ones arrive — no frame buffer.
//!
//! # Capture
//! embassy-stm32 0.6's DCMI driver is snapshot-only (one DMA transfer of at
//! most 65 535 words, no per-line progress), so it is used only to configure
//! the pins, the clock and DCMI_CR; the DMA is driven through the PAC:
//! DMA2 stream 1, request 75 (DCMI) through DMAMUX1 channel 9, 32-bit
//! peripheral-to-memory, **circular** over [`RING_ROWS`] rows in AXI SRAM
//! (DMA1/2 cannot reach DTCM), half- and full-transfer interrupts counting
//! half-rings. The number of words written since the frame began is then
//! `halves × half + (words into the current half)`, read under a critical
//! section that services a pending flag first, so it is exact. Row `r` of
//! the frame sits in ring slot `r mod RING_ROWS`; it is copied out (atomic
//! word loads: the DMA writes behind the compiler's back, the D-cache is off)
//! and checked again afterwards: if the DMA has meanwhile overwritten it, the
//! row is counted as dropped and given to the detector as zeros.
//!
//! # Exposure and strobe
//! The sensor runs in snapshot mode: [`Mt9v034::expose`] restarts the ring,
//! arms one DCMI capture, raises EXPOSURE (integration starts on the edge and
//! lasts the shutter width), busy-waits that long with the lasers lit by the
//! head, and returns; the head switches the lasers off before reading rows.
//! LED_OUT of the sensor is high exactly during integration: wire it into
//! the laser drivers' enable AND gate so the hardware enforces the strobe too.
//!
//! # Image capture in bands
//! A capture (`cms-host capture`) needs every row of a frame, but the ring
//! holds 8 rows and the link moves about 1 MB/s against the sensor's 45
//! MB/s: rows read straight from the ring while the chunks go out are
//! overwritten long before their turn. So the head captures in bands of
//! [`BAND_ROWS`] rows, one exposure each ([`Camera::capture_band_rows`]):
//! after the exposure (lasers off again) [`Camera::start_band`] waits past
//! the rows above the band and copies the band's rows out of the ring as
//! they arrive (a 188-word copy per 32 µs row), and `read_row` then serves
//! them from [`BAND_BYTES`] of band buffer while the head sends them. A
//! band is exposed only once the link has sent the one before (for the
//! first, whatever streaming left): the head waits for an empty link
//! buffer, so a band must fit in it (checked at compile time). A capture assumes a still scene: each band is its own
//! exposure with the same lasers, exposure and gain. 15 bands of 32 rows
//! cost 15 frame times plus 15 × 25 KB on the link: about 0.7 s.
//!
//! # Row window and row skip
//! [`Camera::set_readout`] writes the readout into the sensor (ROW_START,
//! WINDOW_HEIGHT and READ_MODE's row bin, [`readout_registers`]): the
//! sensor then reads out only the window's rows, and for a skip of 2 or 4
//! bins that many rows into one, so a frame has `rows / skip` rows and takes
//! that many row times to read out (the ring and the detector see only
//! them). The MT9V034's read mode has binning, not a plain row skip: a
//! binned row is the mean of its rows, so the camera says
//! [`RowSampling::Bin`] and the head triangulates it at its rows' centre.
//!
//! # Pixel format
//! 8-bit DCMI on D9..D2 of the sensor's 10-bit ADC: 8 bits per pixel, one
//! byte each, four pixels per DMA word (first pixel in the low byte).

use core::cell::Cell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use cms_core::odometer::Odometer;
use cms_core::pipeline::Camera;
use cms_core::readout::{Readout, RowSampling, RowSkip};
use embassy_stm32::dcmi::Dcmi;
use embassy_stm32::gpio::Output;
use embassy_stm32::i2c::{I2c, Master};
use embassy_stm32::mode::Blocking;
use embassy_stm32::pac::dma::vals::{Dir, Dmdis, Fth, Pl, Size};
use embassy_stm32::peripherals::{DCMI, TIM5};
use embassy_stm32::timer::qei::Qei;
use embassy_stm32::{bind_interrupts, pac};
use static_cell::StaticCell;

use crate::board;

/// Rows in the circular DMA buffer.
pub const RING_ROWS: usize = 8;
/// Rows of an image capture per exposure (module docs).
pub const BAND_ROWS: usize = 32;
/// Bytes of the band buffer (8-bit pixels).
pub const BAND_BYTES: usize = BAND_ROWS * board::WIDTH;
// A band's frames (one RawRows chunk of a row each, with at most 48 bytes
// of header, COBS, CRC and delimiter) must fit in the empty link buffer.
const _: () = assert!(BAND_ROWS * (board::WIDTH + 48) <= crate::link::TX_BYTES);
/// 32-bit words per row (4 pixels per word).
pub const ROW_WORDS: usize = board::WIDTH / 4;
/// Words in the ring.
pub const RING_WORDS: usize = RING_ROWS * ROW_WORDS;
const HALF_WORDS: u32 = (RING_WORDS / 2) as u32;
/// DMA2 stream used for the ring, and its DMAMUX1 channel (DMA2 streams are
/// channels 8..15).
const STREAM: usize = 1;
const DMAMUX_CHANNEL: usize = 8 + STREAM;
/// DMAMUX1 request line of the DCMI (RM0433, table "DMAMUX1 requests").
const DCMI_REQUEST: u8 = 75;
/// Longest wait for one row, µs (a frame takes 15 ms to read out).
const ROW_TIMEOUT_US: u32 = 50_000;

/// The ring. AtomicU32 so that reads are never elided or merged while the DMA
/// writes; on a Cortex-M7 a relaxed load is a plain `ldr`.
static RING: [AtomicU32; RING_WORDS] = [const { AtomicU32::new(0) }; RING_WORDS];
/// Half-rings completed since the ring was (re)started.
static HALVES: AtomicU32 = AtomicU32::new(0);
/// A DMA transfer error happened.
static DMA_ERROR: AtomicBool = AtomicBool::new(false);

/// Handler of the ring's DMA interrupt, bound here with the stream it
/// serves (the board binds the interrupts of the drivers it creates).
struct RingInterrupt;

bind_interrupts!(
    /// The binding's proof, which nothing asks for: the ring's DMA is
    /// driven through the PAC, not by an embassy driver.
    struct RingIrqs {
        DMA2_STREAM1 => RingInterrupt;
    }
);

impl embassy_stm32::interrupt::typelevel::Handler<embassy_stm32::interrupt::typelevel::DMA2_STREAM1> for RingInterrupt {
    unsafe fn on_interrupt() {
        service_ring();
    }
}

/// Counts completed half-rings and clears their flags (interrupt, or a
/// reader with interrupts off).
fn service_ring() {
    let isr = pac::DMA2.isr(0).read();
    let mut halves = 0;
    if isr.htif(STREAM) {
        halves += 1;
    }
    if isr.tcif(STREAM) {
        halves += 1;
    }
    if isr.teif(STREAM) {
        DMA_ERROR.store(true, Ordering::Relaxed);
    }
    pac::DMA2.ifcr(0).write(|w| {
        w.set_htif(STREAM, isr.htif(STREAM));
        w.set_tcif(STREAM, isr.tcif(STREAM));
        w.set_teif(STREAM, isr.teif(STREAM));
    });
    if halves > 0 {
        HALVES.fetch_add(halves, Ordering::Relaxed);
    }
}

/// Words the DMA has written since the ring started.
fn words_written() -> u32 {
    critical_section::with(|_| {
        loop {
            service_ring();
            let ndtr = pac::DMA2.st(STREAM).ndtr().read().ndt() as u32;
            let isr = pac::DMA2.isr(0).read();
            if isr.htif(STREAM) || isr.tcif(STREAM) {
                continue; // a half completed between the two reads: count it first
            }
            let halves = HALVES.load(Ordering::Relaxed);
            let offset = RING_WORDS as u32 - ndtr.min(RING_WORDS as u32);
            let in_half = offset.saturating_sub((halves % 2) * HALF_WORDS).min(HALF_WORDS);
            return halves * HALF_WORDS + in_half;
        }
    })
}

/// Stops the stream, then restarts it at the beginning of the ring.
fn restart_ring() {
    let st = pac::DMA2.st(STREAM);
    st.cr().modify(|w| w.set_en(false));
    while st.cr().read().en() {}
    pac::DMA2.ifcr(0).write(|w| {
        w.set_htif(STREAM, true);
        w.set_tcif(STREAM, true);
        w.set_teif(STREAM, true);
        w.set_dmeif(STREAM, true);
        w.set_feif(STREAM, true);
    });
    HALVES.store(0, Ordering::Relaxed);
    DMA_ERROR.store(false, Ordering::Relaxed);
    pac::DMAMUX1.ccr(DMAMUX_CHANNEL).write(|w| w.set_dmareq_id(DCMI_REQUEST));
    st.par().write_value(pac::DCMI.dr().as_ptr() as u32);
    st.m0ar().write_value(RING.as_ptr() as u32);
    st.ndtr().write(|w| w.set_ndt(RING_WORDS as u16));
    st.fcr().write(|w| {
        w.set_dmdis(Dmdis::DISABLED);
        w.set_fth(Fth::HALF);
    });
    st.cr().write(|w| {
        w.set_dir(Dir::PERIPHERAL_TO_MEMORY);
        w.set_circ(true);
        w.set_minc(true);
        w.set_psize(Size::BITS32);
        w.set_msize(Size::BITS32);
        w.set_pl(Pl::VERY_HIGH);
        w.set_htie(true);
        w.set_tcie(true);
        w.set_teie(true);
        w.set_en(true);
    });
}

/// MT9V034 registers used here (data sheet register reference).
mod reg {
    pub const CHIP_VERSION: u8 = 0x00;
    pub const COL_START: u8 = 0x01;
    pub const ROW_START: u8 = 0x02;
    pub const WINDOW_HEIGHT: u8 = 0x03;
    pub const WINDOW_WIDTH: u8 = 0x04;
    pub const HBLANK: u8 = 0x05;
    pub const VBLANK: u8 = 0x06;
    pub const CHIP_CONTROL: u8 = 0x07;
    pub const READ_MODE_A: u8 = 0x0D;
    pub const SHUTTER_WIDTH_A: u8 = 0x0B;
    pub const RESET: u8 = 0x0C;
    pub const ADC_MODE: u8 = 0x1C;
    pub const ANALOG_GAIN_A: u8 = 0x35;
    pub const AEC_AGC_ENABLE: u8 = 0xAF;
    /// The MT9V034's CHIP_VERSION.
    pub const MT9V034: u16 = 0x1324;
    /// ROW_START of the first active row (rows 0–3 are dark), and the
    /// register's largest value.
    pub const FIRST_ACTIVE_ROW: u16 = 4;
    pub const ROW_START_MAX: u16 = 482;
    /// READ_MODE (context A), bit by bit:
    /// * 1:0 row bin: 0 every row, 1 two rows binned into one, 2 four;
    /// * 3:2 column bin, the same for columns (0 here: the detector needs
    ///   every column);
    /// * 4 row flip, 5 column flip (read bottom to top, right to left: 0);
    /// * 6 show dark columns, 7 show dark rows (0: active pixels only);
    /// * 9:8 reserved, set at reset (0x0300) and kept set.
    pub const READ_MODE_RESERVED: u16 = 0x0300;
    pub const READ_MODE_ROW_BIN_2: u16 = 1;
    pub const READ_MODE_ROW_BIN_4: u16 = 2;
}

/// The register writes of a readout: ROW_START (first row of the window,
/// counted from the first dark row), WINDOW_HEIGHT (the window's rows
/// before binning) and READ_MODE (the row bin). `None` for a window whose
/// start the sensor cannot take.
pub fn readout_registers(r: &Readout) -> Option<[(u8, u16); 3]> {
    let row_start = reg::FIRST_ACTIVE_ROW + r.first_row();
    if row_start > reg::ROW_START_MAX || r.end_row() as usize > board::HEIGHT {
        return None;
    }
    let bin = match r.skip() {
        RowSkip::X1 => 0,
        RowSkip::X2 => reg::READ_MODE_ROW_BIN_2,
        RowSkip::X4 => reg::READ_MODE_ROW_BIN_4,
    };
    Some([
        (reg::ROW_START, row_start),
        (reg::WINDOW_HEIGHT, r.rows()),
        (reg::READ_MODE_A, reg::READ_MODE_RESERVED | bin),
    ])
}

/// Why the camera failed.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub enum CameraError {
    /// I²C transfer failed (no sensor, bus stuck).
    I2c,
    /// The sensor is not an MT9V034 (CHIP_VERSION read).
    WrongChip(u16),
    /// No row within the timeout (no pixel clock, no VSYNC).
    Timeout,
    /// DMA transfer error or DCMI overrun.
    Transfer,
    /// `read_row` without an exposure, or past the last row.
    NoFrame,
    /// A readout the sensor's registers cannot take.
    Readout,
}

/// The sensor and its capture path.
pub struct Mt9v034 {
    i2c: I2c<'static, Blocking, Master>,
    _dcmi: Dcmi<'static, DCMI>,
    exposure_pin: Output<'static>,
    qei: Qei<'static, TIM5>,
    odometer: Cell<Odometer>,
    shutter_rows: u16,
    /// Rows a frame of the readout written into the sensor has.
    frame_rows: usize,
    next_row: Option<usize>,
    dropped_rows: u32,
    cycles_per_us: u32,
    /// A capture's band of rows, and the next of its `rows` to serve.
    band: &'static mut [u8; BAND_BYTES],
    band_next: Option<(usize, usize)>,
}

impl Mt9v034 {
    /// Checks the chip, configures it (full 752 × 480 window, snapshot mode,
    /// manual exposure and gain, linear 10-bit ADC) and the odometer.
    pub fn new(
        i2c: I2c<'static, Blocking, Master>,
        dcmi: Dcmi<'static, DCMI>,
        exposure_pin: Output<'static>,
        qei: Qei<'static, TIM5>,
        sysclk_hz: u32,
    ) -> Result<Self, CameraError> {
        let odometer = Odometer::new(16, qei.count() as u32, board::ENCODER_NM_PER_COUNT, board::ENCODER_REVERSE)
            .map_err(|_| CameraError::NoFrame)?;
        let mut cam = Mt9v034 {
            i2c,
            _dcmi: dcmi,
            exposure_pin,
            qei,
            odometer: Cell::new(odometer),
            shutter_rows: 0,
            frame_rows: board::HEIGHT,
            next_row: None,
            dropped_rows: 0,
            cycles_per_us: sysclk_hz / 1_000_000,
            band: {
                static BAND: StaticCell<[u8; BAND_BYTES]> = StaticCell::new();
                BAND.init([0; BAND_BYTES])
            },
            band_next: None,
        };
        let id = cam.read(reg::CHIP_VERSION)?;
        if id != reg::MT9V034 {
            return Err(CameraError::WrongChip(id));
        }
        cam.write(reg::RESET, 0x0001)?; // soft reset of the digital logic
        cam.write(reg::RESET, 0x0000)?;
        for (r, v) in [
            (reg::COL_START, 1),
            (reg::ROW_START, 4),
            (reg::WINDOW_HEIGHT, board::HEIGHT as u16),
            (reg::WINDOW_WIDTH, board::WIDTH as u16),
            (reg::HBLANK, board::HBLANK as u16),
            (reg::VBLANK, 45),
            // Progressive scan, snapshot mode (bits 4:3 = 3), parallel output
            // on, simultaneous integration and readout.
            (reg::CHIP_CONTROL, 0x0398),
            (reg::AEC_AGC_ENABLE, 0x0000), // manual exposure and gain: the detector's noise model needs them fixed
            (reg::ADC_MODE, 0x0302),       // linear 10-bit ADC, context A and B
            (reg::ANALOG_GAIN_A, 16),      // 1×
            (reg::READ_MODE_A, reg::READ_MODE_RESERVED), // every row and column, not flipped, no dark pixels
        ] {
            cam.write(r, v)?;
        }
        cam.set_exposure(200)?;
        Ok(cam)
    }

    fn write(&mut self, r: u8, v: u16) -> Result<(), CameraError> {
        let [hi, lo] = v.to_be_bytes();
        self.i2c.blocking_write(board::SENSOR_I2C_ADDR, &[r, hi, lo]).map_err(|_| CameraError::I2c)
    }

    fn read(&mut self, r: u8) -> Result<u16, CameraError> {
        let mut b = [0u8; 2];
        self.i2c.blocking_write_read(board::SENSOR_I2C_ADDR, &[r], &mut b).map_err(|_| CameraError::I2c)?;
        Ok(u16::from_be_bytes(b))
    }

    /// Shutter width in rows for `exposure_us` (rounded up, at least one).
    fn set_exposure(&mut self, exposure_us: u32) -> Result<(), CameraError> {
        let rows = (exposure_us as u64 * 1000).div_ceil(board::ROW_TIME_NS as u64).clamp(1, 32_765) as u16;
        if rows != self.shutter_rows {
            self.write(reg::SHUTTER_WIDTH_A, rows)?;
            self.shutter_rows = rows;
        }
        Ok(())
    }

    /// Exposure actually used, µs (whole rows).
    pub fn exposure_ns(&self) -> u32 {
        self.shutter_rows as u32 * board::ROW_TIME_NS
    }

    fn elapsed_us(&self, since: u32) -> u32 {
        cortex_m::peripheral::DWT::cycle_count().wrapping_sub(since) / self.cycles_per_us
    }
}

impl Camera for Mt9v034 {
    type Error = CameraError;

    fn width(&self) -> u16 {
        board::WIDTH as u16
    }

    fn height(&self) -> u16 {
        board::HEIGHT as u16
    }

    fn bits(&self) -> u8 {
        board::BITS
    }

    fn expose(&mut self, exposure_us: u32, _laser_mask: u8) -> Result<i64, CameraError> {
        self.set_exposure(exposure_us)?;
        let odometer_um = self.odometer_um().unwrap_or(0);
        // Ring from its start, then one DCMI capture (snapshot mode: the next
        // frame after VSYNC, then CAPTURE clears itself).
        restart_ring();
        pac::DCMI.icr().write(|w| {
            w.set_ovr_isc(true);
            w.set_err_isc(true);
            w.set_frame_isc(true);
        });
        pac::DCMI.cr().modify(|w| {
            w.set_enable(true);
            w.set_capture(true);
        });
        // Integration starts on EXPOSURE's rising edge and lasts the shutter
        // width; the lasers (lit by the head) stay on for exactly that long.
        self.exposure_pin.set_high();
        cortex_m::asm::delay(self.exposure_ns() / 1000 * self.cycles_per_us);
        self.exposure_pin.set_low();
        self.next_row = Some(0);
        self.band_next = None;
        Ok(odometer_um)
    }

    fn read_row(&mut self, row: &mut [u16]) -> Result<(), CameraError> {
        if let Some((i, rows)) = self.band_next {
            if i >= rows {
                self.band_next = None;
                return Err(CameraError::NoFrame);
            }
            let src = &self.band[i * board::WIDTH..][..board::WIDTH];
            for (p, &b) in row.iter_mut().zip(src) {
                *p = u16::from(b);
            }
            self.band_next = Some((i + 1, rows));
            return Ok(());
        }
        self.ring_row(row)
    }

    fn odometer_um(&self) -> Option<i64> {
        let mut o = self.odometer.get();
        let d = o.update(self.qei.count() as u32);
        self.odometer.set(o);
        Some(d)
    }

    fn dropped_rows(&self) -> u32 {
        self.dropped_rows
    }

    fn capture_band_rows(&self) -> u16 {
        BAND_ROWS as u16
    }

    fn set_readout(&mut self, readout: &Readout) -> Result<RowSampling, CameraError> {
        let writes = readout_registers(readout).ok_or(CameraError::Readout)?;
        // Written while no capture is armed: the sensor takes them at the
        // next frame start, which the next EXPOSURE pulse begins.
        for (r, v) in writes {
            self.write(r, v)?;
        }
        self.frame_rows = usize::from(readout.rows_read());
        Ok(if readout.skip() == RowSkip::X1 { RowSampling::Skip } else { RowSampling::Bin })
    }

    fn start_band(&mut self, first: u16, rows: u16, scratch: &mut [u16]) -> Result<(), CameraError> {
        let rows = usize::from(rows).min(BAND_ROWS);
        let lost = self.dropped_rows;
        for _ in 0..first {
            self.ring_row(scratch)?;
        }
        for i in 0..rows {
            self.ring_row(scratch)?;
            for (b, &p) in self.band[i * board::WIDTH..][..board::WIDTH].iter_mut().zip(scratch.iter()) {
                *b = p as u8;
            }
        }
        // A band row the DMA overtook would be a black row in the image:
        // better no capture than a wrong one.
        if self.dropped_rows != lost {
            return Err(CameraError::Transfer);
        }
        self.band_next = Some((0, rows));
        Ok(())
    }
}

impl Mt9v034 {
    /// The next row of the exposed frame straight from the ring, waiting
    /// for it to arrive (module docs).
    fn ring_row(&mut self, row: &mut [u16]) -> Result<(), CameraError> {
        let r = self.next_row.ok_or(CameraError::NoFrame)?;
        if r >= self.frame_rows {
            self.next_row = None;
            return Err(CameraError::NoFrame);
        }
        let need = ((r + 1) * ROW_WORDS) as u32;
        let start = cortex_m::peripheral::DWT::cycle_count();
        while words_written() < need {
            let ris = pac::DCMI.ris().read();
            if DMA_ERROR.load(Ordering::Relaxed) || ris.ovr_ris() || ris.err_ris() {
                self.next_row = None;
                return Err(CameraError::Transfer);
            }
            if self.elapsed_us(start) > ROW_TIMEOUT_US {
                self.next_row = None;
                return Err(CameraError::Timeout);
            }
        }
        let base = (r % RING_ROWS) * ROW_WORDS;
        for (k, px) in row.chunks_exact_mut(4).enumerate().take(ROW_WORDS) {
            let w = RING[base + k].load(Ordering::Relaxed).to_le_bytes();
            for (p, b) in px.iter_mut().zip(w) {
                *p = b as u16;
            }
        }
        // Overwritten while (or before) we copied it: the DMA is RING_ROWS
        // rows ahead. Lost, counted, and blank for the detector.
        if words_written() > ((r + RING_ROWS) * ROW_WORDS) as u32 {
            self.dropped_rows = self.dropped_rows.wrapping_add(1);
            row.fill(0);
        }
        self.next_row = Some(r + 1);
        Ok(())
    }
}
