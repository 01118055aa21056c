//! The head's command handling: each [`HostMsg`] checked against the
//! head's state and the camera, then carried out and acknowledged, or
//! refused with an [`ErrorCode`] (a fault while streaming, lasers off).

use super::{Camera, ColumnWindow, Detector, Track, Windows};
use super::{CaptureJob, EXPOSURE_RANGE_US, Head, LaserDriver, STATUS_INTERVAL_US, valid_trigger};
use crate::fixed::Px;
use crate::odometer::DistanceTrigger;
use crate::protocol::{Command, DeviceMsg, ErrorCode, HeadState, HostMsg, LASERS, Start, Trigger};
use crate::readout::Readout;
use heapless::Vec;

impl<const W: usize, L: LaserDriver> Head<W, L> {
    /// Carries out one command.
    pub fn handle<C: Camera>(&mut self, cmd: Command, now_us: u64, camera: &C, reply: &mut impl FnMut(&DeviceMsg)) {
        self.last_heard_us = now_us;
        let seq = cmd.seq;
        let streaming = self.state == HeadState::Streaming;
        // Ok(true): acknowledged with the status (the state changed).
        let done = match cmd.msg {
            HostMsg::Heartbeat => return,
            HostMsg::GetInfo => return reply(&DeviceMsg::Hello(self.info(camera))),
            HostMsg::Start(s) => self.start(s, now_us, camera).map(|()| true),
            HostMsg::Stop => {
                self.state = HeadState::Idle;
                self.capture = None;
                self.set_lasers(0);
                Ok(true)
            }
            HostMsg::SetExposure { exposure_us: us } => {
                let period_us = 1_000_000 / self.start.rate_hz as u64;
                if !(EXPOSURE_RANGE_US.0..=EXPOSURE_RANGE_US.1).contains(&us)
                    || (streaming && !self.duty.sustainable(us, period_us))
                {
                    Err(ErrorCode::OutOfRange)
                } else {
                    self.exposure_us = us;
                    self.store_dirty = true;
                    Ok(false)
                }
            }
            // The rest set what a stream uses, or read the sensor: refused
            // while streaming.
            _ if streaming => Err(ErrorCode::Busy),
            HostMsg::SetDetector(cfg) => Detector::new(cfg).map_err(|_| ErrorCode::InvalidConfig).map(|d| {
                self.detector = d;
                self.store_dirty = true;
                false
            }),
            HostMsg::SetCalibration(c) => self.load_calibration(c).map_err(|_| ErrorCode::InvalidConfig).map(|()| {
                self.store_dirty = true;
                false
            }),
            HostMsg::CaptureImage(mask) => {
                if mask >= (1 << LASERS) {
                    Err(ErrorCode::OutOfRange)
                } else if self.capture.is_some() {
                    Err(ErrorCode::Busy)
                } else if camera.width() as usize > W {
                    // The rows go through the head's row buffer, as for Start.
                    Err(ErrorCode::SensorFault)
                } else {
                    self.capture = Some(CaptureJob { seq, mask, next_row: 0 });
                    Ok(false)
                }
            }
            HostMsg::SetWindows(w) => {
                let given: Vec<ColumnWindow, LASERS> = w.iter().flatten().copied().collect();
                if !given.is_empty() && Windows::new(&given, camera.width()).is_err() {
                    Err(ErrorCode::OutOfRange)
                } else {
                    self.windows = w;
                    Ok(false)
                }
            }
            HostMsg::SetReadout { first_row, rows, skip } => {
                Readout::from_factor(first_row, rows, skip, camera.height()).map_err(|_| ErrorCode::OutOfRange).map(
                    |r| {
                        self.readout = Some(r);
                        false
                    },
                )
            }
            HostMsg::SetTracking { half_width_px: 0 } => {
                self.tracking = None;
                Ok(false)
            }
            HostMsg::SetTracking { half_width_px } => {
                Track::new(half_width_px).map_err(|_| ErrorCode::OutOfRange).map(|t| {
                    self.tracking = Some(t);
                    false
                })
            }
            HostMsg::SetTrigger(t) if !valid_trigger(t) => Err(ErrorCode::OutOfRange),
            HostMsg::SetTrigger(t) => {
                self.trigger = t;
                self.store_dirty = true;
                Ok(false)
            }
        };
        match done {
            Ok(with_status) => {
                reply(&DeviceMsg::Ack(seq));
                if with_status {
                    reply(&DeviceMsg::Status(self.status(now_us)));
                }
            }
            Err(code) => self.fail(code, Some(seq), reply),
        }
    }

    /// `Start`: checked (no capture under way, rate and lasers in range, a
    /// row that fits the buffers, the duty cycle sustainable at the rate, an
    /// odometer for a distance trigger, the detector's bit depth the
    /// camera's), then streaming from `now_us`, each lit laser's track
    /// spread evenly across the row.
    fn start<C: Camera>(&mut self, s: Start, now_us: u64, camera: &C) -> Result<(), ErrorCode> {
        if self.capture.is_some() {
            return Err(ErrorCode::Busy);
        }
        let valid_mask = s.laser_mask != 0 && s.laser_mask < (1 << LASERS);
        if !(1..=1000).contains(&s.rate_hz) || !valid_mask {
            return Err(ErrorCode::OutOfRange);
        }
        if camera.width() as usize > W {
            return Err(ErrorCode::SensorFault);
        }
        if !self.duty.sustainable(self.exposure_us, 1_000_000 / s.rate_hz as u64) {
            return Err(ErrorCode::OutOfRange);
        }
        self.distance = match self.trigger {
            Trigger::Timed => None,
            Trigger::Distance { every_um } => match camera.odometer_um().map(|p| DistanceTrigger::new(every_um, p)) {
                Some(Ok(t)) => Some(t),
                _ => return Err(ErrorCode::OutOfRange),
            },
        };
        // The detector's saturation level and noise floor assume its
        // bit depth: streaming with another camera depth is refused.
        if self.detector.config().bits != camera.bits() {
            return Err(ErrorCode::InvalidConfig);
        }
        self.start = s;
        self.frame_readout = self.readout;
        self.state = HeadState::Streaming;
        self.fault = None;
        self.epoch_us = if self.frames == 0 { now_us } else { self.epoch_us };
        self.next_frame_us = now_us;
        self.next_status_us = now_us + STATUS_INTERVAL_US;
        self.window_start_us = now_us;
        self.window_on_us = 0;
        self.sequential_next = 0;
        let w = camera.width() as i32;
        let lit = s.laser_mask.count_ones() as i32;
        let mut k = 0;
        for (i, t) in self.track.iter_mut().enumerate() {
            if s.laser_mask & (1 << i) != 0 {
                k += 1;
                *t = Px::from_int(w * k / (lit + 1));
            }
        }
        Ok(())
    }
}
