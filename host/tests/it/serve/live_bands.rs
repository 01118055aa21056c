//! The live EN 13231-3 band figures of `listen sim --serve` on its default
//! rail (30 µm at 50 mm, 20 µm at 200 mm, 2 µm of roughness), against
//! `analyze` of the same run's recording.

use cms_host::analyze::live::bands::{BandsReport, LiveBands};
use serde_json::Value;

use super::*;

/// analyze's state of a line's band, as the live figures name it.
fn analyze_state(band: &Value) -> &'static str {
    match (band["judged"].as_bool(), band["not_judged"].is_null(), band["passes"].as_bool()) {
        (_, false, _) => "not judged",
        (Some(true), true, Some(true)) => "within",
        (Some(true), true, Some(false)) => "over",
        _ => "not evaluated",
    }
}

/// The live figures of the recording's frames fed in order, as the
/// listener fed them.
fn replayed(rec: &Path) -> BandsReport {
    let mut live = LiveBands::default();
    cms_host::analyze::read_recording(rec, &cms_host::progress::Silent, |_, f| {
        live.add(&f);
        Ok(())
    })
    .unwrap();
    live.report().cloned().expect("calibrated frames")
}

/// On the default rail no band is red on noise or on the model: each
/// line's figures since the start are `analyze`'s within their stated
/// uncertainty, with its state (over the limit in 30–100 and 100–300 mm,
/// where the rail is: 60 and 40 µm peak-to-peak); the socket's last update
/// and the status line carry them; the one-sine fit is a diagnostic.
#[test]
fn live_bands_agree_with_analyze() {
    let dir = tempfile::tempdir().unwrap();
    let listen = Listen::start(dir.path(), &["--duration", "10"]);
    let page = feed::reader(&listen.host);
    let rec = listen.rec.clone();
    let (status, stderr) = listen.wait();
    assert!(status.success(), "{stderr}");
    let (updates, last) = page.join().unwrap();
    assert!(updates > 10, "{updates} updates");

    let out = crate::common::cms_host(&["analyze", rec.to_str().unwrap(), "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let a: Value = serde_json::from_slice(&out.stdout).unwrap();
    let live = replayed(&rec);
    let mut compared = 0;
    for la in a["lasers"].as_array().unwrap() {
        let k = la["laser"].as_u64().unwrap() as usize;
        let line = live.lines.iter().find(|l| l.laser == Some(k)).expect("every laser live");
        for (b, want) in la["en13231"]["bands"].as_array().unwrap().iter().enumerate().take(3) {
            let got = &line.bands[b];
            let state = analyze_state(want);
            assert_eq!(got.state, state, "laser {k} band {b}: {got:?} vs {want}");
            let Some(f) = got.since else { continue };
            let pp = want["average_mean_pp_mm"].as_f64().unwrap() * 1000.0;
            let rms = want["rms_mm"].as_f64().unwrap() * 1000.0;
            eprintln!(
                "laser {k} band {}: mean p-p {:.2} ± {:.2} µm (analyze {pp:.2}), RMS {:.2} ± {:.2} µm (analyze {rms:.2})",
                got.band, f.mean_pp_um, f.mean_pp_u_um, f.rms_um, f.rms_u_um
            );
            assert!((f.mean_pp_um - pp).abs() <= f.mean_pp_u_um, "laser {k} band {b}: {f:?} vs {pp}");
            assert!((f.rms_um - rms).abs() <= f.rms_u_um, "laser {k} band {b}: {f:?} vs {rms}");
            compared += 1;
        }
    }
    assert!(compared >= 6, "{compared} figures compared: {live:?}");
    // The rail is over the limit where analyze says it is, never "failed".
    let over: Vec<&str> = live.lines[0].bands.iter().filter(|b| b.state == "over").map(|b| b.band.as_str()).collect();
    assert_eq!(over, ["30–100 mm", "100–300 mm"], "{live:?}");

    // What the page got: the same lines and states, figures near the end's.
    let bands = &last["bands"];
    assert_eq!(bands["edition"], "EN 13231-3:2006", "{bands}");
    let lines = bands["lines"].as_array().expect("the page's bands");
    assert_eq!(lines.len(), live.lines.len(), "{bands}");
    for (l, r) in lines.iter().zip(&live.lines) {
        for (b, rb) in l["bands"].as_array().unwrap().iter().zip(&r.bands) {
            let s = b["state"].as_str().unwrap();
            assert!(["within", "over", "not judged", "not evaluated"].contains(&s), "{b}");
            if rb.since.is_some() && s != "not evaluated" {
                assert_eq!(s, rb.state, "{b}");
            }
        }
    }
    // The ISO 3095 verdicts: judged once 5 m have no gap, else what they need.
    let iso = &last["iso3095"];
    match iso["state"].as_str() {
        Some("evaluated") => {
            let avg =
                iso["lines"].as_array().unwrap().iter().find(|l| l["laser"].is_null()).expect("the energy average");
            let b50 = avg["bands"].as_array().unwrap().iter().find(|b| b["wavelength_mm"] == 50.0).unwrap();
            assert_eq!(b50["verdict"], "EXCEEDS", "{iso}");
        }
        Some("not evaluated yet") => {
            assert!(iso["why"].as_str().unwrap().starts_with("not evaluated yet: it needs 5000 mm"), "{iso}")
        }
        _ => panic!("{iso}"),
    }
    for c in last["corrugation"].as_array().unwrap() {
        assert!(c["verdict"].is_string(), "the sine's diagnostic: {c}");
    }
    let status_line = stderr.lines().rev().find(|l| l.contains("bands 2006 since")).expect("bands in the status line");
    assert!(status_line.contains("30–100 L0") && status_line.contains("over"), "{status_line}");
}
