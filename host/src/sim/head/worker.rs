//! Rendering on a second thread, overlapped with the head's detection.
//!
//! The reference scene costs about as much to render (≈ 8 ms a frame) as to
//! detect (≈ 7 ms): rendering row `r + 1…` while the head detects row `r`
//! nearly halves the frame time on a multi-core host. Rows depend only on
//! the scene, the shot and the row, so the pixels are identical to rendering
//! inline.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;
use std::time::Duration;

use cms_core::readout::Readout;

use super::RowRenderer;

enum Job {
    Frame { generation: u64, frame: u64, t_us: u64, exposure_us: u32, mask: u8, readout: Readout },
}

enum Done {
    Odometer { generation: u64, odometer_um: i64 },
    Row { generation: u64, row: u16, pixels: Vec<u16> },
}

/// A [`RowRenderer`] running on its own thread.
pub struct Threaded {
    size: (u16, u16),
    bits: u8,
    generation: u64,
    readout: Readout,
    jobs: Option<SyncSender<Job>>,
    done: Receiver<Done>,
    spare: SyncSender<Vec<u16>>,
    thread: Option<JoinHandle<()>>,
    cpu_ns: Arc<AtomicU64>,
}

impl Threaded {
    /// Moves `renderer` to a new thread.
    pub fn new<R: RowRenderer + Send + 'static>(mut renderer: R) -> std::io::Result<Threaded> {
        let (size, bits) = (renderer.size(), renderer.bits());
        let (jobs, job_rx) = sync_channel::<Job>(2);
        // Room for a whole frame: the worker never waits for the head within one.
        let (done_tx, done) = sync_channel::<Done>(size.1 as usize + 2);
        let (spare, spare_rx) = sync_channel::<Vec<u16>>(size.1 as usize + 2);
        let cpu_ns = Arc::new(AtomicU64::new(0));
        let cpu = cpu_ns.clone();
        let thread = std::thread::Builder::new().name("cms-sim-render".into()).spawn(move || {
            let cpu0 = super::server::thread_cpu();
            while let Ok(Job::Frame { generation, frame, t_us, exposure_us, mask, readout }) = job_rx.recv() {
                let odometer_um = renderer.begin_frame(frame, t_us, exposure_us, mask);
                if done_tx.send(Done::Odometer { generation, odometer_um }).is_err() {
                    return;
                }
                for row in (0..readout.rows_read()).map(|i| readout.sensor_row(i)) {
                    let mut pixels = spare_rx.try_recv().unwrap_or_default();
                    pixels.resize(size.0 as usize, 0);
                    renderer.row(row, &mut pixels);
                    if done_tx.send(Done::Row { generation, row, pixels }).is_err() {
                        return;
                    }
                }
                let spent = super::server::thread_cpu() - cpu0 + renderer.cpu();
                cpu.store(spent.as_nanos() as u64, Ordering::Relaxed);
            }
        })?;
        let readout = Readout::full(size.1);
        Ok(Threaded { size, bits, generation: 0, readout, jobs: Some(jobs), done, spare, thread: Some(thread), cpu_ns })
    }
}

impl RowRenderer for Threaded {
    fn size(&self) -> (u16, u16) {
        self.size
    }
    fn bits(&self) -> u8 {
        self.bits
    }
    fn cpu(&self) -> Duration {
        Duration::from_nanos(self.cpu_ns.load(Ordering::Relaxed))
    }
    fn begin_frame(&mut self, frame: u64, t_us: u64, exposure_us: u32, mask: u8) -> i64 {
        self.generation += 1;
        let generation = self.generation;
        let job = Job::Frame { generation, frame, t_us, exposure_us, mask, readout: self.readout };
        if self.jobs.as_ref().is_none_or(|j| j.send(job).is_err()) {
            return 0;
        }
        // Rows of an abandoned frame are skipped.
        loop {
            match self.done.recv() {
                Ok(Done::Odometer { generation: g, odometer_um }) if g == generation => return odometer_um,
                Ok(Done::Row { pixels, .. }) => {
                    let _ = self.spare.try_send(pixels);
                }
                Ok(Done::Odometer { .. }) => {}
                Err(_) => return 0,
            }
        }
    }
    fn set_readout(&mut self, readout: &Readout) {
        self.readout = *readout;
    }
    fn row(&mut self, r: u16, out: &mut [u16]) {
        loop {
            match self.done.recv() {
                Ok(Done::Row { generation, row, pixels }) if generation == self.generation && row >= r => {
                    debug_assert_eq!(row, r, "rows are read in order");
                    let n = out.len().min(pixels.len());
                    out[..n].copy_from_slice(&pixels[..n]);
                    let _ = self.spare.try_send(pixels);
                    return;
                }
                Ok(Done::Row { pixels, .. }) => {
                    let _ = self.spare.try_send(pixels);
                }
                Ok(Done::Odometer { .. }) => {}
                Err(_) => {
                    out.fill(0);
                    return;
                }
            }
        }
    }
}

impl Drop for Threaded {
    fn drop(&mut self) {
        // Closing the job channel ends the worker once it finishes its frame;
        // draining `done` unblocks it if its queue is full.
        self.jobs = None;
        while self.done.recv().is_ok() {}
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
