//! GNSS positions end to end: `listen sim --gnss sim --record` with the
//! simulated receiver on its own pty, the fixes in the recording, `info`,
//! `export --format geojson`, and `locate` checking them against the
//! odometer and the survey on a track register — agreeing where the run
//! is what it says, disagreeing (or failing) where it is not.

use std::path::{Path, PathBuf};

use crate::common::{one_line_error, one_line_failure, run};

const REGISTER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/track-register.csv");

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Records `frames` frames at 1 m/s with the simulated receiver, with a
/// survey saying where the run starts.
fn record(dir: &Path, name: &str, frames: &str, start: &str, heading: &str) -> PathBuf {
    let survey = dir.join(format!("{name}.toml"));
    std::fs::write(
        &survey,
        format!("line = \"A\"\ntrack = \"1\"\nstart_chainage = \"{start}\"\nchainage = \"{heading}\"\n"),
    )
    .unwrap();
    let rec = dir.join(format!("{name}.cmsrec"));
    let o = run(&[
        "listen",
        "sim",
        "--sim-light=incoherent",
        "--gnss",
        "sim",
        "--frames",
        frames,
        "--sim-speed-mm-s",
        "1000",
        "--record",
        s(&rec),
        "--survey",
        s(&survey),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("listen: gnss /dev/pts/"), "{err}");
    rec
}

fn locate(rec: &Path, register: &Path) -> String {
    let o = run(&["locate", s(rec), "--register", s(register)]);
    assert!(o.status.success(), "{o:?}");
    String::from_utf8(o.stdout).unwrap()
}

/// The example register with every vertex rewritten by `f(lat, lon, chainage)`.
fn register_like(dir: &Path, name: &str, f: impl Fn(f64, f64, f64) -> Vec<(f64, f64, f64)>) -> PathBuf {
    let text = std::fs::read_to_string(REGISTER).unwrap();
    let mut out = String::from("lat_deg,lon_deg,chainage_m\n");
    for line in text.lines().filter(|l| !l.starts_with('#') && !l.starts_with("lat_deg")) {
        let v: Vec<f64> = line.split(',').map(|x| x.parse().unwrap()).collect();
        for (la, lo, c) in f(v[0], v[1], v[2]) {
            out += &format!("{la:.9},{lo:.9},{c:.3}\n");
        }
    }
    let p = dir.join(name);
    std::fs::write(&p, out).unwrap();
    p
}

#[test]
fn a_run_with_gnss_is_placed_on_its_register_and_a_wrong_one_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    // About 4 s at 1 m/s: 41+100 to 41+104 on the first straight (longer
    // on a loaded machine: the simulated head keeps real time as it can).
    let rec = record(dir.path(), "run", "120", "41+100", "up");

    let info = String::from_utf8(run(&["info", s(&rec)]).stdout).unwrap();
    assert!(info.contains("format: 6"), "{info}");
    let line = info.lines().find(|l| l.starts_with("gnss: ")).unwrap_or_else(|| panic!("{info}"));
    let fixes: u64 = line["gnss: ".len()..].split(' ').next().unwrap().parse().unwrap();
    let placed: u64 = line.split("), ").nth(1).unwrap().split(' ').next().unwrap().parse().unwrap();
    assert!(line.contains("RTK fixed") && placed <= fixes, "{line}");

    // The fixes as GeoJSON: the receiver's own times, and where each was placed.
    let o = run(&["export", s(&rec), "--format", "geojson"]);
    assert!(o.status.success(), "{o:?}");
    let doc: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let features = doc["features"].as_array().unwrap();
    assert_eq!(features[0]["geometry"]["type"], "LineString");
    assert_eq!(features.len() as u64, fixes + 1);
    let props: Vec<&serde_json::Value> = features[1..].iter().map(|f| &f["properties"]).collect();

    // 10 Hz on the receiver's clock, however long the run took: as many
    // fixes as tenths of a second between its first and last UTC, plus
    // one. Epochs late under load are sent at once when due (none added);
    // a pty the listener left full for seconds may lose some (10 % allowed).
    // UTC is written to 10 ms: ±0.2 epochs over the span.
    let utc_ms = |p: &serde_json::Value| {
        let ymd: Vec<u32> = p["date"].as_str().unwrap().split('-').map(|x| x.parse().unwrap()).collect();
        let day = chrono::NaiveDate::from_ymd_opt(ymd[0] as i32, ymd[1], ymd[2]).unwrap();
        day.signed_duration_since(chrono::NaiveDate::default()).num_milliseconds()
            + p["utc_ms_of_day"].as_i64().unwrap()
    };
    let span_s = (utc_ms(props[props.len() - 1]) - utc_ms(props[0])) as f64 / 1e3;
    let epochs = 10.0 * span_s;
    let intervals = (fixes - 1) as f64;
    assert!(span_s >= 3.0, "{span_s} s for {fixes} fixes: the run is 4 s at least");
    assert!(intervals <= epochs + 1.0 && intervals >= 0.9 * epochs - 1.0, "{fixes} fixes over {span_s} s of UTC");

    // Every fix after the first profile is placed among the frames: the
    // ones that are not (the receiver may speak before the head's first
    // frame arrives) come first.
    let unplaced = props.iter().take_while(|p| p["head_us"].is_null()).count() as u64;
    assert!(props[unplaced as usize..].iter().all(|p| p["head_us"].is_u64()), "{line}");
    assert_eq!(placed, fixes - unplaced, "{line}");

    // The odometer and GNSS agree, and the survey with both.
    let out = locate(&rec, Path::new(REGISTER));
    assert!(out.contains("verdict: agrees"), "{out}");
    assert!(out.contains("survey: start_chainage 41+100.000") && !out.contains("DISAGREES"), "{out}");
    let zero = out.split("chainage at odometer 0: ").nth(1).unwrap();
    let at: f64 = zero[3..10].parse().unwrap();
    assert!((at - 100.0).abs() < 0.05, "{out}");

    // A register with a 1 m chainage jump at 41+102: the fixes past it
    // disagree with the odometer.
    let jump = register_like(dir.path(), "jump.csv", |la, lo, c| match c {
        c if c < 41_100.5 => vec![(la, lo, c)],
        c if (41_199.5..41_200.5).contains(&c) => {
            // The segment from 41+100 to 41+200 split at 41+102 with the jump.
            let text = std::fs::read_to_string(REGISTER).unwrap();
            let prev: Vec<f64> = text
                .lines()
                .find(|l| l.ends_with(",41100.000"))
                .unwrap()
                .split(',')
                .map(|x| x.parse().unwrap())
                .collect();
            let at = |t: f64| (prev[0] + (la - prev[0]) * t, prev[1] + (lo - prev[1]) * t);
            let (a, b) = (at(0.02), at(0.0205));
            vec![(a.0, a.1, 41_102.0), (b.0, b.1, 41_103.05), (la, lo, c + 1.0)]
        }
        c => vec![(la, lo, c + 1.0)],
    });
    let out = locate(&rec, &jump);
    assert!(out.contains("verdict: DISAGREES"), "{out}");

    // Another track, 50 m to the north: no fix is on it.
    let other = register_like(dir.path(), "other.csv", |la, lo, c| vec![(la + 50.0 / 111_250.0, lo, c)]);
    let out = locate(&rec, &other);
    assert!(out.contains("verdict: failed") && out.contains("off the centreline"), "{out}");

    // The run's track as GeoJSON, on the register's line.
    let p = &features[1]["geometry"]["coordinates"];
    let (lon, lat) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
    // 41+100 is about (52.09115 N, 5.12266 E).
    assert!((lat - 52.091_15).abs() < 1e-4 && (lon - 5.122_66).abs() < 1e-4, "{p}");
    assert_eq!(features[1]["properties"]["quality"], "RTK fixed");

    // The analysis's report plots the track and counts its fixes.
    let report = dir.path().join("report");
    let o = run(&["analyze", s(&rec), "--report", s(&report)]);
    assert!(o.status.success(), "{o:?}");
    let html = std::fs::read_to_string(report.join("report.html")).unwrap();
    let at = html.find("<section id=\"track\">").unwrap();
    let track = &html[at..at + html[at..].find("</section>").unwrap()];
    assert!(track.contains("<figure class=\"plot\"><svg"), "{track}");
    assert!(track.contains(&format!("<td class=\"num\">{fixes}</td><td>{fixes} RTK fixed</td>")), "{track}");
    assert!(report.join("track.png").exists());

    // fixes.parquet (another reader than the writer): every fix, placed on
    // the chainage the run was given (41+100, up) from its odometer.
    use crate::analyze::parquet::{fixes_schema, pq};
    let fx = pq::read(&report.join("fixes.parquet"));
    assert_eq!(fx.schema(), fixes_schema());
    assert_eq!(fx.rows as u64, fixes);
    let (odo, ch, lat) = (fx.f64("odometer_mm"), fx.f64("chainage_mm"), fx.f64("lat_deg"));
    let mut placed_rows = 0;
    for i in 0..fx.rows {
        assert!((lat[i].unwrap() - 52.091).abs() < 0.01, "row {i}");
        assert_eq!(odo[i].is_some(), ch[i].is_some(), "row {i}");
        if let (Some(o), Some(c)) = (odo[i], ch[i]) {
            assert!((c - (41_100_000.0 + o)).abs() < 1e-6, "row {i}: {c} at odometer {o}");
            placed_rows += 1;
        }
    }
    assert_eq!(placed_rows as u64, placed);
    assert!(fx.str("quality").iter().all(|q| q.as_deref() == Some("RTK fixed")));
}

#[test]
fn a_survey_that_gnss_contradicts_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    // The user typed 41+000 and down; the run starts at 41+100 going up.
    let rec = record(dir.path(), "typo", "60", "41+000", "down");
    let out = locate(&rec, Path::new(REGISTER));
    assert!(out.contains("verdict: agrees"), "{out}");
    let off = out
        .split("survey: start_chainage 41+000.000 — GNSS places odometer 0 ")
        .nth(1)
        .unwrap_or_else(|| panic!("{out}"));
    let d: f64 = off.split(' ').next().unwrap().parse().unwrap();
    assert!((d - 100.0).abs() < 0.05, "{out}");
    assert!(off.contains("m from it: DISAGREES (tolerance"), "{out}");
    assert!(out.contains("survey: chainage down — GNSS says rising: DISAGREES"), "{out}");
}

#[test]
fn gnss_misuse_is_refused_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    // The simulated receiver rides with the simulated head only.
    let e = one_line_error(&run(&["listen", "/dev/null", "--gnss", "sim", "--frames", "1"]));
    assert!(e.contains("PORT `sim`"), "{e}");
    // A receiver's port that does not exist: the device's failure.
    let e = one_line_failure(&run(&["listen", "sim", "--gnss", "/nonexistent/gnss", "--frames", "1"]), 3);
    assert!(e.contains("/nonexistent/gnss"), "{e}");
    // A recording without fixes, and a register with a bad line.
    let rec = dir.path().join("plain.cmsrec");
    assert!(run(&["listen", "sim", "--frames", "2", "--record", s(&rec)]).status.success());
    let e = one_line_error(&run(&["locate", s(&rec), "--register", REGISTER]));
    assert!(e.contains("no GNSS fixes"), "{e}");
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "lat_deg,lon_deg,chainage_m\n52,5,100\n52.001,x,200\n").unwrap();
    let e = one_line_error(&run(&["locate", s(&rec), "--register", s(&bad)]));
    assert!(e.contains("bad.csv:3") && e.contains("lon_deg"), "{e}");
    // --csv over an input is refused.
    let e = one_line_error(&run(&["locate", s(&rec), "--register", REGISTER, "--csv", s(&rec)]));
    assert!(e.contains("is an input"), "{e}");

    // A recording of format 3 (before fixes) is not appended fixes to.
    let mut bytes = std::fs::read(&rec).unwrap();
    let survey_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    bytes[8] = 3;
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&bytes[..16 + survey_len]);
    bytes[16 + survey_len..20 + survey_len].copy_from_slice(&crc.to_le_bytes());
    let v3 = dir.path().join("v3.cmsrec");
    std::fs::write(&v3, &bytes).unwrap();
    let e = one_line_error(&run(&["listen", "sim", "--gnss", "sim", "--frames", "2", "--record", s(&v3)]));
    assert!(e.contains("format 3 holds no GNSS fixes"), "{e}");
    assert_eq!(std::fs::read(&v3).unwrap(), bytes, "the old recording is left as it was");
}

const REGISTER_40KM: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/track-register-40km.csv");

/// `bench recording --gnss` at the scale of a survey: 5 km of frames 0.3 m
/// apart (9 m/s at 30 Hz) with the simulated receiver's 5 556 fixes on
/// the 40 km register, placed by `locate` where the survey says, and
/// plotted by the report; 3 km the other way from a survey saying `down`.
#[test]
fn a_synthetic_survey_of_kilometres_with_gnss_is_placed_on_its_register() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("up.cmsrec");
    let o = run(&[
        "bench",
        "recording",
        "--frames",
        "16667",
        "--step-mm",
        "300",
        "--points",
        "16",
        "--seed",
        "3",
        "--start-chainage",
        "12+000",
        "--date",
        "2026-06-01",
        "--gnss",
        REGISTER_40KM,
        "--out",
        s(&rec),
    ]);
    assert!(o.status.success(), "{o:?}");
    // 555.5 s of the head's clock from the first frame to the last, 10 Hz.
    assert!(String::from_utf8_lossy(&o.stdout).contains(", 5556 GNSS fixes, 5000.1 m of rail"), "{o:?}");
    let info = String::from_utf8(run(&["info", s(&rec)]).stdout).unwrap();
    assert!(info.contains("gnss: 5556 fixes (5556 RTK fixed), 5556 placed among the frames"), "{info}");

    let out = locate(&rec, Path::new(REGISTER_40KM));
    assert!(out.contains("5556 fixes on the track, 0 not used"), "{out}");
    assert!(out.contains("verdict: agrees") && !out.contains("DISAGREES"), "{out}");
    assert!(out.contains("survey: start_chainage 12+000.000 — GNSS places odometer 0 "), "{out}");
    let zero = out.split("chainage at odometer 0: 12+").nth(1).unwrap_or_else(|| panic!("{out}"));
    let at: f64 = zero[..7].parse().unwrap();
    // 5 556 fixes of 10 mm each way: the offset to a fraction of a millimetre.
    assert!(at.abs() < 0.005, "{out}");
    assert!(zero.contains("(rising with the odometer"), "{out}");

    // The report plots the track and its table has the run: every fix
    // placed, the run's 555.5 s and its chainage from its odometer.
    let report = dir.path().join("report");
    let o = run(&["analyze", s(&rec), "--report", s(&report)]);
    assert!(o.status.success(), "{o:?}");
    let svg = std::fs::read_to_string(report.join("track.svg")).unwrap();
    assert!(svg.contains("GNSS track"), "{svg}");
    let html = std::fs::read_to_string(report.join("report.html")).unwrap();
    let at = html.find("<section id=\"track\">").unwrap();
    let track = &html[at..at + html[at..].find("</section>").unwrap()];
    let row = "<td class=\"num\">1</td><td class=\"num\">5556</td><td>5556 RTK fixed</td><td class=\"num\">5556</td>\
               <td>2026-06-01 08:00:00.0</td><td>2026-06-01 08:09:15.5</td><td class=\"num\">555.5</td>";
    assert!(track.contains(row), "{track}");
    assert!(track.contains("<td>12+000.100 to 16+999.600</td>"), "{track}");

    // Down from 30+000: chainage falls with the odometer.
    let survey = dir.path().join("down.toml");
    std::fs::write(&survey, "start_chainage = \"30+000\"\nchainage = \"down\"\n").unwrap();
    let down = dir.path().join("down.cmsrec");
    let o = run(&[
        "bench",
        "recording",
        "--frames",
        "10000",
        "--step-mm",
        "300",
        "--points",
        "16",
        "--survey",
        s(&survey),
        "--gnss",
        REGISTER_40KM,
        "--out",
        s(&down),
    ]);
    assert!(o.status.success(), "{o:?}");
    let out = locate(&down, Path::new(REGISTER_40KM));
    assert!(out.contains("verdict: agrees") && !out.contains("DISAGREES"), "{out}");
    assert!(out.contains("chainage at odometer 0: 30+000.00") && out.contains("(falling with the odometer"), "{out}");
}

#[test]
fn bench_recording_gnss_misuse_is_refused_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.cmsrec");
    let bench = |extra: &[&str]| {
        let mut args = vec!["bench", "recording", "--frames", "100", "--points", "4", "--out", s(&out)];
        args.extend_from_slice(extra);
        one_line_error(&run(&args))
    };
    // No start chainage: nowhere on the register to start.
    let e = bench(&["--gnss", REGISTER_40KM]);
    assert!(e.contains("--gnss needs the run's start chainage"), "{e}");
    // A run that leaves the register: 100 frames of 1 m from 49+950.
    let e = bench(&["--gnss", REGISTER_40KM, "--start-chainage", "49+950", "--step-mm", "1000"]);
    assert!(e.contains("the run covers 49+950.100 to 50+049.100") && e.contains("10+000.000 to 50+000.000"), "{e}");
    // A register that is not one, and one that does not exist.
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "lat_deg,lon_deg,chainage_m\n52,5,100\n52.001,5,90\n").unwrap();
    let e = bench(&["--gnss", s(&bad), "--start-chainage", "0+095"]);
    assert!(e.contains("bad.csv") && e.contains("must increase"), "{e}");
    let e = bench(&["--gnss", "/nonexistent/reg.csv", "--start-chainage", "0+095"]);
    assert!(e.contains("/nonexistent/reg.csv"), "{e}");
    assert!(!out.exists(), "nothing written");
}

/// `analyze --track-register`: a run with fixes and no typed start is
/// placed by them, within their tolerance of where it was; a typed start
/// 100 m off is disputed, named, and GNSS places the run; one that agrees
/// is said to.
#[test]
fn analyze_places_a_run_by_its_fixes_and_checks_its_typed_start() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("run.cmsrec");
    let o = run(&[
        "bench",
        "recording",
        "--frames",
        "900",
        "--step-mm",
        "33",
        "--points",
        "16",
        "--seed",
        "5",
        "--start-chainage",
        "41+100",
        "--gnss",
        REGISTER,
        "--out",
        s(&rec),
    ]);
    assert!(o.status.success(), "{o:?}");
    let analyze = |extra: &[&str]| {
        let mut args = vec!["analyze", s(&rec), "--track-register", REGISTER];
        args.extend_from_slice(extra);
        let o = run(&args);
        assert!(o.status.success(), "{o:?}");
        String::from_utf8(o.stdout).unwrap()
    };
    // No typed start (`--chainage auto` sets the survey's aside).
    let json: serde_json::Value = serde_json::from_str(&analyze(&["--chainage", "auto", "--json"])).unwrap();
    let p = &json["gnss_placing"][0];
    assert_eq!((p["placed_by"].as_str(), p["typed_start_m"].as_f64()), (Some("gnss"), None), "{p}");
    let (start, tol) = (p["gnss"]["start_m"].as_f64().unwrap(), p["gnss"]["tolerance_m"].as_f64().unwrap());
    assert!((start - 41_100.0).abs() <= tol && tol < 0.2, "{p}");
    assert_eq!(p["gnss"]["heading"].as_str(), Some("up"), "{p}");
    let used = json["run_joins"][0]["start_m"].as_f64().unwrap();
    assert!((used - start).abs() < 1e-6, "{json}");

    // A typed start 100 m off: disputed, GNSS places the run.
    let out = analyze(&["--chainage", "41+200"]);
    let line = out.lines().find(|l| l.starts_with("run 1: placed by")).unwrap_or_else(|| panic!("{out}"));
    assert!(line.contains("placed by GNSS — GNSS puts position 0 at 41+100.0"), "{line}");
    assert!(line.contains("typed start 41+200.000 is +100.0") && line.contains("START DISPUTED"), "{line}");
    assert!(out.contains("run 1: position 0 at chainage 41+100.0"), "{out}");
    // The survey's own start (41+100) agrees.
    let out = analyze(&[]);
    assert!(out.contains("typed start 41+100.000 is ") && out.contains(": agrees (combined tolerance 25.0"), "{out}");
    assert!(!out.contains("DISPUTED"), "{out}");
}

/// `trend --track-register`: two surveys of one rail a year apart, each
/// typed 100 m off where their fixes put them, are both placed by GNSS
/// (disputed, named under each survey) and followed at the fixes' chainage.
#[test]
fn trend_places_each_survey_by_its_fixes() {
    let dir = tempfile::tempdir().unwrap();
    let mut recs = Vec::new();
    for (seed, date) in [("5", "2025-03-01"), ("6", "2026-03-01")] {
        let rec = dir.path().join(format!("{date}.cmsrec"));
        let o = run(&[
            "bench",
            "recording",
            "--frames",
            "900",
            "--points",
            "120",
            "--seed",
            seed,
            "--start-chainage",
            "41+100",
            "--date",
            date,
            "--gnss",
            REGISTER,
            "--out",
            s(&rec),
        ]);
        assert!(o.status.success(), "{o:?}");
        recs.push(rec);
    }
    let trend = |extra: &[&str]| {
        let mut args = vec!["trend", s(&recs[0]), s(&recs[1]), "--block-m", "5", "--chainage", "41+200"];
        args.extend_from_slice(&["--chainage", "41+200"]);
        args.extend_from_slice(extra);
        let o = run(&args);
        assert!(o.status.success(), "{o:?}");
        String::from_utf8(o.stdout).unwrap()
    };
    let text = trend(&["--track-register", REGISTER]);
    let placed: Vec<&str> = text.lines().filter(|l| l.trim_start().starts_with("run 1: placed by GNSS")).collect();
    assert_eq!(placed.len(), 2, "{text}");
    assert!(placed.iter().all(|l| l.contains("START DISPUTED")), "{text}");
    let first_block = |json: &str| {
        let v: serde_json::Value = serde_json::from_str(json).unwrap();
        v["blocks"][0]["start_mm"].as_f64().unwrap()
    };
    let by_gnss = first_block(&trend(&["--track-register", REGISTER, "--json"]));
    assert!((by_gnss - 41_100_000.0).abs() < 200.0, "{by_gnss}");
    // Without the register the typed start places them, 100 m on.
    let typed = first_block(&trend(&["--json"]));
    assert!((typed - 41_200_000.0).abs() < 1.0, "{typed}");
}
