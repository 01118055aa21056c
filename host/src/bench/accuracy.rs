//! `bench accuracy`: the Monte-Carlo study of every detection method against
//! the Cramér–Rao bound, and the paper's synthetic protocol. Writes
//! `accuracy.csv`, `accuracy.svg`, `paper_protocol.csv` and `accuracy.md`
//! (the report). The simulation is `cms_study::montecarlo`, shared with the
//! tests.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use cms_core::peak::Method;
use cms_study::montecarlo::{self as mc, CellStats, Levels, SIGMAS, SNRS_DB, Study};

use super::{BenchError, put};

/// Options of the accuracy study.
#[derive(Debug, Clone)]
pub struct AccuracyOptions {
    /// Seed of the trials (the results repeat with it).
    pub seed: u64,
    /// Trials per method, σ and SNR.
    pub trials: u64,
    /// Folder of the files.
    pub out: PathBuf,
    /// Bit depth of the rows.
    pub bits: u8,
    /// Stripe amplitude, counts (`None`: the bit depth's default).
    pub amplitude: Option<f64>,
    /// Background, counts (`None`: the bit depth's default).
    pub background: Option<f64>,
    /// Trials of the paper's protocol.
    pub paper_trials: u64,
    /// Which table the report prints.
    pub table: ReportTable,
    /// Worker threads (`None`: one a core); the results do not depend on it.
    pub threads: Option<usize>,
}

/// Which Markdown table the accuracy report prints.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReportTable {
    /// RMS/CRLB, methods as rows, SNR as columns, one table per σ.
    Pivot,
    /// One row per method × σ × SNR with bias, std, RMS, max |e|, misses.
    Full,
}

/// Runs the accuracy study, writes its files into `a.out`, returns the report.
pub fn accuracy(a: &AccuracyOptions) -> Result<String, BenchError> {
    let mut levels = Levels::for_bits(a.bits);
    levels.amplitude = a.amplitude.unwrap_or(levels.amplitude);
    levels.background = a.background.unwrap_or(levels.background);
    let full = ((1u64 << a.bits) - 1) as f64;
    if !(levels.amplitude > 0.0 && levels.background >= 0.0 && levels.amplitude + levels.background < full) {
        return Err(BenchError::Options(format!(
            "amplitude {} + background {} must be positive and below {full}",
            levels.amplitude, levels.background
        )));
    }
    let study =
        Study { seed: a.seed, trials: a.trials as usize, bits: a.bits, levels, threads: super::threads(a.threads) };
    let t0 = Instant::now();
    let cells = study.run();
    let (fixed, random) = study.paper_protocol(a.paper_trials as usize);
    let secs = t0.elapsed().as_secs_f64();

    super::create_dir(&a.out)?;
    let csv_path = a.out.join("accuracy.csv");
    put(&csv_path, &mc::csv(&cells))?;
    let pp_path = a.out.join("paper_protocol.csv");
    put(&pp_path, &paper_csv(&fixed, &random))?;
    let svg_path = a.out.join("accuracy.svg");
    plot(&svg_path, &cells, &study)?;

    let mut r = String::new();
    report_header(&mut r, &study);
    match a.table {
        ReportTable::Pivot => pivot_tables(&mut r, &cells),
        ReportTable::Full => full_table(&mut r, &cells),
    }
    paper_section(&mut r, &study, &fixed, &random);
    let md_path = a.out.join("accuracy.md");
    put(&md_path, &r)?;
    let _ = writeln!(
        r,
        "\nWrote {}, {}, {} and {} ({} threads, {secs:.1} s).",
        csv_path.display(),
        svg_path.display(),
        pp_path.display(),
        md_path.display(),
        study.threads
    );
    Ok(r)
}

fn report_header(r: &mut String, s: &Study) {
    let _ = writeln!(r, "# Stripe detector accuracy: Monte-Carlo against the Cramér–Rao bound\n");
    if s.trials < mc::FULL_TRIALS {
        let _ = writeln!(
            r,
            "> **Quick run: {} trials per cell; the full study needs at least {}.**\n",
            s.trials,
            mc::FULL_TRIALS
        );
    }
    let _ = writeln!(
        r,
        "* Rows: {} samples, {}-bit, one Gaussian stripe of amplitude A = {} counts on a background of {} \
         counts; true centre x0 uniform over [{}, {}) px (random sub-pixel offsets).",
        mc::ROW_LEN,
        s.bits,
        s.levels.amplitude,
        s.levels.background,
        mc::STUDY_X0.0,
        mc::STUDY_X0.1
    );
    let _ = writeln!(
        r,
        "* **SNR is measured over the whole {}-sample row**, as MATLAB `awgn(x, snr, 'measured')` on the \
         stripe signal (background excluded) — not peak amplitude over noise; A/σn is given per column.",
        mc::ROW_LEN
    );
    let _ = writeln!(
        r,
        "* CRLB = (σeff/A)·sqrt(2σ/√π) with **σeff = sqrt(σn² + 1/12): quantisation included** as uniform \
         noise of 1/12 LSB²."
    );
    let _ = writeln!(
        r,
        "* Detector: `Config::new({}, scales [max(σ/2, 1), 1.5σ])`, `max_stripes` 1, other settings default.",
        s.bits
    );
    let _ = writeln!(
        r,
        "* {} trials per cell, seed {}; every method sees the same rows. Misses (rows without exactly one \
         stripe) are left out of the statistics and shown as `(n miss)`. The sampling error of an RMS/CRLB \
         figure is about 1/sqrt(2·trials) = {:.0} % (relative).\n",
        s.trials,
        s.seed,
        100.0 / (2.0 * s.trials as f64).sqrt()
    );
}

fn ratio_str(v: f64) -> String {
    if !v.is_finite() {
        "—".into()
    } else if v < 10.0 {
        format!("{v:.2}")
    } else if v < 100.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.0}")
    }
}

fn cell_of(cells: &[CellStats], m: Method, sigma: f64, snr: f64) -> Option<&CellStats> {
    cells.iter().find(|c| c.method == m && c.sigma == sigma && c.snr_db == snr)
}

fn pivot_tables(r: &mut String, cells: &[CellStats]) {
    let _ = writeln!(r, "## RMS error / CRLB (1.00 = the bound)\n");
    for &sigma in &SIGMAS {
        let (lo, hi) = mc::study_scales(sigma);
        let _ = writeln!(r, "### σ = {sigma} px (scales {lo}–{hi} px)\n");
        let _ = write!(r, "| method |");
        for snr in SNRS_DB {
            let _ = write!(r, " {snr} dB |");
        }
        let _ = write!(r, "\n|---|");
        for _ in SNRS_DB {
            let _ = write!(r, "---:|");
        }
        let any = |f: &dyn Fn(&CellStats) -> String| {
            SNRS_DB
                .iter()
                .map(|&snr| cell_of(cells, Method::Cwt, sigma, snr).map_or("—".into(), f))
                .collect::<Vec<_>>()
                .join(" | ")
        };
        let _ = write!(r, "\n| *A/σn* | {} |", any(&|c| format!("*{:.1}*", c.a_over_noise)));
        let _ = write!(r, "\n| *CRLB, px* | {} |", any(&|c| format!("*{:.5}*", c.crlb)));
        for m in Method::ALL {
            let _ = write!(r, "\n| {} |", m.name());
            for &snr in &SNRS_DB {
                let s = match cell_of(cells, m, sigma, snr) {
                    None => "—".into(),
                    Some(c) if c.misses > 0 => format!("{} ({} miss)", ratio_str(c.ratio()), c.misses),
                    Some(c) => ratio_str(c.ratio()),
                };
                let _ = write!(r, " {s} |");
            }
        }
        let _ = writeln!(r, "\n");
    }
    let _ = writeln!(r, "Bias, std, RMS, max |error|, misses per cell: `accuracy.csv`, or `--table full`.\n");
}

fn full_table(r: &mut String, cells: &[CellStats]) {
    let _ = writeln!(r, "## Every cell (errors in px)\n");
    let _ = writeln!(
        r,
        "| method | σ px | SNR dB | A/σn | CRLB | bias | std | RMS | max \\|e\\| | RMS/CRLB | misses | gross |"
    );
    let _ = writeln!(r, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for c in cells {
        let _ = writeln!(
            r,
            "| {} | {} | {} | {:.1} | {:.5} | {:+.5} | {:.5} | {:.5} | {:.4} | {} | {} | {} |",
            c.method.name(),
            c.sigma,
            c.snr_db,
            c.a_over_noise,
            c.crlb,
            c.bias,
            c.std,
            c.rms,
            c.max_abs,
            ratio_str(c.ratio()),
            c.misses,
            c.gross
        );
    }
    let _ = writeln!(r, "\n`gross`: detections more than one stripe σ from the truth (kept in the statistics).\n");
}

fn paper_section(r: &mut String, s: &Study, fixed: &[CellStats], random: &[CellStats]) {
    let crlb = fixed.first().map_or(f64::NAN, |c| c.crlb);
    let a_sn = fixed.first().map_or(f64::NAN, |c| c.a_over_noise);
    let trials = fixed.first().map_or(0, |c| c.trials);
    let _ = writeln!(r, "## Paper protocol (§6.2, Table 3) and why x0 = 107.5 flatters\n");
    let _ = writeln!(
        r,
        "{} samples, σ = {} px, scales {}–{} px, {} dB measured over the row (A/σn = {a_sn:.1}), {trials} trials, \
         {}-bit levels as above; CRLB {crlb:.5} px. *Published*: x0 = {} exactly, as in the paper. *Random*: x0 \
         uniform over [107, 108). The paper does not say what its ± is; mean |error| and RMS are both given.\n",
        mc::ROW_LEN,
        mc::paper::SIGMA,
        mc::paper::SCALES.0,
        mc::paper::SCALES.1,
        mc::paper::SNR_DB,
        s.bits,
        mc::paper::X0
    );
    let _ = writeln!(
        r,
        "| method | paper's Table 3 | published: mean \\|e\\| | RMS | bias | max \\|e\\| | RMS/CRLB | random: mean \\|e\\| \
         | RMS | bias | max \\|e\\| | RMS/CRLB |"
    );
    let _ = writeln!(r, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (f, x) in fixed.iter().zip(random) {
        let printed = mc::paper::TABLE3
            .iter()
            .find(|t| t.0 == f.method)
            .map_or("—".to_string(), |t| format!("±{} ({})", t.2, t.1));
        let miss = |c: &CellStats| if c.misses > 0 { format!(" ({} miss)", c.misses) } else { String::new() };
        let _ = writeln!(
            r,
            "| {} | {printed} | {:.4}{} | {:.4} | {:+.4} | {:.4} | {} | {:.4}{} | {:.4} | {:+.4} | {:.4} | {} |",
            f.method.name(),
            f.mean_abs,
            miss(f),
            f.rms,
            f.bias,
            f.max_abs,
            ratio_str(f.ratio()),
            x.mean_abs,
            miss(x),
            x.rms,
            x.bias,
            x.max_abs,
            ratio_str(x.ratio())
        );
    }
    let _ = writeln!(r);
}

fn paper_csv(fixed: &[CellStats], random: &[CellStats]) -> String {
    let mut s = format!("placement,{}\n", mc::CSV_HEADER);
    for (name, cells) in [("x0=107.5", fixed), ("x0~U[107,108)", random)] {
        for line in mc::csv(cells).lines().skip(1) {
            let _ = writeln!(s, "{name},{line}");
        }
    }
    s
}

const COLOURS: [(u8, u8, u8); 10] = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
];

/// RMS/CRLB against SNR, log y, one line per method, one panel per σ.
fn plot(path: &Path, cells: &[CellStats], s: &Study) -> Result<(), BenchError> {
    let finite = cells.iter().map(|c| c.ratio()).filter(|v| v.is_finite());
    let lo = finite.clone().fold(1.0f64, f64::min) * 0.8;
    let hi = finite.fold(1.0f64, f64::max) * 1.25;
    crate::plot::fonts();
    // Drawn into a string, then written whole like every output.
    let mut svg = String::new();
    draw(&mut svg, cells, s, lo, hi).map_err(|e| BenchError::Plot { path: path.to_path_buf(), why: e.to_string() })?;
    put(path, &svg)
}

/// [`plot`]'s drawing.
fn draw(svg: &mut String, cells: &[CellStats], s: &Study, lo: f64, hi: f64) -> Result<(), Box<dyn std::error::Error>> {
    use plotters::prelude::*;
    let root = SVGBackend::with_string(svg, (1400, 1000)).into_drawing_area();
    root.fill(&WHITE)?;
    let title = format!(
        "RMS error / CRLB, {} trials per point, {}-bit, A = {}; SNR measured over the {}-sample row (MATLAB awgn 'measured')",
        s.trials,
        s.bits,
        s.levels.amplitude,
        mc::ROW_LEN
    );
    let root = root.titled(&title, ("sans-serif", 20))?;
    for (i, (panel, &sigma)) in root.split_evenly((2, 2)).iter().zip(&SIGMAS).enumerate() {
        let (smin, smax) = mc::study_scales(sigma);
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("stripe σ = {sigma} px (scales {smin}–{smax})"), ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(8f64..42f64, (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .x_labels(4)
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| if *v >= 10.0 { format!("{v:.0}") } else { format!("{v:.1}") })
            .x_desc("SNR, dB (measured over the row)")
            .y_desc("RMS / CRLB")
            .draw()?;
        chart
            .draw_series(DashedLineSeries::new([(8.0, 1.0), (42.0, 1.0)], 6, 4, BLACK.stroke_width(1)))?
            .label("CRLB")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK));
        for (k, m) in Method::ALL.into_iter().enumerate() {
            let (r, g, b) = COLOURS[k % COLOURS.len()];
            let colour = RGBColor(r, g, b);
            let width = if m == Method::Cwt { 3 } else { 2 };
            let pts: Vec<(f64, f64)> = SNRS_DB
                .iter()
                .filter_map(|&snr| cell_of(cells, m, sigma, snr))
                .map(|c| (c.snr_db, c.ratio()))
                .filter(|p| p.1.is_finite())
                .collect();
            chart
                .draw_series(LineSeries::new(pts, colour.stroke_width(width)).point_size(3))?
                .label(m.name())
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(width)));
        }
        if i == 0 {
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperLeft)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 13))
                .draw()?;
        }
    }
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn options(out: PathBuf, seed: u64, threads: usize) -> AccuracyOptions {
        AccuracyOptions {
            seed,
            trials: 4,
            out,
            bits: 12,
            amplitude: None,
            background: None,
            paper_trials: 5,
            table: ReportTable::Pivot,
            threads: Some(threads),
        }
    }

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("cms-bench-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn accuracy_writes_every_cell_and_repeats_with_the_seed() {
        let (d1, d2) = (scratch("a"), scratch("b"));
        let report = accuracy(&options(d1.clone(), 9, 2)).unwrap();
        accuracy(&options(d2.clone(), 9, 1)).unwrap();
        let c1 = std::fs::read_to_string(d1.join("accuracy.csv")).unwrap();
        let c2 = std::fs::read_to_string(d2.join("accuracy.csv")).unwrap();
        assert_eq!(c1, c2, "same seed, same CSV");
        assert_eq!(
            std::fs::read(d1.join("paper_protocol.csv")).unwrap(),
            std::fs::read(d2.join("paper_protocol.csv")).unwrap()
        );
        let mut lines = c1.lines();
        assert_eq!(lines.next(), Some(mc::CSV_HEADER));
        assert_eq!(lines.count(), Method::ALL.len() * 4 * 4);
        let svg = std::fs::read_to_string(d1.join("accuracy.svg")).unwrap();
        assert!(svg.starts_with("<svg") && svg.contains("cwt-paper"));
        assert!(report.contains("measured over the whole 480-sample row"));
        assert!(report.contains("Quick run"));
        assert!(report.contains("| cwt-paper | ±0.0062"));
        let _ = std::fs::remove_dir_all(&d1);
        let _ = std::fs::remove_dir_all(&d2);
    }
}
