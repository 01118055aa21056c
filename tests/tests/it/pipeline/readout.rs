//! Row readouts (`SetReadout`): skipped and binned rows, triangulated
//! where they were read.

use super::*;

/// One frame's profile from a calibrated head after `SetReadout` (`None`:
/// none sent) on a camera honouring it as `sampling`, and the rows the
/// camera read for it.
fn readout_frame(readout: Option<(u16, u16, u8)>, sampling: Option<RowSampling>) -> (Profile, u32, Vec<Readout>) {
    let (mut h, l) = head();
    let mut cam = Cam { sampling, ..Cam::watching(&l) };
    let mut out = Vec::new();
    h.handle(cmd(1, HostMsg::SetCalibration(calibration(3))), 0, &cam, &mut |m| out.push(m.clone()));
    if let Some((first_row, rows, skip)) = readout {
        h.handle(cmd(2, HostMsg::SetReadout { first_row, rows, skip }), 0, &cam, &mut |m| out.push(m.clone()));
        assert!(out.contains(&DeviceMsg::Ack(2)), "{out:?}");
    }
    h.handle(cmd(3, start(0b111, LaserPattern::Simultaneous)), 10, &cam, &mut |m| out.push(m.clone()));
    h.poll(20, &mut cam, &mut || 0, &mut |m| out.push(m.clone()));
    let p = out.iter().find_map(|m| if let DeviceMsg::Profile(p) = m { Some(p.clone()) } else { None }).unwrap();
    (p, cam.rows_read, cam.readouts)
}

/// Each laser's metric point by sensor row.
fn metric_by_row(p: &Profile) -> Vec<std::collections::BTreeMap<u16, Metric>> {
    p.lasers.iter().map(|lp| lp.points.iter().map(|q| (q.row, q.metric.expect("calibrated"))).collect()).collect()
}

/// `SetReadout`: a window read one row in two gives half the window's
/// rows, numbered by their sensor rows, whether the camera reads whole
/// frames (the head passes over the others) or only those rows; their
/// metric points are the full readout's at the same rows within the
/// noise; a binning camera's are the mean of its two rows'.
#[test]
fn a_row_readout_numbers_points_by_sensor_row_and_keeps_their_metric_positions() {
    let (full, full_rows, _) = readout_frame(None, None);
    assert_eq!(full_rows, 480);
    let full = metric_by_row(&full);
    assert!(full.iter().all(|l| l.len() == 480));
    let want_rows: Vec<u16> = (40..440).step_by(2).collect();
    let close = |a: &Metric, b: &Metric, what: &str| {
        // Along the rail: the row decides (0.14 mm a row), the stripe's
        // noise moves it by well under a µm; height: σ of a few hundredths
        // of a pixel is a few µm.
        assert!((a.along_um - b.along_um).abs() <= 2, "{what}: {a:?} vs {b:?}");
        assert!((a.height_nm - b.height_nm).abs() <= 25_000, "{what}: {a:?} vs {b:?}");
    };
    for sampling in [None, Some(RowSampling::Skip)] {
        let (p, rows_read, set) = readout_frame(Some((40, 400, 2)), sampling);
        let want = Readout::new(40, 400, RowSkip::X2, 480).unwrap();
        assert_eq!(set, vec![want], "set once, before the exposure");
        assert_eq!(rows_read, if sampling.is_none() { 439 } else { 200 }, "{sampling:?}");
        for (k, l) in metric_by_row(&p).iter().enumerate() {
            assert_eq!(l.keys().copied().collect::<Vec<_>>(), want_rows, "laser {k}, {sampling:?}");
            for (r, m) in l {
                close(m, &full[k][r], &format!("laser {k} row {r} {sampling:?}"));
            }
        }
    }
    // Binned: rows 40 + 2i again, each point where the mean of rows r and
    // r + 1 is.
    let (p, rows_read, _) = readout_frame(Some((40, 400, 2)), Some(RowSampling::Bin));
    assert_eq!(rows_read, 200);
    for (k, l) in metric_by_row(&p).iter().enumerate() {
        assert_eq!(l.keys().copied().collect::<Vec<_>>(), want_rows, "laser {k} binned");
        for (r, m) in l {
            let (a, b) = (&full[k][r], &full[k][&(r + 1)]);
            let mid = Metric { along_um: (a.along_um + b.along_um) / 2, height_nm: (a.height_nm + b.height_nm) / 2 };
            close(m, &mid, &format!("laser {k} row {r} binned"));
            assert!(m.along_um != a.along_um, "triangulated at the centre, not at row {r}");
        }
    }
    // One row in four over the whole sensor.
    let (p, rows_read, _) = readout_frame(Some((0, 480, 4)), Some(RowSampling::Skip));
    assert_eq!(rows_read, 120);
    assert!(p.lasers.iter().all(|l| l.points.iter().map(|q| q.row).eq((0..480).step_by(4))));
}

/// `SetReadout` refuses, lasers off, what does not fit the sensor or is
/// not a skip of 1, 2 or 4, and anything while streaming; a capture reads
/// every row whatever the readout, and the next frame has the readout back.
#[test]
fn a_bad_readout_is_refused_and_captures_read_every_row() {
    let (mut h, l) = head();
    let mut cam = Cam { sampling: Some(RowSampling::Skip), ..Cam::watching(&l) };
    for (seq, (first_row, rows, skip)) in
        [(1, (0, 480, 3)), (2, (0, 0, 1)), (3, (0, 6, 4)), (4, (400, 96, 1)), (5, (u16::MAX, 2, 2)), (6, (0, 480, 0))]
    {
        let out =
            collect(|r| h.handle(cmd(seq, HostMsg::SetReadout { first_row, rows, skip }), 0, &cam, &mut |m| r(m)));
        assert_eq!(out, vec![DeviceMsg::Error { seq: Some(seq), code: ErrorCode::OutOfRange }]);
        assert_eq!(l.now(), 0);
    }
    let out = collect(|r| {
        h.handle(cmd(7, HostMsg::SetReadout { first_row: 100, rows: 200, skip: 4 }), 0, &cam, &mut |m| r(m))
    });
    assert_eq!(out, vec![DeviceMsg::Ack(7)]);
    assert_eq!(h.streaming_readout(), None, "from the next Start on");
    h.handle(cmd(8, start(0b001, LaserPattern::Simultaneous)), 10, &cam, &mut |_| {});
    let want = Readout::new(100, 200, RowSkip::X4, 480).unwrap();
    assert_eq!(h.streaming_readout(), Some(want));
    let busy = collect(|r| {
        h.handle(cmd(9, HostMsg::SetReadout { first_row: 0, rows: 480, skip: 1 }), 20, &cam, &mut |m| r(m))
    });
    assert!(busy.contains(&DeviceMsg::Error { seq: Some(9), code: ErrorCode::Busy }), "{busy:?}");
    assert_eq!(l.now(), 0);
    // A fault stopped it; a capture now reads all 480 rows.
    let out = collect(|r| {
        h.handle(cmd(10, HostMsg::CaptureImage(0b001)), 30, &cam, &mut |m| r(m));
        h.poll(30, &mut cam, &mut || 0, &mut |m| r(m));
    });
    let rows: std::collections::BTreeSet<u16> =
        out.iter().filter_map(|m| if let DeviceMsg::RawRows(r) = m { Some(r.first_row) } else { None }).collect();
    assert_eq!(rows.len(), 480);
    assert_eq!(cam.readouts, vec![Readout::full(480)], "no frame yet: the capture's readout only");
    h.handle(cmd(11, start(0b001, LaserPattern::Simultaneous)), 40, &cam, &mut |_| {});
    let out = collect(|r| h.poll(40, &mut cam, &mut || 0, &mut |m| r(m)));
    let p = out.iter().find_map(|m| if let DeviceMsg::Profile(p) = m { Some(p.clone()) } else { None }).unwrap();
    assert_eq!(cam.readouts, vec![Readout::full(480), want]);
    assert!(p.lasers[0].points.iter().map(|q| q.row).eq((100..300).step_by(4)), "{p:?}");
}
