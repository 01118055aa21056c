//! `bench speed`: nanoseconds per row of every detection method on 640-,
//! 752- and 1280-px 12-bit rows with 1 and 3 stripes, and the ratio `cwt` /
//! `cog` measured in the same run. `cargo bench -p cms-host --bench detect`
//! times the same rows with criterion; `bench qemu` counts instructions.

use std::fmt::Write as _;
use std::time::Instant;

use cms_core::peak::{Detector, Method, Stripes};
use cms_study::montecarlo as mc;

use super::BenchError;

/// Options of the speed benchmark.
#[derive(Debug, Clone)]
pub struct SpeedOptions {
    /// Rows timed per method, size and repetition.
    pub rows: u64,
    /// Repetitions (methods interleaved); the fastest is reported.
    pub reps: u64,
    /// Untimed rows per method and size before the repetitions.
    pub warmup: u64,
    /// Only these methods (empty: all).
    pub methods: Vec<Method>,
    /// Only these row sizes, (length, stripes) (empty: all).
    pub sizes: Vec<(usize, usize)>,
    /// Seed of the synthetic rows.
    pub seed: u64,
}

/// One timed configuration.
struct Timing {
    len: usize,
    stripes: usize,
    method: Method,
    ns: Vec<f64>,
    found_ok: u64,
    found_rows: u64,
}

/// The least disturbed repetition: other load only ever adds time.
fn fastest(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::NAN, f64::min)
}

/// The median (NaN of nothing).
pub(super) fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        s[n / 2]
    } else {
        (s[n / 2 - 1] + s[n / 2]) / 2.0
    }
}

const SPEED_BITS: u8 = 12;
const SPEED_DISTINCT_ROWS: usize = 64;

/// Times every method on every size; returns the report.
pub fn speed(a: &SpeedOptions) -> Result<String, BenchError> {
    let methods: Vec<Method> = if a.methods.is_empty() { Method::ALL.to_vec() } else { a.methods.clone() };
    let sizes: Vec<(usize, usize)> = if a.sizes.is_empty() {
        mc::SPEED_LENGTHS.iter().flat_map(|&l| mc::SPEED_STRIPES.iter().map(move |&k| (l, k))).collect()
    } else {
        a.sizes.clone()
    };
    let mut timings = Vec::new();
    for &(len, stripes) in &sizes {
        let rows = mc::speed_rows(len, stripes, SPEED_BITS, SPEED_DISTINCT_ROWS, a.seed);
        let mut dets = methods
            .iter()
            .map(|&m| {
                Detector::<{ mc::SPEED_MAX_LEN }>::new(mc::speed_config(m, SPEED_BITS, stripes))
                    .map(Box::new)
                    .map_err(|source| BenchError::Detector { method: m.name(), source })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let mut ts: Vec<Timing> = methods
            .iter()
            .map(|&method| Timing { len, stripes, method, ns: Vec::new(), found_ok: 0, found_rows: 0 })
            .collect();
        let mut out: Stripes<4> = Stripes::new();
        for (det, t) in dets.iter_mut().zip(ts.iter_mut()) {
            for i in 0..a.warmup as usize {
                det.detect(std::hint::black_box(rows[i % rows.len()].as_slice()), &mut out)
                    .map_err(|source| BenchError::Detect { method: t.method.name(), source })?;
            }
            for r in &rows {
                det.detect(r.as_slice(), &mut out)
                    .map_err(|source| BenchError::Detect { method: t.method.name(), source })?;
                t.found_rows += 1;
                t.found_ok += u64::from(out.len() == stripes);
            }
        }
        // Repetitions outermost, methods interleaved: a clock or thermal drift
        // during the run hits every method alike, so the ratios are fair.
        for _ in 0..a.reps {
            for (det, t) in dets.iter_mut().zip(ts.iter_mut()) {
                let mut acc = 0usize;
                let start = Instant::now();
                for i in 0..a.rows as usize {
                    det.detect(std::hint::black_box(rows[i % rows.len()].as_slice()), &mut out)
                        .map_err(|source| BenchError::Detect { method: t.method.name(), source })?;
                    acc += out.len();
                }
                let dt = start.elapsed();
                std::hint::black_box(acc);
                t.ns.push(dt.as_nanos() as f64 / a.rows as f64);
            }
        }
        timings.extend(ts);
    }
    Ok(speed_report(a, &methods, &sizes, &timings))
}

fn speed_report(a: &SpeedOptions, methods: &[Method], sizes: &[(usize, usize)], ts: &[Timing]) -> String {
    let mut r = String::new();
    let _ = writeln!(
        r,
        "# Detection time per row (ns; fastest of {} repetitions of {} rows, methods interleaved)\n",
        a.reps, a.rows
    );
    let _ = writeln!(
        r,
        "{SPEED_BITS}-bit rows, stripes of σ = {} px at {} dB measured over the row, {} distinct rows cycled; \
         detector scales {}–{} px, `max_stripes` = stripes per row. Single thread, `{}` build.\n",
        mc::SPEED_SIGMA,
        mc::SPEED_SNR_DB,
        SPEED_DISTINCT_ROWS,
        mc::study_scales(mc::SPEED_SIGMA).0,
        mc::study_scales(mc::SPEED_SIGMA).1,
        if cfg!(debug_assertions) { "debug (numbers meaningless)" } else { "release" }
    );
    let get = |m: Method, (l, k): (usize, usize)| {
        ts.iter().find(|t| t.method == m && t.len == l && t.stripes == k).map_or(f64::NAN, |t| fastest(&t.ns))
    };
    let _ = write!(r, "| method |");
    for (l, k) in sizes {
        let _ = write!(r, " {l} px × {k} |");
    }
    let _ = write!(r, "\n|---|");
    for _ in sizes {
        let _ = write!(r, "---:|");
    }
    for &m in methods {
        let _ = write!(r, "\n| {} |", m.name());
        for &s in sizes {
            let _ = write!(r, " {:.0} |", get(m, s));
        }
    }
    if methods.contains(&Method::Cwt) && methods.contains(&Method::Cog) {
        let _ = write!(r, "\n| **cwt / cog** |");
        for &s in sizes {
            let _ = write!(r, " **{:.2}** |", get(Method::Cwt, s) / get(Method::Cog, s));
        }
    }
    let _ = writeln!(r, "\n");
    let noisy = ts.iter().filter(|t| t.ns.len() > 1 && median(&t.ns) > 1.1 * fastest(&t.ns)).count();
    if noisy > 0 {
        let _ = writeln!(
            r,
            "Note: in {noisy} of {} configurations the median repetition was more than 10 % slower than the \
             fastest (a busy machine?); `scripts/instructions.sh` counts instructions instead.\n",
            ts.len()
        );
    }
    for t in ts.iter().filter(|t| t.found_ok < t.found_rows) {
        let _ = writeln!(
            r,
            "Note: {} found the wrong number of stripes in {} of {} rows of {} px × {}.",
            t.method.name(),
            t.found_rows - t.found_ok,
            t.found_rows,
            t.len,
            t.stripes
        );
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speed_reports_the_ratio() {
        let a = SpeedOptions {
            rows: 20,
            reps: 1,
            warmup: 0,
            methods: vec![Method::Cwt, Method::Cog],
            sizes: vec![(640, 1), (1280, 3)],
            seed: 1,
        };
        let r = speed(&a).unwrap();
        assert!(r.contains("| **cwt / cog** |"), "{r}");
        assert!(!r.contains("wrong number"), "{r}");
    }
}
