//! `analyze` along a long run: memory set by its pieces (whole blocks and
//! the standards' margins), not by the length of track.

use std::process::Command;

use crate::common::bin;

/// Peak resident memory of `cms-host ARGS`, kB, as the kernel accounts it
/// for a finished child (a Python parent's `getrusage(RUSAGE_CHILDREN)`:
/// this test process has other children running beside it).
fn peak_kb(args: &[&str]) -> u64 {
    let script = "import resource, subprocess, sys\n\
                  r = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)\n\
                  sys.stderr.buffer.write(r.stderr)\n\
                  print(r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)";
    let out = Command::new("python3").args(["-c", script, bin()]).args(args).output().expect("python3");
    let text = String::from_utf8_lossy(&out.stdout);
    let mut words = text.split_whitespace();
    assert_eq!(words.next(), Some("0"), "cms-host {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    words.next().and_then(|k| k.parse().ok()).expect("a peak")
}

#[test]
fn memory_does_not_grow_with_the_track() {
    let dir = tempfile::tempdir().unwrap();
    let mut peaks = Vec::new();
    // 170 m and 680 m of rail: both longer than a piece and its margins.
    for frames in [10_000, 40_000] {
        let rec = dir.path().join(format!("run{frames}.cmsrec"));
        let rec = rec.to_str().unwrap();
        let f = frames.to_string();
        let o = crate::common::cms_host(&["bench", "recording", "--frames", &f, "--points", "120", "--out", rec]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        peaks.push(peak_kb(&["analyze", rec, "--json"]));
    }
    println!("analyze peak: {} kB for 170 m, {} kB for 680 m", peaks[0], peaks[1]);
    // Four times the track: within 10 % (and a few MB of the allocator's slack).
    assert!(peaks[1] as f64 <= 1.1 * peaks[0] as f64 + 4096.0, "{peaks:?}");
    assert!(peaks[1] < 100_000, "{peaks:?}");
}
