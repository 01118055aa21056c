//! Search windows and tracking set by the host.

use super::*;

/// `SetWindows`: with windows for lasers 0 and 1 only around their lines and
/// laser 2's window put where its line is not, a streaming head reports
/// lasers 0 and 1 as without windows and nothing for laser 2; a window past
/// the row or too narrow is refused (lasers off), as is the command while
/// streaming; a lit laser without a window makes the frame a full-row search.
#[test]
fn search_windows_set_by_the_host_restrict_what_the_head_reports() {
    let w = |first_px, width_px| Some(ColumnWindow { first_px, width_px });
    let run = |windows: Option<[Option<ColumnWindow>; 3]>| {
        let (mut h, l) = head();
        let mut cam = Cam::watching(&l);
        let mut out = Vec::new();
        if let Some(ws) = windows {
            h.handle(cmd(1, HostMsg::SetWindows(ws)), 0, &cam, &mut |m| out.push(m.clone()));
            assert!(out.contains(&DeviceMsg::Ack(1)), "{out:?}");
        }
        h.handle(cmd(2, start(0b111, LaserPattern::Simultaneous)), 10, &cam, &mut |m| out.push(m.clone()));
        let mut refused = Vec::new();
        h.handle(cmd(3, HostMsg::SetWindows([None; 3])), 15, &cam, &mut |m| refused.push(m.clone()));
        assert!(refused.contains(&DeviceMsg::Error { seq: Some(3), code: ErrorCode::Busy }), "{refused:?}");
        out.clear();
        h.handle(cmd(4, start(0b111, LaserPattern::Simultaneous)), 16, &cam, &mut |m| out.push(m.clone()));
        h.poll(20, &mut cam, &mut || 0, &mut |m| out.push(m.clone()));
        let p = out.iter().find_map(|m| if let DeviceMsg::Profile(p) = m { Some(p.clone()) } else { None }).unwrap();
        p.lasers.iter().map(|lp| lp.points.len()).collect::<Vec<_>>()
    };
    // Lines at 200, 380, 560 (±2 px).
    assert_eq!(run(None), vec![480, 480, 480]);
    assert_eq!(run(Some([w(152, 96), w(332, 96), w(640, 96)])), vec![480, 480, 0]);
    assert_eq!(run(Some([w(152, 96), w(332, 96), None])), vec![480, 480, 480], "laser 2 without a window: full rows");
    let (mut h, l) = head();
    let cam = Cam::watching(&l);
    for (seq, bad) in [(5, [w(700, 96), None, None]), (6, [w(100, 4), None, None])] {
        let mut out = Vec::new();
        h.handle(cmd(seq, HostMsg::SetWindows(bad)), 0, &cam, &mut |m| out.push(m.clone()));
        assert!(out.contains(&DeviceMsg::Error { seq: Some(seq), code: ErrorCode::OutOfRange }), "{out:?}");
        assert_eq!(l.now(), 0);
    }
}

/// `SetTracking`: a head whose windows follow their lines reports, frame
/// after frame, exactly what it reports without (the lines stand still
/// within a frame, so each row's candidate is the pixel the screen would
/// have led to); 0 turns it off; a half width the detector does not take
/// is refused (lasers off), as is the command while streaming.
#[test]
fn tracked_windows_set_by_the_host_report_what_the_windows_report() {
    let w = |first_px, width_px| Some(ColumnWindow { first_px, width_px });
    let frames = |track: Option<u16>| {
        let (mut h, l) = head();
        let mut cam = Cam::watching(&l);
        let mut out = Vec::new();
        h.handle(cmd(1, HostMsg::SetWindows([w(152, 96), w(332, 96), w(512, 96)])), 0, &cam, &mut |m| {
            out.push(m.clone())
        });
        if let Some(px) = track {
            h.handle(cmd(2, HostMsg::SetTracking { half_width_px: px }), 0, &cam, &mut |m| out.push(m.clone()));
            assert!(out.contains(&DeviceMsg::Ack(2)), "{out:?}");
        }
        h.handle(cmd(3, start(0b111, LaserPattern::Simultaneous)), 10, &cam, &mut |m| out.push(m.clone()));
        let mut refused = Vec::new();
        h.handle(cmd(4, HostMsg::SetTracking { half_width_px: 8 }), 15, &cam, &mut |m| refused.push(m.clone()));
        assert!(refused.contains(&DeviceMsg::Error { seq: Some(4), code: ErrorCode::Busy }), "{refused:?}");
        out.clear();
        h.handle(cmd(5, start(0b111, LaserPattern::Simultaneous)), 16, &cam, &mut |m| out.push(m.clone()));
        // Three frames at 10 Hz.
        for t in [20, 100_020, 200_020] {
            h.poll(t, &mut cam, &mut || 0, &mut |m| out.push(m.clone()));
        }
        let profiles: Vec<Profile> =
            out.iter().filter_map(|m| if let DeviceMsg::Profile(p) = m { Some(p.clone()) } else { None }).collect();
        assert!(profiles.len() >= 2, "{} profiles", profiles.len());
        profiles.iter().map(|p| p.lasers.clone()).collect::<Vec<_>>()
    };
    let plain = frames(None);
    assert!(plain[0].iter().all(|lp| lp.points.len() == 480), "every row of every line");
    assert_eq!(frames(Some(8)), plain, "tracked ±8 px");
    assert_eq!(frames(Some(64)), plain, "tracked ±64 px");
    assert_eq!(frames(Some(0)), plain, "off");
    let (mut h, l) = head();
    let cam = Cam::watching(&l);
    for (seq, bad) in [(5, 1), (6, 65), (7, u16::MAX)] {
        let mut out = Vec::new();
        h.handle(cmd(seq, HostMsg::SetTracking { half_width_px: bad }), 0, &cam, &mut |m| out.push(m.clone()));
        assert!(out.contains(&DeviceMsg::Error { seq: Some(seq), code: ErrorCode::OutOfRange }), "{bad}: {out:?}");
        assert_eq!(l.now(), 0);
    }
}
