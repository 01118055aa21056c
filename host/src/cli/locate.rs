//! `cms-host locate`: a recording's GNSS fixes on a track register, its
//! chainage from them, checked against the odometer and the survey.

use std::fmt::Write as _;
use std::path::PathBuf;

use clap::Args;
use cms_host::gnss::register::{self, Check, Register};
use cms_host::output;
use cms_host::recording::{self, survey_info::Survey};

use super::exit::{Usage, input};

/// Arguments of `cms-host locate`.
#[derive(Args, Debug, Clone)]
pub struct LocateArgs {
    /// A recording made by `cms-host listen --gnss … --record`.
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
    /// The track register: a CSV of the centreline, `lat_deg,lon_deg,chainage_m`
    /// (docs/gnss.md).
    #[arg(long, value_name = "REGISTER.csv")]
    pub register: PathBuf,
    /// The register centreline's standard uncertainty, m (0.001..=10).
    #[arg(long, value_name = "M", default_value_t = 0.05, value_parser = parse_sigma)]
    pub register_sigma_m: f64,
    /// Every fix used, one CSV line each: its odometer, chainage, offset
    /// from the centreline, residual and tolerance (a regular file, replaced whole).
    #[arg(long, value_name = "OUT.csv")]
    pub csv: Option<PathBuf>,
}

fn parse_sigma(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if (0.001..=10.0).contains(&v) => Ok(v),
        _ => Err(format!("`{s}`: a standard uncertainty of 0.001 to 10 m")),
    }
}

fn chainage(m: f64) -> String {
    // Rounded to the millimetre first: 11 999.9999 m is 12+000.000, not 11+1000.000.
    let m = (m * 1000.0).round() / 1000.0;
    let km = (m / 1000.0).floor();
    format!("{km:.0}+{:07.3}", m - km * 1000.0)
}

/// The report of one head session's check.
fn describe(c: &Check, survey: Option<&Survey>) -> String {
    let mut s = String::new();
    let dir = if c.scale >= 0.0 { "rising" } else { "falling" };
    let _ = writeln!(
        s,
        "  {} fixes on the track, {} not used ({} more than {} m off the centreline, {} outside the frames' times or not from satellites)",
        c.located.len(),
        c.unused,
        c.off_track,
        register::OFF_TRACK_M,
        c.unused - c.off_track
    );
    let _ = writeln!(
        s,
        "  chainage at odometer 0: {} ({dir} with the odometer, {:+.5} m of chainage per m of odometer)",
        chainage(c.chainage_at_zero_m),
        c.scale
    );
    if let Some(w) = c.worst() {
        let _ = writeln!(
            s,
            "  residuals: RMS {:.3} m; worst {:+.3} m at {} (its tolerance {:.3} m)",
            c.rms_m(),
            w.residual_m(),
            chainage(w.on_track.chainage_m),
            w.tolerance_m
        );
    }
    let n = c.disagreeing();
    if n == 0 {
        let _ = writeln!(s, "  verdict: agrees — every fix within its tolerance of the odometer's chainage");
    } else {
        let _ = writeln!(
            s,
            "  verdict: DISAGREES — {n} of {} fixes beyond their tolerance of the odometer's chainage (a slipping wheel, a wrong register or another track)",
            c.located.len()
        );
    }
    if let Some(p) = survey.and_then(|sv| sv.placement().ok()) {
        let tol = c.worst().map_or(0.0, |w| w.tolerance_m);
        if let Some(start) = p.start_m {
            let d = c.chainage_at_zero_m - start;
            let verdict = if d.abs() <= tol { "agrees" } else { "DISAGREES" };
            let _ = writeln!(
                s,
                "  survey: start_chainage {} — GNSS places odometer 0 {d:+.3} m from it: {verdict} (tolerance {tol:.3} m)",
                chainage(start)
            );
        }
        if let Some(h) = p.heading {
            let said_up = matches!(h, recording::survey_info::Heading::Up);
            let verdict = if said_up == (c.scale >= 0.0) { "agrees" } else { "DISAGREES" };
            let _ =
                writeln!(s, "  survey: chainage {} — GNSS says {dir}: {verdict}", if said_up { "up" } else { "down" });
        }
    }
    s
}

/// `cms-host locate`.
pub fn run(args: &LocateArgs) -> anyhow::Result<()> {
    let mut reg = Register::load(&args.register)?;
    reg.sigma_m = args.register_sigma_m;
    if let Some(o) = &args.csv {
        if recording::same_file(o, &args.file) || recording::same_file(o, &args.register) {
            anyhow::bail!(Usage(format!("--csv {} is an input; refusing to overwrite it", o.display())));
        }
        output::check_target(o)?;
    }
    let (sessions, stats) = recording::fixes_of(&args.file)?;
    for w in recording::warnings(&args.file, &stats) {
        eprintln!("{w}");
    }
    if sessions.is_empty() {
        return Err(input(format!(
            "{}: no GNSS fixes (recorded without listen --gnss, or format {} before fixes)",
            args.file.display(),
            stats.header.map_or(0, |h| h.format)
        )));
    }
    let survey = match recording::survey_of(&args.file) {
        Ok(Some(t)) => Survey::parse(&t).ok(),
        _ => None,
    };
    let (a, b) = reg.span_m();
    let mut out = format!(
        "locate: {} on {} ({} to {})\n",
        output::printable(&args.file.display().to_string()),
        output::printable(&args.register.display().to_string()),
        chainage(a),
        chainage(b)
    );
    let mut csv = String::from("session,odometer_m,chainage_m,offset_m,fitted_m,residual_m,tolerance_m,disagrees\n");
    for (k, sess) in sessions.iter().enumerate() {
        let _ = writeln!(out, "session {} of {}: {} fixes", k + 1, sessions.len(), sess.fixes.len());
        match register::check(&reg, &sess.fixes, &sess.profiles) {
            Ok(c) => {
                out += &describe(&c, survey.as_ref());
                for l in &c.located {
                    let _ = writeln!(
                        csv,
                        "{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{}",
                        k + 1,
                        l.odometer_m,
                        l.on_track.chainage_m,
                        l.on_track.offset_m,
                        l.fitted_m,
                        l.residual_m(),
                        l.tolerance_m,
                        l.disagrees()
                    );
                }
            }
            Err(e) => {
                let _ = writeln!(out, "  verdict: failed — {e}");
            }
        }
    }
    print!("{out}");
    if let Some(o) = &args.csv {
        output::write_atomically(o, |w| std::io::Write::write_all(w, csv.as_bytes()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chainages_print_as_km_plus_metres() {
        assert_eq!(chainage(41_100.012_6), "41+100.013");
        assert_eq!(chainage(999.5), "0+999.500");
        assert_eq!(chainage(12_000.0), "12+000.000");
        assert_eq!(chainage(11_999.999_9), "12+000.000");
    }
}
