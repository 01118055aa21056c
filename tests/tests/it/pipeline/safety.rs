//! The head's laser-safety rules (lasers off unless streaming, and off on
//! any fault, lost heartbeat or refused command; the duty limit), its
//! calibration checks, triggers, settings and status.

use super::*;

#[test]
fn lasers_are_off_until_streaming_and_profiles_match_the_truth() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    assert_eq!(l.now(), 0, "off at construction");
    let mut out = Vec::new();
    let mut clock = 0u64;
    let mut ns = || {
        clock += 1000;
        clock
    };
    h.poll(0, &mut cam, &mut ns, &mut |m| out.push(m.clone()));
    assert_eq!(l.now(), 0);
    assert_eq!(cam.exposures, 0, "idle: no exposure");
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 10, &cam, &mut |m| out.push(m.clone()));
    assert!(out.contains(&DeviceMsg::Ack(1)));
    h.poll(20, &mut cam, &mut ns, &mut |m| out.push(m.clone()));
    assert_eq!(cam.lit, vec![0b111], "lit during the exposure");
    assert_eq!(l.now(), 0, "strobed: off again before the rows are read");
    let profiles: Vec<&Profile> =
        out.iter().filter_map(|m| if let DeviceMsg::Profile(p) = m { Some(p) } else { None }).collect();
    assert_eq!(profiles.len(), 1);
    let p = profiles[0];
    assert_eq!(p.laser_mask, 0b111);
    assert_eq!(p.lasers.len(), 3);
    let mut se = 0.0;
    let mut n = 0;
    for lp in &p.lasers {
        assert_eq!(lp.points.len(), 480, "laser {}: one point per row", lp.laser);
        for pt in &lp.points {
            let e = pt.position.to_f64() - Cam::truth(pt.row, lp.laser as usize);
            se += e * e;
            n += 1;
        }
    }
    let rms = (se / n as f64).sqrt();
    assert!(rms < 0.02, "RMS {rms}");
    out.clear();
    h.handle(cmd(2, HostMsg::Stop), 30, &cam, &mut |m| out.push(m.clone()));
    assert_eq!(l.now(), 0);
    assert_eq!(h.state(), HeadState::Idle);
    assert!(out.contains(&DeviceMsg::Ack(2)));
}

#[test]
fn heartbeat_loss_turns_the_lasers_off() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    let mut out = Vec::new();
    let mut ns = || 0u64;
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |m| out.push(m.clone()));
    let mut t = 0;
    // Heartbeats every 250 ms keep it streaming for 3 s.
    while t < 3_000_000 {
        h.poll(t, &mut cam, &mut ns, &mut |m| out.push(m.clone()));
        if t % 250_000 == 0 {
            h.handle(cmd(2, HostMsg::Heartbeat), t, &cam, &mut |m| out.push(m.clone()));
        }
        t += 50_000;
    }
    assert_eq!(h.state(), HeadState::Streaming);
    assert!(cam.lit.len() >= 29 && cam.lit.iter().all(|&m| m == 0b111), "{:?}", cam.lit);
    // Silence: at most 1 s + one poll later the lasers are off.
    let last_heard = t - 50_000;
    out.clear();
    while h.state() == HeadState::Streaming {
        h.poll(t, &mut cam, &mut ns, &mut |m| out.push(m.clone()));
        t += 10_000;
    }
    assert!(t - last_heard <= HEARTBEAT_TIMEOUT_US + 70_000, "{}", t - last_heard);
    assert_eq!(l.now(), 0);
    assert_eq!(h.state(), HeadState::Fault);
    assert!(out.contains(&DeviceMsg::Error { seq: None, code: ErrorCode::HeartbeatLost }));
    // Nothing relights them but a new Start.
    let before = cam.exposures;
    for _ in 0..30 {
        h.poll(t, &mut cam, &mut ns, &mut |_| {});
        t += 100_000;
    }
    assert_eq!(l.now(), 0);
    assert_eq!(cam.exposures, before);
}

#[test]
fn any_error_while_streaming_stops_with_lasers_off() {
    for bad in
        [HostMsg::SetDetector(default_detector()), HostMsg::SetExposure { exposure_us: 0 }, HostMsg::CaptureImage(1)]
    {
        let (mut h, l) = head();
        let mut cam = Cam::watching(&l);
        let mut ns = || 0u64;
        h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
        h.poll(0, &mut cam, &mut ns, &mut |_| {});
        assert_eq!(cam.lit, vec![0b111]);
        let mut out = Vec::new();
        h.handle(cmd(2, bad.clone()), 1, &cam, &mut |m| out.push(m.clone()));
        assert_eq!(l.now(), 0, "{bad:?}");
        assert_eq!(h.state(), HeadState::Fault);
        assert!(out.iter().any(|m| matches!(m, DeviceMsg::Error { seq: Some(2), .. })));
        // No further strobe after the fault.
        h.poll(200_000, &mut cam, &mut ns, &mut |_| {});
        assert_eq!(cam.lit, vec![0b111], "{bad:?}");
    }
    // A link error (bad CRC from the host) too.
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    h.handle(cmd(1, start(0b001, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    h.poll(0, &mut cam, &mut || 0, &mut |_| {});
    assert_eq!(cam.lit, vec![0b001]);
    h.link_error(ErrorCode::Crc, &mut |_| {});
    assert_eq!(l.now(), 0);
    assert_eq!(h.state(), HeadState::Fault);
}

#[test]
fn camera_fault_turns_the_lasers_off() {
    let (mut h, l) = head();
    let mut cam = Cam::new();
    let mut out = Vec::new();
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    cam.fail = true;
    h.poll(0, &mut cam, &mut || 0, &mut |m| out.push(m.clone()));
    assert_eq!(l.now(), 0);
    assert!(out.contains(&DeviceMsg::Error { seq: None, code: ErrorCode::SensorFault }));
}

#[test]
fn sequential_pattern_lights_one_laser_per_frame() {
    let (mut h, l) = head();
    let mut cam = Cam::new();
    let mut masks = Vec::new();
    h.handle(cmd(1, start(0b101, LaserPattern::Sequential)), 0, &cam, &mut |_| {});
    for i in 0..4u64 {
        h.handle(cmd(2, HostMsg::Heartbeat), i * 100_000, &cam, &mut |_| {});
        h.poll(i * 100_000, &mut cam, &mut || 0, &mut |m| {
            if let DeviceMsg::Profile(p) = m {
                masks.push(p.laser_mask);
                assert_eq!(p.lasers.len(), 1);
                assert_eq!(p.lasers[0].points.len(), 480);
            }
        });
    }
    assert_eq!(masks, vec![0b001, 0b100, 0b001, 0b100]);
    // Between frames of the sequential pattern, all off.
    assert_eq!(l.now(), 0);
    assert!(l.0.borrow().iter().all(|&m| m.count_ones() <= 1));
}

#[test]
fn invalid_commands_are_refused_and_lasers_stay_off() {
    let (mut h, l) = head();
    let cam = Cam::new();
    let mut out = Vec::new();
    let mut bad_cfg = default_detector();
    bad_cfg.bits = 3;
    h.handle(cmd(1, HostMsg::SetDetector(bad_cfg)), 0, &cam, &mut |m| out.push(m.clone()));
    h.handle(cmd(2, start(0, LaserPattern::Simultaneous)), 0, &cam, &mut |m| out.push(m.clone()));
    h.handle(
        cmd(3, HostMsg::Start(Start { rate_hz: 0, laser_mask: 1, pattern: LaserPattern::Simultaneous })),
        0,
        &cam,
        &mut |m| out.push(m.clone()),
    );
    assert_eq!(
        out,
        vec![
            DeviceMsg::Error { seq: Some(1), code: ErrorCode::InvalidConfig },
            DeviceMsg::Error { seq: Some(2), code: ErrorCode::OutOfRange },
            DeviceMsg::Error { seq: Some(3), code: ErrorCode::OutOfRange },
        ]
    );
    assert_eq!(l.now(), 0);
    assert_eq!(h.state(), HeadState::Idle);
}

#[test]
fn dropping_the_head_turns_the_lasers_off() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    h.poll(0, &mut cam, &mut || 0, &mut |_| {});
    assert_eq!(cam.lit, vec![0b111]);
    let switches = l.0.borrow().len();
    drop(h);
    assert_eq!(l.now(), 0);
    assert_eq!(l.0.borrow().len(), switches + 1, "the drop drives the enables low");
}

#[test]
fn capture_sends_the_whole_image_with_lasers_lit_only_for_it() {
    let (mut h, l) = head();
    let mut cam = Cam::new();
    let mut out = Vec::new();
    h.handle(cmd(4, HostMsg::CaptureImage(0b010)), 0, &cam, &mut |m| out.push(m.clone()));
    h.poll(0, &mut cam, &mut || 0, &mut |m| out.push(m.clone()));
    let bytes: usize =
        out.iter().filter_map(|m| if let DeviceMsg::RawRows(r) = m { Some(r.data.len()) } else { None }).sum();
    assert_eq!(bytes, 752 * 480 * 2);
    assert_eq!(l.now(), 0);
    assert!(l.0.borrow().contains(&0b010));
}

#[test]
fn a_detector_of_another_bit_depth_is_refused_at_start() {
    let l = Lasers::default();
    let mut cfg = default_detector();
    cfg.bits = 8;
    cfg.saturation = 255;
    let mut h: Head<752, Lasers> = Head::new(l.clone(), cfg, Identity { firmware: "t", board: "t" }).unwrap();
    let cam = Cam::new(); // 12-bit
    let mut out = Vec::new();
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |m| out.push(m.clone()));
    assert_eq!(out, vec![DeviceMsg::Error { seq: Some(1), code: ErrorCode::InvalidConfig }]);
    assert_eq!(l.now(), 0);
    assert_eq!(ErrorCode::from(WireError::Crc), ErrorCode::Crc);
    assert_eq!(ErrorCode::from(WireError::Version(3)), ErrorCode::Version(3));
    assert_eq!(ErrorCode::from(WireError::Overflow), ErrorCode::Decode);
}

#[test]
fn a_calibrated_head_triangulates_every_point_and_refuses_bad_calibrations() {
    let (mut h, l) = head();
    let mut cam = Cam::new();
    let mut out = Vec::new();
    // Refused: the id 0, a plane through the camera, a datum above it.
    let mut through = calibration(5);
    through.planes[1][3] = 0.0;
    let mut above = calibration(6);
    above.datum = [0.0, 0.0, 1.0, 200.0];
    // Refused too: three identical planes, and two swapped
    // (stripes are numbered left to right), which the host refuses as well.
    let mut same = calibration(10);
    same.planes = [same.planes[0]; 3];
    let mut swapped = calibration(11);
    swapped.planes.swap(0, 2);
    for (seq, bad) in [(1, calibration(0)), (2, through), (3, above), (8, same), (9, swapped)] {
        h.handle(cmd(seq, HostMsg::SetCalibration(bad)), 0, &cam, &mut |m| out.push(m.clone()));
        assert!(out.contains(&DeviceMsg::Error { seq: Some(seq), code: ErrorCode::InvalidConfig }), "{out:?}");
        assert!(h.calibration().is_none());
    }
    h.handle(cmd(4, HostMsg::SetCalibration(calibration(7))), 0, &cam, &mut |m| out.push(m.clone()));
    assert!(out.contains(&DeviceMsg::Ack(4)));
    out.clear();
    h.handle(cmd(5, HostMsg::GetInfo), 0, &cam, &mut |m| out.push(m.clone()));
    assert!(matches!(&out[0], DeviceMsg::Hello(i) if i.calibration_id == 7), "{out:?}");

    out.clear();
    let mut clock = 0u64;
    let mut ns = || {
        clock += 1000;
        clock
    };
    h.handle(cmd(6, start(0b111, LaserPattern::Simultaneous)), 10, &cam, &mut |m| out.push(m.clone()));
    h.poll(20, &mut cam, &mut ns, &mut |m| out.push(m.clone()));
    // Not while streaming: the lasers go off, the calibration stays.
    h.handle(cmd(7, HostMsg::SetCalibration(calibration(8))), 30, &cam, &mut |m| out.push(m.clone()));
    assert!(out.contains(&DeviceMsg::Error { seq: Some(7), code: ErrorCode::Busy }));
    assert_eq!(l.now(), 0);
    assert_eq!(h.calibration().map(|c| c.id), Some(7));

    let tri = h.triangulator().unwrap();
    let p = out.iter().find_map(|m| if let DeviceMsg::Profile(p) = m { Some(p) } else { None }).unwrap();
    let mut n = 0;
    for lp in &p.lasers {
        for pt in &lp.points {
            let m = pt.metric.expect("every point triangulated");
            let want = tri.profile(lp.laser as usize, pt.position, pt.row).unwrap();
            assert!((f64::from(m.along_um) - f64::from(want.along_mm) * 1e3).abs() <= 0.51, "{m:?} {want:?}");
            assert!((f64::from(m.height_nm) - f64::from(want.height_mm) * 1e6).abs() <= 4.0, "{m:?} {want:?}");
            n += 1;
        }
    }
    assert_eq!(n, 3 * 480);
}

/// Frames whose time passed before the head came to them are dropped, not
/// queued, and counted late (a part of the dropped frames).
#[test]
fn frames_the_head_is_late_for_are_dropped_and_counted_late() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    // 10 Hz: frames due at 0, 100, 200 … ms; the head comes at 0, 350 and 400 ms.
    for t in [0, 350_000, 400_000] {
        h.poll(t, &mut cam, &mut || 0, &mut |_| {});
    }
    assert_eq!(cam.exposures, 3);
    assert_eq!((h.late_frames(), h.status(400_000).dropped_frames), (2, 2));
}

#[test]
fn exposure_times_rate_over_the_duty_limit_is_refused() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    // 30 ms at 10 Hz is 30 %: over the 25 % limit.
    h.handle(cmd(1, HostMsg::SetExposure { exposure_us: 30_000 }), 0, &cam, &mut |_| {});
    let out = collect(|r| h.handle(cmd(2, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |m| r(m)));
    assert_eq!(out, vec![DeviceMsg::Error { seq: Some(2), code: ErrorCode::OutOfRange }]);
    assert_eq!(h.state(), HeadState::Idle);
    // 25 ms at 10 Hz is exactly the limit: accepted, and strobed 25 % of the time.
    h.handle(cmd(3, HostMsg::SetExposure { exposure_us: 25_000 }), 0, &cam, &mut |_| {});
    h.handle(cmd(4, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    assert_eq!(h.state(), HeadState::Streaming);
    let mut status = None;
    for t in (0..=2_000_000u64).step_by(10_000) {
        if t % 500_000 == 0 {
            h.handle(cmd(5, HostMsg::Heartbeat), t, &cam, &mut |_| {});
        }
        h.poll(t, &mut cam, &mut || 0, &mut |m| {
            if let DeviceMsg::Status(s) = m {
                status = Some(*s);
            }
        });
    }
    assert_eq!(cam.lit.len(), 21);
    assert_eq!(status.unwrap().laser_duty_permille, 250);
    assert_eq!(status.unwrap().dropped_frames, 0);
    // Raising the exposure while streaming past the limit is a fault: lasers off.
    let out =
        collect(|r| h.handle(cmd(6, HostMsg::SetExposure { exposure_us: 26_000 }), 2_000_000, &cam, &mut |m| r(m)));
    assert!(out.contains(&DeviceMsg::Error { seq: Some(6), code: ErrorCode::OutOfRange }));
    assert_eq!(h.state(), HeadState::Fault);
    assert_eq!(l.now(), 0);
}

proptest! {
    /// Whatever is asked, the strobes the limiter allows add up to at most
    /// duty · T + burst over every interval T (checked on all intervals
    /// between strobe starts, where the bound is tightest).
    #[test]
    fn the_duty_limit_holds_over_every_interval(
        requests in proptest::collection::vec((0u64..200_000, 1u32..60_000), 1..200),
    ) {
        let mut d = DutyLimit::default();
        let mut t = 0u64;
        let mut allowed: Vec<(u64, u64)> = Vec::new();
        for (gap, on) in requests {
            // A strobe cannot start before the previous one ended.
            t += gap + allowed.last().map_or(0, |&(s, o)| (s + o).saturating_sub(t));
            if d.request(t, on) {
                allowed.push((t, on as u64));
            }
        }
        for i in 0..allowed.len() {
            let mut on = 0;
            for j in i..allowed.len() {
                on += allowed[j].1;
                // Interval from the start of strobe i to the end of strobe j.
                let span = allowed[j].0 + allowed[j].1 - allowed[i].0;
                prop_assert!(
                    on * 1000 <= span * MAX_DUTY_PERMILLE as u64 + DUTY_BURST_US as u64 * 1000,
                    "{} us on in {} us", on, span
                );
            }
        }
    }
}

#[test]
fn heartbeat_loss_stops_the_strobes_within_one_second_in_every_mode() {
    for (pattern, mask) in [(LaserPattern::Simultaneous, 0b111), (LaserPattern::Sequential, 0b011)] {
        let (mut h, l) = head();
        let mut cam = Cam::watching(&l);
        cam.odo.set(Some(0));
        h.handle(cmd(1, HostMsg::SetTrigger(Trigger::Distance { every_um: 1000 })), 0, &cam, &mut |_| {});
        h.handle(cmd(2, start(mask, pattern)), 0, &cam, &mut |_| {});
        // The trolley moves 1 mm per 10 ms poll; the host falls silent at 0.
        let mut last_strobe = 0;
        let mut t = 0;
        while t < 3_000_000 {
            let before = cam.lit.len();
            h.poll(t, &mut cam, &mut || 0, &mut |_| {});
            if cam.lit.len() > before {
                last_strobe = t;
            }
            cam.odo.set(Some(t as i64 / 10));
            t += 10_000;
        }
        assert!(last_strobe > 0 && last_strobe <= HEARTBEAT_TIMEOUT_US, "{pattern:?}: strobe at {last_strobe} us");
        assert_eq!(l.now(), 0);
        assert_eq!(h.state(), HeadState::Fault);
    }
}

#[test]
fn the_distance_trigger_takes_a_frame_every_interval_and_counts_the_ones_it_cannot() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    // Without an encoder a distance trigger cannot start.
    h.handle(cmd(1, HostMsg::SetTrigger(Trigger::Distance { every_um: 5_000 })), 0, &cam, &mut |_| {});
    let out = collect(|r| h.handle(cmd(2, start(0b001, LaserPattern::Simultaneous)), 0, &cam, &mut |m| r(m)));
    assert_eq!(out, vec![DeviceMsg::Error { seq: Some(2), code: ErrorCode::OutOfRange }]);
    let out =
        collect(|r| h.handle(cmd(3, HostMsg::SetTrigger(Trigger::Distance { every_um: 0 })), 0, &cam, &mut |m| r(m)));
    assert_eq!(out, vec![DeviceMsg::Error { seq: Some(3), code: ErrorCode::OutOfRange }]);
    // With one: a frame at each 5 mm, carrying the odometer.
    cam.odo.set(Some(-2_000));
    h.handle(
        cmd(4, HostMsg::Start(Start { rate_hz: 50, laser_mask: 1, pattern: LaserPattern::Simultaneous })),
        0,
        &cam,
        &mut |_| {},
    );
    let mut odo = Vec::new();
    // 0.2 m/s for 0.3 s (polled every ms; 40 frames/s), then 10 m/s for
    // 0.2 s: 50 frames/s cannot keep up with one per 5 mm (2000/s), so
    // those are dropped.
    let mut p = -2_000i64;
    for ms in 0..500u64 {
        p += if ms < 300 { 200 } else { 10_000 };
        cam.odo.set(Some(p));
        if ms % 200 == 0 {
            h.handle(cmd(5, HostMsg::Heartbeat), ms * 1000, &cam, &mut |_| {});
        }
        h.poll(ms * 1000, &mut cam, &mut || 0, &mut |m| {
            if let DeviceMsg::Profile(pr) = m {
                odo.push(pr.odometer_um);
            }
        });
    }
    // The slow part: every 5 mm exactly, 12 frames in 60 mm.
    let slow: Vec<i64> = odo.iter().copied().filter(|&o| o <= 58_000).collect();
    assert_eq!(slow.len(), 12, "{slow:?}");
    assert_eq!(slow[0], 3_000);
    assert!(slow.windows(2).all(|w| w[1] - w[0] == 5_000), "{slow:?}");
    // The fast part: at most 50 frames/s, the rest counted as dropped.
    let fast = odo.len() - slow.len();
    assert!(fast <= 11, "{fast}");
    let status = h.status(500_000);
    let boundaries = (p + 2_000) / 5_000;
    assert_eq!(odo.len() as i64 + status.dropped_frames as i64, boundaries, "every boundary is a frame or a drop");
}

#[test]
fn settings_changes_ask_to_be_stored_and_restore_reports_what_it_refused() {
    let (mut h, _l) = head();
    let cam = Cam::new();
    assert_eq!(h.take_store_request(), None, "nothing changed");
    assert_eq!(h.info(&cam).store, StoreHealth::Volatile);
    h.handle(cmd(1, HostMsg::SetCalibration(calibration(7))), 0, &cam, &mut |_| {});
    h.handle(cmd(2, HostMsg::SetExposure { exposure_us: 300 }), 0, &cam, &mut |_| {});
    let s = h.take_store_request().expect("changed");
    assert_eq!(s.calibration, Some(calibration(7)));
    assert_eq!(s.exposure_us, 300);
    assert_eq!(h.take_store_request(), None, "asked once");
    // Not while streaming (a flash erase stalls the bus for a second).
    h.handle(cmd(3, start(0b001, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    h.handle(cmd(4, HostMsg::SetExposure { exposure_us: 200 }), 0, &cam, &mut |_| {});
    assert_eq!(h.take_store_request(), None);
    h.handle(cmd(5, HostMsg::Stop), 0, &cam, &mut |_| {});
    assert_eq!(h.take_store_request().map(|s| s.exposure_us), Some(200));

    // A fresh head restores it.
    let (mut h2, _) = head();
    h2.restore(&s, StoreHealth::Ok);
    assert_eq!(h2.stored(), s);
    assert_eq!(h2.info(&cam).calibration_id, 7);
    assert_eq!(h2.info(&cam).store, StoreHealth::Ok);
    assert_eq!(h2.take_store_request(), None, "restoring is not a change");
    // A stored calibration the head refuses is reported and not used.
    let (mut h3, _) = head();
    let bad = Stored { calibration: Some(calibration(0)), ..s };
    h3.restore(&bad, StoreHealth::Ok);
    assert_eq!(h3.calibration(), None);
    assert_eq!(h3.info(&cam).store, StoreHealth::Refused);
    assert_eq!(h3.stored().exposure_us, 300, "the rest is used");
}

#[test]
fn status_carries_cycles_dropped_rows_backlog_and_duty() {
    let (mut h, l) = head();
    let mut cam = Cam::watching(&l);
    h.set_cpu_hz(480_000_000);
    h.set_link_backlog(12_345);
    cam.lost_rows = 17;
    h.handle(cmd(1, start(0b111, LaserPattern::Simultaneous)), 0, &cam, &mut |_| {});
    let mut clock = 0u64;
    // 50 µs of processing per row, 480 rows per frame.
    let mut ns = || {
        clock += 480 * 50_000;
        clock
    };
    let mut statuses = Vec::new();
    for t in (0..=1_000_000u64).step_by(100_000) {
        h.poll(t, &mut cam, &mut ns, &mut |m| {
            if let DeviceMsg::Status(s) = m {
                statuses.push(*s);
            }
        });
    }
    let s = statuses.last().expect("a status after 1 s");
    assert_eq!(s.ns_per_row, 50_000);
    assert_eq!(s.cycles_per_row, 24_000, "50 us at 480 MHz");
    assert_eq!(s.dropped_rows, 17);
    assert_eq!(s.link_backlog_bytes, 12_345);
    assert_eq!(s.lasers_on, 0b111);
    // 10 exposures of 200 µs in 1 s: 2 per mille.
    assert_eq!(s.laser_duty_permille, 2);
}
